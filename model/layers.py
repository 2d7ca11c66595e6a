"""Transformer building blocks shared by the branches and the renderer.

All attention goes through :func:`masked_attention`, which accepts a key-validity mask and is safe
when a query has no valid key at all (its output is zero instead of NaN) -- the Temporal Branch hits
that case for empty motion masks and for tracks that are invalid in every frame.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

__all__ = [
    "QUERY_INIT_STD", "masked_attention", "Attention", "MLP", "SelfAttentionBlock", "QueryBlock", "AdaLNBlock",
    "timestep_embedding", "patchify", "unpatchify", "locality_prior", "locality_heads", "grid_positions",
    "token_cameras", "dynamic_token_cameras", "render_noise", "frame_group_change",
]


# Learnable query sets (static and dynamic) start at unit scale. At std 0.02 the first self-attention's
# output, nearly the same for every query, swamps them: with fresh weights the spread of query states
# across slots is 0.03 of their std (0.43 at std 1), and training then collapses every slot onto one
# vector (measured on vt4d-tiny 0.2.0: spread 0.0017 of 0.77).
QUERY_INIT_STD = 1.0


def masked_attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor,
                     key_valid: torch.Tensor | None = None, bias: torch.Tensor | None = None) -> torch.Tensor:
    """Scaled dot-product attention over heads.

    Args:
        q: (B, heads, Lq, Dh); k, v: (B, heads, Lk, Dh).
        key_valid: optional (B, Lk) bool, False keys are ignored.
        bias: optional float (heads, Lq, Lk) or (B, heads, Lq, Lk) added to the attention logits (a
            positional prior).
    Returns:
        (B, heads, Lq, Dh); rows whose batch item has no valid key are exactly zero.
    """
    if bias is not None:
        bias = bias.to(q.dtype)
    if key_valid is None:
        return F.scaled_dot_product_attention(q, k, v, attn_mask=bias)
    any_valid = key_valid.any(dim=-1)  # (B,)
    safe = key_valid | ~any_valid[:, None]  # rows without keys attend everywhere, then get zeroed
    mask = safe[:, None, None, :]
    if bias is not None:
        mask = torch.where(mask, bias if bias.ndim == 4 else bias[None], torch.tensor(float("-inf"), dtype=q.dtype, device=q.device))
    out = F.scaled_dot_product_attention(q, k, v, attn_mask=mask)
    return out * any_valid[:, None, None, None].to(out.dtype)


def locality_heads(heads: int) -> int:
    """How many of the first heads carry a locality prior: half of them (all of a single head), so every
    token keeps heads that may read anywhere."""
    return heads // 2 if heads > 1 else heads


def locality_prior(anchors: torch.Tensor, positions: torch.Tensor, heads: int, sigma: float) -> torch.Tensor:
    """A Gaussian attention-logit prior between anchored items and positions on one image grid.

    anchors: (Na, 2) and positions: (Np, 2), (row, col) in the same units as ``sigma`` (encoder patches).
    Returns (heads, Na, Np): -d^2 / (2 sigma^2) for the first half of the heads, 0 for the others (so
    every token keeps heads that may read anywhere)."""
    d2 = ((anchors[:, None, :] - positions[None, :, :]) ** 2).sum(-1)
    prior = (-d2 / (2.0 * sigma ** 2))[None].repeat(heads, 1, 1)
    prior[locality_heads(heads):] = 0.0
    return prior


def grid_positions(side: int, cell: float = 1.0) -> torch.Tensor:
    """(side^2, 2) (row, col) centres of a side x side grid of cells of size ``cell``, row-major."""
    idx = (torch.arange(side, dtype=torch.float32) + 0.5) * cell
    rows, cols = torch.meshgrid(idx, idx, indexing="ij")
    return torch.stack([rows, cols], dim=-1).reshape(-1, 2)


def token_cameras(n: int, views: int, cells: int, spread: bool = False,
                  device: torch.device | None = None) -> torch.Tensor:
    """(n,) index of the encoded camera (of ``views``) that anchored token i belongs to; its cell is
    i mod ``cells``. i mod V, under which a camera reaches only cells / gcd(V, cells) distinct cells; with
    ``spread``, when gcd(V, cells) > 1 and a camera has more tokens than that, (i + floor(i / cells)) mod V:
    each block of ``cells`` tokens shifts by one camera, so each camera's tokens cover distinct cells
    (config ``spread_views``; 320 tokens on 64 cells: V = 2, 4, 8 spread, V = 10 already has 32 distinct
    cells each)."""
    index = torch.arange(n, device=device)
    common = math.gcd(views, cells)
    if spread and common > 1 and -(-n // views) > cells // common:
        index = index + index // cells
    return index % views


class Attention(nn.Module):
    """Multi-head attention; self-attention when ``context`` is None, cross-attention otherwise."""

    def __init__(self, width: int, heads: int, context_width: int | None = None) -> None:
        super().__init__()
        self.heads = heads
        self.q = nn.Linear(width, width)
        self.kv = nn.Linear(context_width or width, 2 * width)
        self.out = nn.Linear(width, width)

    def forward(self, x: torch.Tensor, context: torch.Tensor | None = None,
                key_valid: torch.Tensor | None = None, bias: torch.Tensor | None = None) -> torch.Tensor:
        """x: (B, Lq, D); context: (B, Lk, Dc) or None; key_valid: (B, Lk) bool; bias: (heads, Lq, Lk)
        float added to the logits. Returns (B, Lq, D)."""
        B, Lq, D = x.shape
        ctx = x if context is None else context
        q = self.q(x).view(B, Lq, self.heads, D // self.heads).transpose(1, 2)
        k, v = self.kv(ctx).view(B, ctx.shape[1], 2, self.heads, D // self.heads).permute(2, 0, 3, 1, 4)
        out = masked_attention(q, k, v, key_valid, bias)
        return self.out(out.transpose(1, 2).reshape(B, Lq, D))


class MLP(nn.Module):
    def __init__(self, width: int, ratio: float) -> None:
        super().__init__()
        hidden = int(round(width * ratio))
        self.net = nn.Sequential(nn.Linear(width, hidden), nn.GELU(approximate="tanh"), nn.Linear(hidden, width))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class SelfAttentionBlock(nn.Module):
    """Pre-norm self-attention + MLP over a set of tokens, with optional key validity."""

    def __init__(self, width: int, heads: int, mlp_ratio: float) -> None:
        super().__init__()
        self.norm1, self.attn = nn.LayerNorm(width), Attention(width, heads)
        self.norm2, self.mlp = nn.LayerNorm(width), MLP(width, mlp_ratio)

    def forward(self, x: torch.Tensor, key_valid: torch.Tensor | None = None) -> torch.Tensor:
        """x: (B, L, D); key_valid: (B, L) bool or None."""
        x = x + self.attn(self.norm1(x), key_valid=key_valid)
        return x + self.mlp(self.norm2(x))


class QueryBlock(nn.Module):
    """Learnable queries: self-attention, cross-attention to a context, MLP (Sec. 3.1 and 3.2)."""

    def __init__(self, width: int, heads: int, mlp_ratio: float) -> None:
        super().__init__()
        self.norm_self, self.self_attn = nn.LayerNorm(width), Attention(width, heads)
        self.norm_q, self.norm_ctx = nn.LayerNorm(width), nn.LayerNorm(width)
        self.cross_attn = Attention(width, heads)
        self.norm_mlp, self.mlp = nn.LayerNorm(width), MLP(width, mlp_ratio)

    def forward(self, queries: torch.Tensor, context: torch.Tensor,
                context_valid: torch.Tensor | None = None, bias: torch.Tensor | None = None) -> torch.Tensor:
        """queries: (B, Nq, D); context: (B, L, D); context_valid: (B, L) bool; bias: (heads, Nq, L)
        float added to the cross-attention logits. Returns (B, Nq, D)."""
        queries = queries + self.self_attn(self.norm_self(queries))
        queries = queries + self.cross_attn(self.norm_q(queries), self.norm_ctx(context), context_valid, bias)
        return queries + self.mlp(self.norm_mlp(queries))


class AdaLNBlock(nn.Module):
    """Renderer block: spatial self-attention (within a frame), temporal self-attention (across frames
    at one patch), cross-attention to the scene tokens, MLP; each residual branch modulated by the
    flow time tau (adaptive LayerNorm shift/scale/gate, zero-initialised gates as in DiT)."""

    N_BRANCHES = 4

    def __init__(self, width: int, heads: int, mlp_ratio: float) -> None:
        super().__init__()
        self.norms = nn.ModuleList(nn.LayerNorm(width, elementwise_affine=False) for _ in range(self.N_BRANCHES))
        self.spatial = Attention(width, heads)
        self.temporal = Attention(width, heads)
        self.cross = Attention(width, heads)
        self.norm_tokens = nn.LayerNorm(width)
        self.mlp = MLP(width, mlp_ratio)
        self.modulation = nn.Linear(width, 3 * self.N_BRANCHES * width)
        nn.init.zeros_(self.modulation.weight)
        nn.init.zeros_(self.modulation.bias)

    def forward(self, x: torch.Tensor, cond: torch.Tensor, tokens: torch.Tensor,
                tokens_valid: torch.Tensor | None, token_bias: torch.Tensor | None = None) -> torch.Tensor:
        """x: (B, T, P, D) video patch tokens; cond: (B, D) tau embedding; tokens: (B, N, D);
        tokens_valid: (B, N) bool or None; token_bias: (heads, T P, N) or (B, heads, T P, N) float added to the
        cross-attention logits. Returns (B, T, P, D)."""
        B, T, P, D = x.shape
        mods = self.modulation(F.silu(cond)).view(B, self.N_BRANCHES, 3, 1, 1, D)

        def branch(i: int, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            shift, scale, gate = mods[:, i, 0], mods[:, i, 1], mods[:, i, 2]
            return self.norms[i](h) * (1 + scale) + shift, gate

        h, gate = branch(0, x)
        x = x + gate * self.spatial(h.reshape(B * T, P, D)).view(B, T, P, D)
        h, gate = branch(1, x)
        h = h.transpose(1, 2).reshape(B * P, T, D)
        x = x + gate * self.temporal(h).view(B, P, T, D).transpose(1, 2)
        h, gate = branch(2, x)
        ctx = self.norm_tokens(tokens)
        x = x + gate * self.cross(h.reshape(B, T * P, D), ctx, tokens_valid, token_bias).view(B, T, P, D)
        h, gate = branch(3, x)
        return x + gate * self.mlp(h)


def timestep_embedding(tau: torch.Tensor, dim: int, max_period: float = 10_000.0,
                       dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Sinusoidal embedding of flow times tau in [0, 1] (scaled by 1000 as in DiT). (B,) -> (B, dim) in ``dtype``
    (float32; float64 for the prior's sampler)."""
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, device=tau.device, dtype=dtype) / half)
    args = 1000.0 * tau.to(dtype)[:, None] * freqs[None]
    emb = torch.cat([torch.cos(args), torch.sin(args)], dim=-1)
    return F.pad(emb, (0, dim - emb.shape[-1]))


