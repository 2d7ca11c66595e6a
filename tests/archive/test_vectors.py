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


#: what each rejection is named for, as the reader's message says it (issue 52.6: a vector rejected for an
#: accidental second defect would pass the class check above and fail here)
REASONS = {
    "invalid_bad_magic.vt4da": "bad magic", "invalid_duplicate_keys.vt4da": "duplicate key",
    "invalid_huge_count.vt4da": r"claims 1099511627776 scenes", "invalid_index_checksum.vt4da": "index checksum",
    "invalid_no_commit.vt4da": "no valid commit", "invalid_offset_past_end.vt4da": "past the end",
    "invalid_overlapping_records.vt4da": "overlapping records", "invalid_preamble_flags.vt4da": "unknown required flags",
    "invalid_preamble_major.vt4da": "major version 2", "invalid_segment_checksum.vt4da": "segment .* checksum",
    "invalid_truncated.vt4da": "too short for an archive", "invalid_truncated_commit.vt4da": "truncated: commit generation",
    "invalid_light_tail_checksum.vt4da": "tail fails its meta checksum", "invalid_light_tail_too_long.vt4da":
    "tail of 262145 bytes exceeds", "invalid_light_tail_garbage.vt4da": "neither a record frame nor a footer",
    "invalid_light_journal_mismatch.vt4da": "journal .* does not list the frames",
    "invalid_light_count.vt4da": "hold 36 distinct scenes, the commit says 37",
    "invalid_compressed_ratio.vt4da": "over 64x", "invalid_compressed_size_mismatch.vt4da": "declare its raw length",
}


@pytest.mark.parametrize("name", sorted(n for n, e in EXPECTED.items() if not e["valid"]))
def test_invalid_vectors_fail_for_the_reason_their_name_gives(name):
    with pytest.raises(_error_class(EXPECTED[name]["error"]), match=REASONS[name]):
        with open_archive(os.path.join(VECTORS, name)) as ar:
            dict(ar.iter_records())
