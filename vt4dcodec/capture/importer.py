"""``vt4d import``: videos or image folders named after the cameras + one calibration file -> a capture
directory (FORMAT.md Part III).

The calibration is read by :mod:`.calibration` (OpenCV FileStorage, Pose2Sim/Anipose/caliscope TOML,
COLMAP text, NeRF transforms.json).  ``MEDIA_DIR`` holds, per calibrated camera, a video named after it
(``cam00.mp4``, also .mov .m4v .mkv .webm .avi) or a folder of images named after it (``cam00/*.png``
or .jpg ..., in natural name order).  Names match exactly, else ignoring case; media for cameras the
calibration lacks are left out (and listed in the result).

Checks before anything is written: every camera has media; each medium's size equals the calibration's
image size (or, with ``scale_intrinsics``, is a uniform rescale of it, and K is rescaled); every camera
has the same number of frames.  Units: translations are taken as
metres or millimetres by :func:`~vt4dcodec.capture.calibration.decide_units` (``units="auto"``) or as
given.  Videos are copied byte for byte (``media="copy"``, their codec unchanged: the reader decodes
any codec its FFmpeg knows) or decoded into PNG sequences (``media="png"``, which ``frames=`` needs to
trim videos).  Image folders always become PNG sequences.  Distortion stays in the manifest; the
frames are stored as recorded.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from ..cameras import Trajectory
from ..errors import CameraError, CaptureError
from .calibration import CameraCalibration, decide_units, read_calibration, safe_name, scaled
from .io import (
    CAPTURE_FORMAT,
    CAPTURE_VERSION,
    MANIFEST_NAME,
    PNG_NAME,
    CaptureManifest,
    camera_json,
    read_manifest,
    write_manifest,
)
from .probe import IMAGE_SUFFIXES, VIDEO_SUFFIXES, probe_png, probe_video

__all__ = ["import_capture", "find_media", "IMPORT_MEDIA"]

IMPORT_MEDIA = ("copy", "png")


def _natural_key(name: str) -> list[Any]:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def _images(folder: Path) -> list[Path]:
    return sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()),
                  key=lambda p: _natural_key(p.name))


def find_media(media_dir: str | os.PathLike) -> dict[str, Path]:
    """Media of ``media_dir`` by camera name: videos by file stem, image folders by folder name."""
    media_dir = Path(media_dir)
    if not media_dir.is_dir():
        raise CaptureError(f"{media_dir}: media directory not found (it holds one video or image folder per camera)")
    found: dict[str, Path] = {}
    for p in sorted(media_dir.iterdir()):
        if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES:
            name = p.stem
        elif p.is_dir() and _images(p):
            name = p.name
        else:
            continue
        if name in found:
            raise CaptureError(f"{media_dir}: two media for camera {name!r} ({found[name].name}, {p.name}); keep one")
        found[name] = p
    if not found:
        raise CaptureError(f"{media_dir}: no videos ({', '.join(VIDEO_SUFFIXES)}) or image folders found; name each "
                           "camera's video or image folder after the camera in the calibration")
    return found


def _match(cams: list[CameraCalibration], media: dict[str, Path], media_dir: Path) -> dict[str, Path]:
    lower: dict[str, list[str]] = {}
    for name in media:
        lower.setdefault(name.lower(), []).append(name)
    out, missing = {}, []
    for cam in cams:
        if cam.name in media:
            out[cam.name] = media[cam.name]
        elif len(lower.get(cam.name.lower(), [])) == 1:
            out[cam.name] = media[lower[cam.name.lower()][0]]
        else:
            missing.append(cam.name)
    if missing:
        raise CaptureError(f"{media_dir}: no video or image folder for calibrated cameras {missing} (found media "
                           f"{sorted(media)}); name each camera's video <name>.mp4 or image folder <name>/ after "
                           "its name in the calibration")
    return out


def _image_size(path: Path) -> tuple[int, int]:
    if path.suffix.lower() == ".png":
        return probe_png(path)
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise CaptureError(f"{path}: cannot decode the image")
    return int(img.shape[1]), int(img.shape[0])


def _probe(path: Path) -> dict[str, Any]:
    if path.is_file():
        info = probe_video(path)
        if not info.decodable:
            raise CaptureError(f"{path}: its first frame does not decode; transcode it (ffmpeg -i IN -c:v libx264 "
                               "-pix_fmt yuv420p OUT.mp4)")
        return {"kind": "video", "width": info.width, "height": info.height, "frames": info.num_frames,
                "codec": info.codec, "fps": info.fps}
    images = _images(path)
    w, h = _image_size(images[0])
    return {"kind": "images", "width": w, "height": h, "frames": len(images), "codec": "images", "fps": None}


def _fit_size(cam: CameraCalibration, w: int, h: int, scale_intrinsics: bool, source: Path) -> CameraCalibration:
    """``cam`` at the media's size ``w`` x ``h``: checked, and with ``scale_intrinsics`` rescaled."""
    where = f"camera {cam.name!r}"
    if cam.width is None or cam.height is None:
        K = cam.K
        if not (-0.5 <= K[0, 2] <= w - 0.5 and -0.5 <= K[1, 2] <= h - 0.5):
            raise CaptureError(f"{where}: the calibration's principal point ({K[0, 2]:.1f}, {K[1, 2]:.1f}) lies outside "
                               f"the {w}x{h} frames of {source.name}; is this the camera's media, at the calibrated size?")
        return CameraCalibration(cam.name, cam.K, cam.w2c, w, h, cam.distortion)
    if (cam.width, cam.height) == (w, h):
        return cam
    if (cam.width, cam.height) == (h, w):
        raise CaptureError(f"{where}: {source.name} is {w}x{h} but the calibration is for {cam.width}x{cam.height}: "
                           "the frames are rotated against the calibration (portrait vs landscape); rotate the media "
                           "to the calibrated orientation (ffmpeg -vf transpose) or recalibrate")
    sx, sy = w / cam.width, h / cam.height
    if not scale_intrinsics or abs(sx - sy) > 1e-3 * max(sx, sy):
        fix = ("pass scale_intrinsics=True (--scale-intrinsics) to rescale K to the media" if abs(sx - sy) <= 1e-3 *
               max(sx, sy) else "the aspect ratios differ, so the media were cropped: use the calibrated footage")
        raise CaptureError(f"{where}: {source.name} is {w}x{h} but the calibration is for {cam.width}x{cam.height}; {fix}")
    K = cam.K.copy()
    K[0, 0], K[0, 1], K[1, 1] = K[0, 0] * sx, K[0, 1] * sx, K[1, 1] * sy
    K[0, 2], K[1, 2] = (K[0, 2] + 0.5) * sx - 0.5, (K[1, 2] + 0.5) * sy - 0.5  # pixel centres at integers
    return CameraCalibration(cam.name, K, cam.w2c, w, h, cam.distortion)


