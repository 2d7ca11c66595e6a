"""A static rANS entropy coder with integer frequency tables (FORMAT.md, "Entropy-coded token encodings").

Everything here is integer arithmetic on Python ints, so every machine encodes and decodes the same
bytes.  Parameters (normative, fixed by the format):

- probability precision ``PROB_BITS = 14``: frequencies are integers summing to ``M = 2^14``;
- coder state ``x`` is an unsigned 32-bit integer kept in ``[L, 2^32)`` with ``L = 2^23``;
- renormalisation moves single bytes.

Stream = the final encoder state as a little-endian ``u32``, followed by the renormalisation bytes in the
order the decoder reads them.  Decoding one symbol::

    slot = x mod M;  s = the symbol with cum[s] <= slot < cum[s] + freq[s]
    x = freq[s] * (x >> 14) + slot - cum[s]
    while x < L: x = (x << 8) | next stream byte

After the last symbol the state MUST equal ``L`` and every stream byte MUST have been read; both hold for
every stream the encoder makes, so they double as an integrity check.  A hostile stream cannot make the
decoder loop: each symbol reads at most 2 bytes, and running out of bytes is an error.

Interleaved lanes (format 1.5, required flag bit 4): a stream of ``K`` lanes (1 <= K <= 32) starts with
``K`` states (lane 0 first), and symbol ``k`` is decoded with the state of lane ``k mod K``, every lane
reading its renormalisation bytes from the one shared byte stream in symbol order; at the end every lane's
state MUST be ``L``.  ``K = 1`` is the single-chain stream above.  The encoder runs ``k = n-1 .. 0`` with
lane ``k mod K``, each lane starting at ``L``, and writes the ``K`` final states before the reversed bytes.

Frequency table bytes: ``u16 first_symbol``, ``u16 count`` (little-endian), then ``count`` LEB128 varints,
the frequencies of symbols ``first_symbol .. first_symbol + count - 1`` (every other symbol has frequency
0).  Each varint is 1..3 bytes with no redundant trailing zero group, each frequency is at most ``M``, and
they sum to exactly ``M``.

Two implementations of the same coder: ``_rans_native.c`` (built by ``pip install``; decoding ~4 ns a symbol
on one chain, ~1.5 ns with 8 lanes) and the pure-Python loops below (the fallback where no C compiler was found, and the reference the tests hold
the C code to, byte for byte).  :data:`NATIVE` says which one :func:`rans_encode` / :func:`rans_decode` use.
"""

from __future__ import annotations

import bisect

from typing import Sequence

import numpy as np

from ..errors import MalformedSectionError, TruncatedError
from .layout import BytesLike

try:
    from . import _rans_native as _rans_native  # (re-exported: rans_tokens counts codes with it)
    NATIVE = True
except ImportError:  # built without a C compiler: the pure-Python coder below does the work
    NATIVE = False

__all__ = ["PROB_BITS", "PROB_SCALE", "STATE_LOWER", "MAX_LANES", "NATIVE", "AdaptiveRows", "normalize_counts", "pack_table",
           "parse_table", "is_lane_count", "rans_encode", "rans_encode_many", "rans_decode", "rans_decode_mapped",
           "rans_encode_ctx", "rans_decode_ctx"]

PROB_BITS = 14
PROB_SCALE = 1 << PROB_BITS          # M: frequencies sum to this
STATE_LOWER = 1 << 23                # L: the state lives in [L, 2^32)
MAX_LANES = 32                       # interleaved lanes of one stream (format 1.5): 1 <= K <= 32
_STATE_UPPER_SHIFT = 23 - PROB_BITS + 8  # x_max(s) = freq[s] << 17


