"""Repair never loses a committed scene that still verifies; truncation is never served silently.

Regression tests for the damage an independent review found (each builds the reproducing file), and a property test: over random
damage, ``repair`` never reduces the set of committed scenes whose record is still intact.
"""

import dataclasses
import os
import struct

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from vt4dcodec.archive import ArchiveWriter, open_archive, repair_archive, verify_archive
from vt4dcodec.archive.layout import FOOTER_SIZE, HEADER_SIZE, SLOT_OFFSETS, SLOT_SIZE, pack_footer, pack_slot, parse_footer
from vt4dcodec.archive.reader import ArchiveTruncatedError
from vt4dcodec.archive.recovery import ArchiveNotFoundError
from vt4dcodec.cli import main
from vt4dcodec.errors import ArchiveError, LimitExceededError, UnsupportedVersionError, Vt4dError

from .helpers import payload_for, scene_record


def _three_scenes(path) -> None:
    with ArchiveWriter(path, durable=False) as w:
        for i in range(3):
            w.append(f"scene-{i}", scene_record(i))


def _flip(path, offset: int, bit: int = 0) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 1 << bit
    path.write_bytes(bytes(data))


def _readable(path) -> dict[str, bytes]:
    """Keys whose record reads back CRC-clean from the archive's last commit."""
    out = {}
    with open_archive(path) as ar:
        for e in ar.entries():
            try:
                out[e.key] = ar.read_entry(e)
            except ArchiveError:
                pass
    return out


# --- defect 1: repair --full-scan destroyed intact scenes ---------------------------------------
def test_full_scan_repair_keeps_intact_scenes_after_a_flipped_payload_bit(tmp_path, capsys):
    path = tmp_path / "a.vt4da"
    _three_scenes(path)
    with open_archive(path) as ar:
        first = min(ar.entries(), key=lambda e: e.offset)
    _flip(path, first.offset + first.length // 2)
    size = path.stat().st_size
    rc = main(["repair", "--full-scan", str(path)])
    out = capsys.readouterr()
    assert rc != 0  # one committed scene could not be recovered: not reported as success
    assert first.key in out.out + out.err and "could not be recovered" in out.out + out.err
    assert path.stat().st_size >= size  # nothing verifiable was cut
    assert _readable(path) == {f"scene-{i}": scene_record(i) for i in range(3) if f"scene-{i}" != first.key}
    verify_archive(path)


def test_full_scan_prefers_the_newest_commit_over_superseded_records(tmp_path):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, durable=False) as w:
        w.append("k", payload_for("old", 300), validate=False)
        w.append("a", payload_for("a", 300), validate=False)
        w.commit()
        w.append("k", payload_for("new", 300), validate=False, replace=True)
        w.commit()
        w.append("z", payload_for("z", 300), validate=False)
    with open_archive(path) as ar:
        a = ar.entry("a")
    _flip(path, a.frame_offset + 1)  # the frame magic of "a": a strict scan stopped here
    report = repair_archive(str(path), full_scan=True)
    got = _readable(path)
    assert got == {"k": payload_for("new", 300), "a": payload_for("a", 300), "z": payload_for("z", 300)}
    assert report.copied == ["a"] and report.unrecoverable == [] and report.complete
    verify_archive(path, containers=False)  # "a" was re-framed: its frame and the index agree again


def test_repair_dry_run_changes_nothing_and_reports_the_plan(tmp_path, capsys):
    path = tmp_path / "a.vt4da"
    _three_scenes(path)
    with open_archive(path) as ar:
        e = ar.entry("scene-1")
    _flip(path, e.offset + 5)
    before = path.read_bytes()
    assert main(["repair", "--full-scan", "--dry-run", str(path)]) != 0
    out = capsys.readouterr()
    assert "would" in out.out and "scene-1" in out.err
    assert path.read_bytes() == before


