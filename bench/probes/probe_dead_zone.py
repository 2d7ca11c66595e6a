#!/usr/bin/env python
"""What do the writer's rounding offsets (dead zones) buy at each quality level? Bytes, PSNR and the rate
ratio against H.265 per (stored cameras, level, offsets), and what each token class costs.

    python bench/probes/probe_dead_zone.py MODEL [--first-seed 2000] [--scenes 12] [--levels 1,2,3,4]
        [--views 1,4,10] [--offsets 0.5/0.5/0.5,0.5/0.25/0.5,0.45/0.25/0.45] [--out FILE.json]

MODEL: a model directory with quality levels. Each offset triple is (MEAN, CHANGE, DYNAMIC), applied to every
level swept (``vt4dcodec.format.learned.writer_codes``; the model's own ``entropy_rounding`` is replaced). On
held-out synthetic 10-camera captures (split test, seeds the rate study does not use), the first V cameras
are encoded into one file per level and offsets, the stored cameras rendered (their own views), PSNR
averaged; H.265 (libx265, bench_codecs' sweep with 1/2- and 1/4-size encodes) on the same clips gives the
bytes at each point's PSNR. Prints one line per setting (means over scenes; ratio = mean of per-clip ratios
where H.265 reaches the PSNR) and the bytes of each token class under the model's tables at round-to-nearest,
and writes everything to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_codecs import available_codecs, bytes_at_psnr, quality, sweep, video_roundtrip  # noqa: E402

from vt4dcodec import codec  # noqa: E402
from vt4dcodec.format import EntropyTables, dumps, learned  # noqa: E402
from vt4dcodec.synth import SynthConfig, generate_scene  # noqa: E402

CLASS_NAMES = ("MEAN", "CHANGE", "DYNAMIC", "MEAN_AFTER_NEGATIVE", "MEAN_AFTER_POSITIVE") + tuple(
    f"MEAN_PARTNER_{sign}{k}" for sign in ("NEGATIVE", "POSITIVE") for k in ("_AFTER_NEGATIVE", "", "_AFTER_POSITIVE"))


def class_bytes(scene, tables: EntropyTables, level: int, views: int) -> dict[str, float]:
    """Ideal code length (bytes) of each token class of ``scene`` at ``level`` under ``tables``, round to nearest."""
    d = tables.steps.shape[2]
    freqs = tables.freqs[level].reshape(-1, tables.freqs.shape[3])
    out: dict[str, float] = defaultdict(float)
    for which, tokens in (("static", scene.static_tokens), ("dynamic", scene.dynamic_tokens)):
        sym, ctx = learned.coded_symbols(learned.quantize(tokens, tables, level, which), tables, level, views, which)
        bits = -np.log2(freqs[ctx, sym] / 16384.0)
        for cls in np.unique(ctx // d):
            out[CLASS_NAMES[cls]] += float(bits[ctx // d == cls].sum() / 8)
    return dict(out)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model")
    p.add_argument("--first-seed", type=int, default=2000)
    p.add_argument("--scenes", type=int, default=12)
    p.add_argument("--levels", default="1,2,3,4")
    p.add_argument("--views", default="1,4,10")
    p.add_argument("--offsets", default="0.5/0.5/0.5,0.5/0.35/0.5,0.5/0.25/0.5,0.5/0.15/0.5,0.5/0/0.5,"
                                        "0.45/0.25/0.45,0.45/0.5/0.45")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    net = codec.load_model(args.model).eval()
    base = codec.model_tables(net)
    levels = [int(v) for v in args.levels.split(",")]
    views = [int(v) for v in args.views.split(",")]
    offsets = [tuple(float(x) for x in o.split("/")) for o in args.offsets.split(",")]
    spec = available_codecs(["h265"])["h265"]
    rows, classes = [], defaultdict(list)
    for seed in range(args.first_seed, args.first_seed + args.scenes):
        cap = generate_scene(seed, split="test", config=SynthConfig(num_cameras=10, num_frames=net.config.frames,
                                                                      height=net.config.image_size,
                                                                      width=net.config.image_size)).capture
        names = list(cap.camera_names)
        T = net.config.frames
        truth = {n: np.ascontiguousarray(cap.frames[n][:T]) for n in names}
        trajs = {n: cap.cameras[n][:T] for n in names}
        h265 = {k: {n: video_roundtrip(truth[n], "h265", spec, *k[:1], float(cap.fps or 8.0), k[1]) for n in names}
                for k in sweep(spec, False)}
        for v in views:
            stored = names[:v]
            curve = [(sum(h265[k][n][0] for n in stored), float(np.mean([quality(h265[k][n][1], truth[n])[0]
                                                                         for n in stored]))) for k in h265]
            scene = codec.encode(cap, net, cameras=stored, seed=0)
            for level in levels:
                classes[v, level].append(class_bytes(scene, base, level - 1, v))
                for off in offsets:
                    tables = EntropyTables(base.steps, base.freqs, base.origins, base.fingerprint,
                                           np.tile(off, (base.levels, 1)), base.partners)
                    data = dumps(scene, encoding="learned-rans", quality=level, tables=tables)
                    videos = codec.SceneDecoder.open(data, model=net).render_many([trajs[n] for n in stored], seed=0)
                    psnr = float(np.mean([quality(x, truth[n])[0] for n, x in zip(stored, videos)]))
                    h, _ = bytes_at_psnr(curve, psnr)
                    rows.append({"seed": seed, "views": v, "level": level, "offsets": off, "bytes": len(data),
                                 "psnr": psnr, "ratio": None if h is None else len(data) / h})
        print(f"seed {seed} done", flush=True)
    summary = []
    for key in sorted({(r["views"], r["level"], r["offsets"]) for r in rows}):
        rs = [r for r in rows if (r["views"], r["level"], r["offsets"]) == key]
        ratios = [r["ratio"] for r in rs if r["ratio"] is not None]
        summary.append({"views": key[0], "level": key[1], "offsets": key[2],
                        "bytes": float(np.mean([r["bytes"] for r in rs])), "psnr": float(np.mean([r["psnr"] for r in rs])),
                        "ratio": float(np.mean(ratios)) if ratios else None, "clips_with_ratio": len(ratios)})
        print(json.dumps(summary[-1]))
    costs = {f"{v} cameras, q{lv}": {c: float(np.mean([x.get(c, 0.0) for x in xs])) for c in CLASS_NAMES}
             for (v, lv), xs in sorted(classes.items())}
    for k, c in costs.items():
        print(k, "bytes by class at round-to-nearest:", {n: round(b, 1) for n, b in c.items() if b})
    if args.out:
        args.out.write_text(json.dumps({"command": " ".join(sys.argv), "summary": summary, "class_bytes": costs,
                                        "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
