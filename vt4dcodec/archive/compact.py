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
from .index import IndexEntry, encode_summary, shared_first
from .layout import MAX_GENERATION, VERSION_MINOR
from .lock import WriterLock
from .reader import open_archive
from .verify import UncommittedTailError
from .writer import _check_magic, _check_version, replace_with_new_archive

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
    try:
        before = os.path.getsize(path)
        with open_archive(path) as reader:
            if reader.uncommitted_bytes:
                raise UncommittedTailError(f"{path}: {reader.uncommitted_bytes} bytes after the last commit; "
                                           "run `vt4d repair` first")
            old_generation = reader.generation
            entries = sorted(reader.entries(), key=lambda e: e.offset)
            def record(e: IndexEntry) -> tuple[str, bytes, bytes]:  # a CRC-checked copy
                payload = reader.read_entry(e)
                if e.has_summary or version >= (1, 2):
                    return e.key, payload, e.summary_bytes
                summary = reader.entry_summary(e, payload)  # 1.0 and 1.1 store one with every record (5.3)
                return e.key, payload, encode_summary(shared_first(summary) if version >= (1, 1) else summary)

            records = (record(e) for e in entries)
            commit = replace_with_new_archive(
                path, records, generation=old_generation + 1 if old_generation < MAX_GENERATION else 1,
                version=version, durable=durable, suffix="compact")
        return CompactReport(path, len(entries), before, os.path.getsize(path), commit.generation,
                             (version[0], version[1]))
    finally:
        lock.release()
