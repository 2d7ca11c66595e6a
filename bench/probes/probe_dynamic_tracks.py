#!/usr/bin/env python
"""How well a ``dynamic_splat`` model's dynamic tokens say where their track goes.

    python bench/probes/probe_dynamic_tracks.py RUN [RUN ...] [--scenes 8] [--first-seed 400] [--items 4]
        [--threads 1] [--out FILE.json]

For each training run (its latest ``checkpoint/``) and for one- and five-camera batches of ``--items``
items from the scene cache (``runs/scene_cache``, the training pool's seeds from ``--first-seed``): the
mean latent-pixel error of the track positions the renderer decodes from the tokens (eval mode, no
token noise) (``Renderer.dynamic_track``) against the targets of the track loss
(``VideoTok4D.track_targets``), next to the error of each slot's mean target over the batch (a token that
says nothing about its own track), how far the tracks move from their middle-frame position, the mean
|ln depth ratio|, the opacity gate (DYNAMIC_GATE_SCALE x its parameter), the patches' opacity (mean, and
the share of patch pixels at least half opaque), and the patch content's mean squared error against the
patch loss's targets (``VideoTok4D.patch_targets``: the source latent around the track) next to that of
each slot's mean target and of the mean target of all (what the content map's bias alone can give). Prints one JSON line per run and writes the list to ``--out``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from vt4dcodec.model.renderer import DYNAMIC_GATE_SCALE
from vt4dcodec.model.train.common import model_from_run
from vt4dcodec.model.train.data import PairDataset, ScenePool, collate_pairs


def probe(run: Path, cache: Path, seeds: list[int], items: int) -> dict:
    model, state = model_from_run(run)
    if not model.config.dynamic_splat:
        raise SystemExit(f"{run}: not a dynamic_splat model")
    torch.manual_seed(0)
    pool = ScenePool.for_config(model.config, cache, 10)
    data = PairDataset(pool, seeds, recon_share=0.3, neighbour_sigma_deg=45)
    out: dict = {"run": str(run), "step": state.get("step"),
                 "gate": float(model.renderer.dynamic_gate.detach()) * DYNAMIC_GATE_SCALE,
                 "gate_used": float(model.renderer.dynamic_opacity_scale().detach())}
    for views in (1, 5):
        stride = max(1, len(data) // items)
        batch = collate_pairs([data[(i * stride, views)] if views > 1 else data[i * stride] for i in range(items)])
        with torch.no_grad():
            _, z_d = model.encode(batch.source)
            uv_t, depth_t, valid = model.track_targets(batch.source)
            T = uv_t.shape[2]
            w2c = batch.source.source[1]
            w2c_mid = (w2c[:, None] if w2c.ndim == 4 else w2c)[:, :, T // 2]
            uv, depth = model.renderer.dynamic_track(z_d, w2c_mid)
            uv, depth = uv[:, :, :T], depth[:, :, :T]
            w = valid.float()

            def mean(x: torch.Tensor) -> float:
                return float((x * w).sum() / w.sum().clamp_min(1.0))

            r = model.renderer
            target, has = model.patch_targets(batch.source)  # (S, N_d, q, C), (S, N_d)
            S, n_d, q, C = target.shape
            content = r.dynamic_content(z_d).view(S, n_d, C + 1, q)
            alpha = r.dynamic_opacity_scale() * torch.sigmoid(content[:, :, C])
            colour = content[:, :, :C].transpose(2, 3)
            hw = has.float()[..., None, None]
            slot_target = (target * hw).sum(0, keepdim=True) / hw.sum(0, keepdim=True).clamp_min(1.0)

            def patch_mse(pred: torch.Tensor) -> float:
                return float((((pred - target) ** 2) * hw).sum() / (hw.sum() * q * C).clamp_min(1.0))

            slot_mean = (uv_t * w[..., None]).sum((0, 2), keepdim=True) / w.sum((0, 2), keepdim=True).clamp_min(1)[..., None]
            out[f"views{views}"] = {
                "head_px": mean((uv - uv_t).norm(dim=-1)),
                "slot_mean_px": mean((slot_mean - uv_t).norm(dim=-1)),
                "track_motion_px": mean((uv_t - uv_t[:, :, T // 2:T // 2 + 1]).norm(dim=-1)),
                "depth_abs_log_ratio": mean(torch.log(depth / depth_t.clamp_min(1e-3)).abs()),
                "opacity_mean": float(alpha.mean()),
                "opaque_share": float((alpha >= 0.5).float().mean()),
                "patch_mse": patch_mse(colour),
                "patch_slot_mean_mse": patch_mse(slot_target.expand_as(target)),
                "patch_mean_mse": patch_mse((target * hw).sum((0, 1), keepdim=True).div(hw.sum().clamp_min(1.0))
                                            .expand_as(target)),
            }
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--cache", type=Path, default=Path("runs/scene_cache"))
    parser.add_argument("--scenes", type=int, default=8)
    parser.add_argument("--first-seed", type=int, default=400)
    parser.add_argument("--items", type=int, default=4)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    seeds = list(range(args.first_seed, args.first_seed + args.scenes))
    results = []
    for run in args.runs:
        results.append(probe(run, args.cache, seeds, args.items))
        print(json.dumps(results[-1]))
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
