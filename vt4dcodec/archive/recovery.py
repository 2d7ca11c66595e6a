"""Find complete, checksum-valid records in raw archive bytes and plan a repair that loses nothing.

:func:`scan_records` walks the structures that follow a position: record frames (kept when their
meta and payload CRCs hold) and commits (an index block + footer whose CRCs hold).  A strict scan
stops at the first byte that is neither (a torn write); a *resyncing* scan skips damaged bytes to the
next frame or index magic and carries on, so one flipped bit never hides the records after it.

:func:`plan_repair` decides what a repair keeps, before anything is written (``vt4d repair
--dry-run`` prints the plan).  Its rules (FORMAT.md Part II section 9):

* what was committed is judged against every commit the file claims (:func:`find_claims`: the valid
  header slots and every intact footer, wherever it is);
* a default repair keeps the last commit only when every record it names verifies and no claimed
  commit is newer; otherwise it becomes a full scan;
* the base is the newest commit whose index verifies where it says it is; every base entry whose
  payload verifies is kept where it is; one whose frame header is damaged but whose payload verifies
  is copied into a fresh frame; one whose offset is wrong but whose record verifies elsewhere (same
  key, length and CRC) is re-indexed; one whose payload fails is *lost* and is reported by key, never
  silently replaced by an older version of the same key;
* every complete record after the base commit is added, a later frame of a key winning;
* the newest claimed commit whose index can still be read (also one moved by inserted or deleted
  bytes) names the keys and versions that must survive: each is kept, found among the records, or
  reported lost; a newer commit whose index is gone counts its lost scenes without their keys;
* only bytes after the last valid structure are cut; damaged bytes between valid ones stay in place;
* the new commit's generation is one more than any generation seen, so no stale slot outranks it; if
  that would pass 2^64 - 1 the repaired archive is written as a new file from generation 1.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from typing import Any, Callable

from ..errors import ArchiveError, FormatError
from .index import ArchiveIndex, IndexEntry, decode_summary
from .layout import (FOOTER_MAGIC, FOOTER_SIZE, FRAME_HEADER_SIZE, FRAME_MAGIC, HEADER_SIZE, INDEX_ENTRY_SIZE,
                     INDEX_HEADER_SIZE, INDEX_MAGIC, FLAG_SEGMENTED, FLAG_V12, MAX_TAIL_BYTES, MANIFEST_HEADER_SIZE, MANIFEST_MAGIC, MAX_GENERATION,
                     MAX_SEGMENTS, SEGMENT_REF_SIZE, MAX_SCENES, SLOT_OFFSETS, SLOT_SIZE, Commit,
                     check_key, crc32, frame_meta_crc, is_footer, parse_footer, parse_frame_header, parse_preamble,
                     parse_slot)
from .segments import (COMPRESSED_MAGIC, JOURNAL_MAGIC, IndexView, compressed_length, journal_length_at_end,
                       len_of_journal, load_index, load_named, manifest_length, max_journal_length, parse_journal,
                       parse_manifest, segment_block)
from .source import ByteSource

__all__ = ["ScanResult", "scan_records", "Claim", "find_claims", "RepairPlan", "plan_repair", "RepairReport",
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
        if summary:  # length 0: the record stores no summary (FORMAT.md Part II 5.3)
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


def _try_light(source: ByteSource, pos: int, size: int) -> Commit | None:
    """The light commit (version 1.2) whose intact footer is at ``pos`` and whose named index block verifies."""
    if size - pos < FOOTER_SIZE:
        return None
    raw = source.read(pos, FOOTER_SIZE)
    if not is_footer(raw):
        return None
    try:
        commit = parse_footer(raw)
    except FormatError:
        return None
    if not commit.light or commit.footer_offset != pos:
        return None
    if _payload_crc(source, commit.index_offset, commit.index_length) != commit.index_crc32:
        return None
    return commit


def _segment_length(source: ByteSource, pos: int, size: int) -> int | None:
    """The length an index block at ``pos`` declares (segments of 1.1 commits have no footer; a 1.2
    segment may be a compressed ``V4AZ`` block)."""
    if size - pos < INDEX_HEADER_SIZE:
        return None
    head = source.read(pos, INDEX_HEADER_SIZE)
    stored = compressed_length(head)
    if stored is not None:
        return stored
    magic, esize, count, keys_len, summ_len = struct.unpack("<4sIQQQ", head)
    if magic != INDEX_MAGIC or esize != INDEX_ENTRY_SIZE or count > MAX_SCENES:
        return None
    return int(INDEX_HEADER_SIZE + count * INDEX_ENTRY_SIZE + keys_len + summ_len)


def _next_magic(source: ByteSource, pos: int, size: int) -> int | None:
    """The first offset >= ``pos`` where a frame or index magic starts, or None."""
    while pos < size:
        block = source.read(pos, min(_SCAN_CHUNK + 3, size - pos))  # +3: a magic across chunks
        hits = [i for i in (block.find(FRAME_MAGIC), block.find(INDEX_MAGIC), block.find(MANIFEST_MAGIC),
                            block.find(COMPRESSED_MAGIC), block.find(FOOTER_MAGIC), block.find(JOURNAL_MAGIC))
                if i >= 0]
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
        elif magic in (INDEX_MAGIC, MANIFEST_MAGIC, FOOTER_MAGIC[:4]):  # a commit; a light one (1.2) is its footer
            commit = _try_commit(source, pos, size) if magic != FOOTER_MAGIC[:4] else _try_light(source, pos, size)
            if commit is not None:
                result.commits.append(commit)
                result.commits_skipped += 1
                pos = result.end = commit.end
                continue
        elif magic == JOURNAL_MAGIC:  # a light commit's journal (1.2): not damage
            count = struct.unpack("<I", source.read(pos + 4, 4))[0] if size - pos >= 16 else 0
            head = source.read(pos, min(size - pos, max_journal_length(count), MAX_TAIL_BYTES)) if count else b""
            length = len_of_journal(head, 0) if head else None
            if length is not None and length <= len(head):
                try:
                    parse_journal(head[:length])
                    pos = result.end = pos + length
                    continue
                except FormatError:
                    pass
        if not resync:
            break
        nxt = _next_magic(source, pos + 1, size)
        if nxt is None:
            break
        if not (magic in (INDEX_MAGIC, COMPRESSED_MAGIC) and _segment_length(source, pos, size) == nxt - pos):
            result.damaged.append((pos, nxt))  # (an index segment of a 1.1 commit is not damage)
        pos = nxt
    return result


# --- what the file claims was committed ------------------------------------------------------------
@dataclass(frozen=True)
class Claim:
    """A commit the file says was made: a header slot, or an intact footer found anywhere in the file.

    ``at`` is where its footer is in the file (for a slot, where the slot says); bytes inserted into or
    deleted from the file before it move a footer away from the offset it names (``at !=
    commit.footer_offset``)."""

    commit: Commit
    at: int


def _find_footers(source: ByteSource, size: int) -> list[Claim]:
    """Every intact footer in the file (both magics and its CRC hold, a version this reader knows)."""
    found = []
    pos = HEADER_SIZE
    while pos + FOOTER_SIZE <= size:
        block = source.read(pos, min(_SCAN_CHUNK + len(FOOTER_MAGIC) - 1, size - pos))  # a magic across chunks
        i = block.find(FOOTER_MAGIC)
        while i >= 0 and pos + i + FOOTER_SIZE <= size:
            raw = block[i: i + FOOTER_SIZE]
            if len(raw) < FOOTER_SIZE:
                raw = source.read(pos + i, FOOTER_SIZE)
            if is_footer(raw):
                try:
                    found.append(Claim(parse_footer(raw), pos + i))
                except FormatError:  # a footer of a version or with fields this reader does not know
                    pass
            i = block.find(FOOTER_MAGIC, i + 1)
        pos += _SCAN_CHUNK
    return found


def find_claims(source: ByteSource, header: bytes) -> list[Claim]:
    """Every commit the file claims (valid header slots and intact footers), newest first, each once."""
    size = source.size()
    claims: dict[Commit, int] = {}
    for cl in _find_footers(source, size):  # a footer where its commit says it is wins over a moved copy
        if claims.get(cl.commit) != cl.commit.footer_offset:
            claims[cl.commit] = cl.at
    for off in SLOT_OFFSETS:
        c = parse_slot(header[off: off + SLOT_SIZE])
        if c is not None:
            claims.setdefault(c, c.footer_offset)
    return sorted((Claim(c, at) for c, at in claims.items()), key=lambda cl: -cl.commit.generation)


@dataclass
class ClaimedKeys:
    """What a claimed commit's index still tells: the entry of each key it names, as far as it can be read.

    A segmented index is read newest segment first and only up to its first damaged segment, so every
    entry read is the commit's own (a damaged segment could hold a newer entry for a key an older one
    names).  ``complete``: every one of the commit's scenes was read."""

    claim: Claim
    entries: list[IndexEntry]
    complete: bool
    segments: list[tuple[int, int]] = field(default_factory=list)  # [start, end) of its older index segments