def test_repair_skips_damage_between_uncommitted_records(tmp_path):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, durable=False) as w:
        w.append("c", payload_for("c", 100), validate=False)
    w = ArchiveWriter(path, durable=False)
    e1 = w.append("u1", payload_for("u1", 500), validate=False)
    w.append("u2", payload_for("u2", 500), validate=False)
    os.close(w._fd)  # killed: no commit, no abort
    w._fd = None
    w._lock.release()
    _flip(path, e1.offset + 7)
    report = repair_archive(str(path))
    assert report.recovered == ["u2"]  # a strict walk stopped at u1 and cut u2 off
    assert _readable(path) == {"c": payload_for("c", 100), "u2": payload_for("u2", 500)}
    verify_archive(path, containers=False)


# --- defect 2: a truncated archive silently opened as an older one --------------------------------
def _two_commits(path) -> None:
    with ArchiveWriter(path, durable=False) as w:
        w.append("k", payload_for("v1", 200), validate=False)
        w.commit()
        w.append("k", payload_for("v2", 200), validate=False, replace=True)
        w.append("m", payload_for("m", 200), validate=False)


@pytest.mark.parametrize("cut", [10, FOOTER_SIZE])
def test_truncated_archive_raises_naming_the_lost_commit(tmp_path, capsys, cut):
    path = tmp_path / "a.vt4da"
    _two_commits(path)
    os.truncate(path, path.stat().st_size - cut)
    with pytest.raises(ArchiveTruncatedError, match="generation 2") as info:
        open_archive(path)
    assert info.value.lost.generation == 2 and info.value.fallback.generation == 1
    assert main(["ls", str(path)]) != 0
    assert "--allow-truncated" in capsys.readouterr().err
    with open_archive(path, allow_truncated=True) as ar:  # knowingly: the old state
        assert ar.generation == 1 and ar.read_bytes("k") == payload_for("v1", 200)
    assert main(["ls", "--allow-truncated", str(path)]) == 0
    with pytest.raises(ArchiveTruncatedError):
        ArchiveWriter(path, durable=False)  # a writer must not silently build on the older state


def test_truncated_exactly_at_an_older_footer_is_detected(tmp_path):
    path = tmp_path / "a.vt4da"
    _two_commits(path)
    with open_archive(path) as ar:
        assert ar.generation == 2
    data = path.read_bytes()
    pos = data.index(b"V4AFOOT\x00", HEADER_SIZE + 64 + FOOTER_SIZE)  # generation 1's footer
    os.truncate(path, pos + FOOTER_SIZE)
    with pytest.raises(ArchiveTruncatedError):
        open_archive(path)


def test_repair_of_a_truncated_archive_recovers_its_records(tmp_path, capsys):
    path = tmp_path / "a.vt4da"
    _two_commits(path)
    os.truncate(path, path.stat().st_size - 10)
    assert main(["repair", str(path)]) == 0
    assert "generation 2" in capsys.readouterr().out
    with open_archive(path) as ar:
        assert ar.generation == 3
        assert ar.read_bytes("k") == payload_for("v2", 200) and ar.read_bytes("m") == payload_for("m", 200)
    verify_archive(path, containers=False)


# --- defect 4: generation 2^64 - 1 ------------------------------------------------------------------
def test_exhausted_generation_counter_is_a_typed_error(tmp_path, capsys):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, durable=False) as w:
        w.append("k", payload_for("k", 50), validate=False)
    data = bytearray(path.read_bytes())
    top = dataclasses.replace(parse_footer(bytes(data[-FOOTER_SIZE:])), generation=2**64 - 1)
    data[-FOOTER_SIZE:] = pack_footer(top)
    data[SLOT_OFFSETS[1]: SLOT_OFFSETS[1] + SLOT_SIZE] = pack_slot(top)
    path.write_bytes(bytes(data))
    with open_archive(path) as ar:
        assert ar.generation == 2**64 - 1
    with pytest.raises(LimitExceededError, match="generation"):
        ArchiveWriter(path, durable=False)
    src = tmp_path / "s.vt4d"
    src.write_bytes(scene_record(1))
    assert main(["pack", "--append", str(src), "-o", str(path)]) != 0
    assert "generation" in capsys.readouterr().err


