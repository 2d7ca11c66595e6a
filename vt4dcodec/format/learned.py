"""The ``learned-rans`` token encoding (format 1.6, required flag bit 5; FORMAT.md I.6.2).

Tokens are quantized with the per-level, per-channel steps of the model that made them and coded with that
model's integer rANS tables, one table per context (class x channel): the entropy model of the tokenizer
(``model.entropy``), frozen into integers when the model shipped. The tables are not in the file: the file
names its model by fingerprint, and a reader decodes the tokens only with the tables of that model
(:class:`EntropyTables`, found by the resolver the package installs, or passed in). Without them a reader
still opens, verifies checksums and reads shapes, cameras and metadata; the tokens raise
:class:`~vt4dcodec.errors.EntropyTablesError`.

Decoding is integers only (the context rANS coder of ``rans.py``) up to the last step, ``f32(q * step)``.

Payload of ``ZSTA`` / ``ZDYN``: ``u8 level``, ``u8 views``, then one rANS chain of ``N * d`` symbols. In a
file with required flag bit 10 the chain's rows adapt to the symbols they code (``rans.AdaptiveRows``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import EntropyTablesError, FormatError, LimitExceededError, MalformedSectionError, TruncatedError
from .encodings import LEARNED_ENCODING
from .fingerprint import ModelFingerprint
from .layout import BytesLike
from .rans import PROB_SCALE, Dependency, dependent_contexts, rans_decode_ctx, rans_encode_ctx

__all__ = ["LEARNED_ENCODING", "EntropyTables", "MAX_VIEWS", "MEAN", "CHANGE", "DYNAMIC", "encode_learned_tokens",
           "decode_learned_tokens", "parse_learned_payload", "quantize", "writer_codes", "coded_symbols", "set_tables_resolver", "register_tables", "find_tables",
           "MAX_LEARNED_VALUES", "MEAN_AFTER_NEGATIVE", "MEAN_AFTER_POSITIVE", "MEAN_PARTNER_NEGATIVE",
           "MEAN_PARTNER_POSITIVE", "pair_class"]

MAX_VIEWS = 64
MEAN, CHANGE, DYNAMIC = 0, 1, 2
# tables of 5 classes code a MEAN token given the sign of the previous MEAN token's code in its channel
MEAN_AFTER_NEGATIVE, MEAN_AFTER_POSITIVE = 3, 4
# tables of 11 classes also by the sign of the same token's code in the channel's partner channel: classes
# 5, 6, 7 when it is negative and 8, 9, 10 when it is positive, for a previous MEAN code below, at or above 0
MEAN_PARTNER_NEGATIVE, MEAN_PARTNER_POSITIVE = 5, 8
CLASS_COUNTS = (3, 5, 11)
MAX_LEVELS = 16
MAX_LEARNED_VALUES = 1 << 21  # N * d per matrix, as the other entropy-coded encodings (I.7)


@dataclass(frozen=True, eq=False)
class EntropyTables:
    """The frozen entropy model of one tokenizer (FORMAT.md I.6.2, "Tables").

    steps: float32 (L, 2, d), the quantizer step of each level for Z_s (index 0) and Z_d (1), each > 0;
    freqs: int64 (L, C, d, A), the rANS frequencies of each level, class (MEAN, CHANGE, DYNAMIC, and with
        C = 5 MEAN_AFTER_NEGATIVE, MEAN_AFTER_POSITIVE) and channel: each row a run of ``n >= 1`` positive
        frequencies summing to 2^14 followed by zeros, with ``n = 2Q + 1`` for the MEAN classes and DYNAMIC and
        ``4Q + 1`` for CHANGE, Q the level's half-range of codes.  With C = 5 a MEAN token after the first is
        coded with the MEAN_AFTER_* table of its channel when the previous MEAN token's code there is negative
        or positive (:meth:`mean_dependency`);
    origins: int64 (64, N_s), for 1..64 encoded cameras the anchor origin of each static token (``o <= i``,
        and ``origins[v, o] = o``): a token with ``o = i`` is of class MEAN, else CHANGE;
    fingerprint: the model these tables belong to;
    rounding: optional float64 (L, 3), the writer's rounding offset ``f`` in [0, 1/2] of each level for MEAN
        (every MEAN class), CHANGE and DYNAMIC values (:func:`writer_codes`); None or 1/2: round to nearest.
        An encoder's choice, not needed to read a file;
    partners: with C = 11 (and only then) int64 (d,), each channel's partner channel ``-1 <= p < c`` (-1: none):
        a MEAN value is coded given the signs of the previous MEAN token's code in its channel and of its own
        token's code in the partner channel (:func:`pair_class`), channels that tokens move together in.
    """

    steps: np.ndarray
    freqs: np.ndarray
    origins: np.ndarray
    fingerprint: ModelFingerprint
    rounding: np.ndarray | None = None
    partners: np.ndarray | None = None

    def __post_init__(self) -> None:
        steps = np.asarray(self.steps, dtype=np.float32)
        freqs = np.asarray(self.freqs).astype(np.int64)
        origins = np.asarray(self.origins).astype(np.int64)
        d = self.fingerprint.static_shape[1]
        n_s = self.fingerprint.static_shape[0]
        if steps.ndim != 3 or steps.shape[1:] != (2, d) or not 1 <= steps.shape[0] <= MAX_LEVELS:
            raise EntropyTablesError(f"entropy tables: steps must be (L, 2, {d}) with 1 <= L <= {MAX_LEVELS}")
        L = steps.shape[0]
        if freqs.ndim != 4 or freqs.shape[1] not in CLASS_COUNTS or freqs.shape[0] != L or freqs.shape[2] != d \
                or freqs.shape[3] < 3:
            raise EntropyTablesError(f"entropy tables: freqs must be ({L}, 3, 5 or 11, {d}, A)")
        if origins.shape != (MAX_VIEWS, n_s):
            raise EntropyTablesError(f"entropy tables: origins must be ({MAX_VIEWS}, {n_s})")
        if not (np.isfinite(steps).all() and (steps > 0).all()):
            raise EntropyTablesError("entropy tables: every step must be finite and > 0")
        size = (freqs > 0).sum(axis=3)
        prefix = np.arange(freqs.shape[3])[None, None, None, :] < size[..., None]
        if (freqs < 0).any() or ((freqs > 0) != prefix).any() or (freqs.sum(axis=3) != PROB_SCALE).any():
            raise EntropyTablesError("entropy tables: each table must be positive frequencies summing to 2^14, "
                                     "then zeros")
        if ((size[:, [MEAN, DYNAMIC]] - 1) % 2).any():
            raise EntropyTablesError("entropy tables: a MEAN or DYNAMIC table must have an odd symbol count")
        half = (size[:, [MEAN, DYNAMIC]] - 1) // 2  # (L, 2, d): Q of Z_s and Z_d
        if (size[:, CHANGE] != 4 * half[:, 0] + 1).any():
            raise EntropyTablesError("entropy tables: a CHANGE table must have 4Q + 1 symbols (Q of its MEAN table)")
        if freqs.shape[1] > 3 and (size[:, 3:] != size[:, [MEAN]]).any():
            raise EntropyTablesError("entropy tables: a MEAN_AFTER_* or MEAN_PARTNER_* table must have the symbol "
                                     "count of its MEAN table")
        partners = None if self.partners is None else np.asarray(self.partners).astype(np.int64)
        if (partners is not None) != (freqs.shape[1] == 11):
            raise EntropyTablesError("entropy tables: partners come with tables of 11 classes, and only with them")
        if partners is not None and (partners.shape != (d,) or (partners < -1).any()
                                     or (partners >= np.arange(d)).any()):
            raise EntropyTablesError(f"entropy tables: partners must be ({d},) channels, each -1 or below its own")
        index = np.arange(n_s)[None, :]
        if (origins < 0).any() or (origins > index).any() or \
                (np.take_along_axis(origins, origins, axis=1) != origins).any():
            raise EntropyTablesError("entropy tables: each origin must be an earlier token that is its own origin")
        rounding = None if self.rounding is None else np.asarray(self.rounding, dtype=np.float64)
        if rounding is not None and (rounding.shape != (L, 3) or not np.isfinite(rounding).all()
                                     or (rounding < 0).any() or (rounding > 0.5).any()):
            raise EntropyTablesError(f"entropy tables: rounding must be ({L}, 3) offsets within [0, 1/2]")
        if rounding is not None:
            rounding.setflags(write=False)
            object.__setattr__(self, "rounding", rounding)
        if partners is not None:
            partners.setflags(write=False)
            object.__setattr__(self, "partners", partners)
        for name, value in (("steps", steps), ("freqs", freqs), ("origins", origins)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "_half", half)

    @property
    def levels(self) -> int:
        return int(self.steps.shape[0])

    @property
    def contextual(self) -> bool:
        """Whether MEAN tokens are coded given the previous MEAN token (tables of 5 or 11 classes)."""
        return int(self.freqs.shape[1]) > 3

    def mean_dependency(self, views: int) -> np.ndarray:
        """(N_s,) int64: for each MEAN static token after the first, the index of the previous MEAN token (the
        largest MEAN index below it); -1 for the first MEAN token and for CHANGE tokens."""
        change = self.copies(views)[1]
        index = np.where(~change, np.arange(len(change)), -1)
        last = np.maximum.accumulate(index)  # the latest MEAN index at or before each token
        prev = np.concatenate([[-1], last[:-1]])
        out: np.ndarray = np.where(change, -1, prev).astype(np.int64)
        return out

    def half_range(self, level: int) -> np.ndarray:
        """(2, d) int64: Q of Z_s and Z_d at ``level``, codes lie in -Q .. Q."""
        return self._half[level]  # type: ignore[attr-defined, no-any-return]

    def copies(self, views: int) -> tuple[np.ndarray, np.ndarray]:
        """(origin (N_s,), change (N_s,) bool) for ``views`` encoded cameras: each static token's origin, and
        whether the token is a frame copy (class CHANGE, coded given its origin) rather than MEAN."""
        origin = self.origins[views - 1]
        return origin, origin != np.arange(len(origin))

    def contexts(self, which: str, views: int) -> np.ndarray:
        """(N, d) int64 context (class * d + channel) of each value of the "static" or "dynamic" matrix."""
        d = self.steps.shape[2]
        channel = np.arange(d)[None, :]
        if which == "dynamic":
            return np.broadcast_to(DYNAMIC * d + channel, self.fingerprint.dynamic_shape)
        cls = np.where(self.copies(views)[1], CHANGE, MEAN)
        out: np.ndarray = cls[:, None] * d + channel
        return out


_resolver: Callable[[ModelFingerprint], EntropyTables | None] | None = None
_registered: dict[ModelFingerprint, EntropyTables] = {}


def register_tables(tables: EntropyTables) -> None:
    """Make ``tables`` findable by their fingerprint in this process (the codec registers the tables of every
    model it encodes with, so a scene it made saves and loads even when the model is not installed)."""
    _registered[tables.fingerprint] = tables


def set_tables_resolver(resolver: Callable[[ModelFingerprint], EntropyTables | None] | None) -> None:
    """Install the function that finds the entropy tables of a model fingerprint (None when it has no
    such model). ``import vt4dcodec`` installs one that looks in the shipped and ``$VT4D_MODEL_PATH``
    models."""
    global _resolver
    _resolver = resolver


def find_tables(fingerprint: ModelFingerprint, tables: EntropyTables | None = None) -> EntropyTables:
    """``tables`` when given (it must belong to ``fingerprint``), else the resolver's. EntropyTablesError
    when there are none: the file's tokens cannot be read without the model that coded them."""
    if tables is None:
        tables = _registered.get(fingerprint)
    if tables is None and _resolver is not None:
        tables = _resolver(fingerprint)
    if tables is None:
        raise EntropyTablesError(
            f"the tokens are coded with the entropy tables of model {fingerprint.model_id} "
            f"{fingerprint.model_version} (weights {fingerprint.weights_sha256[:12]}), which is not installed: "
            f"install that model or put its directory under $VT4D_MODEL_PATH (shapes, cameras and metadata "
            f"read without it)")
    if tables.fingerprint != fingerprint:
        raise EntropyTablesError(
            f"the entropy tables given belong to model {tables.fingerprint.model_id} "
            f"{tables.fingerprint.model_version}, not to the file's {fingerprint.model_id} {fingerprint.model_version}")
    return tables


