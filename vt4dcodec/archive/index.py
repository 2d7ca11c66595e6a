"""The index block: a sorted fixed-width table (key -> payload offset, length, CRC, summary).

Layout (see FORMAT.md, Part II)::

    0   4  magic "V4AI"
    4   4  u32 entry size (48)
    8   8  u64 count
    16  8  u64 keys blob length
    24  8  u64 summaries blob length
    32  count x 48-byte entries, sorted by key bytes, keys unique
        then the keys blob (UTF-8 keys packed in entry order), then the summaries blob (msgpack maps)

Parsing is O(1) allocation beyond the index bytes themselves (``np.frombuffer`` view) plus one O(n)
validation pass; lookup is a binary search over the key blob (O(log n)).
"""

from __future__ import annotations

import operator
import struct
from dataclasses import dataclass, field
from typing import Any, Iterator, Sequence

import msgpack
import numpy as np

from ..errors import ArchiveError, ChecksumError, LimitExceededError, TruncatedError
from .layout import (FRAME_HEADER_SIZE, HEADER_SIZE, INDEX_ENTRY_SIZE, INDEX_HEADER_SIZE, INDEX_MAGIC,
                     MAX_SCENES, MAX_SUMMARY_BYTES, Commit, check_key, crc32)

__all__ = ["IndexEntry", "ArchiveIndex", "DuplicateKeyError", "OverlappingRecordsError", "IndexChecksumError",
           "encode_summary", "decode_summary"]

ENTRY_DTYPE = np.dtype([
    ("payload_offset", "<u8"), ("payload_length", "<u8"), ("payload_crc32", "<u4"),
    ("key_len", "<u2"), ("flags", "<u2"), ("key_offset", "<u8"), ("summary_offset", "<u8"),
    ("summary_len", "<u4"), ("reserved", "<u4"),
])
assert ENTRY_DTYPE.itemsize == INDEX_ENTRY_SIZE
_INDEX_HEADER = struct.Struct("<4sIQQQ")

#: entry flag bit 0 (index segments of version 1.1 only): the summary is the previous entry's first
#: ``reserved`` bytes followed by the ``summary_len - reserved`` bytes stored at ``summary_offset``
ENTRY_PREFIX = 0x1
PREFIX_RESTART = 16  #: entries 0, 16, 32, ... never use a prefix, so a summary decodes from <= 16
MIN_PREFIX = 8
#: summary fields that differ from scene to scene; a 1.1 writer packs them last so neighbours share
#: the longest prefix (the model fingerprint, encoding, shapes...)
PER_SCENE_FIELDS = ("source_capture_id", "created_utc", "bytes")


def shared_first(summary: dict[str, Any]) -> dict[str, Any]:
    """The same summary with the per-scene fields moved to the end (prefix coding shares more)."""
    return {**{k: v for k, v in summary.items() if k not in PER_SCENE_FIELDS},
            **{k: summary[k] for k in PER_SCENE_FIELDS if k in summary}}


def _common_prefix(a: bytes, b: bytes) -> int:
    n = min(len(a), len(b))
    if a[:n] == b[:n]:
        return n
    lo, hi = 0, n  # a[:lo] == b[:lo], a[:hi + 1] != b[:hi + 1] (slice compares run at C speed)
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if a[:mid] == b[:mid]:
            lo = mid
        else:
            hi = mid - 1
    return lo


class DuplicateKeyError(ArchiveError):
    """Two records of one index (or an append without ``replace=True``) share a key."""


class OverlappingRecordsError(ArchiveError):
    """Two index entries point at overlapping byte ranges."""


def _no_ext(code: int, data: bytes) -> Any:
    raise ArchiveError(f"record summary uses msgpack extension type {code}; not allowed")


def encode_summary(summary: dict[str, Any]) -> bytes:
    """msgpack bytes of a JSON-like summary dict (str keys), bounded by MAX_SUMMARY_BYTES."""
    if not isinstance(summary, dict):
        raise ArchiveError(f"record summary must be a dict, got {type(summary).__name__}")
    try:
        raw: bytes = msgpack.packb(summary, use_bin_type=True, strict_types=False)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ArchiveError(f"record summary is not msgpack-serialisable: {exc}") from None
    if len(raw) > MAX_SUMMARY_BYTES:
        raise LimitExceededError(f"record summary is {len(raw)} bytes (limit {MAX_SUMMARY_BYTES})")
    return raw