def normalize_counts(counts: np.ndarray) -> list[int]:
    """Integer frequencies summing to ``M`` from symbol counts (every symbol that occurs gets >= 1).

    Deterministic: floor of the proportional share, the remainder handed out by largest fractional part
    (ties to the lower symbol), then any symbol pushed to 0 is lifted to 1 by taking from the largest
    (ties to the lower symbol).  Vectorised (``_normalize_counts_py`` is the plain loop it must equal).
    """
    c = np.asarray(counts, dtype=np.int64).reshape(-1)
    total = int(c.sum())
    if total <= 0:
        raise ValueError("cannot build a frequency table from zero symbols")
    scaled = c * PROB_SCALE  # counts are <= 2^21 per matrix, so this stays far inside int64
    freqs = scaled // total
    order = np.lexsort((np.arange(c.size), -(scaled % total)))  # largest remainder first, then lower symbol
    freqs[order[: PROB_SCALE - int(freqs.sum())]] += 1
    lift = np.flatnonzero((c > 0) & (freqs == 0))
    if lift.size and c.size > PROB_SCALE // 2:
        return _normalize_counts_py(counts)
    # With at most M/2 symbols the largest frequency is >= 2 whenever it is taken from (the sum stays M),
    # so no lift makes a new zero and the symbols to lift are known up front, in symbol order.
    for i in lift.tolist():
        freqs[i] = 1
        freqs[int(np.argmax(freqs))] -= 1  # argmax: the first of the largest, i.e. ties to the lower symbol
    return freqs.tolist()


