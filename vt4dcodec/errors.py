"""One exception family for everything a user can get wrong.

Every error vt4dcodec raises on bad input derives from :class:`Vt4dError`, so callers can catch one
class.  Each subclass also derives from the builtin that fits (``ValueError``, ``OSError``,
``KeyError``...), so generic handlers keep working.  Messages say what was wrong and what to do.

Parts of the library add narrower subclasses next to their code, always below one of these.
"""

from __future__ import annotations

__all__ = [
    "Vt4dError",
    # container (.vt4d)
    "FormatError",
    "BadMagicError",
    "UnsupportedVersionError",
    "UnsupportedFeatureError",
    "TruncatedError",
    "ChecksumError",
    "MalformedHeaderError",
    "MalformedSectionError",
    "LimitExceededError",
    # archives
    "ArchiveError",
    "ArchiveLockedError",
    "SceneNotFoundError",
    "RangeNotSupportedError",
    # cameras and captures
    "CameraError",
    "CaptureError",
    "TrajectoryError",
    # models and the codec
    "ModelError",
    "ModelNotFoundError",
    "ModelMismatchError", "EntropyTablesError",
    "DeviceError", "MissingExtraError",
]


class Vt4dError(Exception):
    """Base of every error vt4dcodec raises for bad input or bad state."""


# --- the single-scene container ----------------------------------------------------------------
class FormatError(Vt4dError, ValueError):
    """A byte stream is not a valid ``.vt4d`` scene (or archive record)."""


class BadMagicError(FormatError):
    """The file does not start with the vt4d signature (wrong file, or text-mode/transfer damage)."""


class UnsupportedVersionError(FormatError):
    """The file's major version is newer (or older) than this reader understands."""


class UnsupportedFeatureError(FormatError):
    """The file sets a required feature flag, or holds a critical section, this reader does not know."""


class TruncatedError(FormatError):
    """The data ends before a structure it declares."""


class ChecksumError(FormatError):
    """A stored checksum does not match the bytes it covers."""


class MalformedHeaderError(FormatError):
    """The msgpack header is not valid (bad type, missing or unknown key, out-of-range value)."""


class MalformedSectionError(FormatError):
    """A section's layout or contents contradict the header or the specification."""


class EntropyTablesError(FormatError, LookupError):
    """The tokens are coded with a model's entropy tables (``learned-rans``) that are not at hand, or tables
    given for them belong to another model or are malformed."""


class LimitExceededError(FormatError):
    """A declared size, count, depth or shape exceeds a documented limit; nothing was allocated."""


# --- archives ------------------------------------------------------------------------------------
class ArchiveError(FormatError):
    """A multi-scene archive is damaged or used wrongly."""


class ArchiveLockedError(ArchiveError, OSError):
    """Another writer holds the archive's lock."""


class RangeNotSupportedError(Vt4dError, OSError):
    """A remote server ignores byte-range requests (HTTP ``Range``), which random access needs."""


class SceneNotFoundError(ArchiveError, KeyError):
    """No scene with that key is committed in the archive."""

    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0]) if self.args else "scene not found"


# --- cameras and captures ------------------------------------------------------------------------
class CameraError(Vt4dError, ValueError):
    """Camera parameters break the conventions (non-finite, non-orthonormal rotation, f <= 0, ...)."""


class CaptureError(Vt4dError, ValueError):
    """A capture directory is incomplete or inconsistent (missing files, frame counts differ, ...)."""


class TrajectoryError(CameraError):
    """A target trajectory is invalid or cannot be built from the given parameters."""


# --- models and the codec ------------------------------------------------------------------------
class ModelError(Vt4dError, ValueError):
    """A model config or weights file is invalid."""


class ModelNotFoundError(ModelError, LookupError):
    """No shipped model has that id and no path by that name exists."""


class ModelMismatchError(ModelError):
    """The tokens were made by a different model than the one asked to decode them."""


# --- where the codec runs --------------------------------------------------------------------------
class DeviceError(Vt4dError, RuntimeError):
    """The device asked for (``device="cuda"``, ``--device cuda``) is not there, or is not a known device."""


class MissingExtraError(Vt4dError, ImportError):
    """What was asked needs a package of an optional extra that is not installed (the message names the extra,
    e.g. ``pip install -e ".[train]"`` for anything that runs the torch networks)."""
