"""Shared helpers for the archive tests: deterministic opaque payloads and real scene records."""

from __future__ import annotations

import functools
import hashlib


def payload_for(key: str, size: int | None = None) -> bytes:
    """Deterministic opaque record bytes for ``key`` (length 1..4096 unless given)."""
    digest = hashlib.sha256(key.encode()).digest()
    n = size if size is not None else 1 + int.from_bytes(digest[:2], "little") % 4096
    out = bytearray()
    block = digest
    while len(out) < n:
        block = hashlib.sha256(block).digest()
        out += block
    return bytes(out[:n])


@functools.lru_cache(maxsize=None)
def scene_record(seed: int) -> bytes:
    """A real ``.vt4d`` record (small shapes so tests stay fast)."""
    from vt4dcodec.archive.examples import example_record

    return example_record(seed, static_shape=(16, 8), dynamic_shape=(8, 8), frames=2)
