"""Read an archive: find the last commit, load its index, fetch records by key.

Opening costs three reads whether or not the file ends with a footer: the 160-byte header (the
preamble is always checked, and its commit slots name the last commit when the tail is not a footer
or reveal a commit cut off by truncation), the 64-byte tail, then the index.  Reading a scene is one read of exactly its payload.
Readers never lock; they see the last state committed before they opened.
"""

from __future__ import annotations

import os
from typing import Any, Iterator

from ..errors import ArchiveError, ChecksumError, FormatError, SceneNotFoundError, TruncatedError
from ..format import Scene, SceneFile, loads, open_scene
from ..format.sections import DEFAULT_MAX_DECODED_BYTES, decoded_budget
from .index import IndexEntry
from .records import summarize_payload
from .layout import (FOOTER_SIZE, HEADER_SIZE, INDEX_HEADER_SIZE, SLOT_OFFSETS, SLOT_SIZE, Commit, crc32,
                     is_footer, parse_footer, parse_preamble, parse_slot)
from .segments import load_index
from .source import ByteSource, open_source

__all__ = ["ArchiveReader", "open_archive", "find_commit", "NoCommitError", "RecordChecksumError",
           "ArchiveTruncatedError", "best_slot", "newest_slot"]

MIN_ARCHIVE_SIZE = HEADER_SIZE + INDEX_HEADER_SIZE + FOOTER_SIZE


class NoCommitError(ArchiveError):
    """Neither the tail nor a header slot holds a valid commit; ``vt4d repair --full-scan`` may help."""


class RecordChecksumError(ArchiveError, ChecksumError):
    """A record's bytes do not match the CRC in the index."""


def best_slot(header: bytes, size: int) -> Commit | None:
    """The valid header slot with the highest generation whose commit lies inside ``size`` bytes."""
    best = None
    for off in SLOT_OFFSETS:
        c = parse_slot(header[off: off + SLOT_SIZE])
        if c is not None and c.end <= size and (best is None or c.generation > best.generation):
            best = c
    return best


class ArchiveTruncatedError(ArchiveError, TruncatedError):
    """A header slot names a newer commit that ends past the end of the file: the file was cut short.

    Reading the older commit that is still intact would silently serve an earlier state of the
    archive (scenes missing, replaced keys reverted), so readers refuse unless asked
    (``allow_truncated=True``, CLI ``--allow-truncated``).  ``lost`` is the commit that was cut off.
    """

    def __init__(self, message: str, lost: Commit | None = None, fallback: Commit | None = None):
        super().__init__(message)
        self.lost = lost
        self.fallback = fallback


def newest_slot(header: bytes) -> Commit | None:
    """The valid header slot with the highest generation, wherever its commit ends."""
    best = None
    for off in SLOT_OFFSETS:
        c = parse_slot(header[off: off + SLOT_SIZE])
        if c is not None and (best is None or c.generation > best.generation):
            best = c
    return best


def find_commit(source: ByteSource, *, allow_truncated: bool = False) -> tuple[Commit, bool]:
    """The last commit and whether it is the file's tail footer (False: found via a header slot).

    FORMAT.md Part II section 7: the preamble is always checked (magic, major version, required
    flags); a valid header slot naming a newer commit than the one found, ending past the end of
    the file, means the file was truncated: :class:`ArchiveTruncatedError` unless
    ``allow_truncated`` (then the last intact commit is returned).
    """
    size = source.size()
    if size < MIN_ARCHIVE_SIZE:
        if size >= 8:
            parse_preamble(source.read(0, min(size, 32)) + bytes(32))  # bad magic beats "too short"
        raise TruncatedError(f"{source.name}: {size} bytes is too short for an archive ({MIN_ARCHIVE_SIZE} minimum)")
    header = source.read(0, HEADER_SIZE)
    parse_preamble(header)
    commit: Commit | None = None
    at_tail = False
    raw_tail = source.read(size - FOOTER_SIZE, FOOTER_SIZE)
    if is_footer(raw_tail):  # a written footer is authoritative: an unknown version or bad field raises
        tail = parse_footer(raw_tail)
        if tail.end == size:
            commit, at_tail = tail, True
    # A writer may have committed (and moved the slots past our size snapshot) since we measured:
    # re-measure, so slots naming commits that are now complete are not mistaken for truncation.
    if hasattr(source, "refresh"):
        source.refresh()
    now = max(size, source.size())
    if commit is None:
        commit = best_slot(header, now)
    newest = newest_slot(header)
    if newest is not None and newest.end > now and (commit is None or newest.generation > commit.generation):
        if not allow_truncated or commit is None:
            older = ("no older commit is intact" if commit is None else
                     f"generation {commit.generation} ({commit.scene_count} scenes) is the last intact one; "
                     "pass allow_truncated=True (CLI: --allow-truncated) to read it knowingly")
            raise ArchiveTruncatedError(
                f"{source.name}: truncated: commit generation {newest.generation} ({newest.scene_count} scenes) "
                f"ends at byte {newest.end} but the file has {now} bytes; {older}, or run `vt4d repair` "
                "to recover the records that are still in the file",
                lost=newest, fallback=commit)
    if commit is None:
        raise NoCommitError(
            f"{source.name}: no valid commit (footer and header slots damaged); "
            "run `vt4d repair --full-scan` to rebuild the index from the records"
        )
    return commit, at_tail


