#!/usr/bin/env python
"""Where is a real clip's own-view error: in the pixels that move, or in the still ones? And how far is the
frozen autoencoder's ceiling?

    python bench/probes/probe_real_motion_error.py [--model vt4d-tiny ...] [--source cam_0] [--quality 9]
        [--refine 0] [--out FILE.json]

Encodes ``--source`` of the caliscope sample (every 8-frame clip, the codec's default fit), renders its own view
and splits the squared error per pixel into the moving pixels (a colour channel more than 0.08 from the pixel's
temporal median over the clip: no ground-truth masks exist for real footage) and the rest. Prints per model the
PSNR, the moving pixels' share of the frame and of the error, the PSNR the render would have if the moving
pixels were exact, and the PSNR per frame of the clip; and once the autoencoder's own reconstruction of the same
frames (the ceiling of any token set), all means over the clips.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from vt4dcodec import codec
from vt4dcodec.capture.caliscope import find_sample_capture
from vt4dcodec.eval.metrics import video_metrics
from vt4dcodec.eval.real_footage import evaluate_cameras, open_capture

MOVING = 0.08  # a pixel moves where a channel is this far (of the range) from its temporal median


def split_error(truth: np.ndarray, render: np.ndarray, moving: np.ndarray | None = None
                ) -> dict[str, float | list[float]]:
    """(T, H, W, 3) uint8 truth and render -> PSNR, moving share, the moving pixels' share of the error, PSNR
    with the moving pixels exact, per-frame PSNR. ``moving`` (T, H, W) bool: the moving pixels where they are
    known (synthetic masks); by default those a channel more than :data:`MOVING` from its temporal median."""
    t, r = truth.astype(np.float64) / 255.0, render.astype(np.float64) / 255.0
    if moving is None:
        moving = np.abs(t - np.median(t, axis=0, keepdims=True)).max(-1) > MOVING
    err = ((t - r) ** 2).mean(-1)
    still = float((err * ~moving).sum() / err.size)
    return {"psnr": float(-10 * np.log10(err.mean())), "moving_share": float(moving.mean()),
            "moving_error_share": float((err * moving).sum() / err.sum()),
            "psnr_moving_exact": float(-10 * np.log10(max(still, 1e-12))),
            "psnr_per_frame": [float(-10 * np.log10(err[i].mean())) for i in range(err.shape[0])]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", nargs="+", default=["vt4d-tiny"])
    ap.add_argument("--source", default="cam_0")
    ap.add_argument("--quality", type=int, default=9)
    ap.add_argument("--refine", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    path = find_sample_capture()
    if path is None:
        print("caliscope_4cam not found", file=sys.stderr)
        return 2
    capture = open_capture(path, size=64)
    result: dict = {"command": "python bench/probes/probe_real_motion_error.py "
                    + " ".join(argv if argv is not None else sys.argv[1:]), "models": {}}
    net, clips = None, []
    for name in args.model:
        net = codec.load_model(name)
        _, clips = evaluate_cameras(capture, net, [args.source], [args.source], quality=args.quality,
                                    refine=args.refine)
        per_clip = [split_error(c["cameras"][args.source]["truth"], c["cameras"][args.source]["ours"]) for c in clips]
        summary = {k: float(np.mean([p[k] for p in per_clip])) for k in per_clip[0] if k != "psnr_per_frame"}
        summary["psnr_per_frame"] = np.mean([p["psnr_per_frame"] for p in per_clip], axis=0).round(3).tolist()
        summary["clips"] = len(per_clip)
        result["models"][name] = summary
        print(f"{name}: PSNR {summary['psnr']:.2f} dB; moving pixels {summary['moving_share']:.1%} of the frame, "
              f"{summary['moving_error_share']:.1%} of the error; with them exact {summary['psnr_moving_exact']:.2f} dB; "
              f"per frame {summary['psnr_per_frame']}")
    assert net is not None
    ceiling = []
    for c in clips:  # the last model's clips: the fitted real frames every model was measured on
        frames = c["cameras"][args.source]["truth"]
        with torch.no_grad():
            rec = net.autoencoder(torch.from_numpy(frames.astype(np.float32) / 255.0).permute(0, 3, 1, 2))
        rec_u8 = (rec.clamp(0, 1).permute(0, 2, 3, 1).numpy() * 255.0).round().astype(np.uint8)
        m = video_metrics(rec_u8, frames, np.zeros(frames.shape[:3], bool))
        ceiling.append((m["psnr"], m["ssim"]))
    result["autoencoder"] = {"psnr": float(np.mean([c[0] for c in ceiling])),
                             "ssim": float(np.mean([c[1] for c in ceiling])), "clips": len(ceiling)}
    print(f"autoencoder ceiling ({args.model[-1]}'s): {result['autoencoder']['psnr']:.2f} dB, "
          f"SSIM {result['autoencoder']['ssim']:.3f}")
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
