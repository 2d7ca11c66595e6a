"""What the encoder E(V_s, P_s) consumes: a source clip plus its non-learned preprocessing.

The learned networks never call OpenCV: optical flow, motion isolation (paper Sec. 3.2) and track
propagation are computed once per clip by ``model.inputs.motion`` / ``model.inputs.tracks`` and arrive here as arrays.
One clip is a :class:`SourceInputs` (numpy); a training or inference batch is a :class:`SourceBatch`
(torch), built by :meth:`SourceBatch.collate` from :func:`stack_inputs`, the same arrays in numpy (what the
ONNX encoder runs on; this module imports torch only when a batch is built). A scene may be encoded from several synchronized cameras
at once: the batch then holds ``views`` clips per scene, scene-major, and the encoder fuses them into
one token set per scene.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch

__all__ = ["SourceInputs", "SourceBatch", "stack_inputs"]


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
        track_depth: optional (N, T) float32 depth in metres of track i's point at frame t along the
            camera's z axis, 0 where unknown: training supervision only (the synthetic generator's depth);
            the encoder never reads it.
    """

    frames: np.ndarray
    K: np.ndarray
    w2c: np.ndarray
    motion_mask: np.ndarray
    track_xy: np.ndarray
    track_valid: np.ndarray
    track_depth: np.ndarray | None = None

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
        if self.track_depth is not None and self.track_depth.shape != (N, T):
            raise ValueError("track_depth must be (N, T)")


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
        track_depth: optional (B, N, T) float32 metres, 0 = unknown (:class:`SourceInputs`); training only.
        views: clips per scene (V >= 1). The B items are scene-major: scene b's cameras are items
            b V .. b V + V - 1, so the batch encodes B / V scenes.
    """

    frames: torch.Tensor
    K: torch.Tensor
    w2c: torch.Tensor
    motion_mask: torch.Tensor
    track_xy: torch.Tensor
    track_valid: torch.Tensor
    latents: torch.Tensor | None = None
    track_depth: torch.Tensor | None = None
    views: int = 1

    @classmethod
    def collate(cls, items: list[SourceInputs], views: int = 1) -> "SourceBatch":
        """Stack clips; they must share T, H, W, latent size and track count N. ``views`` > 1: the
        items are ``views`` synchronized cameras per scene, scene-major."""
        if views < 1 or len(items) % views:
            raise ValueError(f"{len(items)} clips do not split into scenes of {views} views")
        import torch  # lazy: SourceInputs and stack_inputs serve the torch-free ONNX encoder too

        arrays = stack_inputs(items)
        return cls(**{name: torch.from_numpy(value) for name, value in arrays.items()}, views=views)

    def to(self, device: "torch.device | str") -> "SourceBatch":
        import torch

        def move(value: object) -> object:
            return value.to(device) if isinstance(value, torch.Tensor) else value

        return SourceBatch(**{f.name: move(getattr(self, f.name)) for f in fields(self)})

    @property
    def batch_size(self) -> int:
        """Clips in the batch (B); scenes = B / views."""
        return int(self.frames.shape[0])

    @property
    def num_scenes(self) -> int:
        return self.batch_size // self.views

    @property
    def source(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Each scene's encoded cameras, the trajectories a renderer with projected anchors places the
        scene's tokens with (``VideoTok4D.render(..., source=...)``): (K (S, T, 3, 3), w2c (S, T, 4, 4))
        for one view per scene, else (K (S, V, T, 3, 3), w2c (S, V, T, 4, 4)) in encoding order."""
        if self.views == 1:
            return self.K, self.w2c
        S, V = self.num_scenes, self.views
        return self.K.reshape(S, V, *self.K.shape[1:]), self.w2c.reshape(S, V, *self.w2c.shape[1:])


def stack_inputs(items: list[SourceInputs]) -> dict[str, np.ndarray]:
    """The encoder's input arrays of a batch of clips (the :class:`SourceBatch` fields, numpy): frames
    (B, T, 3, H, W) float32 in [0, 1] (uint8 / 255), K (B, T, 3, 3), w2c (B, T, 4, 4), motion_mask
    (B, T, h, w), track_xy (B, N, T, 2) float32, track_valid (B, N, T) bool. The clips must share T, H,
    W, the latent size and N; with every clip's ``track_depth`` also track_depth (B, N, T) float32."""
    def stack(name: str) -> np.ndarray:
        return np.stack([getattr(it, name) for it in items])

    extra = {}
    if items and all(it.track_depth is not None for it in items):
        extra["track_depth"] = stack("track_depth").astype(np.float32)
    return {
        "frames": stack("frames").transpose(0, 1, 4, 2, 3).astype(np.float32, order="C") / np.float32(255.0),
        "K": stack("K").astype(np.float32), "w2c": stack("w2c").astype(np.float32),
        "motion_mask": stack("motion_mask").astype(np.float32), "track_xy": stack("track_xy").astype(np.float32),
        "track_valid": stack("track_valid").astype(bool), **extra,
    }