def pair_class(previous: int, partner: int) -> int:
    """The class of a MEAN value in tables of 11 classes from the signs (-1, 0, 1) of the previous MEAN token's
    code in its channel and of its own token's code in the partner channel (0 also where there is none)."""
    if partner < 0:
        return MEAN_PARTNER_NEGATIVE + previous + 1
    if partner > 0:
        return MEAN_PARTNER_POSITIVE + previous + 1
    return (MEAN_AFTER_NEGATIVE, MEAN, MEAN_AFTER_POSITIVE)[previous + 1]


def _check_level(tables: EntropyTables, level: int) -> None:
    if isinstance(level, bool) or not isinstance(level, (int, np.integer)) or not 0 <= level < tables.levels:
        raise FormatError(f"quality level index must be 0 .. {tables.levels - 1}, got {level!r}")


def _group(which: str) -> int:
    """Index of a token matrix in the tables' steps and half-ranges: 0 for "static" (Z_s), 1 for Z_d."""
    return 0 if which == "static" else 1


def quantize(tokens: np.ndarray, tables: EntropyTables, level: int, which: str) -> np.ndarray:
    """int64 codes q = clip(round_half_to_even(x / step), -Q, Q) of a (N, d) token matrix (binary64)."""
    step = tables.steps[level, _group(which)].astype(np.float64)
    half = tables.half_range(level)[_group(which)]
    codes: np.ndarray = np.clip(np.rint(np.asarray(tokens, np.float64) / step), -half, half).astype(np.int64)
    return codes


