"""The evaluation protocol of dynamic novel-view synthesis (the paper's Tables 1, 4 and 5 at this scale);
``python -m vt4dcodec.eval`` runs it (:mod:`vt4dcodec.eval.command`).

Protocol.  Held-out scenes ``generate_scene(seed, split="test")`` (textures disjoint from the training
split) for seeds ``first_seed .. first_seed + scenes - 1`` with synchronized moving cameras and moving
objects.  Camera 0 is the source.  Every method sees only the source clip and predicts the videos of
the target cameras along their trajectories.  Five target sets (``VIEW_SETS``; rows carry ``"set"``):

* ``far``: the original protocol: rigs of ``num_cameras`` (``views + 1``, at least 4) cameras from
  :func:`make_scene`, targets cameras 1..views (50-160 degrees from the source);
* ``near``: rigs of ``RIG_CAMERAS`` (10) cameras, same split and seeds, targets the ``NEAR_VIEWS`` (2)
  cameras whose first-frame optical axes are closest in direction to camera 0's
  (:func:`nearest_cameras`);
* ``source``: the same 10-camera rigs, target camera 0 itself: reconstruction of the encoded view.
  The nearest-frame and depth-warp baselines are skipped there (the target is the source: they are
  trivially exact); the flat mean colour stays as the reference.
* ``multi-held`` / ``multi-enc``: multi-camera encoding on the same 10-camera rigs: every other camera
  (0, 2, 4, 6, 8: ``MULTI_ENCODED``) is encoded into one token set; the targets are the five held-out
  cameras (1, 3, ...) or the five encoded ones. The warp and nearest-frame baselines are skipped (they
  are single-source); the flat reference is the mean colour of the encoded cameras' clips.

The methods:

* ``ours``: ``codec.encode`` camera 0 with the model, store it as an int8 ``.vt4d`` (or, with the
  setting ``quality`` = N and a model with quality levels, as learned-rans at level N) (``format.dumps``;
  its length is the reported size), load those bytes back with ``SceneDecoder`` and
  ``render_many`` the target trajectories (``steps`` Euler steps, None: each model's recorded
  ``decode_steps``; noise seed ``seed``);
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

Token health (:func:`token_health_report`): for each token model, over the evaluated scenes' source
clips (the tokens as decoded from the int8 ``.vt4d`` bytes): slot spread, effective rank across
scenes and saturation of Z_s and Z_d (:mod:`model.diagnostics`), and the token-swap drop: the
source-view PSNR with the scene's own tokens minus with the next scene's (in seed order, cyclic), the
same source cameras, steps and seed.  Issue 12's thresholds are ``HEALTH_THRESHOLDS``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import torch
from tqdm import tqdm

from vt4dcodec import codec
from vt4dcodec.errors import Vt4dError
from vt4dcodec.format import dumps
from vt4dcodec.media import psnr
from vt4dcodec.model import VideoTok4D
from vt4dcodec.model.diagnostics import psnr_db, token_health
from vt4dcodec.synth import SynthConfig, generate_scene
from vt4dcodec.synth.generator import SynthScene

from . import baselines
from .metrics import round_metric, video_metrics

__all__ = [
    "EvalSettings", "EvaluationError", "METHODS", "TOKEN_METHODS", "VIEW_SETS", "RIG_CAMERAS", "HEALTH_THRESHOLDS",
    "make_scene", "predict_scene", "score_scene", "representation_floats", "run_evaluation", "describe_model",
    "axis_angles_deg", "nearest_cameras", "set_targets", "set_sources", "parse_sets", "token_health_report",
    "MULTI_SETS", "MULTI_ENCODED", "ABLATIONS",
]

# method -> (label, (model key, drop_static, drop_dynamic)) for token methods
TOKEN_METHODS: dict[str, tuple[str, tuple[str, bool, bool]]] = {
    "ours": ("VideoTok4D (Z_s + Z_d)", ("main", False, False)),
    "ours_no_static": ("VideoTok4D w/o Z_s", ("main", True, False)),
    "ours_no_dynamic": ("VideoTok4D w/o Z_d", ("main", False, True)),
    "unified": ("Unified tokens (ablation)", ("unified", False, False)),
    "no_motion_isolation": ("w/o motion isolation (ablation)", ("no_motion", False, False)),
    "fixed_grid": ("Fixed-grid temporal attention (ablation)", ("fixed_grid", False, False)),
}
# Table 5's ablations: model key -> (config field, the value that makes the ablation, command-line flag)
ABLATIONS: dict[str, tuple[str, bool, str]] = {
    "unified": ("unified_tokens", True, "--unified"),
    "no_motion": ("motion_isolation", False, "--no-motion-isolation"),
    "fixed_grid": ("track_attention", False, "--fixed-grid"),
}
BASELINE_METHODS = {"nearest_frame": "Nearest source frame (view-bound)", "depth_warp": "Depth forward-warp (RGB-D)",
                    "mean_colour": "Flat source mean colour (reference)"}
METHODS: dict[str, str] = {**{k: v[0] for k, v in TOKEN_METHODS.items()}, **BASELINE_METHODS}
METRICS = ("psnr", "ssim", "psnr_dynamic", "psnr_static")
ENCODING = "int8"
VIEW_SETS = ("far", "near", "source", "multi-held", "multi-enc")
MULTI_SETS = ("multi-held", "multi-enc")
MULTI_ENCODED = (0, 2, 4, 6, 8)  # camera indices encoded together on the multi-camera sets
RIG_CAMERAS = 10  # cameras of the near/source rigs
NEAR_VIEWS = 2  # targets of the near set
# baselines that are trivially exact when the target is the source camera itself
SKIPPED_ON_SOURCE = ("nearest_frame", "depth_warp")
# issue 12, "Done when": never change these to make a model pass
HEALTH_THRESHOLDS = {"spread_min": 0.2, "swap_drop_min_db": 5.0}


class EvaluationError(Vt4dError, ValueError):
    """Inconsistent evaluation settings (models that do not fit the scenes, a merge with another protocol)."""


@dataclass(frozen=True)
class EvalSettings:
    """The protocol: which scenes, views and sampler settings.  Equal settings give equal numbers."""

    scenes: int = 50
    first_seed: int = 0
    views: int = 3
    steps: int | None = None  # None: each model's recorded decode_steps
    seed: int = 0
    num_cameras: int = 4
    frames: int = 8
    image_size: int = 64
    quality: int | None = None  # None: int8 tokens; N: learned-rans level N for models with quality levels

    def __post_init__(self) -> None:
        for key in ("scenes", "views", "steps", "frames", "image_size", "quality"):
            value = getattr(self, key)
            if (value is None and key not in ("steps", "quality")) or (value is not None and value < 1):
                raise EvaluationError(f"{key} must be >= 1")
        if self.num_cameras < self.views + 1:
            raise EvaluationError(f"num_cameras ({self.num_cameras}) must be at least views + 1 ({self.views + 1})")

    @property
    def seeds(self) -> list[int]:
        return list(range(self.first_seed, self.first_seed + self.scenes))

    def rig_cameras(self, view_set: str = "far") -> int:
        """Cameras per scene of a target set: ``num_cameras`` for "far", ``RIG_CAMERAS`` otherwise."""
        _check_set(view_set)
        return self.num_cameras if view_set == "far" else RIG_CAMERAS

    def steps_for(self, net: VideoTok4D) -> int:
        """The sampler steps a model renders with: ``steps``, or the model's recorded ``decode_steps``."""
        return int(net.decode_steps if self.steps is None else self.steps)


