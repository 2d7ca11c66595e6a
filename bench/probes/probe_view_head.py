"""Can a light per-view network on the token splat stand in for the renderer's space-time blocks?

The renderer's per-view cost is its four space-time blocks (attention over a view's 512 latent patches and
cross-attention to the tokens) on top of the token splat and the frozen decoder (docs/benchmarks/render_batch.md):
batching cannot share it. A renderer whose per-view part is the splat, a small convolutional head and the
decoder would render a view several times cheaper. This probe asks whether such a head can reach the blocks'
quality, before any renderer is built: the shipped model encodes synthetic captures (camera 0 alone, or cameras
0, 2, 4, 6, 8 together, stored at ``--quality``), each of the ten cameras is rendered by the shipped renderer
(one step, as the codec decodes) while hooks keep what it worked from -- the splat (the x0 estimate before the
blocks' correction), the target's rays and the scene's tokens -- and a head (2-D convolutions per frame with a
temporal convolution between them, FiLM from the tokens' mean) is trained for ``--minutes`` to predict the
target frames' latents from them (``x0 = splat + head``; latent MSE, as the renderer's own x0 loss). On held-out
test captures it reports the decoded PSNR of the shipped render, the splat alone and splat + head per target set,
paired per video, and each part's time per view (one thread).

``python bench/probes/probe_view_head.py --train 300 --test 50 --minutes 40 --out bench/results/view_head.json``
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from vt4dcodec import codec
from vt4dcodec.eval.protocol import nearest_cameras
from vt4dcodec.format import dumps
from vt4dcodec.media import psnr
from vt4dcodec.model.layers import unpatchify
from vt4dcodec.model.weights_io import from_pretrained
from vt4dcodec.model.directories import model_directory
from vt4dcodec.synth import SynthConfig, generate_scene

MULTI = (0, 2, 4, 6, 8)


class ViewHead(nn.Module):
    """[splat latent (C), rays (6)] per frame -> a latent correction (C): ``layers`` 3x3 convolutions of
    ``width`` channels (one stride-2 stage in the middle), a kernel-3 temporal convolution after each, FiLM of
    every layer from the mean of the scene's tokens; the output layer starts at zero (x0 = the splat)."""

    def __init__(self, channels: int, token_dim: int, width: int = 48, layers: int = 4, tokens: int = 0) -> None:
        super().__init__()
        self.attend: nn.MultiheadAttention | None = None
        if tokens:  # one cross-attention to the tokens at the coarse stage (each token slot with its own embedding)
            self.token_in = nn.Linear(token_dim, width)
            self.slots = nn.Parameter(torch.randn(tokens, width) * 0.02)
            self.attend = nn.MultiheadAttention(width, 4, batch_first=True)
            self.attend_norm = nn.LayerNorm(width)
        self.inp = nn.Conv2d(channels + 6, width, 3, padding=1)
        self.space = nn.ModuleList(nn.Conv2d(width, width, 3, padding=1) for _ in range(layers))
        self.time = nn.ModuleList(nn.Conv1d(width, width, 3, padding=1, groups=width) for _ in range(layers))
        self.down = nn.Conv2d(width, width, 3, stride=2, padding=1)
        self.film = nn.Linear(2 * token_dim, 2 * width * layers)
        self.out = nn.Conv2d(width, channels, 3, padding=1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)
        nn.init.zeros_(self.film.weight)
        nn.init.zeros_(self.film.bias)
        self.layers = layers

    def forward(self, splat: torch.Tensor, rays: torch.Tensor, code: torch.Tensor,
                tokens: torch.Tensor | None = None) -> torch.Tensor:
        """splat (B, T, C, h, w), rays (B, T, 6, h, w), code (B, 2 d), tokens (B, N, d) -> correction (B, T, C, h, w)."""
        B, T, C, h, w = splat.shape
        x = F.gelu(self.inp(torch.cat([splat, rays], 2).flatten(0, 1)))
        film = self.film(code).view(B, self.layers, 2, -1)
        half = self.layers // 2
        skip = x
        for k, (space, mix) in enumerate(zip(self.space, self.time)):
            if k == half:
                skip, x = x, self.down(x)
                if self.attend is not None and tokens is not None:
                    hh, ww = x.shape[-2:]
                    q = x.view(B, T, -1, hh * ww).permute(0, 1, 3, 2).reshape(B, T * hh * ww, -1)
                    keys = self.token_in(tokens) + self.slots[None]
                    a = self.attend(self.attend_norm(q), keys, keys, need_weights=False)[0]
                    x = x + a.view(B, T, hh * ww, -1).permute(0, 1, 3, 2).reshape(B * T, -1, hh, ww)
            if k == self.layers - 1 and half:
                x = F.interpolate(x, size=(h, w), mode="nearest") + skip
            x = space(x)
            hh, ww = x.shape[-2:]
            y = x.view(B, T, -1, hh, ww).permute(0, 3, 4, 2, 1).reshape(-1, x.shape[1], T)
            x = x + mix(y).view(B, hh, ww, -1, T).permute(0, 4, 3, 1, 2).reshape(B * T, -1, hh, ww)
            scale, shift = film[:, k, 0], film[:, k, 1]
            x = F.gelu(x.view(B, T, -1, hh, ww) * (1 + scale[:, None, :, None, None])
                       + shift[:, None, :, None, None]).flatten(0, 1)
        return self.out(x).view(B, T, C, h, w)