def _dead_zone(x: np.ndarray, offset: float, limit: np.ndarray) -> np.ndarray:
    """sign(x) floor(|x| + offset), clipped to -limit .. limit (int64)."""
    out: np.ndarray = np.clip(np.sign(x) * np.floor(np.abs(x) + offset), -limit, limit).astype(np.int64)
    return out


def writer_codes(tokens: np.ndarray, tables: EntropyTables, level: int, which: str, views: int) -> np.ndarray:
    """int64 codes the reference writer stores for a (N, d) token matrix of a scene of ``views`` encoded
    cameras: :func:`quantize` (round to nearest), or with the tables' ``rounding`` offset ``f < 1/2`` for a
    class a dead zone, ``sign(x) floor(|x| + f)`` of ``x = token / step`` -- a value is stored as 0 unless
    ``|x| > 1 - f`` -- and for a CHANGE value of its difference to its origin's stored code, so a frame copy
    that barely moved stores "no change", which costs next to nothing. Any codes are valid in a file; these
    spend fewer bytes where the model's distortion rises least (the rounding offsets of video encoders' rate-
    distortion optimised quantization). A smaller code is not always a cheaper one (a frame copy whose origin's
    code shrank stores a change where round to nearest stored none), so the dead-zoned matrix is kept only where
    its stream is no longer than round to nearest's with plain and with adaptive rows; else round to nearest,
    which is then better in rate and in distortion, and dead zones never cost a file bytes."""
    q = quantize(tokens, tables, level, which)
    if tables.rounding is None:
        return q
    dead = _dead_zone_codes(tokens, q, tables, level, which, views)
    if np.array_equal(dead, q):
        return q
    for adaptive in (False, True):
        if len(_stream(dead, tables, level, which, views, adaptive)) > \
                len(_stream(q, tables, level, which, views, adaptive)):
            return q
    return dead


