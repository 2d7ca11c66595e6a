#!/usr/bin/env python
"""How far could one static token per encoder cell take the source view? Oracles beside a checkpoint.

    python bench/probes/probe_static_oracle.py RUN_DIR [--scenes 16] [--cache runs/scene_cache] [--out FILE.json]

On held-out synthetic scenes (camera 0, its own trajectory), PSNR of the source clip against:

- ``autoencoder``: the frozen autoencoder's reconstruction (the ceiling of any latent renderer);
- ``time_mean``: every frame's latent replaced by the clip's time-averaged latent -- per encoder cell
  (p x p latent pixels x C channels; 2 x 2 x 8 = 32 values for vt4d-tiny) exactly what one token of
  width d = 32 could hold if it copied its cell: a static picture, no motion;
- ``time_mean_int4``: the same, rounded to 15 levels of its absolute maximum (int4 storage);
- ``frame_groups``: every frame's latent replaced by the mean over its group of frames (4 groups of 2
  frames for 8 frames): what a cell's time-mean token plus one copy per frame group could hold;
- ``pooled_2x``: the per-frame latent averaged over 2 x 2 latent pixels (one value per channel per cell:
  what a token would hold if it kept only its cell's mean);
- ``render``: the checkpoint's 1-step render of its own tokens (camera 0 encoded);
- ``flat``: the clip's mean colour (the reference every table prints).

SSIM (kornia's, 11x11 window, as the evaluation) of ``time_mean``, ``frame_groups`` and ``render`` too. Prints one JSON
line (means over scenes) and writes it to ``--out`` when given.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
import kornia
import torch.nn.functional as F

from vt4dcodec.model.inputs.source_inputs import SourceBatch
from vt4dcodec.model.train.common import model_from_run
from vt4dcodec.model.train.data import ScenePool


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    """PSNR in dB of two clips in [0, 1] over all their values."""
    return float(10.0 * torch.log10(1.0 / ((a.float() - b.float()) ** 2).mean().clamp_min(1e-12)))


def ssim(a: torch.Tensor, b: torch.Tensor) -> float:
    """Mean SSIM of two (1, T, 3, H, W) clips in [0, 1], frames as the batch."""
    return float(kornia.metrics.ssim(a[0].float(), b[0].float(), 11).mean())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a training run directory (RUN/checkpoint)")
    parser.add_argument("--scenes", type=int, default=16)
    parser.add_argument("--cache", type=Path, default=Path("runs/scene_cache"))
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    model, state = model_from_run(args.run)
    cfg = model.config
    pool = ScenePool(args.cache, 10, cfg.frames, cfg.image_size, cfg.latent_size, cfg.n_tracks, split="test")
    scores: dict[str, list[float]] = {k: [] for k in ("autoencoder", "time_mean", "time_mean_int4", "pooled_2x",
                                                      "frame_groups", "render", "flat", "ssim_time_mean",
                                                      "ssim_frame_groups", "ssim_render")}
    ae = model.autoencoder
    with torch.no_grad():
        for seed in range(args.scenes):
            sc = pool.scene(seed)
            truth = torch.from_numpy(sc["frames"][0]).permute(0, 3, 1, 2).float()[None] / 255.0  # (1, T, 3, H, W)
            lat = ae.encode(truth)  # (1, T, C, h, w)

            def decoded(latent: torch.Tensor) -> torch.Tensor:
                return ae.decode(latent).float().clamp(0.0, 1.0)

            mean = lat.mean(1, keepdim=True).expand_as(lat)
            scale = mean.abs().amax().clamp_min(1e-8)
            T = lat.shape[1]
            groups = torch.arange(T) * 4 // T  # frame t -> its group of T / 4 frames
            group_mean = torch.stack([lat[:, groups == g].mean(1) for g in range(4)], 1)[:, groups]
            pooled = F.interpolate(F.avg_pool2d(lat[0], 2), scale_factor=2, mode="nearest")[None]
            z_s, z_d = model.encode(SourceBatch.collate(pool.source_inputs(seed, [0])))
            K, w2c = torch.from_numpy(sc["K"][[0]]).float(), torch.from_numpy(sc["w2c"][[0]]).float()
            scores["autoencoder"].append(psnr(decoded(lat), truth))
            scores["time_mean"].append(psnr(decoded(mean), truth))
            scores["ssim_time_mean"].append(ssim(decoded(mean), truth))
            scores["time_mean_int4"].append(psnr(decoded(torch.round(mean / scale * 7.0) / 7.0 * scale), truth))
            scores["frame_groups"].append(psnr(decoded(group_mean), truth))
            scores["ssim_frame_groups"].append(ssim(decoded(group_mean), truth))
            scores["pooled_2x"].append(psnr(decoded(pooled), truth))
            render = model.render(z_s, z_d, K, w2c, steps=1, seed=0, source=(K, w2c))
            scores["render"].append(psnr(render, truth))
            scores["ssim_render"].append(ssim(render, truth))
            scores["flat"].append(psnr(truth.mean((1, 3, 4), keepdim=True).expand_as(truth), truth))
    result = {"run": str(args.run), "step": int(state["step"]), "scenes": args.scenes,
              **{k: round(float(np.mean(v)), 3 if k.startswith('ssim') else 2) for k, v in scores.items()}}
    print(json.dumps(result))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
