"""``vt4d encode``, ``vt4d decode``, ``vt4d demo``: the codec from the command line."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any, Iterator, Sequence

from .. import codec
from ..archive import ArchiveWriter, is_archive, open_archive
from ..capture.io import MANIFEST_NAME, read_manifest
from ..capture.resample import FITS
from ..capture.trajectories import check_trajectory_spec, describe_spec_presets
from ..codec import (DEFAULT_ENCODING, DEFAULT_MODEL, DEFAULT_STEPS, SceneDecoder, iter_capture_dirs, model_fingerprint,
                     parse_camera_list)
from ..demo import run_demo
from ..errors import ArchiveError, CaptureError, MissingExtraError, ModelError
from ..format import ENCODINGS, dumps, load, save
from ..media import CAPTURE_KEY, VIDEO_FORMATS, scene_fps, write_frames
from . import (EXIT_INTERRUPTED, add_budget_option, add_command, add_deprecated_flag, add_device_option,
               add_overwrite_option, add_storage_option,
               add_upscale_option, check_output_file, check_output_folder, check_upscale, emit, nonneg_int,
               note_replacing, plural, positive_int, progress, read_head, storage_options, trajectory_label, working)

__all__ = ["register"]

ENCODE_EXAMPLES = [
    "vt4d encode demo_out/capture -o scene.vt4d                 one capture -> one scene file",
    "vt4d encode demo_out/capture --camera cam03 --start 0 -o s.vt4d",
    "vt4d encode demo_out/capture --cameras cam00,cam02,cam04 -o multi.vt4d   one scene from 3 cameras",
    "vt4d encode portrait_capture --fit pad -o s.vt4d           keep the whole portrait frame (black bars)",
    "vt4d encode captures/ --archive train.vt4da                every capture dir under captures/ -> one archive",
    "vt4d encode captures/ --archive train.vt4da -y             again, replacing the scenes already there",
    "vt4d encode long_capture --split --archive clips.vt4da     a long capture -> consecutive 8-frame clips",
    "torchrun --nproc_per_node=4 -m vt4dcodec encode captures/ --archive shards/train.vt4da",
    "                                                           each rank encodes its share into its own shard",
    "                                                           (train-rank00000-of-00004.vt4da, ...)",
]
ENCODE_NOTES = """\
A model encodes clips of exactly its frame count (vt4d-tiny: 8 frames at 64x64).  Larger frames are
undistorted, resized and centre-cropped with the intrinsics updated (--fit pad: letterboxed instead,
keeping the whole picture); longer captures take the clip at --start, or all consecutive clips with
--split (a shorter tail is dropped).  Only the clip's frames of the encoded cameras are read (videos
are seeked): the cost follows the clip, not the length of the capture.  Archive keys are
CAPTURE_ID/CAMERA/CLIP_START (CAMERA: the encoded cameras joined by '.', or 'all').  The time printed is the encoding alone; loading the model is timed apart.
"""


def _decode_notes() -> str:
    return ("trajectories (-t, repeatable; one output per trajectory):\n"
            "  source                       the scene's own source cameras\n"
            "  camera:NAME                  capture camera NAME over the scene's clip (needs --capture DIR)\n"
            "  path/to/trajectory.json      a saved trajectory (vt4dcodec.capture.trajectories.save_trajectory)\n"
            "  PRESET[:KEY=VALUE,...]       built from the first source camera; presets with their parameters\n"
            "                               and defaults (metres, degrees; num_frames=N sets the length):\n"
            + describe_spec_presets("    ") + "\n"
            "  (interpolate, which needs a target camera, is for Python or a saved JSON.)\n"
            "SOURCE may be a local path or a URL (http://, s3://, memory://...; fsspec).\n")


DECODE_EXAMPLES = [
    "vt4d decode scene.vt4d -t source -t orbit:degrees=30 -o out/",
    "vt4d decode train.vt4da --key scene-000042 -t dolly_in:metres=0.5 --format png -o out/",
    "vt4d decode https://example.org/scene.vt4d -t pan:degrees=15 -o out/",
    "vt4d decode scene.vt4d --capture capture/ -t camera:cam05 -o out/",
]


def _dist_rank() -> tuple[int, int]:
    """(rank, world size) from torchrun's environment; (0, 1) when not launched by torchrun."""
    try:
        rank, world = int(os.environ.get("RANK", "0")), int(os.environ.get("WORLD_SIZE", "1"))
    except ValueError:
        raise CaptureError("RANK and WORLD_SIZE must be integers") from None
    if not 0 <= rank < world:
        raise CaptureError(f"RANK {rank} is outside WORLD_SIZE {world}")
    return rank, world


