"""Repair's exit status can be trusted (issue 52): 0 means nothing committed was lost, judged against every
intact footer and header slot; otherwise 1, naming every lost key (``lost``; ``lost_unnamed`` counts lost
scenes no readable index names).

Each reproducer of the issue builds its archive with the library's writer and then damages its bytes:
a truncated archive, bytes inserted into or deleted from a committed record, damage inside the committed
region under a default repair, an index entry with a valid CRC but a wrong offset, and an archive whose
generation counter is spent.  A property test applies one random damage and checks the report against
what was committed.
"""

import dataclasses
import json
import os
import stat

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from vt4dcodec.archive import ArchiveWriter, open_archive, repair_archive, verify_archive
from vt4dcodec.archive.index import ArchiveIndex
from vt4dcodec.archive.layout import FOOTER_SIZE, HEADER_SIZE, MAX_GENERATION, SLOT_OFFSETS, SLOT_SIZE, crc32, pack_footer, pack_slot, parse_footer
from vt4dcodec.archive.segments import pack_manifest, parse_manifest
from vt4dcodec.cli import main
from vt4dcodec.errors import ArchiveError, Vt4dError

from .helpers import payload_for, scene_record

MODES = pytest.mark.parametrize("full", [False, True], ids=["default", "full-scan"])


def _single_commits(path, n: int = 3) -> dict[str, bytes]:
    """``n`` commits of one real scene each; returns what was committed."""
    for i in range(n):
        with ArchiveWriter(path, durable=False) as w:
            w.append(f"scene-{i}", scene_record(i))
    return {f"scene-{i}": scene_record(i) for i in range(n)}


def _one_commit(path, n: int = 3, version=(1, 1)) -> dict[str, bytes]:
    with ArchiveWriter(path, durable=False, version=version) as w:
        for i in range(n):
            w.append(f"scene-{i}", scene_record(i))
    return {f"scene-{i}": scene_record(i) for i in range(n)}


def _entry(path, key: str):
    with open_archive(path) as ar:
        return ar.entry(key)


def _splice(path, pos: int, insert: bytes = b"", delete: int = 0) -> None:
    """Insert ``insert`` at ``pos`` after deleting ``delete`` bytes there."""
    data = path.read_bytes()
    path.write_bytes(data[:pos] + insert + data[pos + delete:])


def _flip(path, pos: int, mask: int) -> None:
    data = bytearray(path.read_bytes())
    data[pos] ^= mask
    path.write_bytes(bytes(data))


def _readable(path) -> dict[str, bytes]:
    with open_archive(path) as ar:
        return dict(ar.iter_records())


def _repair_cli(path, full: bool, capsys, *extra: str) -> tuple[int, dict]:
    rc = main(["repair", "--json", *(["--full-scan"] if full else []), *extra, str(path)])
    return rc, json.loads(capsys.readouterr().out)


# --- a truncated archive: --full-scan exited 0 with every scene gone --------------------------------------
@MODES
@pytest.mark.parametrize("keep", [300, 2000, 4000])
def test_repair_of_a_truncated_archive_fails_counting_what_it_lost(tmp_path, capsys, full, keep):
    path = tmp_path / "a.vt4da"
    committed = _single_commits(path)
    os.truncate(path, keep)
    rc, report = _repair_cli(path, full, capsys)
    got = _readable(path)
    missing = set(committed) - set(got)
    assert missing, "the cut should lose a scene"
    assert rc == 1 and not report["complete"]
    assert set(report["lost"]) <= missing
    assert len(report["lost"]) + report["lost_unnamed"] == len(missing)
    assert all(got[k] == committed[k] for k in got)
    verify_archive(path)


@MODES
def test_repair_of_a_truncated_archive_that_lost_nothing_exits_0(tmp_path, capsys, full):
    path = tmp_path / "a.vt4da"
    committed = _single_commits(path)
    os.truncate(path, path.stat().st_size - 10)  # the last footer torn: every record is still there
    rc, report = _repair_cli(path, full, capsys)
    assert rc == 0 and report["complete"] and report["lost"] == [] and report["lost_unnamed"] == 0
    assert _readable(path) == committed


