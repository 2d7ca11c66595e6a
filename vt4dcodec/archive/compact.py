"""``vt4d compact``: rewrite an archive with only its live records and one index, atomically.

Appends leave superseded bytes behind: replaced records, index segments that were merged, and (in
version 1.0 archives) every earlier whole index.  Compaction holds the writer lock, copies every
live record (CRC-checked) in file order into ``<archive>.compact-<pid>``, commits it once, fsyncs, and
renames it over the archive, so a reader sees either the old file or the new one, never a mix, and a
crash leaves the original untouched.  Readers that opened the old file keep reading it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

from ..errors import ArchiveError
from .layout import MAX_GENERATION, VERSION_MINOR
from .lock import WriterLock
from .reader import open_archive
from .verify import UncommittedTailError
from .writer import ArchiveWriter, _check_magic, _check_version, _fsync_dir

__all__ = ["CompactReport", "compact_archive"]


@dataclass
class CompactReport:
    path: str
    scenes: int
    bytes_before: int
    bytes_after: int
    generation: int  # of the compacted archive (the old generation + 1, so it never repeats)
    version: tuple[int, int]

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def compact_archive(path: str | os.PathLike[str], *, version: tuple[int, int] = (1, VERSION_MINOR),
                    durable: bool = True) -> CompactReport:
    """Rewrite ``path`` with only its live records and one index (see the module docstring)."""
    path = os.fspath(path)
    _check_version(version)
    if not os.path.exists(path):
        raise ArchiveError(f"{path}: no such archive")
    _check_magic(path)  # before the lock: a file that is no archive gets no .lock beside it
    lock = WriterLock(path).acquire()
    tmp = f"{path}.compact-{os.getpid()}"
    try:
        before = os.path.getsize(path)
        with open_archive(path) as reader:
            if reader.uncommitted_bytes:
                raise UncommittedTailError(f"{path}: {reader.uncommitted_bytes} bytes after the last commit; "
                                           "run `vt4d repair` first")
            old_generation = reader.generation
            entries = sorted(reader.entries(), key=lambda e: e.offset)
            w = ArchiveWriter(tmp, "x", durable=durable, version=version)
            try:
                for e in entries:
                    w._append_raw(e.key, reader.read_entry(e), e.summary_bytes)  # CRC-checked copy
                w._next_generation = old_generation + 1 if old_generation < MAX_GENERATION else 1
                w._write_commit()
                generation = w.generation
            except BaseException:
                w.close(commit=False)
                raise
            w._close_fd()
            w._lock.release_and_remove()
        os.chmod(tmp, os.stat(path).st_mode & 0o7777)  # the compacted archive keeps the old file's permissions
        os.replace(tmp, path)
        if durable:
            _fsync_dir(path)
        return CompactReport(path, len(entries), before, os.path.getsize(path), generation,
                             (version[0], version[1]))
    except BaseException:
        for leftover in (tmp, tmp + ".lock"):
            try:
                os.unlink(leftover)
            except FileNotFoundError:
                pass
        raise
    finally:
        lock.release()
