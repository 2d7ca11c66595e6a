"""Table 3: track decoding from frozen tokens (the paper's track probe, at this project's scale).

Light track decoders, identical but for the tokens they read, are trained on frozen tokens of a tokenizer
(Z_s only, Z_d only, both, and as a reference none: the query and camera alone) to predict the 2-D track
of a query pixel through the whole clip, supervised by the synthetic generator's exact tracks
(:func:`vt4dcodec.synth.true_tracks`).  The paper's claim: Z_s decodes static tracks better, Z_d dynamic
ones, both together best.

    python -m vt4dcodec.eval.track_probe --train-scenes 192 --test-scenes 32 --steps 3000 --threads 1 \
        --out docs/results/table3_tracks.json --figure docs/figures/table3_tracks.png

Protocol (docs/tracks.md):

* Tokens: every camera of a scene is encoded on its own, exactly as ``model.train.tokenize_scenes`` does
  (:class:`ScenePool` caches, one batch per scene); they are computed once and cached under
  ``--cache`` keyed by the tokenizer's fingerprint.  The generator's ground truth for the same scenes is
  regenerated, and its frames are checked to be the cached ones bit for bit.
* Queries: per camera, ``--queries`` static pixels (background: the room) and as many dynamic pixels (on
  a moving object, ``dynamic_mask``; fewer where the object covers fewer pixels), each at a random frame
  t0.  The static set is the background queries, the dynamic set the object queries, the mixed set both
  together (half and half where the camera sees enough of the objects).  Training samples the mixed pool
  (train-split scenes); evaluation uses test-split scenes (disjoint assets).
* Decoder: the query (u0, v0) as Fourier features, t0 one-hot, its ray at t0 and the camera trajectory
  (every frame's w2c, its pose relative to t0 and the focal lengths) embedded as one query vector; two
  cross-attention blocks over [a learned null token; the chosen token streams, each with a learned type
  embedding]; an MLP head gives the displacement from (u0, v0) at every frame (zero at t0).  Huber loss
  (1 px) on the frames where the true track is visible, t0 excluded.  Same architecture, seed, batches and
  steps for every decoder.
* Metric: end-point error in pixels of the 64 x 64 images on visible frames other than t0; per test scene
  the mean over its (query, frame) pairs, then mean +- standard error over scenes; paired differences
  between decoders on the same queries, per scene.  "No motion" (predict (u0, v0)) is the trivial
  baseline.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from vt4dcodec.errors import Vt4dError
from vt4dcodec.synth import SynthConfig, generate_scene
from vt4dcodec.synth.tracks import setup_of, surface_ids, true_tracks

from .metrics import mean_se, round_metric
from .protocol import EvaluationError

__all__ = ["DECODERS", "TRACK_SETS", "ProbeSettings", "TrackData", "TrackProbe", "build_records", "load_data",
           "train_probe", "predict", "evaluate", "summarize", "orderings", "format_table", "format_orderings",
           "save_figure", "run", "main"]

DECODERS = ("static", "dynamic", "both", "none")     # which token streams a decoder reads
DECODER_LABELS = {"static": "Z_s", "dynamic": "Z_d", "both": "Z_s + Z_d", "none": "no tokens", "still": "no motion"}
TRACK_SETS = ("static", "dynamic", "mixed")
KIND_STATIC, KIND_DYNAMIC, KIND_PAD = 0, 1, -1
DISPLACEMENT_SCALE = 4.0    # pixels: the head's output unit
HUBER_DELTA = 1.0           # pixels
RECORD_VERSION = 1          # bump when the cached records change meaning


@dataclass(frozen=True)
class ProbeSettings:
    """What one Table 3 run measures (everything that changes a number is here and in the results file).

    Attributes:
        train_scenes, test_scenes: scene seeds 0..n-1 of the train and test split.
        cameras: cameras per scene (every one is encoded on its own; 10 reuses runs/scene_cache*).
        queries: static queries per camera, and at most as many dynamic ones.
        steps, batch_sets, queries_per_set: optimiser steps; token sets per batch and queries per set.
        width, heads, blocks, fourier: the decoder (query/token width, attention heads, cross-attention
            blocks, Fourier frequencies of (u0, v0)).
        lr, weight_decay: AdamW (linear warm-up over 5 % of the steps, cosine decay to 10 %).
        seed: decoder initialisation, batch order and query sampling.
    """

    train_scenes: int = 192
    test_scenes: int = 32
    cameras: int = 10
    queries: int = 32
    steps: int = 3000
    batch_sets: int = 16
    queries_per_set: int = 32
    width: int = 128
    heads: int = 4
    blocks: int = 2
    fourier: int = 8
    lr: float = 1e-3
    weight_decay: float = 0.01
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("train_scenes", "test_scenes", "cameras", "queries", "steps", "batch_sets",
                     "queries_per_set", "width", "heads", "blocks", "fourier"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise EvaluationError(f"{name} must be a positive integer, got {v!r}")
        if self.width % self.heads:
            raise EvaluationError(f"width {self.width} must be a multiple of heads {self.heads}")
        if not (self.lr > 0 and math.isfinite(self.lr)) or not (self.weight_decay >= 0):
            raise EvaluationError("lr must be positive and weight_decay non-negative")


# --- data ---------------------------------------------------------------------------------------------
@dataclass
class TrackData:
    """Frozen tokens and true tracks of S token sets (one per scene camera), P query slots each.

    Attributes:
        z_s: (S, N_s, d) float32 static tokens; z_d: (S, N_d, d) float32 dynamic tokens.
        K: (S, T, 3, 3) float32 intrinsics (pixels); w2c: (S, T, 4, 4) float32 world-to-camera (metres).
        queries: (S, P, 3) int64 (u0, v0, t0); kind: (S, P) int8, 0 static, 1 dynamic, -1 empty slot
            (valid slots come first).
        xy: (S, P, T, 2) float32 true positions (pixels); visible: (S, P, T) bool.
        scene: (S,) int64 scene seed of each set; camera: (S,) int64 camera index.
        image_size: H = W of the clips, pixels.
        frames: (S, T, H, W, 3) uint8 or None: the clips (kept for the figure only).
    """

    z_s: np.ndarray
    z_d: np.ndarray
    K: np.ndarray
    w2c: np.ndarray
    queries: np.ndarray
    kind: np.ndarray
    xy: np.ndarray
    visible: np.ndarray
    scene: np.ndarray
    camera: np.ndarray
    image_size: int
    frames: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.z_s)

    @property
    def counts(self) -> np.ndarray:
        """(S,) number of valid query slots per set."""
        counts: np.ndarray = (self.kind != KIND_PAD).sum(axis=1)
        return counts


def sample_queries(object_ids: np.ndarray, dynamic_mask: np.ndarray, n: int, rng: np.random.Generator
                   ) -> tuple[np.ndarray, np.ndarray]:
    """``n`` static (background) and up to ``n`` dynamic pixels of one camera's clip, each at a random frame.

    ``object_ids`` and ``dynamic_mask`` are (T, H, W).  Returns queries (2n, 3) int64 (u, v, t0) and kind
    (2n,) int8 (0 static, 1 dynamic, -1 empty slot at the end where fewer dynamic pixels exist).
    """
    T, H, W = object_ids.shape
    static = np.flatnonzero(object_ids.reshape(-1) == 0)
    dynamic = np.flatnonzero(dynamic_mask.reshape(-1))
    picked_s = rng.choice(static, size=n, replace=len(static) < n) if len(static) else np.zeros(0, np.int64)
    picked_d = rng.choice(dynamic, size=min(n, len(dynamic)), replace=False)
    flat = np.concatenate([picked_s, picked_d]).astype(np.int64)
    t, rem = np.divmod(flat, H * W)
    v, u = np.divmod(rem, W)
    q = np.zeros((2 * n, 3), np.int64)
    kind = np.full(2 * n, KIND_PAD, np.int8)
    q[: len(flat)] = np.stack([u, v, t], -1)
    kind[: len(picked_s)] = KIND_STATIC
    kind[len(picked_s): len(flat)] = KIND_DYNAMIC
    return q, kind


def _record_path(cache: Path, fingerprint: str, split: str, seed: int, cameras: int, queries: int,
                 query_seed: int) -> Path:
    return cache / fingerprint / f"{split}-{seed:06d}-c{cameras}-q{queries}-s{query_seed}-v{RECORD_VERSION}.npz"


def build_records(tokenizer: Any, pool: Any, seed: int, queries: int, query_seed: int) -> dict[str, np.ndarray]:
    """One scene's arrays for :class:`TrackData`: every camera encoded by the frozen ``tokenizer`` exactly as
    ``tokenize_event`` does, queries sampled and their true tracks computed from the generator.

    ``pool`` is the :class:`~vt4dcodec.model.train.data.ScenePool` (split, cameras, frames, size, cache).
    Raises :class:`EvaluationError` if the regenerated scene's frames differ from the pool's cached ones.
    """
    from vt4dcodec.model.train.tokenize_scenes import tokenize_event

    cached = pool.scene(seed)
    config = SynthConfig(num_cameras=pool.cameras, num_frames=pool.frames, height=pool.image_size,
                         width=pool.image_size)
    scene = generate_scene(seed, split=pool.split, config=config)
    names = sorted(scene.capture.cameras)
    frames = np.stack([scene.capture.frames[n] for n in names])
    depth = scene.capture.depth or {}
    if not np.array_equal(frames, cached["frames"]) or not np.array_equal(
            np.stack([depth[n] for n in names]), cached["depth"]):
        raise EvaluationError(f"scene {pool.split}-{seed} in {pool.cache} is not what the generator makes now; "
                              "clear that cache entry")
    tokens = tokenize_event(tokenizer, pool, seed)
    setup = setup_of(scene)
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("z_s", "z_d", "K", "w2c", "queries", "kind", "xy",
                                                          "visible")}
    split_code = 0 if pool.split == "train" else 1
    for c, name in enumerate(names):
        rng = np.random.default_rng([query_seed, split_code, seed, c])
        q, kind = sample_queries(scene.object_ids[name], scene.dynamic_mask[name], queries, rng)
        surfaces = surface_ids(setup, name, depth[name], scene.object_ids[name])
        xy, vis = true_tracks(scene, name, q, setup=setup, surfaces=surfaces)
        vis &= (kind != KIND_PAD)[:, None]
        out["z_s"].append(tokens[c][0])
        out["z_d"].append(tokens[c][1])
        out["K"].append(cached["K"][c].astype(np.float32))
        out["w2c"].append(cached["w2c"][c].astype(np.float32))
        out["queries"].append(q)
        out["kind"].append(kind)
        out["xy"].append(np.nan_to_num(xy).astype(np.float32))
        out["visible"].append(vis)
    return {k: np.stack(v) for k, v in out.items()}


def load_data(tokenizer: Any, pool: Any, seeds: Sequence[int], *, queries: int, query_seed: int, cache: Path,
              keep_frames: int = 0, progress: Callable[[str], None] | None = None) -> TrackData:
    """:class:`TrackData` of every camera of ``seeds`` of ``pool``, built once and cached under ``cache``
    (per tokenizer fingerprint; plain ``.npz``, no pickle).  ``keep_frames``: keep the clips of the first
    that many scenes (for the figure)."""
    fp = tokenizer.stored_fingerprint()
    key = f"{fp.model_id}-{fp.model_version}-{fp.weights_sha256[:12]}"
    parts: dict[str, list[np.ndarray]] = {}
    frames = []
    t_start = time.perf_counter()
    for i, seed in enumerate(seeds):
        path = _record_path(cache, key, pool.split, seed, pool.cameras, queries, query_seed)
        if path.is_file():
            with np.load(path, allow_pickle=False) as npz:
                rec = {k: npz[k] for k in npz.files}
        else:
            rec = build_records(tokenizer, pool, seed, queries, query_seed)
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
            with tmp.open("wb") as f:
                np.savez(f, **rec)
            os.replace(tmp, path)
        rec["scene"] = np.full(len(rec["z_s"]), seed, np.int64)
        rec["camera"] = np.arange(len(rec["z_s"]), dtype=np.int64)
        for k, v in rec.items():
            parts.setdefault(k, []).append(v)
        if i < keep_frames:
            frames.append(pool.scene(seed)["frames"])
        if progress and (i + 1) % 16 == 0:
            progress(f"  {pool.split}: {i + 1}/{len(seeds)} scenes ({time.perf_counter() - t_start:.0f} s)")
    data = {k: np.concatenate(v) for k, v in parts.items()}
    return TrackData(**data, image_size=pool.image_size, frames=np.concatenate(frames) if frames else None)


# --- the decoder --------------------------------------------------------------------------------------
class _Block(nn.Module):
    """Pre-norm cross-attention of the queries to the token memory, then an MLP (both residual)."""

    def __init__(self, width: int, heads: int) -> None:
        super().__init__()
        self.norm_q = nn.LayerNorm(width)
        self.norm_m = nn.LayerNorm(width)
        self.attn = nn.MultiheadAttention(width, heads, batch_first=True)
        self.norm_mlp = nn.LayerNorm(width)
        self.mlp = nn.Sequential(nn.Linear(width, 2 * width), nn.GELU(), nn.Linear(2 * width, width))

    def forward(self, q: torch.Tensor, memory: torch.Tensor) -> torch.Tensor:
        m = self.norm_m(memory)
        q = q + self.attn(self.norm_q(q), m, m, need_weights=False)[0]
        return q + self.mlp(self.norm_mlp(q))


class TrackProbe(nn.Module):
    """A light track decoder over a frozen token set.

    ``reads`` chooses the token streams: "static" (Z_s), "dynamic" (Z_d), "both" or "none"; everything
    else (layers, sizes, initialisation given the seed) is the same for all four.  :meth:`forward` maps
    tokens, the camera trajectory and query pixels to the query's pixel position at every frame.
    """

    def __init__(self, reads: str, *, token_dim: int, frames: int, image_size: int, width: int = 128,
                 heads: int = 4, blocks: int = 2, fourier: int = 8) -> None:
        super().__init__()
        if reads not in DECODERS:
            raise EvaluationError(f"a track decoder reads one of {DECODERS}, got {reads!r}")
        self.reads, self.frames, self.image_size, self.fourier = reads, frames, image_size, fourier
        self.token_in = nn.Sequential(nn.Linear(token_dim, width), nn.GELU(), nn.Linear(width, width))
        self.type_embed = nn.Parameter(0.02 * torch.randn(2, width))
        self.null = nn.Parameter(0.02 * torch.randn(1, 1, width))
        query_dim = 4 * fourier + 2 + frames + 6 + frames * 26
        self.query_in = nn.Sequential(nn.Linear(query_dim, width), nn.GELU(), nn.Linear(width, width))
        self.blocks = nn.ModuleList(_Block(width, heads) for _ in range(blocks))
        hidden, out = nn.Linear(width, width), nn.Linear(width, frames * 2)   # created in this order (seeded init)
        nn.init.zeros_(out.weight)   # starts as "no motion"
        nn.init.zeros_(out.bias)
        self.head = nn.Sequential(nn.LayerNorm(width), hidden, nn.GELU(), out)

    def memory(self, z_s: torch.Tensor, z_d: torch.Tensor) -> torch.Tensor:
        """The attended set (B, 1 + n, width): the null token, then the streams this decoder reads."""
        parts = [self.null.expand(len(z_s), 1, -1)]
        if self.reads in ("static", "both"):
            parts.append(self.token_in(z_s) + self.type_embed[0])
        if self.reads in ("dynamic", "both"):
            parts.append(self.token_in(z_d) + self.type_embed[1])
        return torch.cat(parts, dim=1)

    def query_features(self, K: torch.Tensor, w2c: torch.Tensor, queries: torch.Tensor) -> torch.Tensor:
        """(B, Q, query_dim) features of queries (B, Q, 3) (u0, v0, t0) under cameras K (B, T, 3, 3), w2c (B, T, 4, 4)."""
        B, Q = queries.shape[:2]
        T, S = self.frames, self.image_size
        uv = queries[..., :2].float()
        t0 = queries[..., 2].long()
        uvn = uv / (S - 1) * 2 - 1
        freqs = math.pi * 2.0 ** torch.arange(self.fourier, dtype=torch.float32)
        ang = (uvn[..., None] * freqs).flatten(-2)                                   # (B, Q, 2F)
        onehot = F.one_hot(t0, T).float()
        bidx = torch.arange(B)[:, None].expand(B, Q)
        K0, w0 = K[bidx, t0], w2c[bidx, t0]                                          # (B, Q, 3, 3), (B, Q, 4, 4)
        R0 = w0[..., :3, :3]
        pix = torch.cat([uv, torch.ones_like(uv[..., :1])], -1)
        d_cam = torch.linalg.solve(K0, pix[..., None])[..., 0]
        d_world = (R0.transpose(-1, -2) @ F.normalize(d_cam, dim=-1)[..., None])[..., 0]
        centre = -(R0.transpose(-1, -2) @ w0[..., :3, 3:])[..., 0]
        rel = w2c[:, None] @ torch.linalg.inv(w0)[:, :, None]                        # (B, Q, T, 4, 4)
        per_frame = torch.cat([w2c[:, None, :, :3, :].flatten(-2).expand(B, Q, T, 12), rel[..., :3, :].flatten(-2),
                               (torch.stack([K[..., 0, 0], K[..., 1, 1]], -1) / S)[:, None].expand(B, Q, T, 2)], -1)
        return torch.cat([uvn, ang.sin(), ang.cos(), onehot, d_world, centre, per_frame.flatten(-2)], -1)

    def forward(self, z_s: torch.Tensor, z_d: torch.Tensor, K: torch.Tensor, w2c: torch.Tensor,
                queries: torch.Tensor) -> torch.Tensor:
        """Positions (B, Q, T, 2) in pixels of queries (B, Q, 3) given tokens z_s (B, N_s, d), z_d (B, N_d, d)
        and the clip's cameras K (B, T, 3, 3), w2c (B, T, 4, 4); exactly (u0, v0) at t0."""
        memory = self.memory(z_s, z_d)
        q = self.query_in(self.query_features(K, w2c, queries))
        for block in self.blocks:
            q = block(q, memory)
        B, Q = queries.shape[:2]
        disp = self.head(q).view(B, Q, self.frames, 2) * DISPLACEMENT_SCALE
        at_t0 = disp.gather(2, queries[..., 2].long()[..., None, None].expand(B, Q, 1, 2))
        return queries[..., None, :2].float() + (disp - at_t0)     # exactly the query at t0


