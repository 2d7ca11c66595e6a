"""``vt4d generate``: sample one 4D token state from one camera of a capture with the Co4DGen prior,
save it as a ``.vt4d`` and render every requested view from that single sample."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from ..capture.io import read_capture, read_manifest
from ..capture.trajectories import check_trajectory_spec, describe_spec_presets
from ..codec import DEFAULT_STEPS, SceneDecoder, load_renderer, model_fingerprint
from ..errors import CaptureError, ModelError, ModelNotFoundError, TrajectoryError
from ..format import ENCODINGS, save
from ..generate import (DEFAULT_PRIOR, DEFAULT_PRIOR_STEPS, GENERATED_ENCODING, generate, load_prior_model,
                        sampler_setting)
from ..media import CAPTURE_KEY, VIDEO_FORMATS, write_frames
from . import (add_command, add_device_option, add_overwrite_option, add_upscale_option, check_output_folder,
               check_upscale, emit,
               nonneg_int, note_replacing, plural, positive_int, progress, trajectory_label, working)
from .codec_commands import render_in_batches

__all__ = ["register", "split_view_specs"]


def _generate_notes() -> str:
    return ("The anchor (--anchor) is the camera whose 4D token state the prior samples; presets are built from\n"
            "the conditioning camera's first pose.  Views (--views, comma-separated, or --views repeated) are\n"
            "rendered from the one sample; presets there are built from the anchor's first pose, \"source\" is\n"
            "the anchor itself.  Every argument is checked before the prior loads.  Presets, with their\n"
            "parameters and defaults (as in vt4d decode -t):\n"
            + describe_spec_presets("  ") + "\n"
            "Writes DIR/scene.vt4d (provenance \"generated\") and one video per view.\n")


GENERATE_EXAMPLES = [
    "vt4d generate demo_out/capture --anchor orbit:degrees=20 --views source,pan:degrees=15,orbit:degrees=-20 -o gen/",
    "vt4d generate cap --camera cam01 --anchor traj_a.json --views source,dolly_in --seed 3 --format png -o gen/",
]


def split_view_specs(values: list[str]) -> list[str]:
    """Comma-separated view lists -> specs; a piece ``key=value`` without ``:`` continues the previous
    preset's parameters (``orbit:degrees=30,distance=2,pan`` -> ``orbit:degrees=30,distance=2``, ``pan``)."""
    specs: list[str] = []
    for value in values:
        for piece in filter(None, (p.strip() for p in value.split(","))):
            if "=" in piece and ":" not in piece and specs and ":" in specs[-1]:
                specs[-1] += "," + piece
            elif "=" in piece and ":" not in piece:
                raise CaptureError(f"view {piece!r}: parameters need a preset first, e.g. orbit:{piece}")
            else:
                specs.append(piece)
    return specs


