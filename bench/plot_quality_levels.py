#!/usr/bin/env python
"""Contact sheet of a model's quality levels: what each level looks like, beside its bytes and PSNR.

    python bench/plot_quality_levels.py --model checkpoints/vt4d-tiny-2.0-rd/model --seeds 1000,1001 \
        --out docs/figures/quality_levels.png

For each held-out synthetic capture (``generate_scene(seed, split="test")``, 10 cameras): camera 0 encoded
alone and saved at every quality level (learned-rans) and at int4; its own view (first and last frame) and one
other camera rendered from the saved bytes; rows = scenes x views, columns = ground truth, int4, q1 .. qN.
Each tile is labelled with the file's bytes and the view's PSNR. Public API only.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", required=True, help="model directory or shipped id (with quality levels)")
    p.add_argument("--seeds", default="1000,1001")
    p.add_argument("--other", default="cam03", help="the novel camera rendered beside the own view")
    p.add_argument("--out", default=str(ROOT / "docs/figures/quality_levels.png"))
    args = p.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import torch

    from vt4dcodec import codec
    from vt4dcodec.format import dumps
    from vt4dcodec.media import psnr
    from vt4dcodec.synth import SynthConfig, generate_scene

    torch.set_num_threads(2)
    net = codec.load_model(args.model)
    levels = codec.quality_levels(args.model)
    if not levels:
        print(f"{args.model} has no quality levels", file=sys.stderr)
        return 2
    cfg = net.config
    rows = []
    for seed in (int(s) for s in args.seeds.split(",")):
        cap = generate_scene(seed, split="test", config=SynthConfig(num_cameras=10, num_frames=cfg.frames,
                                                                    height=cfg.image_size, width=cfg.image_size)).capture
        scenes = {cfg.feeds_back(None): codec.encode(cap, net, "int4", camera="cam00", seed=0)}
        files = {"int4": dumps(scenes[cfg.feeds_back(None)], encoding="int4")}
        for q in levels:  # each level from the tokens `vt4d encode --quality q` stores (a pass per level: feeds_back)
            if cfg.feeds_back(q) not in scenes:
                scenes[cfg.feeds_back(q)] = codec.encode(cap, net, camera="cam00", seed=0, quality=q)
            files[f"q{q}"] = dumps(scenes[cfg.feeds_back(q)], encoding="learned-rans", quality=q,
                                   tables=codec.model_tables(net))
        for view in ("cam00", args.other):
            truth = cap.frames[view][:cfg.frames]
            tiles = [("ground truth", truth, "")]
            for name, data in files.items():
                video = codec.SceneDecoder.open(data, model=net).render(cap.cameras[view][:cfg.frames], seed=0)
                tiles.append((name, video, f"{len(data):,} B, {psnr(video, truth):.1f} dB"))
            rows.append((f"seed {seed} {view}", tiles))
    T = cfg.frames
    fig, axes = plt.subplots(2 * len(rows), len(rows[0][1]), figsize=(1.3 * len(rows[0][1]), 2.7 * len(rows)),
                             dpi=110, squeeze=False)
    for r, (label, tiles) in enumerate(rows):
        for c, (name, video, text) in enumerate(tiles):
            for k, t in enumerate((0, T - 1)):
                ax = axes[2 * r + k, c]
                ax.imshow(video[t])
                ax.set_xticks([])
                ax.set_yticks([])
                if k == 0:
                    ax.set_title(f"{name}\n{text}" if text else name, fontsize=6)
            if c == 0:
                axes[2 * r, 0].set_ylabel(label, fontsize=6)
    fig.tight_layout()
    fig.savefig(args.out)
    print(f"-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