class ArchiveReader:
    """A read-only view of an archive's last commit.

    ``path_or_url`` is a local path, an fsspec URL (``memory://``, ``http://``, ``s3://``...; extra
    ``storage_options`` go to fsspec), raw bytes, or a :class:`ByteSource`.  ``max_decoded_bytes``: the
    decoded-size budget of each scene :meth:`open_scene` and :meth:`load` read (FORMAT.md I.7; default 64 MiB,
    None for none; an attribute, so it can be raised later).
    """

    def __init__(self, path_or_url: Any, *, allow_truncated: bool = False,
                 max_decoded_bytes: int | None = DEFAULT_MAX_DECODED_BYTES, **storage_options: Any):
        self.max_decoded_bytes = decoded_budget(max_decoded_bytes)
        self.source: ByteSource = open_source(path_or_url, **storage_options)
        try:
            self.commit, self.committed_at_tail = find_commit(self.source, allow_truncated=allow_truncated)
        except BaseException:
            self.source.close()
            raise
        try:
            self.index = load_index(self.source.read, self.commit)
        except BaseException:
            self.source.close()
            raise

    # -- mapping-like access ---------------------------------------------------------------------
    @property
    def name(self) -> str:
        return self.source.name

    @property
    def generation(self) -> int:
        return self.commit.generation

    def __len__(self) -> int:
        return len(self.index)

    def __contains__(self, key: object) -> bool:
        return isinstance(key, str) and self.index.lookup(key) is not None

    def __iter__(self) -> Iterator[str]:
        return iter(self.index.keys())

    def keys(self) -> list[str]:
        """All committed keys, sorted by their UTF-8 bytes."""
        return self.index.keys()

    def entry(self, key: str) -> IndexEntry:
        e = self.index.lookup(key)
        if e is None:
            raise SceneNotFoundError(f"no scene {key!r} in {self.name}")
        return e

    def entries(self) -> Iterator[IndexEntry]:
        return self.index.entries()

    def summary(self, key: str) -> dict[str, Any]:
        """The record's summary (frames, shapes, encoding, fingerprint...): as stored in the index, or, for
        a record that stores none (FORMAT.md Part II 5.3), read from the record's own header."""
        return self.entry_summary(self.entry(key))

    def entry_summary(self, entry: IndexEntry, payload: bytes | None = None) -> dict[str, Any]:
        """:meth:`summary` of an entry (one read of the record when it stores no summary, unless the caller
        has read its ``payload`` already)."""
        if entry.has_summary:
            return entry.summary
        if payload is None:
            payload = self.read_entry(entry)
        try:
            return summarize_payload(payload)
        except FormatError:  # stored without validation and not a scene: its size is what is known
            return {"bytes": len(payload)}

    # -- records -----------------------------------------------------------------------------------
    def read_entry(self, entry: IndexEntry, *, check: bool = True) -> bytes:
        """The payload of ``entry`` in one read; CRC-checked unless ``check=False``."""
        data = self.source.read(entry.offset, entry.length)
        if check and crc32(data) != entry.crc32:
            raise RecordChecksumError(f"record {entry.key!r} in {self.name} fails its checksum")
        return data

    def read_bytes(self, key: str, *, check: bool = True) -> bytes:
        """The scene's complete ``.vt4d`` bytes (byte-for-byte what was archived)."""
        return self.read_entry(self.entry(key), check=check)

    def open_scene(self, key: str) -> SceneFile:
        """A lazy ``vt4dcodec.format.SceneFile`` over the record (within :attr:`max_decoded_bytes`)."""
        return open_scene(self.read_bytes(key), max_decoded_bytes=self.max_decoded_bytes)

    def load(self, key: str) -> Scene:
        """The fully validated ``vt4dcodec.format.Scene`` (LimitExceededError over :attr:`max_decoded_bytes`)."""
        return loads(self.read_bytes(key), max_decoded_bytes=self.max_decoded_bytes)

    def iter_records(self, *, check: bool = True, chunk_bytes: int = 8 << 20) -> Iterator[tuple[str, bytes]]:
        """(key, payload) for every scene in file order.

        Neighbouring records are fetched together in reads of up to ``chunk_bytes`` (the frame
        headers between them come along), so a full pass costs few large reads instead of one per
        scene.  A record larger than ``chunk_bytes`` is read on its own.
        """
        positions, offsets, lengths, crcs = self.index.layout_columns()
        i, n = 0, len(positions)
        while i < n:
            j, start = i + 1, offsets[i]
            while j < n and offsets[j] + lengths[j] - start <= chunk_bytes:
                j += 1
            block = self.source.read(start, offsets[j - 1] + lengths[j - 1] - start)
            for k in range(i, j):
                data = block[offsets[k] - start: offsets[k] - start + lengths[k]]
                if check and crc32(data) != crcs[k]:
                    raise RecordChecksumError(f"record {self.index.key_at(positions[k])!r} in {self.name} "
                                              "fails its checksum")
                yield self.index.key_at(positions[k]), data
            i = j

    @property
    def uncommitted_bytes(self) -> int:
        """Bytes after the last commit (an active or crashed writer's records)."""
        return self.source.size() - self.commit.end

    def close(self) -> None:
        self.source.close()

    def __enter__(self) -> "ArchiveReader":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"ArchiveReader({self.name!r}, scenes={len(self)}, generation={self.generation})"


def open_archive(path_or_url: Any, *, allow_truncated: bool = False,
                 max_decoded_bytes: int | None = DEFAULT_MAX_DECODED_BYTES, **storage_options: Any) -> ArchiveReader:
    """Open an archive for reading (see :class:`ArchiveReader`).

    A truncated archive (a header slot names a commit cut off the end) raises
    :class:`ArchiveTruncatedError`; ``allow_truncated=True`` reads its last intact commit instead.
    ``max_decoded_bytes``: the decoded-size budget of each scene read (FORMAT.md I.7).
    """
    if isinstance(path_or_url, os.PathLike):
        path_or_url = os.fspath(path_or_url)
    return ArchiveReader(path_or_url, allow_truncated=allow_truncated, max_decoded_bytes=max_decoded_bytes,
                         **storage_options)
