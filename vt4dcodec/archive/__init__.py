"""Multi-scene archives (``.vt4da``): records, index, footer, recovery, fsspec access.

Reading::

    from vt4dcodec.archive import open_archive
    with open_archive("scenes.vt4da") as ar:        # or "http://host/scenes.vt4da", "memory://x"
        scene = ar.load("scene-000042")              # 3 reads to open, 1 read per scene

Writing (one writer at a time; readers see the last commit)::

    from vt4dcodec.archive import ArchiveWriter
    with ArchiveWriter("scenes.vt4da") as w:         # commits on exit
        w.append("scene-000042", scene_or_vt4d_bytes)

The byte layout is specified in FORMAT.md, Part II.  This package never imports torch.
"""

from .compact import CompactReport, compact_archive
from .index import ArchiveIndex, DuplicateKeyError, IndexChecksumError, IndexEntry, OverlappingRecordsError
from .layout import ARCHIVE_EXTENSION, ARCHIVE_MAGIC, Commit, check_key
from .lock import WriterLock
from .reader import ArchiveReader, ArchiveTruncatedError, NoCommitError, RecordChecksumError, open_archive
from .recovery import ArchiveNotFoundError, RepairPlan, RepairReport, plan_repair, scan_records
from .source import BytesSource, FsspecSource, LocalSource, open_source
from .verify import UncommittedTailError, verify_archive
from .writer import ArchiveWriter, UncommittedDataError, create_archive, repair_archive

__all__ = [
    "ARCHIVE_MAGIC", "ARCHIVE_EXTENSION", "ArchiveReader", "ArchiveWriter", "ArchiveIndex", "IndexEntry",
    "Commit", "open_archive", "create_archive", "verify_archive", "repair_archive", "scan_records",
    "RepairReport", "WriterLock", "check_key", "is_archive", "open_source", "LocalSource", "FsspecSource",
    "BytesSource", "DuplicateKeyError", "OverlappingRecordsError", "IndexChecksumError", "NoCommitError",
    "RecordChecksumError", "UncommittedDataError", "UncommittedTailError", "ArchiveTruncatedError",
    "ArchiveNotFoundError", "RepairPlan", "plan_repair", "compact_archive", "CompactReport",
]


def is_archive(head: bytes) -> bool:
    """True if ``head`` (the first bytes of a file) starts with the archive magic."""
    return bytes(head[: len(ARCHIVE_MAGIC)]) == ARCHIVE_MAGIC
