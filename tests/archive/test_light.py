"""Archive version 1.2: light commits (a journal and a footer instead of an index), compressed index
segments, records without summaries (FORMAT.md Part II 5.3, 5.6, 5.7)."""

import os
import struct
from collections import Counter

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vt4dcodec.archive import ArchiveWriter, compact_archive, open_archive, repair_archive, verify_archive
from vt4dcodec.archive.examples import example_scene
from vt4dcodec.archive.layout import FLAG_V12, FOOTER_SIZE, HEADER_SIZE, MAX_TAIL_BYTES, parse_footer
from vt4dcodec.archive.segments import FANOUT, MAX_COMPRESSION, compress_segment, size_class
from vt4dcodec.format import dumps

from .helpers import payload_for


def _small_scene(seed: int) -> bytes:
    """A ~400-byte scene: issue 52's small-scene growth workload."""
    return dumps(example_scene(seed, static_shape=(4, 8), dynamic_shape=(2, 8), frames=1, encoding="int4-rans"))


def test_single_commits_of_small_scenes_stay_under_1_5x_their_payload(tmp_path):
    path = tmp_path / "a.vt4da"
    payload = 0
    with ArchiveWriter(path, "w", durable=False) as w:
        for i in range(600):
            rec = _small_scene(i % 16)
            w.append(f"scene-{i:07d}", rec)
            payload += len(rec)
            w.commit()
    assert 380 < payload / 600 < 450
    ratio = os.path.getsize(path) / payload
    assert ratio <= 1.45, ratio  # 1.1 wrote 2.96x; the budget is 1.5x
    with open_archive(path) as ar:
        assert len(ar) == 600 and ar.commit.flags & FLAG_V12
        assert ar.source.reads == 3 + max(len(ar.index.refs) - 1, 0)
        assert ar.summary("scene-0000005")["frames"] == 1  # read from the record: it stores no summary
        assert not ar.entry("scene-0000005").has_summary
    verify_archive(path)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.tuples(st.integers(0, 20), st.integers(0, 3), st.sampled_from([10, 3000, 40000])),
                min_size=1, max_size=25))
def test_light_and_full_commits_read_back_exactly_with_bounded_opens(tmp_path_factory, commits):
    path = tmp_path_factory.mktemp("light") / "a.vt4da"
    want: dict[str, bytes] = {}
    n = light = 0
    with ArchiveWriter(path, "w", durable=False) as w:
        for c, (new, replace, size) in enumerate(commits):
            keys = [f"k{n + i:04d}" for i in range(new)] + sorted(want)[:replace]
            n += new
            for key in keys:
                want[key] = payload_for(f"{key}/{c}", size)
                w.append(key, want[key], validate=False, replace=True)
            if keys:
                w.commit()
                light += w._commit.light
                assert w._commit.tail_length <= MAX_TAIL_BYTES
                assert max(Counter(size_class(r.count) for r, _ in w._segments).values(), default=0) <= FANOUT - 1
    with open_archive(path) as ar:
        assert ar.source.reads == 3 + max(len(ar.index.refs) - 1, 0)  # the tail comes with the index block
        assert dict(ar.iter_records()) == want
        tail = ar.commit.tail_length
    verify_archive(path, containers=False)
    if tail:  # the next writer goes on from the tail it finds
        with ArchiveWriter(path, durable=False) as w:
            w.append("zz-last", b"x", validate=False)
        with open_archive(path) as ar:
            assert ar.read_bytes("zz-last") == b"x" and len(ar) == len(want) + 1


def test_a_pack_writes_an_index_and_later_small_commits_are_light(tmp_path):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, "w", durable=False) as w:
        for i in range(40):
            w.append(f"k{i:03d}", payload_for(str(i), 200), validate=False)
    with open_archive(path) as ar:
        assert not ar.commit.light and ar.index.refs[0].compressed  # 40 records: a full commit
    for i in range(3):
        with ArchiveWriter(path, durable=False) as w:
            w.append(f"n{i}", payload_for(f"n{i}", 200), validate=False)
    with open_archive(path) as ar:
        assert ar.commit.light and len(ar) == 43 and ar.generation == 4
        assert ar.read_bytes("n1") == payload_for("n1", 200)


