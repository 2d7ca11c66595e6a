#!/usr/bin/env python
"""Deterministic generator of the archive golden vectors in ``spec/vectors/archive/``.

    python spec/make_archive_vectors.py [OUTDIR]

Writes ``*.vt4da`` files and ``expected.json``: for each valid vector the committed generation and
the SHA-256 of every record's payload (what a reader must return), the keys a repair recovers,
and for each invalid vector the error class ``verify_archive`` must raise.  Running it twice gives identical
bytes (records are ``vt4dcodec.archive.examples`` scenes with fixed timestamps; writes are
deterministic); ``tests/archive/test_vectors.py`` checks the committed files against a fresh run.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
import sys
import tempfile

import numpy as np

from vt4dcodec.archive import ArchiveWriter, open_archive
from vt4dcodec.archive.examples import example_record
from vt4dcodec.archive.index import ENTRY_DTYPE
from vt4dcodec.archive.layout import FOOTER_SIZE, HEADER_SIZE, INDEX_HEADER_SIZE, Commit, crc32, pack_footer, parse_footer

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_OUT = os.path.join(HERE, "vectors", "archive")


def _record(seed: int) -> bytes:
    return example_record(seed, static_shape=(8, 4), dynamic_shape=(4, 4), frames=2)


def _write(tmp: str, name: str, steps, version=(1, 0), record=None) -> bytes:
    """Build an archive by ``steps``: a list of commits, each a list of (key, seed, replace).

    The vectors of version 1.0 are kept byte for byte forever, so they are written as 1.0."""
    path = os.path.join(tmp, name)
    w = ArchiveWriter(path, "w", durable=False, version=version)
    for batch in steps:
        for key, seed, replace in batch:
            w.append(key, (record or _record)(seed), replace=replace)
        w.commit()
    w.close()
    with open(path, "rb") as f:
        return f.read()


def _crashed(tmp: str) -> bytes:
    """One commit, then a complete uncommitted record, then a torn one (a writer killed mid-append)."""
    path = os.path.join(tmp, "crashed.vt4da")
    w = ArchiveWriter(path, "w", durable=False, version=(1, 0))
    w.append("committed", _record(10))
    w.commit()
    w.append("complete-after-commit", _record(11))
    torn = w.append("torn", _record(12))
    os.truncate(path, torn.offset + torn.length // 2)
    os.close(w._fd)  # abandon like a killed process (no abort, no commit)
    w._fd = None
    w._lock.release()
    with open(path, "rb") as f:
        return f.read()


def _reindex(data: bytes, index: bytes, count: int | None = None) -> bytes:
    """Replace the last commit's index, with a footer whose CRC matches, and empty header slots."""
    c = parse_footer(data[-FOOTER_SIZE:])
    new = Commit(c.generation + 1, c.index_offset, len(index), crc32(index),
                 c.scene_count if count is None else count)
    head = bytearray(data[: c.index_offset])
    head[32:HEADER_SIZE] = bytes(HEADER_SIZE - 32)
    return bytes(head) + index + pack_footer(new)


def _index_parts(data: bytes) -> tuple[bytes, np.ndarray, bytes]:
    c = parse_footer(data[-FOOTER_SIZE:])
    index = data[c.index_offset: c.footer_offset]
    n = struct.unpack_from("<Q", index, 8)[0]
    table = np.frombuffer(index, ENTRY_DTYPE, n, INDEX_HEADER_SIZE).copy()
    return index[:INDEX_HEADER_SIZE], table, index[INDEX_HEADER_SIZE + 48 * n:]


