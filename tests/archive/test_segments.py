"""Archive version 1.1: segmented indexes keep commits proportional to what changed; compaction.

Version 1.0 rewrites the whole index at every commit (1,000 single-scene commits: 247 MB
for 1.8 MB of scenes); in 1.1 a commit writes a segment of its keys plus the small ones it merges.
"""

import os
import struct
from collections import Counter

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from vt4dcodec.archive import ArchiveWriter, compact_archive, open_archive, repair_archive, verify_archive
from vt4dcodec.archive.layout import (FLAG_SEGMENTED, FOOTER_SIZE, HEADER_SIZE, MAX_SEGMENTS, crc32, pack_footer,
                                      parse_footer)
from vt4dcodec.archive.segments import FANOUT, plan_merge, size_class
from vt4dcodec.archive.verify import UncommittedTailError
from vt4dcodec.cli import main
from vt4dcodec.errors import ArchiveError, FormatError, Vt4dError

from .helpers import payload_for, scene_record


V11 = (1, 1)  # this module tests version 1.1's segment merging; 1.2's light commits: test_light.py

def _single_commits(path, n, size=2000, replace_every=0):
    with ArchiveWriter(path, "w", durable=False, version=V11) as w:
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
    with ArchiveWriter(path, durable=False, version=V11) as w:
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
    assert plan_merge([], 1) == []
    assert plan_merge([1, 1, 1], 1) == [0, 1, 2]
    assert plan_merge([1, 1, 4], 1) == []
    assert plan_merge([1, 1, 1, 4, 4, 4], 1) == [0, 1, 2, 3, 4, 5]  # 4 ones -> 4, then four 4s -> 16
    assert plan_merge([3, 2, 1], 2) == [0, 1, 2]  # 1, 2 and 3 entries are one class: [4^0, 4^1)
    assert plan_merge([2, 9, 1, 3], 1) == [0, 2, 3]  # not only the newest: the 9 stays
    assert plan_merge([5, 2, 2, 2], 1, lambda chosen: 1) == [1, 2, 3]  # replaced keys: stays class 0
    assert plan_merge([10**6] * (MAX_SEGMENTS // 2), 1) == list(range(MAX_SEGMENTS // 2))  # bounded count
    assert plan_merge([1, 1, 1, 1, 40], 20) == [0, 1, 2, 3, 4]  # another writer's 4 of a class: fold all


def test_size_classes_are_powers_of_four():
    assert [size_class(c) for c in (0, 1, 2, 3, 4, 15, 16, 63, 64, 255, 256, 2**24)] == [0, 0, 0, 0, 1, 1, 2, 2, 3, 3, 4, 12]


def _simulate(commits: list[tuple[int, int]], rng_seed: int = 0) -> dict:
    """The reference writer's merging (``ArchiveWriter._write_commit``) over key sets: each commit adds
    ``new`` keys and replaces up to ``replace`` live ones.  Returns the worst per-class and total
    segment counts seen after any commit, the entries written (the index bytes, in entries) and the
    entries committed."""
    import random

    rng = random.Random(rng_seed)
    segments: list[set[int]] = []
    live: list[int] = []
    written = committed = worst_class = worst_total = 0
    for new, replace in commits:
        pending = set(range(len(live), len(live) + new)) | set(rng.sample(live, min(replace, len(live))))
        if not pending:
            continue
        keys, folded = set(pending), set()

        def merged_count(chosen):
            for i in chosen:
                if i not in folded:
                    keys.update(segments[i])
                    folded.add(i)
            return len(keys)

        merge = set(plan_merge([len(s) for s in segments], len(pending), merged_count))
        merged_count(sorted(merge))
        segments = [keys] + [s for i, s in enumerate(segments) if i not in merge]
        live.extend(range(len(live), len(live) + new))
        written += len(keys)
        committed += len(pending)
        per_class = Counter(size_class(len(s)) for s in segments)
        worst_class = max(worst_class, max(per_class.values()))
        worst_total = max(worst_total, len(segments))
    return {"worst_per_class": worst_class, "worst_segments": worst_total, "written": written,
            "committed": committed, "scenes": len(live), "segments": len(segments)}


def _levels(n: int) -> int:
    return size_class(n) + 1  # size classes an entry count up to n can be in


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 40) | st.integers(1, 3), st.integers(0, 4) | st.just(0)),
                min_size=1, max_size=400), st.integers(0, 2**16))