def _check_set(view_set: str) -> None:
    if view_set not in VIEW_SETS:
        raise EvaluationError(f"unknown view set {view_set!r}; choose from {list(VIEW_SETS)}")


def parse_sets(spec: str | Sequence[str]) -> tuple[str, ...]:
    """``"far,near"`` or a sequence -> the sets in ``VIEW_SETS`` order, each once."""
    names = [x.strip() for x in (spec.split(",") if isinstance(spec, str) else spec) if x.strip()]
    for name in names:
        _check_set(name)
    if not names:
        raise EvaluationError(f"no view set given; choose from {list(VIEW_SETS)}")
    return tuple(s for s in VIEW_SETS if s in names)


def make_scene(seed: int, settings: EvalSettings, view_set: str = "far") -> SynthScene:
    """The held-out test scene for ``seed`` (split="test": textures disjoint from training), with the
    rig of ``view_set`` (near and source share one 10-camera scene per seed)."""
    cfg = SynthConfig(num_cameras=settings.rig_cameras(view_set), num_frames=settings.frames,
                      height=settings.image_size, width=settings.image_size)
    return generate_scene(seed, split="test", config=cfg)


def axis_angles_deg(w2c: np.ndarray) -> np.ndarray:
    """(C, 4, 4) or (C, T, 4, 4) world-to-camera (first frame used) -> (C, C) angles in degrees between
    the cameras' optical axes (the z rows of the rotations): 0 = same viewing direction."""
    w = np.asarray(w2c, np.float64)
    z = (w[:, 0] if w.ndim == 4 else w)[:, 2, :3]
    z = z / np.linalg.norm(z, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip(z @ z.T, -1.0, 1.0)))


