"""Archive version 1.1: segmented indexes keep commits proportional to what changed; compaction.

Version 1.0 rewrites the whole index at every commit (1,000 single-scene commits: 247 MB
for 1.8 MB of scenes); in 1.1 a commit writes a segment of its keys plus the small ones it merges.
"""

import os
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from vt4dcodec.archive import ArchiveWriter, compact_archive, open_archive, repair_archive, verify_archive
from vt4dcodec.archive.layout import (FLAG_SEGMENTED, FOOTER_SIZE, HEADER_SIZE, MAX_SEGMENTS, crc32, pack_footer,
                                      parse_footer)
from vt4dcodec.archive.segments import FANOUT, plan_merge
from vt4dcodec.archive.verify import UncommittedTailError
from vt4dcodec.cli import main
from vt4dcodec.errors import ArchiveError, FormatError, Vt4dError

from .helpers import payload_for, scene_record


def _single_commits(path, n, size=2000, replace_every=0):
    with ArchiveWriter(path, "w", durable=False) as w:
        for i in range(n):
            key = f"k{(i % replace_every) if replace_every else i:05d}"
            w.append(key, payload_for(f"{key}/{i}", size), validate=False, replace=True)
            w.commit()


def test_single_scene_commits_grow_the_file_linearly(tmp_path):
    path = tmp_path / "a.vt4da"
    n, size = 600, 2000
    _single_commits(path, n, size)
    with open_archive(path) as ar:
        assert len(ar) == n and ar.commit.segmented
        one_index = ar.commit.index_length + sum(r.length for r in ar.index.refs[1:])
        segments = len(ar.index.segments)
    total = os.path.getsize(path)
    assert total <= 1.5 * n * size + one_index, (total, n * size)
    assert segments <= (FANOUT - 1) * 6  # at most FANOUT - 1 per size class


def test_every_version_reads_the_same_content(tmp_path):
    for version in ((1, 0), (1, 1)):
        path = tmp_path / f"v{version[1]}.vt4da"
        with ArchiveWriter(path, "w", durable=False, version=version) as w:
            for i in range(40):
                w.append(f"k{i % 13:03d}", payload_for(f"{i}", 100 + i), validate=False, replace=True)
                if i % 3 == 0:
                    w.commit()
        with open_archive(path) as ar:
            got = dict(ar.iter_records())
            assert ar.keys() == sorted(got) and len(ar) == 13 == len(list(ar.entries()))
            assert bool(ar.commit.flags & FLAG_SEGMENTED) == (version == (1, 1))
        want = {f"k{k:03d}": payload_for(f"{i}", 100 + i) for i in range(40) for k in [i % 13]}
        assert got == want
        verify_archive(path, containers=False)


def test_open_reads_header_footer_index_and_each_older_segment(tmp_path):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, durable=False) as w:
        for i in range(500):
            w.append(f"k{i:04d}", payload_for(f"{i}", 50), validate=False)
    with open_archive(path) as ar:
        assert ar.source.reads == 3 and len(ar.index.segments) == 1  # one bulk commit: one segment
    _single_commits(path, 7)
    with open_archive(path) as ar:
        assert ar.source.reads == 3 + len(ar.index.segments) - 1


def test_a_reopened_writer_continues_the_segments(tmp_path):
    path = tmp_path / "a.vt4da"
    for i in range(9):
        with ArchiveWriter(path, durable=False) as w:
            w.append(f"k{i}", payload_for(f"{i}", 30), validate=False)
            w.append("shared", payload_for(f"s{i}", 30), validate=False, replace=True)
    with open_archive(path) as ar:
        assert ar.read_bytes("shared") == payload_for("s8", 30) and len(ar) == 10
        assert len(ar.index.segments) < 9
    verify_archive(path, containers=False)


def test_version_1_0_archives_stay_1_0_when_appended(tmp_path):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, "w", durable=False, version=(1, 0)) as w:
        w.append("a", payload_for("a", 10), validate=False)
    with ArchiveWriter(path, durable=False) as w:
        w.append("b", payload_for("b", 10), validate=False)
    data = path.read_bytes()
    assert struct.unpack_from("<HHI", data, 8) == (1, 0, 0)
    assert parse_footer(data[-FOOTER_SIZE:]).flags == 0