def read_claim(source: ByteSource, claim: Claim) -> ClaimedKeys | None:
    """What the index of a claimed commit names, read where it is: at the offsets the commit names, or moved
    as far as its footer moved (bytes inserted or deleted before it).  A moved index is read in the
    commit's own coordinates (its entries' offsets may be stale): it names the keys the commit held and
    each one's payload length and CRC, which is what a repair needs to know what was lost.  None when not
    even the commit's own index block verifies."""
    c, size = claim.commit, source.size()
    best: ClaimedKeys | None = None
    if c.light:
        return _read_light_claim(source, claim)
    for delta in dict.fromkeys((0, claim.at - c.footer_offset)):
        start = c.index_offset + delta
        if start < HEADER_SIZE or start + c.index_length > size:
            continue
        block = source.read(start, c.index_length)
        if crc32(block) != c.index_crc32:
            continue
        try:
            if not c.segmented:
                view = IndexView([ArchiveIndex.parse(block, c)])
            else:
                refs = parse_manifest(block, c)
                segments = [ArchiveIndex.parse_unchecked(segment_block(block[manifest_length(len(refs)):], refs[0]),
                                                         refs[0].offset, refs[0].count, prefix=True)]
                where = [(r.offset + d, r.end + d) for r in refs[1:] for d in dict.fromkeys((0, delta))]
                for r in refs[1:]:  # an older segment may lie before or after the shift
                    raw = next((b for d in dict.fromkeys((0, delta)) if r.offset + d >= HEADER_SIZE
                                and r.offset + d + r.length <= size
                                and crc32(b := source.read(r.offset + d, r.length)) == r.crc32), None)
                    if raw is None:
                        break
                    segments.append(ArchiveIndex.parse_unchecked(segment_block(raw, r), r.offset, r.count, prefix=True))
                view = IndexView(segments)
        except FormatError:
            continue
        found = ClaimedKeys(claim, list(view.entries()), len(view) == c.scene_count, where if c.segmented else [])
        if best is None or len(found.entries) > len(best.entries):
            best = found
        if found.complete:
            break
    return best