def _shard_path(path: str, rank: int, world: int) -> str:
    if world == 1:
        return path
    stem, ext = os.path.splitext(path)
    return f"{stem}-rank{rank:05d}-of-{world:05d}{ext or '.vt4da'}"


def _captures(inputs: list[str]) -> list[Path]:
    found: list[Path] = []
    for item in inputs:
        p = Path(item)
        if (p / MANIFEST_NAME).is_file():
            found.append(p)
        elif p.is_dir():
            found.extend(iter_capture_dirs(p))
        else:
            raise CaptureError(f"{item} is not a capture directory (no {MANIFEST_NAME}) nor a directory of captures")
    if not found:
        raise CaptureError(f"no capture directories found in {inputs}")
    return found


def _check_cameras(captures: list[Path], camera: str | None, cameras: str | None = None) -> int:
    """--camera / --cameras name cameras of every capture (read from the manifests: cheap). Returns the most
    cameras one scene encodes."""
    if camera is not None and cameras is not None:
        raise CaptureError("give --camera (one camera) or --cameras (several), not both")
    if camera is None and cameras is None:
        return 1
    flag = "--camera" if camera is not None else "--cameras"
    most = 1
    for cap_dir in captures:
        names = [e.name for e in read_manifest(cap_dir).cameras]
        wanted = [camera] if camera is not None else parse_camera_list(cameras, names, label="--cameras")
        missing = [c for c in wanted if c not in names]
        if missing:
            raise CaptureError(f"{cap_dir} has no camera {missing[0]!r} ({flag}); it has {', '.join(names)}")
        most = max(most, len(wanted))
    return most


COMMIT_SECONDS = 10.0  # encode --archive commits at the first capture boundary after this long


def _scene_key(cap: Any, names: list[str], start: int) -> str:
    """The archive key of a scene: CAPTURE_ID/CAMERAS/CLIP_START (CAMERAS 'all' for every camera of the capture)."""
    encoded = "all" if len(names) > 1 and len(names) == len(cap.camera_names) else ".".join(names)
    return f"{cap.capture_id}/{encoded}/{int(start):06d}"


def _expected_keys(cap: Any, args: argparse.Namespace, frames: int) -> list[str]:
    """The keys encoding ``cap`` will write (read from its manifest, before any encoding), for --skip-existing."""
    if args.cameras is not None:
        names = parse_camera_list(args.cameras, cap.camera_names, label="--cameras")
    else:
        names = [args.camera or cap.camera_names[0]]
    starts = range(0, cap.num_frames - frames + 1, frames) if args.split else [args.start]
    return [_scene_key(cap, names, s) for s in starts]


def _check_keys_free(args: argparse.Namespace, captures: list[Path], taken: Any, frames: int, archive: str) -> None:
    """Before any encoding: a scene this run would write whose key the archive holds needs -y/--overwrite
    (encode it again) or --skip-existing (keep it)."""
    if args.replace or args.overwrite or args.skip_existing:
        return
    for cap_dir in captures:
        for key in _expected_keys(read_manifest(cap_dir), args, frames):
            if key in taken:
                raise ArchiveError(f"scene {key!r} is already in {archive}: pass -y/--overwrite to encode it "
                                   "again, or --skip-existing to keep it and encode the rest")


def _save_keeping_mode(scene: Any, path: str) -> int:
    """save(scene, path), keeping the permission bits of a file it replaces (save writes a new file and
    renames it over the old one, which would otherwise get the default mode)."""
    try:
        mode = os.stat(path).st_mode & 0o7777
    except FileNotFoundError:
        mode = None
    n = save(scene, path)
    if mode is not None:
        os.chmod(path, mode)
    return n


