"""Plücker camera-ray embeddings of a trajectory at latent resolution (the P_s / P_tgt inputs).

Thin wrapper over :mod:`vt4dcodec.model.geometry`: intrinsics given for the H x W image are rescaled to
the h x w latent map with the pixel-centre rule cx' = (cx + 0.5) s - 0.5, then every latent pixel
centre gets its world ray (d, o x d).
"""

from __future__ import annotations

import torch

from .geometry import plucker_rays, scale_intrinsics

__all__ = ["latent_rays"]


def latent_rays(K: torch.Tensor, w2c: torch.Tensor, image_size: int, latent_size: int,
                dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Rays at latent resolution for cameras whose K refers to ``image_size`` pixels.

    K: (B, T, 3, 3) px; w2c: (B, T, 4, 4) metres. Returns (B, T, 6, latent_size, latent_size) in ``dtype``
    (float32; float64 for the prior's sampler).
    """
    s = latent_size / image_size
    K_latent = scale_intrinsics(K.to(dtype), s, s)
    return plucker_rays(K_latent, w2c.to(dtype), latent_size, latent_size).to(dtype)