# --- defect 5: the preamble is checked even when the tail footer is valid -----------------------
@pytest.mark.parametrize("field,value", [(8, 2), (12, 4)])
def test_open_rejects_a_bad_preamble_behind_a_valid_footer(tmp_path, field, value):
    path = tmp_path / "a.vt4da"
    _three_scenes(path)
    data = bytearray(path.read_bytes())
    struct.pack_into("<H" if field == 8 else "<I", data, field, value)
    path.write_bytes(bytes(data))
    with pytest.raises(UnsupportedVersionError):
        open_archive(path)
    with pytest.raises(UnsupportedVersionError):
        verify_archive(path)


# --- defect 6: repair of a wrong path ----------------------------------------------------------------
def test_repair_of_a_missing_path_creates_nothing(tmp_path, capsys):
    path = tmp_path / "typo.vt4da"
    with pytest.raises(ArchiveNotFoundError):
        repair_archive(str(path))
    assert main(["repair", str(path)]) != 0
    assert "no such archive" in capsys.readouterr().err
    assert os.listdir(tmp_path) == []


def test_repair_of_a_scene_file_leaves_no_lock(tmp_path):
    path = tmp_path / "s.vt4d"
    path.write_bytes(scene_record(0))
    with pytest.raises(ArchiveError, match="single-scene"):
        repair_archive(str(path))
    assert os.listdir(tmp_path) == ["s.vt4d"]
    with pytest.raises(Vt4dError):
        ArchiveWriter(path)
    assert os.listdir(tmp_path) == ["s.vt4d"]


# --- defect 7: a failed first pack leaves nothing behind ---------------------------------------------
def test_failed_pack_leaves_no_archive_and_no_lock(tmp_path, capsys):
    d = tmp_path / "in"
    d.mkdir()
    (d / "a.vt4d").write_bytes(scene_record(0))
    (d / "b.vt4d").write_bytes(b"not a scene")
    out = tmp_path / "o.vt4da"
    assert main(["pack", str(d), "-o", str(out), "-q"]) != 0
    assert sorted(os.listdir(tmp_path)) == ["in"]
    (d / "b.vt4d").write_bytes(scene_record(1))
    assert main(["pack", str(d), "-o", str(out), "-q"]) == 0  # the retry works
    assert _readable(out) == {"a": scene_record(0), "b": scene_record(1)}


def test_writer_that_fails_after_commits_keeps_the_archive(tmp_path):
    path = tmp_path / "a.vt4da"
    with pytest.raises(RuntimeError):
        with ArchiveWriter(path, "x", durable=False) as w:
            w.append("k", payload_for("k", 10), validate=False)
            w.commit()
            raise RuntimeError("boom")
    assert _readable(path) == {"k": payload_for("k", 10)}


# --- property: repair never reduces the set of verifiable committed scenes ---------------------------
def _build_random(path, ops) -> dict[str, tuple[int, int]]:
    """Commit batches of (key, size, replace) ops; returns key -> (frame start, payload end) of the
    newest committed version of each key."""
    newest: dict[str, tuple[int, int]] = {}
    versions: dict[str, int] = {}
    with ArchiveWriter(path, "w", durable=False) as w:
        for batch in ops:
            for key, size in batch:
                versions[key] = versions.get(key, 0) + 1
                e = w.append(key, payload_for(f"{key}#{versions[key]}", size), validate=False, replace=True)
                newest[key] = (e.frame_offset, e.offset + e.length)
            w.commit()
    return newest