def _refine_runtime(args: argparse.Namespace) -> str:
    """The encoder runtime of ``vt4d encode``: --runtime, or torch where --refine asks for the torch model
    (checked before any work: a quality level, torch installed, not --runtime onnx)."""
    if not args.refine:
        if args.tune != "psnr":
            raise ModelError(f"--tune {args.tune} sets what refinement optimises: give --refine N with it")
        return str(args.runtime)
    if args.encoding is not None and args.quality is None:
        raise ModelError("--refine refines the stored values of a quality level: give --quality Q instead of "
                         "--encoding (or leave both out for the model's default level)")
    if args.runtime == "onnx":
        raise ModelError("--refine runs the torch networks: leave --runtime out (or give --runtime torch), or drop "
                         "--refine to encode on onnxruntime")
    if not codec.torch_available():
        raise MissingExtraError(f"--refine needs torch, which is not installed: {codec.TRAIN_EXTRA_HINT}; or drop "
                                "--refine")
    return "torch"


def cmd_encode(args: argparse.Namespace) -> int:
    if args.output is None and args.archive is None:
        raise CaptureError("give -o FILE.vt4d (one scene) or --archive FILE.vt4da (many scenes)")
    if args.output is not None and args.archive is not None:
        raise CaptureError("give -o FILE.vt4d or --archive FILE.vt4da, not both")
    if args.replace and args.archive is None:
        raise CaptureError("--replace applies to --archive; an existing -o FILE.vt4d is replaced with -y/--overwrite")
    if args.skip_existing and args.archive is None:
        raise CaptureError("--skip-existing applies to --archive")
    if args.skip_existing and (args.replace or args.overwrite):
        raise CaptureError("give --skip-existing (keep the scenes there) or -y/--overwrite (encode them again), "
                           "not both")
    if args.output is not None:  # output paths checked before any work
        check_output_file("-o", args.output, ".vt4d", "a scene file",
                          "--archive FILE.vt4da writes an archive" if args.output.lower().endswith(".vt4da")
                          else "videos are rendered from it by `vt4d decode`" if args.output.lower().endswith(
                              (".mp4", ".png", ".npz", ".mov", ".mkv", ".webm", ".avi")) else "")
    else:
        check_output_file("--archive", args.archive, ".vt4da", "an archive",
                          "-o FILE.vt4d writes one scene" if args.archive.lower().endswith(".vt4d") else "")
    runtime = _refine_runtime(args)
    captures = _captures(args.captures)
    if args.archive is None and (len(captures) > 1 or args.split):
        raise CaptureError("several captures or --split make several scenes: write them with --archive FILE.vt4da")
    views = _check_cameras(captures, args.camera, args.cameras)  # before the model loads
    rank, world = _dist_rank()
    mine = captures[rank::world]
    if args.output is not None:
        note_replacing(args, [args.output])
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)  # like --archive: the folder is made
    elif not args.split and os.path.isfile(_shard_path(args.archive, rank, world)):
        with open_archive(_shard_path(args.archive, rank, world)) as reader:  # keys taken: before the model loads
            _check_keys_free(args, mine, set(reader.keys()), 0, reader.name)
    loading = time.perf_counter()
    with working(args, f"loading {args.model or codec.DEFAULT_MODEL}"):
        model = codec.load_encoder(args.model or codec.DEFAULT_MODEL, runtime, cameras=views, device=args.device)
    started = time.perf_counter()
    results: list[dict[str, Any]] = []
    writer = None
    if args.archive is not None:
        shard = Path(_shard_path(args.archive, rank, world))
        shard.parent.mkdir(parents=True, exist_ok=True)  # e.g. shards/ on a fresh cluster job
        writer = ArchiveWriter(shard)
        if args.split:  # the clip starts follow the model's frame count
            try:
                _check_keys_free(args, mine, writer, model.config.frames, str(shard))
            except BaseException:
                writer.close(commit=False)
                raise
    committed_at, skipped = time.monotonic(), []
    try:
        for cap_dir in progress(args, mine, len(mine), "encode", "capture"):
            cap = read_manifest(cap_dir)  # the encode reads only each clip's frames of the encoded cameras
            if writer is not None and args.skip_existing:
                keys = _expected_keys(cap, args, model.config.frames)
                if keys and all(k in writer for k in keys):  # encoded by an earlier run: nothing to do
                    skipped.extend(keys)
                    continue
            recorded = {CAPTURE_KEY: {"fps": float(cap.fps)}}  # decoded videos play at the capture's rate
            if args.split:
                scenes = codec.encode_clips(cap, model, args.encoding, camera=args.camera, cameras=args.cameras,
                                            seed=args.seed, fit=args.fit, metadata=recorded, quality=args.quality,
                                            refine=args.refine, tune=args.tune)
            else:
                scenes = [codec.encode(cap, model, args.encoding, camera=args.camera, cameras=args.cameras,
                                       start=args.start, seed=args.seed, fit=args.fit, metadata=recorded,
                                       quality=args.quality, refine=args.refine, tune=args.tune)]
            for scene in scenes:
                info = scene.metadata["vt4d"]
                if writer is not None:
                    key = _scene_key(cap, info.get("source_cameras", [info["source_camera"]]), info["clip_start"])
                    if args.skip_existing and key in writer:
                        skipped.append(key)
                        continue
                    data = dumps(scene)
                    # the encoder's own output: checked as a container, never refused by the reading budget
                    writer.append(key, data, replace=args.replace or args.overwrite, max_decoded_bytes=None)
                    results.append({"key": key, "bytes": len(data), "capture": str(cap_dir)})
                else:
                    n = _save_keeping_mode(scene, args.output)
                    results.append({"file": args.output, "bytes": n, "capture": str(cap_dir)})
            if writer is not None and time.monotonic() - committed_at >= COMMIT_SECONDS:
                writer.commit()  # periodic commits: a crash or Ctrl-C loses at most the last few scenes
                committed_at = time.monotonic()
        if writer is not None:
            writer.commit()
    except KeyboardInterrupt:
        if writer is None:
            raise
        writer.commit()  # keep every scene finished so far (a capture is appended whole, after its encode)
        kept = len(results)
        print(f"vt4d encode: interrupted: kept the {plural(kept, 'scene')} this run encoded in {writer.path} "
              f"({plural(len(writer), 'scene')} in all); run the same command with --skip-existing to encode "
              "the rest", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        if writer is not None:
            writer.close(commit=False)
    elapsed = time.perf_counter() - started
    fp = codec.model_fingerprint(model)
    quality = args.quality if args.quality is not None or args.encoding is not None else codec.default_quality(model)
    load_s = started - loading
    summary = {"scenes": results, "seconds": round(elapsed, 3), "load_seconds": round(load_s, 3),
               "model": fp.to_dict(), "encoding": "learned-rans" if quality else args.encoding or DEFAULT_ENCODING,
               "quality": quality, "refine": args.refine, "tune": args.tune, "rank": rank, "world_size": world,
               "archive": _shard_path(args.archive, rank, world) if args.archive else None, "skipped": skipped}
    lines = [f"{r.get('key') or r['file']}: {r['bytes']} bytes  (from {r['capture']})" for r in results]
    if skipped:
        lines.append(f"skipped {plural(len(skipped), 'scene')} already in the archive (--skip-existing)")
    lines.append(f"encoded {plural(len(results), 'scene')} with {fp.short()} in {elapsed:.1f} s "
                 f"(model loaded in {load_s:.1f} s before that)")
    emit(args, summary, lines)
    return 0


def _open_scene_source(args: argparse.Namespace):
    """(scene, file-name stem) from a local path or URL: a scene file, or an archive with --key."""
    source, key = args.source, args.key
    if "::" in source and key is None:
        source, key = source.split("::", 1)
    options = storage_options(args.storage_option)
    stem = Path(source.split("?")[0].rstrip("/")).stem
    if is_archive(read_head(source, options)):
        if key is None:
            raise CaptureError(f"{source} is an archive: pick a scene with --key KEY (see `vt4d ls {source}`)")
        with open_archive(source, allow_truncated=args.allow_truncated, max_decoded_bytes=args.max_decoded_bytes,
                          **options) as ar:
            return ar.load(key), f"{stem}_{key.replace('/', '_')}"
    if key is not None:
        raise CaptureError(f"{source} is a single scene file; --key applies to archives only")
    return load(source, max_decoded_bytes=args.max_decoded_bytes, **options), stem


FILE_FORMATS = {".mp4": "mp4", ".npz": "npz"}  # decode -o NAME.mp4 / NAME.npz: one trajectory, that file


def _decode_target(args: argparse.Namespace, count: int) -> Path | None:
    """The file ``-o`` names (``-o v.mp4`` with one trajectory), or None for a folder of outputs; sets
    args.format from the file's extension.  Checked before the scene is read or a model loaded."""
    out = Path(args.output)
    fmt = FILE_FORMATS.get(out.suffix.lower())
    if fmt is None or out.is_dir():
        args.format = args.format or "mp4"
        if out.exists() and not out.is_dir():
            raise CaptureError(f"-o {out} is a file; give a folder for the outputs, or a .mp4/.npz name for one "
                               "trajectory")
        check_output_folder("-o", out)
        return None
    if args.format not in (None, fmt):
        raise CaptureError(f"-o {out} names a .{fmt} file but --format is {args.format}; give a folder for "
                           f"--format {args.format}")
    if count != 1:
        raise CaptureError(f"-o {out} names one file, but {count} trajectories are rendered; give a folder "
                           "(-o DIR) for one output per trajectory")
    check_output_folder("-o", out.parent)
    args.format = fmt
    return out


def render_in_batches(decoder: SceneDecoder, trajectories: Sequence[Any], **options: Any) -> Iterator[Any]:
    """The views of ``trajectories`` in order, rendered ``codec.RENDER_BATCH`` at a time (one forward pass each:
    ``SceneDecoder.render_many``), so several trajectories render as batches while a progress bar still moves
    and each output is written as its batch is done."""
    for start in range(0, len(trajectories), codec.RENDER_BATCH):
        yield from decoder.render_many(list(trajectories[start:start + codec.RENDER_BATCH]), **options)


def cmd_decode(args: argparse.Namespace) -> int:
    specs = args.trajectory or ["source"]
    target = _decode_target(args, len(specs))
    check_upscale(args)
    for spec in specs:  # every spec checked before the scene is read or a model loaded
        check_trajectory_spec(spec)
    scene, stem = _open_scene_source(args)
    ext = "" if args.format == "png" else "." + args.format  # PNG frames go to a folder per trajectory
    names = [target] if target is not None else [Path(args.output) / f"{stem}_{trajectory_label(spec, i)}{ext}"
                                                 for i, spec in enumerate(specs)]
    note_replacing(args, names)
    loading = time.perf_counter()
    with working(args, "loading the model"):
        decoder = SceneDecoder.open(scene, model=args.model, force=args.force, runtime=args.runtime,
                                    device=args.device)
    trajectories = [decoder.trajectory(s, capture=args.capture) for s in specs]  # fail on a bad spec before any rendering
    out_dir = Path(args.output) if target is None else target.parent
    out_dir.mkdir(parents=True, exist_ok=True)
    fps = scene_fps(scene)  # the capture's frame rate, as the file records it
    started = time.perf_counter()
    outputs = []
    views = render_in_batches(decoder, trajectories, steps=args.steps, seed=args.seed,
                              drop_static=args.drop == "static", drop_dynamic=args.drop == "dynamic")
    for i, (spec, traj, frames) in enumerate(progress(args, zip(specs, trajectories, views), len(specs), "decode",
                                                      "trajectory")):
        path = write_frames(names[i], frames, args.format, fps=fps, extra={"K": traj.K, "w2c": traj.w2c},
                            scale=args.upscale)
        outputs.append({"trajectory": spec, "path": str(path), "frames": int(frames.shape[0])})
    elapsed = time.perf_counter() - started
    load_s = started - loading
    result = {"outputs": outputs, "seconds": round(elapsed, 3), "load_seconds": round(load_s, 3), "fps": fps,
              "steps": decoder.model.decode_steps if args.steps is None else args.steps, "seed": args.seed,
              "model": model_fingerprint(decoder.model).to_dict()}
    emit(args, result, [f"{o['trajectory']} -> {o['path']}" for o in outputs]
         + [f"rendered {plural(len(outputs), 'trajectory', 'trajectories')} in {elapsed:.1f} s (model loaded in {load_s:.1f} s before that)"])
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    result = run_demo(args.output, model=args.model or DEFAULT_MODEL, seed=args.seed, steps=args.steps,
                      overwrite=args.overwrite, upscale=args.upscale, log=None if args.json or args.quiet else print)
    emit(args, result)
    return 0




def register(subparsers: Any) -> None:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--model", default=None,
                        help="model id or model directory (encode default: vt4d-tiny; decode default: the "
                             "model named by the file's fingerprint)")
    common.add_argument("--seed", type=nonneg_int, default=0, help="random seed (default 0)")

    p = add_command(
        subparsers, "encode", parents=[common], help="compress capture directories into .vt4d scenes or an archive",
        description="Encode one camera, or several synchronized cameras, of a capture (a clip of the model's "
                    "frame count) into a .vt4d scene: one token set per scene, whatever the number of cameras.",
        examples=ENCODE_EXAMPLES, notes=ENCODE_NOTES)
    p.add_argument("captures", nargs="+", help="capture directories, or directories holding capture directories")
    p.add_argument("-o", "--output", help="output .vt4d file (one capture, one clip); its folder is created")
    p.add_argument("--archive", help="append the scenes to this archive (.vt4da), created if missing")
    add_overwrite_option(p, "replace an existing -o file, or the scenes whose key is already in --archive")
    add_deprecated_flag(p, "--replace", "replace")  # the spelling before -y; for --archive only, as it was
    p.add_argument("--skip-existing", action="store_true",
                   help="leave out scenes whose key is already in --archive (resume an interrupted run)")
    p.add_argument("--camera", help="source camera name (default: the capture's first camera)")
    p.add_argument("--cameras", metavar="all|CAM,CAM,...",
                   help="encode several cameras into one scene: 'all' or a comma-separated list (the first is the "
                        "reference camera whose trajectory the scene stores); instead of --camera")
    p.add_argument("--start", type=nonneg_int, default=0, help="first frame of the clip (default 0)")
    p.add_argument("--split", action="store_true", help="encode every consecutive clip of a long capture")
    p.add_argument("--fit", choices=FITS, default="crop",
                   help="frames that are not square: 'crop' (default: resize the shorter side, centre-crop; a "
                        "portrait 9:16 frame loses 44 %% of its picture) or 'pad' (resize the longer side, black "
                        "bars: the whole picture is kept)")
    p.add_argument("--encoding", choices=ENCODINGS, default=None,
                   help=f"token encoding (default: the model's default quality level where it has quality levels, "
                        f"else {DEFAULT_ENCODING}: the smallest within 0.1 dB of float32 tokens on held-out views, see "
                        "docs/BENCHMARKS.md)")
    p.add_argument("--quality", type=int, default=None, metavar="Q",
                   help="a quality level of the model's entropy model, 1 (fewest bytes) up to its number of "
                        "levels (models trained with a rate term; codec.quality_levels): stores the tokens as "
                        "learned-rans at that level (format 1.6) instead of --encoding (vt4d info shows the level and "
                        "bits per pixel)")
    p.add_argument("--refine", type=nonneg_int, default=0, metavar="N",
                   help="encoder-side refinement: N iterations that move the tokens so the encoded cameras' renders "
                        "from the stored values match their frames, at a rate cost (fewer bytes, sharper encoded "
                        "views; each iteration renders every encoded camera once, forward and backward: about 0.13 s "
                        "per camera for vt4d-tiny on 2 CPU threads). Needs a quality level and torch (the train "
                        "extra); 10 is a good start (docs/benchmarks/codecs.md). Default 0: the encoder's tokens")
    p.add_argument("--tune", choices=codec.TUNES, default="psnr",
                   help="what --refine optimises beside the bytes: 'psnr' (default: pixel error) or 'ssim' (pixel "
                        "error and structure: a higher SSIM, sharper edges, for a few per cent more bytes)")
    p.add_argument("--runtime", choices=codec.RUNTIMES, default="auto",
                   help="encoder runtime: 'onnx' runs the model's exported encoder on onnxruntime without torch "
                        "(1 .. 10 cameras per scene, ~4x less memory), 'torch' the networks (the train extra); 'auto' "
                        "(default) takes onnx for one camera, or for any count it has a graph for where torch is not "
                        "installed, else torch")
    add_device_option(p, "the encoder")
    p.set_defaults(func=cmd_encode)

    p = add_command(
        subparsers, "decode", parents=[common], help="render camera trajectories from a .vt4d scene or an archive key",
        description="Render a stored scene along one or more camera trajectories (no re-encoding).",
        examples=DECODE_EXAMPLES, notes=_decode_notes())
    p.add_argument("source", help="a .vt4d file, an archive (.vt4da) with --key, or ARCHIVE::KEY (path or URL)")
    p.add_argument("--key", help="scene key inside an archive")
    add_storage_option(p)
    p.add_argument("--allow-truncated", action="store_true",
                   help="read the last intact commit of an archive whose newest commit was cut off")
    add_budget_option(p)
    p.add_argument("-t", "--trajectory", action="append",
                   help="trajectory: 'source', 'camera:NAME', a preset spec, or a JSON file (repeatable; default source)")
    p.add_argument("--capture", metavar="DIR", default=None,
                   help="the capture directory the scene was encoded from (for -t camera:NAME)")
    p.add_argument("-o", "--output", required=True,
                   help="output directory (one file per trajectory), or with one trajectory a .mp4 or .npz file")
    p.add_argument("--format", choices=VIDEO_FORMATS, default=None,
                   help="mp4 video (default), PNG frames or .npz arrays (default: the -o file's extension)")
    p.add_argument("--steps", type=positive_int, default=DEFAULT_STEPS,
                   help="Euler steps of the rectified-flow sampler (default: the model's recorded best-fidelity "
                        "setting, decode_steps in its config.json)")
    p.add_argument("--drop", choices=("static", "dynamic"), help="token masking: render without Z_s or Z_d")
    p.add_argument("--force", action="store_true", help="decode even if the model's fingerprint differs")
    p.add_argument("--runtime", choices=codec.RUNTIMES, default="auto",
                   help="renderer runtime: 'onnx' runs the model's exported renderer on onnxruntime without torch, "
                        "'torch' the networks (the train extra); 'auto' (default) takes torch where it is installed, "
                        "else onnx")
    add_device_option(p, "the renderer")
    add_overwrite_option(p, "replace outputs that exist (without it they are replaced with a note)")
    add_upscale_option(p)
    p.set_defaults(func=cmd_decode)

    p = add_command(
        subparsers, "demo", parents=[common],
        help="make a synthetic capture, encode it, render views, write videos + a picture",
        description="End-to-end demo on a held-out synthetic scene: encode one camera, decode the source view and "
                    "two other cameras' trajectories, write mp4s and a PNG contact sheet, print size and PSNR.",
        examples=["vt4d demo -o demo_out                 run it (again: an earlier demo's output is replaced)",
                  "vt4d demo -o demo_out --steps 4 --json"])
    p.add_argument("-o", "--output", default="demo_out",
                   help="output directory (default demo_out); an earlier demo's output there is replaced")
    add_overwrite_option(p, "also replace a capture in OUTPUT/capture that the demo did not write")
    p.add_argument("--steps", type=positive_int, default=DEFAULT_STEPS,
                   help="sampler steps (default: the model's recorded decode_steps)")
    add_upscale_option(p, default=4)
    p.set_defaults(func=cmd_demo)
