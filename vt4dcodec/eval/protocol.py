"""The evaluation protocol of dynamic novel-view synthesis (the paper's Tables 1, 4 and 5 at this scale);
``python -m vt4dcodec.eval`` runs it (:mod:`vt4dcodec.eval.command`).

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
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from vt4dcodec import codec
from vt4dcodec.errors import Vt4dError
from vt4dcodec.format import dumps
from vt4dcodec.media import psnr
from vt4dcodec.model import VideoTok4D
from vt4dcodec.synth import SynthConfig, generate_scene
from vt4dcodec.synth.generator import SynthScene

from . import baselines
from .metrics import round_metric, video_metrics

__all__ = [
    "EvalSettings", "EvaluationError", "METHODS", "TOKEN_METHODS", "make_scene", "predict_scene", "score_scene",
    "representation_floats", "run_evaluation", "describe_model",
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
                                        "psnr_visible": round_metric(psnr(w.frames, sc.capture.frames[k], ~w.holes))}
                                       for w, u, k in zip(warps, unseen, targets)],
                             "bytes": None, "seconds": seconds}
    return out


def score_scene(sc: SynthScene, settings: EvalSettings, predictions: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per (method, target view): seed, view, metrics, extra fields and bytes."""
    names = sc.capture.camera_names
    rows = []
    for method, pred in predictions.items():
        for i, k in enumerate(names[1:settings.views + 1]):
            metrics = video_metrics(pred["videos"][i], sc.capture.frames[k], sc.dynamic_mask[k])
            rows.append({"method": method, "seed": sc.seed, "view": k,
                         "dynamic_fraction": round(float(sc.dynamic_mask[k].mean()), 5),
                         **{m: round_metric(v) for m, v in metrics.items()}, "bytes": pred["bytes"], **pred["extra"][i]})
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


# --- the run ----------------------------------------------------------------------------------------
def _check_models(models: dict[str, VideoTok4D], settings: EvalSettings) -> None:
    for key, net in models.items():
        cfg = net.config
        if (cfg.frames, cfg.image_size) != (settings.frames, settings.image_size):
            raise EvaluationError(f"model {key!r} encodes {cfg.frames} frames of {cfg.image_size}px; the evaluation "
                                  f"uses {settings.frames} frames of {settings.image_size}px")
    if "main" in models and "unified" in models and models["main"].config.token_floats != models["unified"].config.token_floats:
        raise EvaluationError("the unified ablation must have the same token budget as the main model")


def describe_model(net: VideoTok4D) -> dict[str, Any]:
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