def decode_summary(raw: bytes) -> dict[str, Any]:
    """Inverse of :func:`encode_summary`; rejects non-maps, ext types and absurd nesting."""
    try:
        value = msgpack.unpackb(raw, raw=False, strict_map_key=True, ext_hook=_no_ext,
                                use_list=True)
    except ArchiveError:
        raise
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise ArchiveError(f"record summary is not valid msgpack: {exc}") from None
    if not isinstance(value, dict):
        raise ArchiveError("record summary must be a msgpack map")
    return value


@dataclass(frozen=True)
class IndexEntry:
    """One committed scene: its payload (a complete ``.vt4d``) is ``length`` bytes at ``offset``."""

    key: str
    offset: int
    length: int
    crc32: int
    summary_bytes: bytes = field(repr=False, default=b"\x80")

    @property
    def summary(self) -> dict[str, Any]:
        """The stored summary; ``{}`` when the record stores none (FORMAT.md Part II 5.3: its fields are
        then in the record's own header, see ``ArchiveReader.summary``)."""
        return decode_summary(self.summary_bytes) if self.summary_bytes else {}

    @property
    def has_summary(self) -> bool:
        return bool(self.summary_bytes)

    @property
    def frame_offset(self) -> int:
        """Where this record's frame (32-byte header + key + summary + payload) starts."""
        return self.offset - FRAME_HEADER_SIZE - len(self.key.encode()) - len(self.summary_bytes)


