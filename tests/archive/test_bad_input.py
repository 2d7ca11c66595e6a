"""Damaged and hostile archives raise typed errors, never wrong data, never huge allocations."""

import struct

import numpy as np
import pytest
from hypothesis import given, strategies as st

from vt4dcodec.archive import ArchiveWriter, open_archive, verify_archive
from vt4dcodec.archive.index import ENTRY_DTYPE, DuplicateKeyError, IndexChecksumError, OverlappingRecordsError
from vt4dcodec.archive.layout import FOOTER_SIZE, HEADER_SIZE, INDEX_HEADER_SIZE, Commit, crc32, pack_footer
from vt4dcodec.archive.reader import NoCommitError
from vt4dcodec.errors import (ArchiveError, BadMagicError, ChecksumError, LimitExceededError, TruncatedError,
                              UnsupportedVersionError, Vt4dError)

from .helpers import payload_for

KEYS1 = ["alpha", "beta", "gamma"]
KEYS2 = ["delta", "eps"]


def _build(tmp_path) -> bytes:
    """A version 1.0 archive (whole index per commit): the hostile indexes below rewrite that index.
    (A 1.1 segment is the same block; manifests are attacked in test_segments.py.)"""
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, durable=False, version=(1, 0)) as w:
        for k in KEYS1:
            w.append(k, payload_for(k, 40), validate=False)
        w.commit()
        for k in KEYS2:
            w.append(k, payload_for(k, 30), validate=False)
    return path.read_bytes()


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> bytes:
    return _build(tmp_path_factory.mktemp("bad"))


def _commit_of(data: bytes) -> Commit:
    from vt4dcodec.archive.layout import parse_footer

    return parse_footer(data[-FOOTER_SIZE:])


def _read_all(data: bytes) -> dict[str, bytes]:
    with open_archive(data) as ar:
        return dict(ar.iter_records())


def _with_index(data: bytes, index: bytes, count: int | None = None, clear_slots: bool = True) -> bytes:
    """Replace the last commit's index by ``index`` and write a footer whose CRC matches it."""
    c = _commit_of(data)
    new = Commit(c.generation + 1, c.index_offset, len(index), crc32(index),
                 c.scene_count if count is None else count)
    head = bytearray(data[: c.index_offset])
    if clear_slots:
        head[32:HEADER_SIZE] = bytes(HEADER_SIZE - 32)
    return bytes(head) + index + pack_footer(new)


def _table(data: bytes) -> tuple[np.ndarray, bytes, bytes]:
    c = _commit_of(data)
    idx = data[c.index_offset: c.footer_offset]
    n, kl, sl = struct.unpack_from("<QQQ", idx, 8)
    t = np.frombuffer(idx, ENTRY_DTYPE, n, INDEX_HEADER_SIZE).copy()
    return t, idx[:INDEX_HEADER_SIZE], idx[INDEX_HEADER_SIZE + 48 * n:]


def test_good_archive_reads(good):
    assert _read_all(good) == {k: payload_for(k, 40) for k in KEYS1} | {k: payload_for(k, 30) for k in KEYS2}


def test_damaged_footer_falls_back_to_header_slot_and_verify_reports_it(good, tmp_path):
    bad = bytearray(good)
    bad[-10] ^= 0xFF
    assert _read_all(bytes(bad)) == _read_all(good)  # the slot names the same commit
    p = tmp_path / "x.vt4da"
    p.write_bytes(bytes(bad))
    with pytest.raises(ArchiveError):
        verify_archive(str(p), records=False)


def _refooter(data: bytes, fmt: str, offset: int, value: int) -> bytes:
    """The tail footer with one field changed and its CRC fixed: still a written footer (II 7, step 3)."""
    foot = bytearray(data[-FOOTER_SIZE:])
    struct.pack_into(fmt, foot, offset, value)
    struct.pack_into("<I", foot, FOOTER_SIZE - 4, crc32(bytes(foot[:-4])))
    return data[:-FOOTER_SIZE] + bytes(foot)


@pytest.mark.parametrize("field, fmt, offset, value, error", [
    ("major 2", "<H", 8, 2, UnsupportedVersionError),
    ("unknown flag bit 5", "<I", 12, 1 << 5, UnsupportedVersionError),
    ("index offset inside the header", "<Q", 24, 100, ArchiveError),
    ("scene count over 2^24", "<Q", 40, 2**24 + 1, LimitExceededError),
])
def test_a_written_footer_is_never_passed_over_for_an_older_slot(good, field, fmt, offset, value, error):
    """Issue 52.8: a tail footer whose magics and CRC hold is the last commit's; one this reader cannot
    use is an error, not a reason to read the state an older slot names (the slots here are intact)."""
    bad = _refooter(good, fmt, offset, value)
    with pytest.raises(error):
        _read_all(bad)
    torn = bytearray(bad)
    torn[-1] ^= 1  # the same footer torn (CRC fails): not a written footer, the slots are used
    assert _read_all(bytes(torn)) == _read_all(good)


