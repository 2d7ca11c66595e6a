"""Token health: numbers that tell a tokenizer whose tokens carry a scene from a collapsed one.

All take token tensors (B, N, d) (one row per scene) and return python floats:

* :func:`slot_spread`: how different the N token slots of one scene are -- the standard deviation
  across slots (per channel, averaged), over the overall standard deviation of the tokens. 0 means
  every slot holds the same vector (vt4d-tiny 0.2.0: 0.0017 / 0.77 = 0.002).
* :func:`effective_rank`: across scenes, exp(entropy) of the normalised singular values of the
  centred (B, N*d) token matrix (Roy & Vetterli 2007): how many directions the tokens vary in from
  scene to scene (0.2.0: about 3.5).
* :func:`saturation`: the fraction of token values with |z| > 0.95 (tanh saturation; 0.2.0's Z_d: 0.96).
* :func:`swap_drop_db`: the PSNR of renders with a scene's own tokens minus the PSNR with another
  scene's tokens for the same targets; near 0 dB means the renderer ignores the tokens.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

__all__ = ["slot_spread", "effective_rank", "saturation", "token_health", "psnr_db", "swap_drop_db", "video_quality"]


def slot_spread(z: torch.Tensor) -> float:
    """z: (B, N, d). Mean over scenes and channels of the std across slots, over the overall std."""
    z = z.detach().float()
    overall = float(z.std())
    if overall == 0.0 or z.shape[1] < 2:
        return 0.0
    return float(z.std(dim=1).mean()) / overall


def effective_rank(z: torch.Tensor) -> float:
    """z: (B, N, d), B >= 2 scenes. exp(entropy) of the normalised singular values across scenes."""
    x = z.detach().double().flatten(1)
    if x.shape[0] < 2:
        return 0.0
    s = torch.linalg.svdvals(x - x.mean(dim=0, keepdim=True))
    total = float(s.sum())
    if total <= 0.0:
        return 0.0
    p = s / total
    p = p[p > 0]
    return float(torch.exp(-(p * p.log()).sum()))


def saturation(z: torch.Tensor, threshold: float = 0.95) -> float:
    return float((z.detach().abs() > threshold).float().mean())


def token_health(z_s: torch.Tensor, z_d: torch.Tensor) -> dict[str, float]:
    """The three token statistics for both groups: keys ``{static,dynamic}_{spread,rank,saturation}``."""
    out: dict[str, float] = {}
    for name, z in (("static", z_s), ("dynamic", z_d)):
        out[f"{name}_spread"] = slot_spread(z)
        out[f"{name}_rank"] = effective_rank(z)
        out[f"{name}_saturation"] = saturation(z)
    return out


def psnr_db(video: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """Per-item PSNR (dB) of videos (B, ...) in [0, 1]."""
    mse = ((video.float() - truth.float()) ** 2).flatten(1).mean(dim=1).clamp_min(1e-10)
    return 10.0 * torch.log10(1.0 / mse)


def video_quality(pred: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """PSNR (dB; the mean squared error over every value, floored at 1e-10) and SSIM (kornia, 11x11 Gaussian
    window, mean over frames) of (T, H, W, 3) uint8 videos (read-only or broadcast arrays too)."""
    import kornia

    a = torch.from_numpy(np.array(pred)).permute(0, 3, 1, 2).float() / 255.0
    b = torch.from_numpy(np.array(truth)).permute(0, 3, 1, 2).float() / 255.0
    mse = float(((a - b) ** 2).mean().clamp_min(1e-10))
    return 10.0 * float(np.log10(1.0 / mse)), float(kornia.metrics.ssim(a, b, 11).mean())


@torch.no_grad()
def swap_drop_db(model: Any, z_s: torch.Tensor, z_d: torch.Tensor, K_tgt: torch.Tensor, w2c_tgt: torch.Tensor,
                 truth: torch.Tensor, *, steps: int = 1, seed: int = 0,
                 source: tuple[torch.Tensor, torch.Tensor] | None = None) -> dict[str, float]:
    """Render targets with each scene's own tokens and with the next scene's (rolled by one), same
    cameras and noise; returns mean PSNRs and their difference (``swap_drop_db``). B >= 2.
    ``source``: each scene's source trajectory (``SourceBatch.source``), for models that need it; the
    swapped tokens are placed with the other scene's source camera, the one they were encoded from."""
    swapped_source = None if source is None else (source[0].roll(1, 0), source[1].roll(1, 0))
    own = model.render(z_s, z_d, K_tgt, w2c_tgt, steps=steps, seed=seed, source=source)
    swapped = model.render(z_s.roll(1, 0), z_d.roll(1, 0), K_tgt, w2c_tgt, steps=steps, seed=seed,
                           source=swapped_source)
    p_own, p_swap = psnr_db(own, truth).mean(), psnr_db(swapped, truth).mean()
    return {"psnr_own_db": float(p_own), "psnr_swapped_db": float(p_swap), "swap_drop_db": float(p_own - p_swap)}