# --- 1-15 bytes inserted into or deleted from one committed record ----------------------------------------
@MODES
@pytest.mark.parametrize("delta", [1, 3, 15, -1, -15])
@pytest.mark.parametrize("where", ["payload", "frame"])
def test_bytes_inserted_or_deleted_in_a_committed_record_name_the_lost_scene(tmp_path, capsys, full, delta, where):
    path = tmp_path / "a.vt4da"
    committed = _one_commit(path)
    e = _entry(path, "scene-1")
    pos = e.offset + e.length // 2 if where == "payload" else e.frame_offset + 10  # the frame: its lengths
    _splice(path, pos, bytes(range(1, delta + 1)), max(-delta, 0))
    rc, report = _repair_cli(path, full, capsys)
    got = _readable(path)
    if where == "frame":  # its payload is intact, found through the moved index: copied into a new frame
        assert rc == 0 and report["complete"] and got == committed, report
        assert report["copied"] == ["scene-1"]
    else:
        assert rc == 1 and report["lost"] == ["scene-1"] and report["lost_unnamed"] == 0
        assert got == {k: v for k, v in committed.items() if k != "scene-1"}
    verify_archive(path)


def test_the_message_names_the_lost_scene_and_a_second_repair_exits_0(tmp_path, capsys):
    path = tmp_path / "a.vt4da"
    _one_commit(path)
    _splice(path, _entry(path, "scene-1").offset + 40, bytes(5))
    assert main(["repair", str(path)]) == 1
    err = capsys.readouterr().err
    assert "1 committed scene could not be recovered" in err and "scene-1" in err
    assert main(["repair", str(path)]) == 0  # the loss was reported once; the repaired archive is whole
    assert "nothing to repair" in capsys.readouterr().out


def test_a_damaged_newer_version_is_reported_not_replaced_by_the_older_one(tmp_path, capsys):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, durable=False) as w:
        w.append("k", payload_for("v1", 300), validate=False)
        w.append("a", payload_for("a", 300), validate=False)
    with ArchiveWriter(path, durable=False) as w:
        w.append("k", payload_for("v2", 300), validate=False, replace=True)
    _splice(path, _entry(path, "k").offset + 100, b"\x07\x07\x07")  # the newest commit's index moves with it
    report = repair_archive(str(path), full_scan=True)
    assert report.lost == ["k"] and not report.complete
    assert _readable(path) == {"a": payload_for("a", 300)}  # k is not served as its older version


# --- default repair ignored damage inside the committed region ---------------------------------------
def test_default_repair_scans_when_a_committed_record_fails_its_checksum(tmp_path, capsys):
    path = tmp_path / "a.vt4da"
    committed = _one_commit(path)
    _flip(path, _entry(path, "scene-1").offset + 100, 0x10)
    assert main(["verify", str(path)]) == 1
    capsys.readouterr()
    assert main(["repair", str(path)]) == 1
    out = capsys.readouterr()
    assert "full scan" in out.out and "scene-1" in out.out and "nothing to repair" not in out.out
    assert "scene-1" in out.err
    assert main(["verify", str(path)]) == 0
    assert _readable(path) == {k: v for k, v in committed.items() if k != "scene-1"}


def test_default_repair_reframes_a_committed_record_whose_frame_is_damaged(tmp_path, capsys):
    path = tmp_path / "a.vt4da"
    committed = _one_commit(path)
    _flip(path, _entry(path, "scene-2").frame_offset + 32, 0x01)  # its key: the frame no longer matches the index
    assert main(["verify", str(path)]) == 1
    rc, report = _repair_cli(path, False, capsys)
    assert rc == 0 and report["copied"] == ["scene-2"] and report["full_scan"] and report["scan_reason"]
    verify_archive(path)
    assert _readable(path) == committed


def test_default_repair_of_an_intact_archive_still_does_nothing(tmp_path, capsys):
    path = tmp_path / "a.vt4da"
    _single_commits(path)
    before = path.read_bytes()
    rc, report = _repair_cli(path, False, capsys)
    assert rc == 0 and report["new_generation"] is None and not report["full_scan"] and report["lost"] == []
    assert path.read_bytes() == before


