"""spec/header.schema.json agrees with the reader: valid vectors' headers pass, and the key sets match."""

from __future__ import annotations

import json

import msgpack
import pytest

from format_strategies import REPO, load_vector_tool
from vt4dcodec.format.header import CAMERA_KEYS, HEADER_KEYS

SCHEMA = json.loads((REPO / "spec" / "header.schema.json").read_text())


def test_schema_key_sets_match_the_reader():
    assert set(SCHEMA["required"]) == HEADER_KEYS == set(SCHEMA["properties"])
    assert set(SCHEMA["properties"]["cameras"]["required"]) == CAMERA_KEYS


def test_valid_vectors_headers_validate():
    jsonschema = pytest.importorskip("jsonschema")
    mv = load_vector_tool()
    for path in sorted((REPO / "spec" / "vectors" / "valid").glob("*.vt4d")):
        header, _ = mv.split(path.read_bytes())
        if "future_minor" in path.stem:
            header.pop("future_key")  # a newer minor version may add keys; 1.0's schema lists exactly 1.0's
        jsonschema.validate(header, SCHEMA)


def test_schema_rejects_what_the_reader_rejects():
    jsonschema = pytest.importorskip("jsonschema")
    mv = load_vector_tool()
    for name in ("header_unknown_key", "header_missing_key", "bad_sha256", "absurd_shape"):
        data = (REPO / "spec" / "vectors" / "invalid" / f"{name}.vt4d").read_bytes()
        header = msgpack.unpackb(data[64:64 + int.from_bytes(data[40:44], "little")], raw=False)
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(header, SCHEMA)
    assert mv  # the helper module loads
