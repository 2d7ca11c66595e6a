"""What the encoder E(V_s, P_s) consumes: a source clip plus its non-learned preprocessing.

The learned networks never call OpenCV: optical flow, motion isolation (paper Sec. 3.2) and track
propagation are computed once per clip by ``model.motion`` / ``model.tracks`` and arrive here as arrays.
One clip is a :class:`SourceInputs` (numpy); a training or inference batch is a :class:`SourceBatch`
(torch), built by :meth:`SourceBatch.collate`.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch

__all__ = ["SourceInputs", "SourceBatch"]


@dataclass
class SourceInputs:
    """One source clip ready for the encoder.

    Attributes:
        frames: (T, H, W, 3) uint8 RGB.
        K: (T, 3, 3) float32 intrinsics in pixels of ``frames``.
        w2c: (T, 4, 4) float32 world-to-camera poses, metres.
        motion_mask: (T, h, w) float32 in [0, 1], the motion mask M_t at latent resolution (Eq. 4).
        track_xy: (N, T, 2) float32 track positions p_i^t in latent pixel coordinates (u, v), pixel
            centres at integers.
        track_valid: (N, T) bool, True where track i is valid at frame t.
    """

    frames: np.ndarray
    K: np.ndarray
    w2c: np.ndarray
    motion_mask: np.ndarray
    track_xy: np.ndarray
    track_valid: np.ndarray

    def __post_init__(self) -> None:
        T = self.frames.shape[0]
        if self.frames.dtype != np.uint8 or self.frames.ndim != 4 or self.frames.shape[-1] != 3:
            raise ValueError("frames must be (T, H, W, 3) uint8")
        if self.K.shape != (T, 3, 3) or self.w2c.shape != (T, 4, 4):
            raise ValueError("K must be (T, 3, 3) and w2c (T, 4, 4)")
        if self.motion_mask.ndim != 3 or self.motion_mask.shape[0] != T:
            raise ValueError("motion_mask must be (T, h, w)")
        N = self.track_xy.shape[0]
        if self.track_xy.shape != (N, T, 2) or self.track_valid.shape != (N, T):
            raise ValueError("track_xy must be (N, T, 2) and track_valid (N, T)")


@dataclass
class SourceBatch:
    """A batch of source clips as tensors (leading batch dimension B).

    Attributes:
        frames: (B, T, 3, H, W) float32 in [0, 1].
        K: (B, T, 3, 3) float32.   w2c: (B, T, 4, 4) float32.
        motion_mask: (B, T, h, w) float32.
        track_xy: (B, N, T, 2) float32 (latent pixels).   track_valid: (B, N, T) bool.
        latents: optional (B, T, C, h, w) float32, the frozen autoencoder's latents of ``frames``
            when a caller already has them (training reads them from a cache); None = computed.
    """

    frames: torch.Tensor
    K: torch.Tensor
    w2c: torch.Tensor
    motion_mask: torch.Tensor
    track_xy: torch.Tensor
    track_valid: torch.Tensor
    latents: torch.Tensor | None = None

    @classmethod
    def collate(cls, items: list[SourceInputs]) -> "SourceBatch":
        """Stack clips; they must share T, H, W, latent size and track count N."""
        def stack(name: str) -> np.ndarray:
            return np.stack([getattr(it, name) for it in items])

        frames = torch.from_numpy(stack("frames")).permute(0, 1, 4, 2, 3).float().div_(255.0)
        return cls(
            frames=frames,
            K=torch.from_numpy(stack("K")).float(),
            w2c=torch.from_numpy(stack("w2c")).float(),
            motion_mask=torch.from_numpy(stack("motion_mask")).float(),
            track_xy=torch.from_numpy(stack("track_xy")).float(),
            track_valid=torch.from_numpy(stack("track_valid")).bool(),
        )

    def to(self, device: torch.device | str) -> "SourceBatch":
        return SourceBatch(**{f.name: None if getattr(self, f.name) is None else getattr(self, f.name).to(device)
                              for f in fields(self)})

    @property
    def batch_size(self) -> int:
        return int(self.frames.shape[0])