# --- training and prediction --------------------------------------------------------------------------
def _batch(data: TrackData, sets: np.ndarray, slots: np.ndarray) -> dict[str, torch.Tensor]:
    rows = sets[:, None]
    return {"z_s": torch.from_numpy(data.z_s[sets]), "z_d": torch.from_numpy(data.z_d[sets]),
            "K": torch.from_numpy(data.K[sets]), "w2c": torch.from_numpy(data.w2c[sets]),
            "queries": torch.from_numpy(data.queries[rows, slots]), "xy": torch.from_numpy(data.xy[rows, slots]),
            "visible": torch.from_numpy(data.visible[rows, slots])}


def _scored(queries: torch.Tensor, visible: torch.Tensor) -> torch.Tensor:
    """(B, Q, T) bool: visible frames other than t0."""
    T = visible.shape[-1]
    return visible & (torch.arange(T) != queries[..., 2:3])


def train_probe(reads: str, data: TrackData, settings: ProbeSettings,
                progress: Callable[[str], None] | None = None) -> tuple[TrackProbe, list[float]]:
    """Train one decoder reading ``reads`` on ``data`` (its valid query slots, uniformly); returns it (eval
    mode) and the loss every 100 steps.  The seed fixes both the initialisation and the batches, so every
    decoder sees the same batches."""
    if len(data) == 0 or not (data.counts > 0).any():
        raise EvaluationError("no training queries")
    torch.manual_seed(settings.seed)
    T = data.xy.shape[2]
    net = TrackProbe(reads, token_dim=data.z_s.shape[-1], frames=T, image_size=data.image_size,
                     width=settings.width, heads=settings.heads, blocks=settings.blocks, fourier=settings.fourier)
    opt = torch.optim.AdamW(net.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)
    warm = max(1, settings.steps // 20)

    def lr_at(step: int) -> float:
        if step < warm:
            return (step + 1) / warm
        x = (step - warm) / max(1, settings.steps - warm)
        return 0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * x))

    sched = torch.optim.lr_scheduler.LambdaLR(opt, lr_at)
    rng = np.random.default_rng(settings.seed)
    usable = np.flatnonzero(data.counts > 0)
    losses, running, t_start = [], [], time.perf_counter()
    net.train()
    for step in range(settings.steps):
        sets = usable[rng.integers(len(usable), size=settings.batch_sets)]
        slots = (rng.random((settings.batch_sets, settings.queries_per_set)) * data.counts[sets][:, None]).astype(np.int64)
        b = _batch(data, sets, slots)
        pred = net(b["z_s"], b["z_d"], b["K"], b["w2c"], b["queries"])
        mask = _scored(b["queries"], b["visible"])
        err = F.huber_loss(pred, b["xy"], delta=HUBER_DELTA, reduction="none").sum(-1)
        loss = (err * mask).sum() / mask.sum().clamp_min(1)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
        opt.step()
        sched.step()
        running.append(float(loss.detach()))
        if (step + 1) % 100 == 0 or step + 1 == settings.steps:
            losses.append(float(np.mean(running)))
            running = []
            if progress and ((step + 1) % 500 == 0 or step + 1 == settings.steps):
                progress(f"  {reads}: step {step + 1}/{settings.steps} loss {losses[-1]:.3f} "
                         f"({time.perf_counter() - t_start:.0f} s)")
    return net.eval(), losses