damage = st.lists(st.one_of(
    st.tuples(st.just("flip"), st.floats(0, 1, exclude_max=True), st.integers(0, 7)),
    st.tuples(st.just("zero"), st.floats(0, 1, exclude_max=True), st.integers(1, 300)),
    st.tuples(st.just("cut"), st.floats(0, 1, exclude_max=True), st.just(0)),
), min_size=1, max_size=3)
batches = st.lists(st.lists(st.tuples(st.sampled_from("abcdefg"), st.integers(1, 600)), min_size=1, max_size=4),
                   min_size=1, max_size=4)


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(ops=batches, hits=damage, full=st.booleans())
def test_repair_never_reduces_the_verifiable_committed_scenes(tmp_path_factory, ops, hits, full):
    path = tmp_path_factory.mktemp("prop") / "a.vt4da"
    newest = _build_random(path, ops)
    original = path.read_bytes()
    data = bytearray(original)
    for kind, where, arg in hits:
        pos = int(where * len(data))
        if kind == "flip":
            data[pos] ^= 1 << arg
        elif kind == "zero":
            data[pos: pos + arg] = bytes(len(data[pos: pos + arg]))
        else:
            del data[max(pos, 1):]
    path.write_bytes(bytes(data))
    # verifiable before repair: the newest committed frame of the key is byte-for-byte intact
    intact = {k for k, (a, b) in newest.items() if b <= len(data) and data[a:b] == original[a:b]}
    try:
        report = repair_archive(str(path), full_scan=full)
    except Vt4dError:  # a refusal (e.g. a damaged magic without --full-scan) must write nothing
        assert path.read_bytes() == bytes(data)
        assert not full or not intact, "a full-scan repair gave up although committed scenes were intact"
        if not intact:
            return
        report = repair_archive(str(path), full_scan=True)
    with open_archive(path) as ar:
        for k in intact:
            want = original[newest[k][1] - ar.entry(k).length: newest[k][1]]
            assert ar.read_bytes(k) == want, f"{k}: not the newest committed version"
    if report.full_scan:  # every record was checked: the result verifies end to end
        verify_archive(path, containers=False)


def test_encode_style_writer_that_fails_before_its_commit_leaves_nothing(tmp_path):
    """`vt4d encode --archive` opens ArchiveWriter(shard), appends, and closes with commit=False in a
    finally block: a failure before its commit must not leave an empty archive and a lock behind."""
    shard = tmp_path / "shards" / "train.vt4da"
    shard.parent.mkdir()
    with pytest.raises(ArchiveError):
        writer = ArchiveWriter(shard)
        try:
            writer.append("a", payload_for("a", 10), validate=False)
            writer.append("bad key/", b"x", validate=False)  # fails mid-encode
        finally:
            writer.close(commit=False)
    assert os.listdir(shard.parent) == []
    writer = ArchiveWriter(shard)  # the retry starts clean and succeeds
    writer.append("a", payload_for("a", 10), validate=False)
    writer.commit()
    writer.close(commit=False)
    assert _readable(shard) == {"a": payload_for("a", 10)}


def test_repair_with_nothing_to_do_keeps_a_version_1_1_writer_whole(tmp_path):
    path = tmp_path / "a.vt4da"
    _single = [("k%d" % i, payload_for(str(i), 20)) for i in range(6)]
    for key, data in _single:
        with ArchiveWriter(path, durable=False) as w:
            w.append(key, data, validate=False)
    report = repair_archive(str(path), full_scan=True)
    assert report.new_generation is None and report.complete
    with ArchiveWriter(path, durable=False) as w:
        w.append("new", payload_for("new", 5), validate=False)
    assert _readable(path) == dict(_single) | {"new": payload_for("new", 5)}


# --- file modes: every rewrite keeps the archive's permission bits (issue 52) ----------------------------
@pytest.mark.parametrize("mode", [0o600, 0o640])
@pytest.mark.parametrize("rewrite", ["append", "repair", "repair_full_scan", "compact", "compact_1_0"])
def test_every_rewrite_keeps_the_archives_permission_bits(tmp_path, mode, rewrite):
    import stat

    from vt4dcodec.archive import compact_archive

    path = tmp_path / "a.vt4da"
    _three_scenes(path)
    if rewrite.startswith("repair"):  # an uncommitted record and a torn tail for repair to act on
        w = ArchiveWriter(path, durable=False)
        w.append("late", payload_for("late", 50), validate=False)
        os.close(w._fd)
        w._fd = None
        w._lock.release()
        with open(path, "ab") as f:
            f.write(b"V4AR torn")
    os.chmod(path, mode)
    if rewrite == "append":
        with ArchiveWriter(path, durable=False) as w:
            w.append("more", payload_for("more", 50), validate=False)
    elif rewrite.startswith("repair"):
        report = repair_archive(path, full_scan=rewrite.endswith("full_scan"))
        assert "late" in _readable(path) and report.complete
    else:
        compact_archive(path, version=(1, 0) if rewrite.endswith("1_0") else (1, 1), durable=False)
    assert stat.S_IMODE(os.stat(path).st_mode) == mode
    assert len(_readable(path)) >= 3
