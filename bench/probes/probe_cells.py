#!/usr/bin/env python
"""Where does a tokenizer lose a scene's detail: in the tokens, or in the renderer?

    python bench/probes/probe_cells.py RUN_DIR [--train-scenes 64] [--test-scenes 16] [--cache runs/scene_cache]

For a training checkpoint (``RUN_DIR/checkpoint``) of a model with anchored static tokens
(``locality_sigma > 0``: static token i belongs to encoder grid cell i mod P), camera 0 of each scene
is encoded, and each grid cell's content is taken as the frozen autoencoder's latent of the source
clip, averaged over the frames, inside the cell (C x p x p values; the scene's mean cell is subtracted
so that global colour does not count). Two R^2 figures, both on held-out scenes:

- ``r2_token_ridge``: a ridge map (fitted on training scenes) from the mean of the static tokens
  anchored at a cell to that cell's content: how much of its cell a token holds, linearly;
- ``r2_render``: the rendered source view, re-encoded by the autoencoder, against the same content:
  how much of it reaches the output.

A renderer that uses what the tokens hold gives ``r2_render >= r2_token_ridge``; low values of both
say the encoder does not put the cell's content in its token. Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from vt4dcodec.model.inputs.source_inputs import SourceBatch
from vt4dcodec.model.train.common import model_from_run
from vt4dcodec.model.train.data import ScenePool
from vt4dcodec.model.videotok4d import VideoTok4D


def _cells(t: torch.Tensor, g: int, p: int) -> np.ndarray:
    """(C, h, w) -> (g * g, C * p * p): the content of each encoder grid cell."""
    C = t.shape[0]
    return t.view(C, g, p, g, p).permute(1, 3, 0, 2, 4).reshape(g * g, C * p * p).numpy()


def collect(model: VideoTok4D, pool: ScenePool, scenes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per cell of each scene: (mean anchored static token, cell content, re-encoded render's cell)."""
    cfg = model.config
    p, g = cfg.patch_size, cfg.patches_per_side
    anchor = np.arange(cfg.n_static) % (g * g)
    count = np.bincount(anchor, minlength=g * g)[:, None]
    tokens, content, rendered = [], [], []
    with torch.no_grad():
        for seed in range(scenes):
            sc = pool.scene(seed)
            z_s, z_d = model.encode(SourceBatch.collate(pool.source_inputs(seed, [0])))
            truth = torch.from_numpy(sc["frames"][0]).permute(0, 3, 1, 2).float()[None] / 255.0
            K, w2c = torch.from_numpy(sc["K"][[0]]).float(), torch.from_numpy(sc["w2c"][[0]]).float()
            out = model.render(z_s, z_d, K, w2c, steps=1, seed=0, source=(K, w2c))
            cells = _cells(model.autoencoder.encode(truth)[0].mean(0), g, p)
            mean = cells.mean(0, keepdims=True)
            per_cell = np.zeros((g * g, z_s.shape[-1]))
            np.add.at(per_cell, anchor, z_s[0].numpy())
            tokens.append(per_cell / np.maximum(count, 1))
            content.append(cells - mean)
            rendered.append(_cells(model.autoencoder.encode(out)[0].mean(0), g, p) - mean)
    return np.concatenate(tokens), np.concatenate(content), np.concatenate(rendered)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path)
    parser.add_argument("--train-scenes", type=int, default=64)
    parser.add_argument("--test-scenes", type=int, default=16)
    parser.add_argument("--cache", type=Path, default=Path("runs/scene_cache"))
    parser.add_argument("--ridge", type=float, default=1e-2)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    model, state = model_from_run(args.run)
    cfg = model.config
    if not cfg.locality_sigma > 0:
        parser.error("the checkpoint's static tokens are not anchored (locality_sigma = 0): no cell to compare")

    def pool(split: str) -> ScenePool:
        return ScenePool(args.cache, 10, cfg.frames, cfg.image_size, cfg.latent_size, cfg.n_tracks, split=split)

    x_train, y_train, _ = collect(model, pool("train"), args.train_scenes)
    x_test, y_test, r_test = collect(model, pool("test"), args.test_scenes)
    a = np.c_[x_train, np.ones(len(x_train))]
    w = np.linalg.solve(a.T @ a + args.ridge * np.eye(a.shape[1]), a.T @ y_train)
    pred = np.c_[x_test, np.ones(len(x_test))] @ w
    var = float((y_test ** 2).mean())
    print(json.dumps({
        "step": int(state["step"]), "patch_size": cfg.patch_size, "cells": cfg.patches_per_side ** 2,
        "r2_token_ridge": round(1.0 - float(((pred - y_test) ** 2).mean()) / var, 3),
        "r2_render": round(1.0 - float(((r_test - y_test) ** 2).mean()) / var, 3),
        "train_scenes": args.train_scenes, "test_scenes": args.test_scenes,
    }))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