def _invalid(base: bytes) -> dict[str, tuple[bytes, str]]:
    c = parse_footer(base[-FOOTER_SIZE:])
    out = {}
    bad = bytearray(base)
    bad[-8] ^= 0xFF
    bad[40] ^= 0xFF
    bad[104] ^= 0xFF
    out["no_commit"] = (bytes(bad), "NoCommitError")
    bad = bytearray(base)
    bad[c.index_offset + 50] ^= 0x01
    out["index_checksum"] = (bytes(bad), "IndexChecksumError")
    out["bad_magic"] = (b"\x89PNG" + base[4:], "BadMagicError")
    out["truncated"] = (base[:200], "TruncatedError")
    head, t, blobs = _index_parts(base)
    t[1]["payload_offset"] = t[0]["payload_offset"] + 3
    out["overlapping_records"] = (_reindex(base, head + t.tobytes() + blobs), "OverlappingRecordsError")
    head, t, blobs = _index_parts(base)
    t[0]["payload_offset"] = 2**62
    out["offset_past_end"] = (_reindex(base, head + t.tobytes() + blobs), "ArchiveError")
    head, t, blobs = _index_parts(base)
    keys_len = struct.unpack_from("<Q", head, 16)[0]
    first = blobs[: int(t[0]["key_len"])]  # make key #1 a copy of key #0
    dup_keys = first + first + blobs[int(t[0]["key_len"]) + int(t[1]["key_len"]): keys_len]
    t[1]["key_len"] = t[0]["key_len"]
    t["key_offset"] = np.concatenate([[0], np.cumsum(t["key_len"].astype(np.int64))[:-1]])
    new_head = head[:16] + struct.pack("<Q", len(dup_keys)) + head[24:]
    out["duplicate_keys"] = (_reindex(base, new_head + t.tobytes() + dup_keys + blobs[keys_len:]),
                             "DuplicateKeyError")
    huge = bytearray(head)
    huge[8:16] = struct.pack("<Q", 2**40)
    out["huge_count"] = (_reindex(base, bytes(huge) + t.tobytes() + blobs, count=len(t)), "LimitExceededError")
    return out


def _segmented_invalid(seg: bytes) -> dict[str, tuple[bytes, str]]:
    """Rejections added with version 1.1 (issue 15): each a minimal change of a valid archive."""
    out = {}
    bad = bytearray(seg)
    struct.pack_into("<H", bad, 8, 2)  # preamble major 2 behind a valid tail footer
    out["preamble_major"] = (bytes(bad), "UnsupportedVersionError")
    bad = bytearray(seg)
    struct.pack_into("<I", bad, 12, 0x4)  # an unknown required flag in the preamble
    out["preamble_flags"] = (bytes(bad), "UnsupportedVersionError")
    # truncated: 10 bytes cut off; a valid header slot names the lost commit
    out["truncated_commit"] = (seg[:-10], "ArchiveTruncatedError")
    c = parse_footer(seg[-FOOTER_SIZE:])
    index = seg[c.index_offset: c.footer_offset]
    older = struct.unpack_from("<Q", index, 64)[0]  # reference 1: an older segment
    bad = bytearray(seg)
    bad[older + 40] ^= 0x01
    out["segment_checksum"] = (bytes(bad), "IndexChecksumError")
    return out


def _small_record(seed: int) -> bytes:
    return example_record(seed, static_shape=(2, 4), dynamic_shape=(1, 4), frames=1)


def _light(tmp: str) -> bytes:
    """Version 1.2: two full commits of 17 scenes (a manifest naming two compressed segments), then three
    light commits (one replaces a key already replaced in the tail); records under 4 KiB store no summary."""
    full = [[(f"scene-{i:02d}", i, False) for i in range(first, first + 17)] for first in (0, 17)]
    light = [[("scene-40", 40, False), ("scene-03", 41, True)], [("scene-03", 42, True)], [("scene-41", 43, False)]]
    return _write(tmp, "light.vt4da", full + light, version=(1, 2), record=_small_record)


def _refooter(data: bytes, **fields) -> bytes:
    """The same bytes with the tail footer's fields changed (its CRC made valid again)."""
    from dataclasses import replace
    c = replace(parse_footer(data[-FOOTER_SIZE:]), **fields)
    return data[:-FOOTER_SIZE] + pack_footer(c)


