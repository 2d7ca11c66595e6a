"""Find complete, checksum-valid records in raw archive bytes and plan a repair that loses nothing.

:func:`scan_records` walks the structures that follow a position: record frames (kept when their
meta and payload CRCs hold) and commits (an index block + footer whose CRCs hold).  A strict scan
stops at the first byte that is neither (a torn write); a *resyncing* scan skips damaged bytes to the
next frame or index magic and carries on, so one flipped bit never hides the records after it.

:func:`plan_repair` decides what a repair keeps, before anything is written (``vt4d repair
--dry-run`` prints the plan).  Its rules (FORMAT.md Part II section 9):

* the base is the newest commit whose index verifies (highest generation among the tail footer, the
  header slots and, in a full scan, every commit found in the file);
* every base entry whose payload verifies is kept where it is; one whose frame header is damaged but
  whose payload verifies is copied into a fresh frame; one whose payload fails is *unrecoverable*
  and is reported by key, never silently replaced by an older version of the same key;
* every complete record after the base commit is added, a later frame of a key winning;
* only bytes after the last valid structure are cut; damaged bytes between valid ones stay in place;
* the new commit's generation is one more than any generation seen, so no stale slot outranks it.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from typing import Any

from ..errors import ArchiveError, FormatError, LimitExceededError
from .index import IndexEntry, decode_summary
from .layout import (FOOTER_SIZE, FRAME_HEADER_SIZE, FRAME_MAGIC, HEADER_SIZE, INDEX_ENTRY_SIZE,
                     INDEX_HEADER_SIZE, INDEX_MAGIC, FLAG_SEGMENTED, MANIFEST_HEADER_SIZE, MANIFEST_MAGIC, MAX_GENERATION,
                     MAX_SEGMENTS, SEGMENT_REF_SIZE, MAX_SCENES, SLOT_OFFSETS, SLOT_SIZE, Commit,
                     check_key, frame_meta_crc, parse_footer, parse_frame_header, parse_preamble,
                     parse_slot)
from .segments import IndexView, load_index
from .source import ByteSource

__all__ = ["ScanResult", "scan_records", "RepairPlan", "plan_repair", "RepairReport",
           "ArchiveNotFoundError"]

_SCAN_CHUNK = 1 << 20  # frames are read whole; only the 32-byte heads are read speculatively
SCENE_MAGIC_PREFIX = b"\x89VT4D"  # a single-scene .vt4d file, never an archive


class ArchiveNotFoundError(ArchiveError, FileNotFoundError):
    """The archive to repair does not exist (repair never creates one)."""


@dataclass
class ScanResult:
    """Records and commits found after ``start``, in file order, and where the valid bytes end."""

    start: int
    end: int
    records: list[IndexEntry] = field(default_factory=list)
    commits_skipped: int = 0
    commits: list[Commit] = field(default_factory=list)
    damaged: list[tuple[int, int]] = field(default_factory=list)  # skipped [start, end) ranges

    @property
    def latest(self) -> dict[str, IndexEntry]:
        """Records by key; a later frame for the same key wins (append with replace=True)."""
        out: dict[str, IndexEntry] = {}
        for r in self.records:
            out[r.key] = r
        return out


def _payload_crc(source: ByteSource, offset: int, length: int) -> int:
    crc = 0
    for off in range(0, length, _SCAN_CHUNK):  # bounded memory for huge records
        crc = zlib.crc32(source.read(offset + off, min(_SCAN_CHUNK, length - off)), crc)
    return crc & 0xFFFFFFFF


def _try_frame(source: ByteSource, pos: int, size: int) -> IndexEntry | None:
    if size - pos < FRAME_HEADER_SIZE:
        return None
    head = source.read(pos, FRAME_HEADER_SIZE)
    try:
        fh = parse_frame_header(head)
    except FormatError:
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
    except (FormatError, UnicodeDecodeError):
        return None
    payload_offset = pos + fh.payload_start
    if _payload_crc(source, payload_offset, fh.payload_len) != fh.payload_crc32:
        return None
    return IndexEntry(key, payload_offset, fh.payload_len, fh.payload_crc32, bytes(summary))


def _try_commit(source: ByteSource, pos: int, size: int) -> Commit | None:
    """The commit whose intact index block or segment manifest (at ``pos``) and footer follow, or None."""
    if size - pos < INDEX_HEADER_SIZE + FOOTER_SIZE:
        return None
    magic, esize, count, keys_len, summ_len = struct.unpack("<4sIQQQ", source.read(pos, INDEX_HEADER_SIZE))
    if magic == MANIFEST_MAGIC:  # u32 segment count sits where an index has its entry size
        mlen = MANIFEST_HEADER_SIZE + esize * SEGMENT_REF_SIZE
        seg = _segment_length(source, pos + mlen, size) if 1 <= esize <= MAX_SEGMENTS else None
        if seg is None:
            return None
        index_len = mlen + seg
    elif magic == INDEX_MAGIC and count <= MAX_SCENES:
        index_len = INDEX_HEADER_SIZE + count * INDEX_ENTRY_SIZE + keys_len + summ_len
    else:
        return None
    if index_len + FOOTER_SIZE > size - pos:
        return None
    try:
        commit = parse_footer(source.read(pos + index_len, FOOTER_SIZE))
    except FormatError:
        return None
    if commit.index_offset != pos or commit.index_length != index_len:
        return None
    if _payload_crc(source, pos, index_len) != commit.index_crc32:
        return None
    return commit


def _segment_length(source: ByteSource, pos: int, size: int) -> int | None:
    """The length an index block at ``pos`` declares (segments of 1.1 commits have no footer)."""
    if size - pos < INDEX_HEADER_SIZE:
        return None
    magic, esize, count, keys_len, summ_len = struct.unpack("<4sIQQQ", source.read(pos, INDEX_HEADER_SIZE))
    if magic != INDEX_MAGIC or esize != INDEX_ENTRY_SIZE or count > MAX_SCENES:
        return None
    return int(INDEX_HEADER_SIZE + count * INDEX_ENTRY_SIZE + keys_len + summ_len)


def _next_magic(source: ByteSource, pos: int, size: int) -> int | None:
    """The first offset >= ``pos`` where a frame or index magic starts, or None."""
    while pos < size:
        block = source.read(pos, min(_SCAN_CHUNK + 3, size - pos))  # +3: a magic across chunks
        hits = [i for i in (block.find(FRAME_MAGIC), block.find(INDEX_MAGIC), block.find(MANIFEST_MAGIC)) if i >= 0]
        if hits:
            return pos + min(hits)
        pos += _SCAN_CHUNK
    return None


def scan_records(source: ByteSource, start: int, *, resync: bool = False) -> ScanResult:
    """Walk frames and intact commits from ``start``.

    A strict scan stops at the first thing that is neither; with ``resync`` damaged bytes are
    skipped to the next frame/index magic (recorded in ``damaged``) and the walk goes on.  ``end``
    is always the end of the last valid structure found.
    """
    size = source.size()
    result = ScanResult(start=start, end=start)
    pos = start
    while pos < size:
        magic = source.read(pos, 4) if size - pos >= 4 else b""
        if magic == FRAME_MAGIC:
            entry = _try_frame(source, pos, size)
            if entry is not None:
                result.records.append(entry)
                pos = result.end = entry.offset + entry.length
                continue
        elif magic in (INDEX_MAGIC, MANIFEST_MAGIC):
            commit = _try_commit(source, pos, size)
            if commit is not None:
                result.commits.append(commit)
                result.commits_skipped += 1
                pos = result.end = commit.end
                continue
        if not resync:
            break
        nxt = _next_magic(source, pos + 1, size)
        if nxt is None:
            break
        if not (magic == INDEX_MAGIC and _segment_length(source, pos, size) == nxt - pos):
            result.damaged.append((pos, nxt))  # (an index segment of a 1.1 commit is not damage)
        pos = nxt
    return result


# --- planning ---------------------------------------------------------------------------------------
@dataclass
class RepairPlan:
    """What a repair will do; nothing has been written when this exists."""

    size: int
    base: Commit | None  # the newest commit whose index verifies (None: none does)
    entries: dict[str, IndexEntry]  # records kept in place (base entries that verify + later records)
    copies: dict[str, IndexEntry]  # base entries whose payload verifies but whose frame is damaged
    recovered: list[str]  # keys taken from records after the base commit
    unrecoverable: list[str]  # base keys whose payload fails its CRC (and no later record replaces)
    cut: int  # the file is truncated to this length before the new commit is appended
    damaged_bytes: int  # damaged bytes skipped between valid structures (left in place)
    new_generation: int
    preamble_ok: bool
    full_scan: bool
    lost: Commit | None = None  # a commit named by a header slot but cut off the end of the file
    base_footer_ok: bool = True  # the base commit's own footer is intact and ends the file
    segmented: bool = False  # the preamble says commits may use segmented indexes (version 1.1)
    view: IndexView | None = None  # the base commit's index

    @property
    def needs_commit(self) -> bool:
        return bool(self.base is None or self.recovered or self.copies or self.unrecoverable
                    or self.cut != self.size or not self.preamble_ok or not self.base_footer_ok)


def _frame_intact(source: ByteSource, e: IndexEntry) -> bool:
    key_raw = e.key.encode()
    start = e.frame_offset
    if start < HEADER_SIZE:
        return False
    meta = source.read(start, FRAME_HEADER_SIZE + len(key_raw) + len(e.summary_bytes))
    try:
        fh = parse_frame_header(meta)
    except FormatError:
        return False
    return ((fh.key_len, fh.summary_len, fh.payload_len, fh.payload_crc32)
            == (len(key_raw), len(e.summary_bytes), e.length, e.crc32)
            and meta[FRAME_HEADER_SIZE:] == key_raw + e.summary_bytes
            and frame_meta_crc(meta, key_raw, e.summary_bytes) == fh.meta_crc32)


def _load_index(source: ByteSource, c: Commit, size: int) -> IndexView | None:
    if c.end > size:
        return None
    try:
        return load_index(source.read, c)
    except FormatError:
        return None


def plan_repair(source: ByteSource, *, full_scan: bool, base: Commit | None = None,
                lost: Commit | None = None) -> RepairPlan:
    """Plan a repair (see the module docstring).

    Without ``full_scan`` the given ``base`` (the last commit) is trusted and only the bytes after it
    are walked; with it the whole file is walked, every record of the chosen base is checked, and
    the newest commit whose index verifies becomes the base.
    """
    size = source.size()
    header = source.read(0, min(size, HEADER_SIZE))
    try:
        segmented = bool(parse_preamble(header) & FLAG_SEGMENTED)
        preamble_ok = len(header) == HEADER_SIZE
    except FormatError:
        preamble_ok = segmented = False
    slots = [c for off in SLOT_OFFSETS if (c := parse_slot(header[off: off + SLOT_SIZE])) is not None]
    generations = [c.generation for c in slots]
    if not full_scan and base is not None:
        scan = scan_records(source, base.end, resync=True)
        index = None
    else:
        scan = scan_records(source, HEADER_SIZE, resync=True)
        base, index = None, None
        candidates = sorted({*scan.commits, *slots}, key=lambda c: c.generation, reverse=True)
        for c in candidates:
            index = _load_index(source, c, size)
            if index is not None:
                base = c
                break
    if not preamble_ok and base is None and not scan.records:
        raise ArchiveError(f"{source.name}: no archive preamble, commit or record frame found; "
                           "not an archive (nothing was changed)")
    generations += [c.generation for c in scan.commits]
    entries: dict[str, IndexEntry] = {}
    copies: dict[str, IndexEntry] = {}
    unrecoverable: list[str] = []
    checked = index is not None  # the full path: every record the base names is checked
    if index is not None:
        for e in index.entries():
            if _payload_crc(source, e.offset, e.length) != e.crc32:
                unrecoverable.append(e.key)
            elif _frame_intact(source, e):
                entries[e.key] = e
            else:
                copies[e.key] = e
    elif base is not None:
        index = _load_index(source, base, size)
        if index is None:
            raise ArchiveError(f"{source.name}: the last commit's index does not verify; use a full scan")
        entries = {e.key: e for e in index.entries()}
    recovered: dict[str, None] = {}
    after = base.end if base is not None else HEADER_SIZE
    for r in scan.records:
        if r.offset > after:
            entries[r.key] = r
            copies.pop(r.key, None)
            recovered.pop(r.key, None)
            recovered[r.key] = None
    unrecoverable = [k for k in unrecoverable if k not in entries]
    if base is not None:
        generations.append(base.generation)
    if lost is not None:
        generations.append(lost.generation)
    new_generation = max(generations, default=-1) + 1
    if new_generation > MAX_GENERATION:
        raise LimitExceededError(
            f"{source.name}: generation counter exhausted ({max(generations)}); copy the scenes to a new "
            "archive with `vt4d compact`")
    ends = [scan.end, HEADER_SIZE] + ([base.end] if base is not None else [])
    ends += [e.offset + e.length for e in entries.values()]
    cut = max(ends)
    damaged = sum(b - a for a, b in scan.damaged if b <= cut)
    footer_ok = False
    if base is not None and base.end == size:
        try:
            footer_ok = parse_footer(source.read(base.footer_offset, FOOTER_SIZE)) == base
        except FormatError:
            pass
    return RepairPlan(size, base, entries, copies, list(recovered), unrecoverable, cut, damaged,
                      new_generation, preamble_ok, full_scan or checked or base is None, lost, footer_ok,
                      segmented, index)


@dataclass
class RepairReport:
    """What :func:`repair_archive` found and did (or, in a dry run, would do)."""

    path: str
    last_generation: int | None  # the commit repair started from (None: no commit verified)
    committed: int  # scenes in that commit
    recovered: list[str]  # keys recovered from records after it
    discarded_bytes: int  # torn bytes cut off the end (they held no verifiable record)
    new_generation: int | None  # None when nothing needed doing (or dry run)
    full_scan: bool = False
    unrecoverable: list[str] = field(default_factory=list)  # committed keys whose record fails its CRC
    copied: list[str] = field(default_factory=list)  # records re-framed because their frame was damaged
    damaged_bytes: int = 0  # damaged bytes between valid structures, left in place
    lost_generation: int | None = None  # a commit cut off the end of a truncated file
    lost_scenes: int | None = None  # how many scenes that commit held
    scenes: int = 0  # scenes in the repaired archive
    dry_run: bool = False

    @property
    def complete(self) -> bool:
        """True when every committed scene the file still held is in the repaired archive."""
        return not self.unrecoverable and (self.lost_scenes is None or self.scenes >= self.lost_scenes)

    def to_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "complete": self.complete}
