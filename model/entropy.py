"""The learned entropy model of the tokens: quality levels, per-channel densities, frozen integer tables.

A token value z in (-1, 1) is stored at quality level ``l`` as the integer ``q = round(z / step[l, c])``,
``|q| <= Q = floor(1 / step + 1/2)``, and read back as ``float32(q) * step`` (``c``: its channel; Z_s
and Z_d have their own steps). The integers are entropy-coded with one frequency table per *context*
(class, channel), where the class of a token is

- ``MEAN`` (0): a static token that is the first (time-average) token of its anchor (or any static token
  of a model without frame copies); its symbol is ``q + Q``;
- ``CHANGE`` (1): a later frame copy of an anchor (``Renderer.copy_origin``): it is coded as the
  difference ``q - q_origin`` to its anchor's time-average token, symbol ``q - q_origin + 2Q``. Copies of
  a cell that did not change cost next to nothing;
- ``DYNAMIC`` (2): a dynamic token; symbol ``q + Q``;
- with ``config.entropy_context``, ``MEAN_AFTER_NEGATIVE`` (3) and ``MEAN_AFTER_POSITIVE`` (4): a MEAN token
  after the first whose previous MEAN token (the one with the largest smaller index) has a negative or
  positive code in the same channel (neighbouring cells' tokens agree); symbol ``q + Q`` as for MEAN;
- with ``config.entropy_partners`` as well, six more MEAN classes by the sign of the same token's code in
  the channel's *partner* channel (an earlier channel that moves with it): ``MEAN_PARTNER_NEGATIVE`` + 0/1/2
  (5, 6, 7) and ``MEAN_PARTNER_POSITIVE`` + 0/1/2 (8, 9, 10) for a previous MEAN code below / at / above 0
  (``vt4dcodec.format.learned.pair_class``); a partner code of 0 (or no partner) keeps the classes above.

Each context has a density over its value range (``HALF_RANGE``: (-1, 1), the change class (-2, 2)): a
piecewise-constant density of ``BINS`` bins (softmax of learned logits), so its CDF F is piecewise
linear and the probability of every quantization bin is exact for any step. In training (CompressAI's
``EntropyBottleneck`` with additive noise) the tokens get uniform noise of one step and the rate is
``-log2(F(x + step/2) - F(x - step/2))`` bits; a loss D + lambda_l R trains the encoder, the renderer,
the densities and the steps of level ``l`` together. :meth:`TokenEntropyModel.update` (CompressAI's
``update()``) freezes everything the decoder needs into integer buffers that ship in the weights (and
so in the weights SHA-256 of the model fingerprint): 14-bit rANS frequency tables per level and
context, the float16-exact steps, and for every number of encoded cameras the anchor origin of each
static token. Reading a file then needs no float arithmetic beyond ``float32(q) * step``
(``vt4dcodec.format.learned``, FORMAT.md).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from vt4dcodec.format.learned import pair_class

__all__ = ["TokenEntropyModel", "BINS", "Q_MAX", "ALPHABET", "MIN_STEP", "MAX_STEP", "MAX_VIEWS", "MEAN", "CHANGE",
           "DYNAMIC", "MEAN_AFTER_NEGATIVE", "MEAN_AFTER_POSITIVE", "MEAN_PARTNER_NEGATIVE", "MEAN_PARTNER_POSITIVE",
           "HALF_RANGE", "PROB_BITS", "bin_probabilities", "frequencies", "symbol_count"]

BINS = 256                 # density bins over a class's value range
Q_MAX = 32                 # |q| <= 32: steps >= 1/32 (finer than int5)
MIN_STEP, MAX_STEP = 1.0 / 32.0, 1.0
ALPHABET = 4 * Q_MAX + 1   # the widest table: a change symbol in 0 .. 4Q
MAX_VIEWS = 64             # encoded cameras of one token set (format: 1 + 63 extra cameras)
MEAN, CHANGE, DYNAMIC, MEAN_AFTER_NEGATIVE, MEAN_AFTER_POSITIVE = 0, 1, 2, 3, 4
MEAN_PARTNER_NEGATIVE, MEAN_PARTNER_POSITIVE = 5, 8  # + 0, 1, 2: previous MEAN code below, at, above 0
HALF_RANGE = (1.0, 2.0) + (1.0,) * 9
PROB_BITS = 14             # the rANS coder's precision (vt4dcodec.format.rans)
MIN_PROB = 2.0 ** -PROB_BITS


def symbol_count(step: float, cls: int) -> int:
    """Symbols of the table of a context of class ``cls`` at quantizer ``step``: 2Q + 1 (4Q + 1 for a
    change), Q = floor(1 / step + 1/2)."""
    q = int(math.floor(1.0 / step + 0.5))
    return (4 if cls == CHANGE else 2) * q + 1


def bin_probabilities(logits: np.ndarray, step: float, cls: int) -> np.ndarray:
    """float64 probabilities of every symbol of one context (``logits``: its BINS density logits): the
    density's mass over each quantization bin [(k - 1/2) step, (k + 1/2) step], the outer bins reaching
    to the range's ends."""
    r = HALF_RANGE[cls]
    p = np.exp(logits.astype(np.float64) - logits.max())
    p /= p.sum()
    cum = np.concatenate([[0.0], np.cumsum(p)])
    cum[-1] = 1.0
    n = symbol_count(step, cls)
    half = n // 2
    edges = (np.arange(n + 1) - half - 0.5) * step
    u = np.clip((edges + r) / (2 * r) * BINS, 0.0, BINS)
    j = np.minimum(np.floor(u).astype(np.int64), BINS - 1)
    F = cum[j] + (u - j) * p[j]
    F[0], F[-1] = 0.0, 1.0
    return np.maximum(np.diff(F), 0.0)


