"""One writer at a time: an exclusive ``flock`` on ``<archive>.lock`` holding the writer's pid.

The lock file is left in place after release (deleting it would race with a waiting writer); its
lock, not its existence, is what counts.  The kernel drops the lock when the holder dies (even by
SIGKILL), so a crashed writer never leaves the archive locked.  Readers never take the lock.
"""

from __future__ import annotations

import fcntl
import os

from ..errors import ArchiveLockedError

__all__ = ["WriterLock", "lock_path"]


def lock_path(archive_path: str | os.PathLike) -> str:
    return os.fspath(archive_path) + ".lock"


class WriterLock:
    """Non-blocking exclusive lock; raises :class:`ArchiveLockedError` naming the holder's pid."""

    def __init__(self, archive_path: str | os.PathLike):
        self.path = lock_path(archive_path)
        self._fd: int | None = None
        self.created = False  #: this lock created the lock file (so it may remove it again)

    def acquire(self) -> "WriterLock":
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
            self.created = True
        except FileExistsError:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "unknown"
            os.close(fd)
            raise ArchiveLockedError(
                f"archive {self.path[:-5]!r} is being written by another process (pid {holder}); "
                "wait for it to finish (readers do not need the lock)"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            try:
                os.ftruncate(self._fd, 0)
                fcntl.flock(self._fd, fcntl.LOCK_UN)
            finally:
                os.close(self._fd)
                self._fd = None

    def release_and_remove(self) -> None:
        """Release, removing the lock file first if this lock created it (used when the writer
        created nothing that stays: a failed open, or an archive it created and then removed).
        Another writer racing for the lock fails with ArchiveLockedError (locks are non-blocking)."""
        if self._fd is not None and self.created:
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass
        self.release()

    @property
    def held(self) -> bool:
        return self._fd is not None

    def __enter__(self) -> "WriterLock":
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()