def _journal_chain(read: Callable[[int, int], bytes], tail_start: int, footer: int
                   ) -> tuple[list[list[IndexEntry]], list[tuple[int, int]], bool]:
    """Walk a light commit's journals back from its footer (each ends right before its commit's footer
    and names where its commit's frames start, right after the previous footer), stopping at the first
    that does not verify.  Returns (their entries, newest journal first: certain to be this commit's, since
    no newer journal is missing; the [start, end) of each; whether the walk reached the full commit's
    footer, so that every journal of the tail was read)."""
    entries_read: list[list[IndexEntry]] = []
    spans: list[tuple[int, int]] = []
    end = footer
    while end - 8 >= tail_start:
        length = journal_length_at_end(read(end - 8, 8))
        if length is None or length > end - tail_start:
            break
        try:
            start_of_commit, entries = parse_journal(read(end - length, length))
        except FormatError:
            break
        if entries[-1].offset + entries[-1].length != end - length:  # its frames end where it starts
            break
        spans.append((end - length, end))
        entries_read.append(entries)
        if start_of_commit == tail_start + FOOTER_SIZE:  # the first light commit after the full one
            return entries_read, spans, True
        end = start_of_commit - FOOTER_SIZE  # the previous light commit's journal ends at its footer
    return entries_read, spans, False


