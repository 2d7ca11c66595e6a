"""End-to-end codec timing: encode time per capture and decode time per rendered view.

    python bench/bench_codec.py [--model vt4d-tiny] [--scenes 5] [--views 3] [--steps 8]
                                [--out bench/results/codec.json]

For each held-out synthetic scene (split "test"), encodes camera 0 (flow, motion isolation, tracks,
encoder) into an int8 ``.vt4d`` and renders ``--views`` other cameras' trajectories from one loaded
scene.  Reports medians of wall time and of this process's CPU time (the machine is shared: CPU time is
the figure that reflects the work), the load average, and the torch thread count.  The first scene is
a warm-up and is not counted.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

from vt4dcodec import codec
from vt4dcodec.format import dumps
from vt4dcodec.synth import SynthConfig, generate_scene


def timed(fn):
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default=codec.DEFAULT_MODEL)
    parser.add_argument("--scenes", type=int, default=5)
    parser.add_argument("--views", type=int, default=3)
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("bench/results/codec.json"))
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    net = codec.load_model(args.model)
    cfg = net.config
    synth_cfg = SynthConfig(num_cameras=args.views + 1, num_frames=cfg.frames, height=cfg.image_size,
                            width=cfg.image_size)
    enc_wall, enc_cpu, dec_wall, dec_cpu, sizes = [], [], [], [], []
    for i in range(args.scenes + 1):
        scene = generate_scene(1000 + i, split="test", config=synth_cfg)
        cap = scene.capture
        encoded, w, c = timed(lambda: codec.encode(cap, net, "int8", camera=cap.camera_names[0]))
        data = dumps(encoded)
        decoder = codec.SceneDecoder.open(data, model=net)
        targets = [cap.cameras[n] for n in cap.camera_names[1:]]
        _, dw, dc = timed(lambda: decoder.render_many(targets, steps=args.steps, seed=0))
        if i == 0:
            continue  # warm-up
        enc_wall.append(w)
        enc_cpu.append(c)
        dec_wall.append(dw / len(targets))
        dec_cpu.append(dc / len(targets))
        sizes.append(len(data))
        print(f"scene {i}: encode {w:.2f} s wall / {c:.2f} s CPU, decode {dw / len(targets):.2f} s per view, "
              f"{len(data)} bytes", file=sys.stderr)
    result = {
        "model": codec.model_fingerprint(net).to_dict(),
        "scenes": args.scenes, "views_per_scene": args.views, "steps": args.steps, "threads": args.threads,
        "frames": cfg.frames, "image_size": cfg.image_size,
        "encode_seconds_wall_median": statistics.median(enc_wall),
        "encode_seconds_cpu_median": statistics.median(enc_cpu),
        "decode_seconds_per_view_wall_median": statistics.median(dec_wall),
        "decode_seconds_per_view_cpu_median": statistics.median(dec_cpu),
        "scene_bytes_int8_median": statistics.median(sizes),
        "load_average": os.getloadavg(), "machine": platform.machine(), "torch": torch.__version__,
        "command": "python bench/bench_codec.py " + " ".join(argv if argv is not None else sys.argv[1:]),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
