"""``vt4d import``: videos or image folders named after the cameras + one calibration file -> a capture
directory (FORMAT.md Part III).

The calibration is read by :mod:`.calibration` (OpenCV FileStorage, Pose2Sim/Anipose/caliscope TOML,
COLMAP text, NeRF transforms.json, N3DV/DyNeRF poses_bounds.npy, MultiCamVideo camera_extrinsics.json).
``MEDIA_DIR`` holds, per calibrated camera, a video named after it (``cam00.mp4``, also .mov .m4v .mkv
.webm .avi) or a folder of images named after it (``cam00/*.png`` or .jpg ..., in natural name order).
A camera takes the medium given for it in ``camera_map`` (``--map NAME=FILE``), else the one of its name
(exactly, else ignoring case), else the one carrying the same camera number (Pose2Sim's ``int_cam01_img``
and ``cam01.mp4``: each number once on both sides); media for cameras the calibration lacks are left
out.  N3DV's rows pair with the media in name order (as the DyNeRF loaders pair them), and the
datasets' media folders are the default ``MEDIA_DIR`` (N3DV: the folder of ``poses_bounds.npy``;
MultiCamVideo: the scene's ``videos/``).

Checks before anything is written: every camera has media; each medium's size equals the calibration's
image size, or is up to :data:`PADDING_PX` pixels smaller on the right and bottom (the encoder padded
the calibration frames to a multiple of 16, e.g. Pose2Sim's 1088-wide calibration of 1080-wide videos:
imported with K unchanged and a :class:`CalibrationSizeWarning` naming the difference), or, with
``scale_intrinsics``, is a uniform rescale of it (and K is rescaled); every camera has the same number of
frames, and a moving camera (MultiCamVideo) a pose for each.  Units: translations are taken as
metres or millimetres by :func:`~vt4dcodec.capture.calibration.decide_units` (``units="auto"``) or as
given (MultiCamVideo's centimetres become metres).  Videos are copied byte for byte (``media="copy"``, their codec unchanged: the reader decodes
any codec its FFmpeg knows) or decoded into PNG sequences (``media="png"``, which ``frames=`` needs to
trim videos).  Image folders always become PNG sequences.  Distortion stays in the manifest; the
frames are stored as recorded.
"""

from __future__ import annotations

import os
import re
import shutil
import warnings
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..cameras import Trajectory
from ..errors import CameraError, CaptureError
from .calibration import (
    MULTICAMVIDEO_SENSOR_MM,
    MULTICAMVIDEO_SIZE,
    CameraCalibration,
    decide_units,
    multicamvideo_scene,
    n3dv_file,
    natural_key,
    read_calibration,
    safe_name,
    scaled,
)
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

__all__ = ["import_capture", "find_media", "camera_number", "IMPORT_MEDIA", "PADDING_PX", "CalibrationSizeWarning"]

IMPORT_MEDIA = ("copy", "png")
PADDING_PX = 16  # media this much smaller than the calibration (right/bottom) are taken as encoder padding


class CalibrationSizeWarning(UserWarning):
    """A medium a few pixels smaller than its calibrated size was imported with K unchanged (encoder padding)."""


def _images(folder: Path) -> list[Path]:
    return sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()),
                  key=lambda p: natural_key(p.name))


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


def camera_number(name: str) -> int | None:
    """The camera number a name carries (``int_cam01_img``, ``cam01``, ``cam_1`` -> 1): its only run of
    digits, else the one right after ``cam``; None when there is none or it is ambiguous."""
    runs = re.findall(r"\d+", name)
    if len(runs) == 1:
        return int(runs[0])
    after_cam = re.findall(r"cam(?:era)?[_-]?(\d+)", name, flags=re.IGNORECASE)
    return int(after_cam[0]) if len(after_cam) == 1 else None


def _is_medium(path: Path) -> bool:
    return (path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES) or (path.is_dir() and bool(_images(path)))