def nearest_cameras(capture: Any, source: str, k: int) -> list[tuple[str, float]]:
    """The ``k`` other cameras of ``capture`` whose first-frame optical axes are closest in direction to
    ``source``'s: [(name, angle in degrees)], closest first (ties in camera order)."""
    names = list(capture.camera_names)
    angles = axis_angles_deg(np.stack([capture.cameras[n].w2c[0] for n in names]))[names.index(source)]
    others = sorted((i for i, n in enumerate(names) if n != source), key=lambda i: (angles[i], i))
    if len(others) < k:
        raise EvaluationError(f"{source} has {len(others)} other cameras, {k} needed")
    return [(names[i], float(angles[i])) for i in others[:k]]


def set_sources(sc: SynthScene, view_set: str = "far") -> list[str]:
    """The cameras encoded for a target set: camera 0, or ``MULTI_ENCODED`` on the multi-camera sets."""
    _check_set(view_set)
    names = sc.capture.camera_names
    return [names[i] for i in MULTI_ENCODED] if view_set in MULTI_SETS else [names[0]]


def set_targets(sc: SynthScene, settings: EvalSettings, view_set: str = "far") -> tuple[str, list[str]]:
    """(source camera -- the first encoded one --, target cameras) of a scene for a target set."""
    names = sc.capture.camera_names
    _check_set(view_set)
    if view_set in MULTI_SETS:
        encoded = set_sources(sc, view_set)
        return encoded[0], encoded if view_set == "multi-enc" else [n for n in names if n not in encoded]
    if view_set == "far":
        return names[0], list(names[1:settings.views + 1])
    if view_set == "near":
        return names[0], [n for n, _ in nearest_cameras(sc.capture, names[0], NEAR_VIEWS)]
    return names[0], [names[0]]


# --- predictions ------------------------------------------------------------------------------------
def stored_quality(net: VideoTok4D, quality: int | None) -> int | None:
    """The quality level the protocol stores a model's tokens at: ``quality`` for a model with quality levels,
    None (int8, :data:`ENCODING`) otherwise -- the ablations have no entropy model."""
    return quality if quality is not None and codec.quality_levels(net) else None


def stored_encoding(net: VideoTok4D, quality: int | None) -> str:
    """How the protocol stores a model's tokens (:func:`stored_quality`), as a label: ``learned-rans qN`` or
    :data:`ENCODING`."""
    level = stored_quality(net, quality)
    return ENCODING if level is None else f"learned-rans q{level}"


def _render_tokens(net: VideoTok4D, sc: SynthScene, sources: Sequence[str], targets: Sequence[str],
                   settings: EvalSettings, variants: dict[str, tuple[bool, bool]]
                   ) -> tuple[dict[str, list[np.ndarray]], int, float, codec.SceneDecoder]:
    """Encode ``sources`` (one camera or several) into a .vt4d (:func:`stored_encoding`), decode the bytes,
    render every target per variant.

    Returns (variant -> videos, file bytes, seconds spent, the decoder of the stored bytes).
    """
    t0 = time.perf_counter()
    scene = codec.encode(sc.capture, net, ENCODING, cameras=list(sources), seed=settings.seed,
                         quality=stored_quality(net, settings.quality))
    blob = dumps(scene)  # a learned-rans scene's tables: registered by codec.encode
    decoder = codec.SceneDecoder.open(blob, model=net)
    trajectories = [sc.capture.cameras[k] for k in targets]
    videos = {name: decoder.render_many(trajectories, steps=settings.steps, seed=settings.seed,
                                        drop_static=ds, drop_dynamic=dd)
              for name, (ds, dd) in variants.items()}
    return videos, len(blob), time.perf_counter() - t0, decoder


