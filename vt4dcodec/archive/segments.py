"""Segmented indexes (archive version 1.1): a commit names up to 64 index segments instead of
rewriting one whole index, so a commit costs what it changed and the file grows with it.

A **segment** is an index block exactly as in version 1.0 (``V4AI``, FORMAT.md Part II 5.1-5.4),
holding the entries of some keys.  The index block of a commit with required flag bit 0 is a
**manifest** immediately followed by the commit's own (newest) segment, so one read fetches both::

    0   4  magic "V4AM"
    4   4  u32 segment count m (1..64)
    8   8  u64 scene count (distinct keys over all segments; equals the commit's)
    16  16 reserved (zero)
    32  m x 32: segment references, newest first:
            u64 offset, u64 length, u64 entry count, u32 CRC-32 of the segment, u32 reserved (zero)

A key's entry is the one in the newest segment that holds it.  Reference 0 is the segment right
after the manifest (it ends where the footer starts); the others lie before the manifest, each
before the one listed ahead of it, without overlapping.  Opening costs the header, the footer, the
index block and one read per older segment.

Writers merge segments *tiered* (``plan_merge``): a commit writes one segment with its changed keys;
while ``FANOUT - 1`` (3) other segments are of the new segment's size class (``count`` in
``[4^L, 4^(L+1))``), they are folded into it.  A folded segment may be any of the older ones, not only
the newest: the new segment holds each of its keys' current entry, so it shadows them all.  Every
commit so names at most 3 segments per size class, for any sequence of commit sizes, and an entry is
rewritten at most floor(log4(n)) times when commits add new keys.

Version 1.2 (commit flag bit 1) adds two things (FORMAT.md Part II 5.6, 5.7): a segment may be stored
**compressed** (``V4AZ`` header + one zstd frame of the index block; the reference's last field says so),
and a commit may be **light**: it names an earlier full commit's index block, and the frames between that
block and its own footer (the *tail*, at most 256 KiB) are its newest entries, read with the index block in
one read.
"""

from __future__ import annotations

import heapq
import struct
from dataclasses import dataclass
from typing import Callable, Iterator

import zstandard

from ..errors import ArchiveError, FormatError, LimitExceededError, TruncatedError
from .index import ArchiveIndex, IndexChecksumError, IndexEntry
from .layout import (FOOTER_MAGIC, FOOTER_SIZE, FRAME_HEADER_SIZE, FRAME_MAGIC, HEADER_SIZE, INDEX_ENTRY_SIZE,
                     INDEX_HEADER_SIZE, MANIFEST_HEADER_SIZE, MANIFEST_MAGIC, MAX_SCENES, MAX_SEGMENTS,
                     SEGMENT_REF_SIZE, Commit, check_key, crc32, frame_meta_crc, is_footer, parse_frame_header)

__all__ = ["SegmentRef", "IndexView", "manifest_length", "pack_manifest", "parse_manifest", "load_index", "plan_merge",
           "size_class", "FANOUT", "compress_segment", "segment_block", "parse_tail", "COMPRESSED_MAGIC",
           "SEGMENT_COMPRESSED", "MAX_COMPRESSION", "JOURNAL_MAGIC", "pack_journal", "parse_journal", "journal_length_at_end", "len_of_journal",
           "load_named", "max_journal_length"]

FANOUT = 4
_MANIFEST = struct.Struct("<4sIQ16x")
_REF = struct.Struct("<QQQII")
assert _MANIFEST.size == MANIFEST_HEADER_SIZE and _REF.size == SEGMENT_REF_SIZE

COMPRESSED_MAGIC = b"V4AZ"
SEGMENT_COMPRESSED = 0x1  #: segment reference flag (1.2 commits): the segment is a ``V4AZ`` block
MAX_COMPRESSION = 64  #: a compressed segment's raw length is at most 64 x its stored zstd bytes
COMPRESSED_HEADER_SIZE = 32
_ZHEAD = struct.Struct("<4s4xQQ8x")  # magic, raw length R, stored length Z
assert _ZHEAD.size == COMPRESSED_HEADER_SIZE
_ZSTD_LEVEL = 3  # sorted index entries: ~12 bytes each at level 3 (level 19 gains ~5 % for 10x the time)


