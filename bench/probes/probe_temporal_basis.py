#!/usr/bin/env python
"""How much of a clip can a few values per latent cell hold over time, by the temporal basis they weigh?

    python bench/probes/probe_temporal_basis.py [--model vt4d-tiny] [--scenes 50] [--first-seed 0]
        [--caliscope-source cam_0] [--threads 2] [--out FILE.json]

For each clip (the evaluation protocol's held-out synthetic scenes, camera 0's own 8 frames; and every 8-frame
clip of the caliscope sample's ``--caliscope-source``, the codec's default fit), every latent value's time series
(the frozen autoencoder's latent, 8 frames) is replaced by its least-squares fit in a small temporal basis, decoded,
and scored against the real frames (PSNR over the clip, mean over clips with its standard error):

- ``time_mean``: one constant (what one token per cell holds);
- ``groups4``: 4 frame-group indicators (pairs of frames: a time average plus 4 frame copies, ``frame_copies``,
  span a 4-dimensional subspace -- the time average is their mean);
- ``hat4``: 4 hat functions centred on the pairs' centres (frames 0.5, 2.5, 4.5, 6.5), constant beyond the first
  and last (``copy_blend``: the same 4 copies blended linearly over time);
- ``hat5``: 5 hat functions at frames 0, 1.75, 3.5, 5.25, 7 (5 tokens a cell all used as knots);
- ``dct4``, ``dct5``: the first 4 or 5 DCT-II functions over the 8 frames;
- ``exact``: every frame (the autoencoder's own reconstruction, the ceiling of any token set).

A linear fit in latent space is what a token holding its cell linearly could reach; the renderer gets less.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from vt4dcodec import codec
from vt4dcodec.capture.caliscope import find_sample_capture
from vt4dcodec.eval.metrics import video_metrics
from vt4dcodec.eval.protocol import EvalSettings, make_scene
from vt4dcodec.eval.real_footage import open_capture
from vt4dcodec.eval.report import write_json

FRAMES = 8


def hats(knots: np.ndarray, frames: int = FRAMES) -> np.ndarray:
    """(frames, len(knots)) hat functions at ``knots`` (increasing), constant beyond the first and last."""
    basis = np.zeros((frames, len(knots)))
    for i in range(frames):
        t = min(max(float(i), knots[0]), knots[-1])
        j = min(int(np.searchsorted(knots, t, side="right")) - 1, len(knots) - 2)
        w = (t - knots[j]) / (knots[j + 1] - knots[j])
        basis[i, j], basis[i, j + 1] = 1.0 - w, w
    return basis


def groups(n: int, frames: int = FRAMES) -> np.ndarray:
    """(frames, n) indicators of n equal frame groups."""
    return np.eye(n)[np.arange(frames) * n // frames]


def dct(n: int, frames: int = FRAMES) -> np.ndarray:
    """(frames, n) the first n DCT-II functions."""
    t = np.arange(frames) + 0.5
    return np.stack([np.cos(np.pi * t * k / frames) for k in range(n)], axis=1)


BASES = {"time_mean": np.ones((FRAMES, 1)), "groups4": groups(4), "hat4": hats(np.array([0.5, 2.5, 4.5, 6.5])),
         "hat5": hats(np.linspace(0.0, 7.0, 5)), "dct4": dct(4), "dct5": dct(5), "exact": np.eye(FRAMES)}


def projection(basis: np.ndarray) -> torch.Tensor:
    """(frames, frames) float32: the least-squares projection onto the span of ``basis``'s columns."""
    return torch.tensor(basis @ np.linalg.pinv(basis), dtype=torch.float32)


def projected_videos(ae, frames: np.ndarray, projections: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
    """Per projection: the autoencoder ``ae``'s decode (uint8 (T, H, W, 3)) of ``frames``' latent with every
    value's time series projected (:func:`projection`)."""
    x = torch.from_numpy(frames.astype(np.float32) / 255.0).permute(0, 3, 1, 2)[None]
    out = {}
    with torch.no_grad():
        z = ae.encode(x)
        for name, proj in projections.items():
            video = ae.decode(torch.einsum("st,btchw->bschw", proj, z)).clamp(0, 1)[0]
            out[name] = (video.permute(0, 2, 3, 1).numpy() * 255.0).round().astype(np.uint8)
    return out


def basis_psnrs(net, clips: list[np.ndarray]) -> dict[str, dict[str, float]]:
    """Per basis: mean PSNR and SSIM over ``clips`` ((8, H, W, 3) uint8 each) of the autoencoder's decode of the
    latent projected onto the basis, with the PSNR's standard error."""
    projections = {k: projection(b) for k, b in BASES.items()}
    scores: dict[str, list[tuple[float, float]]] = {k: [] for k in BASES}
    for frames in clips:
        for name, u8 in projected_videos(net.autoencoder, frames, projections).items():
            m = video_metrics(u8, frames, np.zeros(frames.shape[:3], bool))
            scores[name].append((m["psnr"], m["ssim"]))
    out = {}
    for name, rows in scores.items():
        p = np.array([r[0] for r in rows])
        out[name] = {"psnr": round(float(p.mean()), 3), "se": round(float(p.std(ddof=1) / np.sqrt(len(p))), 3)
                     if len(p) > 1 else None, "ssim": round(float(np.mean([r[1] for r in rows])), 4), "clips": len(p)}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="vt4d-tiny", help="whose frozen autoencoder")
    ap.add_argument("--scenes", type=int, default=50)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--caliscope-source", default="cam_0")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    net = codec.load_model(args.model)
    settings = EvalSettings(scenes=args.scenes, first_seed=args.first_seed)
    synthetic = []
    for seed in settings.seeds:
        sc = make_scene(seed, settings, "source")
        synthetic.append(np.asarray(sc.capture.frames[sc.capture.camera_names[0]]))
    result = {"command": "python bench/probes/probe_temporal_basis.py " + " ".join(argv if argv is not None
                                                                                  else sys.argv[1:]),
              "model": args.model, "synthetic": basis_psnrs(net, synthetic)}
    path = find_sample_capture()
    if path is not None:
        real = np.asarray(open_capture(path, size=64).frames[args.caliscope_source])
        clips = [real[i:i + FRAMES] for i in range(0, len(real) - FRAMES + 1, FRAMES)]
        result["caliscope"] = basis_psnrs(net, clips)
    for where in ("synthetic", "caliscope"):
        for name, r in result.get(where, {}).items():
            print(f"{where:9s} {name:9s} {r['psnr']:6.2f} dB +- {r['se']}  SSIM {r['ssim']:.3f}  ({r['clips']} clips)")
    if args.out is not None:
        print(f"wrote {write_json(args.out, result)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
