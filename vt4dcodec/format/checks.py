"""Small typed-check helpers shared by the header and fingerprint parsers (raise FormatError kinds)."""

from __future__ import annotations

import re
from typing import Any

from ..errors import FormatError, MalformedHeaderError

__all__ = ["require_map", "require_int", "require_str", "require_bool", "require_shape", "require_sha256",
           "exact_keys"]

_HEX64 = re.compile(r"[0-9a-f]{64}")


def require_map(value: Any, what: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise MalformedHeaderError(f"{what} must be a map, got {type(value).__name__}")
    return value


def exact_keys(value: dict[str, Any], required: set[str], what: str, *, allow_extra: bool = False) -> None:
    """Check a map holds exactly ``required`` keys (extra keys allowed only for newer minor versions)."""
    keys = set(value)
    missing = required - keys
    if missing:
        raise MalformedHeaderError(f"{what} is missing key(s) {sorted(missing)}")
    extra = keys - required
    if extra and not allow_extra:
        raise MalformedHeaderError(
            f"{what} has unknown key(s) {sorted(extra)}; version 1.0 allows exactly {sorted(required)}"
        )


def require_int(value: Any, what: str, lo: int, hi: int, error: type[FormatError] = MalformedHeaderError) -> int:
    if type(value) is not int:  # bool is an int subclass: refuse it here
        raise MalformedHeaderError(f"{what} must be an integer, got {type(value).__name__}")
    if not lo <= value <= hi:
        raise error(f"{what} = {value} is outside the allowed range [{lo}, {hi}]")
    return value


def require_bool(value: Any, what: str) -> bool:
    if type(value) is not bool:
        raise MalformedHeaderError(f"{what} must be true or false, got {type(value).__name__}")
    return value


def require_str(value: Any, what: str, *, max_chars: int = 256, min_chars: int = 1,
                pattern: re.Pattern[str] | None = None, hint: str = "") -> str:
    if not isinstance(value, str):
        raise MalformedHeaderError(f"{what} must be a string, got {type(value).__name__}")
    if not min_chars <= len(value) <= max_chars:
        raise MalformedHeaderError(f"{what} must have {min_chars}..{max_chars} characters, got {len(value)}")
    if pattern is not None and not pattern.fullmatch(value):
        raise MalformedHeaderError(f"{what} = {value[:80]!r} is not valid{': ' + hint if hint else ''}")
    return value


def require_sha256(value: Any, what: str) -> str:
    return require_str(value, what, max_chars=64, min_chars=64, pattern=_HEX64,
                       hint="expected 64 lowercase hexadecimal digits (a SHA-256)")


def require_shape(value: Any, what: str, max_rows: int, max_cols: int, max_values: int,
                  error: type[FormatError] = MalformedHeaderError) -> tuple[int, int]:
    """A ``[rows, cols]`` pair with 1 <= rows <= max_rows, 1 <= cols <= max_cols, rows*cols <= max_values."""
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise MalformedHeaderError(f"{what} must be a pair [rows, cols], got {value!r:.80}")
    rows = require_int(value[0], f"{what}[0]", 1, max_rows, error)
    cols = require_int(value[1], f"{what}[1]", 1, max_cols, error)
    if rows * cols > max_values:
        raise error(f"{what} = {rows}x{cols} holds more than {max_values} values")
    return rows, cols