def _read_light_claim(source: ByteSource, claim: Claim) -> ClaimedKeys | None:
    """What a light commit (1.2) names: the full commit's index it names and its tail, read where they are
    or moved with its footer.  When the tail does not parse (a damaged frame header, bytes inserted into a
    record), its journals, walked back from the footer, name the records committed there, each with its
    payload's offset, length and CRC; the index it names may lie where it says while the tail moved."""
    c, size = claim.commit, source.size()
    deltas = list(dict.fromkeys((0, claim.at - c.footer_offset)))

    def reader(d: int) -> Callable[[int, int], bytes]:
        return lambda off, n: source.read(off + d, n) if off + d >= HEADER_SIZE and off + d + n <= size else b""

    def index_bytes(d: int, view: IndexView) -> list[tuple[int, int]]:  # the index block and older segments
        return [(c.index_offset + d, c.index_offset + c.index_length + d)] + [
            (r.offset + e, r.end + e) for r in view.refs for e in deltas]

    named: IndexView | None = None
    where: list[tuple[int, int]] = []
    for load in (load_index, load_named):  # the whole commit, else the index it names (its tail damaged)
        for d in deltas:
            try:
                view = load(reader(d), c)
            except FormatError:
                continue
            if load is load_index:
                return ClaimedKeys(claim, list(view.entries()), len(view) == c.scene_count, index_bytes(d, view))
            named, where = view, index_bytes(d, view)
            break
    tail_start = c.index_offset + c.index_length
    best: ClaimedKeys | None = None
    for d in reversed(deltas):  # the journals lie before the footer: moved with it first
        journaled, spans, whole = _journal_chain(reader(d), tail_start, c.footer_offset)
        whole = whole and named is not None  # every journal and the index they follow were read
        found = {e.key: e for e in named.entries()} if whole and named is not None else {}
        for entries in reversed(journaled):
            found.update((e.key, e) for e in entries)
        told = ClaimedKeys(claim, sorted(found.values(), key=lambda e: e.key.encode()),
                           whole and len(found) == c.scene_count, where + [(a + d, b + d) for a, b in spans])
        if best is None or (told.complete, len(told.entries)) > (best.complete, len(best.entries)):
            best = told
    return best if best is not None and (best.entries or best.complete) else None


# --- planning ---------------------------------------------------------------------------------------
@dataclass
class RepairPlan:
    """What a repair will do; nothing has been written when this exists."""

    size: int
    base: Commit | None  # the newest commit whose index verifies where it names it (None: none does)
    entries: dict[str, IndexEntry]  # records kept in place (base entries that verify + later records)
    copies: dict[str, IndexEntry]  # base entries whose payload verifies but whose frame is damaged
    recovered: list[str]  # keys taken from records after the base commit
    lost: list[str]  # committed keys the repaired archive will not hold (record damaged or missing)
    cut: int  # the file is truncated to this length before the new commit is appended
    damaged_bytes: int  # damaged bytes skipped between valid structures (left in place)
    new_generation: int  # 1 when ``rewrite``
    preamble_ok: bool
    full_scan: bool  # the whole file was walked (asked for, or because of ``scan_reason``)
    lost_commit: Commit | None = None  # the newest claimed commit, when it is newer than the base
    base_footer_ok: bool = True  # the base commit's own footer is intact and ends the file
    segmented: bool = False  # the preamble says commits may use segmented indexes (version 1.1)
    view: IndexView | None = None  # the base commit's index
    lost_unnamed: int = 0  # committed scenes lost whose keys no readable index names
    uncertain: bool = False  # a newer commit's index is gone and some of its records are damaged or cut off
    reindexed: list[str] = field(default_factory=list)  # base entries pointing at the wrong bytes, found elsewhere
    scan_reason: str | None = None  # why a repair not asked for a full scan made one
    rewrite: bool = False  # the generation counter is spent: the repaired archive is written as a new file
    v12: bool = False  # the preamble says commits may be light and segments compressed (version 1.2)

    @property
    def needs_commit(self) -> bool:
        return bool(self.base is None or self.recovered or self.copies or self.lost or self.reindexed
                    or self.lost_commit is not None or self.cut != self.size or not self.preamble_ok
                    or not self.base_footer_ok)


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


