"""The library's version, recorded in every file it writes (``provenance.library_version``).

Written in one place, ``pyproject.toml``; read back here from the installed package's metadata.  A
source tree that was never installed (no metadata) reports ``0+unknown``.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("vt4dcodec")
except PackageNotFoundError:  # pragma: no cover - running from a tree that pip never installed
    __version__ = "0+unknown"
