"""Dynamic novel-view synthesis evaluation (issue #6 item 3; the paper's Tables 1, 4 and 5 at this scale).

    python -m vt4dcodec.model.evaluate --model vt4d-tiny [--unified runs/tok_unified/model] \
        --scenes 50 --views 3 --steps 8 --out docs/results/eval.json --figure docs/figures/eval_scenes.png

Protocol.  Held-out scenes ``generate_scene(seed, split="test")`` (textures disjoint from the training
split) for seeds ``first_seed .. first_seed + scenes - 1``, each with ``views + 1`` (at least 4)
synchronized moving cameras and moving objects.  Camera 0 is the source.  Every method sees only the
source clip and predicts the videos of cameras 1..views along their trajectories:

* ``ours``: ``codec.encode`` camera 0 with the model, store it as an int8 ``.vt4d`` (``format.dumps``;
  its length is the reported size), load those bytes back with ``SceneDecoder`` and
  ``render_many`` the target trajectories (``steps`` Euler steps, noise seed ``seed``);
* ``ours_no_static`` / ``ours_no_dynamic``: the same tokens rendered with Z_s or Z_d masked out of the
  renderer (Table 4);
* ``unified``: the unified-token ablation (one token set of the same size, no Temporal Branch), encoded
  and rendered the same way (Table 1/5), if its model is given;
* ``nearest_frame``: the source frame closest in pose, copied (view-bound);
* ``mean_colour``: every pixel of every frame is the source video's mean colour (3 floats): a
  reference that shows how much PSNR a method earns without any structure;
* ``depth_warp``: source frame t forward-warped into target camera t with its exact depth (z-buffered
  splatting, holes inpainted): an explicit RGB-D representation.  Reported with it: the fraction of
  target pixels without a splat, and the fraction a surfel splat leaves uncovered (what the source
  camera never sees).

Metrics per (scene, target view) video against the ground truth: PSNR (dB, all pixels), SSIM (kornia,
11x11 Gaussian window, mean over frames), PSNR over the target view's ground-truth dynamic-object pixels
only (views with no such pixel are skipped) and over the other (static) pixels.  Means over views with
the standard error, paired differences against ``ours`` and the fraction of views where ``ours`` wins.
Sizes: floats of the representation (tokens ``N_s*d + N_d*d``, RGB-D ``T*H*W*4``, source video
``T*H*W*3``) and the bytes of the int8 ``.vt4d`` for token methods.

``--merge`` adds or replaces some methods in an existing results file (same protocol), so a model
that finishes training later is added without rerunning the rest; ``--tables FILE`` prints the
Markdown tables of a results file (what docs/RESULTS.md shows).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch

from vt4dcodec import codec
from vt4dcodec.errors import Vt4dError
from vt4dcodec.format import dumps
from vt4dcodec.media import psnr
from vt4dcodec.synth import SynthConfig, generate_scene
from vt4dcodec.synth.generator import SynthScene

from . import baselines
from .videotok4d import VideoTok4D

__all__ = [
    "EvalSettings", "METHODS", "TOKEN_METHODS", "load_run_checkpoint", "resolve_model", "video_metrics", "predict_scene", "score_scene", "summarize",
    "run_evaluation", "format_tables", "save_figure", "main",
]

# method -> (label, (model key, drop_static, drop_dynamic)) for token methods
TOKEN_METHODS: dict[str, tuple[str, tuple[str, bool, bool]]] = {
    "ours": ("VideoTok4D (Z_s + Z_d)", ("main", False, False)),
    "ours_no_static": ("VideoTok4D w/o Z_s", ("main", True, False)),
    "ours_no_dynamic": ("VideoTok4D w/o Z_d", ("main", False, True)),
    "unified": ("Unified tokens (ablation)", ("unified", False, False)),
}
BASELINE_METHODS = {"nearest_frame": "Nearest source frame (view-bound)", "depth_warp": "Depth forward-warp (RGB-D)",
                    "mean_colour": "Flat source mean colour (reference)"}
METHODS: dict[str, str] = {**{k: v[0] for k, v in TOKEN_METHODS.items()}, **BASELINE_METHODS}
METRICS = ("psnr", "ssim", "psnr_dynamic", "psnr_static")
ENCODING = "int8"


class EvaluationError(Vt4dError, ValueError):
    """Inconsistent evaluation settings (models that do not fit the scenes, a merge with another protocol)."""


@dataclass(frozen=True)
class EvalSettings:
    """The protocol: which scenes, views and sampler settings.  Equal settings give equal numbers."""

    scenes: int = 50
    first_seed: int = 0
    views: int = 3
    steps: int = 8
    seed: int = 0
    num_cameras: int = 4
    frames: int = 8
    image_size: int = 64

    def __post_init__(self) -> None:
        for key in ("scenes", "views", "steps", "frames", "image_size"):
            if getattr(self, key) < 1:
                raise EvaluationError(f"{key} must be >= 1")
        if self.num_cameras < self.views + 1:
            raise EvaluationError(f"num_cameras ({self.num_cameras}) must be at least views + 1 ({self.views + 1})")

    @property
    def seeds(self) -> list[int]:
        return list(range(self.first_seed, self.first_seed + self.scenes))


def make_scene(seed: int, settings: EvalSettings) -> SynthScene:
    """The held-out test scene for ``seed`` (split="test": textures disjoint from training)."""
    cfg = SynthConfig(num_cameras=settings.num_cameras, num_frames=settings.frames, height=settings.image_size,
                      width=settings.image_size)
    return generate_scene(seed, split="test", config=cfg)


# --- metrics ----------------------------------------------------------------------------------------
def video_metrics(pred: np.ndarray, truth: np.ndarray, dynamic_mask: np.ndarray) -> dict[str, float]:
    """PSNR (dB), SSIM and PSNR over dynamic / static pixels of (T, H, W, 3) uint8 videos.

    ``dynamic_mask`` (T, H, W) bool marks the ground truth's moving-object pixels; a region with no
    pixel gives NaN for its PSNR.
    """
    import kornia

    a = torch.from_numpy(np.ascontiguousarray(pred)).permute(0, 3, 1, 2).float() / 255.0
    b = torch.from_numpy(np.ascontiguousarray(truth)).permute(0, 3, 1, 2).float() / 255.0
    mask = np.asarray(dynamic_mask, bool)
    return {
        "psnr": psnr(pred, truth),
        "ssim": float(kornia.metrics.ssim(a, b, 11).mean()),
        "psnr_dynamic": psnr(pred, truth, mask),
        "psnr_static": psnr(pred, truth, ~mask),
    }


# --- predictions ------------------------------------------------------------------------------------
def _render_tokens(net: VideoTok4D, sc: SynthScene, source: str, targets: Sequence[str], settings: EvalSettings,
                   variants: dict[str, tuple[bool, bool]]) -> tuple[dict[str, list[np.ndarray]], int, float]:
    """Encode ``source`` into an int8 .vt4d, decode the bytes, render every target per variant.

    Returns (variant -> videos, file bytes, seconds spent).
    """
    t0 = time.perf_counter()
    scene = codec.encode(sc.capture, net, ENCODING, camera=source, seed=settings.seed)
    blob = dumps(scene)
    decoder = codec.SceneDecoder.open(blob, model=net)
    trajectories = [sc.capture.cameras[k] for k in targets]
    videos = {name: decoder.render_many(trajectories, steps=settings.steps, seed=settings.seed,
                                        drop_static=ds, drop_dynamic=dd)
              for name, (ds, dd) in variants.items()}
    return videos, len(blob), time.perf_counter() - t0


def predict_scene(sc: SynthScene, settings: EvalSettings, methods: Sequence[str],
                  models: dict[str, VideoTok4D]) -> dict[str, dict[str, Any]]:
    """Every method's predicted videos of the target views of one scene.

    Returns method -> {"videos": [per view (T, H, W, 3) uint8], "extra": [per view dict],
    "bytes": int | None, "seconds": float}.
    """
    names = sc.capture.camera_names
    source, targets = names[0], names[1:settings.views + 1]
    src_frames, src_traj = sc.capture.frames[source], sc.capture.cameras[source]
    out: dict[str, dict[str, Any]] = {}
    for key in sorted({TOKEN_METHODS[m][1][0] for m in methods if m in TOKEN_METHODS}):
        variants = {m: TOKEN_METHODS[m][1][1:] for m in methods if m in TOKEN_METHODS and TOKEN_METHODS[m][1][0] == key}
        videos, nbytes, seconds = _render_tokens(models[key], sc, source, targets, settings, variants)
        for m, vids in videos.items():
            out[m] = {"videos": vids, "extra": [{} for _ in vids], "bytes": nbytes, "seconds": seconds / len(videos)}
    if "nearest_frame" in methods:
        t0 = time.perf_counter()
        preds = [baselines.nearest_source_frame(src_frames, src_traj, sc.capture.cameras[k]) for k in targets]
        out["nearest_frame"] = {"videos": [p[0] for p in preds],
                                "extra": [{"source_frames": p[1].tolist()} for p in preds],
                                "bytes": None, "seconds": time.perf_counter() - t0}
    if "mean_colour" in methods:
        t0 = time.perf_counter()
        flat = baselines.mean_colour(src_frames)
        out["mean_colour"] = {"videos": [flat] * len(targets), "extra": [{} for _ in targets], "bytes": None,
                              "seconds": time.perf_counter() - t0}
    if "depth_warp" in methods:
        t0 = time.perf_counter()
        depth = sc.capture.depth[source]
        warps = [baselines.forward_warp(src_frames, depth, src_traj, sc.capture.cameras[k]) for k in targets]
        seconds = time.perf_counter() - t0
        # how much of each target view the source covers at all: surfel splat, holes not filled
        unseen = [baselines.forward_warp(src_frames, depth, src_traj, sc.capture.cameras[k], inpaint=False,
                                         footprint=True).hole_fraction for k in targets]
        out["depth_warp"] = {"videos": [w.frames for w in warps],
                             "extra": [{"hole_fraction": round(w.hole_fraction, 5),
                                        "surfel_hole_fraction": round(u, 5),
                                        "psnr_visible": _round(psnr(w.frames, sc.capture.frames[k], ~w.holes))}
                                       for w, u, k in zip(warps, unseen, targets)],
                             "bytes": None, "seconds": seconds}
    return out


def _round(x: float, nd: int = 4) -> float | None:
    return None if not math.isfinite(x) else round(float(x), nd)


def score_scene(sc: SynthScene, settings: EvalSettings, predictions: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per (method, target view): seed, view, metrics, extra fields and bytes."""
    names = sc.capture.camera_names
    rows = []
    for method, pred in predictions.items():
        for i, k in enumerate(names[1:settings.views + 1]):
            metrics = video_metrics(pred["videos"][i], sc.capture.frames[k], sc.dynamic_mask[k])
            rows.append({"method": method, "seed": sc.seed, "view": k,
                         "dynamic_fraction": round(float(sc.dynamic_mask[k].mean()), 5),
                         **{m: _round(v) for m, v in metrics.items()}, "bytes": pred["bytes"], **pred["extra"][i]})
    return rows