def dynamic_token_cameras(n_dynamic: int, views: int, device: torch.device | None = None) -> torch.Tensor:
    """(N_d,) long: the encoded camera of dynamic token k, k mod V (``config.dynamic_splat``)."""
    return torch.arange(n_dynamic, device=device) % views


def dynamic_patch_offsets(size: int, like: torch.Tensor) -> torch.Tensor:
    """(size^2, 2) (du, dv) latent-pixel offsets of a dynamic token's size x size patch from its track
    point, row-major, centred (``config.dynamic_splat``); dtype and device of ``like``."""
    side = torch.arange(size, dtype=like.dtype, device=like.device) - (size - 1) / 2
    dv, du = torch.meshgrid(side, side, indexing="ij")
    return torch.stack([du, dv], dim=-1).reshape(-1, 2)


def patchify(x: torch.Tensor, p: int) -> torch.Tensor:
    """(B, T, C, h, w) -> (B, T, (h/p)(w/p), C p p), patches in row-major order."""
    B, T, C, h, w = x.shape
    x = x.reshape(B, T, C, h // p, p, w // p, p).permute(0, 1, 3, 5, 2, 4, 6)
    return x.reshape(B, T, (h // p) * (w // p), C * p * p)


def unpatchify(x: torch.Tensor, p: int, C: int, h: int, w: int) -> torch.Tensor:
    """Inverse of :func:`patchify`: (B, T, (h/p)(w/p), C p p) -> (B, T, C, h, w)."""
    B, T = x.shape[:2]
    x = x.reshape(B, T, h // p, w // p, C, p, p).permute(0, 1, 4, 2, 5, 3, 6)
    return x.reshape(B, T, C, h, w)


def render_noise(frames: int, channels: int, size: int, seed: int) -> torch.Tensor:
    """The noise (1, frames, channels, size, size) float32 a render of ``seed`` starts from (CPU generator); its
    first T frames are the noise of a T-frame render."""
    generator = torch.Generator(device="cpu").manual_seed(int(seed))
    return torch.randn((1, frames, channels, size, size), generator=generator)


def frame_group_change(values: torch.Tensor, covers: torch.Tensor) -> torch.Tensor:
    """Each anchored token's frame group's mean minus its time average: values (S, N_a, T, F) at the token's cell
    per frame, covers (N_a, T) the frames of its group (``Renderer.copy_frames``) -> (S, N_a, F), zero for a
    token that covers no frame."""
    count = covers.sum(1)
    group = torch.einsum("sntc,nt->snc", values, covers / count.clamp_min(1.0)[:, None])
    return (group - values.mean(2)) * (count > 0)[None, :, None]