def _write_png_from_video(video: Path, folder: Path, count: int) -> None:
    import av
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    written = 0
    with av.open(str(video)) as container:
        for frame in container.decode(video=0):
            if written == count:
                break
            if not cv2.imwrite(str(folder / PNG_NAME.format(written)), frame.to_ndarray(format="bgr24")):
                raise CaptureError(f"cannot write {folder / PNG_NAME.format(written)}")
            written += 1
    if written < count:
        raise CaptureError(f"{video}: decodes {written} frames, fewer than the {count} its packets promised")


def _write_png_from_images(images: list[Path], folder: Path, count: int, size: tuple[int, int]) -> None:
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    for i, src in enumerate(images[:count]):
        dst = folder / PNG_NAME.format(i)
        if src.suffix.lower() == ".png" and probe_png(src) == size:
            with src.open("rb") as fh:
                head = fh.read(26)
            if head[24:26] == b"\x08\x02":  # 8-bit RGB already: copy the bytes
                shutil.copyfile(src, dst)
                continue
        img = cv2.imread(str(src), cv2.IMREAD_COLOR)
        if img is None:
            raise CaptureError(f"{src}: cannot decode the image")
        if (img.shape[1], img.shape[0]) != size:
            raise CaptureError(f"{src} is {img.shape[1]}x{img.shape[0]} but the folder's first image is "
                               f"{size[0]}x{size[1]}; every frame of a camera has one size")
        if not cv2.imwrite(str(dst), img):
            raise CaptureError(f"cannot write {dst}")


