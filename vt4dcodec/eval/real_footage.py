"""Real-footage check for any capture: encode one camera (or several), render the others (or every
camera), and compare each render with that camera's real frames.

    python -m vt4dcodec.eval.real_footage --capture CAPTURE_DIR --source cam00 --target all \
        --out real.json --sheet real_sheet.png
    python -m vt4dcodec.eval.real_footage --model vt4d-tiny --out docs/results/real_caliscope.json \
        --figure docs/figures/real_caliscope.png
    python -m vt4dcodec.eval.real_footage --model vt4d-tiny --target source \
        --out docs/results/real_caliscope_source.json --figure docs/figures/real_caliscope_source.png

``--capture`` is a capture directory (``capture.json``: any capture, e.g. one made by ``vt4d import``;
each clip's frames are read as ``vt4d encode`` reads them, a clip at a time) or a caliscope recording
(``camera_array.toml``: imported in memory at the model's image size, every ``--frame-step``-th
frame).  The default is the caliscope_4cam sample (four static webcams, a person moving a ChArUco
board, 48 synchronized frames at ~6 fps).  ``--source`` names the encoded camera, or several
(comma-separated: one token set from all of them, ``encode(cameras=...)``); by default the source
and target are the pair whose optical axes are closest in direction (the pair that overlaps best).
``--target`` is one camera, ``source`` (the first encoded camera's own view: reconstruction) or
``all`` (every camera of the capture, encoded ones included).

The capture is cut into consecutive clips of the model's length (``--max-clips`` keeps the first N);
each clip is encoded exactly as ``vt4d encode`` does (int8 ``.vt4d``, fitted to the model's square by
``--fit crop|pad``; without capture depth ``prepare_source`` estimates it by plane sweep, which with
static cameras has no baseline and falls back to one constant depth), the bytes are decoded, and every
target camera's trajectory for the same frames is rendered and compared with its real frames, fitted
the same way (PSNR, SSIM).  References on the same clips: a flat image of the encoded clip's mean
colour (the structure-free reference; the summary states ours − flat), the nearest frame of the
encoded cameras (static cameras: the source frame at the same time) and the forward warp of the first
encoded camera with the same plane-sweep depth.  The last two are skipped for encoded cameras (there
they are trivially exact).  Results: one row per (clip, camera, method), a summary over every row and
one per camera; ``--sheet`` writes a contact sheet (per camera, its real frames above the render, first
clip) and ``--figure`` the single-target figure.  ``--steps`` defaults to the model's recorded
``decode_steps``; the steps used are recorded.
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import torch
from PIL import Image

from vt4dcodec import codec
from vt4dcodec.cameras import Trajectory
from vt4dcodec.capture.caliscope import find_sample_capture, import_caliscope
from vt4dcodec.capture.contact_sheet import contact_sheet
from vt4dcodec.capture.capture import Capture
from vt4dcodec.capture.io import MANIFEST_NAME, CaptureManifest, read_manifest
from vt4dcodec.capture.resample import FITS, fit_capture
from vt4dcodec.errors import CaptureError
from vt4dcodec.format import dumps

from vt4dcodec.model.inputs.depth import estimate_depth
from vt4dcodec.model.inputs.motion import DEFAULT_DEPTH_RANGE

from . import baselines
from .command import resolve_model, run_command
from .metrics import video_metrics
from .protocol import ENCODING, SKIPPED_ON_SOURCE, axis_angles_deg, stored_encoding
from .report import save_png_small, write_json

__all__ = ["DEFAULT_CAPTURE", "open_capture", "best_overlap_pair", "evaluate_cameras", "evaluate_real",
           "summarize_real", "summarize_by_camera", "save_real_figure", "save_contact_sheet", "main"]

DEFAULT_CAPTURE = str(find_sample_capture() or "caliscope_4cam")  # $VT4D_CALISCOPE or shared/data beside the repo
METHODS = ("ours", "nearest_frame", "depth_warp", "mean_colour")


def _trajectories(capture: "Capture | CaptureManifest") -> dict[str, Trajectory]:
    if isinstance(capture, Capture):
        return capture.cameras
    return {e.name: e.trajectory for e in capture.cameras}


def open_capture(path: str | Path, *, size: int, frame_step: int = 1, fit: str = "crop"
                 ) -> "Capture | CaptureManifest":
    """A capture directory as its manifest (clips are read as they are encoded), or a caliscope recording
    imported in memory at ``size`` x ``size`` (fitted by ``fit``), every ``frame_step``-th frame."""
    path = Path(path)
    if (path / MANIFEST_NAME).is_file():
        if frame_step != 1:
            raise CaptureError("--frame-step applies to caliscope recordings; a capture directory is read as it is")
        return read_manifest(path)
    if (path / "camera_array.toml").is_file():
        return import_caliscope(path, height=size, width=size, frame_step=frame_step, fit=fit)
    raise CaptureError(f"--capture {path}: neither a capture directory ({MANIFEST_NAME}) nor a caliscope recording "
                       "(camera_array.toml); make a capture with `vt4d import CALIBRATION MEDIA_DIR -o DIR`")


def axis_angle(capture: "Capture | CaptureManifest", a: str, b: str) -> float:
    """Angle in degrees between the first-frame optical axes (camera z in world) of cameras a and b."""
    cams = _trajectories(capture)
    return float(axis_angles_deg(np.stack([cams[a].w2c[0], cams[b].w2c[0]]))[0, 1])


def best_overlap_pair(capture: "Capture | CaptureManifest") -> tuple[str, str, float]:
    """(source, target, angle in degrees) of the two cameras whose first-frame optical axes are closest."""
    best = min(itertools.combinations(capture.camera_names, 2), key=lambda p: axis_angle(capture, *p))
    return best[0], best[1], axis_angle(capture, *best)


def _joined(trajs: list[Trajectory]) -> Trajectory:
    """Several equal-size trajectories as one (their frames one after another), for the nearest frame."""
    if len(trajs) == 1:
        return trajs[0]
    return Trajectory(K=np.concatenate([t.K for t in trajs]), w2c=np.concatenate([t.w2c for t in trajs]),
                      width=trajs[0].width, height=trajs[0].height)


def evaluate_cameras(capture: "Capture | CaptureManifest", net: Any, sources: Sequence[str], targets: Sequence[str],
                     *, steps: int | None = None, seed: int = 0, fit: str = "crop", max_clips: int | None = None,
                     quality: int | None = None, refine: int = 0, tune: str = "psnr"
                     ) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Encode every clip of ``sources`` (one token set), render each of ``targets``; returns (rows, clips).
    The tokens are stored as int8, or with ``quality`` = N (a model with quality levels) as learned-rans at
    level N, refined ``refine`` iterations at encode for ``tune`` (``codec.encode(refine=..., tune=...)``).

    Rows: ``method``, ``camera``, ``clip_start``, ``psnr``, ``ssim`` (and ``bytes``, ``seconds`` for ours;
    hole fraction and depth for the warp).  Clips: ``start``, ``source`` (the first source camera's
    fitted frames) and ``cameras``: target -> ``{"truth": real frames, "ours": render, ...references}``.
    ``steps`` None: the model's recorded ``decode_steps``."""
    T, size = net.config.frames, net.config.image_size
    sources, targets = list(sources), list(targets)
    starts = list(range(0, capture.num_frames - T + 1, T))[:max_clips]
    if not starts:
        raise CaptureError(f"the capture has {capture.num_frames} frames; the model's clips are {T}")
    names = sources + [t for t in targets if t not in sources]
    rows, clips = [], []
    for start in starts:
        t0 = time.perf_counter()
        scene = codec.encode(capture, net, ENCODING, cameras=sources, start=start, seed=seed, fit=fit, quality=quality,
                             refine=refine, tune=tune)
        blob = dumps(scene)  # a learned-rans scene's tables: registered by codec.encode
        decoder = codec.SceneDecoder.open(blob, model=net)
        clip = fit_capture(codec.read_clip(capture, names, start, T), height=size, width=size, fit=fit)
        renders = decoder.render_many([clip.cameras[t] for t in targets], steps=steps, seed=seed)
        seconds = time.perf_counter() - t0
        src = sources[0]
        src_frames, src_traj = clip.frames[src], clip.cameras[src]
        encoded_frames = np.concatenate([clip.frames[s] for s in sources])
        flat = baselines.mean_colour(encoded_frames)[:T]
        depth = None
        per_camera: dict[str, dict[str, np.ndarray]] = {}
        for target, ours in zip(targets, renders):
            truth = clip.frames[target]
            videos = {"ours": ours}
            warp = None
            if target not in sources:
                resolved = decoder.trajectory(clip.cameras[target])
                nearest, _ = baselines.nearest_source_frame(encoded_frames, _joined([clip.cameras[s] for s in sources]),
                                                            resolved)
                if depth is None:
                    depth = estimate_depth(src_frames, src_traj.K, src_traj.w2c, near=DEFAULT_DEPTH_RANGE[0],
                                           far=DEFAULT_DEPTH_RANGE[1])
                warp = baselines.forward_warp(src_frames, depth, src_traj, resolved)
                videos.update({"nearest_frame": nearest, "depth_warp": warp.frames})
            videos["mean_colour"] = flat
            no_dynamic = np.zeros(truth.shape[:3], bool)  # no ground-truth object masks for real footage
            for method, video in videos.items():
                m = video_metrics(video, truth, no_dynamic)
                rows.append({"method": method, "camera": target, "clip_start": start, "psnr": round(m["psnr"], 4),
                             "ssim": round(m["ssim"], 4),
                             **({"bytes": len(blob), "seconds": round(seconds, 2)} if method == "ours" else {}),
                             **({"hole_fraction": round(warp.hole_fraction, 4),
                                 "depth_median_m": round(float(np.median(depth)), 3)}
                                if method == "depth_warp" and warp is not None and depth is not None else {})})
            per_camera[target] = {"truth": truth, **videos}
        clips.append({"start": start, "source": src_frames, "cameras": per_camera})
    return rows, clips


