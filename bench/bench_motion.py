"""Benchmark of the non-learned Track-Aware Dynamic Attention inputs (model.inputs.motion/tracks/depth/preprocess).

Measures on synthetic test-split scenes (vt4dcodec.synth, 64x64, 8 frames, 3 cameras per scene):
  * motion-mask IoU against the ground-truth dynamic masks, with capture depth and with plane-sweep depth,
    on the seeds the constants were tuned on (0-5), on seeds 6-11 (held out for the first version; the
    pose-consistency step was designed after seeing its static seed-6 failure) and on fresh seeds 12-17
    (looked at once, after the constants were fixed);
  * the masked share of static scenes (moving cameras, nothing else moves);
  * plane-sweep depth error (AbsRel, delta < 1.25) against the capture depth;
  * track drift: tracks seeded on moving objects at frame 0 and carried forward by DIS flow, against the
    same seeds carried by the exact ground-truth flow;
  * timings per 8-frame 64x64 clip (single-threaded torch and OpenCV, as in a DataLoader worker).

Run:  python bench/bench_motion.py            (about 3-6 minutes on 2 shared cores)
Writes bench/results/motion.json.  ``--timing-only`` skips the accuracy part and writes the timings alone to
``--out`` (default bench/results/motion_timing.json; under 1 minute).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from vt4dcodec.model.inputs.depth import estimate_depth
from vt4dcodec.model.inputs.motion import estimate_flows, isolate_motion
from vt4dcodec.model.inputs.preprocess import prepare_source
from vt4dcodec.model.inputs.tracks import bilinear_sample, propagate_tracks, sample_seeds
from vt4dcodec.synth import SynthConfig, generate_scene

TUNING_SEEDS = range(0, 6)
HELD_OUT_SEEDS = range(6, 12)
FRESH_SEEDS = range(12, 18)
DEPTH_RANGE = (1.0, 25.0)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def depth_errors(est: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    ok = gt > 0
    e, g = est[ok], gt[ok]
    return float(np.mean(np.abs(e - g) / g)), float(np.mean(np.maximum(e / g, g / e) < 1.25))


def clips(seeds, static: bool):
    for seed in seeds:
        scene = generate_scene(seed, split="test", config=SynthConfig(num_cameras=3, static=static))
        for name, traj in scene.capture.cameras.items():
            yield seed, name, scene, traj


def summary(values) -> dict:
    v = np.asarray(values, dtype=np.float64)
    return {"mean": float(v.mean()), "median": float(np.median(v)), "p10": float(np.percentile(v, 10)),
            "min": float(v.min()), "max": float(v.max()), "n": int(v.size)}


def track_drift(scene, name: str, traj, rng: np.random.Generator) -> list[float]:
    """End-point distance (px) between DIS-propagated and GT-flow-propagated tracks, forward from frame 0."""
    frames = scene.capture.frames[name]
    gt_flow, gt_valid = scene.flow[name], scene.flow_valid[name]
    dyn = scene.dynamic_mask[name][:1].astype(np.float32)
    if not dyn.any():
        return []
    seed_frames, seed_xy = sample_seeds(dyn, 32, rng=rng)
    fwd, bwd = estimate_flows(frames)
    tracks = propagate_tracks(seed_frames, seed_xy, fwd, bwd)
    # reference: integrate the exact forward flow while the point stays visible (flow_valid)
    pos = seed_xy.astype(np.float64).copy()
    alive = np.ones(len(pos), bool)
    H, W = frames.shape[1:3]
    for t in range(frames.shape[0] - 1):
        ij = np.clip(np.round(pos).astype(int), 0, [W - 1, H - 1])
        alive &= gt_valid[t, ij[:, 1], ij[:, 0]]
        pos = pos + bilinear_sample(gt_flow[t], pos)
    both = alive & tracks.valid[:, -1]
    return np.linalg.norm(tracks.xy[both, -1] - pos[both], axis=-1).tolist()


def timed(fn, repeats: int = 5) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e3)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--timing-only", action="store_true", help="measure the timings alone")
    parser.add_argument("--out", type=Path, default=None,
                        help="results file (default: bench/results/motion.json, or motion_timing.json with "
                             "--timing-only)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    cv2.setNumThreads(1)  # single-threaded throughout, as in a DataLoader worker
    out: dict = {"machine": {"python": sys.version.split()[0], "platform": platform.platform(),
                             "cpus": os.cpu_count(), "loadavg_start": os.getloadavg()}}
    rng = np.random.default_rng(0)
    groups = (("tuning_seeds_0_5", TUNING_SEEDS), ("held_out_seeds_6_11", HELD_OUT_SEEDS),
              ("fresh_seeds_12_17", FRESH_SEEDS))
    for label, seeds in () if args.timing_only else groups:
        ious_cap, ious_est, abs_rel, delta, drift, per_clip = [], [], [], [], [], []
        for seed, name, scene, traj in clips(seeds, static=False):
            frames, gt = scene.capture.frames[name], scene.dynamic_mask[name]
            cap = isolate_motion(frames, traj.K, traj.w2c, scene.capture.depth[name])
            est = isolate_motion(frames, traj.K, traj.w2c, None, depth_range=DEPTH_RANGE, flows=(cap.flow_fwd, cap.flow_bwd))
            ious_cap.append(iou(cap.mask, gt))
            ious_est.append(iou(est.mask, gt))
            a, d = depth_errors(est.depth, scene.capture.depth[name])
            abs_rel.append(a)
            delta.append(d)
            drift.extend(track_drift(scene, name, traj, rng))
            per_clip.append({"seed": seed, "camera": name, "iou_capture_depth": ious_cap[-1],
                             "iou_estimated_depth": ious_est[-1], "gt_dynamic_share": float(gt.mean())})
        static_share, static_abs_rel, static_delta, per_clip_static = [], [], [], []
        for seed, name, scene, traj in clips(seeds, static=True):
            frames = scene.capture.frames[name]
            static_share.append(float(isolate_motion(frames, traj.K, traj.w2c, scene.capture.depth[name]).mask.mean()))
            per_clip_static.append({"seed": seed, "camera": name, "masked_share": static_share[-1]})
            est_depth = estimate_depth(frames, traj.K, traj.w2c, near=DEPTH_RANGE[0], far=DEPTH_RANGE[1])
            a, d = depth_errors(est_depth, scene.capture.depth[name])
            static_abs_rel.append(a)
            static_delta.append(d)
        out[label] = {
            "mask_iou_capture_depth": summary(ious_cap),
            "mask_iou_estimated_depth": summary(ious_est),
            "static_scene_masked_share": summary(static_share),
            "depth_abs_rel_dynamic_scenes": summary(abs_rel),
            "depth_delta125_dynamic_scenes": summary(delta),
            "depth_abs_rel_static_scenes": summary(static_abs_rel),
            "depth_delta125_static_scenes": summary(static_delta),
            "track_drift_px_frame7_dis_vs_gt_flow": summary(drift) if drift else None,
            "per_clip": per_clip,
            "per_clip_static": per_clip_static,
        }
        print(label, json.dumps({k: v for k, v in out[label].items() if not k.startswith("per_clip")}, indent=1),
              flush=True)
    if not args.timing_only:
        dynamic = [c["iou_capture_depth"] for label, _ in groups for c in out[label]["per_clip"]]
        static = [c["masked_share"] for label, _ in groups for c in out[label]["per_clip_static"]]
        out["all_seeds"] = {"mask_iou_capture_depth": summary(dynamic), "static_scene_masked_share": summary(static)}
        print("all_seeds", json.dumps(out["all_seeds"], indent=1), flush=True)

    scene = generate_scene(0, split="test", config=SynthConfig(num_cameras=1))
    name = next(iter(scene.capture.cameras))
    traj, frames, depth = scene.capture.cameras[name], scene.capture.frames[name], scene.capture.depth[name]
    out["timing_ms_per_clip"] = {
        "estimate_flows_14_dis": timed(lambda: estimate_flows(frames)),
        "isolate_motion_capture_depth": timed(lambda: isolate_motion(frames, traj.K, traj.w2c, depth)),
        "prepare_source_capture_depth_64_tracks": timed(lambda: prepare_source(frames, traj, depth)),
        "estimate_depth_plane_sweep": timed(lambda: estimate_depth(frames, traj.K, traj.w2c, near=1.0, far=25.0), 2),
        # what `vt4d encode` runs on footage without depth: the plane sweep, then motion isolation on it
        "prepare_source_estimated_depth_64_tracks": timed(lambda: prepare_source(frames, traj, None), 3),
        "prepare_source_no_motion_isolation": timed(lambda: prepare_source(frames, traj, None, motion_isolation=False)),
    }
    out["machine"]["loadavg_end"] = os.getloadavg()
    print(json.dumps(out["timing_ms_per_clip"], indent=1))
    path = args.out or Path(__file__).parent / "results" / ("motion_timing.json" if args.timing_only else "motion.json")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1) + "\n")
    print("wrote", path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
