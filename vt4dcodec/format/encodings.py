"""Token encodings: how an (N, d) float32 token matrix becomes section bytes and back (FORMAT.md,
"Token encodings").

=========  ===========================  =============================================================
encoding   stored per value             maximum error |x - decode(encode(x))|
=========  ===========================  =============================================================
float32    little-endian IEEE binary32  0 (lossless)
float16    little-endian IEEE binary16  max(2^-11 * |x|, 2^-25); |x| must be <= 65504
int8       u8 code, per-channel affine  scale_c / 2 * (1 + 2^-20) + 2^-23 * max(|lo_c|, |hi_c|)
                                        + (2^b - 1) * 2^-150 (scales rounded in the subnormal range)
int4       u4 code, two per byte        same formula with the 4-bit scale
int<b>-rans  b-bit code (b = 2..8),     same formula with the b-bit scale of the code's channel group
           rANS entropy-coded           (format 1.1, interleaved lanes 1.5; see rans_tokens.py)
=========  ===========================  =============================================================

Affine encodings (b = 8 or 4 bits, channel c = column of the token matrix):
``lo_c = min x[:, c]``, ``hi_c = max x[:, c]`` (float32), ``scale_c = float32((hi_c - lo_c) / (2^b - 1))``
computed in float64 then rounded to float32, ``offset_c = lo_c``.  Codes
``q = clip(round_half_to_even((x - offset_c) / scale_c), 0, 2^b - 1)`` in float64 (``q = 0`` where
``scale_c == 0``).  Decoding: ``x = float32(float64(offset_c) + float64(scale_c) * q)``.
int4 packs the row-major code sequence two per byte, element ``2i`` in the LOW nibble and ``2i+1`` in the
HIGH nibble of byte ``i``; an odd count leaves the last high nibble 0.
The quantization section holds ``scale[0..d)`` then ``offset[0..d)``, little-endian float32.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import FormatError, MalformedSectionError
from .affine import affine_codes, group_params
from .layout import BytesLike
from .rans_tokens import (RANS_BITS, RANS_ENCODINGS, check_groups, decode_rans_codes, decode_rans_tokens,
                          encode_rans_tokens)

__all__ = ["ENCODINGS", "V1_0_ENCODINGS", "RANS_ENCODINGS", "EncodedTokens", "encode_tokens", "decode_tokens",
           "codes_from_payload", "dequantize", "payload_size", "is_affine", "is_entropy_coded", "is_learned", "LEARNED_ENCODING", "ALL_ENCODINGS", "FLOAT16_MAX", "max_abs_error"]

V1_0_ENCODINGS = ("float32", "float16", "int8", "int4")
LEARNED_ENCODING = "learned-rans"  # format 1.6: the model's quantizer and entropy tables (learned.py)
# the encodings whose file carries everything to decode it; learned-rans also needs its model's tables
ENCODINGS = V1_0_ENCODINGS + RANS_ENCODINGS
ALL_ENCODINGS = ENCODINGS + (LEARNED_ENCODING,)
_BITS = {"int8": 8, "int4": 4}
FLOAT16_MAX = 65504.0


def is_affine(encoding: str) -> bool:
    """True for the encodings that store per-channel scale/offset (a quantization section)."""
    return encoding in _BITS


def is_entropy_coded(encoding: str) -> bool:
    """True for the ``int<b>-rans`` encodings (format 1.1, required feature flag bit 0)."""
    return encoding in RANS_BITS


def is_learned(encoding: str) -> bool:
    """True for ``learned-rans`` (format 1.6, required feature flag bit 5): codes of the model's tables."""
    return encoding == LEARNED_ENCODING


