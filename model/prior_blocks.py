"""Co4DGen building blocks (paper Sec. 3.3): the conditioning encoder E_cond(V_c, P_c, P_a) and the
co-denoising block G^l with Static-Dynamic Cross-Token Attention.

Routing (the paper's "static queries attend only within the static stream, whereas dynamic queries
attend to both streams") is one attention over the concatenation [H_s; H_d] with the boolean mask of
:func:`static_dynamic_mask`: row i (a query) may see column j (a key) unless i is static and j is
dynamic.  Static outputs therefore do not depend on the dynamic stream at all in that layer.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from vt4dcodec.errors import ModelError

from .layers import MLP, Attention, SelfAttentionBlock, timestep_embedding
from .rays import latent_rays

__all__ = ["static_dynamic_mask", "StaticDynamicAttention", "CoDenoisingBlock", "ConditionEncoder"]


def static_dynamic_mask(n_static: int, n_dynamic: int, device: torch.device | None = None) -> torch.Tensor:
    """(N, N) bool attention mask over [static; dynamic] tokens, True = may attend.

    Static rows see static columns only; dynamic rows see every column.
    """
    n = n_static + n_dynamic
    mask = torch.ones((n, n), dtype=torch.bool, device=device)
    mask[:n_static, n_static:] = False
    return mask


class StaticDynamicAttention(nn.Module):
    """Static-Dynamic Cross-Token Attention: multi-head attention over [H_s; H_d] with the asymmetric
    mask above.  Queries, keys and values have per-stream projections (the two streams carry different
    kinds of content); the output projection is per stream too."""

    def __init__(self, width: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.qkv_s, self.qkv_d = nn.Linear(width, 3 * width), nn.Linear(width, 3 * width)
        self.out_s, self.out_d = nn.Linear(width, width), nn.Linear(width, width)

    def forward(self, h_s: torch.Tensor, h_d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """h_s: (B, N_s, D), h_d: (B, N_d, D) -> attention outputs of the same shapes."""
        B, n_s, D = h_s.shape
        n_d = h_d.shape[1]
        qkv = torch.cat([self.qkv_s(h_s), self.qkv_d(h_d)], dim=1)  # (B, N, 3D)
        q, k, v = qkv.view(B, n_s + n_d, 3, self.heads, D // self.heads).permute(2, 0, 3, 1, 4)
        mask = static_dynamic_mask(n_s, n_d, h_s.device)
        out = F.scaled_dot_product_attention(q, k, v, attn_mask=mask).transpose(1, 2).reshape(B, n_s + n_d, D)
        return self.out_s(out[:, :n_s]), self.out_d(out[:, n_s:])


class _Modulation(nn.Module):
    """adaLN shift/scale/gate for ``branches`` residual branches of one stream, from the conditioning
    vector c (flow time + pooled condition); zero-initialised so every block starts as the identity."""

    def __init__(self, width: int, branches: int) -> None:
        super().__init__()
        self.branches = branches
        self.linear = nn.Linear(width, 3 * branches * width)
        nn.init.zeros_(self.linear.weight)
        nn.init.zeros_(self.linear.bias)

    def forward(self, c: torch.Tensor) -> torch.Tensor:
        """c: (B, D) -> (B, branches, 3, 1, D)."""
        B, D = c.shape
        return self.linear(F.silu(c)).view(B, self.branches, 3, 1, D)


def _modulate(norm: nn.Module, x: torch.Tensor, mods: torch.Tensor, i: int) -> tuple[torch.Tensor, torch.Tensor]:
    shift, scale, gate = mods[:, i, 0], mods[:, i, 1], mods[:, i, 2]
    return norm(x) * (1 + scale) + shift, gate


class CoDenoisingBlock(nn.Module):
    """G^l: (H_s^{l+1}, H_d^{l+1}) = G^l(H_s^l, H_d^l, h, tau).

    Three residual branches per stream, each adaLN-modulated by c = emb(tau) + pool(h) (per-stream
    modulation): (1) Static-Dynamic Cross-Token Attention, (2) cross-attention to the conditioning
    features h (injected into both streams), (3) an MLP.
    """

    BRANCHES = 3

    def __init__(self, width: int, heads: int, mlp_ratio: float) -> None:
        super().__init__()
        self.norms_s = nn.ModuleList(nn.LayerNorm(width, elementwise_affine=False) for _ in range(self.BRANCHES))
        self.norms_d = nn.ModuleList(nn.LayerNorm(width, elementwise_affine=False) for _ in range(self.BRANCHES))
        self.mod_s, self.mod_d = _Modulation(width, self.BRANCHES), _Modulation(width, self.BRANCHES)
        self.joint = StaticDynamicAttention(width, heads)
        self.cross_s, self.cross_d = Attention(width, heads), Attention(width, heads)
        self.norm_cond = nn.LayerNorm(width)
        self.mlp_s, self.mlp_d = MLP(width, mlp_ratio), MLP(width, mlp_ratio)

    def forward(self, h_s: torch.Tensor, h_d: torch.Tensor, cond: torch.Tensor, c: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """h_s (B, N_s, D), h_d (B, N_d, D), cond: h (B, L, D), c: (B, D). Returns updated streams."""
        ms, md = self.mod_s(c), self.mod_d(c)
        xs, gs = _modulate(self.norms_s[0], h_s, ms, 0)
        xd, gd = _modulate(self.norms_d[0], h_d, md, 0)
        a_s, a_d = self.joint(xs, xd)
        h_s, h_d = h_s + gs * a_s, h_d + gd * a_d
        ctx = self.norm_cond(cond)
        xs, gs = _modulate(self.norms_s[1], h_s, ms, 1)
        xd, gd = _modulate(self.norms_d[1], h_d, md, 1)
        h_s, h_d = h_s + gs * self.cross_s(xs, ctx), h_d + gd * self.cross_d(xd, ctx)
        xs, gs = _modulate(self.norms_s[2], h_s, ms, 2)
        xd, gd = _modulate(self.norms_d[2], h_d, md, 2)
        return h_s + gs * self.mlp_s(xs), h_d + gd * self.mlp_d(xd)


class ConditionEncoder(nn.Module):
    """E_cond(V_c, P_c, P_a) -> h (B, L, D) conditioning tokens.

    * V_c: frames (B, T, 3, H, W) in [0, 1] cut into ``cond_patch`` x ``cond_patch`` pixel patches
      (linear patch embedding), plus the Plücker rays of P_c at the patch centres (6 channels, embedded
      and added) -- so every video token knows where in the world its pixels look.
    * P_a: Plücker rays of the anchor trajectory on a coarser ``anchor_grid`` x ``anchor_grid`` grid per
      frame, embedded as their own tokens -- the camera the sampled tokens must be the scene *of*.
    Both carry a learned frame-index embedding and a learned type embedding, then ``layers``
    self-attention blocks mix them.  L = T (H/p)^2 + T g^2.
    """

    def __init__(self, width: int, heads: int, mlp_ratio: float, layers: int, frames: int, image_size: int,
                 cond_patch: int, anchor_grid: int) -> None:
        super().__init__()
        if image_size % cond_patch:
            raise ModelError(f"image_size {image_size} is not divisible by cond_patch {cond_patch}")
        self.frames, self.image_size, self.patch, self.anchor_grid = frames, image_size, cond_patch, anchor_grid
        self.grid = image_size // cond_patch
        self.patch_embed = nn.Linear(3 * cond_patch * cond_patch, width)
        self.ray_embed_c = nn.Linear(6, width)
        self.ray_embed_a = nn.Linear(6, width)
        self.frame_embed = nn.Parameter(torch.randn(frames, width) * 0.02)
        self.type_embed = nn.Parameter(torch.randn(2, width) * 0.02)
        self.blocks = nn.ModuleList(SelfAttentionBlock(width, heads, mlp_ratio) for _ in range(layers))
        self.norm = nn.LayerNorm(width)

    def num_tokens(self, T: int) -> int:
        return T * (self.grid ** 2 + self.anchor_grid ** 2)

    def forward(self, frames: torch.Tensor, K_c: torch.Tensor, w2c_c: torch.Tensor, K_a: torch.Tensor,
                w2c_a: torch.Tensor) -> torch.Tensor:
        """frames (B, T, 3, H, W) in [0, 1]; K_* (B, T, 3, 3) px of the H x W image; w2c_* (B, T, 4, 4)."""
        B, T, _, H, W = frames.shape
        p, g, ga = self.patch, self.grid, self.anchor_grid
        patches = frames.reshape(B, T, 3, g, p, g, p).permute(0, 1, 3, 5, 2, 4, 6).reshape(B, T, g * g, 3 * p * p)
        with torch.autocast(frames.device.type, enabled=False):
            dtype = self.patch_embed.weight.dtype  # float32, or float64 in the sampler's copy
            rays_c = latent_rays(K_c, w2c_c, self.image_size, g, dtype).flatten(3).transpose(2, 3)   # (B, T, g*g, 6)
            rays_a = latent_rays(K_a, w2c_a, self.image_size, ga, dtype).flatten(3).transpose(2, 3)  # (B, T, ga*ga, 6)
        frame_pos = self.frame_embed[:T][None, :, None, :]
        video = self.patch_embed(patches) + self.ray_embed_c(rays_c) + frame_pos + self.type_embed[0]
        anchor = self.ray_embed_a(rays_a) + frame_pos + self.type_embed[1]
        h = torch.cat([video.reshape(B, T * g * g, -1), anchor.reshape(B, T * ga * ga, -1)], dim=1)
        for block in self.blocks:
            h = block(h)
        return self.norm(h)


def flow_time_embedding(tau: torch.Tensor, width: int, mlp: nn.Module) -> torch.Tensor:
    """emb(tau): sinusoidal features of tau in [0, 1] through ``mlp``. (B,) -> (B, width)."""
    return mlp(timestep_embedding(tau, width, dtype=next(mlp.parameters()).dtype))
