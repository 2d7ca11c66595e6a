"""User metadata: bounded JSON-like key/values (FORMAT.md, "Metadata").

Allowed values: str, int (signed 64-bit), finite float, bool, None, lists and str-keyed maps of those,
at most MAX_METADATA_DEPTH levels deep (the top map counts as 1) and MAX_METADATA_BYTES once encoded.
"""

from __future__ import annotations

import math
from typing import Any, TypeAlias

import msgpack
import numpy as np

from ..errors import LimitExceededError, MalformedHeaderError
from .limits import MAX_METADATA_BYTES, MAX_METADATA_DEPTH, MAX_STRING_CHARS

__all__ = ["normalize_metadata", "packed_metadata_size"]

_INT64 = (-(1 << 63), (1 << 63) - 1)

# A metadata value once normalized.
MetadataValue: TypeAlias = "str | int | float | bool | None | list[MetadataValue] | dict[str, MetadataValue]"


def normalize_metadata(value: Any) -> dict[str, Any]:
    """Validate user metadata and return a plain copy (tuples become lists).

    Raises MalformedHeaderError for a disallowed type and LimitExceededError for depth or size.
    """
    if not isinstance(value, dict):
        raise MalformedHeaderError(f"metadata must be a map of str keys, got {type(value).__name__}")
    out = _normalize_map(value, "metadata", 1)
    size = packed_metadata_size(out)
    if size > MAX_METADATA_BYTES:
        raise LimitExceededError(
            f"metadata is {size} bytes once encoded; the limit is {MAX_METADATA_BYTES} (store bulk data elsewhere)"
        )
    return out


def packed_metadata_size(value: dict[str, Any]) -> int:
    return len(msgpack.packb(value, use_bin_type=True))


def _normalize_map(value: dict[Any, Any], path: str, depth: int) -> dict[str, MetadataValue]:
    out = {}
    for k, v in value.items():
        if not isinstance(k, str):
            raise MalformedHeaderError(f"{path} has a non-string key {k!r:.40}; keys must be str")
        _check_str(k, f"{path} key")
        out[k] = _normalize(v, f"{path}.{k[:40]}", depth + 1)
    return out


def _normalize(value: Any, path: str, depth: int) -> MetadataValue:
    # Iterative depth is bounded by MAX_METADATA_DEPTH, so recursion here is at most 8 deep.
    if isinstance(value, (dict, list, tuple)) and depth > MAX_METADATA_DEPTH:
        raise LimitExceededError(f"{path} nests deeper than {MAX_METADATA_DEPTH} levels")
    if isinstance(value, dict):
        return _normalize_map(value, path, depth)
    if isinstance(value, (list, tuple)):
        return [_normalize(v, f"{path}[{i}]", depth + 1) for i, v in enumerate(value)]
    if value is None or isinstance(value, (bool, np.bool_)):
        return None if value is None else bool(value)
    if isinstance(value, np.integer):
        value = int(value)
    if isinstance(value, np.floating):
        value = float(value)
    if isinstance(value, int):
        if not _INT64[0] <= value <= _INT64[1]:
            raise MalformedHeaderError(f"{path} = {value} does not fit a signed 64-bit integer")
        return int(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise MalformedHeaderError(f"{path} is {value}; metadata floats must be finite")
        return float(value)
    if isinstance(value, str):
        return _check_str(value, path)
    raise MalformedHeaderError(
        f"{path} has type {type(value).__name__}; metadata allows str, int, float, bool, None, lists and maps"
    )


def _check_str(value: str, path: str) -> str:
    if len(value.encode("utf-8", "surrogatepass")) > MAX_STRING_CHARS:
        raise LimitExceededError(f"{path} is a string longer than {MAX_STRING_CHARS} bytes")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        raise MalformedHeaderError(f"{path} is not valid Unicode text (lone surrogate)") from None
    return value