def evaluate_real(capture: "Capture | CaptureManifest", net: Any, source: str, target: str, *,
                  steps: int | None = None, seed: int = 0) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """One source camera and one target (``target == source``: the encoded camera's own view, without the
    two trivially exact baselines): :func:`evaluate_cameras`, with each clip's videos for that target
    (``truth``, ``ours``, ...) at the top level of the clip, as :func:`save_real_figure` draws them."""
    rows, clips = evaluate_cameras(capture, net, [source], [target], steps=steps, seed=seed)
    return rows, [{"start": c["start"], "source": c["source"], **c["cameras"][target]} for c in clips]


def save_real_figure(path: str | Path, clips: list[dict[str, Any]], source: str, target: str,
                     rows_per_clip: Sequence[int] = (0, 4), max_clips: int = 3) -> Path:
    """PNG: rows = (clip, frame), columns source | target (real) | ours | nearest frame | depth warp."""
    matplotlib.use("Agg")
    picks = [(c, t) for c in clips[:max_clips] for t in rows_per_clip if t < len(c["truth"])]
    cols = [("source", f"source {source}"), ("truth", f"real {target}"), ("ours", "VideoTok4D"),
            ("nearest_frame", "nearest frame"), ("depth_warp", "depth warp"), ("mean_colour", "flat mean colour")]
    cols = [c for c in cols if clips and c[0] in clips[0]]
    fig, axes = plt.subplots(len(picks), len(cols), figsize=(1.1 * len(cols), 1.15 * len(picks)), squeeze=False)
    for r, (clip, t) in enumerate(picks):
        for c, (key, title) in enumerate(cols):
            ax = axes[r, c]
            ax.imshow(clip[key][t], interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(title, fontsize=6)
            if c == 0:
                ax.set_ylabel(f"frame {clip['start'] + t}", fontsize=6)
    fig.tight_layout(pad=0.2)
    return save_png_small(fig, path)


def summarize_real(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per method present: mean PSNR / SSIM over its rows (clips x cameras); and ``ours_minus_flat``: ours −
    the flat image (paired per clip and camera: mean, standard error, count)."""
    out: dict[str, Any] = {}
    for method in METHODS:
        rs = [r for r in rows if r["method"] == method]
        if rs:
            out[method] = {"psnr_mean": round(float(np.mean([r["psnr"] for r in rs])), 3),
                           "ssim_mean": round(float(np.mean([r["ssim"] for r in rs])), 4), "clips": len(rs)}
    flat = {(r["clip_start"], r.get("camera")): r["psnr"] for r in rows if r["method"] == "mean_colour"}
    d = np.array([r["psnr"] - flat[(r["clip_start"], r.get("camera"))] for r in rows
                  if r["method"] == "ours" and (r["clip_start"], r.get("camera")) in flat])
    if d.size:
        out["ours_minus_flat"] = {"psnr_mean": round(float(d.mean()), 3),
                                  "se": round(float(d.std(ddof=1) / math.sqrt(d.size)), 3) if d.size > 1 else None,
                                  "clips": int(d.size)}
    return out


def summarize_by_camera(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """:func:`summarize_real` of each camera's rows, in the order the cameras first appear."""
    cameras = list(dict.fromkeys(r.get("camera") for r in rows))
    return {str(c): summarize_real([r for r in rows if r.get("camera") == c]) for c in cameras}


def save_contact_sheet(path: str | Path, clip: dict[str, Any], *, thumb_height: int = 64) -> tuple[int, int]:
    """PNG (256 colours) of one clip: per target camera two rows, its real frames (``real:NAME``) above the
    render (``vt4d:NAME``), every frame of the clip across; returns its (width, height)."""
    frames: dict[str, np.ndarray] = {}
    for name, videos in clip["cameras"].items():
        frames[f"real:{name}"] = videos["truth"]
        frames[f"vt4d:{name}"] = videos["ours"]
    T, H, W = next(iter(frames.values())).shape[:3]
    traj = Trajectory(K=np.array([[W, 0, (W - 1) / 2], [0, W, (H - 1) / 2], [0, 0, 1.0]]), w2c=np.eye(4)[None],
                      width=W, height=H)
    sheet = contact_sheet(Capture(cameras={n: traj[np.zeros(T, int)] for n in frames}, frames=frames),
                          max_frames=T, thumb_height=thumb_height)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(sheet).quantize(256).save(path, optimize=True)
    return sheet.shape[1], sheet.shape[0]


def _camera_list(value: str, available: list[str], flag: str) -> list[str]:
    names = codec.parse_camera_list(value, available, label=flag)
    missing = [n for n in names if n not in available]
    if missing:
        raise CaptureError(f"{flag}: the capture has no camera {missing[0]!r}; it has {available}")
    return names


def _quality(value: str | None, net: Any) -> int | None:
    """The quality level ``--quality`` asks for (None: int8): ``N``, ``int8``, or by default the level the codec
    stores a model's tokens at (:func:`codec.default_quality`; int8 for a model without levels)."""
    levels = codec.quality_levels(net)
    if value is None:
        return codec.default_quality(net) if levels else None
    if value == "int8":
        return None
    if not value.isdigit() or int(value) not in levels:
        have = f"a level {levels[0]} .. {levels[-1]} or int8" if levels else "int8 (the model has no quality levels)"
        raise CaptureError(f"--quality must be {have}, got {value!r}")
    return int(value)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m vt4dcodec.eval.real_footage", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default="vt4d-tiny", help="shipped id, model directory or training run directory")
    p.add_argument("--capture", default=DEFAULT_CAPTURE,
                   help="a capture directory (capture.json, e.g. from `vt4d import`) or a caliscope recording "
                        "(camera_array.toml); default: the caliscope_4cam sample")
    p.add_argument("--source", default=None, help="encoded camera, or several comma-separated (one scene from all "
                   "of them); default: the best-overlapping pair's first camera")
    p.add_argument("--target", default=None, help="camera to render and compare (default: the best-overlapping "
                   "pair's other camera), 'source' (the first encoded camera's own view) or 'all' (every camera)")
    p.add_argument("--fit", choices=FITS, default="crop", help="frames that are not square: centre-crop (default) or "
                   "pad (letterbox)")
    p.add_argument("--max-clips", type=int, default=None, help="evaluate only the first N clips (default: all)")
    p.add_argument("--frame-step", type=int, default=1, help="caliscope recordings: keep every N-th frame")
    p.add_argument("--steps", type=int, default=None, help="sampler steps (default: the model's recorded "
                   "decode_steps)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quality", default=None, metavar="N|int8",
                   help="how the tokens are stored: learned-rans at quality level N of the model, or int8 (default: "
                        "the model's default level, as `vt4d encode` stores them; int8 for a model without levels)")
    p.add_argument("--refine", type=int, default=0, metavar="N",
                   help="refine the tokens N iterations at encode for their quality level (vt4d encode --refine)")
    p.add_argument("--tune", choices=codec.TUNES, default="psnr",
                   help="what --refine optimises (vt4d encode --tune)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", default="docs/results/real_caliscope.json")
    p.add_argument("--figure", default=None, help="PNG of the first target: source | real | ours | references")
    p.add_argument("--sheet", default=None, help="contact sheet PNG of the first clip: per camera, real over render")
    args = p.parse_args(argv)
    return run_command(lambda: _run(args, argv))


def _run(args: argparse.Namespace, argv: Sequence[str] | None) -> int:
    torch.set_num_threads(max(1, args.threads))
    if args.max_clips is not None and args.max_clips < 1:
        raise CaptureError(f"--max-clips must be at least 1, got {args.max_clips}")
    if args.frame_step < 1:
        raise CaptureError(f"--frame-step must be at least 1, got {args.frame_step}")
    net = resolve_model(args.model).eval()
    quality = _quality(args.quality, net)
    size = net.config.image_size
    t0 = time.perf_counter()
    capture = open_capture(args.capture, size=size, frame_step=args.frame_step, fit=args.fit)
    available = capture.camera_names
    pair = best_overlap_pair(capture) if len(available) > 1 else (available[0], available[0], 0.0)
    sources = _camera_list(args.source, available, "--source") if args.source else [pair[0]]
    if args.target == "source":
        targets, mode = [sources[0]], "source"
    elif args.target == "all":
        targets, mode = list(available), "all cameras"
    else:
        default = pair[1] if pair[1] not in sources else next((c for c in available if c not in sources), None)
        targets = _camera_list(args.target, available, "--target") if args.target else [default]
        mode = "other camera"
        if targets == [None] or set(targets) & set(sources):
            raise CaptureError(f"need a target camera other than the encoded {sources} (--target CAM), or --target "
                               f"source / all; the capture has {available}")
    steps = int(net.decode_steps if args.steps is None else args.steps)
    rows, clips = evaluate_cameras(capture, net, sources, targets, steps=steps, seed=args.seed, fit=args.fit,
                                   quality=quality, max_clips=args.max_clips, refine=args.refine,
                                   tune=args.tune)
    wall = time.perf_counter() - t0
    source, target = sources[0], targets[0] if len(targets) == 1 else "all"
    results = {
        "command": "python -m vt4dcodec.eval.real_footage " + " ".join(sys.argv[1:] if argv is None else argv),
        "capture": str(args.capture), "capture_id": capture.capture_id, "source": source, "target": target,
        "sources": sources, "targets": targets, "target_mode": mode,
        "axis_angle_deg": {t: round(axis_angle(capture, source, t), 2) for t in targets} if len(targets) > 1
        else round(axis_angle(capture, source, targets[0]), 2),
        "frames": capture.num_frames, "fps": capture.fps, "fit": args.fit,
        "image_size": size, "clip_frames": net.config.frames, "clips": len(clips), "steps": steps,
        "decode_steps": int(net.decode_steps), "seed": args.seed,
        "encoding": stored_encoding(net, quality), "refine": args.refine, "tune": args.tune,
        "model": codec.model_fingerprint(net).short(), "training_step": net.training_step,
        "wall_s": round(wall, 1), "summary": summarize_real(rows), "summary_by_camera": summarize_by_camera(rows),
        "rows": rows,
    }
    out = write_json(args.out, results)
    if args.figure:
        save_real_figure(args.figure, [{"start": c["start"], "source": c["source"], **c["cameras"][targets[0]]}
                                       for c in clips], source, targets[0])
    if args.sheet:
        save_contact_sheet(args.sheet, clips[0])
    _print_results(results, sources)
    print(f"{'+'.join(sources)} -> {', '.join(targets)}; {len(clips)} clip(s); steps {steps}; wall {wall:.1f} s; "
          f"results -> {out}")
    return 0


def _print_results(results: dict[str, Any], sources: list[str]) -> None:
    by_camera = results["summary_by_camera"]
    if len(by_camera) > 1:
        print(f"{'camera':12s} {'':8s} " + "  ".join(f"{m:>20s}" for m in METHODS))
        for camera, s in by_camera.items():
            cells = [f"{s[m]['psnr_mean']:6.2f} dB {s[m]['ssim_mean']:6.3f}" if m in s else "-" for m in METHODS]
            print(f"{camera:12s} {'encoded' if camera in sources else '':8s} " + "  ".join(f"{c:>20s}" for c in cells))
        print("(PSNR and SSIM against each camera's real frames; the references are skipped for encoded cameras)")
        return
    summary = results["summary"]
    for method in METHODS:
        if method in summary:
            s = summary[method]
            print(f"{method:14s} PSNR {s['psnr_mean']:.2f} dB  SSIM {s['ssim_mean']:.3f}  ({s['clips']} clips)")
    if results["targets"][0] in sources:
        print(f"{', '.join(SKIPPED_ON_SOURCE)}: skipped (exact when the target is an encoded camera)")
    if "ours_minus_flat" in summary:
        d = summary["ours_minus_flat"]
        se = f" ± {d['se']:.2f}" if d["se"] is not None else ""
        print(f"ours - flat image: {d['psnr_mean']:+.2f}{se} dB over {d['clips']} clips (flat mean colour "
              f"{summary['mean_colour']['psnr_mean']:.2f} dB)")


if __name__ == "__main__":
    raise SystemExit(main())