def test_damaged_footer_and_slots_is_no_commit(good):
    bad = bytearray(good)
    bad[-10] ^= 0xFF
    bad[40] ^= 0xFF
    bad[100] ^= 0xFF
    with pytest.raises(NoCommitError):
        _read_all(bytes(bad))


def test_corrupted_index_is_a_checksum_error(good):
    c = _commit_of(good)
    bad = bytearray(good)
    bad[c.index_offset + 40] ^= 1
    with pytest.raises(IndexChecksumError) as info:
        _read_all(bytes(bad))
    assert isinstance(info.value, ChecksumError)


def test_bad_magic(good):
    bad = b"\x89PNG\r\n\x1a\n" + good[8:]
    with pytest.raises(BadMagicError):
        verify_archive(bad)
    with pytest.raises(BadMagicError):
        open_archive(b"\x89PNG\r\n\x1a\n" + bytes(40))


def test_overlapping_records(good):
    t, head, blobs = _table(good)
    t[1]["payload_offset"] = t[0]["payload_offset"] + 5
    with pytest.raises(OverlappingRecordsError):
        _read_all(_with_index(good, head + t.tobytes() + blobs))


def test_offset_past_the_end(good):
    t, head, blobs = _table(good)
    t[2]["payload_offset"] = 2**62
    with pytest.raises(ArchiveError, match="past the end|outside"):
        _read_all(_with_index(good, head + t.tobytes() + blobs))
    t, head, blobs = _table(good)
    t[2]["payload_length"] = 2**64 - 1  # would overflow offset + length
    with pytest.raises(ArchiveError):
        _read_all(_with_index(good, head + t.tobytes() + blobs))


def test_duplicate_keys(good):
    t, head, blobs = _table(good)
    keys = b"alphaalphadeltaepsgamma"  # the blob packs keys in entry order; make #0 and #1 equal
    t["key_len"] = [5, 5, 5, 3, 5]
    t["key_offset"] = [0, 5, 10, 15, 18]
    kl = struct.unpack_from("<Q", head, 16)[0]
    new_head = head[:16] + struct.pack("<Q", len(keys)) + head[24:]
    with pytest.raises(DuplicateKeyError):
        _read_all(_with_index(good, new_head + t.tobytes() + keys + blobs[kl:]))


def test_huge_counts_fail_before_allocating(good):
    c = _commit_of(good)
    idx = bytearray(good[c.index_offset: c.footer_offset])
    idx[8:16] = struct.pack("<Q", 2**60)
    with pytest.raises(LimitExceededError):
        _read_all(_with_index(good, bytes(idx), count=5))
    with pytest.raises((LimitExceededError, NoCommitError)):
        _read_all(_with_index(good, bytes(idx), count=2**60))
    idx[8:16] = struct.pack("<Q", 10**6)  # within limits, but the index is far too short for it
    with pytest.raises(ArchiveError):
        _read_all(_with_index(good, bytes(idx), count=10**6))


def test_footer_claiming_huge_index_is_not_trusted(good):
    c = _commit_of(good)
    lie = Commit(c.generation + 1, c.index_offset, 2**50, 0, 3)
    bad = bytearray(good[:-FOOTER_SIZE] + pack_footer(lie))
    bad[32:HEADER_SIZE] = bytes(HEADER_SIZE - 32)
    with pytest.raises(NoCommitError):
        _read_all(bytes(bad))


def test_truncation_at_every_offset(good):
    first = {k: payload_for(k, 40) for k in KEYS1}
    full = _read_all(good)
    for n in range(len(good)):
        try:
            got = _read_all(good[:n])
        except Vt4dError:
            assert n < len(good)
            continue
        assert got in ({}, first, full), n


@given(st.lists(st.tuples(st.integers(0, 10**6), st.integers(1, 255)), min_size=1, max_size=4))
def test_byte_flips_never_give_wrong_data(tmp_path_factory, flips):
    good = _good_cache(tmp_path_factory)
    bad = bytearray(good)
    for pos, xor in flips:
        bad[pos % len(bad)] ^= xor
    originals = {k: payload_for(k, 40) for k in KEYS1} | {k: payload_for(k, 30) for k in KEYS2}
    try:
        with open_archive(bytes(bad)) as ar:
            for k in ar.keys():
                try:
                    assert ar.read_bytes(k) == originals[k]
                except (ChecksumError, TruncatedError):
                    pass
    except Vt4dError:
        pass


_GOOD: list[bytes] = []


def _good_cache(factory) -> bytes:
    if not _GOOD:
        _GOOD.append(_build(factory.mktemp("flip")))
    return _GOOD[0]