def _mapped(camera_map: Mapping[str, str], cams: list[CameraCalibration], media_dir: Path) -> dict[str, Path]:
    names = [c.name for c in cams]
    out: dict[str, Path] = {}
    for name, file in camera_map.items():
        if name not in names:
            raise CaptureError(f"camera_map (--map) names camera {name!r}, which the calibration does not have; "
                               f"its cameras are {', '.join(names)}")
        path = media_dir / file if (media_dir / file).exists() else Path(file)
        if not _is_medium(path):
            raise CaptureError(f"camera_map (--map {name}={file}): {path} is not a video ({', '.join(VIDEO_SUFFIXES)}) "
                               f"or a folder of images, in {media_dir} or as a path")
        twin = next((n for n, p in out.items() if p.resolve() == path.resolve()), None)
        if twin is not None:
            raise CaptureError(f"camera_map (--map) gives {path.name} to both {twin!r} and {name!r}; one medium a camera")
        out[name] = path
    return out


def _match(cams: list[CameraCalibration], media: dict[str, Path], media_dir: Path,
           camera_map: Mapping[str, str]) -> tuple[dict[str, Path], dict[str, str]]:
    """Each camera's medium and how it was found ("map", "name" or "number")."""
    out = _mapped(camera_map, cams, media_dir)
    how = {name: "map" for name in out}
    taken = {p.resolve() for p in out.values()}
    free = {name: p for name, p in media.items() if p.resolve() not in taken}
    for cam in cams:
        if cam.name in out:
            continue
        same = [n for n in free if n == cam.name] or [n for n in free if n.lower() == cam.name.lower()]
        if len(same) == 1:
            out[cam.name], how[cam.name] = free.pop(same[0]), "name"
    left = [c.name for c in cams if c.name not in out]
    numbers = {name: camera_number(name) for name in left}
    for name, number in numbers.items():
        holders = [n for n in free if camera_number(n) == number]
        if number is not None and list(numbers.values()).count(number) == 1 and len(holders) == 1:
            out[name], how[name] = free.pop(holders[0]), "number"
    missing = [c.name for c in cams if c.name not in out]
    if missing:
        raise CaptureError(f"{media_dir}: no video or image folder for calibrated cameras {missing} (found media "
                           f"{sorted(media)}); name each camera's video <name>.mp4 or image folder <name>/ after "
                           "its name in the calibration or its camera number, or give it with "
                           "camera_map={NAME: FILE} (--map NAME=FILE)")
    return out, how


def _pair_rows(cams: list[CameraCalibration], media: dict[str, Path], calibration: Path, media_dir: Path,
               camera_map: Mapping[str, str]) -> list[CameraCalibration]:
    """N3DV: row i of poses_bounds.npy is the i-th medium in name order (the DyNeRF loaders' rule)."""
    if camera_map:
        raise CaptureError("camera_map (--map) does not apply to N3DV: its poses_bounds.npy rows pair with the "
                           "videos in name order, as the DyNeRF loaders pair them")
    names = sorted(media, key=natural_key)
    if len(names) != len(cams):
        raise CaptureError(f"{calibration}: {len(cams)} camera rows but {media_dir} holds {len(names)} videos or "
                           f"image folders ({', '.join(names)}); row i is the i-th video in name order, so keep "
                           "exactly the videos the poses were made for")
    return [replace(cam, name=name) for cam, name in zip(cams, names)]


