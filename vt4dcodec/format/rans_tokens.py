"""Entropy-coded token encodings ``int2-rans`` .. ``int8-rans`` (FORMAT.md, "Entropy-coded token
encodings"; format version 1.1, required feature flag bit 0).

A token matrix X (N, d) is quantized with ``b`` bits per value by the same affine rule as ``int8``, but
with one (scale, offset) pair per *group* of ``d / G`` consecutive channels (G = 1: one pair for the
whole matrix; G = d: per channel).  The N*d codes (row-major) are rANS-coded with one static frequency
table stored in the section, either as they are (prediction 0) or as residuals from a per-channel centre
code (prediction 1: symbol = q - centre_c + 2^b - 1), whichever is smaller.  Token section payload,
little-endian::

    u16        G          number of channel groups, 1 <= G <= d, d % G == 0
    f32[G]     scale      per group, finite, >= 0
    f32[G]     offset     per group, finite
    u8         P          prediction: 0 = none, 1 = per-channel centre codes
    u8[d]      centre     (P = 1 only) each < 2^b; the writer uses the lower median of the channel's codes
    table                 frequency table over 0 .. 2^b - 1 (P = 0) or 0 .. 2^(b+1) - 2 (P = 1) (rans.py)
    u8         K          (format 1.5, required flag bit 4, only) lanes of the stream, 1 <= K <= 32
    stream                the rANS stream of the N*d symbols, to the end of the payload (rans.py): one
                          chain, or with K the K lane states and their shared bytes

Decoding: ``q = symbol`` (P = 0) or ``q = symbol - (2^b - 1) + centre_c`` (P = 1, must lie in
0 .. 2^b - 1), then ``x[i, c] = f32(f64(offset_g) + f64(scale_g) * q[i, c])`` with ``g = c // (d / G)``;
the maximum error is the int8 formula with the group's scale and range.

Lanes (format 1.5): symbol k of a K-lane stream is decoded by lane k mod K, so a reader runs K independent
chains of dependent steps at once (~2.6x the speed of one chain in C with K = 8).  The writer's policy
(:func:`policy_lanes`): ``DEFAULT_LANES`` lanes for a matrix of ``LANES_MIN_VALUES`` values or more, else the
1.1 single chain, so small scenes keep their bytes and version.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import FormatError, LimitExceededError, MalformedSectionError, TruncatedError
from . import rans
from .affine import affine_codes, group_params
from .layout import BytesLike

__all__ = ["RANS_ENCODINGS", "RANS_BITS", "MAX_RANS_VALUES", "MAX_LANES", "DEFAULT_LANES", "LANES_MIN_VALUES",
           "encode_rans_tokens", "decode_rans_codes", "decode_rans_tokens", "decode_rans_token_pair",
           "check_groups", "check_lanes", "policy_lanes"]

RANS_BITS = {f"int{b}-rans": b for b in (2, 3, 4, 5, 6, 7, 8)}
RANS_ENCODINGS = tuple(RANS_BITS)
MAX_RANS_VALUES = 1 << 21  # N * d per entropy-coded matrix: bounds the decoder's work (~10 ms in C, ~0.5 s in pure Python)
PREDICT_NONE, PREDICT_CENTRE = 0, 1
MAX_LANES = rans.MAX_LANES  # K of a 1.5 payload: 1 .. 32
# The writer's lane policy: K = 8 for a matrix of 2^15 values or more (a paper-size scene's 1024x64 and 512x64
# both), the 1.1 single chain below.  8 lanes decode a paper-size int5-rans scene in ~0.15 ms, 4 in ~0.18 ms,
# one chain per section in ~0.40 ms (C, this project's machine; FORMAT.md I.6.1), for ~25 bytes more per
# matrix than one chain; 8 encode as fast as 4 and a little faster than one chain.
DEFAULT_LANES = 8
LANES_MIN_VALUES = 1 << 15


def check_groups(groups: int, cols: int) -> None:
    if isinstance(groups, bool) or not isinstance(groups, int) or not 1 <= groups <= cols or cols % groups:
        raise FormatError(f"quantization groups must divide d = {cols} (1 <= groups <= d), got {groups!r}")


def check_lanes(lanes: int | None) -> None:
    """``None`` (the writer's policy), 0 (no lanes: the 1.1 layout) or a lane count 1..32 (format 1.5)."""
    no_lanes = lanes is None or (isinstance(lanes, int) and not isinstance(lanes, bool) and lanes == 0)
    if not no_lanes and not rans.is_lane_count(lanes):
        raise FormatError(f"rans_lanes must be None (the writer's policy), 0 (no lanes, format 1.1) or a lane count "
                          f"1..{MAX_LANES} (format 1.5), got {lanes!r}")


def policy_lanes(values: int) -> int | None:
    """The writer's lanes for a matrix of ``values`` codes: ``DEFAULT_LANES`` from ``LANES_MIN_VALUES`` on,
    else None (one chain: the 1.1 layout, or K = 1 in a file that has lanes for its other matrix)."""
    return DEFAULT_LANES if values >= LANES_MIN_VALUES else None


def _entropy_parts(*parts: tuple[np.ndarray, np.ndarray], lanes: int | None = None) -> list[bytes]:
    """Frequency table [+ lane count K] + rANS stream of each ``(symbols (1-D uint16), their histogram)``
    (1 or 2, coded in one interleaved pass); ``lanes`` None: no K byte, one chain (the 1.1 layout)."""
    freqs = [rans.normalize_counts(counts) for _, counts in parts]
    k = 1 if lanes is None else lanes
    streams = rans.rans_encode_many([(symbols, f) for (symbols, _), f in zip(parts, freqs)], lanes=[k] * len(parts))
    field = b"" if lanes is None else bytes([lanes])
    return [rans.pack_table(f) + field + stream for f, stream in zip(freqs, streams)]


def column_histograms(codes: np.ndarray, bits: int) -> np.ndarray:
    """int64 (d, 2^b): ``hist[c, v]`` = how many rows of ``codes`` (N, d) hold code ``v`` in column ``c``."""
    d, size = codes.shape[1], 1 << bits
    if rans.NATIVE:
        hist = np.zeros((d, size), np.int64)
        rans._rans_native.column_histograms(np.ascontiguousarray(codes, dtype=np.uint8), d, size, hist)
        return hist
    keyed = codes.astype(np.intp) + np.arange(d, dtype=np.intp) * size
    return np.bincount(keyed.reshape(-1), minlength=d * size).reshape(d, size)


def lower_median_codes(codes: np.ndarray, bits: int, hist: np.ndarray | None = None) -> np.ndarray:
    """uint8 (d,): element ``(N - 1) // 2`` of each sorted column of ``codes`` (N, d), in O(N d) from the
    column histograms (the smallest ``v`` with more than ``(N - 1) // 2`` codes ``<= v``)."""
    hist = column_histograms(codes, bits) if hist is None else hist
    at_or_below: np.ndarray = (np.cumsum(hist, axis=1) <= (codes.shape[0] - 1) // 2).sum(axis=1)
    return at_or_below.astype(np.uint8)


def encode_rans_tokens(x: np.ndarray, encoding: str, groups: int = 1, *, lanes: int | None = None,
                       _shortcut: bool = True) -> bytes:
    """The token section payload of finite float32 tokens ``x`` (N, d) in ``encoding`` (deterministic:
    both predictions are coded and the shorter kept, prediction 0 on a tie).  ``lanes``: None for the 1.1
    layout (one chain, no lane count), K = 1..32 for the 1.5 layout of a file with required flag bit 4.

    Shortcut (exact): when every channel has the same centre code, the residuals are the codes shifted
    by one constant, so their counts, normalised frequencies (ties break by symbol order, which a shift
    keeps), table length and stream bytes are those of prediction 0 shifted; prediction 1 is then longer by
    its d centre bytes and is not coded.  (``_shortcut=False`` codes it anyway, for the tests.)"""
    bits = RANS_BITS[encoding]
    n, d = x.shape
    check_groups(groups, d)
    if lanes is not None and not rans.is_lane_count(lanes):
        raise FormatError(f"a 1.5 payload has 1 to {MAX_LANES} rANS lanes, got {lanes!r}")
    if n * d > MAX_RANS_VALUES:
        raise LimitExceededError(f"{n}x{d} tokens exceed the {MAX_RANS_VALUES} values an entropy-coded "
                                 "matrix may hold; use int8 or int4")
    scale, offset = group_params(x, bits, groups)
    width, top = d // groups, (1 << bits) - 1
    codes = affine_codes(x, np.repeat(scale, width), np.repeat(offset, width), bits)
    head = struct.pack("<H", groups) + np.concatenate([scale, offset]).astype("<f4").tobytes()
    # One pass of counting serves the median and both predictions' frequency tables.
    hist = column_histograms(codes, bits)
    plain_part = (codes.reshape(-1).astype(np.uint16), hist.sum(axis=0))
    centre = lower_median_codes(codes, bits, hist)
    if _shortcut and np.all(centre == centre[0]):
        return head + bytes([PREDICT_NONE]) + _entropy_parts(plain_part, lanes=lanes)[0]
    shifted = np.arange(top + 1)[None, :] + top - centre[:, None].astype(np.intp)  # residual of code v in column c
    res_counts = np.bincount(shifted.reshape(-1), weights=hist.reshape(-1), minlength=2 * top + 1).astype(np.int64)
    residual = (codes.astype(np.uint16) + np.uint16(top) - centre).reshape(-1)  # in 0 .. 2^(b+1) - 2
    plain_bytes, predicted_bytes = _entropy_parts(plain_part, (residual, res_counts), lanes=lanes)
    plain = bytes([PREDICT_NONE]) + plain_bytes
    predicted = bytes([PREDICT_CENTRE]) + centre.tobytes() + predicted_bytes
    return head + (predicted if len(predicted) < len(plain) else plain)


@dataclass(frozen=True)
class _Payload:
    """The checked fields of an int<b>-rans token payload, up to its rANS stream."""

    top: int
    groups: int
    scale: np.ndarray      # float32 (groups,)
    offset: np.ndarray     # float32 (groups,)
    centre: np.ndarray | None  # uint8 (cols,) with prediction 1
    freqs: list[int]
    lanes: int             # K: 1 in the 1.1 layout
    stream: memoryview


def _parse_payload(payload: BytesLike, encoding: str, rows: int, cols: int, lanes: bool = False) -> _Payload:
    bits = RANS_BITS[encoding]
    top = (1 << bits) - 1
    data = bytes(payload)
    if rows * cols > MAX_RANS_VALUES:
        raise LimitExceededError(f"{rows}x{cols} tokens exceed the {MAX_RANS_VALUES}-value limit of {encoding}")
    if len(data) < 2:
        raise TruncatedError(f"{encoding} section is {len(data)} bytes, shorter than its group count")
    groups = struct.unpack_from("<H", data)[0]
    if not 1 <= groups <= cols or cols % groups:
        raise MalformedSectionError(f"{encoding} section has {groups} channel groups; they must divide d = {cols}")
    mode_at = 2 + 8 * groups
    if len(data) < mode_at + 1:
        raise TruncatedError(f"{encoding} section ends inside its {groups} quantization parameter pairs")
    both = np.frombuffer(data, dtype="<f4", count=2 * groups, offset=2)
    scale, offset = both[:groups], both[groups:]
    if not (np.all(np.isfinite(both)) and np.all(scale >= 0)):
        raise MalformedSectionError("quantization parameters must be finite with scale >= 0")
    mode, table_at, centre = data[mode_at], mode_at + 1, None
    if mode == PREDICT_CENTRE:
        if len(data) < table_at + cols:
            raise TruncatedError(f"{encoding} section ends inside its {cols} centre codes")
        centre = np.frombuffer(data, dtype=np.uint8, count=cols, offset=table_at)
        if np.any(centre > top):
            raise MalformedSectionError(f"{encoding} centre code above {top}")
        table_at += cols
    elif mode != PREDICT_NONE:
        raise MalformedSectionError(f"{encoding} section has unknown prediction mode {mode}")
    alphabet = (1 << bits) if mode == PREDICT_NONE else (2 << bits) - 1
    freqs, used = rans.parse_table(memoryview(data)[table_at:], alphabet)
    stream_at, count = table_at + used, 1
    if lanes:  # format 1.5 (required flag bit 4): u8 K, then the K lane states and their shared bytes
        if len(data) <= stream_at:
            raise TruncatedError(f"{encoding} section ends before its rANS lane count")
        count, stream_at = data[stream_at], stream_at + 1
        if not 1 <= count <= MAX_LANES:
            raise MalformedSectionError(f"{encoding} section has {count} rANS lanes; a stream has 1 to {MAX_LANES}")
    return _Payload(top, groups, scale, offset, centre, freqs, count, memoryview(data)[stream_at:])


def _residual_error(encoding: str, top: int) -> MalformedSectionError:
    return MalformedSectionError(f"{encoding} residuals decode to codes outside 0..{top}")


def decode_rans_codes(payload: BytesLike, encoding: str, rows: int, cols: int, *,
                      lanes: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(codes uint8 (rows, cols), scale float32 (cols,), offset float32 (cols,)) of a token payload
    (``lanes``: the file sets required flag bit 4, format 1.5, so the payload holds its lane count K).

    Every field is checked before use: group count, parameters finite with scale >= 0, prediction mode and
    centre codes, the frequency table, the lane count, the stream length and its clean end, every code in
    range.  Raises MalformedSectionError / TruncatedError / LimitExceededError.
    """
    p = _parse_payload(payload, encoding, rows, cols, lanes)
    symbols = rans.rans_decode(p.stream, p.freqs, rows * cols, p.lanes).reshape(rows, cols)
    if p.centre is not None:  # int16 in place: no large temporaries (their fresh pages cost more than the sums)
        codes = symbols.astype(np.int16)
        codes += p.centre.astype(np.int16) - p.top
        if codes.min() < 0 or codes.max() > p.top:
            raise _residual_error(encoding, p.top)
        symbols = codes
    width = cols // p.groups
    return (symbols.astype(np.uint8), np.repeat(p.scale, width).astype(np.float32),
            np.repeat(p.offset, width).astype(np.float32))


def decode_rans_tokens(payload: BytesLike, encoding: str, rows: int, cols: int, *,
                       lanes: bool = False) -> np.ndarray | None:
    """The float32 (rows, cols) tokens of a payload, decoded, mapped to codes and dequantized in one pass
    by the compiled coder through a table ``lut[g, q] = f32(f64(offset_g) + f64(scale_g) * q)`` (the
    decoding formula, evaluated once per group and code); non-finite values raise MalformedSectionError.
    None where that path does not apply (pure-Python coder, one-symbol table): use decode_rans_codes.
    ``lanes`` as in :func:`decode_rans_codes`."""
    out = decode_rans_token_pair([(payload, rows, cols)], encoding, lanes=lanes)
    return None if out is None else out[0]


def decode_rans_token_pair(sections: Sequence[tuple[BytesLike, int, int]], encoding: str, *,
                           lanes: bool = False) -> list[np.ndarray] | None:
    """:func:`decode_rans_tokens` of 1 or 2 ``(payload, rows, cols)`` (a scene's static and dynamic
    sections), both decoded in one call (single chains interleaved).  Errors are those of decoding the
    sections one after the other, in order (on any error the sections are decoded again one by one to say
    which)."""
    try:
        jobs: list[rans.MappedJob] = []
        parsed = []
        for payload, rows, cols in sections:
            p = _parse_payload(payload, encoding, rows, cols, lanes)
            q = np.arange(p.top + 1, dtype=np.float64)
            with np.errstate(over="ignore", invalid="ignore"):  # entries beyond float32: refused below if used
                lut = (q * p.scale.astype(np.float64)[:, None] + p.offset.astype(np.float64)[:, None]).astype(np.float32)
            colbase = (np.arange(cols) // (cols // p.groups)) * (p.top + 1)
            jobs.append((p.stream, p.freqs, rows, cols, colbase, lut, p.centre, p.top, p.lanes))
            parsed.append((p, lut))
        mapped = rans.rans_decode_mapped(jobs)
        if mapped is None:
            return None
        for (out, bad), (p, lut) in zip(mapped, parsed):
            if bad:
                raise _residual_error(encoding, p.top)
            if not np.all(np.isfinite(lut)) and not np.all(np.isfinite(out)):  # only used entries count
                raise MalformedSectionError(f"{encoding} token section decodes to non-finite values")
        return [out for out, _ in mapped]
    except FormatError:
        if len(sections) == 1:
            raise
        for section in sections:  # the first section's error first, as if decoded one by one
            decode_rans_token_pair([section], encoding, lanes=lanes)
        raise
