#!/usr/bin/env python
"""Where is the synthetic source view's error: on the moving objects, or on the still scene?

    python bench/probes/probe_source_error_split.py [--model vt4d-tiny ...] [--scenes 50] [--quality 9]
        [--threads 2] [--out FILE.json]

On the evaluation protocol's held-out scenes (camera 0 encoded alone at ``--quality``, its own view rendered as the
decoder does), the squared error per pixel is split by the generator's exact moving-object masks. Printed per
model, beside two references of the same frames -- the frozen autoencoder's latent averaged over pairs of frames
(what a time average plus 4 frame copies could hold) and the autoencoder's own reconstruction: the PSNR, the
moving pixels' share of the error, and the PSNR with the moving pixels exact (the still scene's error alone).
The synthetic source cameras move (up to 0.36 m over a clip), so "still" pixels change too.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from vt4dcodec import codec
from vt4dcodec.eval.protocol import EvalSettings, make_scene
from vt4dcodec.eval.report import write_json
from vt4dcodec.format import dumps

from probe_real_motion_error import split_error  # the probes' folder: sys.path[0] when run as a script
from probe_temporal_basis import BASES, projected_videos, projection


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", nargs="+", default=["vt4d-tiny"])
    ap.add_argument("--scenes", type=int, default=50)
    ap.add_argument("--quality", type=int, default=9)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    nets = {name: codec.load_model(name) for name in args.model}
    ae = nets[args.model[0]].autoencoder
    references = {"pair_average": projection(BASES["groups4"]), "autoencoder": projection(BASES["exact"])}
    settings = EvalSettings(scenes=args.scenes)
    rows: dict[str, list[dict]] = {name: [] for name in [*args.model, *references]}
    moving_share = []
    for seed in settings.seeds:
        sc = make_scene(seed, settings, "source")
        cam = sc.capture.camera_names[0]
        truth, moving = np.asarray(sc.capture.frames[cam]), sc.dynamic_mask[cam]
        moving_share.append(float(moving.mean()))
        for name, net in nets.items():
            blob = dumps(codec.encode(sc.capture, net, "learned-rans", cameras=[cam], seed=0, quality=args.quality))
            video = codec.SceneDecoder.open(blob, model=net).render_many([sc.capture.cameras[cam]], seed=0)[0]
            rows[name].append(split_error(truth, video, moving))
        for name, video in projected_videos(ae, truth, references).items():
            rows[name].append(split_error(truth, video, moving))
    result = {"command": "python bench/probes/probe_source_error_split.py " + " ".join(argv if argv is not None
                                                                                       else sys.argv[1:]),
              "scenes": args.scenes, "quality": args.quality, "moving_share": float(np.mean(moving_share)),
              "rows": []}
    for name, values in rows.items():
        psnr = np.array([v["psnr"] for v in values])
        entry = {"name": name, "psnr": round(float(psnr.mean()), 3),
                 "psnr_se": round(float(psnr.std(ddof=1) / np.sqrt(len(psnr))), 3),
                 "moving_error_share": round(float(np.mean([v["moving_error_share"] for v in values])), 4),
                 "psnr_moving_exact": round(float(np.mean([v["psnr_moving_exact"] for v in values])), 3)}
        result["rows"].append(entry)
        print(f"{name:24s} PSNR {entry['psnr']:.2f} +- {entry['psnr_se']:.2f}; moving pixels hold "
              f"{entry['moving_error_share']:.1%} of the error; with them exact {entry['psnr_moving_exact']:.2f} dB")
    print(f"moving pixels: {result['moving_share']:.1%} of the frames")
    if args.out is not None:
        print(f"wrote {write_json(args.out, result)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
