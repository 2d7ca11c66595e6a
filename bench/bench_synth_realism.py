#!/usr/bin/env python
"""How far the synthetic scenes' frames are from real footage: image statistics side by side.

    python bench/bench_synth_realism.py                       # 40 test scenes per style x 4 cameras, caliscope
    python bench/bench_synth_realism.py --scenes 8 --quick    # a smoke run (~20 s)

Frames are compared at the codec's size (64 x 64, the caliscope recording imported as the codec does:
centre crop, every frame) on statistics that separate a clean ray tracer from a webcam: mean and
spread of luminance, saturation, colourfulness (Hasler and Suesstrunk), mean gradient magnitude, the
share of spectral energy above half the Nyquist frequency, the mean absolute frame-to-frame change and
the share of pixels that change by more than 4 % of the range (per frame step; caliscope runs at 6 fps,
the synthetic scenes at 8).  Each statistic is a mean over clips (a clip: one camera's 8 frames) with its
standard error.  For every style the table gives the distance to the real mean in units of the real
clips' standard deviation, and "gap closed" compares each other style's distance with the "objects"
style's.  Results: bench/results/synth_realism.json, a contact sheet with --figure.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vt4dcodec.synth import SynthConfig, generate_scene  # noqa: E402
from vt4dcodec.synth.generator import STYLES  # noqa: E402

STATS = ("luma_mean", "luma_std", "saturation", "colourfulness", "gradient", "high_freq", "temporal_change",
         "moving_share")


def clip_stats(frames: np.ndarray) -> dict[str, float]:
    """Statistics of one clip, (T, H, W, 3) uint8 RGB."""
    x = frames.astype(np.float64) / 255.0
    luma = x @ np.array([0.299, 0.587, 0.114])
    mx, mn = x.max(-1), x.min(-1)
    sat = np.where(mx > 1e-6, (mx - mn) / np.maximum(mx, 1e-6), 0.0)
    rg = x[..., 0] - x[..., 1]
    yb = 0.5 * (x[..., 0] + x[..., 1]) - x[..., 2]
    colourful = np.sqrt(rg.std() ** 2 + yb.std() ** 2) + 0.3 * np.sqrt(rg.mean() ** 2 + yb.mean() ** 2)
    gx = np.diff(luma, axis=2)[:, :-1, :]
    gy = np.diff(luma, axis=1)[:, :, :-1]
    spec = np.abs(np.fft.fft2(luma - luma.mean(axis=(1, 2), keepdims=True))) ** 2
    f = np.fft.fftfreq(luma.shape[1])[:, None] ** 2 + np.fft.fftfreq(luma.shape[2])[None, :] ** 2
    high = (np.sqrt(f) > 0.25)[None]
    change = np.abs(np.diff(luma, axis=0))
    return {"luma_mean": float(luma.mean()), "luma_std": float(luma.std()), "saturation": float(sat.mean()),
            "colourfulness": float(colourful), "gradient": float(np.sqrt(gx ** 2 + gy ** 2).mean()),
            "high_freq": float((spec * high).sum() / max(spec.sum(), 1e-12)),
            "temporal_change": float(change.mean()), "moving_share": float((change > 0.04).mean())}


def summarise(rows: list[dict[str, float]]) -> dict[str, dict[str, float]]:
    out = {}
    for k in STATS:
        v = np.array([r[k] for r in rows])
        out[k] = {"mean": float(v.mean()), "sd": float(v.std(ddof=1)) if len(v) > 1 else 0.0,
                  "se": float(v.std(ddof=1) / np.sqrt(len(v))) if len(v) > 1 else 0.0}
    return out


def synthetic_clips(style: str, scenes: int, first_seed: int, cameras: int) -> list[np.ndarray]:
    clips = []
    for seed in range(first_seed, first_seed + scenes):
        scene = generate_scene(seed, split="test", config=SynthConfig(style=style))
        for name in list(scene.capture.camera_names)[:cameras]:
            clips.append(np.asarray(scene.capture.frames[name]))
    return clips


def real_clips(path: Path, frames: int) -> list[np.ndarray]:
    from vt4dcodec.eval.real_footage import open_capture
    capture = open_capture(path, size=64)
    out = []
    for name in capture.camera_names:
        video = np.asarray(capture.frames[name]) if hasattr(capture, "frames") else None
        if video is None:
            continue
        for start in range(0, len(video) - frames + 1, frames):
            out.append(video[start:start + frames])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=int, default=40, help="synthetic test scenes per style (default 40)")
    ap.add_argument("--first-seed", type=int, default=3000, help="first test seed (default 3000, no benchmark uses it)")
    ap.add_argument("--cameras", type=int, default=4, help="cameras per scene (default 4, as caliscope)")
    ap.add_argument("--capture", type=Path, default=None, help="caliscope recording (default: the shared sample)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench/results/synth_realism.json")
    ap.add_argument("--styles", default=",".join(STYLES), help=f"synthetic styles, comma-separated (default: all, "
                    f"{','.join(STYLES)}; the first is the baseline of 'gap closed')")
    ap.add_argument("--figure", type=Path, default=None, help="write a contact sheet (real, then each style)")
    ap.add_argument("--quick", action="store_true", help="do not write results (smoke run)")
    args = ap.parse_args(argv)
    t0 = time.time()
    if args.capture is None:
        from vt4dcodec.capture.caliscope import find_sample_capture
        args.capture = find_sample_capture()
    if args.capture is None:
        print("caliscope_4cam not found (--capture)", file=sys.stderr)
        return 2
    styles = [s for s in args.styles.split(",") if s]
    unknown = [s for s in styles if s not in STYLES]
    if unknown or not styles:
        print(f"--styles: unknown style {unknown} (known: {', '.join(STYLES)})", file=sys.stderr)
        return 2
    base = styles[0]
    clips = {"real": real_clips(Path(args.capture), 8)}
    for style in styles:
        clips[style] = synthetic_clips(style, args.scenes, args.first_seed, args.cameras)
    summary = {k: summarise([clip_stats(c) for c in v]) for k, v in clips.items()}
    table = {}
    for k in STATS:
        real = summary["real"][k]
        scale = max(real["sd"], 1e-9)
        dist = {s: abs(summary[s][k]["mean"] - real["mean"]) / scale for s in styles}
        table[k] = {"real": real["mean"], **{s: summary[s][k]["mean"] for s in styles},
                    **{"distance_" + s: dist[s] for s in styles},
                    **{"gap_closed_" + s: 1.0 - dist[s] / max(dist[base], 1e-9) for s in styles[1:]}}
    result = {"command": "python bench/bench_synth_realism.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "clips": {k: len(v) for k, v in clips.items()}, "summary": summary, "table": table,
              "mean_distance": {s: float(np.mean([table[k]["distance_" + s] for k in STATS])) for s in styles},
              "wall_s": round(time.time() - t0, 1)}
    print(f"clips: {result['clips']}")
    print(f"{'statistic':16s} {'real':>8s} " + " ".join(f"{s:>8s}" for s in styles) + "  distance " + " / ".join(styles)
          + " (real SDs)")
    for k in STATS:
        r = table[k]
        print(f"{k:16s} {r['real']:8.4f} " + " ".join(f"{r[s]:8.4f}" for s in styles) + "  "
              + " / ".join(f"{r['distance_' + s]:5.2f}" for s in styles))
    print("mean distance: " + ", ".join(f"{s} {result['mean_distance'][s]:.2f}" for s in styles) + " real SDs")
    if not args.quick:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")
        print(f"wrote {args.out}")
    if args.figure is not None:
        import cv2
        rows = []
        for k in ("real", *styles):
            picks = clips[k][:: max(1, len(clips[k]) // 4)][:4]
            rows.append(np.concatenate([c[len(c) // 2] for c in picks], axis=1))
        sheet = np.concatenate(rows, axis=0)
        args.figure.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(args.figure), cv2.resize(sheet[..., ::-1], None, fx=3, fy=3, interpolation=cv2.INTER_NEAREST))
        print(f"wrote {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