@dataclass(frozen=True)
class SegmentRef:
    offset: int
    length: int
    count: int
    crc32: int
    flags: int = 0  #: SEGMENT_COMPRESSED (1.2)

    @property
    def end(self) -> int:
        return self.offset + self.length

    @property
    def compressed(self) -> bool:
        return bool(self.flags & SEGMENT_COMPRESSED)


def compress_segment(block: bytes) -> tuple[bytes, int]:
    """The stored form of an index block and its reference flags: a ``V4AZ`` block when that is smaller
    (and within the 64x ratio readers accept), else the block itself (FORMAT.md Part II 5.6)."""
    z = zstandard.ZstdCompressor(level=_ZSTD_LEVEL, write_content_size=True).compress(block)
    if COMPRESSED_HEADER_SIZE + len(z) >= len(block) or len(block) > MAX_COMPRESSION * len(z):
        return block, 0
    return _ZHEAD.pack(COMPRESSED_MAGIC, len(block), len(z)) + z, SEGMENT_COMPRESSED


def compressed_length(head: bytes) -> int | None:
    """The stored length (32 + Z) a ``V4AZ`` header declares, or None if ``head`` is not one."""
    if len(head) < COMPRESSED_HEADER_SIZE or head[:4] != COMPRESSED_MAGIC:
        return None
    return COMPRESSED_HEADER_SIZE + int(_ZHEAD.unpack_from(head)[2])


def segment_block(raw: bytes, ref: SegmentRef) -> bytes:
    """The index block of a segment's stored bytes (CRC already checked): the bytes themselves, or a
    ``V4AZ`` block decompressed after its bounds are checked (FORMAT.md Part II 5.6)."""
    if not ref.compressed:
        return raw
    if len(raw) < COMPRESSED_HEADER_SIZE or raw[:4] != COMPRESSED_MAGIC:
        raise ArchiveError(f"index segment at offset {ref.offset} is flagged compressed but is no V4AZ block")
    _magic, r, z = _ZHEAD.unpack_from(raw)
    if COMPRESSED_HEADER_SIZE + z != len(raw):
        raise ArchiveError(f"compressed index segment declares {z} stored bytes, its reference {len(raw) - 32}")
    if r < INDEX_HEADER_SIZE + INDEX_ENTRY_SIZE * ref.count:
        raise ArchiveError(f"compressed index segment of {r} raw bytes cannot hold {ref.count} scenes")
    if r > MAX_COMPRESSION * z:
        raise LimitExceededError(f"compressed index segment expands {z} bytes to {r} (over {MAX_COMPRESSION}x)")
    frame = raw[COMPRESSED_HEADER_SIZE:]
    try:
        params = zstandard.get_frame_parameters(frame)
        if params.content_size != r or params.dict_id:
            raise ArchiveError("compressed index segment's zstd frame must declare its raw length and no dictionary")
        d = zstandard.ZstdDecompressor().decompressobj()
        out = d.decompress(frame)
        complete = d.eof and not d.unused_data
    except zstandard.ZstdError as exc:
        raise ArchiveError(f"compressed index segment does not decode: {exc}") from None
    if not complete or len(out) != r:
        raise ArchiveError("compressed index segment is not exactly one zstd frame of its raw length")
    return out


JOURNAL_MAGIC = b"V4AJ"
_JHEAD = struct.Struct("<4sIQ")  # magic, entry count, commit start (where the commit's first frame is)
_JENTRY = struct.Struct("<IIQ")  # after u16 key length + key: summary length, payload CRC, payload length
_JEND = struct.Struct("<II")  # block length, CRC-32 of every byte before it
MIN_JOURNAL = _JHEAD.size + 2 + 1 + _JENTRY.size + _JEND.size  # one entry with a 1-byte key