def import_capture(
    calibration: str | os.PathLike,
    media_dir: str | os.PathLike,
    output: str | os.PathLike,
    *,
    format: str = "auto",
    units: str = "auto",
    media: str = "copy",
    frames: int | None = None,
    fps: float | None = None,
    capture_id: str | None = None,
    scale_intrinsics: bool = False,
    overwrite: bool = False,
) -> CaptureManifest:
    """Import a calibrated multi-camera recording as a capture directory and return its manifest.

    Args:
        calibration: the calibration file (or a COLMAP / NeRF / EasyMocap directory).
        media_dir: one video (``<camera>.mp4`` ...) or image folder (``<camera>/``) per calibrated camera.
        output: the capture directory to write (created; an existing capture needs ``overwrite``).
        format: ``"auto"`` or one of ``opencv``, ``toml``, ``colmap``, ``nerf``.
        units: translations in ``"m"``, ``"mm"`` or ``"auto"`` (see ``decide_units``).
        media: ``"copy"`` videos as they are, or decode them to ``"png"`` sequences.
        frames: keep the first ``frames`` frames of every camera (videos need ``media="png"`` to trim).
        fps: the frame rate (default: the videos'; image folders alone need it).
        capture_id: default: the output directory's name.
        scale_intrinsics: media at a uniform rescale of the calibrated size get K rescaled.
        overwrite: replace a capture already in ``output``.
    """
    calibration, media_dir, output = Path(calibration), Path(media_dir), Path(output)
    if media not in IMPORT_MEDIA:
        raise CaptureError(f"media must be one of {IMPORT_MEDIA}, got {media!r}")
    if frames is not None and (isinstance(frames, bool) or not isinstance(frames, int) or frames < 1):
        raise CaptureError(f"frames must be a positive integer, got {frames!r}")
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise CaptureError(f"fps must be a positive number, got {fps!r}")
    if (output / MANIFEST_NAME).exists() and not overwrite:
        raise CaptureError(f"{output} already holds a capture; pass overwrite=True to replace it")
    fmt, cams = read_calibration(calibration, format)
    scale, units_note = decide_units(cams, units)
    cams = [scaled(c, scale) for c in cams]
    names = [safe_name(c.name) for c in cams]
    if len(set(names)) != len(names):
        raise CaptureError(f"{calibration}: camera names {[c.name for c in cams]} collide as capture names {names}")
    sources = _match(cams, find_media(media_dir), media_dir)
    probes = {c.name: _probe(sources[c.name]) for c in cams}
    cams = [_fit_size(c, probes[c.name]["width"], probes[c.name]["height"], scale_intrinsics, sources[c.name])
            for c in cams]
    counts = {c.name: probes[c.name]["frames"] for c in cams}
    T = min(counts.values()) if frames is None else frames
    short = {n: k for n, k in counts.items() if k < T}
    if short:
        raise CaptureError(f"frames={T} (--frames {T}) but cameras {sorted(short)} have only {short} frames")
    if frames is None and len(set(counts.values())) != 1:
        raise CaptureError(f"cameras have different frame counts {counts}; a capture is synchronized: trim them to "
                           f"one length, or take the first N frames of each with frames=N (--frames N) and "
                           "media='png' (--media png)")
    long_videos = [n for n in counts if probes[n]["kind"] == "video" and counts[n] != T]
    if long_videos and media == "copy":
        raise CaptureError(f"cameras {long_videos} have more than {T} frames: copied videos keep every frame; "
                           "decode to PNG with media='png' (--media png) to keep the first frames")
    rates = [p["fps"] for p in probes.values() if p["fps"]]
    if fps is None:
        if not rates:
            raise CaptureError("image folders carry no frame rate; pass fps= (--fps)")
        fps = float(np.median(rates))
        if max(rates) - min(rates) > 0.01 * fps:
            raise CaptureError(f"the videos' frame rates differ ({sorted(set(rates))}); a capture has one clock: "
                               "pass fps= (--fps) to state it")
    trajectories = {}
    for cam, name in zip(cams, names):
        try:
            trajectories[name] = Trajectory(K=cam.K, w2c=cam.w2c, width=int(cam.width or 0),
                                            height=int(cam.height or 0), distortion=cam.distortion)
        except CameraError as exc:
            raise CameraError(f"{calibration.name} camera {cam.name!r}: {exc}") from None
    output.mkdir(parents=True, exist_ok=True)
    if (output / MANIFEST_NAME).exists():
        (output / MANIFEST_NAME).unlink()  # incomplete until the new manifest lands
    docs, media_meta = [], {}
    for cam, name in zip(cams, names):
        src, probe = sources[cam.name], probes[cam.name]
        cam_dir = output / name
        if cam_dir.exists():
            shutil.rmtree(cam_dir)
        cam_dir.mkdir()
        if probe["kind"] == "video" and media == "copy":
            rel = f"{name}/rgb{src.suffix.lower()}"
            shutil.copyfile(src, output / rel)
            media_doc = {"type": "mp4", "path": rel}
        elif probe["kind"] == "video":
            _write_png_from_video(src, cam_dir / "rgb", T)
            media_doc = {"type": "png", "path": f"{name}/rgb"}
        else:
            _write_png_from_images(_images(src), cam_dir / "rgb", T, (probe["width"], probe["height"]))
            media_doc = {"type": "png", "path": f"{name}/rgb"}
        docs.append(camera_json(name, trajectories[name], media_doc, None))
        media_meta[name] = {"source": str(src), "codec": probe["codec"], "calibration_name": cam.name}
    doc = {
        "format": CAPTURE_FORMAT,
        "version": CAPTURE_VERSION,
        "capture_id": capture_id or output.name,
        "fps": float(fps),
        "num_frames": int(T),
        "metadata": {"source": "vt4d import", "calibration": {"path": str(calibration), "format": fmt,
                                                             "units": units_note, "scale_to_metres": scale},
                     "media": media_meta},
        "cameras": docs,
    }
    write_manifest(output, doc)
    return read_manifest(output)
