"""The affine quantizer shared by the int8, int4 and int<b>-rans encodings (FORMAT.md, "Affine encodings").

Per channel group (a whole matrix, single channels, or runs of consecutive channels): ``lo``/``hi`` are
the group's float32 min/max, ``scale = f32((f64(hi) - f64(lo)) / (2^b - 1))``, ``offset = lo``; codes
``clip(round_half_to_even((x - offset) / scale), 0, 2^b - 1)`` in float64 (0 where ``scale == 0``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["group_params", "affine_codes"]


def group_params(x: np.ndarray, bits: int, groups: int) -> tuple[np.ndarray, np.ndarray]:
    """(scale, offset) float32 (groups,) of the affine quantizer over channel groups of ``x`` (N, d)."""
    n, d = x.shape
    grouped = x.reshape(n, groups, d // groups)
    lo = grouped.min(axis=(0, 2)).astype(np.float64)
    hi = grouped.max(axis=(0, 2)).astype(np.float64)
    scale = ((hi - lo) / float((1 << bits) - 1)).astype(np.float32)
    return scale, lo.astype(np.float32)


def affine_codes(x: np.ndarray, scale: np.ndarray, offset: np.ndarray, bits: int) -> np.ndarray:
    """uint8 codes ``clip(rint((x - offset) / scale), 0, 2^b - 1)`` in float64; ``scale``/``offset`` are
    per channel (d,) and broadcast over rows; a zero scale gives code 0."""
    s64 = scale.astype(np.float64)
    safe = np.where(s64 > 0, s64, 1.0)
    q = x.astype(np.float64)  # one float64 buffer, every step in place (same values, fewer passes)
    q -= offset.astype(np.float64)
    q /= safe
    np.rint(q, out=q)  # rint: half to even
    if not np.all(s64 > 0):
        q *= s64 > 0  # zero-scale channels: code 0 (q is finite there: (x - offset) / 1)
    np.clip(q, 0, (1 << bits) - 1, out=q)
    return q.astype(np.uint8)