def payload_size(encoding: str, rows: int, cols: int) -> int:
    """Bytes of the raw (uncompressed) token payload for an (rows, cols) matrix (fixed-size encodings)."""
    n = rows * cols
    return {"float32": 4 * n, "float16": 2 * n, "int8": n, "int4": (n + 1) // 2}[encoding]


@dataclass(frozen=True)
class EncodedTokens:
    """Section payloads of one token matrix: ``tokens`` bytes and, for affine encodings, ``quant`` bytes."""

    tokens: bytes
    quant: bytes | None


def _affine_params(x: np.ndarray, bits: int) -> tuple[np.ndarray, np.ndarray]:
    return group_params(x, bits, x.shape[1])  # per channel


def encode_tokens(tokens: np.ndarray, encoding: str, *, groups: int = 1, lanes: int | None = None) -> EncodedTokens:
    """Encode finite float32 tokens (N, d) with ``encoding``; deterministic (round half to even).

    ``groups``: channel groups of the ``int<b>-rans`` encodings (1 = one scale/offset for the matrix,
    d = per channel; must divide d); ``lanes``: their rANS lanes, None for the 1.1 layout (one chain) or
    K = 1..32 for the 1.5 layout (a file with required flag bit 4).  Both are ignored by the other encodings.
    """
    x = np.ascontiguousarray(tokens, dtype=np.float32)
    if encoding in RANS_BITS:
        return EncodedTokens(encode_rans_tokens(x, encoding, groups, lanes=lanes), None)
    if encoding == "float32":
        return EncodedTokens(x.astype("<f4", copy=False).tobytes(), None)
    if encoding == "float16":
        big = float(np.abs(x).max(initial=0.0))
        if big > FLOAT16_MAX:
            raise FormatError(
                f"tokens reach |x| = {big:.6g}, beyond float16's range (65504); use int8 or float32"
            )
        return EncodedTokens(x.astype("<f2").tobytes(), None)
    if encoding not in _BITS:
        raise FormatError(f"unknown token encoding {encoding!r}; choose one of {ENCODINGS}")
    bits = _BITS[encoding]
    scale, offset = _affine_params(x, bits)
    codes = affine_codes(x, scale, offset, bits)
    quant = np.concatenate([scale, offset]).astype("<f4").tobytes()
    if bits == 8:
        return EncodedTokens(codes.tobytes(), quant)
    flat = codes.reshape(-1)
    if flat.size % 2:
        flat = np.concatenate([flat, np.zeros(1, np.uint8)])
    packed = (flat[0::2] | (flat[1::2] << 4)).astype(np.uint8)
    return EncodedTokens(packed.tobytes(), quant)


def codes_from_payload(payload: BytesLike, encoding: str, rows: int, cols: int, *, lanes: bool = False) -> np.ndarray:
    """The stored values as an (rows, cols) array without dequantizing.

    float32 / float16 / int8 payloads are returned as zero-copy read-only views of ``payload``; int4
    codes are unpacked and ``int<b>-rans`` codes entropy-decoded into new uint8 arrays (``lanes``: the file
    sets required flag bit 4, so each payload holds its lane count).  Raises MalformedSectionError if the
    size is wrong or an int4 padding nibble is not zero.
    """
    if encoding in RANS_BITS:
        return decode_rans_codes(payload, encoding, rows, cols, lanes=lanes)[0]
    expected = payload_size(encoding, rows, cols)
    if len(payload) != expected:
        raise MalformedSectionError(
            f"{encoding} token payload is {len(payload)} bytes; a {rows}x{cols} matrix needs {expected}"
        )
    if encoding in ("float32", "float16", "int8"):
        dtype = {"float32": "<f4", "float16": "<f2", "int8": "u1"}[encoding]
        return np.frombuffer(payload, dtype=dtype).reshape(rows, cols)
    packed = np.frombuffer(payload, dtype=np.uint8)
    n = rows * cols
    if n % 2 and packed[-1] >> 4:
        raise MalformedSectionError("int4 payload: the unused last high nibble must be 0")
    codes = np.empty(2 * packed.size, np.uint8)
    codes[0::2] = packed & 0x0F
    codes[1::2] = packed >> 4
    return codes[:n].reshape(rows, cols)


def float16_to_float32(half: np.ndarray) -> np.ndarray:
    """Exact binary16 -> binary32 conversion by bit arithmetic (about 2.5x faster than numpy's astype).

    The magnitude bits shifted into binary32 position are a binary32 value 2^-112 times too small (normal
    and subnormal halves alike); multiplying by 2^112 is exact.  Inf/NaN inputs are not handled: callers
    reject them (decode_tokens checks the decoded values are finite).
    """
    bits = np.ascontiguousarray(half).view(np.uint16)
    mag = ((bits & 0x7FFF).astype(np.uint32) << 13).view(np.float32) * np.float32(2.0**112)
    return (mag.view(np.uint32) | ((bits & 0x8000).astype(np.uint32) << 16)).view(np.float32)


def parse_quant(payload: BytesLike, cols: int) -> tuple[np.ndarray, np.ndarray]:
    """(scale, offset) float32 (cols,) arrays from a quantization payload; both finite, scale >= 0."""
    if len(payload) != 8 * cols:
        raise MalformedSectionError(
            f"quantization payload is {len(payload)} bytes; d = {cols} needs {8 * cols} (scale + offset)"
        )
    both = np.frombuffer(payload, dtype="<f4")
    scale, offset = both[:cols], both[cols:]
    if not (np.all(np.isfinite(both)) and np.all(scale >= 0)):
        raise MalformedSectionError("quantization parameters must be finite with scale >= 0")
    return scale, offset


def decode_tokens(payload: BytesLike, quant: BytesLike | None, encoding: str, rows: int, cols: int, *,
                  lanes: bool = False) -> np.ndarray:
    """Decode a token payload into (rows, cols) float32 values (``lanes`` as in :func:`codes_from_payload`).

    float32 payloads come back as zero-copy read-only views.  Every decoded value must be finite,
    otherwise MalformedSectionError (a reader never hands out NaN/inf tokens).
    """
    if encoding in RANS_BITS:
        out = decode_rans_tokens(payload, encoding, rows, cols, lanes=lanes)  # the compiled one-pass path
        if out is None:
            codes, scale, offset = decode_rans_codes(payload, encoding, rows, cols, lanes=lanes)
            out = dequantize(codes, scale, offset, RANS_BITS[encoding], encoding)
        return out
    codes = codes_from_payload(payload, encoding, rows, cols)
    if encoding in _BITS:
        if quant is None:
            raise FormatError(f"{encoding} tokens cannot be decoded without their quantization section")
        scale, offset = parse_quant(quant, cols)
        return dequantize(codes, scale, offset, _BITS[encoding], encoding)
    if encoding == "float32":
        out = codes
    else:
        if np.any((codes.view(np.uint16) & 0x7C00) == 0x7C00):  # exponent all ones: inf or NaN
            raise MalformedSectionError("float16 token section holds non-finite values")
        out = float16_to_float32(codes)
    if not np.all(np.isfinite(out)):
        raise MalformedSectionError(f"{encoding} token section decodes to non-finite values")
    return out


_F32_MAX = float(np.finfo(np.float32).max)
_native_dequantize: Callable[[np.ndarray, int, np.ndarray, np.ndarray, np.ndarray], bool] | None
try:  # the compiled dequantization of vt4dcodec.format._rans_native (absent: the numpy formula below)
    from . import _rans_native as _compiled  # (the import form rans.py uses: the import contracts resolve it)
    _native_dequantize = _compiled.dequantize_u8
except ImportError:  # pragma: no cover - a build without the extension
    _native_dequantize = None


def dequantize(codes: np.ndarray, scale: np.ndarray, offset: np.ndarray, bits: int, encoding: str) -> np.ndarray:
    """``f32(f64(offset_c) + f64(scale_c) * q)`` for uint8 codes (rows, cols) and per-channel float32
    parameters (cols,); MalformedSectionError if any value is not finite.

    Computed in place in one float64 buffer: the same IEEE operations as the formula, but without the
    broadcast temporaries whose fresh pages cost ~8x the arithmetic.  Finiteness: ``scale >= 0`` makes each
    channel's values non-decreasing in ``q`` (and rounding to float32 keeps that), so when every channel's
    top value ``q = 2^b - 1`` is finite, all are; only otherwise is every value checked.
    """
    if _native_dequantize is not None and codes.dtype == np.uint8 and codes.ndim == 2 and codes.shape[1] > 0:
        # the same formula per value in C (~2.5x faster than float64 passes over every value); False where a
        # column's values would not all be finite float32, which the checked path below then reports
        out = np.empty(codes.shape, np.float32)
        if _native_dequantize(np.ascontiguousarray(codes), codes.shape[1], np.ascontiguousarray(scale, np.float32),
                              np.ascontiguousarray(offset, np.float32), out):
            return out
    s64, o64 = scale.astype(np.float64), offset.astype(np.float64)
    q = codes.astype(np.float64)
    q *= s64
    q += o64
    top64 = o64 + s64 * float((1 << bits) - 1)
    if float(np.abs(o64).max(initial=0.0)) <= _F32_MAX and float(np.abs(top64).max(initial=0.0)) <= _F32_MAX:
        return q.astype(np.float32)  # every value within float32's range: nothing overflows
    with np.errstate(over="ignore", invalid="ignore"):  # values beyond float32 become inf and are refused below
        out = q.astype(np.float32)
        top = top64.astype(np.float32)
    if not np.all(np.isfinite(top)):
        if not np.all(np.isfinite(out)):
            raise MalformedSectionError(f"{encoding} token section decodes to non-finite values")
    return out


def max_abs_error(tokens: np.ndarray, encoding: str, *, groups: int = 1) -> np.ndarray:
    """The documented worst-case |x - decode(encode(x))| for each entry of ``tokens`` (N, d)
    (``groups`` as in :func:`encode_tokens`, for the ``int<b>-rans`` encodings)."""
    x = np.asarray(tokens, dtype=np.float32).astype(np.float64)
    if encoding == "float32":
        return np.zeros_like(x)
    if encoding == "float16":
        return np.maximum(2.0**-11 * np.abs(x), 2.0**-25)
    if encoding in RANS_BITS:
        check_groups(groups, x.shape[1])
        bits = RANS_BITS[encoding]
    else:
        bits, groups = _BITS[encoding], x.shape[1]  # int8 / int4: per channel
    width = x.shape[1] // groups
    scale = np.repeat(group_params(np.asarray(tokens, np.float32), bits, groups)[0], width)
    grouped = x.reshape(x.shape[0], groups, width)
    big = np.repeat(np.maximum(np.abs(grouped.min(axis=(0, 2))), np.abs(grouped.max(axis=(0, 2)))), width)
    # the last term: a scale that rounds in binary32's subnormal range (or to 0) is off by up to 2^-150
    bound = scale.astype(np.float64) / 2 * (1 + 2.0**-20) + 2.0**-23 * big + ((1 << bits) - 1) * 2.0**-150
    return np.broadcast_to(bound, x.shape)
