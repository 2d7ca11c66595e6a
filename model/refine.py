"""Encoder-side token refinement: one scene's tokens moved by gradient descent so that the views the decoder
renders from the stored values match the encoded frames, at a rate cost.

The encoder is one forward pass trained over many scenes (amortised inference); on any one scene it leaves
error that its own renderer could remove. Refinement, as in learned image compression (Campos et al. 2019,
"Content adaptive optimization for neural image compression"; Yang et al. 2020, "Improving inference for
neural image compression"), starts from the encoder's tokens and runs Adam on

    D + w_l x R

D: pixel MSE (plus ``ssim_weight`` x (1 - SSIM), the "ssim" tune) between the encoded cameras' frames
(V, T, H, W) and the renders of the tokens *as the file stores them* -- the writer's codes at the quality level
times the step (``vt4dcodec.format.learned.writer_codes``), with a straight-through gradient -- at the model's
decode steps and seed 0, the decoder's defaults.
R: the entropy model's bits of the token set (its additive-noise proxy, :meth:`TokenEntropyModel.noisy`) per
encoded pixel, weighted by the level's w_l (:func:`rate_weight_of`). Only the encoder's choice of tokens
changes: the file format, the decoder and every reader are untouched, and a refined scene decodes on any
runtime.

Cost: one render and its backward pass over the encoded cameras per iteration (vt4d-tiny on 2 CPU threads:
about 0.13 s per encoded camera). Measured effect: docs/benchmarks/codecs.md ("Encoder refinement").
"""

from __future__ import annotations

import kornia
import numpy as np
import torch

from vt4dcodec.errors import ModelError
from vt4dcodec.format.learned import EntropyTables, dequantize, writer_codes

from .videotok4d import VideoTok4D

__all__ = ["refine_tokens", "stored_values", "rate_weight_of", "REFINE_LR", "RATE_WEIGHT", "RATE_SLOPE", "MAX_REFINE",
           "TUNE_SSIM_WEIGHT"]

REFINE_LR = 0.01      # Adam step on the tokens (values in (-1, 1)); 0.02 lowers the bytes faster but gains less
# Weight of bits per encoded pixel beside pixel MSE at a level of mean static step s: min(RATE_WEIGHT,
# RATE_SLOPE x s^2). A quantiser's distortion, and so the slope dD/dR of its operating point, scales with its step
# squared; at the fine levels a fixed weight outweighs the pixel error (vt4d-tiny q9, one camera: at 0.05 the
# refined files are 23 % smaller and 0.45 dB worse on caliscope; at 0.005 7.6 % smaller and 0.92 dB better on
# synthetic captures). 0.05 was tuned at q1 and q7 (bench/probes/probe_token_refinement.py), where the rule gives 0.05.
RATE_WEIGHT = 0.05
RATE_SLOPE = 0.55
# Weight of 1 - SSIM (kornia's, 11x11 Gaussian window, as the evaluation) beside pixel MSE, per tune
# (codec.encode(tune=...)). 0.02 was chosen on synthetic tuning captures (seeds 2000-2011, probe_token_refinement.py
# --ssim): at q7 with five cameras stored, 10 iterations, +0.021 SSIM and +0.11 dB on the stored views for +5 % bytes
# against "psnr"; 0.1 gains little more SSIM for twice the bytes.
TUNE_SSIM_WEIGHT = {"psnr": 0.0, "ssim": 0.02}
MAX_REFINE = 1000     # iterations one call accepts
TOKEN_BOUND = 0.999   # tokens stay inside the bottleneck's open range (-1, 1)


def stored_values(z: torch.Tensor, tables: EntropyTables, level: int, which: str, views: int) -> torch.Tensor:
    """The values a file stores for z (N, d) -- the writer's codes x step -- with a straight-through gradient."""
    codes = writer_codes(z.detach().cpu().numpy(), tables, level, which, views)
    values = torch.from_numpy(dequantize(codes, tables, level, which)).to(z.device)
    return z + (values - z).detach()


def rate_weight_of(tables: EntropyTables, quality: int) -> float:
    """The rate weight of quality level ``quality`` (1-based): min(RATE_WEIGHT, RATE_SLOPE x s^2), s the level's
    mean static step."""
    step = float(np.mean(tables.steps[int(quality) - 1, 0].astype(np.float64)))
    return min(RATE_WEIGHT, RATE_SLOPE * step * step)


