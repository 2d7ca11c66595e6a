#!/usr/bin/env python
"""Can a decoder-side dequantizer win back the coarse levels' PSNR? A linear map per quality level and token
matrix from a token's 32 stored values (the bin centres the format gives) to the encoder's float token,
fitted on training captures, then the whole 10-camera capture rendered from the stored values and from the
mapped ones on held-out captures.

    python bench/probes/probe_dequantizer.py [--train 60] [--test 12] [--levels 1,3,5]

Prints, per level, the PSNR over the 10 rendered cameras with bin centres and with the fitted map (paired
difference +- standard error over the test captures) and the token MSE of each. No file format change: the
map would run after decoding, before the renderer.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from vt4dcodec import codec  # noqa: E402
from vt4dcodec.format import Scene  # noqa: E402
from vt4dcodec.format.learned import dequantize, writer_codes  # noqa: E402
from vt4dcodec.synth import generate_scene  # noqa: E402


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 10 * np.log10(255.0 ** 2 / max(mse, 1e-12))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--train", type=int, default=60)
    ap.add_argument("--test", type=int, default=12)
    ap.add_argument("--levels", default="1,3,5")
    ap.add_argument("--ridge", type=float, default=1e-2)
    args = ap.parse_args()
    net = codec.load_model("vt4d-tiny")
    tables = codec.model_tables(net)
    assert tables is not None
    levels = [int(q) - 1 for q in args.levels.split(",")]

    def tokens_of(seed: int, split: str) -> tuple[Scene, object]:
        capture = generate_scene(seed, split=split).capture
        return codec.encode(capture, net, cameras="all", encoding="float32"), capture

    train = [tokens_of(seed, "train")[0] for seed in range(args.train)]
    maps: dict[tuple[int, str], np.ndarray] = {}
    for level in levels:
        for which in ("static", "dynamic"):
            xs, ys = [], []
            for s in train:
                tok = s.static_tokens if which == "static" else s.dynamic_tokens
                views = 1 + len(s.extra_cameras)
                deq = dequantize(writer_codes(tok, tables, level, which, views), tables, level, which)
                xs.append(np.concatenate([deq, np.abs(deq), np.ones((len(deq), 1))], axis=1))
                ys.append(tok)
            x, y = np.concatenate(xs).astype(np.float64), np.concatenate(ys).astype(np.float64)
            maps[level, which] = np.linalg.solve(x.T @ x + args.ridge * len(x) * np.eye(x.shape[1]), x.T @ y)
    gains: dict[int, list[float]] = {level: [] for level in levels}
    base: dict[int, list[float]] = {level: [] for level in levels}
    for seed in range(1000, 1000 + args.test):
        s, capture = tokens_of(seed, "test")
        names = list(capture.camera_names)
        trajs = [capture.cameras[n][:8] for n in names]
        truth = [capture.frames[n][:8] for n in names]
        views = 1 + len(s.extra_cameras)
        for level in levels:
            scores = []
            for mapped in (False, True):
                out = []
                for which, tok in (("static", s.static_tokens), ("dynamic", s.dynamic_tokens)):
                    deq = dequantize(writer_codes(tok, tables, level, which, views), tables, level, which)
                    if mapped:
                        deq = np.concatenate([deq, np.abs(deq), np.ones((len(deq), 1))], axis=1) @ maps[level, which]
                    out.append(deq.astype(np.float32))
                scene = Scene(static_tokens=out[0], dynamic_tokens=out[1], cameras=s.cameras,
                              fingerprint=s.fingerprint, encoding="float32", extra_cameras=s.extra_cameras)
                videos = codec.SceneDecoder.open(scene, model=net).render_many(trajs)
                scores.append(float(np.mean([psnr(v, t) for v, t in zip(videos, truth)])))
            base[level].append(scores[0])
            gains[level].append(scores[1] - scores[0])
        print(f"seed {seed}: " + ", ".join(f"q{lv + 1} {base[lv][-1]:.2f} {gains[lv][-1]:+.2f}" for lv in levels),
              flush=True)
    for level in levels:
        g = np.array(gains[level])
        print(f"q{level + 1}: bin centres {np.mean(base[level]):.2f} dB, mapped {np.mean(g):+.3f} +- "
              f"{g.std(ddof=1) / np.sqrt(len(g)):.3f} dB ({len(g)} captures)")


if __name__ == "__main__":
    main()