# --- summary ----------------------------------------------------------------------------------------
def representation_floats(method: str, settings: EvalSettings, models: dict[str, Any] | None = None,
                          token_floats: int | None = None) -> int:
    """Size of a method's representation of one scene in floats (see module docstring)."""
    T, S = settings.frames, settings.image_size
    if method == "nearest_frame":
        return baselines.nearest_frame_floats(T, S, S)
    if method == "depth_warp":
        return baselines.rgbd_floats(T, S, S)
    if method == "mean_colour":
        return 3
    if token_floats is not None:
        return token_floats
    cfg = models[TOKEN_METHODS[method][1][0]].config
    return baselines.token_floats(cfg.n_static, cfg.n_dynamic, cfg.token_dim)


def _mean_se(values: list[float]) -> tuple[float | None, float | None, int]:
    v = np.array([x for x in values if x is not None and math.isfinite(x)], np.float64)
    if v.size == 0:
        return None, None, 0
    se = float(v.std(ddof=1) / math.sqrt(v.size)) if v.size > 1 else None
    return float(v.mean()), se, int(v.size)


def summarize(rows: list[dict[str, Any]], floats: dict[str, int]) -> dict[str, dict[str, Any]]:
    """Per method: mean, standard error and count of every metric, sizes, and paired comparisons
    against ``ours`` (mean of ours - method, fraction of views where ours is higher)."""
    by_method: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        by_method.setdefault(r["method"], []).append(r)
    ours = {(r["seed"], r["view"]): r for r in by_method.get("ours", [])}
    summary: dict[str, dict[str, Any]] = {}
    for method in [m for m in METHODS if m in by_method]:
        rs = by_method[method]
        entry: dict[str, Any] = {"label": METHODS[method], "views": len(rs), "floats": floats[method]}
        for m in METRICS:
            mean, se, n = _mean_se([r[m] for r in rs])
            entry[m] = {"mean": _round(mean) if mean is not None else None,
                        "se": _round(se) if se is not None else None, "n": n}
        sizes = [r["bytes"] for r in rs if r["bytes"] is not None]
        entry["bytes_int8_vt4d"] = round(float(np.mean(sizes)), 1) if sizes else None
        if method == "depth_warp":
            entry["hole_fraction"] = _round(float(np.mean([r["hole_fraction"] for r in rs])))
            entry["surfel_hole_fraction"] = _round(float(np.mean([r["surfel_hole_fraction"] for r in rs])))
            entry["psnr_visible"] = _round(_mean_se([r["psnr_visible"] for r in rs])[0] or float("nan"))
        if method != "ours" and ours:
            for m in ("psnr", "psnr_dynamic"):
                pairs = [(ours[(r["seed"], r["view"])][m], r[m]) for r in rs if (r["seed"], r["view"]) in ours]
                pairs = [(a, b) for a, b in pairs if a is not None and b is not None]
                if pairs:
                    d = np.array([a - b for a, b in pairs])
                    se = float(d.std(ddof=1) / math.sqrt(d.size)) if d.size > 1 else None
                    entry[f"ours_minus_this_{m}"] = {"mean": _round(float(d.mean())),
                                                     "se": _round(se) if se is not None else None,
                                                     "ours_wins": _round(float((d > 0).mean())), "n": int(d.size)}
        summary[method] = entry
    return summary