def pack_journal(commit_start: int, frames: list[IndexEntry]) -> bytes:
    """A light commit's journal: the key, summary length, payload CRC and length of each frame it wrote
    (contiguous from ``commit_start``), so a record whose frame header is damaged can still be named and
    found, and the journals of a tail chain back to the full commit (FORMAT.md Part II 5.7)."""
    body = b"".join(struct.pack("<H", len(k := e.key.encode())) + k
                    + _JENTRY.pack(len(e.summary_bytes), e.crc32, e.length) for e in frames)
    block = _JHEAD.pack(JOURNAL_MAGIC, len(frames), commit_start) + body
    block += struct.pack("<I", len(block) + _JEND.size)
    return block + struct.pack("<I", crc32(block))


def parse_journal(block: bytes) -> tuple[int, list[IndexEntry]]:
    """A whole journal block -> (commit start, its frames' entries with the offsets they imply, summaries
    left empty).  Its CRC is checked (IndexChecksumError); the entries end where the block starts when the
    block follows its frames (the caller checks)."""
    if len(block) < MIN_JOURNAL or block[:4] != JOURNAL_MAGIC:
        raise ArchiveError("not a light commit journal")
    length, crc = _JEND.unpack_from(block, len(block) - _JEND.size)
    if length != len(block):
        raise ArchiveError("light commit journal length disagrees with its block")
    if crc32(block[:-4]) != crc:
        raise IndexChecksumError("light commit journal fails its checksum (corrupted index)")
    _magic, n, commit_start = _JHEAD.unpack_from(block)
    out, pos, at = [], _JHEAD.size, commit_start
    stop = len(block) - _JEND.size
    for _ in range(n):
        if pos + 2 > stop:
            raise ArchiveError("light commit journal entries run past the block")
        (k,) = struct.unpack_from("<H", block, pos)
        if pos + 2 + k + _JENTRY.size > stop:
            raise ArchiveError("light commit journal entries run past the block")
        try:
            key = bytes(block[pos + 2: pos + 2 + k]).decode("utf-8")
        except UnicodeDecodeError:
            raise ArchiveError("light commit journal key is not UTF-8") from None
        check_key(key)
        slen, c, plen = _JENTRY.unpack_from(block, pos + 2 + k)
        offset = at + FRAME_HEADER_SIZE + k + slen
        out.append(IndexEntry(key, offset, plen, c, b""))
        at = offset + plen
        pos += 2 + k + _JENTRY.size
    if pos != stop or not n:
        raise ArchiveError("light commit journal length disagrees with its entries")
    return commit_start, out


def journal_length_at_end(trailer: bytes) -> int | None:
    """The block length stored in the last 8 bytes of a journal (``trailer``)."""
    return int(_JEND.unpack_from(trailer)[0]) if len(trailer) == _JEND.size else None


def len_of_journal(data: bytes, pos: int) -> int:
    """A journal's length, found by walking its entries from its header at ``pos`` (FORMAT.md Part II 5.7);
    more than ``len(data) - pos`` when it runs past ``data``."""
    n = _JHEAD.unpack_from(data, pos)[1]
    q = pos + _JHEAD.size
    for _ in range(n):
        if q + 2 > len(data):
            return len(data) - pos + 1  # runs past: the caller rejects it
        q += 2 + struct.unpack_from("<H", data, q)[0] + _JENTRY.size
    return q + _JEND.size - pos


def max_journal_length(count: int) -> int:
    """The most bytes a journal of ``count`` entries can take (keys of 1,024 bytes)."""
    return _JHEAD.size + count * (2 + 1024 + _JENTRY.size) + _JEND.size