def test_any_sequence_of_commit_sizes_keeps_the_index_bounded(commits, seed):
    r = _simulate(commits, seed)
    assert r["worst_per_class"] <= FANOUT - 1  # FORMAT.md II 5.5: at most 3 segments per size class
    assert r["worst_segments"] <= (FANOUT - 1) * _levels(r["scenes"])  # so open reads are O(log n)
    # index bytes: every committed entry is rewritten at most once per size class above its own
    assert r["written"] <= r["committed"] * _levels(r["committed"])


@pytest.mark.parametrize("name, commits, max_segments", [
    ("1 or 2 scenes at random", [(1 + (i * 7919 % 13 > 6), 0) for i in range(10_000)], 20),
    ("single scenes", [(1, 0)] * 2_000, 20),
    ("1, 2, 3, 1, 2, 3, ...", [(i % 3 + 1, 0) for i in range(3_000)], 20),
    ("replacing while adding", [(i % 2, 2) for i in range(5_000)], 20),
])
def test_long_commit_sequences_stay_within_the_bounds(name, commits, max_segments):
    r = _simulate(commits)
    assert r["worst_per_class"] <= FANOUT - 1
    assert r["segments"] <= max_segments and r["worst_segments"] <= (FANOUT - 1) * _levels(r["scenes"])
    assert r["written"] <= r["committed"] * _levels(r["committed"])


def test_mixed_commit_sizes_merge_in_a_real_archive(tmp_path):
    """The issue-52 reproducer: 24 commits of 1, 2, 3, 1, 2, 3, ... scenes left 24 segments."""
    path = tmp_path / "a.vt4da"
    n = 0
    with ArchiveWriter(path, "w", durable=False, version=V11) as w:
        for c in range(24):
            for _ in range(c % 3 + 1):
                w.append(f"k{n:04d}", payload_for(f"{n}", 20), validate=False)
                n += 1
            w.commit()
    with open_archive(path) as ar:
        classes = Counter(size_class(r.count) for r in ar.index.refs)
        assert len(ar) == 48 and max(classes.values()) <= FANOUT - 1 and len(ar.index.refs) <= 6
        assert ar.source.reads == 3 + len(ar.index.refs) - 1


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.tuples(st.integers(0, 6), st.integers(0, 3)), min_size=1, max_size=30))
def test_real_writer_keeps_the_bounds_for_any_commit_sizes(tmp_path_factory, commits):
    path = tmp_path_factory.mktemp("prop") / "a.vt4da"
    want: dict[str, bytes] = {}
    index_bytes = entries = n = 0
    with ArchiveWriter(path, "w", durable=False, version=V11) as w:
        for c, (new, replace) in enumerate(commits):
            keys = [f"k{n + i:04d}" for i in range(new)] + sorted(want)[:replace]
            n += new
            for key in keys:
                want[key] = payload_for(f"{key}/{c}", 10)
                w.append(key, want[key], validate=False, replace=True)
            if keys:
                w.commit()
                index_bytes += w._commit.index_length
                entries += len(set(keys))
                assert max(Counter(size_class(r.count) for r, _ in w._segments).values()) <= FANOUT - 1
    with open_archive(path) as ar:
        m = len(ar.index.refs) if ar.commit.segmented else 1
        assert ar.source.reads == 3 + m - 1  # header, footer, index block, each older segment
        assert m <= (FANOUT - 1) * _levels(len(want))
        assert dict(ar.iter_records()) == want
    per_entry = 48 + 5 + 65  # entry + key + the widest summary payload_for records get
    per_commit = 32 + 32 * (FANOUT - 1) * _levels(len(want)) + 32  # manifest + segment header
    assert index_bytes <= len(commits) * per_commit + per_entry * entries * _levels(max(entries, 1))


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


@pytest.mark.parametrize("edit", ["count", "zero_segments", "ref0_moved", "overlap", "huge_n", "past_manifest",
                                  "ref1_count", "ref2_count"])
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
    elif edit.endswith("_count"):  # II 5.5: a reference's entry count MUST equal its segment's count
        at = 32 + 32 * int(edit[3]) + 16
        struct.pack_into("<Q", index, at, struct.unpack_from("<Q", index, at)[0] - 1)  # lengths still fit
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
    assert sorted(os.listdir(tmp_path)) == ["a.vt4da"]  # no lock file left (issue 51.4)
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
    assert sorted(os.listdir(tmp_path)) == ["a.vt4da"]  # no lock file left (issue 51.4)
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
