"""Whole-archive verification (``vt4d verify`` on an archive)."""

from __future__ import annotations

from typing import Any, Callable

from ..errors import ArchiveError, FormatError
from ..format.sections import DEFAULT_MAX_DECODED_BYTES
from .layout import (FOOTER_SIZE, FRAME_HEADER_SIZE, HEADER_SIZE, crc32, frame_meta_crc, parse_footer,
                     parse_frame_header, parse_preamble)
from .reader import ArchiveReader, RecordChecksumError, open_archive
from .records import verify_payload

__all__ = ["verify_archive", "UncommittedTailError"]


class UncommittedTailError(ArchiveError):
    """Bytes follow the last commit (a writer is running or crashed; `vt4d repair` handles the latter)."""


def verify_archive(path_or_url: Any, *, records: bool = True, allow_uncommitted: bool = False,
                   progress: Callable[[int], None] | None = None, containers: bool = True,
                   max_decoded_bytes: int | None = DEFAULT_MAX_DECODED_BYTES, **storage_options: Any) -> None:
    """Check an archive end to end; raise the first problem as an ArchiveError/FormatError subclass.

    Checks the preamble, the last commit's footer and index (CRC, bounds, order, overlaps), and with
    ``records`` every record: frame header, key and summary match the index, payload CRC, and full
    container validation of the ``.vt4d`` payload (``containers=False`` skips only that last step,
    for archives of opaque payloads).  ``progress(n)`` is called after each record.  A record that would
    decode to more than ``max_decoded_bytes`` (FORMAT.md I.7; None: no budget) is LimitExceededError.
    """
    with open_archive(path_or_url, max_decoded_bytes=max_decoded_bytes, **storage_options) as reader:
        parse_preamble(reader.source.read(0, HEADER_SIZE))
        footer = parse_footer(reader.source.read(reader.commit.footer_offset, FOOTER_SIZE))
        if footer != reader.commit:
            raise ArchiveError("the last commit's footer disagrees with the header slot naming it")
        if reader.uncommitted_bytes and not allow_uncommitted:
            raise UncommittedTailError(
                f"{reader.name}: {reader.uncommitted_bytes} bytes after the last commit "
                f"(generation {reader.generation}); run `vt4d repair` if no writer is running"
            )
        if records:
            _verify_records(reader, progress, containers)


def _verify_records(reader: ArchiveReader, progress: Callable[[int], None] | None, containers: bool) -> None:
    for n, entry in enumerate(sorted(reader.entries(), key=lambda e: e.offset), 1):
        key_raw = entry.key.encode()
        start = entry.frame_offset
        if start < HEADER_SIZE:
            raise ArchiveError(f"record {entry.key!r}: frame would start inside the header")
        frame = reader.source.read(start, entry.offset + entry.length - start)
        fh = parse_frame_header(frame)
        meta = frame[FRAME_HEADER_SIZE: fh.payload_start]
        if (fh.key_len, fh.summary_len, fh.payload_len, fh.payload_crc32) != (
                len(key_raw), len(entry.summary_bytes), entry.length, entry.crc32):
            raise ArchiveError(f"record {entry.key!r}: frame header disagrees with the index")
        if meta != key_raw + entry.summary_bytes or frame_meta_crc(frame, key_raw, entry.summary_bytes) != fh.meta_crc32:
            raise ArchiveError(f"record {entry.key!r}: frame key/summary disagree with the index")
        payload = frame[fh.payload_start:]
        if crc32(payload) != entry.crc32:
            raise RecordChecksumError(f"record {entry.key!r} fails its checksum")
        try:
            if containers:
                verify_payload(payload, max_decoded_bytes=reader.max_decoded_bytes)
        except ArchiveError:
            raise
        except FormatError as exc:  # the container's error: name the record, keep the class
            raise type(exc)(f"record {entry.key!r}: {exc}") from exc
        if progress:
            progress(n)
