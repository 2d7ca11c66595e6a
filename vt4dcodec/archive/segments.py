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
"""

from __future__ import annotations

import heapq
import struct
from dataclasses import dataclass
from typing import Callable, Iterator

from ..errors import ArchiveError, LimitExceededError
from .index import ArchiveIndex, IndexChecksumError, IndexEntry
from .layout import (HEADER_SIZE, INDEX_ENTRY_SIZE, INDEX_HEADER_SIZE, MANIFEST_HEADER_SIZE, MANIFEST_MAGIC,
                     MAX_SCENES, MAX_SEGMENTS, SEGMENT_REF_SIZE, Commit, crc32)

__all__ = ["SegmentRef", "IndexView", "manifest_length", "pack_manifest", "parse_manifest", "load_index", "plan_merge", "size_class", "FANOUT"]

FANOUT = 4
_MANIFEST = struct.Struct("<4sIQ16x")
_REF = struct.Struct("<QQQI4x")
assert _MANIFEST.size == MANIFEST_HEADER_SIZE and _REF.size == SEGMENT_REF_SIZE


@dataclass(frozen=True)
class SegmentRef:
    offset: int
    length: int
    count: int
    crc32: int

    @property
    def end(self) -> int:
        return self.offset + self.length


def manifest_length(segments: int) -> int:
    return MANIFEST_HEADER_SIZE + SEGMENT_REF_SIZE * segments


def pack_manifest(refs: list[SegmentRef], scene_count: int) -> bytes:
    if not 1 <= len(refs) <= MAX_SEGMENTS:
        raise ArchiveError(f"a manifest names 1..{MAX_SEGMENTS} segments, not {len(refs)}")
    return _MANIFEST.pack(MANIFEST_MAGIC, len(refs), scene_count) + b"".join(
        _REF.pack(r.offset, r.length, r.count, r.crc32) for r in refs)


def parse_manifest(data: bytes, commit: Commit) -> list[SegmentRef]:
    """Check a commit's index block (manifest + newest segment) against the commit: CRC, counts,
    segment bounds and order.  Returns the segment references, newest first."""
    if len(data) != commit.index_length:
        raise ArchiveError(f"index block is {len(data)} bytes, commit says {commit.index_length}")
    if crc32(data) != commit.index_crc32:
        raise IndexChecksumError("archive segment manifest checksum mismatch (corrupted index)")
    magic, m, count = _MANIFEST.unpack_from(data)
    if magic != MANIFEST_MAGIC:
        raise ArchiveError("segmented commit's index block does not start with a manifest (bad magic)")
    if not 1 <= m <= MAX_SEGMENTS or manifest_length(m) + INDEX_HEADER_SIZE > len(data):
        raise ArchiveError(f"manifest segment count {m} disagrees with its index block of {len(data)} bytes")
    if count != commit.scene_count:
        raise ArchiveError(f"manifest holds {count} scenes, its commit says {commit.scene_count}")
    refs = []
    limit = commit.index_offset  # each older segment ends before the one listed ahead of it starts
    for k in range(m):
        off, length, n, crc = _REF.unpack_from(data, MANIFEST_HEADER_SIZE + k * SEGMENT_REF_SIZE)
        if n > MAX_SCENES:
            raise LimitExceededError(f"index segment claims {n} scenes (limit {MAX_SCENES})")
        if length < INDEX_HEADER_SIZE + INDEX_ENTRY_SIZE * n:
            raise ArchiveError(f"index segment of {length} bytes cannot hold {n} scenes")
        if k == 0:
            if (off, length) != (commit.index_offset + manifest_length(m), len(data) - manifest_length(m)):
                raise ArchiveError("the newest index segment must follow its manifest and end at the footer")
        elif off < HEADER_SIZE or off > limit or length > limit - off:
            raise ArchiveError("index segment lies outside the file area before its manifest "
                               "(segments must be listed newest first and must not overlap)")
        else:
            limit = off
        refs.append(SegmentRef(off, length, n, crc))
    return refs


class IndexView:
    """The scenes of one commit: one index, or the newest-wins union of a manifest's segments.

    Lookups search the segments newest first (each a binary search).  Opening marks the entries
    newer segments shadow, costing O(newer keys x log) rather than a pass over every entry.
    """

    def __init__(self, segments: list[ArchiveIndex], expected: int | None = None,
                 refs: list[SegmentRef] | None = None):
        self.segments = segments
        self.refs: list[SegmentRef] = refs or []  # a segmented commit's manifest (empty: one whole index)
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
    read per older segment."""
    data = read(commit.index_offset, commit.index_length)
    if not commit.segmented:
        return IndexView([ArchiveIndex.parse(data, commit)])
    refs = parse_manifest(data, commit)
    segments = []
    for k, r in enumerate(refs):
        raw = data[manifest_length(len(refs)):] if k == 0 else read(r.offset, r.length)
        if crc32(raw) != r.crc32:
            raise IndexChecksumError(f"index segment at offset {r.offset} fails its checksum (corrupted index)")
        segments.append(ArchiveIndex.parse_unchecked(raw, r.offset, r.count, prefix=True))
    return IndexView(segments, commit.scene_count, refs)


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
