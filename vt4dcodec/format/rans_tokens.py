"""Entropy-coded token encodings ``int3-rans`` .. ``int8-rans`` (FORMAT.md, "Entropy-coded token
encodings"; format version 1.1, required feature flag bit 0).

A token matrix X (N, d) is quantized with ``b`` bits per value by the same affine rule as ``int8``, but
with one (scale, offset) pair per *group* of ``d / G`` consecutive channels (G = 1: one pair for the
whole matrix; G = d: per channel), and the N*d codes (row-major) are rANS-coded with one static
frequency table stored in the section.  Token section payload, little-endian::

    u16        G          number of channel groups, 1 <= G <= d, d % G == 0
    f32[G]     scale      per group, finite, >= 0
    f32[G]     offset     per group, finite
    table                 frequency table over the alphabet 0 .. 2^b - 1 (rans.py)
    stream                the rANS stream of the N*d codes, to the end of the payload (rans.py)

Decoding: ``x[i, c] = f32(f64(offset_g) + f64(scale_g) * q[i, c])`` with ``g = c // (d / G)``; the
maximum error is the int8 formula with the group's scale and range.
"""

from __future__ import annotations

import struct

import numpy as np

from ..errors import FormatError, LimitExceededError, MalformedSectionError, TruncatedError
from . import rans
from .affine import affine_codes, group_params

__all__ = ["RANS_ENCODINGS", "RANS_BITS", "MAX_RANS_VALUES", "encode_rans_tokens", "decode_rans_codes",
           "check_groups"]

RANS_BITS = {f"int{b}-rans": b for b in (3, 4, 5, 6, 7, 8)}
RANS_ENCODINGS = tuple(RANS_BITS)
MAX_RANS_VALUES = 1 << 21  # N * d per entropy-coded matrix: bounds the decoder's work (~1 s in pure Python)


def check_groups(groups: int, cols: int) -> None:
    if isinstance(groups, bool) or not isinstance(groups, int) or not 1 <= groups <= cols or cols % groups:
        raise FormatError(f"quantization groups must divide d = {cols} (1 <= groups <= d), got {groups!r}")


def encode_rans_tokens(x: np.ndarray, encoding: str, groups: int = 1) -> bytes:
    """The token section payload of finite float32 tokens ``x`` (N, d) in ``encoding`` (deterministic)."""
    bits = RANS_BITS[encoding]
    n, d = x.shape
    check_groups(groups, d)
    if n * d > MAX_RANS_VALUES:
        raise LimitExceededError(f"{n}x{d} tokens exceed the {MAX_RANS_VALUES} values an entropy-coded "
                                 "matrix may hold; use int8 or int4")
    scale, offset = group_params(x, bits, groups)
    width = d // groups
    codes = affine_codes(x, np.repeat(scale, width), np.repeat(offset, width), bits).reshape(-1)
    freqs = rans.normalize_counts(np.bincount(codes, minlength=1 << bits))
    head = struct.pack("<H", groups) + np.concatenate([scale, offset]).astype("<f4").tobytes()
    return head + rans.pack_table(freqs) + rans.rans_encode(codes, freqs)


def decode_rans_codes(payload, encoding: str, rows: int, cols: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(codes uint8 (rows, cols), scale float32 (cols,), offset float32 (cols,)) of a token payload.

    Every field is checked before use: group count, parameters finite with scale >= 0, the frequency
    table, the stream length and its clean end.  Raises MalformedSectionError / TruncatedError.
    """
    bits = RANS_BITS[encoding]
    data = bytes(payload)
    if rows * cols > MAX_RANS_VALUES:
        raise LimitExceededError(f"{rows}x{cols} tokens exceed the {MAX_RANS_VALUES}-value limit of {encoding}")
    if len(data) < 2:
        raise TruncatedError(f"{encoding} section is {len(data)} bytes, shorter than its group count")
    groups = struct.unpack_from("<H", data)[0]
    if not 1 <= groups <= cols or cols % groups:
        raise MalformedSectionError(f"{encoding} section has {groups} channel groups; they must divide d = {cols}")
    table_at = 2 + 8 * groups
    if len(data) < table_at:
        raise TruncatedError(f"{encoding} section ends inside its {groups} quantization parameter pairs")
    both = np.frombuffer(data, dtype="<f4", count=2 * groups, offset=2)
    scale, offset = both[:groups], both[groups:]
    if not (np.all(np.isfinite(both)) and np.all(scale >= 0)):
        raise MalformedSectionError("quantization parameters must be finite with scale >= 0")
    freqs, used = rans.parse_table(memoryview(data)[table_at:], 1 << bits)
    codes = rans.rans_decode(memoryview(data)[table_at + used:], freqs, rows * cols)
    width = cols // groups
    return (codes.reshape(rows, cols), np.repeat(scale, width).astype(np.float32),
            np.repeat(offset, width).astype(np.float32))