def default_media_dir(fmt: str, calibration: Path) -> Path:
    """Where a dataset keeps its videos: N3DV beside poses_bounds.npy, MultiCamVideo in the scene's videos/."""
    if fmt == "n3dv":
        return n3dv_file(calibration).parent
    if fmt == "multicamvideo":
        return multicamvideo_scene(calibration) / "videos"
    raise CaptureError(f"a {fmt} calibration does not say where its media are: give the folder of videos or "
                       "image folders (MEDIA_DIR, the second argument)")


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
        return replace(cam, width=w, height=h)
    if (cam.width, cam.height) == (w, h):
        return cam
    if (cam.width, cam.height) == (h, w):
        raise CaptureError(f"{where}: {source.name} is {w}x{h} but the calibration is for {cam.width}x{cam.height}: "
                           "the frames are rotated against the calibration (portrait vs landscape); rotate the media "
                           "to the calibrated orientation (ffmpeg -vf transpose) or recalibrate")
    sx, sy = w / cam.width, h / cam.height
    uniform = abs(sx - sy) <= 1e-3 * max(sx, sy)
    dw, dh = cam.width - w, cam.height - h
    if 0 <= dw <= PADDING_PX and 0 <= dh <= PADDING_PX and not (scale_intrinsics and uniform):
        less = " and ".join(f"{d} px {word}" for d, word in ((dw, "narrower"), (dh, "shorter")) if d)
        warnings.warn(f"{where}: {source.name} is {w}x{h}, {less} than the calibrated {cam.width}x{cam.height}: "
                      "taken as encoder padding cut off the right and bottom, K unchanged", CalibrationSizeWarning,
                      stacklevel=2)
        return replace(cam, width=w, height=h)
    if not scale_intrinsics or not uniform:
        fix = ("pass scale_intrinsics=True (--scale-intrinsics) to rescale K to the media" if uniform else
               "the aspect ratios differ, so the media were cropped: use the calibrated footage")
        raise CaptureError(f"{where}: {source.name} is {w}x{h} but the calibration is for {cam.width}x{cam.height}; {fix}")
    K = cam.K.copy()
    K[0, 0], K[0, 1], K[1, 1] = K[0, 0] * sx, K[0, 1] * sx, K[1, 1] * sy
    K[0, 2], K[1, 2] = (K[0, 2] + 0.5) * sx - 0.5, (K[1, 2] + 0.5) * sy - 0.5  # pixel centres at integers
    return replace(cam, K=K, width=w, height=h)


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
    media_dir: str | os.PathLike | None,
    output: str | os.PathLike,
    *,
    format: str = "auto",
    units: str = "auto",
    media: str = "copy",
    frames: int | None = None,
    fps: float | None = None,
    capture_id: str | None = None,
    scale_intrinsics: bool = False,
    camera_map: Mapping[str, str] | None = None,
    focal_mm: float | None = None,
    overwrite: bool = False,
) -> CaptureManifest:
    """Import a calibrated multi-camera recording as a capture directory and return its manifest.

    Args:
        calibration: the calibration file (or a COLMAP / NeRF / EasyMocap / N3DV / MultiCamVideo directory).
        media_dir: one video (``<camera>.mp4`` ...) or image folder (``<camera>/``) per calibrated camera;
            None: the dataset's own (N3DV: beside poses_bounds.npy, MultiCamVideo: the scene's videos/).
        output: the capture directory to write (created; an existing capture needs ``overwrite``).
        format: ``"auto"`` or one of :data:`~vt4dcodec.capture.calibration.CALIBRATION_FORMATS`.
        units: translations in ``"m"``, ``"mm"`` or ``"auto"`` (see ``decide_units``).
        media: ``"copy"`` videos as they are, or decode them to ``"png"`` sequences.
        frames: keep the first ``frames`` frames of every camera (videos need ``media="png"`` to trim).
        fps: the frame rate (default: the videos'; image folders alone need it).
        capture_id: default: the output directory's name.
        scale_intrinsics: media at a uniform rescale of the calibrated size get K rescaled.
        camera_map: calibration camera name -> its video or image folder (in ``media_dir``, or a path), for
            media named neither after the camera nor with its number.
        focal_mm: MultiCamVideo's focal length in mm (default: from the folder name ``f<mm>_aperture<N>``).
        overwrite: replace a capture already in ``output``.
    """
    calibration, output = Path(calibration), Path(output)
    if media not in IMPORT_MEDIA:
        raise CaptureError(f"media must be one of {IMPORT_MEDIA}, got {media!r}")
    if frames is not None and (isinstance(frames, bool) or not isinstance(frames, int) or frames < 1):
        raise CaptureError(f"frames must be a positive integer, got {frames!r}")
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise CaptureError(f"fps must be a positive number, got {fps!r}")
    if (output / MANIFEST_NAME).exists() and not overwrite:
        raise CaptureError(f"{output} already holds a capture; pass overwrite=True to replace it")
    fmt, cams = read_calibration(calibration, format, focal_mm=focal_mm)
    media_dir = default_media_dir(fmt, calibration) if media_dir is None else Path(media_dir)
    found = find_media(media_dir)
    if fmt == "n3dv":
        cams = _pair_rows(cams, found, calibration, media_dir, camera_map or {})
    if fmt == "multicamvideo":
        if units not in ("auto", "m"):
            raise CaptureError(f"MultiCamVideo poses are Unreal Engine centimetres, imported as metres; units={units!r} "
                               "(--units) does not apply")
        scale, units_note = 1.0, "metres (MultiCamVideo's Unreal Engine centimetres / 100)"
    else:
        scale, units_note = decide_units(cams, units)
    cams = [scaled(c, scale) for c in cams]
    names = [safe_name(c.name) for c in cams]
    if len(set(names)) != len(names):
        raise CaptureError(f"{calibration}: camera names {[c.name for c in cams]} collide as capture names {names}")
    sources, matched_by = _match(cams, found, media_dir, camera_map or {})
    probes = {c.name: _probe(sources[c.name]) for c in cams}
    calibrated = {c.name: (c.width, c.height) for c in cams}
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
        w2c = cam.w2c
        if w2c.ndim == 3:  # a moving camera: one pose per frame
            if w2c.shape[0] < T or (frames is None and w2c.shape[0] != T):
                n = min(w2c.shape[0], T)
                raise CaptureError(f"{calibration.name}: camera {cam.name!r} has poses for {w2c.shape[0]} frames and "
                                   f"its media {T}; import the first {n} with frames={n} (--frames {n})")
            w2c = w2c[:T]
        try:
            trajectories[name] = Trajectory(K=cam.K, w2c=w2c, width=int(cam.width or 0),
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
        media_meta[name] = {"source": str(src), "codec": probe["codec"], "calibration_name": cam.name,
                            "matched_by": matched_by[cam.name]}
        if calibrated[cam.name] not in ((cam.width, cam.height), (None, None)):
            media_meta[name]["calibrated_size"] = list(calibrated[cam.name])  # padded or rescaled media
    calib_meta = {"path": str(calibration), "format": fmt, "units": units_note, "scale_to_metres": scale,
                  **_dataset_notes(fmt, cams, names)}
    doc = {
        "format": CAPTURE_FORMAT,
        "version": CAPTURE_VERSION,
        "capture_id": capture_id or output.name,
        "fps": float(fps),
        "num_frames": int(T),
        "metadata": {"source": "vt4d import", "calibration": calib_meta, "media": media_meta},
        "cameras": docs,
    }
    write_manifest(output, doc)
    return read_manifest(output)


def _dataset_notes(fmt: str, cams: list[CameraCalibration], names: list[str]) -> dict[str, Any]:
    """What a dataset's calibration says beyond the cameras: N3DV's near/far bounds, MultiCamVideo's lens."""
    if fmt == "n3dv":
        return {"world": "the poses' own frame and scale (COLMAP's, as LLFF wrote them)",
                "near_far": {name: list(c.near_far) for c, name in zip(cams, names) if c.near_far is not None}}
    if fmt == "multicamvideo":
        return {"world": "Unreal Engine's world in metres with its y axis negated (x forward, y left, z up)",
                "focal_mm": float(cams[0].K[0, 0] * MULTICAMVIDEO_SENSOR_MM / cams[0].width) if cams[0].width else None,
                "sensor_mm": MULTICAMVIDEO_SENSOR_MM, "calibrated_size": MULTICAMVIDEO_SIZE}
    return {}