@torch.no_grad()
def predict(net: TrackProbe, data: TrackData, chunk: int = 32) -> np.ndarray:
    """(S, P, T, 2) float32 predicted positions of every query slot of ``data``."""
    out = []
    P = data.queries.shape[1]
    for start in range(0, len(data), chunk):
        sets = np.arange(start, min(start + chunk, len(data)))
        b = _batch(data, sets, np.broadcast_to(np.arange(P), (len(sets), P)))
        out.append(net(b["z_s"], b["z_d"], b["K"], b["w2c"], b["queries"]).numpy())
    return np.concatenate(out).astype(np.float32)


def still_prediction(data: TrackData) -> np.ndarray:
    """The "no motion" baseline: (S, P, T, 2) every query stays at (u0, v0)."""
    T = data.xy.shape[2]
    return np.repeat(data.queries[:, :, None, :2].astype(np.float32), T, axis=2)


# --- metrics ------------------------------------------------------------------------------------------
def _set_masks(data: TrackData) -> dict[str, np.ndarray]:
    """Per track set: (S, P, T) bool of the scored (query, frame) pairs."""
    T = data.xy.shape[2]
    scored = data.visible & (np.arange(T) != data.queries[..., 2:3])
    return {"static": scored & (data.kind == KIND_STATIC)[..., None],
            "dynamic": scored & (data.kind == KIND_DYNAMIC)[..., None],
            "mixed": scored & (data.kind != KIND_PAD)[..., None]}


