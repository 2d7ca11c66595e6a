#!/usr/bin/env python
"""Would a file whose two token matrices sit at different quality levels serve the five held-out cameras better
within a byte budget? Each learned-rans payload names its own level (FORMAT.md I.6.2), so a writer could store
the static tokens at one level and the dynamic tokens at another.

    python bench/probes/probe_level_mix.py [--first-seed 2000] [--scenes 12] [--mixes 7/7,6/9,7/9,6/8,5/9,8/6,8/7]
        [--out FILE.json]

On held-out synthetic 10-camera captures (split test; tuning seeds, not the rate study's), the even cameras are
encoded into one token set; for each static/dynamic level pair the file's bytes are those of the static level's
file with the dynamic level's ZDYN payload in place of its own, and the five odd (held-out) cameras are rendered
from the static level's static tokens and the dynamic level's dynamic tokens. Prints mean bytes and PSNR per pair.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_codecs import quality  # noqa: E402

from vt4dcodec import codec  # noqa: E402
from vt4dcodec.format import dumps, loads, open_scene  # noqa: E402
from vt4dcodec.synth import SynthConfig, generate_scene  # noqa: E402


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default="vt4d-tiny")
    p.add_argument("--first-seed", type=int, default=2000)
    p.add_argument("--scenes", type=int, default=12)
    p.add_argument("--mixes", default="7/7,6/9,7/9,6/8,5/9,8/6,8/7", help="static/dynamic level pairs")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args()
    mixes = [tuple(int(v) for v in m.split("/")) for m in args.mixes.split(",")]
    torch.set_num_threads(args.threads)
    net = codec.load_model(args.model).eval()
    tables, frames = codec.model_tables(net), net.config.frames
    levels = sorted({q for m in mixes for q in m})
    rows: dict[str, list[tuple[int, float]]] = {f"{a}/{b}": [] for a, b in mixes}
    for seed in range(args.first_seed, args.first_seed + args.scenes):
        cap = generate_scene(seed, split="test", config=SynthConfig(num_cameras=10, num_frames=frames,
                                                                      height=net.config.image_size,
                                                                      width=net.config.image_size)).capture
        names = list(cap.camera_names)
        stored, held = names[::2], names[1::2]
        truth = {n: cap.frames[n][:frames] for n in held}
        trajs = [cap.cameras[n][:frames] for n in held]
        scene = codec.encode(cap, net, cameras=stored, seed=0)
        files = {q: dumps(scene, encoding="learned-rans", quality=q, tables=tables) for q in levels}
        decoded = {q: loads(f) for q, f in files.items()}
        zdyn = {q: len(open_scene(f).raw_section("ZDYN")) for q, f in files.items()}
        for a, b in mixes:
            mixed = loads(files[a])
            mixed.dynamic_tokens = decoded[b].dynamic_tokens
            videos = codec.SceneDecoder.open(dumps(mixed, encoding="float32"), model=net).render_many(trajs, seed=0)
            psnr = float(np.mean([quality(v, truth[n])[0] for n, v in zip(held, videos)]))
            rows[f"{a}/{b}"].append((len(files[a]) - zdyn[a] + zdyn[b], psnr))
        print(f"seed {seed} done", flush=True)
    summary = {k: {"bytes": float(np.mean([r[0] for r in v])), "psnr": float(np.mean([r[1] for r in v])),
                   "psnr_se": float(np.std([r[1] for r in v], ddof=1) / np.sqrt(len(v))) if len(v) > 1 else None}
               for k, v in rows.items()}
    for k, v in summary.items():
        print(f"static/dynamic q{k.replace('/', '/q')}: {v['bytes']:,.0f} B, held-out views {v['psnr']:.2f} dB")
    if args.out:
        args.out.write_text(json.dumps({"command": " ".join(sys.argv), "summary": summary, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
