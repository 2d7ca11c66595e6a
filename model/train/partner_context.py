"""Give a context-coded rate-distortion tokenizer partner channels: each MEAN value is also coded given the sign
of its own token's code in an earlier channel that moves with it, and fit the MEAN densities to that.

    python -m vt4dcodec.model.train.partner_context --model runs/rd8q-dz-model --captures runs/partner_scenes \
        --out runs/rd8q-pc-model --version 2.0.0-dev.q593pc

The tokens of the training captures in ``--captures`` (capture directories; ``vt4d synth --split train``) are
encoded with 1, 4, 5 and 10 cameras (``--views``). From their codes at the ``--select-level`` levels each
channel gets the earlier channel whose code sign, beside the previous MEAN token's, leaves the fewest bits of
its codes (plug-in conditional entropy), or none when no channel saves ``--min-gain`` bits a value
(``config.entropy_partners``). The six new density classes start as copies of the MEAN family's
(``model.entropy``), then the MEAN-family densities alone (MEAN, MEAN_AFTER_*, MEAN_PARTNER_*) are fitted to
the noisy tokens at every level (the calibration loss, steps fixed); CHANGE and DYNAMIC densities, the steps,
the encoder and the renderer are the model's, so every decoded picture is unchanged and only the bytes move.
The model is written with its integer tables frozen again (:meth:`VideoTok4D.update_entropy`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from vt4dcodec.capture.io import MANIFEST_NAME
from vt4dcodec.errors import ModelError

from ..entropy import MEAN, MEAN_AFTER_NEGATIVE, MEAN_AFTER_POSITIVE, MEAN_PARTNER_NEGATIVE
from ..videotok4d import VideoTok4D
from ..weights_io import from_pretrained, save_pretrained
from .add_levels import _rebuilt, _trained_state

__all__ = ["choose_partners", "add_partner_context", "fit_mean_densities", "main"]

MEAN_FAMILY = (MEAN, MEAN_AFTER_NEGATIVE, MEAN_AFTER_POSITIVE) + tuple(range(MEAN_PARTNER_NEGATIVE, 11))


def _entropy_bits(keys: np.ndarray, values: np.ndarray) -> float:
    """Plug-in conditional entropy, bits in all, of ``values`` given ``keys`` (both int64, one per sample)."""
    joint = keys * 1024 + values
    _, joint_counts = np.unique(joint, return_counts=True)
    _, key_counts = np.unique(keys, return_counts=True)
    return float(-(joint_counts * np.log2(joint_counts)).sum() + (key_counts * np.log2(key_counts)).sum())


def choose_partners(codes: list[np.ndarray], previous: list[np.ndarray], min_gain: float = 0.01) -> tuple[int, ...]:
    """Each channel's partner from MEAN-token codes: ``codes`` (N, d) int arrays (one per token set and level,
    MEAN tokens only), ``previous`` the matching (N, d) signs of the previous MEAN token's codes (0 where none).
    Channel c's partner is the earlier channel whose code sign, beside ``previous``, minimises the conditional
    entropy of channel c's codes, if that saves at least ``min_gain`` bits a value; else -1."""
    q = np.concatenate(codes).astype(np.int64)
    prev = np.concatenate(previous).astype(np.int64) + 1
    n, d = q.shape
    partners = [-1]
    for c in range(1, d):
        base = _entropy_bits(prev[:, c], q[:, c] + 512)
        gains = [base - _entropy_bits(prev[:, c] * 3 + np.sign(q[:, p]) + 1, q[:, c] + 512) for p in range(c)]
        best = int(np.argmax(gains))
        partners.append(best if gains[best] / n >= min_gain else -1)
    return tuple(partners)


def add_partner_context(model: VideoTok4D, partners: tuple[int, ...]) -> VideoTok4D:
    """A copy of a context-coded ``model`` with ``partners`` (``config.entropy_partners``): the six new classes'
    densities copies of the MEAN family's of the same previous-token sign, so it codes as before until fitted."""
    if model.entropy is None or not model.config.entropy_context:
        raise ModelError("partner channels need an entropy model with context-coded MEAN tokens "
                         "(config entropy_context = true)")
    if model.config.entropy_partners:
        raise ModelError("the model already has partner channels (config entropy_partners)")
    state = _trained_state(model)
    logits = state["entropy.logits"]
    by_sign = [logits[MEAN_AFTER_NEGATIVE], logits[MEAN], logits[MEAN_AFTER_POSITIVE]]
    state["entropy.logits"] = torch.cat([logits, torch.stack(by_sign + by_sign)])
    return _rebuilt(model, dataclasses.replace(model.config, entropy_partners=tuple(partners)), state)


def fit_mean_densities(model: VideoTok4D, samples: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]],
                       iterations: int, lr: float = 0.02, seed: int = 0) -> dict[str, float]:
    """Fit the MEAN-family density logits alone (the others are kept bit for bit) to ``samples`` (z_s (1, N_s, d),
    z_d (1, N_d, d), origin (N_s,)) at random levels; returns the mean bits a value before and after."""
    entropy = model.entropy
    assert entropy is not None
    keep = entropy.logits.detach().clone()
    family = torch.zeros(entropy.classes, 1, 1, dtype=torch.bool)
    family[list(MEAN_FAMILY)] = True
    opt = torch.optim.Adam([entropy.logits], lr=lr)
    gen = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)

    def mean_bits() -> float:
        with torch.no_grad():
            return float(np.mean([float(entropy.density_loss(zs, zd, o)) for zs, zd, o in samples]))

    before = mean_bits()
    for _ in range(iterations):
        k = int(torch.randint(len(samples), (), generator=gen))
        zs, zd, origin = samples[k]
        loss = entropy.density_loss(zs, zd, origin, level=int(torch.randint(entropy.levels, (), generator=gen)))
        opt.zero_grad()
        loss.backward()
        entropy.logits.grad = torch.where(family, entropy.logits.grad, torch.zeros_like(entropy.logits.grad))
        opt.step()
        with torch.no_grad():
            entropy.logits.copy_(torch.where(family, entropy.logits, keep))
    entropy.log_step.grad = None
    entropy.logits.grad = None
    return {"bits_per_value_before": before, "bits_per_value_after": mean_bits()}


