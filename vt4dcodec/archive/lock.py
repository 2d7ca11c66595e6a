"""One writer at a time: an exclusive lock on ``<archive>.lock`` (``filelock``: ``flock`` on POSIX,
``msvcrt.locking`` on Windows), with the holder's pid written into the file.

The holder removes the lock file as it releases, so no empty ``.lock`` stays beside an archive once a
command is done.  Removing a lock file can race with a writer that opened it just before: that writer
may then lock the removed file while a third locks a new one.  So a writer checks, once it holds the
lock, that the file it locked is still the one at ``<archive>.lock`` and otherwise lets it go and tries
again; and only the holder removes the file, while it still holds the lock.  Its lock, not its
existence, is what counts.  The operating system drops the lock when the holder dies (even by SIGKILL),
so a crashed writer never leaves the archive locked (its lock file stays until the next writer is done
with it).  Readers never take the lock.
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


def _locked_file(lock: FileLock) -> os.stat_result | None:
    """The file ``lock`` holds (stat of its descriptor), or None where filelock does not say."""
    fd = getattr(getattr(lock, "_context", None), "lock_file_fd", None)
    if not isinstance(fd, int):
        return None
    try:
        return os.fstat(fd)
    except OSError:
        return None


def _is_at(path: str, held: os.stat_result) -> bool:
    """Whether ``path`` is still the file ``held`` (not removed, nor replaced by a new one)."""
    try:
        return os.path.samestat(os.stat(path), held)
    except OSError:
        return False


class WriterLock:
    """Non-blocking exclusive lock; raises :class:`ArchiveLockedError` naming the holder's pid.  The lock
    file is removed on release (module docstring)."""

    ATTEMPTS = 5  # a writer that locked a file its holder had just removed tries again (module docstring)

    def __init__(self, archive_path: str | os.PathLike[str]):
        self.path = lock_path(archive_path)
        self._lock: FileLock | None = None
        self._held: os.stat_result | None = None  # the locked file, when filelock says which it is
        self.created = False  #: this lock created the lock file

    def acquire(self) -> "WriterLock":
        for _ in range(self.ATTEMPTS):
            existed = os.path.exists(self.path)
            lock = FileLock(self.path)
            try:
                lock.acquire(blocking=False)
            except Timeout:
                raise ArchiveLockedError(
                    f"archive {self.path[:-5]!r} is being written by another process (pid {_read_pid(self.path)}); "
                    "wait for it to finish (readers do not need the lock)"
                ) from None
            held = _locked_file(lock)
            if held is None or _is_at(self.path, held):
                break
            lock.release()  # the file locked was removed by the writer that just let it go: lock the new one
        else:
            raise ArchiveLockedError(f"archive {self.path[:-5]!r} is being written by other processes, one after "
                                     "another; try again when they are done")
        self.created = not existed
        self._held = held
        _write_pid(self.path, f"{os.getpid()}\n")
        self._lock = lock
        return self

    def release(self) -> None:
        """Remove the lock file (while still holding it: only the holder removes it), then unlock."""
        if self._lock is not None:
            try:
                if not self._remove():
                    _write_pid(self.path, "")
                self._lock.release()
            finally:
                self._lock = None
                self._held = None

    def _remove(self) -> bool:
        if self._held is None or not _is_at(self.path, self._held):
            return False
        try:
            os.unlink(self.path)
        except OSError:  # a folder that does not let us remove files; on Windows a locked file cannot be removed
            return False
        return True

    def release_and_remove(self) -> None:
        """:meth:`release` (which removes the lock file); kept for the writer's failure paths."""
        self.release()

    @property
    def held(self) -> bool:
        return self._lock is not None

    def __enter__(self) -> "WriterLock":
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()