# --- an index entry with a valid CRC but a wrong offset ---------------------------------------------------
def _misplace_entry(path, key: str, shift: int) -> None:
    """Rewrite the last commit so that ``key``'s entry points ``shift`` bytes off, with every CRC valid."""
    with open_archive(path) as ar:
        c, entries = ar.commit, list(ar.entries())
    bad = [dataclasses.replace(e, offset=e.offset + shift) if e.key == key else e for e in entries]
    data = bytearray(path.read_bytes())
    if c.segmented:
        refs = parse_manifest(bytes(data[c.index_offset: c.footer_offset]), c)
        segment = ArchiveIndex.build(bad, prefix=True)
        block = pack_manifest([dataclasses.replace(refs[0], crc32=crc32(segment))], c.scene_count) + segment
    else:
        block = ArchiveIndex.build(bad)
    assert len(block) == c.index_length
    data[c.index_offset: c.footer_offset] = block
    fixed = dataclasses.replace(c, index_crc32=crc32(block))
    data[-FOOTER_SIZE:] = pack_footer(fixed)
    slot = SLOT_OFFSETS[fixed.generation % 2]
    data[slot: slot + SLOT_SIZE] = pack_slot(fixed)
    path.write_bytes(bytes(data))


@MODES
@pytest.mark.parametrize("version", [(1, 0), (1, 1)], ids=["1.0", "1.1"])
@pytest.mark.parametrize("shift", [-1, 7])
def test_an_index_entry_with_a_wrong_offset_drops_no_verifying_record(tmp_path, capsys, full, version, shift):
    path = tmp_path / "a.vt4da"
    committed = _one_commit(path, version=version)
    _misplace_entry(path, "scene-1", shift)
    with pytest.raises(ArchiveError):
        verify_archive(path)
    rc, report = _repair_cli(path, full, capsys)
    assert rc == 0 and report["complete"] and report["reindexed"] == ["scene-1"] and report["lost"] == []
    assert _readable(path) == committed
    verify_archive(path)


# --- a stuck archive: generation 2^64 - 1 with bytes after its commit ------------------------------------
def _spent_generation(path, tail: bytes) -> dict[str, bytes]:
    committed = _one_commit(path, n=2)
    data = bytearray(path.read_bytes())
    top = dataclasses.replace(parse_footer(bytes(data[-FOOTER_SIZE:])), generation=MAX_GENERATION)
    data[-FOOTER_SIZE:] = pack_footer(top)
    data[SLOT_OFFSETS[1]: SLOT_OFFSETS[1] + SLOT_SIZE] = pack_slot(top)
    path.write_bytes(bytes(data) + tail)
    return committed


@MODES
def test_repair_of_an_archive_with_a_spent_generation_counter_writes_a_new_file(tmp_path, capsys, full):
    path = tmp_path / "a.vt4da"
    committed = _spent_generation(path, b"V4AR torn")
    os.chmod(path, 0o640)
    assert main(["compact", str(path)]) == 1  # uncommitted bytes: compact sends the user to repair
    assert "vt4d repair" in capsys.readouterr().err
    rc, report = _repair_cli(path, full, capsys, "--dry-run")
    assert rc == 0 and report["rewritten"] and report["discarded_bytes"] == 9
    rc, report = _repair_cli(path, full, capsys)
    assert rc == 0 and report["rewritten"] and report["new_generation"] == 1
    with open_archive(path) as ar:
        assert ar.generation == 1 and ar.uncommitted_bytes == 0
    assert _readable(path) == committed
    assert stat.S_IMODE(path.stat().st_mode) == 0o640
    assert not [n for n in os.listdir(tmp_path) if ".repair-" in n]  # no temporary file left
    verify_archive(path)
    assert main(["compact", str(path)]) == 0  # and the loop is broken both ways
    with ArchiveWriter(path, durable=False) as w:  # an ordinary append works again
        w.append("more", payload_for("more", 10), validate=False)


