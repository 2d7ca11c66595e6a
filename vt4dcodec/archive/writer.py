"""Append scenes to an archive and commit them atomically (one writer at a time).

Write protocol (normative text in FORMAT.md, Part II):

1. Take the writer lock (``<archive>.lock``).
2. Make a header commit slot point at the last commit (fsync) *before* writing any byte after it,
   so readers that find no footer at the tail still find the last commit.
3. Append record frames after the last footer (pending, not yet visible).
4. ``commit()``: write the new index block, fsync; write the new 64-byte footer, fsync - **this
   fsync is the commit point**; then write the other header slot to point at it, fsync.  In a
   version 1.1 archive the index block is a manifest + one segment holding only the keys this commit
   changed (plus the small segments it merges, see ``segments.py``), so a commit costs what changed.
   In a version 1.2 archive a commit whose frames since the last full commit fit in 256 KiB writes no
   index at all: its footer names that full commit's index and the frames after it (a *light* commit);
   segments are stored zstd-compressed, and small records store no summary.

A writer killed at any instant leaves the file readable at its last commit: either the tail is that
commit's footer, or it is not and a header slot points at it (step 2).  Torn frames after the last
commit are reported by readers as ``uncommitted_bytes``; :func:`repair_archive` (``vt4d repair``)
adds the complete ones to a new commit, or a writer opened with ``on_uncommitted="recover"`` does.
"""

from __future__ import annotations

import os
from typing import Any, Iterable, Iterator, Literal

from ..errors import ArchiveError, FormatError, LimitExceededError
from .index import ArchiveIndex, DuplicateKeyError, IndexEntry, encode_summary, shared_first
from .layout import (ARCHIVE_MAGIC, FLAG_SEGMENTED, FLAG_V12, HEADER_SIZE, MAX_GENERATION, MAX_TAIL_BYTES, PREAMBLE_SIZE,
                     SLOT_OFFSETS, SLOT_SIZE, VERSION_MINOR, Commit, check_key, crc32, pack_footer, pack_frame_header,
                     pack_preamble, pack_slot, parse_preamble, parse_slot)
from .lock import WriterLock
from .reader import ArchiveTruncatedError, NoCommitError, best_slot, find_commit
from .recovery import SCENE_MAGIC_PREFIX, ArchiveNotFoundError, RepairPlan, RepairReport, plan_repair
from .records import record_from, summarize_payload
from ..format.sections import DEFAULT_MAX_DECODED_BYTES
from .segments import (IndexView, SegmentRef, compress_segment, load_index, manifest_length, pack_journal, pack_manifest,
                       plan_merge)
from .source import LocalSource

__all__ = ["ArchiveWriter", "UncommittedDataError", "create_archive", "repair_archive", "replace_with_new_archive"]

Policy = Literal["error", "recover", "discard"]

#: a version 1.2 writer stores no summary for a record smaller than this (FORMAT.md Part II 5.3): readers
#: read the fields from the record's own header, which costs one read of under 4 KiB
SUMMARY_MIN_RECORD = 4096
#: a version 1.2 commit of at most this many records is light when its tail fits (FORMAT.md Part II 5.7);
#: a larger one (a pack) writes an index, which readers open faster than they parse a tail
LIGHT_MAX_RECORDS = 16


class UncommittedDataError(ArchiveError):
    """The archive has bytes after its last commit (a crashed writer); repair or discard them first."""