def test_plan_merge_is_tiered():
    assert plan_merge([], 1) == 0
    assert plan_merge([1, 1, 1], 1) == 3
    assert plan_merge([1, 1, 4], 1) == 0
    assert plan_merge([1, 1, 1, 4, 4, 4], 1) == 6  # 4 ones -> 4, then four 4s -> 16
    assert plan_merge([10**6] * (MAX_SEGMENTS // 2), 1) == MAX_SEGMENTS // 2  # bounded count


# --- hostile manifests ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def segmented(tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("seg") / "a.vt4da"
    _single_commits(path, 6, 40)
    return path.read_bytes()


def _reindex(data: bytes, index: bytes) -> bytes:
    """Replace the last commit's index block (manifest + segment), footer CRCs fixed, slots cleared."""
    c = parse_footer(data[-FOOTER_SIZE:])
    from dataclasses import replace

    head = bytearray(data[: c.index_offset])
    head[32:HEADER_SIZE] = bytes(HEADER_SIZE - 32)
    new = replace(c, index_length=len(index), index_crc32=crc32(index))
    return bytes(head) + index + pack_footer(new)


def _manifest(data: bytes) -> tuple[bytearray, int]:
    c = parse_footer(data[-FOOTER_SIZE:])
    return bytearray(data[c.index_offset: c.footer_offset]), c.index_offset


@pytest.mark.parametrize("edit", ["count", "zero_segments", "ref0_moved", "overlap", "huge_n", "past_manifest"])
def test_hostile_manifests_raise_typed_errors(segmented, edit):
    index, _ = _manifest(segmented)
    m = struct.unpack_from("<I", index, 4)[0]
    assert m >= 2
    if edit == "count":
        struct.pack_into("<Q", index, 8, 99)
    elif edit == "zero_segments":
        struct.pack_into("<I", index, 4, 0)
    elif edit == "ref0_moved":
        struct.pack_into("<Q", index, 32, struct.unpack_from("<Q", index, 32)[0] + 1)
    elif edit == "overlap":  # reference 2 overlaps reference 1
        struct.pack_into("<Q", index, 96, struct.unpack_from("<Q", index, 64)[0] + 8)
    elif edit == "huge_n":
        struct.pack_into("<Q", index, 80, 2**40)
    else:
        struct.pack_into("<Q", index, 64, len(segmented))
    with pytest.raises(FormatError):  # ArchiveError, or LimitExceededError for the huge count
        with open_archive(_reindex(segmented, bytes(index))) as ar:
            dict(ar.iter_records())


@settings(suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.integers(0, 255)), min_size=1, max_size=8))
def test_mutated_segmented_archives_never_crash(segmented, edits):
    data = bytearray(segmented)
    for where, value in edits:
        data[int(where * len(data))] = value
    try:
        with open_archive(bytes(data)) as ar:
            for key, payload in ar.iter_records():
                assert isinstance(payload, bytes)
            len(ar), ar.keys()
    except Vt4dError:
        pass


# --- compaction ------------------------------------------------------------------------------------
def test_compact_reclaims_and_keeps_every_live_scene(tmp_path, capsys):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, "w", durable=False, version=(1, 0)) as w:  # 1.0: a whole index per commit
        for i in range(200):
            w.append(f"k{i % 50:03d}", payload_for(f"{i}", 300), validate=False, replace=True)
            w.commit()
    before = path.stat().st_size
    with open_archive(path) as ar:
        want = dict(ar.iter_records())
        old_generation = ar.generation
    held = open_archive(path)  # a reader that opened the old file keeps reading it
    assert main(["compact", str(path)]) == 0
    assert "50 scenes" in capsys.readouterr().out
    assert path.stat().st_size < before / 5
    with open_archive(path) as ar:
        assert dict(ar.iter_records()) == want and ar.generation == old_generation + 1
        assert ar.commit.segmented
    assert dict(held.iter_records()) == want
    held.close()
    verify_archive(path, containers=False)
    assert sorted(os.listdir(tmp_path)) == ["a.vt4da", "a.vt4da.lock"]
    compact_archive(path, version=(1, 0), durable=False)
    with open_archive(path) as ar:
        assert dict(ar.iter_records()) == want and not ar.commit.segmented


