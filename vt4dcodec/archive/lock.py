"""One writer at a time: an exclusive lock on ``<archive>.lock`` (``filelock``: ``flock`` on POSIX,
``msvcrt.locking`` on Windows), with the holder's pid written into the file.

The lock file is left in place after release (deleting it would race with a waiting writer); its
lock, not its existence, is what counts.  The operating system drops the lock when the holder dies
(even by SIGKILL), so a crashed writer never leaves the archive locked.  Readers never take the lock.
"""

from __future__ import annotations

import os

from filelock import FileLock, Timeout

from ..errors import ArchiveLockedError

__all__ = ["WriterLock", "lock_path"]


def lock_path(archive_path: str | os.PathLike[str]) -> str:
    return os.fspath(archive_path) + ".lock"


def _write_pid(path: str, text: str) -> None:
    """Best effort: the pid is only for the message another writer gets (Windows may refuse a second
    handle on a locked byte; that costs the message its pid, nothing else)."""
    try:
        fd = os.open(path, os.O_WRONLY)
        try:
            os.ftruncate(fd, 0)
            os.write(fd, text.encode())
        finally:
            os.close(fd)
    except OSError:
        pass


def _read_pid(path: str) -> str:
    try:
        with open(path, "rb") as fh:
            return fh.read(32).decode("ascii", "replace").strip() or "unknown"
    except OSError:
        return "unknown"


class WriterLock:
    """Non-blocking exclusive lock; raises :class:`ArchiveLockedError` naming the holder's pid."""

    def __init__(self, archive_path: str | os.PathLike[str]):
        self.path = lock_path(archive_path)
        self._lock: FileLock | None = None
        self.created = False  #: this lock created the lock file (so it may remove it again)

    def acquire(self) -> "WriterLock":
        existed = os.path.exists(self.path)
        lock = FileLock(self.path)
        try:
            lock.acquire(blocking=False)
        except Timeout:
            raise ArchiveLockedError(
                f"archive {self.path[:-5]!r} is being written by another process (pid {_read_pid(self.path)}); "
                "wait for it to finish (readers do not need the lock)"
            ) from None
        self.created = not existed
        _write_pid(self.path, f"{os.getpid()}\n")
        self._lock = lock
        return self

    def release(self) -> None:
        if self._lock is not None:
            try:
                _write_pid(self.path, "")
                self._lock.release()
            finally:
                self._lock = None

    def release_and_remove(self) -> None:
        """Release, removing the lock file first if this lock created it (used when the writer
        created nothing that stays: a failed open, or an archive it created and then removed).
        Another writer racing for the lock fails with ArchiveLockedError (locks are non-blocking)."""
        if self._lock is not None and self.created:
            try:
                os.unlink(self.path)
            except OSError:  # FileNotFoundError; on Windows a locked file cannot be removed
                pass
        self.release()

    @property
    def held(self) -> bool:
        return self._lock is not None

    def __enter__(self) -> "WriterLock":
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()