def collect(net: torch.nn.Module, seeds: list[int], split: str, quality: int) -> list[dict]:
    """For each capture and encode setting: every camera's render inputs, the shipped renderer's output and the
    ground-truth latents."""
    cfg = net.config
    renderer = net.renderer
    seen: dict[str, list[torch.Tensor]] = {}  # render_many renders in chunks: each forward appends

    def on_splat(module: nn.Module, args: tuple[torch.Tensor, ...]) -> None:
        seen.setdefault("splat", []).append(args[0].detach())

    def on_render(module: nn.Module, args: tuple, kwargs: dict, output: torch.Tensor) -> None:
        for key, value in (("rays", args[3]), ("z_s", args[1]), ("z_d", args[2]), ("out", output.detach())):
            seen.setdefault(key, []).append(value)

    hooks = [renderer.splat_in.register_forward_pre_hook(on_splat),
             renderer.register_forward_hook(on_render, with_kwargs=True)]
    items = []
    p, C, h = cfg.renderer_patch, cfg.latent_channels, cfg.latent_size
    try:
        for seed in seeds:
            capture = generate_scene(seed, split=split, config=SynthConfig(num_cameras=10, num_frames=cfg.frames,
                                                                          height=cfg.image_size,
                                                                          width=cfg.image_size)).capture
            names = list(capture.camera_names)
            with torch.no_grad():
                gt = net.latents(torch.from_numpy(np.stack([capture.frames[n] for n in names])).permute(
                    0, 1, 4, 2, 3).float() / 255.0)
            for setting, encoded in (("single", [names[0]]), ("multi", [names[i] for i in MULTI])):
                scene = codec.encode(capture, net, "int8", cameras=encoded, quality=quality, runtime="torch")
                decoder = codec.SceneDecoder.open(dumps(scene), model=net, runtime="torch")  # the stored values
                seen.clear()
                frames = decoder.render_many([capture.cameras[n] for n in names])
                got = {key: torch.cat(values) for key, values in seen.items()}
                splat = unpatchify(got["splat"].float(), p, C, h, h)
                code = torch.cat([got["z_s"].mean(1), got["z_d"].mean(1)], -1)
                tokens = torch.cat([got["z_s"], got["z_d"]], 1).float()
                near = [n for n, _ in nearest_cameras(capture, names[0], 2)]
                roles = []
                for n in names:
                    if setting == "single":
                        roles.append("source" if n == names[0] else "near" if n in near else "other")
                    else:
                        roles.append("multi-enc" if n in encoded else "multi-held")
                items.append({"seed": seed, "setting": setting, "splat": splat, "rays": got["rays"].float(),
                              "code": code.float(), "tokens": tokens, "shipped": got["out"].float(), "gt": gt,
                              "truth": np.stack([capture.frames[n] for n in names]), "shipped_frames": frames,
                              "roles": roles})
    finally:
        for hook in hooks:
            hook.remove()
    return items


