"""Renderer D_theta (paper Sec. 3.1, Eq. 2): the rectified-flow velocity network
v_theta(Y^tau, Z_s, Z_d, P_tgt, tau) over target-video latents.

Target latents Y^tau (B, T, C, h, w) are patchified together with the Plücker rays of P_tgt, pass
through tau-modulated (AdaLN) blocks of spatial, temporal and token cross-attention, and are
unpatchified into a velocity of the same shape. Token masking (the ablation of Table 4): a dropped group
(Z_s or Z_d) is removed from the keys of every cross-attention.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .configs import ModelConfig
from .layers import AdaLNBlock, grid_positions, locality_prior, patchify, timestep_embedding, unpatchify

__all__ = ["Renderer"]


class Renderer(nn.Module):
    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        p, D, C = cfg.renderer_patch, cfg.width, cfg.latent_channels
        self.cfg = cfg
        self.embed = nn.Linear((C + 6) * p * p, D)
        self.pos_space = nn.Parameter(torch.randn(cfg.renderer_patches_per_side ** 2, D) * 0.02)
        self.pos_time = nn.Parameter(torch.randn(cfg.frames, D) * 0.02)
        self.tau_mlp = nn.Sequential(nn.Linear(D, D), nn.SiLU(), nn.Linear(D, D))
        self.token_in = nn.Linear(cfg.token_dim, D)
        n_tokens = cfg.n_static + cfg.n_dynamic
        self.token_slot = nn.Parameter(torch.randn(n_tokens, D) * 0.02)  # queries keep their slot order
        self.token_type = nn.Parameter(torch.randn(2, D) * 0.02)  # static, dynamic
        self.blocks = nn.ModuleList(AdaLNBlock(D, cfg.heads, cfg.mlp_ratio) for _ in range(cfg.renderer_layers))
        self.final_norm = nn.LayerNorm(D, elementwise_affine=False)
        self.final_mod = nn.Linear(D, 2 * D)
        self.out = nn.Linear(D, C * p * p)
        self.token_bias = None
        if cfg.locality_sigma > 0:  # render patch j prefers the static tokens anchored near it (configs)
            cells = grid_positions(cfg.patches_per_side)  # encoder grid, in encoder patches
            n_anchored = n_tokens if cfg.unified_tokens else cfg.n_static
            anchors = cells[torch.arange(n_anchored) % cells.shape[0]]
            patches = grid_positions(cfg.renderer_patches_per_side, cfg.renderer_patch / cfg.patch_size)
            prior = torch.zeros(cfg.heads, patches.shape[0], n_tokens)
            prior[:, :, :n_anchored] = locality_prior(patches, anchors, cfg.heads, cfg.locality_sigma)
            self.token_bias = nn.Parameter(prior)
        for layer in (self.final_mod, self.out):
            nn.init.zeros_(layer.weight)
            nn.init.zeros_(layer.bias)

    def embed_tokens(self, z_s: torch.Tensor, z_d: torch.Tensor, drop_static: bool | torch.Tensor,
                     drop_dynamic: bool | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """[Z_s; Z_d] (B, N_s+N_d, d) -> (B, N_s+N_d, D) and their key validity (None = all kept).

        A drop flag is a bool for the whole batch or a (B,) bool tensor, one per item."""
        B, n_s, n_d = z_s.shape[0], z_s.shape[1], z_d.shape[1]
        tokens = self.token_in(torch.cat([z_s, z_d], dim=1).to(self.token_in.weight.dtype)) + self.token_slot[None]
        types = torch.zeros(n_s + n_d, dtype=torch.long, device=z_s.device)
        if not self.cfg.unified_tokens:
            types[n_s:] = 1
        tokens = tokens + self.token_type[types][None]
        if not any(isinstance(flag, torch.Tensor) or flag for flag in (drop_static, drop_dynamic)):
            return tokens, None
        drops = [torch.as_tensor(flag, dtype=torch.bool, device=z_s.device).expand(B)
                 for flag in (drop_static, drop_dynamic)]
        keep = torch.ones(B, n_s + n_d, dtype=torch.bool, device=z_s.device)
        keep[:, :n_s] &= ~drops[0][:, None]
        keep[:, n_s:] &= ~drops[1][:, None]
        return tokens, keep

    def forward(self, y_tau: torch.Tensor, z_s: torch.Tensor, z_d: torch.Tensor, rays: torch.Tensor,
                tau: torch.Tensor, *, drop_static: bool | torch.Tensor = False,
                drop_dynamic: bool | torch.Tensor = False) -> torch.Tensor:
        """y_tau: (B, T, C, h, w); z_s: (B, N_s, d); z_d: (B, N_d, d); rays: (B, T, 6, h, w) of P_tgt;
        tau: (B,) in [0, 1]. Returns the velocity v (B, T, C, h, w)."""
        B, T, C, h, w = y_tau.shape
        p = self.cfg.renderer_patch
        x = self.embed(patchify(torch.cat([y_tau, rays.to(y_tau.dtype)], dim=2), p))
        x = x + self.pos_space[None, None] + self.pos_time[None, :T, None]
        cond = self.tau_mlp(timestep_embedding(tau, x.shape[-1]))
        tokens, keep = self.embed_tokens(z_s, z_d, drop_static, drop_dynamic)
        bias = None if self.token_bias is None else self.token_bias.repeat(1, T, 1)  # rows t P + p
        for block in self.blocks:
            x = block(x, cond, tokens, keep, bias)
        shift, scale = self.final_mod(F.silu(cond)).view(B, 1, 1, 2, -1).unbind(dim=3)
        x = self.out(self.final_norm(x) * (1 + scale) + shift)
        return unpatchify(x, p, C, h, w)
