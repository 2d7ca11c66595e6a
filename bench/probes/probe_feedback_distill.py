#!/usr/bin/env python
"""How much of encoder refinement can a one-shot map from the first render's residual reach?

For single-camera captures the shipped tokenizer's first tokens Z^0 are rendered at the source camera, and the
render feedback's inputs (model/feedback.py: each anchored static token's 3 x 3-cell window of the latent residual,
each dynamic token's residual along its track) are taken with Z^0; refinement (model/refine.py, ``--iters``
Adam steps at q``--level``) gives the target, the pre-activation change atanh(Z_ref) - atanh(Z^0). A ridge
regression from the inputs to that change is fitted on ``--fit`` training-split captures and applied once to
``--test`` held-out (test-split) captures; printed: the source view's PSNR of the stored tokens for Z^0, the
regression's one step and refinement itself.

    python bench/probes/probe_feedback_distill.py [--fit 40] [--test 12] [--iters 30] [--level 9] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from vt4dcodec import codec
from vt4dcodec.model.feedback import RenderFeedback
from vt4dcodec.model.inputs.preprocess import prepare_source
from vt4dcodec.model.inputs.source_inputs import SourceBatch
from vt4dcodec.model.refine import refine_tokens, stored_values
from vt4dcodec.synth import SynthConfig, generate_scene

BOUND = 0.999


def scene_data(net, tables, seed: int, split: str, level: int, iters: int, lr: float) -> dict:
    cfg = net.config
    cap = generate_scene(seed, split=split, config=SynthConfig(num_cameras=2, num_frames=cfg.frames,
                                                                height=cfg.image_size, width=cfg.image_size)).capture
    name = cap.camera_names[0]
    frames, traj = cap.frames[name][:cfg.frames], cap.cameras[name][:cfg.frames]
    clip = prepare_source(frames, traj, None, latent_hw=(cfg.latent_size, cfg.latent_size), num_tracks=cfg.n_tracks,
                          seed=0, motion_isolation=cfg.motion_isolation)
    batch = SourceBatch.collate([clip], views=1)
    with torch.no_grad():
        a_s, a_d = net.encode_preactivations(batch)
        z_s, z_d = torch.tanh(a_s), torch.tanh(a_d)
        x = net.latents(batch.frames)
        y0 = net.render_latents(z_s, z_d, batch.K, batch.w2c, seed=0, source=batch.source)
        residual = x - y0
        track = net._track_patches(batch, residual)[0].flatten(2)
        reader = RenderFeedback(cfg.replace(feedback_width=1))  # its inputs only: no weights are used
        f_s, f_d = reader.features(z_s, z_d, residual, track, net.renderer.token_cameras(1),
                                   net.renderer.copy_frames(1)[:, :cfg.frames])
    r_s, r_d = refine_tokens(net, z_s[0].numpy(), z_d[0].numpy(), frames[None], traj.K[None], traj.w2c[None],
                             tables=tables, quality=level, iterations=iters, lr=lr)
    n = f_s.shape[1]
    t_s = np.arctanh(np.clip(r_s[:n], -BOUND, BOUND)) - a_s[0, :n].numpy()
    t_d = np.arctanh(np.clip(r_d, -BOUND, BOUND)) - a_d[0].numpy()
    return {"f_s": f_s[0].numpy(), "f_d": f_d[0].numpy(), "t_s": t_s, "t_d": t_d, "a_s": a_s[0].numpy(),
            "a_d": a_d[0].numpy(), "frames": frames, "K": traj.K, "w2c": traj.w2c, "r_s": r_s, "r_d": r_d}


def ridge(f: np.ndarray, t: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    mu, sd = f.mean(0), f.std(0) + 1e-6
    g = (f - mu) / sd
    g1 = np.concatenate([g, np.ones((len(g), 1))], 1)
    w = np.linalg.solve(g1.T @ g1 + lam * np.eye(g1.shape[1]), g1.T @ t)
    return w, mu, sd


def apply(w, mu, sd, f):
    g = (f - mu) / sd
    return np.concatenate([g, np.ones((len(g), 1))], 1) @ w


def psnr_of(net, tables, level, z_s, z_d, d) -> float:
    with torch.no_grad():
        s = stored_values(torch.from_numpy(z_s.astype(np.float32)), tables, level - 1, "static", 1)[None]
        dd = stored_values(torch.from_numpy(z_d.astype(np.float32)), tables, level - 1, "dynamic", 1)[None]
        K = torch.from_numpy(d["K"].astype(np.float32))[None]
        w2c = torch.from_numpy(d["w2c"].astype(np.float32))[None]
        out = net.render(s, dd, K, w2c, seed=0, source=(K, w2c))[0].permute(0, 2, 3, 1).numpy()
    mse = float(np.mean((out - d["frames"] / 255.0) ** 2))
    return 10 * np.log10(1.0 / mse)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fit", type=int, default=40)
    p.add_argument("--test", type=int, default=12)
    p.add_argument("--iters", type=int, default=30)
    p.add_argument("--lr", type=float, default=0.03)
    p.add_argument("--level", type=int, default=9)
    p.add_argument("--lam", default="1,10,100,1000")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    net = codec.load_model("vt4d-tiny").eval()
    tables = codec.model_tables(net)
    fit = [scene_data(net, tables, s, "train", args.level, args.iters, args.lr) for s in range(args.fit)]
    test = [scene_data(net, tables, 1000 + s, "test", args.level, args.iters, args.lr) for s in range(args.test)]
    print(f"data: {len(fit)} fit, {len(test)} test captures", flush=True)
    F_s, T_s = np.concatenate([d["f_s"] for d in fit]), np.concatenate([d["t_s"] for d in fit])
    F_d, T_d = np.concatenate([d["f_d"] for d in fit]), np.concatenate([d["t_d"] for d in fit])
    base = [psnr_of(net, tables, args.level, np.tanh(d["a_s"]), np.tanh(d["a_d"]), d) for d in test]
    refined = [psnr_of(net, tables, args.level, d["r_s"], d["r_d"], d) for d in test]
    result = {"command": " ".join(sys.argv), "base": float(np.mean(base)), "refined": float(np.mean(refined)),
              "ridge": {}}
    print(f"source view: first tokens {np.mean(base):.3f} dB, refined {np.mean(refined):.3f} dB", flush=True)
    for lam in (float(v) for v in args.lam.split(",")):
        w_s, mu_s, sd_s = ridge(F_s, T_s, lam)
        w_d, mu_d, sd_d = ridge(F_d, T_d, lam)
        got = []
        r2 = []
        for d in test:
            p_s, p_d = apply(w_s, mu_s, sd_s, d["f_s"]), apply(w_d, mu_d, sd_d, d["f_d"])
            r2.append(1 - np.mean((p_s - d["t_s"]) ** 2) / np.mean((d["t_s"] - d["t_s"].mean(0)) ** 2))
            a_s = d["a_s"].copy()
            a_s[:len(p_s)] += p_s
            got.append(psnr_of(net, tables, args.level, np.tanh(a_s), np.tanh(d["a_d"] + p_d), d))
        gain = np.array(got) - np.array(base)
        result["ridge"][str(lam)] = {"psnr": float(np.mean(got)), "gain": float(gain.mean()),
                                     "gain_se": float(gain.std(ddof=1) / np.sqrt(len(gain))), "r2_static": float(np.mean(r2))}
        print(f"ridge lambda {lam:g}: {np.mean(got):.3f} dB, gain {gain.mean():+.3f} +- "
              f"{gain.std(ddof=1) / np.sqrt(len(gain)):.3f}, static R^2 {np.mean(r2):.3f}", flush=True)
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