def test_a_1_1_archive_stays_1_1_when_appended_to(tmp_path):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, "w", durable=False, version=(1, 1)) as w:
        w.append("a", payload_for("a", 100), validate=False)
    with ArchiveWriter(path, durable=False) as w:  # the default writer keeps the archive's version
        w.append("b", payload_for("b", 100), validate=False)
    data = path.read_bytes()
    assert struct.unpack_from("<HI", data, 10) == (1, 1)
    c = parse_footer(data[-FOOTER_SIZE:])
    assert not c.light and not c.flags & FLAG_V12


def test_a_damaged_frame_header_in_the_tail_is_recovered_from_its_journal(tmp_path):
    """A light commit's records are known to its tail frames and its journal: with the frame header of one
    damaged, a repair finds the payload by the journal's offset, length and CRC and loses nothing."""
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, "w", durable=False) as w:
        w.append("a", payload_for("a", 300), validate=False)
        w.append("b", payload_for("b", 300), validate=False)
    with open_archive(path) as ar:
        assert ar.commit.light
        frame = ar.entry("a").frame_offset
    data = bytearray(path.read_bytes())
    data[frame + 1] ^= 0x40  # the frame magic: neither the tail nor a walk can parse it
    path.write_bytes(bytes(data))
    with pytest.raises(Exception):
        open_archive(path)
    report = repair_archive(str(path))
    assert report.complete and report.copied == ["a"] and not report.lost
    with open_archive(path) as ar:
        assert dict(ar.iter_records()) == {"a": payload_for("a", 300), "b": payload_for("b", 300)}


def test_a_damaged_journal_never_serves_an_older_version(tmp_path):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, "w", durable=False) as w:
        w.append("k", payload_for("v1", 300), validate=False)
    with ArchiveWriter(path, durable=False) as w:
        w.append("k", payload_for("v2", 300), validate=False, replace=True)
    data = bytearray(path.read_bytes())
    journal = bytes(data).rfind(b"V4AJ")
    data[journal + 20] ^= 0x01  # the newest journal's CRC fails
    path.write_bytes(bytes(data))
    repair_archive(str(path))
    with open_archive(path) as ar:
        assert ar.read_bytes("k") == payload_for("v2", 300)  # the frame verifies: the newest version


def test_compaction_to_1_1_stores_the_summaries_1_2_left_to_the_records(tmp_path):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, "w", durable=False) as w:
        w.append("s", _small_scene(1))
    with open_archive(path) as ar:
        assert not ar.entry("s").has_summary
        summary = ar.summary("s")
    compact_archive(path, version=(1, 1), durable=False)
    with open_archive(path) as ar:
        assert ar.entry("s").has_summary and ar.entry("s").summary == summary
    compact_archive(path, durable=False)
    with open_archive(path) as ar:
        assert ar.summary("s") == summary and len(ar) == 1


def test_segments_compress_only_within_the_ratio_readers_accept():
    block = bytes(32) + bytes(48 * 4000)  # zeros compress far beyond 64x: stored as they are
    assert compress_segment(block) == (block, 0)
    stored, flags = compress_segment(os.urandom(1600) * 4)  # ~4x: compressed
    assert flags == 1 and stored[:4] == b"V4AZ" and struct.unpack_from("<Q", stored, 8)[0] <= MAX_COMPRESSION * (
        len(stored) - 32)


def test_the_tail_bound_turns_a_long_run_of_light_commits_into_a_full_one(tmp_path):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, "w", durable=False) as w:
        for i in range(12):
            w.append(f"k{i:02d}", payload_for(str(i), 30000), validate=False)
            w.commit()
            assert w._commit.tail_length <= MAX_TAIL_BYTES
            assert w._commit.light == (i not in (8,))  # the 9th would pass 256 KiB: a full commit
    assert HEADER_SIZE < os.path.getsize(path)
