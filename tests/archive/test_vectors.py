"""The golden vectors in spec/vectors/archive are reproduced exactly and behave as documented."""

import hashlib
import importlib.util
import json
import os
import shutil

import pytest

import vt4dcodec.archive as archive
import vt4dcodec.archive.index as index_mod
import vt4dcodec.archive.reader as reader_mod
import vt4dcodec.errors as errors
from vt4dcodec.archive import open_archive, repair_archive, verify_archive

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
VECTORS = os.path.join(ROOT, "spec", "vectors", "archive")
EXPECTED = json.load(open(os.path.join(VECTORS, "expected.json")))


def _generator():
    spec = importlib.util.spec_from_file_location("make_archive_vectors",
                                                  os.path.join(ROOT, "spec", "make_archive_vectors.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_generator_reproduces_committed_vectors_byte_for_byte():
    fresh = _generator().build()
    assert sorted(fresh) == sorted(os.listdir(VECTORS))
    for name, content in fresh.items():
        if name == "expected.json":
            assert content == EXPECTED
        else:
            with open(os.path.join(VECTORS, name), "rb") as f:
                assert f.read() == content, name


@pytest.mark.parametrize("name", sorted(n for n, e in EXPECTED.items() if e["valid"]))
def test_valid_vectors_read_as_expected(name, tmp_path):
    exp = EXPECTED[name]
    path = tmp_path / name
    shutil.copy(os.path.join(VECTORS, name), path)
    with open_archive(path) as ar:
        assert ar.generation == exp["generation"] and ar.uncommitted_bytes == exp["uncommitted_bytes"]
        got = {k: hashlib.sha256(v).hexdigest() for k, v in ar.iter_records()}
    assert got == exp["records"]
    if exp["uncommitted_bytes"]:
        report = repair_archive(str(path))
        assert report.recovered == exp["repair_recovers"]
    verify_archive(path)


def _error_class(name):
    for mod in (errors, archive, index_mod, reader_mod):
        if hasattr(mod, name):
            return getattr(mod, name)
    raise AssertionError(name)


@pytest.mark.parametrize("name", sorted(n for n, e in EXPECTED.items() if not e["valid"]))
def test_invalid_vectors_raise_the_documented_error(name):
    with pytest.raises(_error_class(EXPECTED[name]["error"])):
        verify_archive(os.path.join(VECTORS, name))
