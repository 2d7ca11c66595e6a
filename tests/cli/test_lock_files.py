"""No lock file is left beside an archive once a command is done (issue 51.4): the writer removes its
`<archive>.lock` as it releases it, and a file that is no archive gets none (the commands that take the
writer lock check the file first)."""

from __future__ import annotations

import os

import pytest
from cli_helpers import StandInCodec

import vt4dcodec.archive.lock as lock_module
import vt4dcodec.cli as cli
from vt4dcodec.archive import ArchiveWriter, WriterLock, compact_archive
from vt4dcodec.errors import ArchiveLockedError, Vt4dError


def test_compact_of_a_file_that_is_no_archive_leaves_no_lock_file(scene_file, tmp_path):
    with pytest.raises(Vt4dError):
        compact_archive(scene_file)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.vt4d"]
    text = tmp_path / "notes.txt"
    text.write_text("not an archive")
    for argv in (["compact", str(text)], ["repair", str(text)], ["compact", str(scene_file)]):
        assert cli.main(argv) == 1, argv
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "s.vt4d"]


def test_archive_commands_leave_no_lock_file(scene_file, small_captures, tmp_path, monkeypatch):
    """Each of these left an empty a.vt4da.lock beside the archive before (issue 51.4)."""
    archive = tmp_path / "a.vt4da"
    StandInCodec(monkeypatch)
    runs = [["pack", str(scene_file), "-o", str(archive)],
            ["encode", str(small_captures), "--archive", str(archive), "--skip-existing"],
            ["compact", str(archive)],
            ["repair", str(archive)],
            ["extract", str(archive), "-o", str(tmp_path / "out")]]
    for argv in runs:
        assert cli.main([*argv, "-q"]) == 0, argv
        assert not (tmp_path / "a.vt4da.lock").exists(), argv
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.vt4da", "out", "s.vt4d"]


def test_the_lock_file_goes_with_the_lock_and_a_second_writer_is_still_refused(tmp_path):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, "w", durable=False) as w:
        assert (tmp_path / "a.vt4da.lock").read_text().strip() == str(os.getpid())
        with pytest.raises(ArchiveLockedError, match=f"pid {os.getpid()}"):
            ArchiveWriter(path, durable=False)
        w.append("k", b"x" * 10, validate=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.vt4da"]
    with WriterLock(path):  # and the next writer takes it as before
        assert (tmp_path / "a.vt4da.lock").exists()
    assert not (tmp_path / "a.vt4da.lock").exists()


def test_a_writer_that_locked_a_removed_lock_file_tries_again(tmp_path, monkeypatch):
    """The race removal opens: writer B opens the lock file, the holder removes it and lets go, B locks the
    removed file while C could lock a new one at the path. B must see that and lock the file at the path."""
    path = tmp_path / "a.vt4da"
    lock = lock_module.lock_path(path)
    real = lock_module.FileLock
    locked: list[object] = []

    class RacingFileLock(real):  # type: ignore[misc, valid-type]
        def acquire(self, *args, **kwargs):
            result = super().acquire(*args, **kwargs)
            if not locked:  # the first time: the file B locked is replaced by the previous holder's leaving
                os.unlink(lock)
                open(lock, "w").close()
            locked.append(self)
            return result

    monkeypatch.setattr(lock_module, "FileLock", RacingFileLock)
    held = WriterLock(path).acquire()
    assert len(locked) == 2 and not locked[0].is_locked  # let go of the removed file, then locked the new one
    monkeypatch.setattr(lock_module, "FileLock", real)
    with pytest.raises(ArchiveLockedError):  # the file at the path is the one held: C is refused
        WriterLock(path).acquire()
    held.release()
    assert not os.path.exists(lock)
