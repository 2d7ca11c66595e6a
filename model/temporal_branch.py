"""Temporal Branch E_d with Track-Aware Dynamic Attention (paper Sec. 3.2), the learned part:
Z_d = E_d(X^dyn_{1:T}, P_s, F_{1:T-1}).

The non-learned inputs (motion mask M_t, Eq. 3-4; tracks p_i^t with validity, Eq. 6) come from
``model.inputs.motion`` / ``model.inputs.tracks`` through :class:`~vt4dcodec.model.inputs.source_inputs.SourceBatch`. Here:

1. X^dyn_t = X_t ⊙ M_t (Eq. 4), embedded per latent pixel together with the Plücker rays of P_s;
2. Xbar^dyn_t = A_sp(X^dyn_t; M_t) -- spatial self-attention whose keys are the masked pixels only
   (Eq. 5); pixels outside the mask are zeroed afterwards;
3. g_i^t = Xbar^dyn_t(p_i^t) -- bilinear samples at the tracked positions, t in V_i (Eq. 6);
4. per layer l: g~_i = MHA_l(g_i, G_i, G_i) along each track separately (Eq. 7, batched as B*N
   sequences with a key-padding mask from validity, so tracks never mix), then the N_d dynamic
   queries do self-attention, cross-attention to all valid track features, and an MLP.

With ``config.dynamic_splat`` dynamic query k is tied to one track (:func:`select_tracks`: encoded camera
k mod V, its (k // V)-th most moving track): after each track layer it adds a linear map (zero at
initialisation) of that track's features averaged over its valid frames, so token k can say where its
track goes (the renderer splats it there).

Ablations: ``motion_isolation=False`` uses a mask of ones; ``track_attention=False`` replaces the
tracks by fixed grid positions (p_i^t = p_i^1, valid everywhere): fixed-grid temporal attention.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from .configs import ModelConfig
from .layers import QUERY_INIT_STD, QueryBlock, SelfAttentionBlock, dynamic_token_cameras

__all__ = ["TemporalBranch", "TrackAttention", "sample_at_tracks", "fixed_grid_tracks", "select_tracks"]


def sample_at_tracks(features: torch.Tensor, track_xy: torch.Tensor) -> torch.Tensor:
    """g_i^t = features_t(p_i^t), bilinear, zero outside the map (Eq. 6).

    features: (B, T, D, h, w); track_xy: (B, N, T, 2) latent pixel coords (u, v), centres at integers.
    Returns (B, N, T, D).
    """
    B, T, D, h, w = features.shape
    N = track_xy.shape[1]
    scale = track_xy.new_tensor([2.0 / max(w - 1, 1), 2.0 / max(h - 1, 1)])
    grid = (track_xy * scale - 1.0).permute(0, 2, 1, 3).reshape(B * T, N, 1, 2)
    out = F.grid_sample(features.reshape(B * T, D, h, w), grid.to(features.dtype), mode="bilinear",
                        padding_mode="zeros", align_corners=True)  # (B T, D, N, 1)
    return out.view(B, T, D, N).permute(0, 3, 1, 2)


def fixed_grid_tracks(batch: int, n_tracks: int, frames: int, latent_size: int,
                      device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """The fixed-grid ablation: N stationary points on a regular grid, valid in every frame.

    Returns track_xy (B, N, T, 2) and track_valid (B, N, T) bool.
    """
    side = max(1, math.isqrt(n_tracks))
    rows = math.ceil(n_tracks / side)
    u = (torch.arange(side, device=device, dtype=torch.float32) + 0.5) * latent_size / side - 0.5
    v = (torch.arange(rows, device=device, dtype=torch.float32) + 0.5) * latent_size / rows - 0.5
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    xy = torch.stack([uu, vv], dim=-1).reshape(-1, 2)[:n_tracks]
    track_xy = xy[None, :, None, :].expand(batch, -1, frames, -1).contiguous()
    return track_xy, torch.ones(batch, n_tracks, frames, dtype=torch.bool, device=device)


def _stable_descending_order(score: torch.Tensor) -> torch.Tensor:
    """(B, N) long: the indices of score (B, N) from highest to lowest, ties in index order, the same as
    ``torch.sort(-score, dim=1, stable=True).indices``; written with comparisons and a scatter because
    ONNX export has no stable sort (the encoder graph of ``onnx_export``)."""
    N = score.shape[1]
    index = torch.arange(N, device=score.device)
    higher = score[:, None, :] > score[:, :, None]  # [b, i, j]: track j scores above track i
    tie_before = (score[:, None, :] == score[:, :, None]) & (index[None, :] < index[:, None])[None]
    rank = (higher | tie_before).sum(-1)  # (B, N) a permutation of 0..N-1 in every row
    return torch.zeros_like(rank).scatter(1, rank, index[None].expand_as(rank).contiguous())


def select_tracks(motion_mask: torch.Tensor, track_xy: torch.Tensor, track_valid: torch.Tensor, n_dynamic: int,
                  views: int) -> torch.Tensor:
    """The track each dynamic token is tied to (``config.dynamic_splat``): (S, N_d) long indices into a
    scene's V N tracks (camera-major: index c N + i is track i of encoded camera c).

    Token k takes encoded camera c = k mod V and that camera's (k // V mod N)-th track by motion score,
    the mean of the motion mask M_t (B, T, h, w) at the track's position over its valid frames (ties keep
    the track order). track_xy (B, N, T, 2), track_valid (B, N, T); B = S V clips, scene-major."""
    B, N, T = track_valid.shape
    S = B // views
    mask = sample_at_tracks(motion_mask[:, :T, None].float(), track_xy.float())[..., 0]  # (B, N, T)
    valid = track_valid.float()
    score = (mask * valid).sum(-1) / valid.sum(-1).clamp_min(1.0)  # (B, N)
    order = _stable_descending_order(score).view(S, views, N)  # best first per camera
    camera = dynamic_token_cameras(n_dynamic, views, score.device)
    rank = (torch.arange(n_dynamic, device=score.device) // views) % N
    return order[:, camera, rank] + camera[None] * N


class TrackAttention(nn.Module):
    """Eq. 7: self-attention along every track independently.

    The (B, N, T, D) features are reshaped into B*N sequences of length T; keys are restricted to the
    track's valid frames. Attention never crosses the sequence boundary, so track i's output is a
    function of track i's features only.
    """

    def __init__(self, width: int, heads: int, mlp_ratio: float) -> None:
        super().__init__()
        self.block = SelfAttentionBlock(width, heads, mlp_ratio)

    def forward(self, g: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """g: (B, N, T, D); valid: (B, N, T) bool. Returns (B, N, T, D), zero at invalid frames."""
        B, N, T, D = g.shape
        out = self.block(g.reshape(B * N, T, D), key_valid=valid.reshape(B * N, T)).view(B, N, T, D)
        return out * valid[..., None].to(out.dtype)


class TemporalBranch(nn.Module):
    """Returns dynamic query states (B, N_d, D); the caller applies the token bottleneck."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        D, h = cfg.width, cfg.latent_size
        self.cfg = cfg
        self.embed = nn.Linear(cfg.latent_channels + 6, D)
        self.pos_space = nn.Parameter(torch.randn(h * h, D) * 0.02)
        self.spatial = nn.ModuleList(SelfAttentionBlock(D, cfg.heads, cfg.mlp_ratio)
                                     for _ in range(cfg.dynamic_spatial_layers))
        self.track_pos = nn.Linear(4, D)  # (u, v) normalised to [-1, 1] and their sines
        self.pos_time = nn.Parameter(torch.randn(cfg.frames, D) * 0.02)
        self.track_layers = nn.ModuleList(TrackAttention(D, cfg.heads, cfg.mlp_ratio) for _ in range(cfg.track_layers))
        self.queries = nn.Parameter(torch.randn(cfg.n_dynamic, D) * QUERY_INIT_STD)
        self.query_layers = nn.ModuleList(QueryBlock(D, cfg.heads, cfg.mlp_ratio) for _ in range(cfg.track_layers))
        self.track_query: nn.ModuleList | None = None
        if cfg.dynamic_splat:  # query k + W_l (its own track's mean feature); zero: a warm start encodes as before
            self.track_query = nn.ModuleList(nn.Linear(D, D) for _ in range(cfg.track_layers))
            for layer in self.track_query:
                nn.init.zeros_(layer.weight)
                nn.init.zeros_(layer.bias)

    def masked_features(self, latents: torch.Tensor, rays: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Eq. 4-5: Xbar^dyn. latents (B,T,C,h,w), rays (B,T,6,h,w), mask (B,T,h,w) -> (B,T,D,h,w)."""
        B, T, C, h, w = latents.shape
        x_dyn = latents * mask[:, :, None]  # Eq. 4
        x = self.embed(torch.cat([x_dyn, rays], dim=2).permute(0, 1, 3, 4, 2).reshape(B * T, h * w, C + 6))
        x = x + self.pos_space[None]
        inside = mask.reshape(B * T, h * w) > 0.5
        if torch.onnx.is_in_onnx_export():  # the same attention on the whole grid, keys restricted to the mask:
            for block in self.spatial:       # no data-dependent length (ONNX graphs have static shapes here)
                x = block(x, key_valid=inside)
            x = x * inside[..., None].to(x.dtype)
            return x.view(B, T, h, w, -1).permute(0, 1, 4, 2, 3)
        # Eq. 5 on the masked pixels only: gather them (padded to the largest region of the batch),
        # attend among them, scatter back; everything outside the mask stays zero.
        count = inside.sum(dim=1)
        length = h * w if x.is_meta else max(int(count.max()), 1)  # meta: shape checks only
        order = torch.argsort((~inside).to(torch.int8), dim=1, stable=True)[:, :length]  # masked first
        region_valid = torch.arange(length, device=x.device)[None] < count[:, None]
        region = torch.gather(x, 1, order[..., None].expand(-1, -1, x.shape[-1]))
        for block in self.spatial:
            region = block(region, key_valid=region_valid)
        region = region * region_valid[..., None].to(region.dtype)
        out = torch.zeros_like(x).scatter(1, order[..., None].expand(-1, -1, x.shape[-1]), region)
        return out.view(B, T, h, w, -1).permute(0, 1, 4, 2, 3)

    def forward(self, latents: torch.Tensor, rays: torch.Tensor, motion_mask: torch.Tensor,
                track_xy: torch.Tensor, track_valid: torch.Tensor, views: int = 1,
                chosen: torch.Tensor | None = None) -> torch.Tensor:
        """latents X: (B,T,C,h,w); rays: (B,T,6,h,w); motion_mask: (B,T,h,w) in [0,1];
        track_xy: (B,N,T,2) latent pixels; track_valid: (B,N,T) bool. Returns (B / views, N_d, D).
        With ``config.dynamic_splat`` query k reads its :func:`select_tracks` track (chosen on the given
        tracks, before the fixed-grid ablation replaces them); ``chosen`` (S, N_d) passes that selection in
        when the caller already made it.

        With ``views`` > 1 (cameras per scene, scene-major) every camera's tracks are attended along
        on their own (Eq. 7) and the dynamic queries of a scene read the tracks of all its cameras."""
        B, T, _, h, w = latents.shape
        if not self.cfg.motion_isolation:
            motion_mask = torch.ones_like(motion_mask)
        if self.track_query is None:
            chosen = None
        elif chosen is None:
            chosen = select_tracks(motion_mask, track_xy, track_valid, self.cfg.n_dynamic, views)  # (S, N_d)
        if not self.cfg.track_attention:
            track_xy, track_valid = fixed_grid_tracks(B, self.cfg.n_tracks, T, h, latents.device)
        features = self.masked_features(latents, rays, motion_mask.to(latents.dtype))
        g = sample_at_tracks(features, track_xy)  # Eq. 6
        norm_xy = track_xy * track_xy.new_tensor([2.0 / max(w - 1, 1), 2.0 / max(h - 1, 1)]) - 1.0
        g = g + self.track_pos(torch.cat([norm_xy, torch.sin(math.pi * norm_xy)], dim=-1)) + self.pos_time[:T]
        valid = track_valid.bool()
        g = g * valid[..., None].to(g.dtype)
        scenes = B // views
        q = self.queries[None].expand(scenes, -1, -1)
        flat_valid = valid.reshape(scenes, -1)  # (B/V, V N T)
        for layer, (track_layer, query_layer) in enumerate(zip(self.track_layers, self.query_layers)):
            g = track_layer(g, valid)  # Eq. 7 (pre-norm residual block)
            if chosen is not None:
                assert self.track_query is not None
                mean = g.sum(2) / valid.sum(2, keepdim=True).clamp_min(1).to(g.dtype)  # (B, N, D) over valid frames
                mine = torch.gather(mean.reshape(scenes, -1, g.shape[-1]), 1,
                                    chosen[..., None].expand(-1, -1, g.shape[-1]))
                q = q + self.track_query[layer](mine)
            q = query_layer(q, g.reshape(scenes, -1, g.shape[-1]), flat_valid)
        return q