class ArchiveIndex:
    """A parsed, validated index block.  Immutable; build new ones with :meth:`build`."""

    def __init__(self, table: np.ndarray, keys_blob: bytes, summaries_blob: bytes | memoryview):
        self._table = table
        self._keys = keys_blob
        self._summaries = summaries_blob
        # Plain-int columns (one O(n) conversion at open) keep each lookup to a few list reads;
        # keys and summaries are packed, so entry i spans [offset[i], offset[i + 1]).
        self._key_bounds = table["key_offset"].tolist() + [len(keys_blob)]
        self._summary_bounds = table["summary_offset"].tolist() + [len(summaries_blob)]
        self._prefixed = bool(len(table)) and bool(np.any(table["flags"] & ENTRY_PREFIX))
        if self._prefixed:
            self._prefix = table["reserved"].tolist()
        self._offsets = table["payload_offset"].tolist()
        self._lengths = table["payload_length"].tolist()
        self._crcs = table["payload_crc32"].tolist()

    # -- construction --------------------------------------------------------------------------
    @staticmethod
    def build(entries: Sequence[IndexEntry], *, prefix: bool = False) -> bytes:
        """Serialise entries (any order; keys must be unique) into index-block bytes.

        ``prefix`` (version 1.1 segments only): store each summary as the length of the prefix it
        shares with the previous entry's plus the rest (entry flag bit 0), restarting every 16."""
        ordered = sorted(entries, key=lambda e: e.key.encode())
        keys = [check_key(e.key) for e in ordered]
        for a, b in zip(keys, keys[1:]):
            if a == b:
                raise DuplicateKeyError(f"duplicate scene key {a.decode()!r} in one index")
        if len(ordered) > MAX_SCENES:
            raise LimitExceededError(f"{len(ordered)} scenes exceed the archive limit {MAX_SCENES}")
        table = np.zeros(len(ordered), dtype=ENTRY_DTYPE)
        key_off = summ_off = 0
        stored = []
        prev = b""
        for i, (e, k) in enumerate(zip(ordered, keys)):
            summ = e.summary_bytes
            p = _common_prefix(prev, summ) if prefix and i % PREFIX_RESTART else 0
            p = p if p >= MIN_PREFIX else 0
            table[i] = (e.offset, e.length, e.crc32, len(k), ENTRY_PREFIX if p else 0, key_off, summ_off,
                        len(summ), p)
            stored.append(summ[p:])
            key_off += len(k)
            summ_off += len(summ) - p
            prev = summ
        head = _INDEX_HEADER.pack(INDEX_MAGIC, INDEX_ENTRY_SIZE, len(ordered), key_off, summ_off)
        return b"".join([head, table.tobytes(), *keys, *stored])

    @classmethod
    def parse(cls, data: bytes, commit: Commit) -> "ArchiveIndex":
        """Validate index bytes against their commit (CRC, counts, bounds, order, overlaps)."""
        if len(data) != commit.index_length:
            raise TruncatedError(f"index is {len(data)} bytes, commit says {commit.index_length}")
        if crc32(data) != commit.index_crc32:
            raise IndexChecksumError("archive index checksum mismatch (corrupted index)")
        return cls.parse_unchecked(data, commit.index_offset, commit.scene_count)

    @classmethod
    def parse_unchecked(cls, data: bytes, index_offset: int, expected_count: int | None, *,
                        prefix: bool = False) -> "ArchiveIndex":
        """Structure checks only (the CRC is the caller's business).  Records must end by ``index_offset``.

        ``prefix``: the block is a version 1.1 segment, whose entries may prefix-code summaries."""
        if len(data) < INDEX_HEADER_SIZE:
            raise TruncatedError("index block shorter than its 32-byte header")
        magic, esize, count, keys_len, summ_len = _INDEX_HEADER.unpack_from(data)
        if magic != INDEX_MAGIC:
            raise ArchiveError("index block has a bad magic")
        if esize != INDEX_ENTRY_SIZE:
            raise ArchiveError(f"index entry size {esize}, expected {INDEX_ENTRY_SIZE}")
        if count > MAX_SCENES:
            raise LimitExceededError(f"index claims {count} scenes (limit {MAX_SCENES})")
        if expected_count is not None and count != expected_count:
            raise ArchiveError(f"index holds {count} scenes, its commit says {expected_count}")
        table_end = INDEX_HEADER_SIZE + count * INDEX_ENTRY_SIZE
        if table_end + keys_len + summ_len != len(data):
            raise ArchiveError(
                f"index block sizes disagree: {count} entries + {keys_len} key bytes + "
                f"{summ_len} summary bytes != {len(data) - INDEX_HEADER_SIZE}"
            )
        table = np.frombuffer(data, dtype=ENTRY_DTYPE, count=count, offset=INDEX_HEADER_SIZE)
        keys_blob = data[table_end: table_end + keys_len]
        summaries_blob = memoryview(data)[table_end + keys_len:]  # no copy: sliced on access
        cls._validate(table, keys_blob, summaries_blob, index_offset, prefix)
        return cls(table, keys_blob, summaries_blob)

    @staticmethod
    def _validate(t: np.ndarray, keys: bytes, summaries: bytes | memoryview, index_offset: int, prefix: bool = False) -> None:
        n = len(t)
        if n == 0:
            return
        flags = t["flags"]
        pref = t["reserved"].astype(np.int64)
        has = (flags & ENTRY_PREFIX) != 0
        if np.any(flags & ~np.uint16(ENTRY_PREFIX if prefix else 0)) or np.any(pref[~has] != 0):
            raise ArchiveError("index entry sets unknown flags")
        slen = t["summary_len"].astype(np.int64)
        if np.any(has):
            prev_len = np.concatenate([[0], slen[:-1]])
            if (np.any(has[::PREFIX_RESTART]) or np.any(pref[has] < 1) or np.any(pref > slen)
                    or np.any(pref > prev_len)):
                raise ArchiveError("index entry's summary prefix is out of range")
        klen = t["key_len"].astype(np.int64)
        if np.any(klen < 1):
            raise ArchiveError("index entry has an empty key")
        expected_koff = np.concatenate([[0], np.cumsum(klen)[:-1]])
        if np.any(t["key_offset"].astype(np.int64) != expected_koff) or int(klen.sum()) != len(keys):
            raise ArchiveError("index keys are not packed in entry order")
        stored = slen - pref
        expected_soff = np.concatenate([[0], np.cumsum(stored)[:-1]])
        if np.any(t["summary_offset"].astype(np.int64) != expected_soff) or int(stored.sum()) != len(summaries):
            raise ArchiveError("index summaries are not packed in entry order")
        if np.any(slen > MAX_SUMMARY_BYTES):
            raise LimitExceededError("index summary exceeds the size limit")
        off = t["payload_offset"]
        length = t["payload_length"]
        # bounds without uint64 overflow: offset >= header + frame, length <= index_offset - offset
        if np.any(off < HEADER_SIZE + FRAME_HEADER_SIZE) or np.any(off > index_offset):
            raise ArchiveError("index entry offset lies outside the record area (past the end?)")
        if np.any(length > np.uint64(index_offset) - off):
            raise ArchiveError("index entry runs past the start of its index (offset + length past the end)")
        if n > 1 and np.all(off[1:] >= off[:-1]):  # written in key order: no sort needed
            so, sl = off.astype(np.int64), length.astype(np.int64)
        else:
            order = np.argsort(off, kind="stable")
            so, sl = off[order].astype(np.int64), length[order].astype(np.int64)
        if n > 1 and np.any(so[1:] < so[:-1] + sl[:-1]):
            raise OverlappingRecordsError("index entries point at overlapping records")
        bounds = expected_koff.tolist() + [len(keys)]
        ks = [keys[a:b] for a, b in zip(bounds, bounds[1:])]
        if not all(map(operator.lt, ks, ks[1:])):  # strictly increasing (C-level comparison)
            i = next(i for i in range(1, n) if ks[i] <= ks[i - 1])
            if ks[i] == ks[i - 1]:
                raise DuplicateKeyError(f"duplicate key {ks[i].decode(errors='replace')!r} in the index")
            raise ArchiveError("index keys are not sorted")
        for k in (ks[0], ks[-1]):  # keys are cheap to check fully; do it on access too
            _decode_key(k)

    # -- queries -----------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._table)

    def key_bytes(self, i: int) -> bytes:
        return self._keys[self._key_bounds[i]: self._key_bounds[i + 1]]

    def key(self, i: int) -> str:
        return _decode_key(self.key_bytes(i))

    def find(self, key: str) -> int | None:
        """Position of ``key`` (binary search over the sorted keys), or None."""
        try:
            target = key.encode("utf-8")
        except (UnicodeEncodeError, AttributeError):
            return None
        return self.find_bytes(target)

    def find_bytes(self, target: bytes) -> int | None:
        """Position of the key with these UTF-8 bytes, or None."""
        lo, hi = 0, len(self._table)
        while lo < hi:
            mid = (lo + hi) // 2
            k = self.key_bytes(mid)
            if k < target:
                lo = mid + 1
            elif k > target:
                hi = mid
            else:
                return mid
        return None

    def summary_bytes(self, i: int) -> bytes:
        stored = bytes(self._summaries[self._summary_bounds[i]: self._summary_bounds[i + 1]])
        if not self._prefixed or not self._prefix[i]:
            return stored
        return self.summary_bytes(i - 1)[: self._prefix[i]] + stored  # at most 15 steps back

    def entry(self, i: int) -> IndexEntry:
        return IndexEntry(self.key(i), self._offsets[i], self._lengths[i], self._crcs[i], self.summary_bytes(i))

    def entries(self) -> Iterator[IndexEntry]:
        return (self.entry(i) for i in range(len(self)))

    def layout_columns(self) -> tuple[list[int], list[int], list[int], list[int]]:
        """(positions, payload offsets, lengths, CRCs) as lists sorted by offset (bulk reads)."""
        order = np.argsort(self._table["payload_offset"], kind="stable")
        t = self._table[order]
        return (order.tolist(), t["payload_offset"].tolist(), t["payload_length"].tolist(),
                t["payload_crc32"].tolist())

    def keys(self) -> list[str]:
        return [self.key(i) for i in range(len(self))]

    @property
    def payload_bytes(self) -> int:
        return int(self._table["payload_length"].sum()) if len(self) else 0


class IndexChecksumError(ArchiveError, ChecksumError):
    """The index bytes do not match the CRC stored in the commit."""


def _decode_key(raw: bytes) -> str:
    try:
        key = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ArchiveError("index key is not valid UTF-8") from None
    check_key(key)
    return key