# --- the run ----------------------------------------------------------------------------------------
def _check_models(models: dict[str, VideoTok4D], settings: EvalSettings) -> None:
    for key, net in models.items():
        cfg = net.config
        if (cfg.frames, cfg.image_size) != (settings.frames, settings.image_size):
            raise EvaluationError(f"model {key!r} encodes {cfg.frames} frames of {cfg.image_size}px; the evaluation "
                                  f"uses {settings.frames} frames of {settings.image_size}px")
    if "main" in models and "unified" in models and models["main"].config.token_floats != models["unified"].config.token_floats:
        raise EvaluationError("the unified ablation must have the same token budget as the main model")


def _model_info(net: VideoTok4D) -> dict[str, Any]:
    fp = codec.model_fingerprint(net)
    cfg = net.config
    return {"fingerprint": fp.short(), "training_step": getattr(net, "training_step", None), "config": cfg.name, "n_static": cfg.n_static, "n_dynamic": cfg.n_dynamic,
            "token_dim": cfg.token_dim, "unified_tokens": cfg.unified_tokens,
            "motion_isolation": cfg.motion_isolation, "track_attention": cfg.track_attention}


def run_evaluation(settings: EvalSettings, models: dict[str, VideoTok4D], methods: Sequence[str], *,
                   figure_seeds: Sequence[int] = (), progress: bool = False
                   ) -> tuple[list[dict[str, Any]], dict[int, dict[str, dict[str, Any]]], dict[str, float]]:
    """Predict and score every scene.

    Returns (rows, predictions of the ``figure_seeds`` scenes (seed -> method -> prediction, plus the
    scene under key "scene"), wall seconds per method summed over scenes; a token model's encode and
    renders are split evenly over the variants rendered from it).
    """
    _check_models(models, settings)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise EvaluationError(f"unknown methods {unknown}; choose from {list(METHODS)}")
    missing = sorted({TOKEN_METHODS[m][1][0] for m in methods if m in TOKEN_METHODS} - set(models))
    if missing:
        raise EvaluationError(f"methods {list(methods)} need models {missing}")
    seeds = settings.seeds
    iterator = seeds
    if progress:
        from tqdm import tqdm

        iterator = tqdm(seeds, desc="scenes", unit="scene")
    rows: list[dict[str, Any]] = []
    kept: dict[int, dict[str, dict[str, Any]]] = {}
    seconds: dict[str, float] = {"generate": 0.0}
    for seed in iterator:
        t0 = time.perf_counter()
        sc = make_scene(seed, settings)
        seconds["generate"] += time.perf_counter() - t0
        preds = predict_scene(sc, settings, methods, models)
        for m, p in preds.items():
            seconds[m] = seconds.get(m, 0.0) + p["seconds"]
        rows.extend(score_scene(sc, settings, preds))
        if seed in figure_seeds:
            kept[seed] = {**preds, "scene": {"scene": sc}}
    return rows, kept, {k: round(v, 2) for k, v in seconds.items()}