def decode(net: torch.nn.Module, latents: torch.Tensor) -> list[np.ndarray]:
    with torch.no_grad():
        frames = torch.cat([net.autoencoder.decode(item) for item in latents.split(1)]).float().clamp(0, 1)
    return list((frames.permute(0, 1, 3, 4, 2).numpy() * 255.0).round().astype(np.uint8))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", default="vt4d-tiny")
    parser.add_argument("--train", type=int, default=300, help="training captures (split train, seeds 0..)")
    parser.add_argument("--test", type=int, default=50, help="held-out captures (split test, seeds 1000..)")
    parser.add_argument("--quality", type=int, default=9)
    parser.add_argument("--minutes", type=float, default=40.0)
    parser.add_argument("--width", type=int, default=48)
    parser.add_argument("--layers", type=int, default=4)
    parser.add_argument("--attend", type=int, default=1, help="1: one cross-attention to the tokens at the coarse stage")
    parser.add_argument("--batch", type=int, default=8, help="views a step")
    parser.add_argument("--lr", type=float, default=2e-3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    net = from_pretrained(model_directory(args.model)).eval()
    t0 = time.time()
    train = collect(net, list(range(args.train)), "train", args.quality)
    test = collect(net, list(range(1000, 1000 + args.test)), "test", args.quality)
    print(f"collected {len(train)} + {len(test)} encodes in {time.time() - t0:.0f} s", flush=True)
    cat = {k: torch.cat([item[k] for item in train]) for k in ("splat", "rays", "code", "gt", "tokens")}
    views = cat["splat"].shape[0]
    head = ViewHead(net.config.latent_channels, net.config.token_dim, args.width, args.layers,
                    cat["tokens"].shape[1] if args.attend else 0)
    opt = torch.optim.AdamW(head.parameters(), lr=args.lr, weight_decay=1e-4)
    budget = args.minutes * 60.0
    start, step, log = time.time(), 0, []
    while time.time() - start < budget:
        frac = (time.time() - start) / budget
        for group in opt.param_groups:
            group["lr"] = args.lr * 0.5 * (1 + math.cos(math.pi * min(frac, 1.0)))
        idx = torch.randint(0, views, (args.batch,))
        pred = cat["splat"][idx] + head(cat["splat"][idx], cat["rays"][idx], cat["code"][idx], cat["tokens"][idx])
        loss = F.mse_loss(pred, cat["gt"][idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        if step % 200 == 0:
            log.append({"step": step, "seconds": round(time.time() - start, 1), "loss": loss.item()})
            print(log[-1], flush=True)
    head.eval()
    rows: dict[str, dict[str, list[float]]] = {}
    for item in test:
        with torch.no_grad():
            student = item["splat"] + head(item["splat"], item["rays"], item["code"], item["tokens"])
        got = {"shipped": item["shipped_frames"], "splat": decode(net, item["splat"]), "head": decode(net, student)}
        for k, role in enumerate(item["roles"]):
            row = rows.setdefault(role, {m: [] for m in got})
            for method, videos in got.items():
                row[method].append(psnr(videos[k], item["truth"][k]))
    summary = {}
    for role, row in rows.items():
        a = {m: np.asarray(v) for m, v in row.items()}
        d = a["head"] - a["shipped"]
        summary[role] = {"videos": len(d), **{m: round(float(v.mean()), 3) for m, v in a.items()},
                         "head_minus_shipped": round(float(d.mean()), 3),
                         "se": round(float(d.std(ddof=1) / math.sqrt(len(d))), 3)}
        print(role, summary[role], flush=True)
    # time per view, one thread, a view at a time
    torch.set_num_threads(1)
    item = test[0]
    with torch.no_grad():
        x = (item["splat"][:1], item["rays"][:1], item["code"][:1], item["tokens"][:1])
        for _ in range(3):
            head(*x)
        t = time.perf_counter()
        for _ in range(20):
            head(*x)
        head_ms = (time.perf_counter() - t) / 20 * 1000
    report = {"args": {k: str(v) for k, v in vars(args).items()}, "steps": step, "log": log, "sets": summary,
              "head_parameters": sum(p.numel() for p in head.parameters()), "head_ms_per_view_1_thread": head_ms}
    print(json.dumps({k: v for k, v in report.items() if k != "log"}, indent=2))
    if args.out:
        args.out.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