def test_compact_refuses_damage_and_leaves_the_original(tmp_path):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, "w", durable=False) as w:
        e = w.append("a", payload_for("a", 100), validate=False)
        w.append("b", payload_for("b", 100), validate=False)
    data = bytearray(path.read_bytes())
    data[e.offset + 3] ^= 1
    path.write_bytes(bytes(data))
    with pytest.raises(ArchiveError):
        compact_archive(path)
    assert path.read_bytes() == bytes(data)
    assert sorted(os.listdir(tmp_path)) == ["a.vt4da", "a.vt4da.lock"]
    w = ArchiveWriter(path, durable=False)
    w.append("c", payload_for("c", 10), validate=False)
    os.close(w._fd)
    w._fd = None
    w._lock.release()
    with pytest.raises(UncommittedTailError):
        compact_archive(path)


def test_repair_of_a_segmented_archive_with_a_damaged_older_segment(tmp_path):
    path = tmp_path / "a.vt4da"
    _single_commits(path, 7, 50)
    with open_archive(path) as ar:
        want = dict(ar.iter_records())
        older = ar.index.refs[1]
    data = bytearray(path.read_bytes())
    data[older.offset + 40] ^= 1
    path.write_bytes(bytes(data))
    with pytest.raises(ArchiveError):
        open_archive(path)
    report = repair_archive(str(path))
    assert report.complete
    with open_archive(path) as ar:
        assert dict(ar.iter_records()) == want
    verify_archive(path, containers=False)


def test_real_scenes_in_a_segmented_archive_verify(tmp_path):
    path = tmp_path / "a.vt4da"
    for i in range(5):
        with ArchiveWriter(path, durable=False) as w:
            w.append(f"s{i}", scene_record(i))
    verify_archive(path)
    with open_archive(path) as ar:
        assert ar.read_bytes("s3") == scene_record(3)


# --- prefix-coded summaries (1.1 segments) ---------------------------------------------------------
def test_prefix_coded_summaries_round_trip_and_shrink_the_index(tmp_path):
    from vt4dcodec.archive.examples import example_record
    from vt4dcodec.archive.records import summarize_payload

    rec = example_record(1, static_shape=(8, 4), dynamic_shape=(4, 4), frames=2)
    base = summarize_payload(rec)
    sizes = {}
    for version in ((1, 0), (1, 1)):
        path = tmp_path / f"v{version[1]}.vt4da"
        with ArchiveWriter(path, "w", durable=False, version=version) as w:
            for i in range(100):
                w.append(f"s{i:03d}", rec, summary={**base, "source_capture_id": f"cap-{i}"}, validate=False)
        with open_archive(path) as ar:
            sizes[version] = ar.commit.index_length
            assert [ar.summary(f"s{i:03d}")["source_capture_id"] for i in range(100)] == [f"cap-{i}" for i in range(100)]
            assert ar.summary("s050")["fingerprint"] == base["fingerprint"]
        verify_archive(path, containers=False)  # frame summary bytes == decoded index summary bytes
    assert sizes[(1, 1)] < sizes[(1, 0)] / 2.5


@pytest.mark.parametrize("edit", ["restart", "too_long", "flag_in_1_0", "reserved_without_flag"])
def test_hostile_summary_prefixes_are_rejected(tmp_path, edit):
    from vt4dcodec.archive.index import ENTRY_DTYPE, ArchiveIndex, IndexEntry

    entries = [IndexEntry(f"k{i:02d}", 192 + 100 * i, 10, 0, b"\x82\xa1a\xa8abcdefgh\xa1b" + bytes([0xa0 + 1]) + bytes([65 + i]))
               for i in range(20)]
    block = bytearray(ArchiveIndex.build(entries, prefix=True))
    table = np.frombuffer(block, ENTRY_DTYPE, 20, 32).copy()
    assert table["flags"][1] == 1 and table["flags"][0] == 0 and table["flags"][16] == 0
    if edit == "restart":
        table["flags"][16], table["reserved"][16] = 1, 1
    elif edit == "too_long":
        table["reserved"][1] = table["summary_len"][0] + 1
    elif edit == "reserved_without_flag":
        table["reserved"][0] = 3
    block[32: 32 + 48 * 20] = table.tobytes()
    with pytest.raises(ArchiveError):
        ArchiveIndex.parse_unchecked(bytes(block), 10_000, 20, prefix=edit != "flag_in_1_0")