def evaluate(data: TrackData, predictions: dict[str, np.ndarray]) -> dict[str, Any]:
    """EPE per scene, per track set and decoder, and the per-query means (for track-level errors).

    ``predictions``: decoder -> (S, P, T, 2).  Returns {"scenes": [seeds], "scene_epe": {set: {decoder:
    [per-scene EPE or None]}}, "query_epe": {set: {decoder: [per-query EPE]}}, "pairs": {set: n scored
    (query, frame) pairs}, "queries": {set: n queries}}.
    """
    seeds = sorted(set(int(s) for s in data.scene))
    masks = _set_masks(data)
    errors = {k: np.linalg.norm(p - data.xy, axis=-1) for k, p in predictions.items()}      # (S, P, T)
    scene_epe: dict[str, dict[str, list[float | None]]] = {s: {k: [] for k in predictions} for s in TRACK_SETS}
    query_epe: dict[str, dict[str, list[float]]] = {s: {k: [] for k in predictions} for s in TRACK_SETS}
    for name, mask in masks.items():
        per_query_n = mask.sum(-1)
        has = per_query_n > 0
        for k, err in errors.items():
            for seed in seeds:
                rows = data.scene == seed
                n = mask[rows].sum()
                scene_epe[name][k].append(float((err[rows] * mask[rows]).sum() / n) if n else None)
            query_epe[name][k] = ((err * mask).sum(-1)[has] / per_query_n[has]).tolist()
    return {"scenes": seeds, "scene_epe": scene_epe, "query_epe": query_epe,
            "pairs": {s: int(m.sum()) for s, m in masks.items()},
            "queries": {s: int((m.sum(-1) > 0).sum()) for s, m in masks.items()}}


