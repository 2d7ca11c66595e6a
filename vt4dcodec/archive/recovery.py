"""Find complete, checksum-valid records in raw archive bytes (used by repair and by writers).

:func:`scan_records` walks the structures that follow a position: record frames (kept when their
meta and payload CRCs hold), and earlier commits' index blocks + footers (skipped when intact).  It
stops at the first byte that is neither (a torn write).  The writer's ``on_uncommitted="recover"``
and :func:`repair_archive` build a new commit from what it returns.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from typing import Any

from ..errors import ArchiveError
from .index import IndexEntry, decode_summary
from .layout import (FOOTER_SIZE, FRAME_HEADER_SIZE, FRAME_MAGIC, INDEX_ENTRY_SIZE, INDEX_HEADER_SIZE,
                     INDEX_MAGIC, MAX_SCENES, check_key, crc32, frame_meta_crc, parse_footer,
                     parse_frame_header)
from .source import ByteSource

__all__ = ["ScanResult", "scan_records", "RepairReport", "repair_archive"]

_SCAN_CHUNK = 1 << 20  # frames are read whole; only the 32-byte heads are read speculatively


@dataclass
class ScanResult:
    """Records found after ``start``, in file order, and where the valid bytes end."""

    start: int
    end: int
    records: list[IndexEntry] = field(default_factory=list)
    commits_skipped: int = 0

    @property
    def latest(self) -> dict[str, IndexEntry]:
        """Records by key; a later frame for the same key wins (append with replace=True)."""
        out: dict[str, IndexEntry] = {}
        for r in self.records:
            out[r.key] = r
        return out


def _try_frame(source: ByteSource, pos: int, size: int) -> IndexEntry | None:
    if size - pos < FRAME_HEADER_SIZE:
        return None
    head = source.read(pos, FRAME_HEADER_SIZE)
    try:
        fh = parse_frame_header(head)
    except ArchiveError:
        return None
    if fh.total > size - pos:
        return None
    meta = source.read(pos + FRAME_HEADER_SIZE, fh.key_len + fh.summary_len)
    key_raw, summary = meta[: fh.key_len], meta[fh.key_len:]
    if frame_meta_crc(head, key_raw, summary) != fh.meta_crc32:
        return None
    try:
        key = key_raw.decode("utf-8")
        check_key(key)
        decode_summary(summary)
    except (ArchiveError, UnicodeDecodeError):
        return None
    payload_offset = pos + fh.payload_start
    crc = 0
    for off in range(0, fh.payload_len, _SCAN_CHUNK):  # bounded memory for huge records
        crc = zlib.crc32(source.read(payload_offset + off, min(_SCAN_CHUNK, fh.payload_len - off)), crc)
    if (crc & 0xFFFFFFFF) != fh.payload_crc32:
        return None
    return IndexEntry(key, payload_offset, fh.payload_len, fh.payload_crc32, bytes(summary))


def _try_commit(source: ByteSource, pos: int, size: int) -> int | None:
    """Length of an intact index block + footer at ``pos``, or None."""
    if size - pos < INDEX_HEADER_SIZE + FOOTER_SIZE:
        return None
    magic, _esize, count, keys_len, summ_len = struct.unpack("<4sIQQQ", source.read(pos, INDEX_HEADER_SIZE))
    if magic != INDEX_MAGIC or count > MAX_SCENES:
        return None
    index_len = INDEX_HEADER_SIZE + count * INDEX_ENTRY_SIZE + keys_len + summ_len
    if index_len + FOOTER_SIZE > size - pos:
        return None
    try:
        commit = parse_footer(source.read(pos + index_len, FOOTER_SIZE))
    except ArchiveError:
        return None
    if commit.index_offset != pos or commit.index_length != index_len:
        return None
    if crc32(source.read(pos, index_len)) != commit.index_crc32:
        return None
    return index_len + FOOTER_SIZE


def scan_records(source: ByteSource, start: int) -> ScanResult:
    """Walk frames and intact commits from ``start``; stop at the first thing that is neither."""
    size = source.size()
    result = ScanResult(start=start, end=start)
    pos = start
    while pos < size:
        magic = source.read(pos, 4) if size - pos >= 4 else b""
        if magic == FRAME_MAGIC:
            entry = _try_frame(source, pos, size)
            if entry is None:
                break
            result.records.append(entry)
            pos = entry.offset + entry.length
        elif magic == INDEX_MAGIC:
            skip = _try_commit(source, pos, size)
            if skip is None:
                break
            result.commits_skipped += 1
            pos += skip
        else:
            break
        result.end = pos
    return result


@dataclass
class RepairReport:
    """What :func:`repair_archive` found and did."""

    path: str
    last_generation: int | None  # the commit repair started from (None: full scan from scratch)
    committed: int  # scenes in that commit
    recovered: list[str]  # keys recovered from records after it
    discarded_bytes: int  # torn bytes cut off the end
    new_generation: int | None  # None when nothing needed doing (or dry run)
    full_scan: bool = False

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def repair_archive(path: str, *, full_scan: bool = False, dry_run: bool = False) -> RepairReport:
    """Make an archive end in a valid commit again, keeping every complete record.

    The last commit is kept; complete, checksum-valid records written after it are added to a new
    commit; the torn remainder is cut off.  ``full_scan`` ignores the existing commits and rebuilds
    the index from every record frame in the file (for a damaged footer *and* header).
    """
    from .writer import ArchiveWriter

    with ArchiveWriter(path, mode="a", on_uncommitted="recover", full_scan=full_scan, dry_run=dry_run) as w:
        report = w.repair_report
    assert report is not None
    return report