def parse_tail(data: bytes, start: int) -> list[IndexEntry]:
    """The record frames of a light commit's tail (``data``, found at ``start``), in file order
    (FORMAT.md Part II 5.7): footers are skipped, frames must be whole with their meta CRC, and each
    light commit's journal must list exactly the frames written since the item before them."""
    out: list[IndexEntry] = []
    pos, end = 0, len(data)
    since: list[IndexEntry] = []  # frames since the last footer or journal
    last_journal = False
    after_footer = -1  # where the frames after the last footer start (no footer yet: none can be journaled)
    while pos < end:
        last_journal = False
        if data[pos:pos + 8] == FOOTER_MAGIC:
            if not is_footer(data[pos:pos + FOOTER_SIZE]):
                raise ArchiveError(f"light commit's tail holds a damaged footer at offset {start + pos}")
            if since:
                raise ArchiveError(f"frames before the footer at offset {start + pos} are in no journal")
            pos += FOOTER_SIZE
            after_footer = pos
            continue
        if data[pos:pos + 4] == JOURNAL_MAGIC:
            if end - pos < _JHEAD.size + _JEND.size:
                raise ArchiveError(f"light commit journal at offset {start + pos} runs past its tail")
            length = len_of_journal(data, pos)
            if length < MIN_JOURNAL or length > end - pos:
                raise ArchiveError(f"light commit journal at offset {start + pos} runs past its tail")
            commit_start, listed = parse_journal(data[pos:pos + length])
            if commit_start != start + after_footer or \
                    [(e.key, e.offset, e.length, e.crc32) for e in listed] != \
                    [(e.key, e.offset, e.length, e.crc32) for e in since]:
                raise ArchiveError(f"light commit journal at offset {start + pos} does not list the frames before it")
            since, last_journal = [], True
            pos += length
            continue
        if data[pos:pos + 4] != FRAME_MAGIC:
            raise ArchiveError(f"light commit's tail holds neither a record frame nor a footer at offset {start + pos}")
        if end - pos < FRAME_HEADER_SIZE:
            raise ArchiveError(f"record frame at offset {start + pos} runs past its light commit's tail")
        head = data[pos:pos + FRAME_HEADER_SIZE]
        try:
            fh = parse_frame_header(head)
        except FormatError as exc:  # over a limit or unknown flags: a malformed tail (FORMAT.md Part II 5.7)
            raise ArchiveError(f"record frame at offset {start + pos} in a light commit's tail: {exc}") from None
        if fh.total > end - pos:
            raise ArchiveError(f"record frame at offset {start + pos} runs past its light commit's tail")
        key_raw = data[pos + FRAME_HEADER_SIZE: pos + FRAME_HEADER_SIZE + fh.key_len]
        summary = data[pos + FRAME_HEADER_SIZE + fh.key_len: pos + fh.payload_start]
        try:
            key = key_raw.decode("utf-8")
        except UnicodeDecodeError:
            raise ArchiveError(f"record key at offset {start + pos} is not UTF-8") from None
        check_key(key)
        if frame_meta_crc(head, key_raw, summary) != fh.meta_crc32:
            raise IndexChecksumError(f"record frame at offset {start + pos} in a light commit's tail fails its "
                                     "meta checksum (corrupted index)")
        out.append(IndexEntry(key, start + pos + fh.payload_start, fh.payload_len, fh.payload_crc32, bytes(summary)))
        since.append(out[-1])
        pos += fh.total
    if not last_journal:
        raise ArchiveError("a light commit's tail must end with its journal")
    return out


def manifest_length(segments: int) -> int:
    return MANIFEST_HEADER_SIZE + SEGMENT_REF_SIZE * segments


def pack_manifest(refs: list[SegmentRef], scene_count: int) -> bytes:
    if not 1 <= len(refs) <= MAX_SEGMENTS:
        raise ArchiveError(f"a manifest names 1..{MAX_SEGMENTS} segments, not {len(refs)}")
    return _MANIFEST.pack(MANIFEST_MAGIC, len(refs), scene_count) + b"".join(
        _REF.pack(r.offset, r.length, r.count, r.crc32, r.flags) for r in refs)