def frequencies(prob: np.ndarray) -> np.ndarray:
    """Integer frequencies (int64) summing to 2^14, every symbol >= 1, from probabilities: the largest
    remainders get the units left over after flooring (ties to the lower symbol). Deterministic in its
    float64 input; it runs once, at ship time (the tables are stored, never recomputed by a reader)."""
    total = 1 << PROB_BITS
    n = len(prob)
    if n > total:
        raise ValueError("more symbols than frequency units")
    share = prob / prob.sum() * (total - n)
    freq = np.floor(share).astype(np.int64) + 1
    left = total - int(freq.sum())
    order = np.lexsort((np.arange(n), -(share - np.floor(share))))
    freq[order[:left]] += 1
    return freq


class TokenEntropyModel(nn.Module):
    """Densities (3, 5 or 11 classes x ``token_dim`` channels) and per-level quantizer steps of one tokenizer.

    Parameters: ``logits`` (classes, d, BINS) and ``log_step`` (levels, 2, d) (index 0: Z_s, 1: Z_d).
    Buffers filled by :meth:`update` (zero until then): ``steps`` float32 (levels, 2, d),
    ``freqs`` int16 (levels, classes, d, ALPHABET) and ``origins`` int16 (MAX_VIEWS, N_s); with 11 classes
    ``partners`` int16 (d,), each channel's partner channel (-1: none), set at construction.
    """

    def __init__(self, levels: int, n_static: int, token_dim: int, classes: int = 3,
                 partners: tuple[int, ...] | None = None) -> None:
        super().__init__()
        if classes not in (3, 5, 11):
            raise ValueError(f"an entropy model has 3, 5 or 11 density classes, not {classes}")
        if (classes == 11) != (partners is not None) or (partners is not None and (
                len(partners) != token_dim or any(not -1 <= p < c for c, p in enumerate(partners)))):
            raise ValueError("an entropy model of 11 classes needs partners, one earlier channel or -1 a channel")
        self.levels, self.n_static, self.token_dim, self.classes = levels, n_static, token_dim, classes
        self.logits = nn.Parameter(torch.zeros(classes, token_dim, BINS))
        # level 0 the coarsest (1/3 of the range a step), the last the finest (1/32)
        init = torch.linspace(math.log(1.0 / 3.0), math.log(MIN_STEP * 1.01), levels) if levels > 1 \
            else torch.full((1,), math.log(1.0 / 8.0))
        self.log_step = nn.Parameter(init.view(levels, 1, 1).repeat(1, 2, token_dim).contiguous())
        self.register_buffer("steps", torch.zeros(levels, 2, token_dim))
        self.register_buffer("freqs", torch.zeros(levels, classes, token_dim, ALPHABET, dtype=torch.int16))
        self.register_buffer("origins", torch.zeros(MAX_VIEWS, n_static, dtype=torch.int16))
        if partners is not None:
            self.register_buffer("partners", torch.tensor(partners, dtype=torch.int16))

    # training ------------------------------------------------------------------------------------
    def step(self, level: int) -> torch.Tensor:
        """(2, d) the trained quantizer steps of ``level`` (Z_s, Z_d), within [MIN_STEP, MAX_STEP]."""
        return self.log_step[level].exp().clamp(MIN_STEP, MAX_STEP)

    def _cdf(self, x: torch.Tensor, table: torch.Tensor) -> torch.Tensor:
        """F(x) of the contexts ``table`` (x's shape, index cls * d + c) under the densities."""
        p = torch.softmax(self.logits.float(), dim=-1).reshape(-1, BINS)   # (classes d, BINS)
        cum = torch.cat([p.new_zeros(p.shape[0], 1), p.cumsum(-1)], dim=-1)  # (classes d, BINS + 1)
        r = torch.tensor(HALF_RANGE, device=x.device)[table // self.token_dim]
        u = ((x + r) / (2 * r) * BINS).clamp(0.0, float(BINS))
        j = u.detach().floor().clamp(max=BINS - 1).long()
        flat = table * BINS
        return cum.reshape(-1).take(table * (BINS + 1) + j) + (u - j) * p.reshape(-1).take(flat + j)

    def bits(self, x: torch.Tensor, table: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        """-log2 of the probability of the step-wide bin around each (noisy) value ``x`` of context
        ``table``; the ideal code length of its symbol (>= 0, at most PROB_BITS as in the coder)."""
        p = self._cdf(x + step / 2, table) - self._cdf(x - step / 2, table)
        return -torch.log2(p.clamp_min(MIN_PROB))

    def static_tables(self, origin: torch.Tensor) -> torch.Tensor:
        """(N_s, d) context index of every static token value: MEAN or CHANGE per token, by channel."""
        cls = torch.where(origin == torch.arange(len(origin), device=origin.device), MEAN, CHANGE)
        return cls[:, None] * self.token_dim + torch.arange(self.token_dim, device=origin.device)[None, :]

    @staticmethod
    def previous_mean(origin: torch.Tensor) -> torch.Tensor:
        """(N_s,) long: for each MEAN token after the first, the index of the previous MEAN token; -1 for the
        first MEAN token and for CHANGE tokens (``vt4dcodec.format.learned.EntropyTables.mean_dependency``)."""
        index = torch.arange(len(origin), device=origin.device)
        mean = origin == index
        last = torch.cummax(torch.where(mean, index, torch.full_like(index, -1)), dim=0).values
        prev = torch.cat([last.new_full((1,), -1), last[:-1]])
        return torch.where(mean, prev, torch.full_like(prev, -1))

    def context_tables(self, z_s: torch.Tensor, origin: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        """(S, N_s, d) context index of every static value: :meth:`static_tables`, and with 5 classes a MEAN
        token after the first moved to MEAN_AFTER_NEGATIVE / _POSITIVE by the sign of the previous MEAN token's
        code ``round(z / step)`` at this level (the code a file stores; no gradient flows through it); with 11
        classes also by the sign of the token's own code in the channel's partner channel
        (``vt4dcodec.format.learned.pair_class``)."""
        tab = self.static_tables(origin).expand(z_s.shape[0], -1, -1)
        if self.classes == 3:
            return tab
        prev = self.previous_mean(origin)
        has = prev >= 0
        code = torch.round(z_s.detach()[:, prev.clamp(min=0)] / step)  # (S, N_s, d)
        a = torch.where(has[None, :, None], torch.sign(code), torch.zeros_like(code)).long() + 1  # 0, 1, 2
        b = torch.ones_like(a)  # no partner: the sign class of 0
        if self.classes == 11:
            partners = self.partners.long()
            p = partners.clamp(min=0)
            own = torch.round(z_s.detach()[:, :, p] / step[p])  # (S, N_s, d): the partner channel's code
            b = torch.where(partners[None, None, :] >= 0, torch.sign(own), torch.zeros_like(own)).long() + 1
        table = torch.tensor([[pair_class(i - 1, j - 1) for j in range(3)] for i in range(3)], device=z_s.device)
        cls = table[a, b]  # FORMAT.md I.6.2's class of a MEAN value (the 5-class rule where b is 1)
        channel = torch.arange(self.token_dim, device=z_s.device)
        mean = (tab // self.token_dim == MEAN)
        return torch.where(mean, cls * self.token_dim + channel, tab)

    def quantized(self, z: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        """z on the code grid of ``step`` as a file stores it, ``clip(round(z / step), -Q, Q) * step``, with a
        straight-through gradient (identity to z; none to the step). A CHANGE token's code is its own
        rounded code too (round(x - n) + n = round(x) for an integer origin code n), so one rounding serves
        every class."""
        s = step.detach()
        half = torch.floor(1.0 / s + 0.5)
        q = torch.maximum(torch.minimum(torch.round(z.detach() / s), half), -half) * s
        return z + (q - z.detach())

    def noisy(self, z_s: torch.Tensor, z_d: torch.Tensor, level: int, origin: torch.Tensor,
              quantized: bool = False) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Training proxy of quantization at ``level``: z (S, N, d) + step x U(-1/2, 1/2), and the bits
        (S,) each scene's token set would cost. ``origin`` (N_s,) long: each static token's anchor origin
        (itself for MEAN tokens); a CHANGE token's value is its difference to its noisy origin. With
        ``quantized`` the tokens returned (what the renderer reads) are the stored values instead
        (:meth:`quantized`, straight-through) while the bits still come from the noisy values -- the
        "mixed" quantization of learned image codecs, which teaches the renderer the coarse levels' real
        inputs (a step of 1 leaves three values a channel, not a continuum)."""
        step = self.step(level)
        zs = z_s + (torch.rand_like(z_s) - 0.5) * step[0]
        zd = z_d + (torch.rand_like(z_d) - 0.5) * step[1]
        tab_s = self.context_tables(z_s, origin, step[0])
        x_s = zs - torch.where(tab_s // self.token_dim == CHANGE, zs[:, origin], torch.zeros_like(zs))
        tab_d = (DYNAMIC * self.token_dim + torch.arange(self.token_dim, device=z_d.device)).expand(z_d.shape[1], -1)
        bits = self.bits(x_s, tab_s, step[0].expand_as(x_s)).sum(dim=(1, 2)) \
            + self.bits(zd, tab_d.expand_as(zd), step[1].expand_as(zd)).sum(dim=(1, 2))
        if quantized:
            return self.quantized(z_s, step[0]), self.quantized(z_d, step[1]), bits
        return zs, zd, bits

    def density_loss(self, z_s: torch.Tensor, z_d: torch.Tensor, origin: torch.Tensor,
                     level: int | None = None) -> torch.Tensor:
        """Mean bits per value of detached tokens at ``level`` (default: averaged over every level): the
        loss that fits the densities alone (steps fixed), the calibration of a fresh model before rate
        training."""
        levels = range(self.levels) if level is None else (level,)
        total = sum(self.noisy(z_s.detach(), z_d.detach(), lv, origin)[2].mean() for lv in levels)
        return total / (len(levels) * (z_s.shape[1] + z_d.shape[1]) * self.token_dim)

    # shipping ------------------------------------------------------------------------------------
    @torch.no_grad()
    def update(self, origins: torch.Tensor) -> None:
        """Freeze the steps (rounded to float16 values, as weights ship), the integer frequency tables of
        every level and context, and ``origins`` (MAX_VIEWS, N_s), the anchor origin of every static
        token for 1 .. MAX_VIEWS encoded cameras."""
        steps = self.step_values()
        logits = self.logits.detach().double().cpu().numpy()
        freqs = np.zeros((self.levels, self.classes, self.token_dim, ALPHABET), np.int64)
        for level in range(self.levels):
            for cls in range(self.classes):
                for c in range(self.token_dim):
                    step = float(steps[level, 1 if cls == DYNAMIC else 0, c])
                    f = frequencies(bin_probabilities(logits[cls, c], step, cls))
                    freqs[level, cls, c, :len(f)] = f
        self.steps.copy_(steps)
        self.freqs.copy_(torch.from_numpy(freqs.astype(np.int16)))
        self.origins.copy_(origins.to(torch.int16))

    def step_values(self) -> torch.Tensor:
        """(levels, 2, d) float32 steps as they ship: the trained steps rounded to float16 values."""
        return torch.stack([self.step(level) for level in range(self.levels)]).detach().half().float()

    @property
    def frozen(self) -> bool:
        """Whether :meth:`update` has filled the tables."""
        return bool((self.freqs[0, 0, 0] != 0).any())