def _dead_zone_codes(tokens: np.ndarray, q: np.ndarray, tables: EntropyTables, level: int, which: str,
                     views: int) -> np.ndarray:
    """The dead-zoned codes of :func:`writer_codes` (``q``: the matrix's round-to-nearest codes)."""
    assert tables.rounding is not None
    f = tables.rounding[level]
    half = tables.half_range(level)[_group(which)][None, :]
    x = np.asarray(tokens, np.float64) / tables.steps[level, _group(which)].astype(np.float64)
    if which == "dynamic":
        return q if f[DYNAMIC] == 0.5 else _dead_zone(x, f[DYNAMIC], half)
    out = q.copy() if f[MEAN] == 0.5 else _dead_zone(x, f[MEAN], half)
    origin, change = tables.copies(views)
    if f[CHANGE] != 0.5 and change.any():
        base = out[origin[change]]
        out[change] = np.clip(base + _dead_zone(x[change] - base, f[CHANGE], 2 * half), -half, half)
    elif change.any():
        out[change] = q[change]
    return out


def _stream(codes: np.ndarray, tables: EntropyTables, level: int, which: str, views: int, adaptive: bool) -> bytes:
    """The rANS stream of a code matrix (:func:`encode_learned_tokens`'s payload without its two-byte head)."""
    symbols, contexts = coded_symbols(codes, tables, level, views, which)
    return rans_encode_ctx(symbols, contexts, tables.freqs[level].reshape(-1, tables.freqs.shape[3]), adaptive)