def refine_tokens(net: VideoTok4D, z_s: np.ndarray, z_d: np.ndarray, frames: np.ndarray, K: np.ndarray,
                  w2c: np.ndarray, *, tables: EntropyTables, quality: int, iterations: int,
                  lr: float = REFINE_LR, rate_weight: float | None = None,
                  ssim_weight: float = 0.0, seed: int = 0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Refined tokens of one scene for storage at quality level ``quality`` (1-based).

    z_s (N_s, d), z_d (N_d, d) float32: the encoder's tokens; frames (V, T, H, W, 3) uint8: the encoded cameras'
    clips fitted to the model's image (encoding order); K (V, T, 3, 3) px and w2c (V, T, 4, 4): their cameras;
    tables: the model's frozen entropy tables; ``rate_weight``: None for the level's (:func:`rate_weight_of`);
    ``ssim_weight``: weight of 1 - SSIM beside the pixel MSE (0: the "psnr" tune; see TUNE_SSIM_WEIGHT);
    ``seed`` seeds the rate proxy's noise (the same inputs and seed give the same tokens; the caller's random
    state is left as it was). Returns (z_s, z_d) float32 of the same
    shapes, in (-1, 1). ``iterations`` 0 returns the tokens unchanged.
    """
    if isinstance(iterations, bool) or not isinstance(iterations, int) or not 0 <= iterations <= MAX_REFINE:
        raise ModelError(f"refine must be an integer from 0 to {MAX_REFINE} (iterations), got {iterations!r}")
    if net.entropy is None:
        raise ModelError("refinement needs a model with quality levels (an entropy model)")
    level = int(quality) - 1
    if not 0 <= level < net.entropy.levels:
        raise ModelError(f"quality must be 1 .. {net.entropy.levels}, got {quality!r}")
    V, T = frames.shape[:2]
    if K.shape[:2] != (V, T) or w2c.shape[:2] != (V, T):
        raise ModelError(f"refinement: {V} clips of {T} frames but cameras {K.shape[:2]} / {w2c.shape[:2]}")
    if iterations == 0:
        return z_s.astype(np.float32), z_d.astype(np.float32)
    if rate_weight is None:
        rate_weight = rate_weight_of(tables, quality)
    device = next(net.parameters()).device
    was_training = net.training
    net.eval()
    flags = [p.requires_grad for p in net.parameters()]
    for p in net.parameters():
        p.requires_grad_(False)
    try:
        truth = torch.from_numpy(np.ascontiguousarray(frames)).to(device).float().div(255.0).permute(0, 1, 4, 2, 3)
        Kt = torch.from_numpy(np.ascontiguousarray(K, dtype=np.float32)).to(device)
        wt = torch.from_numpy(np.ascontiguousarray(w2c, dtype=np.float32)).to(device)
        source = (Kt[None].expand(V, -1, -1, -1, -1), wt[None].expand(V, -1, -1, -1, -1)) if net.needs_source else None
        zs = torch.tensor(z_s, dtype=torch.float32, device=device, requires_grad=True)
        zd = torch.tensor(z_d, dtype=torch.float32, device=device, requires_grad=True)
        origin = net.static_origins(V)
        opt = torch.optim.Adam([zs, zd], lr=lr)
        render_latents = type(net).render_latents.__wrapped__  # the decoder's integration, with gradients
        pixels = truth[:, :, 0].numel()
        with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []), torch.enable_grad():
            torch.manual_seed(int(seed))
            for _ in range(iterations):
                s = stored_values(zs, tables, level, "static", V)[None].expand(V, -1, -1)
                d = stored_values(zd, tables, level, "dynamic", V)[None].expand(V, -1, -1)
                latents = render_latents(net, s, d, Kt, wt, seed=0, source=source)
                out = torch.cat([net.autoencoder.decode(x) for x in latents.split(1)]).float().clamp(0.0, 1.0)
                loss = torch.nn.functional.mse_loss(out, truth)
                if ssim_weight:
                    ssim = kornia.metrics.ssim(out.flatten(0, 1), truth.flatten(0, 1), 11).mean()
                    loss = loss + ssim_weight * (1.0 - ssim)
                if rate_weight:
                    bits = net.entropy.noisy(zs[None], zd[None], level, origin)[2].sum()
                    loss = loss + rate_weight * bits / pixels
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                with torch.no_grad():
                    zs.clamp_(-TOKEN_BOUND, TOKEN_BOUND)
                    zd.clamp_(-TOKEN_BOUND, TOKEN_BOUND)
        return zs.detach().cpu().numpy().astype(np.float32), zd.detach().cpu().numpy().astype(np.float32)
    finally:
        for p, flag in zip(net.parameters(), flags):
            p.requires_grad_(flag)
        net.train(was_training)