def _entry(values: Sequence[float | None]) -> dict[str, Any]:
    m, se, n = mean_se(list(values))
    return {"mean": None if m is None else round_metric(m), "se": None if se is None else round_metric(se), "n": n}


def _paired(a: list[float | None], b: list[float | None]) -> list[float | None]:
    return [None if x is None or y is None else x - y for x, y in zip(a, b)]


def summarize(ev: dict[str, Any]) -> dict[str, Any]:
    """Mean +- s.e. over scenes per set and decoder; paired differences (Z_s - Z_d, both - each single,
    both - the best single of the set) over scenes and, as a secondary figure, over queries."""
    out: dict[str, Any] = {}
    for s in TRACK_SETS:
        sc, qe = ev["scene_epe"][s], ev["query_epe"][s]
        row: dict[str, Any] = {"epe": {k: _entry(v) for k, v in sc.items()},
                               "epe_over_queries": {k: _entry(v) for k, v in qe.items()}}
        diffs: dict[str, Any] = {}
        if "static" in sc and "dynamic" in sc:
            diffs["Z_s - Z_d"] = ("static", "dynamic")
        if "both" in sc:
            for single in ("static", "dynamic"):
                if single in sc:
                    diffs[f"both - {DECODER_LABELS[single]}"] = ("both", single)
            singles = [k for k in ("static", "dynamic") if k in sc and row["epe"][k]["mean"] is not None]
            if singles:
                best = min(singles, key=lambda k: row["epe"][k]["mean"])
                diffs["both - best single"] = ("both", best)
                row["best_single"] = DECODER_LABELS[best]
        for k in ("static", "dynamic", "both"):
            if k in sc and "none" in sc:
                diffs[f"{DECODER_LABELS[k]} - no tokens"] = (k, "none")
        row["paired"] = {name: {**_entry(_paired(sc[a], sc[b])),
                                "over_queries": _entry([x - y for x, y in zip(qe[a], qe[b])]),
                                "a": a, "b": b}
                         for name, (a, b) in diffs.items()}
        row["pairs"], row["queries"] = ev["pairs"][s], ev["queries"][s]
        out[s] = row
    return out