def dequantize(codes: np.ndarray, tables: EntropyTables, level: int, which: str) -> np.ndarray:
    """float32 f32(q * step), the product computed exactly (binary64) and rounded once."""
    step = tables.steps[level, _group(which)].astype(np.float64)
    values: np.ndarray = (codes.astype(np.float64) * step).astype(np.float32)
    return values


def encode_learned_tokens(tokens: np.ndarray, tables: EntropyTables, level: int, views: int, which: str,
                          adaptive: bool = False) -> bytes:
    """The ``ZSTA`` ("static") or ``ZDYN`` ("dynamic") payload of a token matrix at ``level`` for a scene of
    ``views`` encoded cameras; ``adaptive``: with adaptive rows (FORMAT.md I.6.2, required flag bit 10)."""
    _check_level(tables, level)
    if not 1 <= views <= MAX_VIEWS:
        raise FormatError(f"a learned-rans scene has 1 to {MAX_VIEWS} encoded cameras, not {views}")
    x = np.asarray(tokens, dtype=np.float32)
    if x.size > MAX_LEARNED_VALUES:
        raise LimitExceededError(f"{x.size} learned-rans values in one matrix exceed the limit of {MAX_LEARNED_VALUES}")
    if not np.isfinite(x).all():
        raise FormatError("tokens must be finite")
    return bytes([level, views]) + _stream(writer_codes(x, tables, level, which, views), tables, level, which, views,
                                           adaptive)