def _light_invalid(light: bytes) -> dict[str, tuple[bytes, str]]:
    """Rejections added with version 1.2, each one defect of ``light.vt4da`` (FORMAT.md Part II 5.6, 5.7)."""
    from vt4dcodec.archive.segments import parse_journal
    c = parse_footer(light[-FOOTER_SIZE:])
    tail_start = c.index_offset + c.index_length
    last_frame = light.rfind(b"V4AR")  # the last light commit's frame (scene-41)
    journal = light.rfind(b"V4AJ")  # its journal, right before the footer
    out = {}
    bad = bytearray(light)
    bad[last_frame + 12] ^= 0x01  # the frame's payload CRC field: its meta CRC fails
    out["light_tail_checksum"] = (bytes(bad), "IndexChecksumError")
    out["light_tail_too_long"] = (_refooter(light, tail_length=(1 << 18) + 1), "LimitExceededError")
    bad = bytearray(light)
    bad[last_frame:last_frame + 4] = b"V4AX"
    out["light_tail_garbage"] = (bytes(bad), "ArchiveError")
    bad = bytearray(light)  # the journal's payload length of its one entry, its CRC made valid again
    end = c.footer_offset
    parse_journal(light[journal:end])
    struct.pack_into("<Q", bad, end - 16, struct.unpack_from("<Q", light, end - 16)[0] + 1)
    struct.pack_into("<I", bad, end - 4, crc32(bytes(bad[journal:end - 4])))
    out["light_journal_mismatch"] = (bytes(bad), "ArchiveError")
    out["light_count"] = (_refooter(light, scene_count=c.scene_count + 1), "ArchiveError")
    assert tail_start > c.index_offset
    # the manifest's older segment (reference 1), a V4AZ block: its raw length R changed, the reference's CRC,
    # the index CRC and the tail footer made valid again, so only the 5.6 check is left to fail
    ref1 = c.index_offset + 32 + 32
    seg_off, seg_len = struct.unpack_from("<QQ", light, ref1)
    assert light[seg_off:seg_off + 4] == b"V4AZ"
    z = struct.unpack_from("<Q", light, seg_off + 16)[0]
    r = struct.unpack_from("<Q", light, seg_off + 8)[0]
    for name, new_r, error in (("compressed_ratio", 64 * z + 1, "LimitExceededError"),
                               ("compressed_size_mismatch", r + 1, "ArchiveError")):
        bad = bytearray(light)
        struct.pack_into("<Q", bad, seg_off + 8, new_r)
        struct.pack_into("<I", bad, ref1 + 24, crc32(bytes(bad[seg_off:seg_off + seg_len])))
        out[name] = (_refooter(bytes(bad), index_crc32=crc32(bytes(bad[c.index_offset:tail_start]))), error)
    return out


def _tail_footer_only(data: bytes) -> bytes:
    """A valid archive whose header slots are both empty: readers find the commit at the tail."""
    out = bytearray(data)
    out[32:HEADER_SIZE] = bytes(HEADER_SIZE - 32)
    return bytes(out)


def build() -> dict[str, bytes | dict]:
    """All vectors as {file name: bytes} plus the 'expected.json' manifest (a dict)."""
    files: dict[str, bytes] = {}
    expected: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        files["empty.vt4da"] = _write(tmp, "empty.vt4da", [])
        files["two_commits.vt4da"] = _write(tmp, "two.vt4da", [
            [("scene-a", 1, False), ("scene-b", 2, False), ("dir/scene-c", 3, False)],
            [("scene-b", 4, True), ("scene-d", 5, False)],
        ])
        files["crashed.vt4da"] = _crashed(tmp)
        # version 1.1: six single-scene commits (one a replace) -> a manifest naming merged segments
        files["segmented.vt4da"] = _write(tmp, "seg.vt4da", [
            [("scene-a", 1, False)], [("scene-b", 2, False)], [("dir/scene-c", 3, False)],
            [("scene-b", 4, True)], [("scene-d", 5, False)], [("scene-e", 6, False)],
        ], version=(1, 1))
        files["light.vt4da"] = _light(tmp)
    files["tail_footer_only.vt4da"] = _tail_footer_only(files["two_commits.vt4da"])
    for name, data in list(files.items()):
        with open_archive(data) as ar:
            expected[name] = {
                "valid": True, "generation": ar.generation, "uncommitted_bytes": ar.uncommitted_bytes,
                "records": {k: hashlib.sha256(v).hexdigest() for k, v in ar.iter_records()},
            }
    expected["crashed.vt4da"]["repair_recovers"] = ["complete-after-commit"]
    invalid = (_invalid(files["two_commits.vt4da"]) | _segmented_invalid(files["segmented.vt4da"])
               | _light_invalid(files["light.vt4da"]))
    for stem, (data, error) in invalid.items():
        files[f"invalid_{stem}.vt4da"] = data
        expected[f"invalid_{stem}.vt4da"] = {"valid": False, "error": error}
    return {**files, "expected.json": expected}


def main(out: str = DEFAULT_OUT) -> None:
    os.makedirs(out, exist_ok=True)
    vectors = build()
    for name, content in vectors.items():
        data = (json.dumps(content, indent=1, sort_keys=True) + "\n").encode() if name.endswith(".json") else content
        with open(os.path.join(out, name), "wb") as f:
            f.write(data)
    print(f"wrote {len(vectors)} files to {out}")


if __name__ == "__main__":
    main(*sys.argv[1:2])
