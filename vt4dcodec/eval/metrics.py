"""Metrics of the evaluation: PSNR, SSIM and region PSNR of one predicted video, and their means.

PSNR is in dB over all pixels; SSIM is kornia's (11x11 Gaussian window, mean over frames); the
dynamic / static PSNR is taken over the ground truth's moving-object pixels and over the others.
"""

from __future__ import annotations

import math

import kornia
import numpy as np
import torch

from vt4dcodec.media import psnr

__all__ = ["video_metrics", "round_metric", "mean_se"]


def video_metrics(pred: np.ndarray, truth: np.ndarray, dynamic_mask: np.ndarray) -> dict[str, float]:
    """PSNR (dB), SSIM and PSNR over dynamic / static pixels of (T, H, W, 3) uint8 videos.

    ``dynamic_mask`` (T, H, W) bool marks the ground truth's moving-object pixels; a region with no
    pixel gives NaN for its PSNR.
    """
    a = torch.from_numpy(np.ascontiguousarray(pred)).permute(0, 3, 1, 2).float() / 255.0
    b = torch.from_numpy(np.ascontiguousarray(truth)).permute(0, 3, 1, 2).float() / 255.0
    mask = np.asarray(dynamic_mask, bool)
    return {
        "psnr": psnr(pred, truth),
        "ssim": float(kornia.metrics.ssim(a, b, 11).mean()),
        "psnr_dynamic": psnr(pred, truth, mask),
        "psnr_static": psnr(pred, truth, ~mask),
    }


def round_metric(x: float, nd: int = 4) -> float | None:
    """``x`` rounded to ``nd`` decimals for the results file; None (JSON null) where it is not finite."""
    return None if not math.isfinite(x) else round(float(x), nd)


def mean_se(values: list[float | None]) -> tuple[float | None, float | None, int]:
    """(mean, standard error, count) of the finite values; None for what cannot be computed."""
    v = np.array([x for x in values if x is not None and math.isfinite(x)], np.float64)
    if v.size == 0:
        return None, None, 0
    se = float(v.std(ddof=1) / math.sqrt(v.size)) if v.size > 1 else None
    return float(v.mean()), se, int(v.size)