def predict_scene(sc: SynthScene, settings: EvalSettings, methods: Sequence[str],
                  models: dict[str, VideoTok4D], view_set: str = "far",
                  decoders: dict[str, codec.SceneDecoder] | None = None) -> dict[str, dict[str, Any]]:
    """Every method's predicted videos of the target views (of ``view_set``) of one scene.

    Returns method -> {"videos": [per view (T, H, W, 3) uint8], "extra": [per view dict],
    "bytes": int | None, "seconds": float}.  On the "source" set the nearest-frame and depth-warp
    baselines are skipped (the target is the source).  ``decoders``, if given, receives each token
    model's decoder of the stored bytes (model key -> decoder), for the token-health report.
    """
    source, targets = set_targets(sc, settings, view_set)
    sources = set_sources(sc, view_set)
    if view_set == "source" or view_set in MULTI_SETS:
        methods = [m for m in methods if m not in SKIPPED_ON_SOURCE]
    src_frames, src_traj = sc.capture.frames[source], sc.capture.cameras[source]
    out: dict[str, dict[str, Any]] = {}
    for key in sorted({TOKEN_METHODS[m][1][0] for m in methods if m in TOKEN_METHODS}):
        variants = {m: TOKEN_METHODS[m][1][1:] for m in methods if m in TOKEN_METHODS and TOKEN_METHODS[m][1][0] == key}
        videos, nbytes, seconds, decoder = _render_tokens(models[key], sc, sources, targets, settings, variants)
        if decoders is not None:
            decoders[key] = decoder
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
        flat = baselines.mean_colour(np.concatenate([sc.capture.frames[k] for k in sources]))[:len(src_frames)]
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


