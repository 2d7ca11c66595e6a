"""Fixed-size structures round-trip and reject damage."""

import pytest
from hypothesis import given, strategies as st

from vt4dcodec.archive.layout import (FOOTER_SIZE, SLOT_SIZE, Commit, check_key, pack_footer, pack_frame_header,
                                      pack_slot, parse_footer, parse_frame_header, parse_slot)
from vt4dcodec.errors import ArchiveError, ChecksumError

u64 = st.integers(0, 2**63)
commits = st.builds(lambda g, off, extra, crc, n: Commit(g, 160 + off, 32 + 48 * n + extra, crc, n),
                    u64, st.integers(0, 2**40), st.integers(0, 2**20), st.integers(0, 2**32 - 1),
                    st.integers(0, 1000))


@given(commits)
def test_footer_and_slot_round_trip(c):
    assert parse_footer(pack_footer(c)) == c
    assert parse_slot(pack_slot(c)) == c
    assert len(pack_footer(c)) == FOOTER_SIZE and len(pack_slot(c)) == SLOT_SIZE


@given(commits, st.integers(0, FOOTER_SIZE - 1), st.integers(1, 255))
def test_any_footer_byte_flip_is_detected(c, pos, xor):
    raw = bytearray(pack_footer(c))
    raw[pos] ^= xor
    with pytest.raises(ArchiveError):
        parse_footer(bytes(raw))
    slot = bytearray(pack_slot(c))
    slot[pos] ^= xor
    assert parse_slot(bytes(slot)) is None


def test_footer_checksum_error_is_a_checksum_error():
    raw = bytearray(pack_footer(Commit(1, 160, 32, 0, 0)))
    raw[20] ^= 1
    with pytest.raises(ChecksumError):
        parse_footer(bytes(raw))


@given(st.binary(min_size=1, max_size=64), st.binary(max_size=64), st.integers(0, 2**32 - 1), st.integers(0, 2**40))
def test_frame_header_round_trip(key, summary, crc, n):
    fh = parse_frame_header(pack_frame_header(key, summary, crc, n))
    assert (fh.key_len, fh.summary_len, fh.payload_crc32, fh.payload_len) == (len(key), len(summary), crc, n)


@pytest.mark.parametrize("key", ["a", "scene-000001", "set_a/cam.0/take-2", "_x"])
def test_good_keys(key):
    assert check_key(key) == key.encode()


@pytest.mark.parametrize("key", ["", "../etc/passwd", "/abs", "a//b", "a/", ".hidden", "sp ace", "a\x00b",
                                 "x" * 1025, "é", 7])
def test_bad_keys(key):
    with pytest.raises(ArchiveError):
        check_key(key)