def guidance_scale(text: str) -> float:
    """argparse type of --guidance: a number in [0, 20]."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 20], got {text!r}") from None
    if not 0.0 <= value <= 20.0:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 20], got {text!r}")
    return value


def cmd_generate(args: argparse.Namespace) -> int:
    from ..model.directories import check_tokenizer  # torch-free: the prior may run on its exported graphs

    # every argument is checked before anything is loaded, sampled or written
    check_upscale(args)
    views = split_view_specs(args.views) or ["source"]
    for flag, spec in [("--anchor", args.anchor)] + [("--views", v) for v in views]:
        try:
            check_trajectory_spec(spec)
        except TrajectoryError as exc:
            raise TrajectoryError(f"{flag} {spec!r}: {exc}") from None
    out_dir = Path(args.output)
    if out_dir.exists() and not out_dir.is_dir():
        raise CaptureError(f"-o {out_dir} is a file; give a folder")
    check_output_folder("-o", out_dir)
    note_replacing(args, [out_dir / "scene.vt4d"])
    manifest = read_manifest(args.capture)
    camera = args.camera or manifest.camera_names[0]
    if camera not in manifest.camera_names:
        raise CaptureError(f"capture {manifest.capture_id!r} has no camera {camera!r} (--camera); it has "
                           f"{', '.join(manifest.camera_names)}")
    cap = read_capture(manifest, cameras=[camera])  # the conditioning camera alone
    loading = time.perf_counter()
    with working(args, "loading the prior and its tokenizer"):
        try:
            prior = load_prior_model(args.prior or DEFAULT_PRIOR, runtime=args.runtime, device=args.device)
        except ModelNotFoundError as exc:
            raise ModelNotFoundError(f"{exc}; pass --prior PATH (a prior directory)") from None
        tokenizer = load_renderer(args.model or prior.tokenizer_fingerprint.model_id, args.runtime, device=args.device)
        check_tokenizer(prior, model_fingerprint(tokenizer), networks=getattr(tokenizer, "network_digests", None),
                        sources=getattr(tokenizer, "token_sources", ()))  # before sampling: the renderer must fit the tokens
    started = time.perf_counter()
    try:
        steps, method, guidance = sampler_setting(prior, args.steps, args.sampler, args.guidance)
    except ModelError as exc:
        raise ModelError(f"--guidance {args.guidance}: {prior.model_id} {prior.model_version}: {exc}") from None
    with working(args, f"sampling the prior ({steps} {method} steps"
                       + ("" if guidance == 1.0 else f", guidance {guidance:g}") + ")"):
        scene = generate(cap.frames[camera], cap.cameras[camera], args.anchor, seed=args.seed, model=prior,
                         steps=steps, method=method, guidance=guidance, start=args.start, encoding=args.encoding,
                         metadata={"conditioning": {"capture_id": cap.capture_id, "camera": camera},
                                   CAPTURE_KEY: {"fps": float(cap.fps)}},
                         source_capture_id=cap.capture_id, runtime=args.runtime, device=args.device,
                         tokenizer=args.model or prior.tokenizer_fingerprint.model_id)
    sampled = time.perf_counter()
    out_dir.mkdir(parents=True, exist_ok=True)
    scene_path = out_dir / "scene.vt4d"
    size = save(scene, scene_path)
    decoder = SceneDecoder(scene=scene, model=tokenizer)
    trajectories = [decoder.trajectory(v) for v in views]
    outputs = []
    rendered = render_in_batches(decoder, trajectories, steps=args.render_steps, seed=args.seed)
    for i, (spec, traj, frames) in enumerate(progress(args, zip(views, trajectories, rendered), len(views), "render",
                                                      "view")):
        path = write_frames(out_dir / f"view_{trajectory_label(spec, i)}", frames, args.format, fps=cap.fps,
                            extra={"K": traj.K, "w2c": traj.w2c}, scale=args.upscale)
        outputs.append({"view": spec, "path": str(path), "frames": int(frames.shape[0])})
    done = time.perf_counter()
    result: dict[str, Any] = {
        "scene": str(scene_path), "bytes": size, "views": outputs, "seed": args.seed,
        "load_seconds": round(started - loading, 3), "sample_seconds": round(sampled - started, 3),
        "render_seconds": round(done - sampled, 3),
        "prior": {"model_id": prior.model_id, "model_version": prior.model_version},
        "sampler": {"method": method, "steps": steps, "guidance": guidance},
        "tokenizer": model_fingerprint(decoder.model).to_dict(),
    }
    emit(args, result, [f"sampled 1 token state in {result['sample_seconds']:.1f} s -> {scene_path} ({size} bytes); "
                        f"models loaded in {result['load_seconds']:.1f} s before that"]
         + [f"{o['view']} -> {o['path']}" for o in outputs]
         + [f"rendered {plural(len(outputs), 'view')} from the one sample in {result['render_seconds']:.1f} s"])
    return 0


def register(subparsers: Any) -> None:
    p = add_command(
        subparsers, "generate", help="sample a 4D token state from one video (Co4DGen) and render views from it",
        description="Condition the Co4DGen prior on one camera of a capture, sample the anchor camera's 4D token "
                    "state once, save it as a .vt4d and render every requested view from that one sample.",
        examples=GENERATE_EXAMPLES, notes=_generate_notes())
    p.add_argument("capture", help="capture directory (the conditioning video and its cameras)")
    p.add_argument("--anchor", default="source", help="anchor trajectory: preset spec, 'source' or JSON path")
    p.add_argument("--views", action="append", default=[], help="views to render (comma-separated; repeatable)")
    p.add_argument("-o", "--output", required=True, help="output directory")
    p.add_argument("--camera", help="conditioning camera (default: the capture's first camera)")
    p.add_argument("--start", type=nonneg_int, default=0, help="first frame of the clip (default 0)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="seed of the prior sample and the renders")
    p.add_argument("--prior", default=None, help="prior id or directory (default co4dgen-tiny)")
    p.add_argument("--model", default=None, help="tokenizer id or directory (default: the prior's tokenizer)")
    p.add_argument("--steps", type=positive_int, default=None,
                   help=f"prior sampler steps (default: the prior's recorded setting; {DEFAULT_PRIOR_STEPS} for a "
                        "prior that records none)")
    p.add_argument("--sampler", choices=("euler", "heun"), default=None,
                   help="prior sampler (default: the prior's recorded setting; heun for a prior that records none)")
    p.add_argument("--guidance", type=guidance_scale, default=None,
                   help="classifier-free guidance on the video, 0..20 (1: none; default: the prior's recorded setting); "
                        "needs a prior trained with a null condition")
    p.add_argument("--render-steps", type=positive_int, default=DEFAULT_STEPS, help="renderer steps per view (default: the tokenizer's recorded decode_steps)")
    p.add_argument("--encoding", choices=ENCODINGS, default=GENERATED_ENCODING,
                   help=f"token encoding of the saved scene (default {GENERATED_ENCODING}, as vt4d encode: within "
                        "0.07 dB of float32 tokens on generated scenes, half the bytes of int8)")
    p.add_argument("--format", choices=VIDEO_FORMATS, default="mp4", help="view output format")
    p.add_argument("--runtime", choices=("auto", "torch", "onnx"), default="auto",
                   help="runtime of the prior and the renderer: 'onnx' their exported graphs on onnxruntime without "
                        "torch, 'torch' the networks (the train extra); 'auto' (default) torch where it is installed, "
                        "else onnx")
    add_device_option(p, "the prior and the renderer")
    add_overwrite_option(p, "replace outputs that exist (without it they are replaced with a note)")
    add_upscale_option(p)
    p.set_defaults(func=cmd_generate)