def test_repair_with_a_spent_generation_counter_and_a_damaged_record_names_it(tmp_path, capsys):
    path = tmp_path / "a.vt4da"
    committed = _spent_generation(path, b"")
    _flip(path, _entry(path, "scene-0").offset + 50, 0x40)
    rc, report = _repair_cli(path, False, capsys)
    assert rc == 1 and report["lost"] == ["scene-0"] and report["rewritten"]
    assert _readable(path) == {"scene-1": committed["scene-1"]}


# --- property: one damage, and the report tells the truth ---------------------------------------------
def _build(path, batches) -> tuple[dict[str, bytes], dict[str, int]]:
    """Commit each batch of (key, size); returns the committed payload of each key and its version."""
    committed: dict[str, bytes] = {}
    versions: dict[str, int] = {}
    with ArchiveWriter(path, "w", durable=False) as w:
        for batch in batches:
            for key, size in batch:
                versions[key] = versions.get(key, 0) + 1
                committed[key] = payload_for(f"{key}#{versions[key]}", size)
                w.append(key, committed[key], validate=False, replace=True)
            w.commit()
    return committed, versions


# One damage at a time, which leaves the newest commit named somewhere (its header slot or its footer:
# records are at least 64 bytes, so a 200-byte run cannot reach from the slots to the last footer, and a
# cut keeps the header).  Two damages can erase every trace of a commit; then nothing can name its loss.
one_damage = st.one_of(
    st.tuples(st.just("flip"), st.floats(0, 1, exclude_max=True), st.integers(0, 7)),
    st.tuples(st.just("zero"), st.floats(0, 1, exclude_max=True), st.integers(1, 200)),
    st.tuples(st.just("cut"), st.floats(0, 1, exclude_max=True), st.just(0)),
    st.tuples(st.just("insert"), st.floats(0, 1, exclude_max=True), st.integers(1, 15)),
    st.tuples(st.just("delete"), st.floats(0, 1, exclude_max=True), st.integers(1, 15)),
)
batches = st.lists(st.lists(st.tuples(st.sampled_from("abcdef"), st.integers(64, 600)), min_size=1, max_size=4),
                   min_size=1, max_size=4)


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow], deadline=None)
@given(ops=batches, hit=one_damage, full=st.booleans())
def test_repair_reports_exactly_what_it_lost(tmp_path_factory, ops, hit, full):
    path = tmp_path_factory.mktemp("lost") / "a.vt4da"
    committed, _ = _build(path, ops)
    data = bytearray(path.read_bytes())
    kind, where, arg = hit
    pos = int(where * len(data))
    if kind == "flip":
        data[pos] ^= 1 << arg
    elif kind == "zero":
        data[pos: pos + arg] = bytes(len(data[pos: pos + arg]))
    elif kind == "cut":
        del data[max(pos, HEADER_SIZE):]
    elif kind == "insert":
        data[pos:pos] = bytes([0xA5]) * arg
    else:
        del data[pos: pos + arg]
    path.write_bytes(bytes(data))
    intact = {k for k, v in committed.items() if bytes(data).find(v) >= 0}
    try:
        report = repair_archive(str(path), full_scan=full)
    except Vt4dError:  # a damaged magic or version without --full-scan, or nothing of an archive left: refused
        assert path.read_bytes() == bytes(data)
        try:
            report = repair_archive(str(path), full_scan=True)
        except Vt4dError:
            assert len(data) < 256 and not intact  # nothing left to repair
            return
    got = _readable(path)
    wrong = {k for k in committed if got.get(k) != committed[k]}
    assert not wrong & intact, f"committed records that were intact are not served: {wrong & intact}"
    assert set(got) <= set(committed)
    assert not set(report.lost) & set(got), "a key reported lost is in the archive"
    assert set(report.lost) <= wrong
    assert report.complete == (not wrong) or report.uncertain and not report.complete
    if not report.uncertain:  # every loss is counted: named, or counted without its key
        assert len(wrong) == len(report.lost) + report.lost_unnamed, (wrong, report.lost, report.lost_unnamed)
    verify_archive(path, containers=False)
