#!/usr/bin/env python
"""Can a small token refiner trained through the frozen renderer win back the coarse levels' PSNR (and their
stripes)? The refiner maps each stored token (its 32 bin centres and the level, one-hot) to a correction
added to it (an MLP per token matrix, last layer zero at the start, so it starts at the bin centres); it is
trained with the pixel MSE of one-step renders of a capture's encoded cameras against their frames, on
training captures encoded with all 10 cameras, levels q1..q5 drawn at random; the networks stay frozen.

    python bench/probes/probe_refiner.py [--train 80] [--minutes 30] [--test 12] [--out runs/refiner.pt]

Prints, per level, the held-out captures' PSNR over their 10 cameras from bin centres and refined tokens
(paired difference +- standard error), and writes a picture (docs/figures/refiner_probe.png: truth, bin
centres, refined, for one camera of the first test capture at q1 and q3).  No file format change: a refiner
would run after decoding, before the renderer.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from vt4dcodec import codec  # noqa: E402
from vt4dcodec.format.learned import dequantize, writer_codes  # noqa: E402
from vt4dcodec.synth import generate_scene  # noqa: E402

LEVELS = 5


class Refiner(torch.nn.Module):
    def __init__(self, d: int, hidden: int = 128) -> None:
        super().__init__()
        self.nets = torch.nn.ModuleDict({w: torch.nn.Sequential(
            torch.nn.Linear(d + LEVELS, hidden), torch.nn.GELU(), torch.nn.Linear(hidden, hidden), torch.nn.GELU(),
            torch.nn.Linear(hidden, d)) for w in ("static", "dynamic")})
        for net in self.nets.values():
            torch.nn.init.zeros_(net[-1].weight)
            torch.nn.init.zeros_(net[-1].bias)

    def forward(self, deq: torch.Tensor, level: int, which: str) -> torch.Tensor:
        onehot = torch.zeros(*deq.shape[:-1], LEVELS)
        onehot[..., level] = 1.0
        return deq + self.nets[which](torch.cat([deq, onehot], dim=-1))


def one_step(net, z_s, z_d, K, w2c, source):  # VideoTok4D.render with 1 step, gradients kept
    cfg = net.config
    T = K.shape[1]
    B = K.shape[0]
    g = torch.Generator(device="cpu").manual_seed(0)
    y = torch.randn((1, T, cfg.latent_channels, cfg.latent_size, cfg.latent_size), generator=g).expand(B, -1, -1, -1, -1)
    rays = net.rays(K, w2c)
    cams = net.render_cameras(K, w2c, tuple(t.expand(B, *t.shape[1:]) for t in source))
    v = net.velocity(y.contiguous(), z_s.expand(B, -1, -1), z_d.expand(B, -1, -1), rays, torch.ones(B), cameras=cams)
    frames = torch.cat([net.autoencoder.decode(item) for item in (y - v).split(1)])
    return frames.clamp(0.0, 1.0)


def prepared(net, tables, seed: int, split: str) -> dict:
    capture = generate_scene(seed, split=split).capture
    scene = codec.encode(capture, net, cameras="all", encoding="float32")
    names = list(capture.camera_names)
    K = torch.from_numpy(np.stack([capture.cameras[n].K[:8] for n in names]).astype(np.float32))
    w2c = torch.from_numpy(np.stack([capture.cameras[n].w2c[:8] for n in names]).astype(np.float32))
    truth = torch.from_numpy(np.stack([capture.frames[n][:8] for n in names])).permute(0, 1, 4, 2, 3).float() / 255
    views = len(names)
    deq = {}
    for level in range(LEVELS):
        for which, tok in (("static", scene.static_tokens), ("dynamic", scene.dynamic_tokens)):
            deq[level, which] = torch.from_numpy(dequantize(writer_codes(tok, tables, level, which, views), tables,
                                                            level, which).astype(np.float32))
    return {"K": K, "w2c": w2c, "truth": truth, "deq": deq, "source": (K[None], w2c[None])}


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(10 * torch.log10(1.0 / ((a - b) ** 2).mean().clamp_min(1e-12)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--train", type=int, default=80)
    ap.add_argument("--test", type=int, default=12)
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--views", type=int, default=3, help="cameras rendered per training step")
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--out", type=Path, default=Path("runs/refiner.pt"))
    ap.add_argument("--figure", type=Path, default=Path("docs/figures/refiner_probe.png"))
    args = ap.parse_args()
    torch.manual_seed(0)
    net = codec.load_model("vt4d-tiny")
    net.requires_grad_(False)
    tables = codec.model_tables(net)
    t0 = time.time()
    train = [prepared(net, tables, seed, "train") for seed in range(args.train)]
    print(f"{len(train)} training captures encoded in {time.time() - t0:.0f} s", flush=True)
    refiner = Refiner(net.config.token_dim)
    opt = torch.optim.Adam(refiner.parameters(), lr=args.lr)
    rng = np.random.default_rng(0)
    t0, step, losses = time.time(), 0, []
    while time.time() - t0 < 60 * args.minutes:
        item = train[rng.integers(len(train))]
        level = int(rng.integers(LEVELS))
        pick = torch.from_numpy(rng.choice(len(item["K"]), args.views, replace=False))
        z_s = refiner(item["deq"][level, "static"], level, "static")[None]
        z_d = refiner(item["deq"][level, "dynamic"], level, "dynamic")[None]
        frames = one_step(net, z_s, z_d, item["K"][pick], item["w2c"][pick], item["source"])
        loss = ((frames - item["truth"][pick]) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss))
        step += 1
        if step % 100 == 0:
            print(f"step {step} ({time.time() - t0:.0f} s): loss {np.mean(losses[-100:]):.5f}", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(refiner.state_dict(), args.out)
    gains: dict[int, list[float]] = {lv: [] for lv in (0, 2, 4)}
    base: dict[int, list[float]] = {lv: [] for lv in (0, 2, 4)}
    pictures = []
    with torch.no_grad():
        for i, seed in enumerate(range(1000, 1000 + args.test)):
            item = prepared(net, tables, seed, "test")
            for level in gains:
                scores = []
                for refine in (False, True):
                    z = {w: (refiner(item["deq"][level, w], level, w) if refine else item["deq"][level, w])[None]
                         for w in ("static", "dynamic")}
                    frames = torch.cat([one_step(net, z["static"], z["dynamic"], item["K"][j:j + 1],
                                                 item["w2c"][j:j + 1], item["source"]) for j in range(len(item["K"]))])
                    scores.append(np.mean([psnr(f, t) for f, t in zip(frames, item["truth"])]))
                    if i == 0 and level in (0, 2):
                        pictures.append(frames[0, 4])
                base[level].append(scores[0])
                gains[level].append(scores[1] - scores[0])
            if i == 0:
                pictures.insert(0, item["truth"][0, 4])
            print(f"seed {seed}: " + ", ".join(f"q{lv + 1} {base[lv][-1]:.2f} {gains[lv][-1]:+.2f}" for lv in gains),
                  flush=True)
    for level in gains:
        g = np.array(gains[level])
        print(f"q{level + 1}: bin centres {np.mean(base[level]):.2f} dB, refined {np.mean(g):+.3f} +- "
              f"{g.std(ddof=1) / np.sqrt(len(g)):.3f} dB ({len(g)} captures; {step} steps)")
    import cv2

    row = np.concatenate([(p.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8) for p in pictures], axis=1)
    args.figure.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.figure), cv2.resize(row[:, :, ::-1], None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST),
                [cv2.IMWRITE_PNG_COMPRESSION, 9])


if __name__ == "__main__":
    main()