# --- figure -----------------------------------------------------------------------------------------
FIGURE_COLUMNS = ("ours", "ours_no_dynamic", "unified", "nearest_frame", "depth_warp")


def save_figure(path: str | Path, kept: dict[int, dict[str, dict[str, Any]]], *, view: int = 0,
                times: Sequence[int] | None = None, dpi: int = 100) -> Path:
    """PNG grid: one row per (scene, time), columns source | ground truth | the methods present."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not kept:
        raise EvaluationError("no scenes kept for the figure")
    first = next(iter(kept.values()))
    columns = [c for c in FIGURE_COLUMNS if c in first]
    sc0: SynthScene = first["scene"]["scene"]
    T = sc0.capture.num_frames
    times = list(times) if times is not None else sorted({0, T // 2, T - 1})
    rows = [(seed, t) for seed in kept for t in times]
    ncol = 2 + len(columns)
    fig, axes = plt.subplots(len(rows), ncol, figsize=(1.1 * ncol, 1.15 * len(rows)), squeeze=False)
    titles = ["source (cam 0)", "ground truth"] + [METHODS[c].replace(" (", "\n(") for c in columns]
    for r, (seed, t) in enumerate(rows):
        entry = kept[seed]
        sc: SynthScene = entry["scene"]["scene"]
        names = sc.capture.camera_names
        target = names[1 + view]
        tiles = [sc.capture.frames[names[0]][t], sc.capture.frames[target][t]]
        tiles += [entry[c]["videos"][view][t] for c in columns]
        for c, tile in enumerate(tiles):
            ax = axes[r, c]
            ax.imshow(tile, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(titles[c], fontsize=6)
            if c == 0:
                ax.set_ylabel(f"seed {seed}\n{target} t={t}", fontsize=6)
    fig.tight_layout(pad=0.2)
    return save_png_small(fig, path, dpi=dpi)


def save_png_small(fig: Any, path: str | Path, *, dpi: int = 100) -> Path:
    """Save a matplotlib figure as a 256-colour PNG (docs figures stay well under 300 KB), then close it."""
    import io

    import matplotlib.pyplot as plt
    from PIL import Image

    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, format="png")
    plt.close(fig)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    image = Image.open(buf).convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    image.save(path, optimize=True)
    return path


# --- tables -----------------------------------------------------------------------------------------
def _fmt(entry: dict[str, Any] | None, nd: int = 2) -> str:
    if not entry or entry.get("mean") is None:
        return "n/a"
    se = entry.get("se")
    return f"{entry['mean']:.{nd}f} ± {se:.{nd}f}" if se is not None else f"{entry['mean']:.{nd}f}"


def format_tables(results: dict[str, Any]) -> str:
    """Markdown tables of a results file: the main comparison (Table 1) and token masking (Table 4)."""
    s = results["summary"]
    lines = ["| method | floats | int8 .vt4d bytes | PSNR (dB) | SSIM | dynamic PSNR (dB) | static PSNR (dB) | "
             "ours − this, PSNR (ours wins) | ours − this, dyn. PSNR (ours wins) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]

    def paired(e: dict[str, Any], key: str) -> str:
        p = e.get(f"ours_minus_this_{key}")
        if not p:
            return "—"
        se = f" ± {p['se']:.2f}" if p.get("se") is not None else ""
        return f"{p['mean']:+.2f}{se} ({100 * p['ours_wins']:.0f}%)"

    for m in ("ours", "unified", "nearest_frame", "depth_warp", "mean_colour"):
        if m not in s:
            continue
        e = s[m]
        size = f"{e['bytes_int8_vt4d']:.0f}" if e.get("bytes_int8_vt4d") else "—"
        lines.append(f"| {e['label']} | {e['floats']:,} | {size} | {_fmt(e['psnr'])} | {_fmt(e['ssim'], 3)} | "
                     f"{_fmt(e['psnr_dynamic'])} | {_fmt(e['psnr_static'])} | {paired(e, 'psnr')} | "
                     f"{paired(e, 'psnr_dynamic')} |")
    out = "\n".join(lines)
    if "depth_warp" in s:
        e = s["depth_warp"]
        out += (f"\n\nDepth forward-warp: {100 * e['hole_fraction']:.1f}% of target pixels receive no splat "
                f"(single-pixel splats, before inpainting; {100 * e['surfel_hole_fraction']:.1f}% with surfel "
                f"splats, i.e. not seen by the source camera at all); PSNR over the pixels that do receive a "
                f"splat: {e['psnr_visible']:.2f} dB.")
    mask_rows = [m for m in ("ours_no_static", "ours_no_dynamic", "ours") if m in s]
    if len(mask_rows) > 1:
        out += ("\n\n| tokens rendered | PSNR (dB) | SSIM | dynamic PSNR (dB) | static PSNR (dB) |\n"
                "|---|---:|---:|---:|---:|")
        for m, label in (("ours_no_static", "Z_d only (w/o Z_s)"), ("ours_no_dynamic", "Z_s only (w/o Z_d)"),
                         ("ours", "Z_s + Z_d")):
            if m in s:
                e = s[m]
                out += (f"\n| {label} | {_fmt(e['psnr'])} | {_fmt(e['ssim'], 3)} | {_fmt(e['psnr_dynamic'])} | "
                        f"{_fmt(e['psnr_static'])} |")
    return out + "\n"


# --- command ----------------------------------------------------------------------------------------
def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m vt4dcodec.model.evaluate", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default="vt4d-tiny", help="main model: shipped id, model directory, or a training "
                   "run directory (its latest checkpoint)")
    p.add_argument("--unified", default=None, help="unified-token ablation: model or training run directory")
    p.add_argument("--scenes", type=int, default=50)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--views", type=int, default=3, help="target cameras per scene (cameras 1..views)")
    p.add_argument("--cameras", type=int, default=None, help="cameras per scene (default max(4, views + 1))")
    p.add_argument("--steps", type=int, default=8, help="Euler steps of the renderer")
    p.add_argument("--seed", type=int, default=0, help="sampling noise and track seed")
    p.add_argument("--methods", default=None, help=f"comma-separated subset of {','.join(METHODS)} (default: all "
                   "that have a model)")
    p.add_argument("--merge", action="store_true", help="add/replace these methods in an existing --out file")
    p.add_argument("--out", default="docs/results/eval.json")
    p.add_argument("--figure", default=None, help="PNG of a few scenes across time")
    p.add_argument("--figure-scenes", type=int, default=3)
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--tables", metavar="RESULTS_JSON", default=None, help="print the Markdown tables of a results "
                   "file and exit")
    return p


def load_run_checkpoint(run_dir: str | Path) -> VideoTok4D:
    """The model of a training run's latest checkpoint (``<run>/checkpoint/``, written by the training
    commands), for evaluating a run in progress.  Its fingerprint version is ``<version>+step<N>``."""
    from .configs import ModelConfig
    from .train.common import load_checkpoint

    ckpt = Path(run_dir) / "checkpoint"
    try:
        state = json.loads((ckpt / "state.json").read_text())
        net = VideoTok4D(ModelConfig.from_dict(state["config"]))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise EvaluationError(f"{ckpt} holds no complete training checkpoint: {exc}") from None
    load_checkpoint(ckpt, net, None)
    train_args = state.get("args", {})
    net.model_id = str(train_args.get("model_id", "unnamed"))
    net.model_version = f"{train_args.get('model_version', '0')}+step{int(state['step'])}"
    net.training_step = int(state["step"])
    return net.eval()


def resolve_model(spec: str) -> VideoTok4D:
    """A shipped id, a model directory, or a training run directory (its latest checkpoint)."""
    path = Path(spec)
    if path.is_dir() and not (path / "config.json").is_file() and (path / "checkpoint" / "state.json").is_file():
        return load_run_checkpoint(path)
    return codec.load_model(spec)


def _load_models(args: argparse.Namespace) -> dict[str, VideoTok4D]:
    models = {"main": resolve_model(args.model)}
    if args.unified:
        models["unified"] = resolve_model(args.unified)
        if not models["unified"].config.unified_tokens:
            raise EvaluationError(f"{args.unified} is not a unified-token model (config unified_tokens is false)")
    for net in models.values():
        net.eval()
    return models


def run_command(body: Callable[[], int]) -> int:
    """Run a command body with the project's exit codes: 1 for a Vt4dError, 3 for an OSError."""
    try:
        return body()
    except Vt4dError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 3