SIGNIFICANT_Z = 2.0   # |mean / s.e.| of a paired difference at or above which an ordering is called


def _verdict(mean: float, se: float | None, expected_negative: bool) -> tuple[bool, str, float | None]:
    """(sign as the paper says, verdict, z): "holds" / "reversed" at |z| >= 2, else "tie (within noise)"."""
    z = None if not se else mean / se
    right = mean < 0 if expected_negative else mean > 0
    if z is None or abs(z) < SIGNIFICANT_Z:
        return right, "tie (within noise)", z
    return right, "holds" if right else "reversed", z


def orderings(summary: dict[str, Any]) -> dict[str, Any]:
    """The paper's three claims, each with the paired difference it rests on (per scene; negative = the
    first decoder is better), whether its sign is the paper's, and a verdict at |mean / s.e.| >= 2."""
    checks = {"Z_s better on static tracks": ("static", "Z_s - Z_d", True),
              "Z_d better on dynamic tracks": ("dynamic", "Z_s - Z_d", False)}
    out: dict[str, Any] = {}

    def entry(s: str, label: str, d: dict[str, Any], expected_negative: bool) -> dict[str, Any]:
        right, verdict, z = _verdict(d["mean"], d["se"], expected_negative)
        return {"holds": bool(right), "verdict": verdict, "set": s, "difference": label, "mean": d["mean"],
                "se": d["se"], "z": None if z is None else round_metric(z, 2)}

    for name, (s, key, negative) in checks.items():
        d = summary[s]["paired"].get(key)
        if d and d["mean"] is not None:
            out[name] = entry(s, key, d, negative)
    for s in TRACK_SETS:
        d = summary[s]["paired"].get("both - best single")
        if d and d["mean"] is not None:
            out[f"both best on {s} tracks"] = entry(s, f"both - {summary[s]['best_single']}", d, True)
    return out


def format_orderings(checks: dict[str, Any]) -> str:
    """One line per ordering of :func:`orderings`."""
    return "".join(f"{name}: {o['verdict']}, sign {'as' if o['holds'] else 'against'} the paper ({o['difference']} = "
                   f"{o['mean']:+.3f} ± {o['se'] if o['se'] is not None else float('nan'):.3f} px on {o['set']} "
                   f"tracks)\n" for name, o in checks.items())


def _fmt(e: dict[str, Any] | None, nd: int = 2, signed: bool = False) -> str:
    if not e or e.get("mean") is None:
        return "—"
    m = f"{e['mean']:+.{nd}f}" if signed else f"{e['mean']:.{nd}f}"
    return m + (f" ± {e['se']:.{nd}f}" if e.get("se") is not None else "")


def format_table(results: dict[str, Any]) -> str:
    """The Markdown tables of a results file: EPE per set and decoder, then the paired differences."""
    summary = results["summary"]
    decoders = ["still"] + [d for d in DECODERS if d in results["decoders"]]
    out = ["| track set (test queries / scored pairs) | " + " | ".join(DECODER_LABELS[d] for d in decoders) + " |",
           "|---|" + "---:|" * len(decoders)]
    for s in TRACK_SETS:
        row = summary[s]
        out.append(f"| {s} ({row['queries']:,} / {row['pairs']:,}) | "
                   + " | ".join(_fmt(row["epe"].get(d)) for d in decoders) + " |")
    names = [n for n in summary["mixed"]["paired"]]
    out += ["", "| paired difference (EPE px, per scene) | " + " | ".join(TRACK_SETS) + " |",
            "|---|" + "---:|" * len(TRACK_SETS)]
    for n in names:
        label = n if n != "both - best single" else "both - best single (" + ", ".join(
            summary[s].get("best_single", "—") for s in TRACK_SETS) + ")"
        out.append(f"| {label} | " + " | ".join(_fmt(summary[s]["paired"].get(n), signed=True)
                                                for s in TRACK_SETS) + " |")
    return "\n".join(out) + "\n"


