"""Byte sources an archive is read from: a local file, any fsspec file system, or bytes in memory.

Every source reads by absolute byte range and counts the reads and bytes it serves (``reads``,
``bytes_read``), so tests and benchmarks can check that opening an archive and reading one scene
touches only the footer, the index and that scene's record.

Local files are read with ``os.pread`` on a descriptor opened lazily *per process*: a source that
crosses ``fork`` (DataLoader workers) reopens its own handle instead of sharing the parent's.
"""

from __future__ import annotations

import os
import threading
from abc import ABC, abstractmethod
from typing import Any, Protocol, Self

from ..errors import RangeNotSupportedError, TruncatedError

__all__ = ["ByteSource", "LocalSource", "FsspecSource", "BytesSource", "open_source", "is_url"]


class ByteSource(Protocol):
    reads: int
    bytes_read: int
    name: str

    def size(self) -> int: ...
    def read(self, offset: int, length: int) -> bytes: ...
    def close(self) -> None: ...


class _Counting(ABC):
    def __init__(self, name: str):
        self.name = name
        self.reads = 0
        self.bytes_read = 0
        self._count_lock = threading.Lock()

    def _count(self, data: bytes, offset: int, length: int) -> bytes:
        with self._count_lock:
            self.reads += 1
            self.bytes_read += len(data)
        if len(data) > length:  # only a remote source can do this: it sent more than the range asked for
            raise RangeNotSupportedError(
                f"{self.name}: asked for {length} bytes at offset {offset} and got {len(data)}: the server "
                "ignores byte-range requests (HTTP Range), which reading an archive in place needs; download "
                "the file and open the local copy, or serve it from a server that supports Range"
            )
        if len(data) != length:
            raise TruncatedError(
                f"{self.name}: wanted {length} bytes at offset {offset}, got {len(data)} (file shrank or truncated)"
            )
        return data

    @abstractmethod
    def close(self) -> None: ...

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LocalSource(_Counting):
    """A local file read with ``os.pread``; the descriptor is reopened after ``fork``."""

    def __init__(self, path: str | os.PathLike[str]):
        super().__init__(os.fspath(path))
        self.path = os.fspath(path)
        self._fd: int | None = None
        self._pid = -1
        self._fd_for_pid()  # fail early (FileNotFoundError) on a missing file

    def _fd_for_pid(self) -> int:
        if self._fd is None or self._pid != os.getpid():
            self._fd = os.open(self.path, os.O_RDONLY | getattr(os, "O_BINARY", 0))
            self._pid = os.getpid()
        return self._fd

    def size(self) -> int:
        return os.fstat(self._fd_for_pid()).st_size

    def read(self, offset: int, length: int) -> bytes:
        fd = self._fd_for_pid()
        chunks, got = [], 0
        while got < length:
            chunk = os.pread(fd, length - got, offset + got)
            if not chunk:
                break
            chunks.append(chunk)
            got += len(chunk)
        return self._count(b"".join(chunks) if len(chunks) != 1 else chunks[0], offset, length)

    def close(self) -> None:
        if self._fd is not None and self._pid == os.getpid():
            os.close(self._fd)
        self._fd = None

    def __getstate__(self) -> dict[str, Any]:  # picklable for DataLoader spawn: never ship a descriptor
        state = self.__dict__.copy()
        state.update(_fd=None, _pid=-1, _count_lock=None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._count_lock = threading.Lock()


class FsspecSource(_Counting):
    """Any fsspec file system; each read is one ``fs.cat_file(path, start, end)`` range request."""

    def __init__(self, url: str, fs: Any = None, **storage_options: Any):
        super().__init__(url)
        if fs is None:
            import fsspec

            fs, path = fsspec.core.url_to_fs(url, **storage_options)
        else:
            path = url
        self.fs, self.path = fs, path
        self._size: int | None = None

    def size(self) -> int:
        if self._size is None:
            self._size = int(self.fs.size(self.path))
        return self._size

    def refresh(self) -> None:
        self._size = None

    def read(self, offset: int, length: int) -> bytes:
        data = self.fs.cat_file(self.path, start=offset, end=offset + length) if length else b""
        return self._count(bytes(data), offset, length)

    def close(self) -> None:
        pass


class BytesSource(_Counting):
    """An archive held in memory (tests, vectors)."""

    def __init__(self, data: bytes, name: str = "<bytes>"):
        super().__init__(name)
        self._data = bytes(data)

    def size(self) -> int:
        return len(self._data)

    def read(self, offset: int, length: int) -> bytes:
        return self._count(self._data[offset: offset + length], offset, length)

    def close(self) -> None:
        pass


def is_url(path: Any) -> bool:
    return isinstance(path, str) and "://" in path and not path.startswith("file://")


def open_source(path_or_url: Any, **storage_options: Any) -> ByteSource:
    """A ByteSource for a local path, a ``file://`` / fsspec URL, raw bytes, or an existing source."""
    if hasattr(path_or_url, "read") and hasattr(path_or_url, "size") and hasattr(path_or_url, "bytes_read"):
        source: ByteSource = path_or_url  # already a source (duck-typed)
        return source
    if isinstance(path_or_url, (bytes, bytearray, memoryview)):
        return BytesSource(bytes(path_or_url))
    if isinstance(path_or_url, str) and path_or_url.startswith("file://"):
        return LocalSource(path_or_url[len("file://"):])
    if is_url(path_or_url):
        return FsspecSource(path_or_url, **storage_options)
    return LocalSource(path_or_url)