def score_scene(sc: SynthScene, settings: EvalSettings, predictions: dict[str, dict[str, Any]],
                view_set: str = "far") -> list[dict[str, Any]]:
    """One row per (method, target view): set, seed, view, metrics, extra fields and bytes."""
    _, targets = set_targets(sc, settings, view_set)
    rows = []
    for method, pred in predictions.items():
        for i, k in enumerate(targets):
            metrics = video_metrics(pred["videos"][i], sc.capture.frames[k], sc.dynamic_mask[k])
            rows.append({"method": method, "set": view_set, "seed": sc.seed, "view": k,
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
    for key, (_, _, flag) in ABLATIONS.items():
        if "main" in models and key in models and models["main"].config.token_floats != models[key].config.token_floats:
            raise EvaluationError(f"the {flag} ablation must have the same token budget as the main model")


def describe_model(net: VideoTok4D, settings: EvalSettings | None = None) -> dict[str, Any]:
    """The model's identity and shape; ``decode_steps`` (its recorded default) and, with ``settings``,
    ``steps``: the sampler steps this evaluation rendered it with."""
    fp = codec.model_fingerprint(net)
    cfg = net.config
    info = {"fingerprint": fp.short(), "training_step": net.training_step, "config": cfg.name,
            "n_static": cfg.n_static, "n_dynamic": cfg.n_dynamic, "token_dim": cfg.token_dim,
            "unified_tokens": cfg.unified_tokens, "motion_isolation": cfg.motion_isolation,
            "track_attention": cfg.track_attention, "decode_steps": int(net.decode_steps)}
    if settings is not None:
        info["steps"] = settings.steps_for(net)
        info["encoding"] = stored_encoding(net, settings.quality)
    return info


# --- token health -----------------------------------------------------------------------------------
# the plain render of each token model
MODEL_METHOD = {"main": "ours", **{key: m for m, (_, (key, ds, dd)) in TOKEN_METHODS.items()
                                   if key != "main" and not (ds or dd)}}


def _unit_video(video: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(video)).float()[None] / 255.0


def token_health_report(items: dict[str, list[dict[str, Any]]], settings: EvalSettings, view_set: str
                        ) -> dict[str, Any]:
    """Token health of each token model over the scenes of ``view_set`` (see the module docstring).

    ``items``: model key -> per scene in seed order {"seed", "decoder" (of the stored int8 bytes),
    "trajectory" and "truth" (the source camera's), "own" (its source-view render, or None)}.
    """
    report: dict[str, Any] = {"set": view_set, "thresholds": dict(HEALTH_THRESHOLDS), "models": {}}
    for key, scenes in items.items():
        z_s = torch.stack([torch.from_numpy(np.asarray(x["decoder"].scene.static_tokens, np.float32)) for x in scenes])
        z_d = torch.stack([torch.from_numpy(np.asarray(x["decoder"].scene.dynamic_tokens, np.float32)) for x in scenes])
        entry: dict[str, Any] = {k: round_metric(v) for k, v in token_health(z_s, z_d).items()}
        entry["scenes"] = len(scenes)
        entry["spread_pass"] = bool(min(entry["static_spread"], entry["dynamic_spread"]) >= HEALTH_THRESHOLDS["spread_min"])
        if len(scenes) >= 2:
            own, swapped = [], []
            for i, x in enumerate(scenes):
                other = scenes[(i + 1) % len(scenes)]  # the next scene in seed order
                kwargs = {"steps": settings.steps, "seed": settings.seed}
                mine = x["own"] if x["own"] is not None else x["decoder"].render(x["trajectory"], **kwargs)
                theirs = other["decoder"].render(x["trajectory"], **kwargs)
                truth = _unit_video(x["truth"])
                own.append(float(psnr_db(_unit_video(mine), truth)[0]))
                swapped.append(float(psnr_db(_unit_video(theirs), truth)[0]))
            drops = np.array(own) - np.array(swapped)
            se = float(drops.std(ddof=1) / np.sqrt(drops.size))
            entry.update({"psnr_own_db": round_metric(float(np.mean(own))),
                          "psnr_swapped_db": round_metric(float(np.mean(swapped))),
                          "swap_drop_db": round_metric(float(drops.mean())), "swap_drop_se_db": round_metric(se),
                          "swap_pass": bool(drops.mean() >= HEALTH_THRESHOLDS["swap_drop_min_db"])})
        else:
            entry.update({"psnr_own_db": None, "psnr_swapped_db": None, "swap_drop_db": None,
                          "swap_drop_se_db": None, "swap_pass": None})
        report["models"][key] = entry
    return report


def health_set(sets: Sequence[str]) -> str:
    """The set whose scenes the token health is measured on: "source" (10-camera rigs), else the first."""
    return "source" if "source" in sets else ("near" if "near" in sets else sets[0])


# --- the run ----------------------------------------------------------------------------------------
def run_evaluation(settings: EvalSettings, models: dict[str, VideoTok4D], methods: Sequence[str], *,
                   sets: Sequence[str] = ("far",), figure_seeds: Sequence[int] = (), progress: bool = False
                   ) -> tuple[list[dict[str, Any]], dict[str, dict[int, dict[str, dict[str, Any]]]],
                              dict[str, float], dict[str, Any] | None]:
    """Predict and score every scene of every target set in ``sets``.

    Returns (rows, predictions of the ``figure_seeds`` scenes per set (set -> seed -> method ->
    prediction, plus the scene and its targets under key "scene"), wall seconds per method summed over
    scenes and sets (a token model's encode and renders are split evenly over the variants rendered
    from it), the token-health report of the token models used (None when no token method runs)).
    """
    _check_models(models, settings)
    sets = parse_sets(sets)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise EvaluationError(f"unknown methods {unknown}; choose from {list(METHODS)}")
    missing = sorted({TOKEN_METHODS[m][1][0] for m in methods if m in TOKEN_METHODS} - set(models))
    if missing:
        raise EvaluationError(f"methods {list(methods)} need models {missing}")
    seeds = settings.seeds
    iterator = seeds
    if progress:
        iterator = tqdm(seeds, desc="scenes", unit="scene")
    rows: list[dict[str, Any]] = []
    kept: dict[str, dict[int, dict[str, dict[str, Any]]]] = {s: {} for s in sets}
    seconds: dict[str, float] = {"generate": 0.0}
    health_on = health_set(sets)
    health_items: dict[str, list[dict[str, Any]]] = {}
    for seed in iterator:
        rigs: dict[int, SynthScene] = {}  # near and source share the 10-camera scene
        for view_set in sets:
            t0 = time.perf_counter()
            n = settings.rig_cameras(view_set)
            sc = rigs[n] if n in rigs else rigs.setdefault(n, make_scene(seed, settings, view_set))
            seconds["generate"] += time.perf_counter() - t0
            decoders: dict[str, codec.SceneDecoder] = {}
            preds = predict_scene(sc, settings, methods, models, view_set, decoders=decoders)
            for m, p in preds.items():
                seconds[m] = seconds.get(m, 0.0) + p["seconds"]
            rows.extend(score_scene(sc, settings, preds, view_set))
            if seed in figure_seeds:
                kept[view_set][seed] = {**preds, "scene": {"scene": sc, "targets": set_targets(sc, settings, view_set)[1]}}
            if view_set == health_on:
                source = set_targets(sc, settings, view_set)[0]
                for key, decoder in decoders.items():
                    own = preds[MODEL_METHOD[key]]["videos"][0] if view_set == "source" and MODEL_METHOD[key] in preds else None
                    health_items.setdefault(key, []).append({
                        "seed": seed, "decoder": decoder, "trajectory": sc.capture.cameras[source],
                        "truth": sc.capture.frames[source], "own": own})
    t0 = time.perf_counter()
    health = token_health_report(health_items, settings, health_on) if health_items else None
    if health is not None:
        seconds["token_health"] = time.perf_counter() - t0
    return rows, kept, {k: round(v, 2) for k, v in seconds.items()}, health