def parse_manifest(data: bytes, commit: Commit) -> list[SegmentRef]:
    """Check a commit's index block (manifest + newest segment) against the commit: CRC, counts,
    segment bounds and order.  Returns the segment references, newest first.  A light commit's
    manifest holds the scene count of the full commit that wrote it (checked by :func:`load_index`)."""
    if len(data) != commit.index_length:
        raise ArchiveError(f"index block is {len(data)} bytes, commit says {commit.index_length}")
    if crc32(data) != commit.index_crc32:
        raise IndexChecksumError("archive segment manifest checksum mismatch (corrupted index)")
    magic, m, count = _MANIFEST.unpack_from(data)
    if magic != MANIFEST_MAGIC:
        raise ArchiveError("segmented commit's index block does not start with a manifest (bad magic)")
    if not 1 <= m <= MAX_SEGMENTS or manifest_length(m) + INDEX_HEADER_SIZE > len(data):
        raise ArchiveError(f"manifest segment count {m} disagrees with its index block of {len(data)} bytes")
    if count != commit.scene_count and not commit.light:
        raise ArchiveError(f"manifest holds {count} scenes, its commit says {commit.scene_count}")
    refs = []
    limit = commit.index_offset  # each older segment ends before the one listed ahead of it starts
    for k in range(m):
        off, length, n, crc, flags = _REF.unpack_from(data, MANIFEST_HEADER_SIZE + k * SEGMENT_REF_SIZE)
        flags = flags if commit.v12 else 0  # reserved before 1.2
        if flags & ~SEGMENT_COMPRESSED:
            raise ArchiveError(f"index segment reference sets unknown flags 0x{flags:08x}")
        if n > MAX_SCENES:
            raise LimitExceededError(f"index segment claims {n} scenes (limit {MAX_SCENES})")
        if length < (COMPRESSED_HEADER_SIZE + 1 if flags else INDEX_HEADER_SIZE + INDEX_ENTRY_SIZE * n):
            raise ArchiveError(f"index segment of {length} bytes cannot hold {n} scenes")
        if k == 0:
            if (off, length) != (commit.index_offset + manifest_length(m), len(data) - manifest_length(m)):
                raise ArchiveError("the newest index segment must follow its manifest and end at the footer")
        elif off < HEADER_SIZE or off > limit or length > limit - off:
            raise ArchiveError("index segment lies outside the file area before its manifest "
                               "(segments must be listed newest first and must not overlap)")
        else:
            limit = off
        refs.append(SegmentRef(off, length, n, crc, flags))
    return refs


def manifest_count(data: bytes) -> int:
    """The scene count field of a (checked) manifest."""
    return int(_MANIFEST.unpack_from(data)[2])


