#!/usr/bin/env python
"""Compact cameras (FORMAT.md I.5.1, format 1.2): bytes of the cameras section, and what is left of a
scene besides its tokens, for the trajectories the synthetic test captures hold (8 frames at 64x64 with
timestamps, every camera), in each cameras mode; the largest reprojection change of the float32 mode.

    python bench/bench_compact_cameras.py                   # 20 held-out captures x 10 cameras, ~1 minute
    python bench/bench_compact_cameras.py --captures 5

The whole-file part encodes camera 0 of the first capture with the shipped model (``--model``, default
vt4d-tiny) at the codec's default token encoding, then writes that one scene in each cameras mode: file
bytes, token bytes, non-token bytes (preamble, header, section table, cameras, padding), and the header
alone.  Results: bench/results/compact_cameras.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from vt4dcodec.format import dumps, open_scene  # noqa: E402
from vt4dcodec.format.compact_cameras import (CAMERA_MODES, pack_compact_cameras, reprojection_change,  # noqa: E402
                                              unpack_compact_cameras)
from vt4dcodec.format.sections import compress_payload, pack_cameras, unpack_cameras  # noqa: E402
from vt4dcodec.format.writer import DEFAULT_COMPRESSION_LEVEL  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "compact_cameras.json"


def section_bytes(traj, mode: str) -> tuple[int, object]:
    layout, raw = pack_cameras(traj)
    if mode != "legacy":
        raw = pack_compact_cameras(traj, mode)
        back = unpack_compact_cameras(raw, layout)
    else:
        back = unpack_cameras(raw, layout)
    return len(compress_payload(raw, DEFAULT_COMPRESSION_LEVEL)[1]), back


def whole_files(model: str) -> dict:
    from vt4dcodec import codec
    from vt4dcodec.synth import SynthConfig, generate_scene

    net = codec.load_model(model)
    cfg = net.config
    cap = generate_scene(0, split="test", config=SynthConfig(num_frames=cfg.frames, height=cfg.image_size,
                                                              width=cfg.image_size)).capture
    scene = codec.encode(cap, net, codec.DEFAULT_ENCODING, camera=cap.camera_names[0], seed=0)
    out = {"model": f"{net.model_id} {net.model_version}" if hasattr(net, "model_id") else model,
           "encoding": scene.encoding, "modes": {}}
    for mode in CAMERA_MODES:
        f = open_scene(dumps(scene, cameras=mode))
        out["modes"][mode] = {"version": "%d.%d" % f.version, "file_bytes": f.nbytes, "token_bytes": f.token_bytes,
                              "non_token_bytes": f.nbytes - f.token_bytes,
                              "header_bytes": f.preamble.header_length,
                              "cameras_section_bytes": f.sections[0].stored_length,
                              "preamble_and_table_bytes": 64 + 40 * len(f.sections)}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--captures", type=int, default=20)
    ap.add_argument("--model", default="vt4d-tiny")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    from vt4dcodec.synth import SynthConfig, generate_scene

    sizes = {m: [] for m in CAMERA_MODES}
    worst, f32 = 0.0, 0
    for seed in range(args.captures):
        cap = generate_scene(seed, split="test", config=SynthConfig(num_frames=8, height=64, width=64)).capture
        for name in cap.camera_names:
            traj = cap.cameras[name]
            for mode in CAMERA_MODES:
                n, back = section_bytes(traj, mode)
                sizes[mode].append(n)
                if mode == "compact":
                    worst = max(worst, reprojection_change(traj, back))
                    f32 += pack_compact_cameras(traj, "compact")[0] == 4
    trajectories = len(sizes["legacy"])
    result = {
        "trajectories": trajectories, "captures": args.captures, "frames": 8, "size": "64x64", "timestamps": True,
        "cameras_section_bytes": {m: {"mean": round(float(np.mean(v)), 1), "max": int(np.max(v))}
                                  for m, v in sizes.items()},
        "compact_float32_share": round(f32 / trajectories, 3),
        "compact_max_reprojection_change_px": worst,
        "single_camera_scene": whole_files(args.model),
        "command": "python bench/bench_compact_cameras.py " + " ".join(sys.argv[1:]),
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count()},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
