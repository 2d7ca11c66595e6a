"""Shared small configurations and a numpy backward warp for the synth tests."""

from __future__ import annotations

import functools

import numpy as np

from vt4dcodec.synth import SynthConfig, generate_scene

SMALL = SynthConfig(num_cameras=3, num_frames=4, height=32, width=32)
SMALL_STATIC = SynthConfig(num_cameras=3, num_frames=4, height=32, width=32, static=True)


@functools.lru_cache(maxsize=32)
def scene(seed: int, split: str = "train", config: SynthConfig = SMALL):
    """Cached generated scene (tests must not modify it)."""
    return generate_scene(seed, split=split, config=config)


def backward_warp(image: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Sample ``image`` (H, W, C) at p + flow(p) with bilinear interpolation (clamped at borders)."""
    H, W = image.shape[:2]
    v, u = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    x = np.clip(u + flow[..., 0], 0, W - 1)
    y = np.clip(v + flow[..., 1], 0, H - 1)
    x0 = np.minimum(np.floor(x).astype(int), W - 2)
    y0 = np.minimum(np.floor(y).astype(int), H - 2)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    top = image[y0, x0] * (1 - fx) + image[y0, x0 + 1] * fx
    bot = image[y0 + 1, x0] * (1 - fx) + image[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bot * fy
