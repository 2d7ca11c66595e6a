#!/usr/bin/env python
"""Can the encoder spend its effort better than one forward pass? Encoder-side token refinement: after the
encoder, the stored cameras' frames are rendered from the tokens as the decoder will see them (the writer's
codes at the level, straight-through), and the float tokens are moved by Adam to lower the pixel error of
those renders. The file format and the decoder do not change; only the encoder's tokens do.

    python bench/probes/probe_token_refinement.py [--first-seed 2000] [--scenes 6] [--level 7]
        [--setting half|all|single] [--iters 0,10,30] [--lr 0.01] [--out FILE.json]

On held-out synthetic 10-camera captures (split test; tuning seeds, not the rate study's), prints per iteration
count the file bytes, the stored cameras' PSNR and (setting half) the five held-out cameras' PSNR.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_codecs import quality  # noqa: E402

from vt4dcodec import codec  # noqa: E402
from vt4dcodec.format import dumps  # noqa: E402
from vt4dcodec.model.refine import REFINE_LR, refine_tokens  # noqa: E402
from vt4dcodec.synth import SynthConfig, generate_scene  # noqa: E402


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default="vt4d-tiny")
    p.add_argument("--first-seed", type=int, default=2000)
    p.add_argument("--scenes", type=int, default=6)
    p.add_argument("--level", type=int, default=7)
    p.add_argument("--setting", default="half", choices=["half", "all", "single"])
    p.add_argument("--iters", default="0,10,30")
    p.add_argument("--lr", type=float, default=REFINE_LR)
    p.add_argument("--lam", type=float, default=None, help="weight of the rate (bits per stored pixel; default: the "
                   "level's, vt4dcodec.model.refine.rate_weight_of)")
    p.add_argument("--ssim", type=float, default=0.0, help="weight of 1 - SSIM beside pixel MSE (default 0, the "
                   "'psnr' tune; vt4dcodec.model.refine.TUNE_SSIM_WEIGHT)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("--figure", type=Path, default=None, help="PNG of the first capture's middle frame: truth, then "
                   "each iteration count, for its first stored camera (and first held-out camera)")
    args = p.parse_args()
    checkpoints = sorted({int(v) for v in args.iters.split(",")})
    torch.set_num_threads(args.threads)
    net = codec.load_model(args.model).eval()
    tables, frames = codec.model_tables(net), net.config.frames
    rows: dict[int, list[dict]] = {n: [] for n in checkpoints}
    tiles: list[np.ndarray] = []
    for seed in range(args.first_seed, args.first_seed + args.scenes):
        cap = generate_scene(seed, split="test", config=SynthConfig(num_cameras=10, num_frames=frames,
                                                                      height=net.config.image_size,
                                                                      width=net.config.image_size)).capture
        names = list(cap.camera_names)
        stored = {"half": names[::2], "all": names, "single": names[:1]}[args.setting]
        held = names[1::2] if args.setting == "half" else []
        scene = codec.encode(cap, net, cameras=stored, seed=0, quality=args.level)
        z_s, z_d = scene.static_tokens, scene.dynamic_tokens
        clips = np.stack([cap.frames[n][:frames] for n in stored])
        K = np.stack([cap.cameras[n].K[:frames] for n in stored])
        w2c = np.stack([cap.cameras[n].w2c[:frames] for n in stored])
        for it in checkpoints:  # each count from the encoder's tokens, as `encode(refine=it)` runs it
            t0 = time.perf_counter()
            scene.static_tokens, scene.dynamic_tokens = refine_tokens(
                net, z_s, z_d, clips, K, w2c, tables=tables, quality=args.level, iterations=it, lr=args.lr,
                rate_weight=args.lam, ssim_weight=args.ssim)
            seconds = time.perf_counter() - t0
            blob = dumps(scene, encoding="learned-rans", quality=args.level, tables=tables)
            d = codec.SceneDecoder.open(blob, model=net)
            own = d.render_many([cap.cameras[n][:frames] for n in stored], seed=0)
            sq = [quality(v, cap.frames[n][:frames]) for n, v in zip(stored, own)]
            row = {"seed": seed, "bytes": len(blob), "seconds": seconds,
                   "stored_psnr": float(np.mean([a for a, _ in sq])), "stored_ssim": float(np.mean([b for _, b in sq]))}
            if held:
                nov = d.render_many([cap.cameras[n][:frames] for n in held], seed=0)
                q = [quality(v, cap.frames[n][:frames]) for n, v in zip(held, nov)]
                row["held_psnr"] = float(np.mean([a for a, _ in q]))
                row["held_ssim"] = float(np.mean([b for _, b in q]))
            rows[it].append(row)
            if seed == args.first_seed:
                mid = frames // 2
                if not tiles:
                    tiles.append(np.concatenate([cap.frames[stored[0]][mid]] + ([cap.frames[held[0]][mid]] if held
                                                                                  else []), axis=0))
                tiles.append(np.concatenate([own[0][mid]] + ([nov[0][mid]] if held else []), axis=0))
            print(f"seed {seed} iter {it}: {row}", flush=True)
    if args.figure and tiles:
        import cv2

        sheet = np.concatenate(tiles, axis=1)  # columns: truth, then each iteration count
        cv2.imwrite(str(args.figure), cv2.resize(sheet, None, fx=4, fy=4, interpolation=cv2.INTER_NEAREST)[..., ::-1])
    summary = {}
    base = rows[checkpoints[0]]
    for n, rs in rows.items():
        s = {"bytes": float(np.mean([r["bytes"] for r in rs])),
             "stored_psnr": float(np.mean([r["stored_psnr"] for r in rs])),
             "stored_ssim": float(np.mean([r["stored_ssim"] for r in rs])),
             "seconds": float(np.mean([r["seconds"] for r in rs]))}
        if held:
            diff = [r["held_psnr"] - b["held_psnr"] for r, b in zip(rs, base)]
            s.update(held_psnr=float(np.mean([r["held_psnr"] for r in rs])),
                     held_ssim=float(np.mean([r["held_ssim"] for r in rs])),
                     held_gain=float(np.mean(diff)),
                     held_gain_se=float(np.std(diff, ddof=1) / np.sqrt(len(diff))) if len(diff) > 1 else None)
        summary[n] = s
        print(f"{n} iterations: {s}")
    if args.out:
        args.out.write_text(json.dumps({"command": " ".join(sys.argv), "summary": summary, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