def _fsync_dir(path: str) -> None:
    fd = os.open(os.path.dirname(os.path.abspath(path)) or ".", os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _check_magic(path: str) -> None:
    """The existing file at ``path`` must start with an archive preamble (checked before locking)."""
    with open(path, "rb") as f:
        head = f.read(PREAMBLE_SIZE)
    if len(head) >= 8:
        parse_preamble(head + bytes(PREAMBLE_SIZE - len(head)))


def _empty_archive_bytes(minor: int = VERSION_MINOR) -> bytes:
    index = ArchiveIndex.build([])
    commit = Commit(0, HEADER_SIZE, len(index), crc32(index), 0)
    header = pack_preamble(minor) + pack_slot(commit) + bytes(HEADER_SIZE - 32 - 64)
    return header + index + pack_footer(commit)


def _check_version(version: tuple[int, int]) -> int:
    if tuple(version) not in ((1, 0), (1, 1), (1, 2)):
        raise ArchiveError(f"this writer writes archive versions 1.0, 1.1 and 1.2, not {version!r}")
    return version[1]


def create_archive(path: str | os.PathLike[str], *, exist_ok: bool = False, version: tuple[int, int] = (1, VERSION_MINOR)) -> None:
    """Create an empty archive (generation 0) atomically: write a temp file, fsync, rename.

    ``version`` (1, 2) (default) lets commits be light and segments compressed, (1, 1) lets commits use
    segmented indexes; (1, 0) writes a whole index per commit, readable by 1.0 readers."""
    path = os.fspath(path)
    minor = _check_version(version)
    if os.path.exists(path) and not exist_ok:
        raise FileExistsError(f"{path} already exists")
    tmp = f"{path}.tmp-{os.getpid()}"
    with open(tmp, "wb") as f:
        f.write(_empty_archive_bytes(minor))
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    _fsync_dir(path)


class ArchiveWriter:
    """Append-and-commit access to a local archive.

    Writers need a local POSIX file system (``flock``, ``pwrite``, ``fdatasync``, ``ftruncate``);
    readers work on any fsspec file system.  To publish to object storage, write locally and upload
    the finished file (it is immutable until the next append).

    ``mode``: ``"a"`` open (create if missing), ``"x"`` create (fail if present), ``"w"`` replace
    with an empty archive.  ``on_uncommitted`` decides what happens to bytes after the last commit
    (left by a crashed writer): ``"error"`` (default) raises :class:`UncommittedDataError`,
    ``"recover"`` commits the complete records among them, ``"discard"`` truncates them.
    ``durable=False`` skips fsync (tests and throwaway benchmarks only).

    As a context manager it commits on normal exit and aborts (drops pending records) on error, except
    KeyboardInterrupt (Ctrl-C, or a signal a program turns into one): then every scene whose ``append``
    returned is committed (a frame the interrupt tore is cut off first), so a long write keeps what finished.
    """

    def __init__(self, path: str | os.PathLike[str], mode: str = "a", *, on_uncommitted: Policy = "error",
                 durable: bool = True, full_scan: bool = False, dry_run: bool = False,
                 allow_truncated: bool = False, version: tuple[int, int] = (1, VERSION_MINOR),
                 _repair: bool = False):
        if mode not in ("a", "x", "w"):
            raise ArchiveError(f"mode must be 'a', 'x' or 'w', not {mode!r}")
        if on_uncommitted not in ("error", "recover", "discard"):
            raise ArchiveError(f"on_uncommitted must be error/recover/discard, not {on_uncommitted!r}")
        self.path = os.fspath(path)
        self.durable = durable
        self.repair_report: RepairReport | None = None
        self._created = False
        self._dry_run = False
        self._next_generation: int | None = None
        self._commit: Commit | None = None
        self._pending: dict[str, IndexEntry] = {}
        self._written: list[IndexEntry] = []  # every frame appended since the last commit, in file order
        self._segments: list[tuple[SegmentRef, list[str]]] = []  # newest first (version 1.1)
        self._segmented = False
        self._v12 = False  # the preamble allows light commits and compressed segments (version 1.2)
        self._tail: set[str] = set()  # keys committed by light commits since the last full commit
        self._full_next = False  # the next commit writes an index (repairs and rewrites)
        self._consolidate = False
        _check_version(version)
        exists = os.path.exists(self.path)
        if exists and mode == "a" and not full_scan:
            _check_magic(self.path)  # before the lock: a wrong file gets no .lock beside it
        self._lock = WriterLock(self.path).acquire()
        self._fd: int | None = None
        try:
            if mode == "x" or (mode == "a" and not os.path.exists(self.path)):
                create_archive(self.path, exist_ok=False, version=version)
                self._created = True
            elif mode == "w":
                create_archive(self.path, exist_ok=True, version=version)
            self._fd = os.open(self.path, os.O_RDWR)
            self._open_existing(on_uncommitted, full_scan, dry_run, allow_truncated, _repair)
        except BaseException:
            self._close_fd()
            self._commit = None
            self._release(failed=True)
            raise

    def _release(self, *, failed: bool) -> None:
        """Release the lock.  After a failure, an archive this writer created and never committed a
        scene to is removed with its lock file, so a failed first ``pack``/``encode --archive``
        leaves nothing behind and the retry starts clean; a lock file this writer created for a
        file it could not open is removed too."""
        commit = self._commit
        if failed and self._created and (commit is None or not commit.scene_count):
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass
            self._lock.release_and_remove()
        elif failed and commit is None:
            self._lock.release_and_remove()
        else:
            self._lock.release()

    # -- opening ---------------------------------------------------------------------------------
    def _open_existing(self, policy: Policy, full_scan: bool, dry_run: bool, allow_truncated: bool,
                       repairing: bool) -> None:
        source = LocalSource(self.path)
        plan: RepairPlan | None = None
        try:
            size = source.size()
            if full_scan:
                plan = plan_repair(source, full_scan=True, verify_committed=repairing)
            else:
                try:
                    commit = self._find_commit(source, allow_truncated, mend=not dry_run)
                    if size > commit.end and policy == "error":
                        raise UncommittedDataError(
                            f"{self.path}: {size - commit.end} bytes after the last commit "
                            f"(generation {commit.generation}) - a writer crashed or is running; run "
                            "`vt4d repair` to keep its complete records, or open with "
                            "on_uncommitted='discard' to drop them"
                        )
                    if repairing or (size > commit.end and policy == "recover"):
                        # a repair checks every committed record and every commit the file claims first
                        plan = plan_repair(source, full_scan=False, base=commit, verify_committed=repairing)
                    else:
                        view = load_index(source.read, commit)
                        self._entries = {e.key: e for e in view.entries()}
                        self._commit, self._end, self._pending = commit, commit.end, {}
                        self._set_version(parse_preamble(source.read(0, PREAMBLE_SIZE)))
                        self._segments = self._segments_of(commit, view)
                        self._tail = {e.key for e in view.tail or ()}
                        discarded = size - commit.end
                except UncommittedDataError:
                    raise
                except FormatError as exc:  # no usable last commit: a repair walks the whole file
                    if not repairing:
                        raise
                    plan = plan_repair(source, full_scan=True, verify_committed=True, scan_reason=_scan_reason(exc))
            if plan is not None:
                copy_payloads = {k: source.read(e.offset, e.length) for k, e in plan.copies.items()}
        finally:
            source.close()
        if plan is None:  # the last commit stands (``commit``, read above)
            self._check_generation()
            self.repair_report = RepairReport(self.path, commit.generation, len(self._entries), [], discarded,
                                              None, scenes=len(self._entries), dry_run=dry_run)
            if dry_run:
                self._dry_run = True
                return
            if discarded:
                os.ftruncate(self._handle, self._end)
                self._mend_footer(commit)
            self._ensure_slot(commit)
            return
        self._apply_plan(plan, copy_payloads, dry_run)

    def _apply_plan(self, plan: RepairPlan, copy_payloads: dict[str, bytes], dry_run: bool) -> None:
        base, newest = plan.base, plan.lost_commit
        self.repair_report = RepairReport(
            self.path, None if base is None else base.generation, 0 if base is None else base.scene_count,
            plan.recovered, plan.size - plan.cut, None, full_scan=plan.full_scan, lost=list(plan.lost),
            copied=sorted(plan.copies), damaged_bytes=plan.damaged_bytes,
            lost_generation=None if newest is None else newest.generation,
            lost_scenes=None if newest is None else newest.scene_count, scenes=len(plan.entries) + len(plan.copies),
            dry_run=dry_run, lost_unnamed=plan.lost_unnamed, uncertain=plan.uncertain, reindexed=list(plan.reindexed),
            scan_reason=plan.scan_reason, rewritten=plan.rewrite and plan.needs_commit)
        self._commit, self._entries, self._pending, self._end = base, {}, {}, plan.cut
        self._segmented = plan.segmented or not plan.preamble_ok
        self._v12 = plan.v12 or not plan.preamble_ok
        self._segments = []  # the repaired commit is one new segment (or one whole index)
        self._tail, self._full_next = set(), True
        if dry_run:
            self._dry_run = True
            return
        # a plain writer over the intact base (a plan needs no commit only where it has a base, with its index)
        if not plan.needs_commit and base is not None and plan.view is not None:
            self._segments = self._segments_of(base, plan.view)
            self._tail, self._full_next = {e.key for e in plan.view.tail or ()}, False
            self._entries = dict(plan.entries)
            self._ensure_slot(base)
            return
        if plan.rewrite:  # the generation counter is spent: the repaired archive becomes a new file
            self.repair_report.new_generation = self._rewrite(plan, copy_payloads)
            return
        if not plan.preamble_ok:  # a damaged preamble is mended (magic, version, flags)
            os.pwrite(self._handle, pack_preamble(), 0)
        if base is not None:  # step 2: a slot names the base before anything follows it
            header = os.pread(self._handle, HEADER_SIZE, 0)
            if best_slot(header, plan.cut) != base:
                self._write_slot(base)
        if plan.size != plan.cut:
            os.ftruncate(self._handle, plan.cut)
        self._sync()
        self._pending = dict(plan.entries)
        for key, entry in plan.copies.items():
            self._append_raw(key, copy_payloads[key], entry.summary_bytes)
        self._next_generation = plan.new_generation
        self.repair_report.new_generation = self._write_commit()

    def _rewrite(self, plan: RepairPlan, copy_payloads: dict[str, bytes]) -> int:
        """Write the plan's records into a new file of generation 1 renamed over the archive (as
        `vt4d compact` does), then continue as a writer of that file."""
        def records() -> Iterator[tuple[str, bytes, bytes]]:
            for e in sorted(plan.entries.values(), key=lambda e: e.offset):
                payload = os.pread(self._handle, e.length, e.offset)
                if crc32(payload) != e.crc32:  # the plan checked it; the file changed under the lock
                    raise ArchiveError(f"{self.path}: record {e.key!r} changed during the repair; nothing was written")
                yield e.key, payload, e.summary_bytes
            for key, entry in plan.copies.items():
                yield key, copy_payloads[key], entry.summary_bytes

        commit = replace_with_new_archive(self.path, records(), generation=1,
                                          version=(1, 2 if self._v12 else 1 if self._segmented else 0),
                                          durable=self.durable, suffix="repair")
        self._close_fd()
        self._fd = os.open(self.path, os.O_RDWR)
        view = load_index(lambda off, n: os.pread(self._handle, n, off), commit)
        self._entries = {e.key: e for e in view.entries()}
        self._commit, self._end, self._pending = commit, commit.end, {}
        self._segments = self._segments_of(commit, view)
        self._tail, self._full_next = {e.key for e in view.tail or ()}, False
        return commit.generation

    def _set_version(self, preamble_flags: int) -> None:
        self._segmented = bool(preamble_flags & FLAG_SEGMENTED)
        self._v12 = bool(preamble_flags & FLAG_V12)

    def _segments_of(self, commit: Commit, view: IndexView) -> list[tuple[SegmentRef, list[str]]]:
        """The live segments a 1.1 writer continues from (a whole 1.0-style index is one segment; a light
        commit's tail is not a segment)."""
        stored = view.index_segments
        if commit.segmented:
            return [(r, seg.keys()) for r, seg in zip(view.refs, stored)]
        if self._segmented and stored and len(stored[0]):
            seg = stored[0]
            return [(SegmentRef(commit.index_offset, commit.index_length, len(seg), commit.index_crc32), seg.keys())]
        return []

    def _find_commit(self, source: LocalSource, allow_truncated: bool, *, mend: bool = True) -> Commit:
        commit, at_tail = find_commit(source, allow_truncated=allow_truncated)
        if mend and not at_tail and source.size() == commit.end:  # damaged last footer, intact slot: mend it
            os.pwrite(self._handle, pack_footer(commit), commit.footer_offset)
            self._sync()
        return commit

    def _mend_footer(self, commit: Commit) -> None:
        """Rewrite the last commit's footer if its bytes differ (found through a slot, the tail cut off):
        the frames of the next light commit follow it and its tail must parse (FORMAT.md Part II 5.7)."""
        footer = pack_footer(commit)
        if os.pread(self._handle, len(footer), commit.footer_offset) != footer:
            os.pwrite(self._handle, footer, commit.footer_offset)
            self._sync()

    def _check_generation(self) -> None:
        if self._commit is not None and self._commit.generation >= MAX_GENERATION:
            raise LimitExceededError(
                f"{self.path}: generation {self._commit.generation} is the last the 64-bit counter holds; "
                "no further commit is possible - copy the scenes to a new archive with `vt4d compact`")

    def _ensure_slot(self, commit: Commit) -> None:
        """Step 2 of the protocol: a header slot names ``commit`` before anything follows it.

        Slots claiming a *newer* generation than the last commit (left by a file truncated back to
        an older footer) are cleared, so they can never outrank it once the file grows again.
        """
        header = os.pread(self._handle, HEADER_SIZE, 0)
        parse_preamble(header)
        for off in SLOT_OFFSETS:
            stale = parse_slot(header[off: off + SLOT_SIZE])
            if stale is not None and stale.generation > commit.generation:
                os.pwrite(self._handle, bytes(SLOT_SIZE), off)
        if best_slot(header, commit.end) != commit:
            self._write_slot(commit)
        else:
            self._sync()

    def _write_slot(self, commit: Commit) -> None:
        os.pwrite(self._handle, pack_slot(commit), SLOT_OFFSETS[commit.generation % 2])
        self._sync()

    @property
    def _handle(self) -> int:
        """The archive's open descriptor (every write goes through it)."""
        if self._fd is None:
            raise ArchiveError(f"{self.path}: the writer is closed")
        return self._fd

    def _sync(self) -> None:
        if self.durable:
            os.fdatasync(self._handle)

    # -- appending ---------------------------------------------------------------------------------
    @property
    def generation(self) -> int:
        return -1 if self._commit is None else self._commit.generation

    @property
    def pending_keys(self) -> list[str]:
        return list(self._pending)

    def __contains__(self, key: object) -> bool:
        return key in self._entries or key in self._pending

    def __len__(self) -> int:
        return len(self._entries.keys() | self._pending.keys())

    def append(self, key: str, record: Any, *, summary: dict[str, Any] | None = None, replace: bool = False,
               validate: bool = True, max_decoded_bytes: int | None = DEFAULT_MAX_DECODED_BYTES) -> IndexEntry:
        """Write one scene (a Scene or complete ``.vt4d`` bytes); visible to readers after commit().

        ``summary`` defaults to the container's ``SceneFile.summary()``; ``validate=False`` stores
        bytes without container validation (then pass ``summary`` or get ``{"bytes": n}``); validated
        bytes must decode within ``max_decoded_bytes`` (FORMAT.md I.7).
        Appending a key that exists raises :class:`DuplicateKeyError` unless ``replace=True``.
        """
        self._check_open()
        check_key(key)
        if not replace and key in self:
            raise DuplicateKeyError(f"scene {key!r} is already in {self.path} (pass replace=True)")
        if validate or not isinstance(record, (bytes, bytearray, memoryview)):
            payload = record_from(record, validate=validate, max_decoded_bytes=max_decoded_bytes)
        else:
            payload = bytes(record)
        if summary is None and self._v12 and len(payload) < SUMMARY_MIN_RECORD:
            return self._append_raw(key, payload, b"")  # readers take the fields from the record's header
        if summary is None:
            summary = summarize_payload(payload) if validate else {"bytes": len(payload)}
        if self._segmented:  # per-scene fields last: index segments prefix-code the shared rest
            summary = shared_first(summary)
        return self._append_raw(key, payload, encode_summary(summary))

    def _append_raw(self, key: str, payload: bytes, summary_raw: bytes) -> IndexEntry:
        key_raw = check_key(key)
        pcrc = crc32(payload)
        frame = pack_frame_header(key_raw, summary_raw, pcrc, len(payload)) + key_raw + summary_raw
        start = self._end
        self._pwrite_all(frame + payload, start)
        self._end = start + len(frame) + len(payload)
        entry = IndexEntry(key, start + len(frame), len(payload), pcrc, summary_raw)
        self._pending[key] = entry
        self._written.append(entry)
        return entry

    def _pwrite_all(self, data: bytes, offset: int) -> None:
        view = memoryview(data)
        while view:
            n = os.pwrite(self._handle, view, offset)
            view, offset = view[n:], offset + n

    def commit(self) -> int:
        """Make every pending scene durable and visible; returns the new generation.

        With nothing pending this is a no-op returning the current generation.
        """
        self._check_open()
        if not self._pending and self._commit is not None:
            return self._commit.generation
        return self._write_commit()

    def _write_commit(self) -> int:
        if os.fstat(self._handle).st_size > self._end:  # a frame torn by an interrupted append: not ours to keep
            os.ftruncate(self._handle, self._end)
        # O(changed) for 1.1: the committed entries are updated in place after the commit point
        pending, committed = self._pending, self._entries
        total = len(committed) + sum(1 for k in pending if k not in committed)
        generation = self.generation + 1 if self._next_generation is None else self._next_generation
        if generation > MAX_GENERATION:
            raise LimitExceededError(f"{self.path}: the 64-bit generation counter is exhausted; "
                                     "copy the scenes to a new archive with `vt4d compact`")
        base, journal = self._commit, self._light_journal()
        if base is not None and journal is not None:
            # version 1.2 light commit: a journal of its frames, and a footer naming the last full commit's
            # index and everything after it (the tail)
            tail_start = base.index_offset + base.index_length
            self._pwrite_all(journal, self._end)
            self._end += len(journal)
            index = b""
            new = Commit(generation, base.index_offset, base.index_length, base.index_crc32, total,
                         (base.flags & FLAG_SEGMENTED) | FLAG_V12, self._end - tail_start)
            segments = self._segments
            self._tail.update(pending)  # (its keys)
        elif self._segmented:  # version 1.1: write what changed (plus the segments it merges)
            keys = set(pending) | set(self._tail)
            folded: set[int] = set()

            def merged_count(chosen: list[int]) -> int:  # distinct keys once ``chosen`` are folded in
                for i in chosen:
                    if i not in folded:
                        keys.update(self._segments[i][1])
                        folded.add(i)
                return len(keys)

            merge = set(plan_merge([r.count for r, _ in self._segments], len(keys), merged_count))
            merged_count(sorted(merge))
            # the folded segments may be any older ones: the new segment holds each key's current entry
            segment = ArchiveIndex.build([pending[k] if k in pending else committed[k] for k in keys], prefix=True)
            sflags = 0
            if self._v12:  # 1.2: stored zstd-compressed where that is smaller
                segment, sflags = compress_segment(segment)
            kept = [s for i, s in enumerate(self._segments) if i not in merge]
            ref = SegmentRef(self._end + manifest_length(1 + len(kept)), len(segment), len(keys), crc32(segment),
                             sflags)
            segments = [(ref, list(keys))] + kept
            index = pack_manifest([r for r, _ in segments], total) + segment  # one block, one read
            new = Commit(generation, self._end, len(index), crc32(index), total,
                         FLAG_SEGMENTED | (FLAG_V12 if self._v12 else 0))
            self._tail = set()
        else:  # version 1.0: the whole index, every commit
            index = ArchiveIndex.build(list({**committed, **pending}.values()))
            new = Commit(generation, self._end, len(index), crc32(index), total)
            segments = []
        if index:
            self._pwrite_all(index, self._end)
        self._sync()  # records + index durable before the footer can be
        os.pwrite(self._handle, pack_footer(new), new.footer_offset)
        self._sync()  # <- the commit point
        committed.update(pending)
        self._pending, self._commit, self._end, self._written = {}, new, new.end, []
        self._segments = segments
        self._next_generation, self._full_next = None, False
        self._write_slot(new)
        return new.generation

    def _light_journal(self) -> bytes | None:
        """The journal of this commit's frames when it can be light (version 1.2, at most 16 records, the tail
        within 256 KiB; FORMAT.md Part II 5.7), or None when it writes an index."""
        base = self._commit
        if not self._v12 or base is None or self._full_next or not 0 < len(self._written) <= LIGHT_MAX_RECORDS:
            return None
        journal = pack_journal(base.end, self._written)  # the frames follow the last commit's footer
        fits = self._end + len(journal) - (base.index_offset + base.index_length) <= MAX_TAIL_BYTES
        return journal if fits else None

    def abort(self) -> None:
        """Drop pending scenes: truncate the file back to the last commit (with any frame an error tore)."""
        if self._fd is not None and not self._dry_run and self._commit is not None and (
                self._pending or os.fstat(self._handle).st_size > self._commit.end):
            os.ftruncate(self._handle, self._commit.end)
            self._end = self._commit.end
        self._pending, self._written = {}, []

    # -- lifetime ---------------------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._fd is None:
            raise ArchiveError(f"archive writer for {self.path} is closed")
        if self._dry_run:
            raise ArchiveError("this writer was opened as a dry run")

    def _close_fd(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def close(self, *, commit: bool = True) -> None:
        """Commit pending scenes (unless ``commit=False``: abort them), then release the lock."""
        if self._fd is None:
            return
        try:
            if commit and self._pending and not self._dry_run:
                self.commit()
            else:
                self.abort()
        finally:
            self._close_fd()
            self._release(failed=not commit)

    def __enter__(self) -> "ArchiveWriter":
        return self

    def __exit__(self, exc_type: Any, *exc: Any) -> None:
        interrupted = exc_type is not None and issubclass(exc_type, KeyboardInterrupt)
        self.close(commit=exc_type is None or (interrupted and bool(self._pending)))

    def __repr__(self) -> str:
        return f"ArchiveWriter({self.path!r}, committed={len(self._entries)}, pending={len(self._pending)})"


def replace_with_new_archive(path: str, records: Iterable[tuple[str, bytes, bytes]], *, generation: int,
                             version: tuple[int, int], durable: bool, suffix: str) -> Commit:
    """Write ``records`` (key, payload, summary bytes) into a new archive ``<path>.<suffix>-<pid>`` with one
    commit of ``generation``, and rename it over ``path``, keeping its permission bits: readers see the old
    file or the new one, never a mix, and a failure leaves ``path`` untouched.  Returns the new commit."""
    tmp = f"{path}.{suffix}-{os.getpid()}"
    try:
        w = ArchiveWriter(tmp, "x", durable=durable, version=version)
        try:
            for key, payload, summary in records:
                w._append_raw(key, payload, summary)
            w._next_generation, w._full_next = generation, True  # one index holding every scene
            w._write_commit()
            commit = w._commit
        except BaseException:
            w.close(commit=False)
            raise
        w._close_fd()
        w._lock.release_and_remove()
        assert commit is not None
        os.chmod(tmp, os.stat(path).st_mode & 0o7777)  # the new file keeps the old one's permissions
        os.replace(tmp, path)
        if durable:
            _fsync_dir(path)
        return commit
    except BaseException:
        for leftover in (tmp, tmp + ".lock"):
            try:
                os.unlink(leftover)
            except FileNotFoundError:
                pass
        raise


def _scan_reason(exc: FormatError) -> str:
    """Why a default repair walks the whole file, from the error opening the last commit gave."""
    if isinstance(exc, ArchiveTruncatedError) and exc.lost is not None:
        return (f"the file was truncated: commit generation {exc.lost.generation} ({exc.lost.scene_count} "
                "scenes) is cut off its end")
    if isinstance(exc, NoCommitError):
        return "no usable commit (the footer and both header slots are damaged)"
    return "the last commit's footer or index does not verify"


def _check_repairable(path: str, full_scan: bool) -> None:
    if not os.path.exists(path):
        raise ArchiveNotFoundError(f"{path}: no such archive (repair never creates one; check the path)")
    with open(path, "rb") as f:
        head = f.read(len(ARCHIVE_MAGIC))
    if head.startswith(SCENE_MAGIC_PREFIX):
        raise ArchiveError(f"{path} is a single-scene .vt4d file, not an archive; use `vt4d verify` on it")
    if head != ARCHIVE_MAGIC and not full_scan:
        raise ArchiveError(f"{path} does not start with the archive magic; if it is a damaged archive, "
                           "run `vt4d repair --full-scan --dry-run` to see what can be recovered")


def repair_archive(path: str | os.PathLike[str], *, full_scan: bool = False, dry_run: bool = False) -> RepairReport:
    """Make an archive end in a valid commit again, never dropping a record that verifies.

    The last commit is kept; complete, checksum-valid records written after it (damaged bytes
    skipped) are added to a new commit; torn bytes after the last valid structure are cut off.  A
    truncated archive, or one with no usable commit, is repaired as with ``full_scan``: the newest
    commit whose index verifies is the base, its records are each checked, and the report lists the
    keys that could not be recovered (``unrecoverable``) and any commit lost to truncation.  With
    ``dry_run`` nothing is written and the report is the plan.
    """
    path = os.fspath(path)
    _check_repairable(path, full_scan)
    w = ArchiveWriter(path, mode="a", on_uncommitted="recover", full_scan=full_scan, dry_run=dry_run,
                      _repair=True)
    try:
        report = w.repair_report
    finally:
        w.close()
    assert report is not None
    return report
