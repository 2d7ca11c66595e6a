#!/usr/bin/env python
"""What the frame copies' splat adds to the source view and takes from the near views.

    python bench/probes/probe_frame_splat.py RUN_OR_MODEL [--scenes 8] [--gate-deg 5,10,20] [--threads 1] [--out FILE.json]

For a model with ``frame_copies`` (a training run directory, its latest checkpoint, or a shipped id /
model directory): held-out 10-camera synthetic scenes, camera 0 encoded (float32 tokens), its own
trajectory and the two nearest cameras (the evaluation's near set) rendered in one step twice: as the
model is, and with the frame splat's map zeroed (each copy then reaches the output only through the
time-average splat and the attention); with ``--gate-deg``, also with the same weights under each
``config.frame_gate_deg`` given (the frame splat weighed by the angle between the rays to each token from
its camera and from the target). Mean PSNR in dB per target set. Prints one JSON line and writes it to
``--out``.
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
from vt4dcodec.model.train.ship import reconfigure
from vt4dcodec.synth import SynthConfig, generate_scene


def _tensors(*arrays: np.ndarray) -> list[torch.Tensor]:
    return [torch.from_numpy(np.asarray(a, np.float32))[None] for a in arrays]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", help="a training run directory, a shipped id or a model directory")
    parser.add_argument("--scenes", type=int, default=8)
    parser.add_argument("--gate-deg", default="", help="comma-separated frame_gate_deg values to try")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    model = resolve_model(args.model)
    frame_map = model.renderer.splat_frames
    if frame_map is None:
        raise SystemExit(f"{args.model}: this model has no frame copies (config frame_copies)")
    trained = frame_map.weight.detach().clone()
    gates = [float(g) for g in args.gate_deg.split(",") if g.strip()]
    gated = {}
    for g in gates:  # the same weights under another frame_gate_deg (the gate has no weights)
        gated[f"gate{g:g}"] = reconfigure(model, {"frame_gate_deg": g})
    modes = ["with", "without", *gated]
    scores: dict[str, list[float]] = {f"{s}_{m}": [] for s in ("source", "near") for m in modes}
    for seed in range(args.scenes):
        sc = generate_scene(seed, split="test", config=SynthConfig(num_cameras=10))
        cam = sc.capture.camera_names[0]
        scene = codec.encode(sc.capture, model, "float32", camera=cam)
        z_s, z_d = _tensors(scene.static_tokens, scene.dynamic_tokens)
        source = tuple(_tensors(sc.capture.cameras[cam].K, sc.capture.cameras[cam].w2c))
        targets = [(cam, "source")] + [(name, "near") for name, _ in nearest_cameras(sc.capture, cam, 2)]
        for name, kind in targets:
            K, w2c = _tensors(sc.capture.cameras[name].K, sc.capture.cameras[name].w2c)
            truth = sc.capture.frames[name].astype(np.float64) / 255.0
            for mode in modes:
                with torch.no_grad():
                    frame_map.weight.copy_(torch.zeros_like(trained) if mode == "without" else trained)
                    out = gated.get(mode, model).render(z_s, z_d, K, w2c, steps=1, seed=0, source=source)[0]
                err = np.mean((out.permute(0, 2, 3, 1).double().numpy() - truth) ** 2)
                scores[f"{kind}_{mode}"].append(float(10.0 * np.log10(1.0 / err)))
    result = {"model": args.model, "scenes": args.scenes, **{k: round(float(np.mean(v)), 3) for k, v in scores.items()}}
    print(json.dumps(result))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
