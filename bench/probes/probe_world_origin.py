"""Does a stored scene's render depend on where the capture's world origin is?

    python bench/probes/probe_world_origin.py [--model vt4d-tiny] [--first-seed 7100] [--scenes 50] \
        [--quality 9] [--threads 2] [--out bench/results/world_origin.json]

The renderer measures token depths from a reference point (vt4dcodec.reference): the world origin, unless it
lies less than MIN_REFERENCE_DEPTH in front of an encoded camera, when the codec moves it. For held-out synthetic
10-camera captures (split "test"; the generator puts the origin on the floor below the cameras' look-at point)
this encodes camera 0 at ``--quality`` and renders its own view and its three nearest cameras, PSNR against the
truth, with the same capture in several world frames (a rigid translation: the pictures and the camera geometry
are the same):

- ``original``: the generator's frame;
- ``origin_at_camera``: the origin at camera 0's centre at frame 0 (OpenCV stereo, caliscope and
  structure-from-motion calibrations), through the codec (the reference is moved);
- ``origin_at_camera_unmoved``: the same frame with the reference left at the origin (the codec before
  vt4dcodec.reference: the model's inputs in that frame as they are);
- ``origin_3m_aside``: the origin 3 m along world x (in front of every camera: not moved);
- ``look_at_point``: the origin at the point nearest to the ten cameras' optical axes (in front: not moved).

Per variant it reports the mean PSNR and the paired difference from ``original`` with its standard error.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from unittest import mock

import numpy as np
import torch

from vt4dcodec import codec, reference
from vt4dcodec.eval.metrics import video_metrics
from vt4dcodec.eval.protocol import nearest_cameras
from vt4dcodec.format import dumps
from vt4dcodec.synth import SynthConfig, generate_scene


def moved(capture, point: np.ndarray):
    """The capture in the world frame whose origin is ``point`` (old world coordinates)."""
    return dataclasses.replace(capture, cameras={k: reference.move_trajectory(v, point)
                                                 for k, v in capture.cameras.items()})


def look_at_point(capture) -> np.ndarray:
    w2c = np.stack([np.asarray(capture.cameras[n].w2c, np.float64)[0] for n in capture.camera_names])
    axes, centres = w2c[:, 2, :3], -np.einsum("nji,nj->ni", w2c[:, :3, :3], w2c[:, :3, 3])
    proj = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    return np.linalg.solve(proj.sum(0), np.einsum("nij,nj->i", proj, centres))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", default="vt4d-tiny")
    p.add_argument("--first-seed", type=int, default=7100)
    p.add_argument("--scenes", type=int, default=50)
    p.add_argument("--quality", type=int, default=9)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("bench/results/world_origin.json"))
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    net = codec.load_model(args.model)
    cfg = net.config
    rows = []
    t0 = time.perf_counter()
    for seed in range(args.first_seed, args.first_seed + args.scenes):
        cap = generate_scene(seed, split="test", config=SynthConfig(num_cameras=10, num_frames=cfg.frames,
                                                                   height=cfg.image_size, width=cfg.image_size)).capture
        src = cap.camera_names[0]
        targets = [src] + [k for k, _ in nearest_cameras(cap, src, 3)]
        w0 = np.asarray(cap.cameras[src].w2c, np.float64)[0]
        at_camera = -w0[:3, :3].T @ w0[:3, 3]
        variants = {"original": (np.zeros(3), False), "origin_at_camera": (at_camera, False),
                    "origin_at_camera_unmoved": (at_camera, True), "origin_3m_aside": (np.array([3.0, 0, 0]), False),
                    "look_at_point": (look_at_point(cap), False)}
        row: dict = {"seed": seed}
        for name, (point, unmoved) in variants.items():
            cp = moved(cap, point)
            with mock.patch.object(codec, "model_centre", lambda frame, trajectories: None) if unmoved else \
                    mock.patch.object(codec, "model_centre", codec.model_centre):
                scene = codec.encode(cp, net, cameras=[src], quality=args.quality)
            decoder = codec.SceneDecoder.open(dumps(scene), model=net)
            videos = decoder.render_many([cp.cameras[k] for k in targets])
            none = np.zeros(cap.frames[src].shape[:3], bool)
            psnr = [video_metrics(v, cap.frames[k], none)["psnr"] for v, k in zip(videos, targets)]
            row[name] = {"source": round(psnr[0], 4), "near": round(float(np.mean(psnr[1:])), 4),
                         "reference_moved": decoder.centre() is not None}
        rows.append(row)
        print(seed, {k: (v["source"], v["near"], v["reference_moved"]) for k, v in row.items() if k != "seed"},
              file=sys.stderr, flush=True)
    summary = {}
    for name in rows[0]:
        if name == "seed":
            continue
        summary[name] = {}
        for view in ("source", "near"):
            values = np.array([r[name][view] for r in rows])
            diff = values - np.array([r["original"][view] for r in rows])
            summary[name][view] = {"psnr_mean": round(float(values.mean()), 3),
                                   "minus_original": round(float(diff.mean()), 3),
                                   "se": round(float(diff.std(ddof=1) / np.sqrt(len(diff))), 3) if len(diff) > 1 else None}
        summary[name]["reference_moved_share"] = float(np.mean([r[name]["reference_moved"] for r in rows]))
        print(f"{name:26s} source {summary[name]['source']['psnr_mean']:6.2f} "
              f"({summary[name]['source']['minus_original']:+.3f} +- {summary[name]['source']['se']}), near "
              f"{summary[name]['near']['psnr_mean']:6.2f} ({summary[name]['near']['minus_original']:+.3f} +- "
              f"{summary[name]['near']['se']}); reference moved in {summary[name]['reference_moved_share']:.0%}",
              file=sys.stderr)
    result = {"model": codec.model_fingerprint(net).short(), "quality": args.quality, "scenes": args.scenes,
              "first_seed": args.first_seed, "min_reference_depth_m": reference.MIN_REFERENCE_DEPTH,
              "default_reference_depth_m": reference.DEFAULT_REFERENCE_DEPTH, "wall_s": round(time.perf_counter() - t0, 1),
              "summary": summary, "rows": rows,
              "command": "python bench/probes/probe_world_origin.py " + " ".join(sys.argv[1:] if argv is None else argv)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