def _normalize_counts_py(counts: np.ndarray | Sequence[int]) -> list[int]:
    """The plain-loop :func:`normalize_counts` (the reference the tests compare it with)."""
    ints = [int(c) for c in counts]
    total = sum(ints)
    if total <= 0:
        raise ValueError("cannot build a frequency table from zero symbols")
    freqs = [c * PROB_SCALE // total for c in ints]
    rema = sorted(range(len(ints)), key=lambda i: (-(ints[i] * PROB_SCALE % total), i))
    for i in rema[: PROB_SCALE - sum(freqs)]:
        freqs[i] += 1
    for i, c in enumerate(ints):
        if c and not freqs[i]:
            freqs[i] = 1
            big = max(range(len(freqs)), key=lambda j: (freqs[j], -j))
            freqs[big] -= 1
    return freqs


def pack_table(freqs: list[int]) -> bytes:
    """Table bytes (see the module doc) covering the used symbol range of ``freqs``."""
    f = np.asarray(freqs, dtype=np.int64)
    used = np.flatnonzero(f)
    first, last = int(used[0]), int(used[-1])
    f = f[first:last + 1]
    # LEB128, 1..3 bytes a value (each <= 2^14): 7-bit groups, low first, 0x80 on all but the last
    groups = np.stack([f & 0x7F, (f >> 7) & 0x7F, f >> 14], axis=1)
    size = 1 + (f >= 1 << 7) + (f >= 1 << 14)
    groups[:, :2] |= (np.arange(1, 3)[None, :] < size[:, None]) * 0x80
    keep = np.arange(3)[None, :] < size[:, None]
    head = first.to_bytes(2, "little") + (last - first + 1).to_bytes(2, "little")
    return head + groups[keep].astype(np.uint8).tobytes()


def _pack_table_py(freqs: list[int]) -> bytes:
    """The plain-loop :func:`pack_table` (the reference the tests compare it with)."""
    used = [i for i, f in enumerate(freqs) if f]
    first, last = used[0], used[-1]
    out = bytearray(first.to_bytes(2, "little")) + (last - first + 1).to_bytes(2, "little")
    for f in freqs[first:last + 1]:
        while True:
            byte, f = f & 0x7F, f >> 7
            out.append(byte | (0x80 if f else 0))
            if not f:
                break
    return bytes(out)


def parse_table(data: BytesLike, alphabet: int) -> tuple[list[int], int]:
    """(freqs of length ``alphabet``, bytes consumed) from table bytes at the start of ``data``.

    Raises MalformedSectionError for a table that is cut short, overlong, names symbols outside
    ``[0, alphabet)`` or does not sum to ``M``.
    """
    if len(data) < 4:
        raise TruncatedError("entropy-coded section ends inside its frequency table header")
    first, count = int.from_bytes(bytes(data[0:2]), "little"), int.from_bytes(bytes(data[2:4]), "little")
    if count < 1 or first + count > alphabet:
        raise MalformedSectionError(
            f"frequency table covers symbols {first}..{first + count - 1}; the alphabet is 0..{alphabet - 1}")
    freqs, pos = [0] * alphabet, 4
    for k in range(count):
        value, shift = 0, 0
        while True:
            if pos >= len(data):
                raise TruncatedError("entropy-coded section ends inside its frequency table")
            byte = data[pos]
            pos += 1
            value |= (byte & 0x7F) << shift
            shift += 7
            if not byte & 0x80:
                if byte == 0 and shift > 7:
                    raise MalformedSectionError("frequency table varint has a redundant zero group")
                break
            if shift >= 21:
                raise MalformedSectionError("frequency table varint is longer than 3 bytes")
        if value > PROB_SCALE:
            raise MalformedSectionError(f"symbol frequency {value} exceeds the total {PROB_SCALE}")
        freqs[first + k] = value
    total = sum(freqs)
    if total != PROB_SCALE:
        raise MalformedSectionError(f"frequency table sums to {total}; it must sum to {PROB_SCALE}")
    return freqs, pos


def _cumulative(freqs: list[int]) -> list[int]:
    cum, acc = [], 0
    for f in freqs:
        cum.append(acc)
        acc += f
    return cum


def is_lane_count(lanes: object) -> bool:
    """Whether ``lanes`` is a lane count of one stream: an int K, 1 <= K <= MAX_LANES (bools excluded)."""
    return isinstance(lanes, int) and not isinstance(lanes, bool) and 1 <= lanes <= MAX_LANES


def _check_lanes(lanes: int) -> int:
    if not is_lane_count(lanes):
        raise ValueError(f"a rANS stream has 1 to {MAX_LANES} lanes, not {lanes!r}")
    return lanes


def rans_encode(symbols: np.ndarray, freqs: list[int], lanes: int = 1) -> bytes:
    """The rANS stream of ``symbols`` (1-D ints, each with a non-zero frequency) under ``freqs``, in
    ``lanes`` interleaved lanes (1: the single chain of format 1.1)."""
    return rans_encode_many([(symbols, freqs)], lanes=[lanes])[0]


def rans_encode_many(jobs: Sequence[tuple[np.ndarray, list[int]]], lanes: Sequence[int] | None = None) -> list[bytes]:
    """:func:`rans_encode` of 1 or 2 ``(symbols, freqs)`` (``lanes``: each one's lane count, default 1).
    Each lane is a chain of dependent steps: the compiled coder encodes a stream of lanes a round (one
    symbol of each lane) at a time, and two single chains in one interleaved loop, so the core stays busy."""
    counts = [1] * len(jobs) if lanes is None else [_check_lanes(k) for k in lanes]
    if len(counts) != len(jobs):
        raise ValueError("one lane count per stream")
    if not NATIVE:
        return [_encode_py(symbols, freqs, k) for (symbols, freqs), k in zip(jobs, counts)]
    specs = []
    for (symbols, freqs), k in zip(jobs, counts):
        syms = np.asarray(symbols)
        if syms.dtype != np.uint16 and syms.size and (syms.min() < 0 or syms.max() >= len(freqs)):
            raise ValueError("symbols outside the frequency table")  # (the C code checks every uint16 symbol)
        specs.append((np.ascontiguousarray(syms, dtype=np.uint16).reshape(-1), np.asarray(freqs, dtype=np.uint32), k))
    streams = []
    for stream in _rans_native.encode(tuple(specs)):
        if stream is None:
            raise ValueError("a symbol to encode has frequency 0")
        streams.append(stream)
    return streams


def _encode_py(symbols: np.ndarray, freqs: list[int], lanes: int = 1) -> bytes:
    """Pure-Python :func:`rans_encode` (the reference)."""
    cum = _cumulative(freqs)
    states, out = [STATE_LOWER] * lanes, bytearray()
    values = symbols.tolist()
    for k in range(len(values) - 1, -1, -1):
        s, x = values[k], states[k % lanes]
        f = freqs[s]
        x_max = f << _STATE_UPPER_SHIFT
        while x >= x_max:
            out.append(x & 0xFF)
            x >>= 8
        states[k % lanes] = ((x // f) << PROB_BITS) + (x % f) + cum[s]
    out.reverse()
    return b"".join(x.to_bytes(4, "little") for x in states) + bytes(out)


def _opened(stream: BytesLike, lanes: int = 1) -> tuple[bytes, list[int]]:
    """(stream bytes, initial states of the ``lanes`` lanes) after the checks every decode starts with."""
    data = bytes(stream)
    if len(data) < 4 * lanes:
        if lanes == 1:
            raise TruncatedError("rANS stream is shorter than its 4-byte initial state")
        raise TruncatedError(f"rANS stream is {len(data)} bytes, shorter than the initial states of its {lanes} "
                             f"lanes ({4 * lanes} bytes)")
    states = [int.from_bytes(data[4 * k:4 * k + 4], "little") for k in range(lanes)]
    for k, x in enumerate(states):
        if x < STATE_LOWER:
            raise MalformedSectionError(f"rANS initial state {x} is below {STATE_LOWER}" if lanes == 1 else
                                        f"rANS initial state {x} of lane {k} is below {STATE_LOWER}")
    return data, states


def rans_decode(stream: BytesLike, freqs: list[int], count: int, lanes: int = 1) -> np.ndarray:
    """Decode ``count`` symbols (uint16 array) from ``stream`` of ``lanes`` interleaved lanes under
    ``freqs`` (validated by parse_table).

    Raises TruncatedError if the stream ends early, MalformedSectionError if bytes are left over or a
    final state is not ``L`` (a damaged or forged stream).  Allocates ``2 * count`` bytes, which callers
    bound (MAX_RANS_VALUES).
    """
    data, states = _opened(stream, _check_lanes(lanes))
    nonzero = [s for s, f in enumerate(freqs) if f]
    if len(nonzero) == 1:  # one symbol of probability 1: the stream carries no information, no state changes
        _check_end(data, 4 * lanes, states)
        return np.full(count, nonzero[0], np.uint16)
    if not NATIVE:
        return _decode_py(data, states, freqs, count)
    out = np.empty(count, np.uint16)
    done, pos, final = _rans_native.decode(data, np.asarray(freqs, dtype=np.uint32), out, lanes)
    if done < count:
        raise TruncatedError(f"rANS stream ends after {done} of {count} symbols")
    _check_end(data, pos, final)
    return out


# One stream of :func:`rans_decode_mapped`: (stream, freqs, rows, cols, colbase, lut, centre, top, lanes).
MappedJob = tuple[BytesLike, list[int], int, int, np.ndarray, np.ndarray, np.ndarray | None, int, int]


def rans_decode_mapped(jobs: Sequence[MappedJob]) -> list[tuple[np.ndarray, bool]] | None:
    """Decode 1 or 2 independent streams, mapping each symbol through a table as it is decoded (compiled
    coder only).  ``jobs``: ``(stream, freqs, rows, cols, colbase, lut, centre, top, lanes)`` each; symbol
    ``s`` of column ``c`` becomes ``code = s`` (``centre`` None) or ``s + centre[c] - top``, and
    ``out[i, c] = lut[colbase[c] + code]``.  Two single chains are decoded in one interleaved loop (~1.4x the
    speed of one after the other); a stream of K >= 2 lanes a round (one symbol of each lane) at a time,
    ~2.6x the speed of one chain with K = 8 (FORMAT.md I.6.1).

    Returns [(float32 (rows, cols), whether some code fell outside ``0..top``)] per job, or None where the
    pure-Python coder runs or a table has one symbol (callers then use :func:`rans_decode`).  Stream
    errors raise as in :func:`rans_decode`.
    """
    if not NATIVE or any(sum(1 for f in job[1] if f) == 1 for job in jobs):
        return None
    specs, outs = [], []
    for stream, freqs, rows, cols, colbase, lut, centre, top, lanes in jobs:
        data, _ = _opened(stream, _check_lanes(lanes))
        outs.append((data, rows * cols, np.empty((rows, cols), np.float32)))
        specs.append((data, np.asarray(freqs, dtype=np.uint32), outs[-1][2], cols,
                      np.ascontiguousarray(colbase, dtype=np.uint32), np.ascontiguousarray(lut, dtype=np.float32),
                      b"" if centre is None else np.ascontiguousarray(centre, np.uint8), top, lanes))
    results = []
    for (data, count, out), (done, pos, final, bad) in zip(outs, _rans_native.decode_mapped(tuple(specs))):
        if done < count:
            raise TruncatedError(f"rANS stream ends after {done} of {count} symbols")
        _check_end(data, pos, final)
        results.append((out, bool(bad)))
    return results


def _check_end(data: bytes, pos: int, states: Sequence[int]) -> None:
    if pos != len(data):
        raise MalformedSectionError(f"rANS stream has {len(data) - pos} bytes left after its last symbol")
    for k, x in enumerate(states):
        if x != STATE_LOWER:
            if len(states) == 1:
                raise MalformedSectionError(
                    f"rANS stream ends in state {x}, not {STATE_LOWER}: damaged or forged bytes")
            raise MalformedSectionError(
                f"rANS lane {k} of {len(states)} ends in state {x}, not {STATE_LOWER}: damaged or forged bytes")


def _decode_py(data: bytes, states: list[int], freqs: list[int], count: int) -> np.ndarray:
    """Pure-Python :func:`rans_decode` after the initial-state and one-symbol checks (the reference):
    ``states`` holds the initial state of each lane, symbol ``i`` is lane ``i mod len(states)``'s."""
    slot_symbol = np.repeat(np.arange(len(freqs), dtype=np.uint16), freqs).tolist()
    cum, mask, end, lanes = _cumulative(freqs), PROB_SCALE - 1, len(data), len(states)
    syms, pos, states = [0] * count, 4 * lanes, list(states)
    for i in range(count):
        x = states[i % lanes]
        slot = x & mask
        s = slot_symbol[slot]
        x = freqs[s] * (x >> PROB_BITS) + slot - cum[s]
        while x < STATE_LOWER:
            if pos >= end:
                raise TruncatedError(f"rANS stream ends after {i} of {count} symbols")
            x = (x << 8) | data[pos]
            pos += 1
        states[i % lanes] = x
        syms[i] = s
    _check_end(data, pos, states)
    return np.array(syms, dtype=np.uint16)


# --- context-coded streams (format 1.6, FORMAT.md I.6.2) -------------------------------------------------
def _ctx_args(ctx: np.ndarray, freqs: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    table = np.ascontiguousarray(freqs, dtype=np.uint32)
    if table.ndim != 2 or table.shape[0] < 1 or table.shape[1] < 1:
        raise ValueError("freqs must be a (T, A) table")
    return np.ascontiguousarray(ctx, dtype=np.uint16).reshape(-1), table, table.shape[1]


def rans_encode_ctx(symbols: np.ndarray, ctx: np.ndarray, freqs: np.ndarray, adaptive: bool = False) -> bytes:
    """The single-chain rANS stream of ``symbols`` (1-D) where symbol ``k`` is coded with row ``ctx[k]`` of
    ``freqs`` (T, A), each row a table summing to 2^14; with ``adaptive``, each row adapts to the symbols coded
    with it (:class:`AdaptiveRows`, FORMAT.md I.6.2). ValueError where a symbol has frequency 0."""
    ctx16, table, alphabet = _ctx_args(ctx, freqs)
    syms = np.ascontiguousarray(symbols, dtype=np.int64).reshape(-1)
    if syms.shape != ctx16.shape:
        raise ValueError("one context per symbol")
    if syms.size and (syms.min() < 0 or syms.max() >= alphabet or int(ctx16.max()) >= table.shape[0]):
        raise ValueError("a symbol or context lies outside the tables")
    if NATIVE:
        stream = _rans_native.encode_ctx(syms.astype(np.uint16), ctx16, table, alphabet, bool(adaptive))
        if stream is None:
            raise ValueError("a symbol to encode has frequency 0")
        return stream
    return _encode_ctx_py(syms, ctx16, table, adaptive)


ADAPT_BITS = 16  # precision of an adaptive row's cumulative counts


class AdaptiveRows:
    """The rows of a context-coded stream with **adaptive rows** (FORMAT.md I.6.2, required flag bit 10): row
    ``t`` starts from its table's cumulative frequencies scaled to 2^16 over its symbol count ``n`` (the run of
    positive frequencies), and after each symbol ``s`` coded with it moves towards ``s`` by ``1 / D``,
    ``D = n + k + 3`` for the row's ``k``-th symbol (``k`` from 0): ``cum[i] -= cum[i] // D`` for ``1 <= i <= s``,
    ``cum[i] += (2^16 - cum[i]) // D`` for ``s < i < n``. Symbol ``i``'s rANS start is
    ``((cum[i] * (2^14 - n)) >> 16) + i``: every frequency stays >= 1 and they sum to 2^14. A file's token
    distribution differs from the training set's (each channel's share of zeros, above all), and a row that
    learns it as it goes saves 4-14 % of a learned-rans file without side information."""

    def __init__(self, freqs: np.ndarray) -> None:
        self._freqs = freqs
        self._rows: dict[int, tuple[list[int], int, list[int]]] = {}

    def _row(self, t: int) -> tuple[list[int], int, list[int]]:
        row = self._rows.get(t)
        if row is None:
            f = self._freqs[t].tolist()
            n = next((i for i, v in enumerate(f) if v <= 0), len(f))
            cum, acc = [0], 0
            for v in f[:n]:
                acc += int(v)
                cum.append(acc << (ADAPT_BITS - PROB_BITS))
            row = self._rows[t] = (cum, n, [0])
        return row

    def symbols(self, t: int) -> int:
        """The symbol count ``n`` of row ``t``."""
        return self._row(t)[1]

    def starts(self, t: int) -> list[int]:
        """The rANS starts of row ``t``'s symbols 0 .. n (n + 1 values, the last 2^14) in its present state."""
        cum, n, _ = self._row(t)
        scale = PROB_SCALE - n
        return [((c * scale) >> ADAPT_BITS) + i for i, c in enumerate(cum)]

    def update(self, t: int, s: int) -> None:
        """Row ``t`` has just coded symbol ``s``."""
        cum, n, count = self._row(t)
        d = n + count[0] + 3
        count[0] += 1
        for i in range(1, s + 1):
            cum[i] -= cum[i] // d
        for i in range(s + 1, n):
            cum[i] += ((1 << ADAPT_BITS) - cum[i]) // d


def _rows_and_cumulative(freqs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(int64 frequency rows (T, A), their cumulative sums (T, A + 1), each row starting at 0)."""
    table = freqs.astype(np.int64)
    return table, np.concatenate([np.zeros((len(table), 1), np.int64), np.cumsum(table, axis=1)], axis=1)


def _encode_ctx_py(symbols: np.ndarray, ctx: np.ndarray, freqs: np.ndarray, adaptive: bool = False) -> bytes:
    """Pure-Python :func:`rans_encode_ctx` (the reference)."""
    table, cums = _rows_and_cumulative(freqs)
    sym_list, ctx_list = symbols.tolist(), ctx.tolist()
    if adaptive:  # each symbol's (start, frequency) under its row's state when it is coded, in coding order
        rows, intervals = AdaptiveRows(table), []
        for s, t in zip(sym_list, ctx_list):
            if s >= rows.symbols(t):
                raise ValueError("a symbol to encode has frequency 0")
            starts = rows.starts(t)
            intervals.append((starts[s], starts[s + 1] - starts[s]))
            rows.update(t, s)
    else:
        intervals = [(int(cums[t, s]), int(table[t, s])) for s, t in zip(sym_list, ctx_list)]
    x, out = STATE_LOWER, bytearray()
    for c, f in intervals[::-1]:
        if f == 0:
            raise ValueError("a symbol to encode has frequency 0")
        x_max = f << _STATE_UPPER_SHIFT
        while x >= x_max:
            out.append(x & 0xFF)
            x >>= 8
        x = ((x // f) << PROB_BITS) + (x % f) + c
    out.reverse()
    return x.to_bytes(4, "little") + bytes(out)


Dependency = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _dependency_args(dependency: Dependency, n: int) -> Dependency:
    """(dep int32, centre uint16, dep2 int32, centre2 uint16, offsets int32) checked: one value per symbol for the
    first four, each dependency earlier than its symbol (or -1: none); 9 offsets."""
    dep, dep2 = (np.ascontiguousarray(dependency[k], dtype=np.int32).reshape(-1) for k in (0, 2))
    centre, centre2 = (np.ascontiguousarray(dependency[k], dtype=np.uint16).reshape(-1) for k in (1, 3))
    offsets = np.ascontiguousarray(dependency[4], dtype=np.int32).reshape(-1)
    if any(a.size != n for a in (dep, centre, dep2, centre2)) or offsets.size != 9:
        raise ValueError("a dependency needs one dep, centre, dep2 and centre2 value per symbol and 9 offsets")
    if n and ((dep >= np.arange(n)).any() or (dep2 >= np.arange(n)).any()):
        raise ValueError("a symbol can depend only on an earlier symbol")
    return dep, centre, dep2, centre2, offsets


def _comparison(symbols: np.ndarray, dep: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """0, 1 or 2 per symbol: the symbol at ``dep`` below, equal to or above ``centre``; 1 where dep < 0."""
    out = np.ones(dep.size, np.int64)
    has = dep >= 0
    v = symbols[dep[has]]
    out[has] = np.where(v < centre[has], 0, np.where(v > centre[has], 2, 1))
    return out


def dependent_contexts(symbols: np.ndarray, ctx: np.ndarray, dependency: Dependency) -> np.ndarray:
    """The row of each symbol under ``dependency`` (see :func:`rans_decode_ctx`), for an encoder that knows every
    symbol: ``ctx[k] + offsets[3 a + b]``, ``a`` and ``b`` 0, 1 or 2 as the symbols at ``dep[k]`` and
    ``dep2[k]`` are below, equal to or above ``centre[k]`` and ``centre2[k]`` (1 where there is none)."""
    syms = np.asarray(symbols, dtype=np.int64).reshape(-1)
    dep, centre, dep2, centre2, offsets = _dependency_args(dependency, syms.size)
    a, b = _comparison(syms, dep, centre), _comparison(syms, dep2, centre2)
    out: np.ndarray = np.asarray(ctx, dtype=np.int64).reshape(-1) + offsets.astype(np.int64)[3 * a + b]
    return out


def rans_decode_ctx(stream: BytesLike, ctx: np.ndarray, freqs: np.ndarray,
                    dependency: Dependency | None = None, adaptive: bool = False) -> np.ndarray:
    """Decode ``len(ctx)`` symbols (uint16) of a single-chain stream, symbol ``k`` with row ``ctx[k]`` of
    ``freqs`` (T, A; every row validated to sum to 2^14 by the caller). With ``dependency`` = (dep, centre,
    dep2, centre2, offsets), one value each per symbol but the 9 offsets: symbol ``k`` takes row
    ``ctx[k] + offsets[3 a + b]``, where ``a`` is 0, 1 or 2 as the symbol decoded at ``dep[k]`` (an earlier
    symbol) is below, equal to or above ``centre[k]``, 1 where ``dep[k] < 0``, and ``b`` likewise for ``dep2``
    and ``centre2`` (context-coded MEAN tokens, FORMAT.md I.6.2). With ``adaptive``, each row adapts to the
    symbols decoded with it (:class:`AdaptiveRows`). TruncatedError if the stream ends early,
    MalformedSectionError if bytes are left over or the final state is not ``L``."""
    ctx16, table, alphabet = _ctx_args(ctx, freqs)
    data, states = _opened(stream, 1)
    if ctx16.size and int(ctx16.max()) >= table.shape[0]:
        raise ValueError("a context lies outside the tables")
    dep = None if dependency is None else _dependency_args(dependency, ctx16.size)
    if not NATIVE:
        return _decode_ctx_py(data, states[0], ctx16, table, dep, adaptive)
    out = np.empty(ctx16.size, np.uint16)
    done, pos, final = _rans_native.decode_ctx(data, ctx16, table, alphabet, bool(adaptive), out,
                                               *(() if dep is None else dep))
    if done < ctx16.size:
        raise TruncatedError(f"rANS stream ends after {done} of {ctx16.size} symbols")
    _check_end(data, pos, (final,))
    return out


def _decode_ctx_py(data: bytes, x: int, ctx: np.ndarray, freqs: np.ndarray,
                   dependency: Dependency | None = None, adaptive: bool = False) -> np.ndarray:
    """Pure-Python :func:`rans_decode_ctx` after the initial-state check (the reference)."""
    table, cums = _rows_and_cumulative(freqs)
    adaptive_rows = AdaptiveRows(table) if adaptive else None
    mask, end, pos = PROB_SCALE - 1, len(data), 4
    rows: dict[int, tuple[list[int], list[int]]] = {}
    dep, centre, dep2, centre2, offsets = ([], [], [], [], []) if dependency is None else (a.tolist() for a in dependency)
    syms = [0] * len(ctx)
    for i, t in enumerate(ctx.tolist()):
        if dependency is not None:
            a = b = 1
            if dep[i] >= 0:
                v = syms[dep[i]]
                a = 0 if v < centre[i] else 2 if v > centre[i] else 1
            if dep2[i] >= 0:
                v = syms[dep2[i]]
                b = 0 if v < centre2[i] else 2 if v > centre2[i] else 1
            t += offsets[3 * a + b]
        if not 0 <= t < table.shape[0]:
            raise ValueError("a context lies outside the tables, or a dependency is not earlier")
        slot = x & mask
        if adaptive_rows is not None:
            starts = adaptive_rows.starts(t)
            s = bisect.bisect_right(starts, slot) - 1
            x = (starts[s + 1] - starts[s]) * (x >> PROB_BITS) + slot - starts[s]
            adaptive_rows.update(t, s)
        else:
            if t not in rows:
                rows[t] = (table[t].tolist(), cums[t].tolist())
            f, cum = rows[t]
            s = bisect.bisect_right(cum, slot) - 1
            x = f[s] * (x >> PROB_BITS) + slot - cum[s]
        while x < STATE_LOWER:
            if pos >= end:
                raise TruncatedError(f"rANS stream ends after {i} of {len(ctx)} symbols")
            x = (x << 8) | data[pos]
            pos += 1
        syms[i] = s
    _check_end(data, pos, (x,))
    return np.array(syms, dtype=np.uint16)