class IndexView:
    """The scenes of one commit: one index, or the newest-wins union of a manifest's segments.

    Lookups search the segments newest first (each a binary search).  Opening marks the entries
    newer segments shadow, costing O(newer keys x log) rather than a pass over every entry.
    """

    def __init__(self, segments: list[ArchiveIndex], expected: int | None = None,
                 refs: list[SegmentRef] | None = None, tail: list[IndexEntry] | None = None):
        self.segments = segments
        self.refs: list[SegmentRef] = refs or []  # a segmented commit's manifest (empty: one whole index)
        #: a light commit's tail frames, in file order (``segments[0]`` is then their newest-wins index)
        self.tail: list[IndexEntry] | None = tail
        self._dead: list[set[int]] = [set() for _ in segments]
        if len(segments) > 1:
            seen: set[bytes] = set()
            for s, seg in enumerate(segments):
                if seen:
                    if len(seen) < len(seg):
                        for k in seen:
                            i = seg.find_bytes(k)
                            if i is not None:
                                self._dead[s].add(i)
                    else:
                        self._dead[s] = {i for i in range(len(seg)) if seg.key_bytes(i) in seen}
                if s + 1 < len(segments):
                    seen.update(seg.key_bytes(i) for i in range(len(seg)))
        self._len = sum(len(seg) - len(d) for seg, d in zip(segments, self._dead))
        if expected is not None and self._len != expected:
            raise ArchiveError(f"index segments hold {self._len} distinct scenes, the commit says {expected}")

    def __len__(self) -> int:
        return self._len

    @property
    def index_segments(self) -> list[ArchiveIndex]:
        """The segments stored in the file (a light commit's tail left out), newest first."""
        return self.segments if self.tail is None else self.segments[1:]

    def with_tail(self, tail: list[IndexEntry], expected: int, end: int) -> "IndexView":
        """This index with a light commit's tail frames (file order: a later frame of a key wins) in front;
        ``end`` is the tail's end (its payloads lie before it).  O(tail x segments x log n): the segments'
        entries are not walked again."""
        latest = {e.key: e for e in tail}
        front = ArchiveIndex.parse_unchecked(ArchiveIndex.build(list(latest.values())), end, None)
        view = IndexView.__new__(IndexView)
        view.segments, view.refs, view.tail = [front, *self.segments], self.refs, tail
        view._dead = [set(), *(set(d) for d in self._dead)]
        added = len(front)
        for key in latest:
            raw = key.encode()
            for s, seg in enumerate(self.segments):
                i = seg.find_bytes(raw)
                if i is not None and i not in self._dead[s]:
                    view._dead[s + 1].add(i)  # the live entry of this key: the tail shadows it
                    added -= 1
                    break
        view._len = self._len + added
        if view._len != expected:
            raise ArchiveError(f"index and tail hold {view._len} distinct scenes, the commit says {expected}")
        return view

    def lookup(self, key: str) -> IndexEntry | None:
        for seg in self.segments:
            i = seg.find(key)
            if i is not None:
                return seg.entry(i)
        return None

    def _live(self, s: int) -> Iterator[int]:
        dead = self._dead[s]
        return (i for i in range(len(self.segments[s])) if i not in dead)

    def entries(self) -> Iterator[IndexEntry]:
        """Live entries sorted by key bytes."""
        if len(self.segments) == 1:
            return self.segments[0].entries()
        streams = [self._stream(s) for s in range(len(self.segments))]
        return (self.segments[s].entry(i) for _, s, i in heapq.merge(*streams))

    def _stream(self, s: int) -> Iterator[tuple[bytes, int, int]]:
        seg = self.segments[s]
        return ((seg.key_bytes(i), s, i) for i in self._live(s))

    def keys(self) -> list[str]:
        if len(self.segments) == 1:
            return self.segments[0].keys()
        return [e.key for e in self.entries()]

    def layout_columns(self) -> tuple[list[tuple[int, int]], list[int], list[int], list[int]]:
        """((segment, position), payload offsets, lengths, CRCs) of live entries sorted by offset."""
        rows: list[tuple[tuple[int, int], int, int, int]] = []
        for s, seg in enumerate(self.segments):
            pos, off, length, crc = seg.layout_columns()
            dead = self._dead[s]
            rows.extend(((s, p), o, n, c) for p, o, n, c in zip(pos, off, length, crc) if p not in dead)
        if len(self.segments) > 1:
            rows.sort(key=lambda r: r[1])
        return [r[0] for r in rows], [r[1] for r in rows], [r[2] for r in rows], [r[3] for r in rows]

    def key_at(self, where: tuple[int, int]) -> str:
        return self.segments[where[0]].key(where[1])

    @property
    def payload_bytes(self) -> int:
        return sum(e.length for e in self.entries()) if len(self.segments) > 1 else self.segments[0].payload_bytes


def load_index(read: Callable[[int, int], bytes], commit: Commit) -> IndexView:
    """The validated index of ``commit``; ``read(offset, length)`` fetches bytes.

    Version 1.0 commits: 1 read.  Segmented commits: 1 read (manifest + newest segment), then one
    read per older segment.  A light commit's tail comes with its index block in the first read."""
    if not commit.light:
        data = read(commit.index_offset, commit.index_length)
        if not commit.segmented:
            return IndexView([ArchiveIndex.parse(data, commit)])
        return _segmented(read, data, commit, commit.scene_count)
    block = read(commit.index_offset, commit.index_length + commit.tail_length)
    if len(block) != commit.index_length + commit.tail_length:
        raise TruncatedError(f"light commit's index and tail are {len(block)} bytes, the commit says "
                             f"{commit.index_length + commit.tail_length}")
    data, tail = block[:commit.index_length], block[commit.index_length:]
    base = load_named(read, commit, data)
    start = commit.index_offset + commit.index_length
    return base.with_tail(parse_tail(tail, start), commit.scene_count, commit.footer_offset)


