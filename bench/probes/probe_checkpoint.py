"""Held-out probe of a stage-2 training checkpoint, cheap enough to run while training goes on.

    python bench/probes/probe_checkpoint.py RUN_DIR [--scenes 16] [--figure PNG] [--cache runs/scene_cache] [--split train]

Loads ``RUN_DIR/checkpoint`` (float32 weights, no codec, no quantization), encodes camera 0 of the
first ``--scenes`` held-out 10-camera scenes (split "test", cached with the training pool's settings)
and renders with one step: the source view itself, the two cameras whose optical axes are nearest to
camera 0's ("near") and the three farthest ("far"), each next to a flat image of the source clip's
mean colour; token health (``model.diagnostics``) and the token-swap drop on the source view. Prints
one JSON line. The evaluation of record is ``python -m vt4dcodec.eval`` on a shipped model; this is
for watching a run (docs/training.md quotes it at several steps).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from vt4dcodec.model.diagnostics import psnr_db, token_health
from vt4dcodec.model.inputs.source_inputs import SourceBatch
from vt4dcodec.model.train.common import model_from_run
from vt4dcodec.model.train.data import ScenePool, axis_angles_deg


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path)
    parser.add_argument("--scenes", type=int, default=16)
    parser.add_argument("--cache", type=Path, default=Path("runs/scene_cache"))
    parser.add_argument("--figure", type=Path, default=None, help="PNG: truth | render at frames 0 and 7")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--split", choices=("test", "train"), default="test",
                        help="held-out scenes (default) or the first training scenes: the gap between the two "
                             "says whether a run under- or overfits")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    model, state = model_from_run(args.run)
    cfg = model.config
    pool = ScenePool(args.cache, 10, cfg.frames, cfg.image_size, cfg.latent_size, cfg.n_tracks, split=args.split)
    res: dict[str, list[float]] = {k: [] for k in ("source", "near", "far", "flat_source", "flat_near", "flat_far")}
    zs, zd, truths, Ks, w2cs = [], [], [], [], []
    with torch.no_grad():
        for seed in range(args.scenes):
            sc = pool.scene(seed)
            z_s, z_d = model.encode(SourceBatch.collate(pool.source_inputs(seed, [0])))
            src = (torch.from_numpy(sc["K"][[0]]).float(), torch.from_numpy(sc["w2c"][[0]]).float())
            zs.append(z_s)
            zd.append(z_d)
            order = np.argsort(axis_angles_deg(sc["w2c"])[0])
            flat = torch.from_numpy(sc["frames"][0].reshape(-1, 3).mean(0) / 255.0).float()
            for group, cams in (("source", [0]), ("near", list(order[1:3])), ("far", list(order[-3:]))):
                K = torch.from_numpy(sc["K"][cams]).float()
                w2c = torch.from_numpy(sc["w2c"][cams]).float()
                n = len(cams)
                out = model.render(z_s.expand(n, -1, -1), z_d.expand(n, -1, -1), K, w2c, steps=1, seed=0,
                                   source=(src[0].expand(n, -1, -1, -1), src[1].expand(n, -1, -1, -1)))
                truth = torch.from_numpy(sc["frames"][cams]).permute(0, 1, 4, 2, 3).float() / 255.0
                res[group] += psnr_db(out, truth).tolist()
                res["flat_" + group] += psnr_db(flat[None, None, :, None, None].expand_as(truth), truth).tolist()
                if group == "source":
                    truths.append(truth)
                    Ks.append(K)
                    w2cs.append(w2c)
        z_s, z_d = torch.cat(zs), torch.cat(zd)
        K, w2c, truth = torch.cat(Ks), torch.cat(w2cs), torch.cat(truths)
        own = model.render(z_s, z_d, K, w2c, steps=1, source=(K, w2c))  # K, w2c: the source cameras
        swapped = model.render(z_s.roll(1, 0), z_d.roll(1, 0), K, w2c, steps=1, source=(K.roll(1, 0), w2c.roll(1, 0)))
    result: dict[str, float | int] = {k: round(float(np.mean(v)), 2) for k, v in res.items()}
    result.update({k: round(v, 3) for k, v in token_health(z_s, z_d).items()})
    result["swap_drop_db"] = round(float(psnr_db(own, truth).mean() - psnr_db(swapped, truth).mean()), 2)
    result["step"] = int(state["step"])
    result["split"] = args.split
    print(json.dumps(result))
    if args.figure is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        k = min(6, args.scenes)
        fig, axes = plt.subplots(k, 4, figsize=(6, 1.5 * k), squeeze=False)
        for i in range(k):
            for j, (video, t) in enumerate(((truth, 0), (own, 0), (truth, cfg.frames - 1), (own, cfg.frames - 1))):
                axes[i, j].imshow(video[i, t].permute(1, 2, 0).clamp(0, 1).numpy())
                axes[i, j].axis("off")
        fig.tight_layout()
        fig.savefig(args.figure, dpi=80)
    return 0


if __name__ == "__main__":
    sys.exit(main())