def _payload_at(source: ByteSource, e: IndexEntry, claim: Claim) -> IndexEntry | None:
    """``e``'s payload where the claim's index says it is, or moved as far as its footer was, when its CRC
    holds there (its frame may be damaged: then the scan found no record for it)."""
    size = source.size()
    for delta in dict.fromkeys((0, claim.at - claim.commit.footer_offset)):
        offset = e.offset + delta
        if offset >= HEADER_SIZE + FRAME_HEADER_SIZE and offset + e.length <= size and \
                _payload_crc(source, offset, e.length) == e.crc32:
            return IndexEntry(e.key, offset, e.length, e.crc32, e.summary_bytes)
    return None


def _records_damaged(scan: ScanResult, start: int, end: int, index_bytes: list[tuple[int, int]]) -> bool:
    """Whether bytes in [start, end) that are not the index or footer of a claimed commit (``index_bytes``)
    are damaged or missing, so they may have held a record."""
    gaps = [(max(a, start), min(b, end)) for a, b in scan.damaged if a < end and b > start]
    if scan.end < end:
        gaps.append((max(scan.end, start), end))
    for lo, hi in index_bytes:
        gaps = [g for a, b in gaps for g in ((a, min(b, lo)), (max(a, hi), b)) if g[0] < g[1]]
    return bool(gaps)