def load_named(read: Callable[[int, int], bytes], commit: Commit, data: bytes | None = None) -> IndexView:
    """The index a light commit names (the full commit's index block ``data``, read if not given), without
    its tail."""
    if data is None:
        data = read(commit.index_offset, commit.index_length)
    if len(data) != commit.index_length:
        raise TruncatedError(f"index is {len(data)} bytes, commit says {commit.index_length}")
    if crc32(data) != commit.index_crc32:
        raise IndexChecksumError("archive index checksum mismatch (corrupted index)")
    if commit.segmented:
        return _segmented(read, data, commit, None)
    return IndexView([ArchiveIndex.parse_unchecked(data, commit.index_offset, None)])


def _segmented(read: Callable[[int, int], bytes], data: bytes, commit: Commit, expected: int | None) -> IndexView:
    refs = parse_manifest(data, commit)
    segments = []
    for k, r in enumerate(refs):
        raw = data[manifest_length(len(refs)):] if k == 0 else read(r.offset, r.length)
        if crc32(raw) != r.crc32:
            raise IndexChecksumError(f"index segment at offset {r.offset} fails its checksum (corrupted index)")
        segments.append(ArchiveIndex.parse_unchecked(segment_block(raw, r), r.offset, r.count, prefix=True))
    return IndexView(segments, manifest_count(data) if expected is None else expected, refs)


def size_class(count: int) -> int:
    """A segment's size class: ``L`` with ``count`` in ``[4^L, 4^(L+1))``, i.e. floor(log4(count))
    (0 for 0..3 entries).  Four segments of class ``L`` with distinct keys hold at least 4^(L+1)
    entries, so folding them moves their entries up a class."""
    return (max(count, 1).bit_length() - 1) // 2


def plan_merge(counts: list[int], new_count: int,
               merged_count: Callable[[list[int]], int] | None = None) -> list[int]:
    """Which existing segments (indices into ``counts``, their entry counts newest first) a commit
    folds into its new segment of ``new_count`` changed keys, in ascending order.

    While the other segments include ``FANOUT - 1`` (3) or more of the new segment's size class,
    all of those are folded into it (it may so move up a class, and the rule applies again).  If a
    class still holds more than ``FANOUT - 1`` segments afterwards (a file written by another
    writer) or more than ``MAX_SEGMENTS // 2`` segments would remain, everything is folded.  So
    every commit names at most 3 segments per size class, whatever the sequence of commit sizes.

    ``merged_count(indices)`` is the new segment's entry count once those segments are folded in
    (the distinct keys: a replaced key counts once); without it, keys are assumed distinct.
    """
    def count_with(chosen: list[int]) -> int:
        if merged_count is not None:
            return merged_count(chosen)
        return new_count + sum(counts[i] for i in chosen)

    chosen: list[int] = []
    current = new_count
    while True:
        same = [i for i, c in enumerate(counts) if size_class(c) == size_class(current) and i not in chosen]
        if len(same) < FANOUT - 1:
            break
        chosen = sorted(chosen + same)
        current = count_with(chosen)
    rest = [c for i, c in enumerate(counts) if i not in chosen] + [current]
    per_class: dict[int, int] = {}
    for c in rest:
        per_class[size_class(c)] = per_class.get(size_class(c), 0) + 1
    if len(rest) > MAX_SEGMENTS // 2 or max(per_class.values()) > FANOUT - 1:
        return list(range(len(counts)))
    return chosen