def coded_symbols(codes: np.ndarray, tables: EntropyTables, level: int, views: int, which: str
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(symbols, contexts), flat in coding order, of a (N, d) code matrix: MEAN and DYNAMIC symbols ``q + Q``,
    a frame copy's ``q - q_origin + 2Q``, each with its context (class * d + channel; with tables of 5 classes
    a MEAN token's class chosen by the previous MEAN token's code)."""
    half = tables.half_range(level)[_group(which)][None, :]
    symbols = codes + half
    if which == "static":  # a frame copy: its code's difference to its origin's, centred on 2Q
        origin, change = tables.copies(views)
        symbols[change] = codes[change] - codes[origin[change]] + 2 * half
    flat = symbols.reshape(-1)
    contexts = tables.contexts(which, views).reshape(-1)
    if which == "static" and tables.contextual:
        contexts = dependent_contexts(flat, contexts, _mean_dependency(tables, level, views))
    return flat, contexts


def _mean_dependency(tables: EntropyTables, level: int, views: int) -> Dependency:
    """The rANS dependency (dep, centre, dep2, centre2, offsets) of the static matrix, of tables with
    context-coded MEAN tokens: value (i, c) of a MEAN token after the first depends on value (j, c) of the
    previous MEAN token j, and with tables of 11 classes value (i, c) of a MEAN token on value (i, p) of the
    same token in the partner channel p; centres Q of the channel depended on (the symbol of code 0); the
    offsets move a MEAN row to the row of :func:`pair_class`."""
    d = tables.steps.shape[2]
    n = tables.origins.shape[1]
    prev = tables.mean_dependency(views)
    channel = np.arange(d)[None, :]
    half = tables.half_range(level)[0]
    dep = np.where(prev[:, None] >= 0, prev[:, None] * d + channel, -1)
    centre = np.broadcast_to(half[None, :], dep.shape)
    if tables.partners is None:
        dep2 = np.full(dep.shape, -1)
        centre2 = np.zeros(dep.shape, np.int64)
    else:
        mean = ~tables.copies(views)[1]
        partner = tables.partners[None, :]
        dep2 = np.where(mean[:, None] & (partner >= 0), np.arange(n)[:, None] * d + partner, -1)
        centre2 = np.broadcast_to(half[np.maximum(tables.partners, 0)][None, :], dep.shape)
    offsets = np.array([d * (pair_class(a - 1, b - 1) - MEAN) for a in range(3) for b in range(3)], np.int64)
    flat = [np.ascontiguousarray(a).reshape(-1) for a in (dep, centre, dep2, centre2)]
    return flat[0], flat[1], flat[2], flat[3], offsets


def parse_learned_payload(payload: BytesLike) -> tuple[int, int]:
    """(level, views) of a learned-rans payload; TruncatedError when it is shorter than its 2-byte head
    and rANS state."""
    if len(payload) < 6:
        raise TruncatedError(f"a learned-rans token payload is {len(payload)} bytes, shorter than its 2-byte "
                             f"head and 4-byte rANS state")
    return int(payload[0]), int(payload[1])


def decode_learned_tokens(payload: BytesLike, tables: EntropyTables, rows: int, cols: int, which: str,
                          views: int | None = None, adaptive: bool = False) -> tuple[np.ndarray, int]:
    """(float32 (rows, cols) tokens, level) of a learned-rans payload. ``views``: the file's encoded camera
    count, which the payload's must equal (None: not checked); ``adaptive``: the file's required flag bit 10
    (adaptive rows). MalformedSectionError for a level or view
    count the tables do not have, a code outside -Q .. Q, or a damaged stream; TruncatedError if it ends early."""
    level, stored_views = parse_learned_payload(payload)
    if level >= tables.levels:
        raise MalformedSectionError(f"learned-rans payload names quality level index {level}; the model has "
                                    f"{tables.levels} levels")
    if not 1 <= stored_views <= MAX_VIEWS or (views is not None and stored_views != views):
        raise MalformedSectionError(f"learned-rans payload says {stored_views} encoded cameras; the file has "
                                    f"{views if views is not None else f'1 to {MAX_VIEWS}'}")
    if (rows, cols) != (tables.fingerprint.static_shape if which == "static" else tables.fingerprint.dynamic_shape):
        raise MalformedSectionError("token shape differs from the entropy tables' model")
    ctx = tables.contexts(which, stored_views)
    freqs = tables.freqs[level].reshape(-1, tables.freqs.shape[3])
    dependency = _mean_dependency(tables, level, stored_views) if which == "static" and tables.contextual else None
    symbols = rans_decode_ctx(memoryview(payload)[2:], ctx.reshape(-1), freqs,
                              dependency, adaptive).astype(np.int64).reshape(rows, cols)
    half = tables.half_range(level)[_group(which)][None, :]
    q = symbols - half
    if which == "static":
        origin, change = tables.copies(stored_views)
        q[change] = q[origin[change]] + symbols[change] - 2 * half
        if (np.abs(q) > half).any():
            raise MalformedSectionError("learned-rans payload decodes a frame-copy code outside -Q .. Q: damaged "
                                        "or forged bytes")
    return dequantize(q, tables, level, which), level