def _committed_damage(source: ByteSource, base: Commit, index: IndexView, claims: list[Claim]) -> str | None:
    """Why the last commit cannot simply be kept (a default repair then scans the whole file), or None."""
    bad = [e.key for e in index.entries()
           if _payload_crc(source, e.offset, e.length) != e.crc32 or not _frame_intact(source, e)]
    if bad:
        shown = ", ".join(bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
        return (f"{len(bad)} record{'s' if len(bad) != 1 else ''} of the last commit (generation "
                f"{base.generation}) fail{'' if len(bad) != 1 else 's'} {'their' if len(bad) != 1 else 'its'} "
                f"checksum or frame check: {shown}")
    newer = [cl.commit for cl in claims if cl.commit.generation > base.generation]
    if newer:
        return (f"the file holds a newer commit (generation {newer[0].generation}, {newer[0].scene_count} "
                f"scenes) than the last one it ends with (generation {base.generation})")
    return None


def plan_repair(source: ByteSource, *, full_scan: bool, base: Commit | None = None,
                verify_committed: bool = False, scan_reason: str | None = None) -> RepairPlan:
    """Plan a repair (see the module docstring).

    Without ``full_scan`` the given ``base`` (the last commit) is kept and only the bytes after it are
    walked.  With ``verify_committed`` (what ``vt4d repair`` does) every record of that commit is checked
    first, and every commit the file claims (header slots, intact footers anywhere): if a record fails,
    or a claimed commit is newer than the base, the repair becomes a full scan (``scan_reason`` says why).
    With ``full_scan`` the whole file is walked, the newest commit whose index verifies becomes the base
    and every record it names is checked; what the newest claimed commit whose index can still be read
    names is kept in its version or reported ``lost``, and the scenes of a newer commit whose index is
    gone count as ``lost_unnamed`` (``uncertain`` when records written for it are damaged too).
    """
    size = source.size()
    header = source.read(0, min(size, HEADER_SIZE))
    try:
        flags = parse_preamble(header)
        segmented, v12 = bool(flags & FLAG_SEGMENTED), bool(flags & FLAG_V12)
        preamble_ok = len(header) == HEADER_SIZE
    except FormatError:
        preamble_ok = segmented = v12 = False
    claims = find_claims(source, header) if verify_committed or full_scan or base is None else []
    if not full_scan and base is not None:
        index = _load_index(source, base, size)
        why = None
        if index is None:
            if not verify_committed:
                raise ArchiveError(f"{source.name}: the last commit's index does not verify; use a full scan")
            why = f"the last commit's index (generation {base.generation}) does not verify"
        elif verify_committed:
            why = _committed_damage(source, base, index, claims)
        if why is not None:
            return plan_repair(source, full_scan=True, verify_committed=True, scan_reason=why)
        assert index is not None
        plan = _plan(source, size, base, index, {e.key: e for e in index.entries()}, {}, [], [],
                     scan_records(source, base.end, resync=True), claims, preamble_ok, segmented, full_scan=False,
                     scan_reason=None, known=[ClaimedKeys(Claim(base, base.footer_offset), [], True)])
        plan.v12 = v12
        return plan
    scan = scan_records(source, HEADER_SIZE, resync=True)
    base, index = None, None
    known: list[ClaimedKeys] = []  # newest first, down to the newest commit whose index is read whole
    budget = source.bytes_read + 2 * size + _SCAN_CHUNK  # a file claiming more than it holds is not read forever
    for cl in claims:
        if source.bytes_read > budget:
            break  # the older claims count as unreadable: what they held is reported, never assumed kept
        view = _load_index(source, cl.commit, size)
        told = ClaimedKeys(cl, [], True) if view is not None else read_claim(source, cl)
        if told is not None and (not known or not known[-1].complete):
            known.append(told)
        if view is not None:  # the base: the newest commit whose index verifies where it names it
            base, index = cl.commit, view
            break
    if not preamble_ok and base is None and not scan.records and not claims:
        raise ArchiveError(f"{source.name}: no archive preamble, commit or record frame found; "
                           "not an archive (nothing was changed)")
    frames = {(r.key, r.length, r.crc32): r for r in scan.records}  # records that verify, wherever they are
    entries: dict[str, IndexEntry] = {}
    copies: dict[str, IndexEntry] = {}
    lost: list[str] = []
    reindexed: list[str] = []
    for e in index.entries() if index is not None else ():  # every record the base names is checked
        if _payload_crc(source, e.offset, e.length) == e.crc32:
            (entries if _frame_intact(source, e) else copies)[e.key] = e
        elif (moved_record := frames.get((e.key, e.length, e.crc32))) is not None:
            entries[e.key] = moved_record  # the entry's offset is wrong; its record verifies elsewhere
            reindexed.append(e.key)
        else:
            lost.append(e.key)
    plan = _plan(source, size, base, index, entries, copies, lost, reindexed, scan, claims, preamble_ok, segmented,
                 full_scan=True, scan_reason=scan_reason, known=known, frames=frames)
    plan.v12 = v12
    return plan


def _own_index(c: Commit) -> int:
    """Bytes of index a commit wrote right before its footer (a light commit writes none)."""
    return 0 if c.light else c.index_length


def _plan(source: ByteSource, size: int, base: Commit | None, index: IndexView | None,
          entries: dict[str, IndexEntry], copies: dict[str, IndexEntry], lost: list[str], reindexed: list[str],
          scan: ScanResult, claims: list[Claim], preamble_ok: bool, segmented: bool, *, full_scan: bool,
          scan_reason: str | None, known: list[ClaimedKeys],
          frames: dict[tuple[str, int, int], IndexEntry] | None = None) -> RepairPlan:
    """The rest of a plan once its base is chosen: records after the base; what the claimed commits whose
    index can be read (``known``, newest first, ending at the newest one read whole, whose entries a
    caller may leave out when it is the base: its records were checked) say must survive; what was
    lost; the cut; the generation."""
    recovered: dict[str, None] = {}
    after = base.end if base is not None else HEADER_SIZE
    for r in scan.records:
        if r.offset > after:
            entries[r.key] = r
            copies.pop(r.key, None)
            recovered.pop(r.key, None)
            recovered[r.key] = None
    lost = [k for k in lost if k not in entries]
    named: set[str] = set(entries) | set(copies) | set(lost) if index is not None else set()
    seen: set[str] = set()
    for told in known:  # each key in the version its newest readable commit names
        end = told.claim.at + FOOTER_SIZE
        for w in told.entries:
            if w.key in seen:
                continue
            seen.add(w.key)
            have = entries.get(w.key) or copies.get(w.key)
            if have is not None and ((have.length, have.crc32) == (w.length, w.crc32) or have.offset > end):
                continue  # that version, or one written after that commit
            found = (frames or {}).get((w.key, w.length, w.crc32)) or _payload_at(source, w, told.claim)
            if found is not None:
                keep, drop = (entries, copies) if _frame_intact(source, found) else (copies, entries)
                keep[w.key] = found
                drop.pop(w.key, None)
                lost = [k for k in lost if k != w.key]
                continue
            for d in (entries, copies):  # never an older version instead of the committed one
                d.pop(w.key, None)
            recovered.pop(w.key, None)
            lost += [w.key] if w.key not in lost else []
    whole = known[-1] if known and known[-1].complete else None  # the newest commit whose keys are all known
    whole_end = HEADER_SIZE if whole is None else whole.claim.at + FOOTER_SIZE
    keys = seen | (named if whole is not None and whole.claim.commit == base else set())
    keys |= {r.key for r in scan.records if r.offset > whole_end}
    floor = -1 if whole is None else whole.claim.commit.generation
    unread = [cl for cl in claims if cl.commit.generation > floor]  # newer, their index gone or part of it
    lost_unnamed = max([cl.commit.scene_count - len(keys) for cl in unread] + [0])
    uncertain = False
    if unread:  # their records lie between that commit and the newest one's index: are any damaged?
        index_bytes = [(cl.at - _own_index(cl.commit), cl.at + FOOTER_SIZE) for cl in claims]
        index_bytes += [r for told in known for r in told.segments]
        uncertain = _records_damaged(scan, whole_end, unread[0].at - _own_index(unread[0].commit), index_bytes)
    base_generation = -1 if base is None else base.generation
    lost_commit = next((cl.commit for cl in claims if cl.commit.generation > base_generation), None)
    generations = [cl.commit.generation for cl in claims] + [c.generation for c in scan.commits] + [base_generation]
    new_generation = max(generations) + 1
    rewrite = new_generation > MAX_GENERATION
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
    return RepairPlan(size, base, entries, copies, list(recovered), sorted(lost), cut, damaged,
                      1 if rewrite else new_generation, preamble_ok, full_scan, lost_commit, footer_ok, segmented,
                      index, lost_unnamed, uncertain, reindexed, scan_reason, rewrite)


@dataclass
class RepairReport:
    """What :func:`repair_archive` found and did (or, in a dry run, would do).

    ``complete`` is True only when nothing committed was lost: every scene of the newest commit the file
    claims (an intact footer or header slot) is in the repaired archive, in its committed version or a
    later one.  Otherwise ``lost`` names every lost key, ``lost_unnamed`` counts the lost scenes whose
    keys no readable index names, and ``uncertain`` says that records of a commit whose index is gone are
    damaged (what it held cannot all be checked)."""

    path: str
    last_generation: int | None  # the commit repair started from (None: no commit verified)
    committed: int  # scenes in that commit
    recovered: list[str]  # keys recovered from records after it
    discarded_bytes: int  # torn bytes cut off the end (they held no verifiable record)
    new_generation: int | None  # None when nothing needed doing (or dry run)
    full_scan: bool = False  # the whole file was walked
    lost: list[str] = field(default_factory=list)  # committed keys not in the repaired archive
    copied: list[str] = field(default_factory=list)  # records re-framed because their frame was damaged
    damaged_bytes: int = 0  # damaged bytes between valid structures, left in place
    lost_generation: int | None = None  # the newest claimed commit, when it could not be the base
    lost_scenes: int | None = None  # how many scenes that commit held
    scenes: int = 0  # scenes in the repaired archive
    dry_run: bool = False
    lost_unnamed: int = 0  # committed scenes lost whose keys are unknown (no readable index names them)
    #: the newest commit's index is gone and some of the records written for it are damaged or cut off: a
    #: scene it held may be lost, or recovered in an older version, without a way to tell which
    uncertain: bool = False
    reindexed: list[str] = field(default_factory=list)  # index entries that pointed elsewhere, mended
    scan_reason: str | None = None  # why a repair not asked for a full scan made one
    rewritten: bool = False  # the generation counter was spent: written as a new file from generation 1

    @property
    def unrecoverable(self) -> list[str]:
        """The lost keys (the name of ``lost`` before it also covered records missing from the file)."""
        return self.lost

    @property
    def complete(self) -> bool:
        """True when nothing committed was lost."""
        return not self.lost and not self.lost_unnamed and not self.uncertain

    def to_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "complete": self.complete}
