#!/usr/bin/env python
"""Encoding 2, 4 or 8 cameras: each camera's tokens on the same few cells, or spread over distinct cells.

    python bench/probes/probe_spread_views.py RUN_OR_MODEL [--scenes 8] [--views 2,4,8] [--threads 1] [--out FILE.json]

With V encoded cameras anchored token i belongs to camera i mod V and cell i mod P; when V shares a factor
with the P = 64 cells each camera's tokens land on only 64 / gcd(V, 64) cells (4 cameras: 16 cells, each
held by 5 tokens as frame copies). ``config.spread_views`` shifts each block of P tokens by one camera so
they cover distinct cells (4 cameras: all 64). This renders, for the model as it is and for the same
weights under ``spread_views``, held-out 8-camera synthetic scenes with V evenly spaced cameras encoded
(float32 tokens): the encoded cameras' own views and, for V < 8, the held-out ones. Mean PSNR in dB per
(V, set, layout), and the flat mean-colour image's PSNR on the same views. Prints one JSON line and
writes it to ``--out``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from vt4dcodec import codec
from vt4dcodec.eval.command import resolve_model
from vt4dcodec.media import psnr
from vt4dcodec.model.train.ship import reconfigure
from vt4dcodec.synth import SynthConfig, generate_scene

RIG = 8  # cameras per synthetic scene: V = 2, 4, 8 evenly spaced


def _flat(frames: np.ndarray) -> float:
    mean = frames.reshape(-1, 3).mean(0).round().astype(np.uint8)
    return psnr(np.broadcast_to(mean, frames.shape), frames)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", help="a training run directory, a shipped id or a model directory")
    parser.add_argument("--scenes", type=int, default=8)
    parser.add_argument("--views", default="2,4,8", help=f"comma-separated numbers of encoded cameras (of {RIG})")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    model = resolve_model(args.model)
    if not model.config.anchor_views:
        raise SystemExit(f"{args.model}: this model does not anchor tokens per camera (config anchor_views)")
    views = [int(v) for v in args.views.split(",") if v.strip()]
    if any(not 2 <= v <= RIG or RIG % v for v in views):
        raise SystemExit(f"--views: each must divide {RIG} and be >= 2, got {args.views!r}")
    layouts = {"plain": reconfigure(model, {"spread_views": False}),
               "spread": reconfigure(model, {"spread_views": True})}
    scores: dict[str, list[float]] = {}
    for seed in range(args.scenes):
        capture = generate_scene(seed, split="test", config=SynthConfig(num_cameras=RIG)).capture
        names = capture.camera_names
        for V in views:
            encoded = names[::RIG // V]
            held = [n for n in names if n not in encoded]
            for layout, net in layouts.items():
                decoder = codec.SceneDecoder(scene=codec.encode(capture, net, "float32", cameras=encoded), model=net)
                for kind, group in (("encoded", encoded), ("held", held)):
                    for name in group:
                        out = decoder.render(capture.cameras[name], steps=1)
                        scores.setdefault(f"V{V}_{kind}_{layout}", []).append(psnr(out, capture.frames[name]))
                        if layout == "plain":
                            scores.setdefault(f"V{V}_{kind}_flat", []).append(_flat(capture.frames[name]))
    result = {"model": args.model, "scenes": args.scenes, "rig": RIG,
              **{k: round(float(np.mean(v)), 3) for k, v in scores.items()}}
    print(json.dumps(result))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
