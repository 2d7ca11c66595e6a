"""Model fingerprint, provenance and metadata validation."""

from __future__ import annotations

import numpy as np
import pytest

from format_strategies import fingerprint, simple_scene
from vt4dcodec.errors import FormatError, LimitExceededError, MalformedHeaderError
from vt4dcodec.format import ModelFingerprint, Provenance, dumps, loads
from vt4dcodec.format.metadata import normalize_metadata


def test_fingerprint_matches_and_short_form():
    a = fingerprint((4, 2), (3, 2))
    assert a.matches(fingerprint((4, 2), (3, 2)))
    assert not a.matches(fingerprint((5, 2), (3, 2)))
    assert not a.matches("not a fingerprint")  # type: ignore[arg-type]
    short = a.short()
    assert "test-model@0.1" in short and a.config_sha256[:8] in short and "\n" not in short
    assert ModelFingerprint.from_dict(a.to_dict()) == a


@pytest.mark.parametrize("change, error", [
    ({"config_sha256": "A" * 64}, MalformedHeaderError),
    ({"weights_sha256": "0" * 63}, MalformedHeaderError),
    ({"model_id": ""}, MalformedHeaderError),
    ({"model_id": "bad\nname"}, MalformedHeaderError),
    ({"static_shape": (0, 2)}, LimitExceededError),
    ({"static_shape": (1 << 40, 2)}, LimitExceededError),
    ({"dynamic_shape": (2, 5000)}, LimitExceededError),
    ({"static_shape": (2, True)}, MalformedHeaderError),
    ({"token_dtype": "Float 32"}, MalformedHeaderError),
])
def test_fingerprint_rejects_bad_fields(change, error):
    fields = fingerprint((4, 2), (3, 2)).to_dict()
    fields.update(change)
    with pytest.raises(error):
        ModelFingerprint(**fields)


def test_provenance_validation_and_now():
    p = Provenance.now("cap-7", "generated")
    assert p.kind == "generated" and p.created_utc.endswith("Z")
    assert Provenance.from_dict(p.to_dict()) == p
    for bad in ({"kind": "stolen"}, {"created_utc": "yesterday"}, {"source_capture_id": 5}):
        with pytest.raises(MalformedHeaderError):
            Provenance(**dict(p.to_dict(), **bad))


def test_provenance_honours_source_date_epoch(monkeypatch):
    # reproducible files: the same input encoded twice writes the same bytes when SOURCE_DATE_EPOCH is set
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1767225600")
    assert Provenance.now("cap").created_utc == "2026-01-01T00:00:00Z"
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "0")
    assert Provenance.now(None).created_utc == "1970-01-01T00:00:00Z"
    for bad in ("-1", "1.5", "soon", " 12", "1" * 13, "999999999999"):
        monkeypatch.setenv("SOURCE_DATE_EPOCH", bad)
        with pytest.raises(MalformedHeaderError, match="SOURCE_DATE_EPOCH"):
            Provenance.now("cap")
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "")  # empty: unset
    assert Provenance.now("cap").created_utc.endswith("Z")


def test_metadata_types_depth_and_size():
    assert normalize_metadata({"t": (1, 2), "n": np.int64(3), "f": np.float32(0.5), "b": np.bool_(True)}) == {
        "t": [1, 2], "n": 3, "f": 0.5, "b": True}
    with pytest.raises(MalformedHeaderError):
        normalize_metadata({"x": b"bytes"})
    with pytest.raises(MalformedHeaderError):
        normalize_metadata({1: "int key"})
    with pytest.raises(MalformedHeaderError):
        normalize_metadata({"x": float("nan")})
    with pytest.raises(MalformedHeaderError):
        normalize_metadata({"x": 1 << 64})
    deep = 0
    for _ in range(7):
        deep = [deep]
    normalize_metadata({"d": deep})  # the map + 7 lists = 8 levels: allowed
    with pytest.raises(LimitExceededError):
        normalize_metadata({"d": [deep]})
    with pytest.raises(LimitExceededError):
        normalize_metadata({"big": "x" * 60000, "big2": "y" * 60000, "b3": "z" * 60000, "b4": "w" * 60000,
                            "b5": "v" * 60000})


def test_scene_rejects_inconsistent_parts():
    base = simple_scene()
    with pytest.raises(FormatError, match="fingerprint"):
        simple_scene().__class__(base.static_tokens[:2], base.dynamic_tokens, base.cameras, base.fingerprint)
    bad = base.static_tokens.copy()
    bad[0, 0] = np.nan
    with pytest.raises(FormatError, match="NaN"):
        base.__class__(bad, base.dynamic_tokens, base.cameras, base.fingerprint)
    with pytest.raises(FormatError, match="encoding"):
        base.__class__(base.static_tokens, base.dynamic_tokens, base.cameras, base.fingerprint, encoding="int2")


def test_metadata_round_trips_exactly():
    meta = {"name": "é✓", "n": -(1 << 63), "f": 1e-300, "l": [None, True, {"x": []}]}
    assert loads(dumps(simple_scene(metadata=meta))).metadata == meta