def _token_sets(model: VideoTok4D, captures: list[Path], views: list[int]
                ) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    """(z_s (1, N_s, d), z_d (1, N_d, d), origin (N_s,)) of each capture encoded with its first ``v`` cameras for
    each ``v`` in ``views``; the captures must have the model's frame count and image size (synthetic ones)."""
    from vt4dcodec.capture import read_capture

    from ..inputs.preprocess import prepare_source
    from ..inputs.source_inputs import SourceBatch

    cfg = model.config
    out = []
    for directory in captures:
        capture = read_capture(directory)
        names = capture.camera_names
        clips = []
        for name in names[:max(views)]:
            frames = capture.frames[name][:cfg.frames]
            if frames.shape[:3] != (cfg.frames, cfg.image_size, cfg.image_size):
                raise ModelError(f"{directory}: camera {name} has frames {frames.shape[:3]}, the model takes "
                                 f"({cfg.frames}, {cfg.image_size}, {cfg.image_size})")
            depth = capture.depth[name][:cfg.frames] if capture.has_depth(name) else None
            clips.append(prepare_source(frames, capture.cameras[name][:cfg.frames], depth,
                                        latent_hw=(cfg.latent_size, cfg.latent_size), num_tracks=cfg.n_tracks,
                                        seed=0, motion_isolation=cfg.motion_isolation))
        for v in views:
            if v > len(clips):
                raise ModelError(f"{directory} has {len(clips)} cameras, fewer than --views {v}")
            with torch.no_grad():
                z_s, z_d = model.encode(SourceBatch.collate(clips[:v], views=v))
            out.append((z_s.float(), z_d.float(), model.static_origins(v)))
    return out


def _mean_codes(model: VideoTok4D, samples, levels: list[int]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Codes and previous-MEAN signs of the MEAN tokens of every sample at ``levels`` (round to nearest)."""
    entropy = model.entropy
    assert entropy is not None
    codes, previous = [], []
    for zs, _, origin in samples:
        prev = entropy.previous_mean(origin)
        mean = (origin == torch.arange(len(origin))).numpy()
        for level in levels:
            q = torch.round(zs[0] / entropy.step(level)[0].detach()).numpy().astype(np.int64)
            p = np.where((prev >= 0).numpy()[:, None], np.sign(q[prev.clamp(min=0).numpy()]), 0)
            codes.append(q[mean])
            previous.append(p[mean])
    return codes, previous


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", type=Path, required=True, help="a saved model directory (context-coded MEAN tokens)")
    p.add_argument("--captures", type=Path, required=True, help="directory of training capture directories")
    p.add_argument("--out", type=Path, required=True, help="directory of the model to write")
    p.add_argument("--views", default="1,4,5,10", help="camera counts each capture is encoded with")
    p.add_argument("--select-level", default=None,
                   help="comma-separated level indices whose codes choose the partners (default: the four coarsest)")
    p.add_argument("--min-gain", type=float, default=0.01, help="bits a value a partner must save")
    p.add_argument("--iterations", type=int, default=1500, help="Adam steps of the density fit")
    p.add_argument("--lr", type=float, default=0.02, help="learning rate of the density fit")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--id", default="vt4d-tiny", help="model id recorded in the written model")
    p.add_argument("--version", required=True, help="model version recorded in the written model")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    try:
        views = [int(v) for v in args.views.split(",")]
        levels = None if args.select_level is None else [int(v) for v in args.select_level.split(",")]
    except ValueError:
        p.error("--views and --select-level take comma-separated integers")
    if not views or any(not 1 <= v <= 64 for v in views):
        p.error(f"--views: camera counts lie in 1..64, got {args.views}")
    if not args.captures.is_dir():
        p.error(f"--captures: {args.captures} is not a directory")
    captures = sorted(d for d in args.captures.iterdir() if (d / MANIFEST_NAME).is_file())
    if not captures:
        p.error(f"--captures: no capture directories in {args.captures}")
    t0 = time.time()
    try:
        model = from_pretrained(args.model)
        count = model.config.entropy_levels
        levels = list(range(min(4, count))) if levels is None else levels
        if not levels or any(not 0 <= v < count for v in levels):
            p.error(f"--select-level: level indices of the model lie in 0..{count - 1}, got {args.select_level}")
        samples = _token_sets(model, captures, views)
        codes, previous = _mean_codes(model, samples, levels)
        partners = choose_partners(codes, previous, args.min_gain)
        out = add_partner_context(model, partners)
        out.train()
        fit = fit_mean_densities(out, samples, args.iterations, args.lr)
        out.eval()
        out.update_entropy()
    except ModelError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    save_pretrained(out, args.out, model_id=args.id, model_version=args.version)
    report = {"partners": list(partners), "captures": len(captures), "views": views, "token_sets": len(samples),
              **fit, "wall_s": round(time.time() - t0, 1)}
    (args.out / "partner_context.json").write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