# --- figure -------------------------------------------------------------------------------------------
def save_figure(path: str | Path, results: dict[str, Any], data: TrackData | None = None,
                predictions: dict[str, np.ndarray] | None = None, example: int = 0) -> Path:
    """Bar chart of EPE per track set and decoder (error bars: s.e. over scenes) and, given the test data
    and predictions, one test clip's frame t0 with true and predicted tracks of a few queries."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .report import save_png_small

    summary = results["summary"]
    decoders = ["still"] + [d for d in DECODERS if d in results["decoders"]]
    colours = {"still": "#999999", "none": "#cccccc", "static": "#1f77b4", "dynamic": "#ff7f0e", "both": "#2ca02c"}
    show_example = data is not None and predictions is not None and data.frames is not None
    fig, axes = plt.subplots(1, 2 if show_example else 1, figsize=(11 if show_example else 6, 4.2),
                             gridspec_kw={"width_ratios": [1.3, 1]} if show_example else None, squeeze=False)
    ax = axes[0, 0]
    width = 0.8 / len(decoders)
    for i, d in enumerate(decoders):
        means = [summary[s]["epe"][d]["mean"] or 0.0 for s in TRACK_SETS]
        ses = [summary[s]["epe"][d]["se"] or 0.0 for s in TRACK_SETS]
        ax.bar(np.arange(len(TRACK_SETS)) + (i - (len(decoders) - 1) / 2) * width, means, width, yerr=ses,
               capsize=2, label=DECODER_LABELS[d], color=colours[d])
    ax.set_xticks(np.arange(len(TRACK_SETS)), [f"{s} tracks" for s in TRACK_SETS])
    ax.set_ylabel("EPE (pixels of 64x64), lower is better")
    ax.set_title(f"Track decoding from frozen {results['settings']['model']} tokens\n"
                 f"({results['settings']['test_scenes']} test scenes, mean ± s.e. over scenes)", fontsize=9)
    ax.legend(fontsize=8)
    if show_example:
        assert data is not None and predictions is not None and data.frames is not None
        ax = axes[0, 1]
        s = _example_set(data, example)
        q = data.queries[s]
        T = data.xy.shape[2]
        dyn = data.kind[s] == KIND_DYNAMIC
        t_show = int(np.bincount(q[dyn, 2], minlength=T).argmax()) if dyn.any() else 0   # most dynamic queries
        at_t = q[:, 2] == t_show
        chosen = list(np.flatnonzero(dyn & at_t)[:4]) + list(np.flatnonzero((data.kind[s] == KIND_STATIC) & at_t)[:3])
        ax.imshow(data.frames[s, t_show], extent=(-0.5, data.frames.shape[3] - 0.5, data.frames.shape[2] - 0.5, -0.5))
        for n, i in enumerate(chosen):
            vis = data.visible[s, i]
            ax.plot(*data.xy[s, i][vis].T, "-", color="white", lw=2.2, label="true" if n == 0 else None)
            for d in ("static", "dynamic", "both"):
                if d in predictions:
                    ax.plot(*predictions[d][s, i][vis].T, "-", color=colours[d], lw=1.2,
                            label=DECODER_LABELS[d] if n == 0 else None)
            ax.plot(*q[i, :2], "o", ms=4, mfc="white" if data.kind[s, i] == KIND_DYNAMIC else "black", mec="k")
        ax.set_xlim(-0.5, data.frames.shape[3] - 0.5)
        ax.set_ylim(data.frames.shape[2] - 0.5, -0.5)
        ax.set_title(f"test scene {int(data.scene[s])} cam{int(data.camera[s]):02d}, frame t0 = {t_show} of {T}: "
                     "tracks on visible frames\n(dots: queries at t0; white dynamic, black static)", fontsize=9)
        ax.legend(fontsize=7, loc="lower right")
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    return save_png_small(fig, path)


def _example_set(data: TrackData, example: int) -> int:
    """A test set (with frames) that has dynamic queries: the ``example``-th such, else the first."""
    n = 0 if data.frames is None else len(data.frames)
    good = [s for s in range(n) if (data.kind[s] == KIND_DYNAMIC).sum() >= 4]
    return good[example % len(good)] if good else 0


# --- the command --------------------------------------------------------------------------------------
@dataclass
class RunOutput:
    """What :func:`run` produced: the results (as written to JSON), the test data and predictions."""

    results: dict[str, Any]
    test: TrackData
    predictions: dict[str, np.ndarray] = field(default_factory=dict)


def run(model: str, settings: ProbeSettings, *, decoders: Sequence[str] = DECODERS,
        train_cache: Path = Path("runs/scene_cache"), test_cache: Path = Path("runs/scene_cache_test"),
        token_cache: Path = Path("runs/track_probe"), figure_scenes: int = 4,
        progress: Callable[[str], None] | None = None) -> RunOutput:
    """Tokenize (cached), train one decoder per entry of ``decoders`` and evaluate them on the test scenes."""
    from vt4dcodec.model.train.data import ScenePool
    from vt4dcodec.model.weights_io import from_pretrained

    for d in decoders:
        if d not in DECODERS:
            raise EvaluationError(f"unknown decoder {d!r}; choose from {','.join(DECODERS)}")
    say = progress or (lambda _msg: None)
    t_start = time.perf_counter()
    tokenizer = from_pretrained(model).eval()
    pools = {split: ScenePool(Path(cache), settings.cameras, tokenizer.config.frames, tokenizer.config.image_size,
                              tokenizer.config.latent_size, tokenizer.config.n_tracks,
                              tokenizer.config.motion_isolation, split=split)
             for split, cache in (("train", train_cache), ("test", test_cache))}
    say(f"tokens and true tracks: {settings.train_scenes} train + {settings.test_scenes} test scenes x "
        f"{settings.cameras} cameras")
    train = load_data(tokenizer, pools["train"], range(settings.train_scenes), queries=settings.queries,
                      query_seed=settings.seed, cache=token_cache, progress=say)
    test = load_data(tokenizer, pools["test"], range(settings.test_scenes), queries=settings.queries,
                     query_seed=settings.seed, cache=token_cache, keep_frames=figure_scenes, progress=say)
    t_data = time.perf_counter() - t_start
    say(f"data ready in {t_data:.0f} s: {len(train)} train / {len(test)} test token sets")
    predictions = {"still": still_prediction(test)}
    losses, train_s = {}, {}
    for d in decoders:
        t0 = time.perf_counter()
        net, losses[d] = train_probe(d, train, settings, progress=say)
        train_s[d] = round(time.perf_counter() - t0, 1)
        predictions[d] = predict(net, test)
        n_params = sum(p.numel() for p in net.parameters())
    ev = evaluate(test, predictions)
    summary = summarize(ev)
    fp = tokenizer.stored_fingerprint()
    results = {
        "table": "Table 3: track decoding from frozen tokens (EPE in pixels of 64x64 images)",
        "settings": {**asdict(settings), "model": model, "decoders": list(decoders),
                     "tokenizer": {"id": fp.model_id, "version": fp.model_version,
                                   "weights_sha256": fp.weights_sha256},
                     "train_split": "train", "test_split": "test", "decoder_parameters": n_params,
                     "loss": f"Huber (delta {HUBER_DELTA} px) on visible frames other than t0"},
        "decoders": list(decoders),
        "summary": summary,
        "orderings": orderings(summary),
        "scene_epe": {s: {k: [round_metric(x) if x is not None else None for x in v]
                          for k, v in ev["scene_epe"][s].items()} for s in TRACK_SETS},
        "scenes": ev["scenes"],
        "train_loss_every_100_steps": {k: [round(x, 4) for x in v] for k, v in losses.items()},
        "timing_s": {"data": round(t_data, 1), "train": train_s, "total": round(time.perf_counter() - t_start, 1)},
        "machine": {"python": platform.python_version(), "torch": torch.__version__,
                    "threads": torch.get_num_threads()},
    }
    return RunOutput(results=results, test=test, predictions=predictions)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m vt4dcodec.eval.track_probe", description=__doc__.split("\n\n")[0])
    d = ProbeSettings()
    p.add_argument("--model", default="vt4d-tiny", help="tokenizer: shipped id or model directory")
    p.add_argument("--train-scenes", type=int, default=d.train_scenes)
    p.add_argument("--test-scenes", type=int, default=d.test_scenes)
    p.add_argument("--cameras", type=int, default=d.cameras, help="cameras per scene, each encoded on its own")
    p.add_argument("--queries", type=int, default=d.queries, help="static (and at most as many dynamic) queries "
                   "per camera")
    p.add_argument("--steps", type=int, default=d.steps)
    p.add_argument("--batch-sets", type=int, default=d.batch_sets)
    p.add_argument("--queries-per-set", type=int, default=d.queries_per_set)
    p.add_argument("--width", type=int, default=d.width)
    p.add_argument("--lr", type=float, default=d.lr)
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--decoders", default=",".join(DECODERS), help=f"comma-separated subset of {','.join(DECODERS)}")
    p.add_argument("--train-cache", type=Path, default=Path("runs/scene_cache"), help="ScenePool cache, train split")
    p.add_argument("--test-cache", type=Path, default=Path("runs/scene_cache_test"), help="ScenePool cache, test split")
    p.add_argument("--token-cache", type=Path, default=Path("runs/track_probe"), help="frozen tokens and tracks")
    p.add_argument("--out", type=Path, default=Path("docs/results/table3_tracks.json"))
    p.add_argument("--figure", type=Path, default=None, help="PNG: EPE bars and example tracks")
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--table", metavar="RESULTS_JSON", type=Path, default=None,
                   help="print the Markdown tables of a results file and exit")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.table is not None:
            results = json.loads(args.table.read_text())
            print(format_table(results) + "\n" + format_orderings(orderings(results["summary"])), end="")
            return 0
        if args.threads < 1:
            raise EvaluationError("--threads must be >= 1")
        torch.set_num_threads(args.threads)
        settings = ProbeSettings(train_scenes=args.train_scenes, test_scenes=args.test_scenes, cameras=args.cameras,
                                 queries=args.queries, steps=args.steps, batch_sets=args.batch_sets,
                                 queries_per_set=args.queries_per_set, width=args.width, lr=args.lr, seed=args.seed)
        decoders = [d.strip() for d in args.decoders.split(",") if d.strip()]
        say = None if args.quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
        out = run(args.model, settings, decoders=decoders, train_cache=args.train_cache, test_cache=args.test_cache,
                  token_cache=args.token_cache, progress=say)
    except (Vt4dError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    from .report import write_json

    write_json(args.out, out.results)
    if args.figure is not None:
        save_figure(args.figure, out.results, out.test, out.predictions)
    print(format_table(out.results) + "\n" + format_orderings(out.results["orderings"]), end="")
    print(f"wrote {args.out}" + (f" and {args.figure}" if args.figure else "")
          + f" in {out.results['timing_s']['total']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