def write_json(path: str | Path, data: dict[str, Any]) -> Path:
    """Indented JSON, except that every element of a top-level ``rows`` list takes one line."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps({k: v for k, v in data.items() if k != "rows"}, indent=1)
    if "rows" in data:
        inner = text[1:-1].rstrip()
        rows = ",\n".join("  " + json.dumps(r, separators=(",", ":")) for r in data["rows"])
        text = "{" + inner + (",\n" if inner else "\n") + ' "rows": [\n' + rows + "\n ]\n}"
    path.write_text(text + "\n")
    return path


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    return run_command(lambda: _run(args, argv))


def _run(args: argparse.Namespace, argv: Sequence[str] | None) -> int:
    if args.tables:
        sys.stdout.write(format_tables(json.loads(Path(args.tables).read_text())))
        return 0
    torch.set_num_threads(max(1, args.threads))
    models = _load_models(args)
    cfg = models["main"].config
    settings = EvalSettings(scenes=args.scenes, first_seed=args.first_seed, views=args.views, steps=args.steps,
                            seed=args.seed, num_cameras=args.cameras or max(4, args.views + 1),
                            frames=cfg.frames, image_size=cfg.image_size)
    available = [m for m in METHODS if m not in TOKEN_METHODS or TOKEN_METHODS[m][1][0] in models]
    methods = args.methods.split(",") if args.methods else available
    out = Path(args.out)
    previous = json.loads(out.read_text()) if args.merge and out.is_file() else None
    if previous is not None and previous["settings"] != asdict(settings):
        raise EvaluationError(f"{out} was made with settings {previous['settings']}, not {asdict(settings)}")
    figure_seeds = settings.seeds[:args.figure_scenes] if args.figure else []
    t0, cpu0 = time.perf_counter(), time.process_time()
    rows, kept, seconds = run_evaluation(settings, models, methods, figure_seeds=figure_seeds,
                                         progress=not args.no_progress)
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    if args.figure and set(methods) != set(available):   # the figure shows every available method
        _, kept, _ = run_evaluation(replace(settings, scenes=len(figure_seeds)),
                                    models, available, figure_seeds=figure_seeds)
    model_info = {k: _model_info(v) for k, v in models.items()}
    timing = {"wall_s": round(wall, 1), "process_cpu_s": round(cpu, 1), "per_method_wall_s": seconds,
              "threads": args.threads, "load_average_at_end": [round(x, 2) for x in os.getloadavg()]}
    if previous is not None:
        rows = [r for r in previous["rows"] if r["method"] not in methods] + rows
        model_info = {**previous["models"], **model_info}
        timing = {**previous["timing"], f"merge_{'+'.join(methods)}": timing}
    command = "python -m vt4dcodec.model.evaluate " + " ".join(sys.argv[1:] if argv is None else argv)
    token_floats = {k: baselines.token_floats(v["n_static"], v["n_dynamic"], v["token_dim"]) for k, v in model_info.items()}
    present = sorted({r["method"] for r in rows}, key=list(METHODS).index)
    floats = {m: representation_floats(m, settings, token_floats=token_floats.get(TOKEN_METHODS[m][1][0])
                                       if m in TOKEN_METHODS else None) for m in present}
    results = {
        "commands": (previous["commands"] if previous is not None else []) + [command],
        "settings": asdict(settings), "encoding": ENCODING, "models": model_info,
        "machine": {"python": platform.python_version(), "torch": torch.__version__},
        "timing": timing, "summary": summarize(rows, floats), "rows": rows,
    }
    write_json(out, results)
    if args.figure:
        save_figure(args.figure, kept)
    sys.stdout.write(format_tables(results))
    sys.stdout.write(f"wall {wall:.1f} s, process CPU {cpu:.1f} s; results -> {out}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
