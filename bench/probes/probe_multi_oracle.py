#!/usr/bin/env python
"""What could the five-camera encode give the five held-out cameras? RGB-D oracles beside the model.

    python bench/probes/probe_multi_oracle.py [--scenes 50] [--out FILE.json]

On the evaluation's multi-camera held-out set (held-out 10-camera test scenes, cameras 0, 2, 4, 6, 8
encoded, 1, 3, 5, 7, 9 rendered), PSNR over all pixels and over the moving objects' pixels of:

- ``warp_frames``: the true RGB-D frames of the five encoded cameras forward-warped into each held-out
  camera, frame by frame (nearest encoded camera by viewing direction first, holes filled from the next
  ones, then inpainted): an oracle with the true geometry and every frame's colours -- motion included;
- ``warp_time_mean``: the same with each encoded camera's colours and depths replaced by their per-pixel
  time mean and median: a picture that does not move, what one time-averaged token per cell per encoded
  camera can carry at best (the five-camera layout of vt4d-tiny: no frame copies);
- ``flat``: the encoded cameras' mean colour.

Ours (the shipped model) on the same set is in docs/results/eval.json. If ``warp_frames`` beats
``warp_time_mean`` on the moving objects by much more than ours trails the static regions, the held-out
views need motion from the tokens (frame copies under several cameras), not better static geometry.
Prints one JSON line (means over scenes) and writes it to ``--out`` when given.
"""

from __future__ import annotations

import argparse
import json

import cv2
import numpy as np

from vt4dcodec.eval.baselines import INPAINT_RADIUS_PX, forward_warp
from vt4dcodec.eval.metrics import video_metrics
from vt4dcodec.eval.protocol import EvalSettings, axis_angles_deg, make_scene, set_sources, set_targets


def composite_warp(sources: list[tuple[np.ndarray, np.ndarray, object]], target: object) -> np.ndarray:
    """(T, H, W, 3) uint8: each source's z-buffered warp (:func:`forward_warp`, no inpainting) fills the
    pixels the earlier ones left empty; what no source reaches is inpainted as the single-source baseline does."""
    out, hole = None, None
    for frames, depth, traj in sources:
        warp = forward_warp(frames, depth, traj, target, inpaint=False)
        if out is None:
            out, hole = warp.frames.copy(), warp.holes.copy()
            continue
        fill = hole & ~warp.holes
        out[fill] = warp.frames[fill]
        hole &= warp.holes
    for t in range(len(out)):
        if hole[t].any() and not hole[t].all():
            out[t] = cv2.inpaint(out[t], hole[t].astype(np.uint8), INPAINT_RADIUS_PX, cv2.INPAINT_TELEA)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=50)
    parser.add_argument("--out")
    args = parser.parse_args()
    settings = EvalSettings(scenes=args.scenes)
    rows: dict[str, list[dict[str, float]]] = {"warp_frames": [], "warp_time_mean": [], "flat": []}
    for seed in settings.seeds:
        sc = make_scene(seed, settings, "multi-held")
        cap = sc.capture
        encoded = set_sources(sc, "multi-held")
        _, targets = set_targets(sc, settings, "multi-held")
        names = list(cap.camera_names)
        angles = axis_angles_deg(np.stack([cap.cameras[n].w2c[0] for n in names]))
        mean = np.mean([cap.frames[n].reshape(-1, 3).mean(0) for n in encoded], axis=0).round().astype(np.uint8)
        still = {}  # each encoded camera as a picture that does not move: per-pixel time mean and median depth
        for e in encoded:
            T = cap.frames[e].shape[0]
            colour = cap.frames[e].astype(np.float32).mean(0, keepdims=True).round().astype(np.uint8)
            still[e] = (np.repeat(colour, T, 0), np.repeat(np.median(cap.depth[e], axis=0, keepdims=True), T, 0))
        for name in targets:
            order = sorted(encoded, key=lambda e: angles[names.index(name), names.index(e)])
            per_frame = [(cap.frames[e], cap.depth[e], cap.cameras[e]) for e in order]
            static = [(*still[e], cap.cameras[e]) for e in order]
            truth, mask = cap.frames[name], sc.dynamic_mask[name]
            preds = {"warp_frames": composite_warp(per_frame, cap.cameras[name]),
                     "warp_time_mean": composite_warp(static, cap.cameras[name]),
                     "flat": np.broadcast_to(mean, truth.shape)}
            for key, video in preds.items():
                rows[key].append(video_metrics(video, truth, mask))
    summary = {"scenes": args.scenes, "targets": len(rows["flat"]), "set": "multi-held"}
    for key, items in rows.items():
        for metric in ("psnr", "ssim", "psnr_dynamic", "psnr_static"):
            values = np.array([r[metric] for r in items], np.float64)
            summary[f"{key}_{metric}"] = round(float(np.nanmean(values)), 3)
    print(json.dumps(summary))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(summary, f, indent=1)


if __name__ == "__main__":
    main()
