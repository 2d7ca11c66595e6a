"""Spatial Branch E_s (paper Sec. 3.1): Z_s = E_s(X_{1:T}, P_s).

Latent patches of every source frame, concatenated with the Plücker rays of P_s, are embedded and
passed through factorized spatial (within a frame) and temporal (across frames at one patch)
attention into a camera-aware feature grid; N_s learnable static queries then cross-attend to the
grid (self-attention, cross-attention, MLP per layer) and their final states, through the token
bottleneck, are Z_s.
"""

from __future__ import annotations

import torch
from torch import nn

from .configs import ModelConfig
from .layers import (QUERY_INIT_STD, QueryBlock, SelfAttentionBlock, grid_positions, locality_prior, patchify,
                     token_cameras)

__all__ = ["SpatialBranch"]


class FactorizedBlock(nn.Module):
    """Spatial self-attention per frame, then temporal self-attention per patch position."""

    def __init__(self, width: int, heads: int, mlp_ratio: float) -> None:
        super().__init__()
        self.spatial = SelfAttentionBlock(width, heads, mlp_ratio)
        self.temporal = SelfAttentionBlock(width, heads, mlp_ratio)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: (B, T, P, D) -> (B, T, P, D)."""
        B, T, P, D = x.shape
        x = self.spatial(x.reshape(B * T, P, D)).view(B, T, P, D)
        x = self.temporal(x.transpose(1, 2).reshape(B * P, T, D)).view(B, P, T, D)
        return x.transpose(1, 2)


class SpatialBranch(nn.Module):
    """Returns query states (B, n_queries, D); the caller applies the token bottleneck."""

    def __init__(self, cfg: ModelConfig, n_queries: int) -> None:
        super().__init__()
        p, D = cfg.patch_size, cfg.width
        self.patch_size = p
        self.embed = nn.Linear((cfg.latent_channels + 6) * p * p, D)
        self.pos_space = nn.Parameter(torch.randn(cfg.patches_per_side ** 2, D) * 0.02)
        self.pos_time = nn.Parameter(torch.randn(cfg.frames, D) * 0.02)
        self.blocks = nn.ModuleList(FactorizedBlock(D, cfg.heads, cfg.mlp_ratio) for _ in range(cfg.spatial_layers))
        self.queries = nn.Parameter(torch.randn(n_queries, D) * QUERY_INIT_STD)
        self.query_blocks = nn.ModuleList(QueryBlock(D, cfg.heads, cfg.mlp_ratio) for _ in range(cfg.static_query_layers))
        self.query_bias = None
        self.query_content: nn.Linear | None = None
        self.anchor_views, self.spread_views = cfg.anchor_views, cfg.spread_views
        self.n_anchored = 0
        if cfg.locality_sigma > 0:  # static query i < N_anchored anchored at grid cell i mod P (configs.ModelConfig)
            self.n_anchored = min(cfg.n_anchored, n_queries)  # the rest (unified ablation's Z_d) read anywhere
            cells = grid_positions(cfg.patches_per_side)
            self.register_buffer("anchor", torch.arange(self.n_anchored) % cells.shape[0], persistent=False)
            self.query_bias = nn.Parameter(locality_prior(cells[self.anchor], cells, cfg.heads, cfg.locality_sigma))
            if cfg.query_from_grid:  # zero map: a model warm-started without it begins unchanged
                self.query_content = nn.Linear(D, D)
                nn.init.zeros_(self.query_content.weight)
                nn.init.zeros_(self.query_content.bias)

    def forward(self, latents: torch.Tensor, rays: torch.Tensor, views: int = 1) -> torch.Tensor:
        """latents X: (B, T, C, h, w); rays: (B, T, 6, h, w). Returns (B / views, n_queries, D).

        With ``views`` > 1 the B clips are ``views`` cameras per scene (scene-major): each camera's
        grid is built on its own (its rays say where it looks), then the queries of a scene attend to
        the grids of all its cameras at once. With ``config.anchor_views`` query i is anchored in
        camera i mod V (``config.spread_views``: :func:`layers.token_cameras`), its locality bias and grid
        feature coming from that camera's cell i mod P; without it, in every camera's cell alike."""
        x = self.embed(patchify(torch.cat([latents, rays], dim=2), self.patch_size))
        B, T, P, D = x.shape
        x = x + self.pos_space[None, None] + self.pos_time[None, :T, None]
        for block in self.blocks:
            x = block(x)
        S = B // views
        grid = x.reshape(S, views * T * P, D)  # camera-aware feature grids of a scene's cameras (V T P)
        q = self.queries[None].expand(S, -1, -1)
        na = self.n_anchored
        own = self.anchor_views and views > 1
        if own:
            camera = token_cameras(na, views, P, self.spread_views, x.device)  # each anchored query's camera
        if self.query_content is not None:  # + W * mean over frames of the anchor cell's feature
            cells = x.reshape(S, views, T, P, D).mean(2)  # (S, V, P, D)
            cell = cells[:, camera, self.anchor] if own else cells.mean(1)[:, self.anchor]
            q = torch.cat([q[:, :na] + self.query_content(cell), q[:, na:]], dim=1)
        bias = None
        if self.query_bias is not None:  # (heads, N_anchored, P) -> (heads, n_queries, V T P)
            per_camera = self.query_bias[:, :, None, None, :].expand(-1, -1, views, T, -1)
            if own:  # other cameras' cells: the bias of the query's farthest cell in its own camera
                mine = (camera[:, None] == torch.arange(views, device=x.device)[None])[None, :, :, None, None]
                per_camera = torch.where(mine, per_camera, self.query_bias.amin(-1)[:, :, None, None, None])
            heads = self.query_bias.shape[0]
            bias = per_camera.reshape(heads, na, views * T * P)
            if na < q.shape[1]:  # free queries: no bias
                bias = torch.cat([bias, bias.new_zeros(heads, q.shape[1] - na, views * T * P)], dim=1)
        for block in self.query_blocks:
            q = block(q, grid, bias=bias)
        return q
