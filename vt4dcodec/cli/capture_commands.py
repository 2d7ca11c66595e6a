"""`vt4d import`, `vt4d capture-info` and `vt4d contact-sheet`: make and look at capture directories
(and `vt4d synth`, which makes synthetic ones; defined in :mod:`vt4dcodec.cli.synth_commands`).

Each command is one ``_register_*`` helper listed in :data:`REGISTER`; adding a command to this group
is one function plus one entry there.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from typing import Any, Callable

import numpy as np

from ..capture.contact_sheet import read_sheet_frames, write_contact_sheet
from ..capture.calibration import CALIBRATION_FORMATS
from ..capture.importer import IMPORT_MEDIA, CalibrationSizeWarning, import_capture
from ..capture.io import read_manifest
from ..capture.probe import check_capture
from ..errors import CaptureError
from . import add_command, add_overwrite_option, check_output_file, emit, note_replacing, plural, positive_int
from .synth_commands import add_synth_parser

__all__ = ["register", "capture_info", "REGISTER"]


def capture_info(directory: str) -> dict[str, Any]:
    """A JSON-ready summary of a capture directory (reads the manifest only, checks media exist)."""
    m = read_manifest(directory)
    cams = []
    for e in m.cameras:
        t = e.trajectory
        centers = t.centers
        media = m.directory / e.media_path
        cams.append({
            "name": e.name,
            "width": t.width,
            "height": t.height,
            "fx": float(t.K[0, 0, 0]),
            "fy": float(t.K[0, 1, 1]),
            "cx": float(t.K[0, 0, 2]),
            "cy": float(t.K[0, 1, 2]),
            "distortion": None if t.distortion is None else t.distortion.tolist(),
            "static": bool(np.all(t.w2c == t.w2c[0])),
            "center_first": centers[0].round(6).tolist(),
            "path_length_m": float(np.linalg.norm(np.diff(centers, axis=0), axis=1).sum()),
            "media": {"type": e.media_type, "path": e.media_path, "exists": media.exists()},
            "depth": None if e.depth_type is None else {
                "type": e.depth_type, "path": e.depth_path, "exists": (m.directory / e.depth_path).exists(),
            },
            "duration_s": None if t.timestamps is None else float(t.timestamps[-1] - t.timestamps[0]),
        })
    return {
        "directory": str(m.directory),
        "capture_id": m.capture_id,
        "fps": m.fps,
        "num_frames": m.num_frames,
        "num_cameras": len(m.cameras),
        "cameras": cams,
        "metadata": m.metadata,
    }


def _info_lines(info: dict[str, Any]) -> list[str]:
    lines = [f"capture {info['capture_id']!r} in {info['directory']}",
             f"  {plural(info['num_cameras'], 'camera')}, {plural(info['num_frames'], 'frame')} at {info['fps']:.3f} fps"]
    for c in info["cameras"]:
        depth = c["depth"]["type"] if c["depth"] else "no depth"
        motion = "static" if c["static"] else f"moving, path {c['path_length_m']:.3f} m"
        dist = "distorted" if c["distortion"] else "pinhole"
        missing = "" if c["media"]["exists"] else "  [MEDIA MISSING]"
        lines.append(
            f"  {c['name']:<12} {c['width']}x{c['height']}  fx={c['fx']:.1f} fy={c['fy']:.1f} "
            f"cx={c['cx']:.1f} cy={c['cy']:.1f}  {dist}, {motion}, {c['media']['type']}, {depth}{missing}"
        )
    return lines


def _run_capture_info(args: argparse.Namespace) -> int:
    info = capture_info(args.directory)
    lines = _info_lines(info)
    problems: list[str] = []
    if args.check:
        cameras = check_capture(args.directory)
        problems = [p for c in cameras for p in c["problems"]]
        info["check"] = {"ok": not problems, "cameras": cameras}
        if not problems:
            lines.append(f"  check: every medium matches the manifest ({plural(len(cameras), 'camera')} probed)")
    emit(args, info, lines)
    for p in problems:
        print(f"vt4d capture-info: error: {p}", file=sys.stderr)
    return 1 if problems else 0


def camera_map_entry(text: str) -> tuple[str, str]:
    """An argparse type: ``--map NAME=FILE`` (a calibration camera and its video or image folder)."""
    name, sep, file = text.partition("=")
    if not sep or not name or not file:
        raise argparse.ArgumentTypeError(f"{text!r} is not NAME=FILE (a calibration camera = its video or image folder)")
    return name, file


def _run_import(args: argparse.Namespace) -> int:
    camera_map: dict[str, str] = {}
    for name, file in args.camera_map or []:
        if name in camera_map:
            raise CaptureError(f"--map gives camera {name!r} twice ({camera_map[name]}, {file}); one medium a camera")
        camera_map[name] = file
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CalibrationSizeWarning)
        m = import_capture(args.calibration, args.media_dir, args.output, format=args.format, units=args.units,
                           media=args.media, frames=args.frames, fps=args.fps, capture_id=args.capture_id,
                           scale_intrinsics=args.scale_intrinsics, camera_map=camera_map, focal_mm=args.focal_mm,
                           overwrite=args.overwrite)
    notes = [str(w.message) for w in caught if issubclass(w.category, CalibrationSizeWarning)]
    for w in caught:  # any other warning goes on as it came
        if not issubclass(w.category, CalibrationSizeWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    calib, media = m.metadata["calibration"], m.metadata["media"]
    result = {"directory": str(m.directory), "capture_id": m.capture_id, "num_cameras": len(m.cameras),
              "num_frames": m.num_frames, "fps": m.fps, "cameras": [e.name for e in m.cameras],
              "calibration": calib, "warnings": notes}
    lines = [f"imported {plural(len(m.cameras), 'camera')} x {plural(m.num_frames, 'frame')} at {m.fps:.3f} fps into "
             f"{m.directory}", f"  calibration: {calib['format']}, {calib['units']}"]
    lines += [f"  {name} <- {info['source']} (by camera number)" for name, info in media.items()
              if info.get("matched_by") == "number"]
    emit(args, result, lines)
    if not args.quiet:
        for note in notes:
            print(f"vt4d import: warning: {note}", file=sys.stderr)
    return 0


def _run_contact_sheet(args: argparse.Namespace) -> int:
    check_output_file("-o", args.output, ".png", "a contact sheet")
    note_replacing(args, [args.output])
    capture, numbers = read_sheet_frames(args.directory, args.frames)  # only the frames shown are decoded
    w, h = write_contact_sheet(capture, args.output, thumb_height=args.thumb_height, frame_numbers=numbers)
    emit(args, {"output": args.output, "width": w, "height": h, "cameras": len(capture.cameras)},
         [f"wrote {args.output} ({w}x{h}, {plural(len(capture.cameras), 'camera')})"])
    return 0




def _register_capture_info(sub: Any) -> None:
    p = add_command(sub, "capture-info", help="summarize a capture directory (cameras, frames, media)",
                    description="Print a capture directory's cameras (intrinsics, motion, distortion), frame "
                                "count, fps and media, and whether the media files exist.  Reads the manifest only.",
                    examples=["vt4d capture-info demo_out/capture",
                              "vt4d capture-info captures/test-000000 --json"])
    p.add_argument("directory", help="capture directory (holds capture.json)")
    p.add_argument("--check", action="store_true",
                   help="probe every medium (size, frame count, first frame decodes) against the manifest "
                        "without decoding whole videos; exit 1 naming each mismatch")
    p.set_defaults(func=_run_capture_info)


def _register_import(sub: Any) -> None:
    p = add_command(sub, "import", help="make a capture directory from videos and a calibration file",
                    description="Import a calibrated multi-camera recording: MEDIA_DIR holds one video "
                                "(CAM.mp4, .mov, .mkv, .webm, .avi) or image folder (CAM/) per camera, named "
                                "after the cameras of CALIBRATION or carrying their camera number (cam01.mp4 "
                                "for int_cam01_img), or given with --map.  Calibration formats: OpenCV FileStorage "
                                "YAML/JSON, Pose2Sim/Anipose/caliscope TOML, COLMAP text (cameras.txt + "
                                "images.txt, static rigs), NeRF transforms.json, N3DV/DyNeRF poses_bounds.npy "
                                "(rows pair with the videos in name order; near/far kept as metadata) and "
                                "MultiCamVideo cameras/camera_extrinsics.json (moving cameras).  Sizes and frame "
                                "counts are checked against the media before anything is written; media up to "
                                "16 pixels smaller than the calibration on the right/bottom (encoder padding) "
                                "import with K unchanged and a warning.",
                    examples=["vt4d import calib.toml videos/ -o capture/",
                              "vt4d import sparse/0 images/ -o capture/ --format colmap --fps 30",
                              "vt4d import intri_extri/ videos/ -o capture/ --units mm --frames 100 --media png",
                              "vt4d import n3dv/coffee_martini -o capture/ --frames 30 --media png",
                              "vt4d import MultiCamVideo/train/f18_aperture10/scene1 -o capture/",
                              "vt4d import Calib_scene.toml videos/ -o capture/ --map int_cam01_img=left.mp4"])
    p.add_argument("calibration", help="calibration file (or a COLMAP / NeRF / intri.yml+extri.yml / N3DV / "
                                       "MultiCamVideo scene directory)")
    p.add_argument("media_dir", nargs="?", default=None,
                   help="folder with one video or image folder per camera, named after it (default for N3DV: the "
                        "folder of poses_bounds.npy; for MultiCamVideo: the scene's videos/)")
    p.add_argument("-o", "--output", required=True, help="capture directory to write")
    p.add_argument("--format", choices=("auto", *CALIBRATION_FORMATS), default="auto",
                   help="calibration format (default: detected from the file)")
    p.add_argument("--units", choices=("auto", "m", "mm"), default="auto",
                   help="translation units (default auto: millimetres when cameras are over 50 units apart)")
    p.add_argument("--media", choices=IMPORT_MEDIA, default="copy",
                   help="copy videos as they are (default) or decode them to PNG sequences")
    p.add_argument("--frames", type=positive_int, default=None, help="keep the first N frames of every camera")
    p.add_argument("--fps", type=float, default=None, help="frame rate (default: the videos'; needed for images)")
    p.add_argument("--capture-id", default=None, help="capture id (default: the output directory's name)")
    p.add_argument("--scale-intrinsics", action="store_true",
                   help="media at a uniform rescale of the calibrated size: rescale K to them")
    p.add_argument("--map", dest="camera_map", action="append", type=camera_map_entry, metavar="NAME=FILE",
                   help="give calibration camera NAME the video or image folder FILE (in MEDIA_DIR, or a path); "
                        "repeatable")
    p.add_argument("--focal-mm", type=float, default=None, metavar="MM",
                   help="MultiCamVideo's focal length in mm (default: from the folder name f<mm>_aperture<N>)")
    add_overwrite_option(p, "replace a capture already in the output directory")
    p.set_defaults(func=_run_import)


def _register_contact_sheet(sub: Any) -> None:
    p = add_command(sub, "contact-sheet", help="write a PNG grid of a capture (cameras x frames)",
                    description="Write a PNG contact sheet: one row per camera, evenly spaced frames.",
                    examples=["vt4d contact-sheet demo_out/capture -o sheet.png",
                              "vt4d contact-sheet captures/test-000000 -o sheet.png --frames 4 --thumb-height 64"])
    p.add_argument("directory", help="capture directory (holds capture.json)")
    p.add_argument("-o", "--output", required=True, help="PNG file to write")
    p.add_argument("--frames", type=positive_int, default=8, help="frame columns (default 8)")
    p.add_argument("--thumb-height", type=positive_int, default=96, help="thumbnail height in pixels (default 96)")
    add_overwrite_option(p, "replace the PNG file if it exists (without it, it is replaced with a note)")
    p.set_defaults(func=_run_contact_sheet)


# One entry per command of this group, in --help order (`vt4d synth` is defined in synth_commands).
REGISTER: list[Callable[[Any], None]] = [
    _register_import,
    _register_capture_info,
    _register_contact_sheet,
    add_synth_parser,
]


def register(subparsers: Any) -> None:
    """Add this group's commands to the ``vt4d`` parser."""
    for add in REGISTER:
        add(subparsers)

