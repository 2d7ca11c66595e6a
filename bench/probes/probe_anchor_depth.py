#!/usr/bin/env python
"""How well does the renderer place the anchored static tokens in depth? Token depth vs true cell depth.

    python bench/probes/probe_anchor_depth.py [MODEL] [--scenes 8] [--near] [--out FILE.json]

MODEL: a shipped id or model directory (default ``vt4d-tiny``), or a training run directory (its latest
checkpoint). With ``project_anchors`` each anchored static token sits on its cell's ray of the encoded
camera at the depth the renderer reads from the token (``Renderer.anchor_depths``: the depth of the world
origin in that camera times a learned factor). On held-out synthetic scenes (camera 0 encoded, float32
tokens) this compares that depth with the median true z-depth of the token's cell in the middle frame (the
frame the renderer anchors on), and with the reference depth alone (the factor at 1): median |log error|
per scene and the correlation of log depths. With ``--near`` it also renders the two cameras nearest to
the encoded one (the evaluation's near set, one step) twice: with the renderer's depths and with every
anchored token at its cell's true depth (oracle placement), PSNR in dB: what a better depth could buy the
novel views. Prints one JSON line of means and writes it to ``--out``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from vt4dcodec import codec
from vt4dcodec.eval.command import resolve_model
from vt4dcodec.eval.protocol import nearest_cameras
from vt4dcodec.synth import SynthConfig, generate_scene


def _near_views(model, sc, cam: str, z_s: torch.Tensor, z_d: torch.Tensor, oracle: torch.Tensor) -> dict[str, float]:
    """Mean PSNR (dB) of the two nearest cameras rendered with the model's token depths and with ``oracle``
    (1, N_anchored) metres in their place."""
    src = sc.capture.cameras[cam]
    source = tuple(torch.from_numpy(np.asarray(a, np.float32))[None] for a in (src.K, src.w2c))
    renderer, scores = model.renderer, {"near_psnr_db": [], "near_psnr_oracle_depth_db": []}
    for name, _ in nearest_cameras(sc.capture, cam, 2):
        tgt = sc.capture.cameras[name]
        K, w2c = (torch.from_numpy(np.asarray(a, np.float32))[None] for a in (tgt.K, tgt.w2c))
        truth = sc.capture.frames[name].astype(np.float64) / 255.0
        for key, depths in (("near_psnr_db", None), ("near_psnr_oracle_depth_db", oracle)):
            if depths is not None:  # every anchored token at its cell's true depth
                renderer.anchor_depths = lambda zs, zd, w, d=depths: d.expand(zs.shape[0], -1)
            try:
                with torch.no_grad():
                    out = model.render(z_s, z_d, K, w2c, steps=1, seed=0, source=source)[0]
            finally:
                renderer.__dict__.pop("anchor_depths", None)
            err = np.mean((out.permute(0, 2, 3, 1).double().numpy() - truth) ** 2)
            scores[key].append(float(10.0 * np.log10(1.0 / err)))
    return {k: float(np.mean(v)) for k, v in scores.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", nargs="?", default="vt4d-tiny")
    parser.add_argument("--scenes", type=int, default=8)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--near", action="store_true", help="also render the near views with oracle depths")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    model = resolve_model(args.model)
    cfg, renderer = model.config, model.renderer
    if renderer.depth_head is None:
        raise SystemExit(f"{args.model}: this model does not place its tokens in depth (config project_anchors)")
    cells = renderer.anchor_cells.cpu().numpy()  # (Na, 2) row, col in encoder patches
    px = cfg.image_size / cfg.patches_per_side
    rows = []
    for seed in range(args.scenes):
        sc = generate_scene(seed, split="test", config=SynthConfig(num_cameras=10))
        cam = sc.capture.camera_names[0]
        scene = codec.encode(sc.capture, model, "float32", camera=cam)
        z_s = torch.from_numpy(np.asarray(scene.static_tokens, np.float32))[None]
        z_d = torch.from_numpy(np.asarray(scene.dynamic_tokens, np.float32))[None]
        mid = cfg.frames // 2
        w2c = torch.from_numpy(np.asarray(sc.capture.cameras[cam].w2c, np.float32))[mid][None]
        with torch.no_grad():
            depth = renderer.anchor_depths(z_s, z_d, w2c)[0].numpy()
        truth_map = np.asarray(sc.capture.depth[cam], np.float32)[mid]
        truth = np.array([np.median(truth_map[int(r * px):int((r + 1) * px), int(c * px):int((c + 1) * px)])
                          for r, c in cells])
        ok = truth > 0
        reference = float(w2c[0, 2, 3])
        near = {}
        if args.near:
            oracle = torch.from_numpy(np.where(ok, truth, np.median(truth[ok])).astype(np.float32))[None]
            near = _near_views(model, sc, cam, z_s, z_d, oracle)
        rows.append({"seed": seed, **near,
                     "median_abs_log_error": float(np.median(np.abs(np.log(depth[ok] / truth[ok])))),
                     "reference_median_abs_log_error": float(np.median(np.abs(np.log(reference / truth[ok])))),
                     "log_depth_correlation": float(np.corrcoef(np.log(depth[ok]), np.log(truth[ok]))[0, 1])})
    keys = ("median_abs_log_error", "reference_median_abs_log_error", "log_depth_correlation") \
        + (("near_psnr_db", "near_psnr_oracle_depth_db") if args.near else ())
    result = {"model": args.model, "scenes": args.scenes, **{k: float(np.mean([r[k] for r in rows])) for k in keys},
              "per_scene": rows}
    print(json.dumps({k: v for k, v in result.items() if k != "per_scene"}))
    if args.out:
        args.out.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
