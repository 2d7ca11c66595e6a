"""Small random inputs for the network tests (tiny shapes, deterministic per seed)."""

from __future__ import annotations

import torch

from vt4dcodec.model import ModelConfig, SourceBatch


def orbit_cameras(B: int, T: int, image_size: int, radius: float = 3.0, seed: int = 0
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    """K (B, T, 3, 3) px and w2c (B, T, 4, 4): cameras on a circle looking at the origin."""
    g = torch.Generator().manual_seed(seed)
    f = image_size * 0.9
    c = (image_size - 1) / 2
    K = torch.tensor([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]]).expand(B, T, 3, 3).clone()
    start = torch.rand(B, 1, generator=g) * 6.28
    angle = start + torch.linspace(0, 0.3, T)[None]  # (B, T)
    w2c = torch.zeros(B, T, 4, 4)
    centre = torch.stack([radius * torch.sin(angle), torch.zeros_like(angle), -radius * torch.cos(angle)], -1)
    forward = -centre / radius
    down = torch.tensor([0.0, 1.0, 0.0]).expand_as(forward)
    right = torch.linalg.cross(down, forward, dim=-1)
    R = torch.stack([right, down, forward], dim=-2)  # rows: camera axes in world
    w2c[..., :3, :3] = R
    w2c[..., :3, 3] = -(R @ centre[..., None])[..., 0]
    w2c[..., 3, 3] = 1.0
    return K, w2c


def random_batch(cfg: ModelConfig, B: int = 2, n_tracks: int = 16, seed: int = 0,
                 mask_density: float = 0.2) -> SourceBatch:
    g = torch.Generator().manual_seed(seed)
    T, H, h = cfg.frames, cfg.image_size, cfg.latent_size
    K, w2c = orbit_cameras(B, T, H, seed=seed)
    return SourceBatch(
        frames=torch.rand(B, T, 3, H, H, generator=g),
        K=K, w2c=w2c,
        motion_mask=(torch.rand(B, T, h, h, generator=g) < mask_density).float(),
        track_xy=torch.rand(B, n_tracks, T, 2, generator=g) * (h - 1),
        track_valid=torch.rand(B, n_tracks, T, generator=g) < 0.7,
    )
