#!/usr/bin/env python
"""How much does a render depend on the target camera?

    python bench/probes/probe_pose_dependence.py [--model vt4d-tiny] [--scenes 6]

Camera 0 of each held-out 10-camera scene is encoded through the public codec (default encoding); the
scene is rendered at its source trajectory and at every other camera. Prints, averaged over the other
cameras: PSNR between the render at camera k and the render at the source (high = the renderer
ignores the target pose), the render at camera k against camera k's truth, and the source render
pasted at camera k against that truth (what ignoring the pose would score). The difference of the last
two is what the pose conditioning buys.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

import vt4dcodec
from vt4dcodec import codec
from vt4dcodec.media import psnr
from vt4dcodec.synth import SynthConfig, generate_scene


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default="vt4d-tiny")
    parser.add_argument("--scenes", type=int, default=6)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    rows = []
    for seed in range(args.scenes):
        capture = generate_scene(seed, split="test", config=SynthConfig(num_cameras=10)).capture
        cams = capture.camera_names
        blob = vt4dcodec.format.dumps(codec.encode(capture, args.model, camera=cams[0]))
        decoder = codec.SceneDecoder.open(blob, model=args.model)
        source = decoder.render("source")
        for cam in cams[1:]:
            render, truth = decoder.render(capture.cameras[cam]), capture.frames[cam]
            rows.append((psnr(render, source), psnr(render, truth), psnr(source, truth)))
    mean = np.asarray(rows).mean(0)
    print(json.dumps({
        "model": args.model,
        "scenes": args.scenes, "views": len(rows),
        "render_vs_source_render_db": round(float(mean[0]), 2),
        "render_vs_truth_db": round(float(mean[1]), 2),
        "source_render_pasted_vs_truth_db": round(float(mean[2]), 2),
        "pose_gain_db": round(float(mean[1] - mean[2]), 2),
    }))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
