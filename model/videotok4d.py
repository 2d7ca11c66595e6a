"""VideoTok4D: the tokenizer E = (E_s, E_d) and the renderer D_theta, around a frozen autoencoder.

    z_s, z_d = model.encode(batch)                       # Eq. 1, tokens (B, N_s, d), (B, N_d, d)
    frames = model.render(z_s, z_d, K_tgt, w2c_tgt)      # Euler integration of the rectified flow
    loss, logs = model.rectified_flow_loss(batch, target_frames, K_tgt, w2c_tgt)   # Eq. 2

Rendering takes tokens, never source frames, so one token state renders any number of target
trajectories without re-running the encoder. Sampling noise comes from a ``torch.Generator`` seeded
with ``seed``: the same tokens and seed give the same frames.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from vt4dcodec.errors import ModelError

from .autoencoder import LatentAutoencoder
from .bottleneck import TokenBottleneck
from .configs import ModelConfig
from .rays import latent_rays
from .renderer import Renderer
from .source_inputs import SourceBatch
from .spatial_branch import SpatialBranch
from .temporal_branch import TemporalBranch

__all__ = ["VideoTok4D"]


class VideoTok4D(nn.Module):
    """The whole model for one :class:`ModelConfig`."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.config = cfg
        self.autoencoder = LatentAutoencoder(cfg)
        n_spatial_queries = cfg.n_static + (cfg.n_dynamic if cfg.unified_tokens else 0)
        self.spatial_branch = SpatialBranch(cfg, n_spatial_queries)
        self.static_bottleneck = TokenBottleneck(cfg.width, cfg.token_dim, cfg.token_noise)
        if cfg.unified_tokens:  # ablation: one token set, same budget, no Temporal Branch
            self.temporal_branch = None
            self.dynamic_bottleneck = None
        else:
            self.temporal_branch = TemporalBranch(cfg)
            self.dynamic_bottleneck = TokenBottleneck(cfg.width, cfg.token_dim, cfg.token_noise)
        self.renderer = Renderer(cfg)

    # ---------------------------------------------------------------------------------------------
    def freeze_autoencoder(self) -> None:
        """Stage 2: the autoencoder is fixed (no gradients, never updated)."""
        self.autoencoder.requires_grad_(False)
        self.autoencoder.eval()

    def tokenizer_parameters(self) -> list[nn.Parameter]:
        """Everything trained in stage 2 (encoder branches, bottlenecks, renderer)."""
        return [p for name, p in self.named_parameters() if not name.startswith("autoencoder.")]

    def _check_video(self, frames: torch.Tensor, what: str) -> None:
        cfg = self.config
        if frames.ndim != 5 or frames.shape[2] != 3 or frames.shape[3:] != (cfg.image_size, cfg.image_size):
            raise ModelError(f"{what} must be (B, T, 3, {cfg.image_size}, {cfg.image_size}), got {tuple(frames.shape)}")
        if not 1 <= frames.shape[1] <= cfg.frames:
            raise ModelError(f"{what} has {frames.shape[1]} frames; this model takes 1..{cfg.frames}")
        if not frames.is_meta and not torch.isfinite(frames).all():
            raise ModelError(f"{what} hold non-finite values")

    def _check_cameras(self, K: torch.Tensor, w2c: torch.Tensor, B: int, T: int, what: str) -> None:
        if K.shape != (B, T, 3, 3) or w2c.shape != (B, T, 4, 4):
            raise ModelError(f"{what}: K must be ({B}, {T}, 3, 3) and w2c ({B}, {T}, 4, 4), "
                             f"got {tuple(K.shape)} and {tuple(w2c.shape)}")
        if not K.is_meta and not (torch.isfinite(K).all() and torch.isfinite(w2c).all()):
            raise ModelError(f"{what}: cameras hold non-finite values")

    def rays(self, K: torch.Tensor, w2c: torch.Tensor) -> torch.Tensor:
        """Plücker rays of cameras (B, T) at latent resolution: (B, T, 6, h, w), always float32."""
        with torch.autocast("cuda" if K.device.type == "cuda" else "cpu", enabled=False):
            return latent_rays(K, w2c, self.config.image_size, self.config.latent_size)

    def latents(self, frames: torch.Tensor) -> torch.Tensor:
        """X_t of the frozen encoder: (B, T, 3, H, W) in [0, 1] -> (B, T, C, h, w)."""
        with torch.no_grad():
            return self.autoencoder.encode(frames).float()

    # Eq. 1 ---------------------------------------------------------------------------------------
    def encode(self, batch: SourceBatch) -> tuple[torch.Tensor, torch.Tensor]:
        """Source clip -> (Z_s (B, N_s, d), Z_d (B, N_d, d)) float32 in (-1, 1)."""
        cfg = self.config
        self._check_video(batch.frames, "source frames")
        B, T = batch.frames.shape[:2]
        self._check_cameras(batch.K, batch.w2c, B, T, "source cameras")
        h = cfg.latent_size
        if batch.motion_mask.shape != (B, T, h, h):
            raise ModelError(f"motion_mask must be ({B}, {T}, {h}, {h}), got {tuple(batch.motion_mask.shape)}")
        if batch.track_xy.ndim != 4 or batch.track_xy.shape[0] != B or batch.track_xy.shape[2:] != (T, 2) \
                or batch.track_valid.shape != batch.track_xy.shape[:3]:
            raise ModelError("track_xy must be (B, N, T, 2) and track_valid (B, N, T)")
        x = self.latents(batch.frames)
        rays = self.rays(batch.K, batch.w2c)
        static_states = self.spatial_branch(x, rays)
        if self.temporal_branch is None:
            tokens = self.static_bottleneck(static_states)
            return tokens[:, :cfg.n_static], tokens[:, cfg.n_static:]
        dynamic_states = self.temporal_branch(x, rays, batch.motion_mask, batch.track_xy, batch.track_valid)
        return self.static_bottleneck(static_states), self.dynamic_bottleneck(dynamic_states)

    def _check_tokens(self, z_s: torch.Tensor, z_d: torch.Tensor) -> None:
        cfg = self.config
        if z_s.ndim != 3 or z_s.shape[1:] != cfg.static_shape or z_d.ndim != 3 or z_d.shape[1:] != cfg.dynamic_shape \
                or z_s.shape[0] != z_d.shape[0]:
            raise ModelError(f"tokens must be (B, {cfg.n_static}, {cfg.token_dim}) and (B, {cfg.n_dynamic}, "
                             f"{cfg.token_dim}), got {tuple(z_s.shape)} and {tuple(z_d.shape)}")

    # sampling ------------------------------------------------------------------------------------
    @torch.no_grad()
    def render_latents(self, z_s: torch.Tensor, z_d: torch.Tensor, K_tgt: torch.Tensor, w2c_tgt: torch.Tensor,
                       *, steps: int = 8, seed: int = 0, drop_static: bool = False,
                       drop_dynamic: bool = False) -> torch.Tensor:
        """Euler integration of dY/dtau = v from tau = 1 (seeded noise) to tau = 0.

        K_tgt: (B, T, 3, 3) px of the H x W image; w2c_tgt: (B, T, 4, 4). Returns Y^0 (B, T, C, h, w).
        """
        self._check_tokens(z_s, z_d)
        if not isinstance(steps, int) or steps < 1:
            raise ModelError(f"steps must be a positive integer, got {steps!r}")
        cfg = self.config
        B = z_s.shape[0]
        T = K_tgt.shape[1] if K_tgt.ndim == 4 else -1
        self._check_cameras(K_tgt, w2c_tgt, B, T, "target cameras")
        if not 1 <= T <= cfg.frames:
            raise ModelError(f"target trajectory has {T} frames; this model renders 1..{cfg.frames}")
        device = z_s.device
        generator = torch.Generator(device="cpu").manual_seed(int(seed))
        h = cfg.latent_size
        y = torch.randn((B, T, cfg.latent_channels, h, h), generator=generator).to(device)
        rays = self.rays(K_tgt.to(device), w2c_tgt.to(device))
        z_s, z_d = z_s.float(), z_d.float()
        for i in range(steps):
            tau = torch.full((B,), 1.0 - i / steps, device=device)
            v = self.renderer(y, z_s, z_d, rays, tau, drop_static=drop_static, drop_dynamic=drop_dynamic)
            y = y - v.float() / steps
        return y

    @torch.no_grad()
    def render(self, z_s: torch.Tensor, z_d: torch.Tensor, K_tgt: torch.Tensor, w2c_tgt: torch.Tensor,
               **kwargs: Any) -> torch.Tensor:
        """Tokens + target trajectory -> frames (B, T, 3, H, W) in [0, 1] (kwargs as render_latents)."""
        latents = self.render_latents(z_s, z_d, K_tgt, w2c_tgt, **kwargs)
        return self.autoencoder.decode(latents).float().clamp_(0.0, 1.0)

    # Eq. 2 ---------------------------------------------------------------------------------------
    def rectified_flow_loss(self, batch: SourceBatch, target_frames: torch.Tensor, K_tgt: torch.Tensor,
                            w2c_tgt: torch.Tensor, generator: torch.Generator | None = None
                            ) -> tuple[torch.Tensor, dict[str, float]]:
        """L_tok = E || (Y^1 - Y^0) - v_theta(Y^tau, Z_s, Z_d, P_tgt, tau) ||^2, tau ~ U(0, 1).

        target_frames: (B, T, 3, H, W) in [0, 1]; K_tgt (B, T, 3, 3); w2c_tgt (B, T, 4, 4).
        ``generator`` (CPU) makes tau and Y^1 reproducible. Returns the scalar loss and float logs.
        """
        self._check_video(target_frames, "target frames")
        B, T = target_frames.shape[:2]
        self._check_cameras(K_tgt, w2c_tgt, B, T, "target cameras")
        z_s, z_d = self.encode(batch)
        y0 = self.latents(target_frames)
        y1 = torch.randn(y0.shape, generator=generator).to(y0.device)
        tau = torch.rand((B,), generator=generator).to(y0.device)
        t = tau.view(B, 1, 1, 1, 1)
        y_tau = (1.0 - t) * y0 + t * y1
        v = self.renderer(y_tau, z_s, z_d, self.rays(K_tgt, w2c_tgt), tau)
        loss = F.mse_loss(v.float(), y1 - y0)
        logs = {"loss": float(loss.detach()), "tau": float(tau.mean()),
                "z_s_abs": float(z_s.detach().abs().mean()), "z_d_abs": float(z_d.detach().abs().mean())}
        return loss, logs

    def forward(self, batch: SourceBatch, target_frames: torch.Tensor, K_tgt: torch.Tensor, w2c_tgt: torch.Tensor,
                generator: torch.Generator | None = None) -> tuple[torch.Tensor, dict[str, float]]:
        """The training objective (so DistributedDataParallel can wrap the model): see rectified_flow_loss."""
        return self.rectified_flow_loss(batch, target_frames, K_tgt, w2c_tgt, generator)

    def fingerprint(self, model_id: str, model_version: str) -> Any:
        """The :class:`vt4dcodec.format.ModelFingerprint` a container stores for these weights."""
        from .weights_io import model_fingerprint

        return model_fingerprint(self, model_id, model_version)
