"""Capture directories on disk: read and write (spec: FORMAT.md, Part III).

A capture directory holds ``capture.json`` (the manifest: cameras with intrinsics, optional distortion,
one world-to-camera pose per frame, fps, frame count, timestamps, media paths) and per-camera media:
an mp4 or a PNG sequence of RGB frames, and optional depth as 16-bit PNGs in millimetres or one
float32 ``.npy`` in metres.

Reading takes a window: :func:`read_capture` and :func:`read_camera_frames` read only the cameras and
frames ``[start, start + num_frames)`` asked for (videos are seeked, not decoded from the start; PNG
and depth files outside the window are not opened), so memory follows what is read, not the capture.

Every problem with a directory raises :class:`~vt4dcodec.errors.CaptureError` (or ``CameraError`` for
bad calibration) naming the camera and file; sizes in the manifest are checked against documented
limits before any pixel is allocated, and each decoded file is checked against the manifest.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..cameras import Trajectory, parse_numbers
from ..errors import CameraError, CaptureError
from ..media import write_mp4
from .capture import Capture
from .video import read_video_window

__all__ = [
    "MANIFEST_NAME", "read_camera_depth",
    "CAPTURE_FORMAT",
    "CAPTURE_VERSION",
    "CameraEntry",
    "CaptureManifest",
    "read_manifest",
    "read_capture",
    "write_capture",
    "read_camera_frames",
    "frame_window",
    "MAX_READ_PIXELS",
    "write_manifest",
    "camera_json",
]

MANIFEST_NAME = "capture.json"
CAPTURE_FORMAT = "vt4d-capture"
CAPTURE_VERSION = 1

# Documented limits (FORMAT.md, Part III, "Limits"): checked before anything is allocated.
MAX_MANIFEST_BYTES = 64 * 1024 * 1024
MAX_CAMERAS = 256
MAX_FRAMES = 100_000
MAX_SIDE = 16_384
# Pixels decoded by one read (frames x width x height, summed over the cameras read): bounds what one
# read_capture / read_camera_frames call allocates (2**32 pixels = 12 GiB of RGB).  A capture itself
# has no total: 10 minutes of 8 cameras at 4K60 (36,000 frames each) is a valid capture, read a clip
# at a time.
MAX_READ_PIXELS = 2**32

CAMERA_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$")
MEDIA_TYPES = ("png", "mp4")
DEPTH_TYPES = ("png16_mm", "npy_m")
PNG_NAME = "{:06d}.png"


def _cv2():
    import cv2  # local import: the format side of vt4dcodec never needs OpenCV

    return cv2


# --- the manifest ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraEntry:
    """One camera of a manifest: calibration plus where its media live (paths relative to the directory)."""

    name: str
    trajectory: Trajectory
    media_type: str
    media_path: str
    depth_type: str | None = None
    depth_path: str | None = None


@dataclass(frozen=True)
class CaptureManifest:
    """The parsed, validated ``capture.json`` of a capture directory."""

    directory: Path
    capture_id: str
    fps: float
    num_frames: int
    cameras: tuple[CameraEntry, ...]
    metadata: dict[str, Any]

    @property
    def camera_names(self) -> list[str]:
        return [e.name for e in self.cameras]

    def camera(self, name: str) -> CameraEntry:
        for entry in self.cameras:
            if entry.name == name:
                return entry
        raise CaptureError(f"no camera {name!r} in the capture (cameras: {[c.name for c in self.cameras]})")


def _need(doc: dict, key: str, kind: type | tuple[type, ...], where: str) -> Any:
    if key not in doc:
        raise CaptureError(f"{where}: missing {key!r}")
    value = doc[key]
    if isinstance(value, bool) and bool not in (kind if isinstance(kind, tuple) else (kind,)):
        raise CaptureError(f"{where}: {key!r} has the wrong type")
    if not isinstance(value, kind):
        raise CaptureError(f"{where}: {key!r} has the wrong type ({type(value).__name__})")
    return value


def _safe_relpath(directory: Path, rel: Any, where: str) -> Path:
    """Resolve a manifest path, refusing absolute paths and paths that leave the directory."""
    if not isinstance(rel, str) or not rel or "\\" in rel or "\x00" in rel:
        raise CaptureError(f"{where}: media path must be a non-empty relative path with '/' separators")
    parts = rel.split("/")
    if rel.startswith("/") or any(p in ("", ".", "..") for p in parts):
        raise CaptureError(f"{where}: media path {rel!r} must stay inside the capture directory")
    path = directory.joinpath(*parts)
    if path.exists() and not path.resolve().is_relative_to(directory.resolve()):
        raise CaptureError(f"{where}: media path {rel!r} is a link that leaves the capture directory")
    return path


def _numbers(value: Any, shape: tuple[int, ...] | None, where: str) -> np.ndarray:
    arr = parse_numbers(value, shape, where)
    if not np.all(np.isfinite(arr)):
        raise CameraError(f"{where} holds non-finite numbers")
    return arr


def _parse_camera(doc: Any, directory: Path, T: int, index: int) -> CameraEntry:
    if not isinstance(doc, dict):
        raise CaptureError(f"camera #{index}: must be a JSON object")
    name = _need(doc, "name", str, f"camera #{index}")
    if not CAMERA_NAME.match(name):
        raise CaptureError(f"camera #{index}: name {name!r} must match {CAMERA_NAME.pattern}")
    where = f"camera {name!r}"
    width = _need(doc, "width", int, where)
    height = _need(doc, "height", int, where)
    if not (1 <= width <= MAX_SIDE and 1 <= height <= MAX_SIDE):
        raise CaptureError(f"{where}: image size {width}x{height} outside 1..{MAX_SIDE}")
    K = _numbers(_need(doc, "K", list, where), None, f"{where}: K")
    if K.shape not in ((3, 3), (T, 3, 3)):
        raise CameraError(f"{where}: K must be one 3x3 matrix or one per frame ({T}, 3, 3), got {K.shape}")
    w2c = _numbers(_need(doc, "w2c", list, where), None, f"{where}: w2c")
    if w2c.shape not in ((4, 4), (T, 4, 4)):
        raise CameraError(f"{where}: w2c must be one 4x4 pose (static camera) or one per frame ({T}, 4, 4), got {w2c.shape}")
    if w2c.ndim == 2:
        w2c = np.broadcast_to(w2c, (T, 4, 4))
    dist = doc.get("distortion")
    dist = None if dist is None else _numbers(dist, None, f"{where}: distortion")
    ts = doc.get("timestamps")
    ts = None if ts is None else _numbers(ts, (T,), f"{where}: timestamps")
    try:
        traj = Trajectory(K=K, w2c=w2c, width=width, height=height, distortion=dist, timestamps=ts)
    except CameraError as exc:
        raise CameraError(f"{where}: {exc}") from None
    media = _need(doc, "media", dict, where)
    media_type = _need(media, "type", str, f"{where}: media")
    if media_type not in MEDIA_TYPES:
        raise CaptureError(f"{where}: media type {media_type!r} is not one of {MEDIA_TYPES}")
    media_path = _need(media, "path", str, f"{where}: media")
    _safe_relpath(directory, media_path, where)
    depth = doc.get("depth")
    depth_type = depth_path = None
    if depth is not None:
        if not isinstance(depth, dict):
            raise CaptureError(f"{where}: depth must be null or an object")
        depth_type = _need(depth, "type", str, f"{where}: depth")
        if depth_type not in DEPTH_TYPES:
            raise CaptureError(f"{where}: depth type {depth_type!r} is not one of {DEPTH_TYPES}")
        depth_path = _need(depth, "path", str, f"{where}: depth")
        _safe_relpath(directory, depth_path, where)
    return CameraEntry(name, traj, media_type, media_path, depth_type, depth_path)


def read_manifest(directory: str | os.PathLike) -> CaptureManifest:
    """Parse and validate ``DIR/capture.json`` without decoding any media."""
    directory = Path(directory)
    path = directory / MANIFEST_NAME
    if not directory.is_dir():
        raise CaptureError(f"{directory}: not a directory (a capture is a directory with {MANIFEST_NAME})")
    if not path.is_file():
        raise CaptureError(f"{directory}: no {MANIFEST_NAME}; not a capture directory")
    size = path.stat().st_size
    if size > MAX_MANIFEST_BYTES:
        raise CaptureError(f"{path}: {size} bytes exceeds the manifest limit of {MAX_MANIFEST_BYTES}")
    try:
        doc = json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CaptureError(f"{path}: not valid UTF-8 JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise CaptureError(f"{path}: the manifest must be a JSON object")
    if doc.get("format") != CAPTURE_FORMAT:
        raise CaptureError(f"{path}: format is {doc.get('format')!r}, expected {CAPTURE_FORMAT!r}")
    if doc.get("version") != CAPTURE_VERSION:
        raise CaptureError(f"{path}: unsupported capture version {doc.get('version')!r} (reader knows {CAPTURE_VERSION})")
    T = _need(doc, "num_frames", int, str(path))
    if not 1 <= T <= MAX_FRAMES:
        raise CaptureError(f"{path}: num_frames {T} outside 1..{MAX_FRAMES}")
    fps = _need(doc, "fps", (int, float), str(path))
    if not (math.isfinite(fps) and fps > 0):
        raise CaptureError(f"{path}: fps must be a positive number, got {fps!r}")
    capture_id = doc.get("capture_id", directory.name)
    if not isinstance(capture_id, str):
        raise CaptureError(f"{path}: capture_id must be a string")
    metadata = doc.get("metadata", {})
    if not isinstance(metadata, dict):
        raise CaptureError(f"{path}: metadata must be an object")
    cams = _need(doc, "cameras", list, str(path))
    if not 1 <= len(cams) <= MAX_CAMERAS:
        raise CaptureError(f"{path}: {len(cams)} cameras; a capture has 1..{MAX_CAMERAS}")
    entries = tuple(_parse_camera(c, directory, T, i) for i, c in enumerate(cams))
    names = [e.name for e in entries]
    if len(set(names)) != len(names):
        raise CaptureError(f"{path}: camera names must be unique, got {names}")
    return CaptureManifest(directory, capture_id, float(fps), T, entries, metadata)


# --- media -------------------------------------------------------------------------------------------
def _check_png_header(path: Path, width: int, height: int, where: str) -> None:
    """Refuse a file that is not a PNG of the manifest's size before decoding (no decompression bombs)."""
    with path.open("rb") as fh:
        head = fh.read(24)
    if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        raise CaptureError(f"{where}: {path} is not a PNG file")
    w, h = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    if (w, h) != (width, height):
        raise CaptureError(f"{where}: {path} is {w}x{h}, manifest says {width}x{height}")


def _read_png_sequence(folder: Path, T: int, shape: tuple[int, int], where: str, *, depth: bool,
                       window: range) -> np.ndarray:
    """Frames ``window`` of a PNG folder that must hold exactly ``T`` files (the listing is checked; only
    the files in the window are opened)."""
    cv2 = _cv2()
    if not folder.is_dir():
        raise CaptureError(f"{where}: missing folder {folder}")
    present = sorted(p.name for p in folder.glob("*.png"))
    expected = [PNG_NAME.format(i) for i in range(T)]
    if present != expected:
        missing = sorted(set(expected) - set(present))
        extra = sorted(set(present) - set(expected))
        raise CaptureError(
            f"{where}: {folder} holds {len(present)} PNGs but the manifest says {T} frames "
            f"(missing {missing[:3]}{'...' if len(missing) > 3 else ''}, unexpected {extra[:3]})"
        )
    H, W = shape
    n = len(window)
    out = np.empty((n, H, W) if depth else (n, H, W, 3), dtype=np.uint16 if depth else np.uint8)
    flag = cv2.IMREAD_UNCHANGED if depth else cv2.IMREAD_COLOR
    for j, i in enumerate(window):
        name = expected[i]
        _check_png_header(folder / name, W, H, where)
        img = cv2.imread(str(folder / name), flag)
        if img is None:
            raise CaptureError(f"{where}: cannot decode {folder / name}")
        if depth and (img.dtype != np.uint16 or img.ndim != 2):
            raise CaptureError(f"{where}: {folder / name} must be a single-channel 16-bit PNG")
        if img.shape[:2] != (H, W):
            raise CaptureError(f"{where}: {folder / name} is {img.shape[1]}x{img.shape[0]}, manifest says {W}x{H}")
        out[j] = img if depth else img[..., ::-1]
    return out


def _read_depth_npy(path: Path, T: int, shape: tuple[int, int], where: str, window: range) -> np.ndarray:
    if not path.is_file():
        raise CaptureError(f"{where}: missing depth file {path}")
    expected = T * shape[0] * shape[1] * 4
    if path.stat().st_size > expected + 4096:  # npy header is small; refuse files far larger than declared
        raise CaptureError(f"{where}: {path} is larger than a ({T}, {shape[0]}, {shape[1]}) float32 array")
    try:
        arr = np.load(path, allow_pickle=False, mmap_mode="r")
    except (ValueError, OSError, EOFError) as exc:
        raise CaptureError(f"{where}: {path} is not a valid .npy file ({exc})") from None
    if arr.dtype != np.float32 or arr.shape != (T, *shape):
        raise CaptureError(f"{where}: {path} must be float32 {(T, *shape)}, got {arr.dtype} {arr.shape}")
    return np.array(arr[window.start:window.stop])


def frame_window(manifest: CaptureManifest, start: int = 0, num_frames: int | None = None) -> range:
    """Frames ``[start, start + num_frames)`` of the capture (``num_frames`` None: to the end), checked."""
    T = manifest.num_frames
    if isinstance(start, bool) or not isinstance(start, (int, np.integer)) or not 0 <= start < T:
        raise CaptureError(f"start frame {start!r} outside the capture's frames 0..{T - 1}")
    if num_frames is None:
        num_frames = T - start
    if isinstance(num_frames, bool) or not isinstance(num_frames, (int, np.integer)) or not 1 <= num_frames <= T - start:
        raise CaptureError(f"num_frames {num_frames!r}: the capture has {T - start} frames from frame {start} on")
    return range(int(start), int(start) + int(num_frames))


def _check_read_size(manifest: CaptureManifest, names: list[str], window: range) -> None:
    pixels = sum(len(window) * manifest.camera(n).trajectory.width * manifest.camera(n).trajectory.height
                 for n in names)
    if pixels > MAX_READ_PIXELS:
        raise CaptureError(
            f"reading {len(names)} camera(s) x {len(window)} frames of {manifest.directory} is {pixels} pixels, over "
            f"the limit of {MAX_READ_PIXELS} for one read; read a clip at a time (start=, num_frames=) or fewer "
            "cameras (cameras=)")


def read_camera_frames(manifest: CaptureManifest, name: str, start: int = 0, num_frames: int | None = None
                       ) -> np.ndarray:
    """(num_frames, H, W, 3) uint8 RGB frames ``[start, start + num_frames)`` of one camera of a capture
    directory (default: every frame).  Videos are seeked to the window, not decoded from the start."""
    entry = manifest.camera(name)
    window = frame_window(manifest, start, num_frames)
    _check_read_size(manifest, [name], window)
    shape = (entry.trajectory.height, entry.trajectory.width)
    path = _safe_relpath(manifest.directory, entry.media_path, f"camera {name!r}")
    if entry.media_type == "png":
        return _read_png_sequence(path, manifest.num_frames, shape, f"camera {name!r}", depth=False, window=window)
    return read_video_window(path, window.start, len(window), width=shape[1], height=shape[0],
                             total=manifest.num_frames, where=f"camera {name!r}")


def read_camera_depth(manifest: CaptureManifest, entry: CameraEntry, start: int = 0,
                      num_frames: int | None = None) -> np.ndarray:
    """(num_frames, H, W) float32 depth in metres (0 = unknown) of frames ``[start, start + num_frames)``."""
    window = frame_window(manifest, start, num_frames)
    shape = (entry.trajectory.height, entry.trajectory.width)
    where = f"camera {entry.name!r} depth"
    path = _safe_relpath(manifest.directory, entry.depth_path, where)
    if entry.depth_type == "npy_m":
        return _read_depth_npy(path, manifest.num_frames, shape, where, window)
    mm = _read_png_sequence(path, manifest.num_frames, shape, where, depth=True, window=window)
    return mm.astype(np.float32) / np.float32(1000.0)


def read_capture(directory: "str | os.PathLike | CaptureManifest", *, cameras: "list[str] | None" = None,
                 start: int = 0, num_frames: int | None = None) -> Capture:
    """Load a capture directory into memory (frames RGB uint8, depth float32 metres, 0 = unknown).

    Args:
        directory: the capture directory (or its already read manifest).
        cameras: the cameras to read, in this order (default: all, in manifest order).
        start, num_frames: the frames to read, ``[start, start + num_frames)`` (default: all).  The
            returned capture holds just that window: frame 0 is capture frame ``start``, and poses and
            timestamps are cut to it.  Only the window is decoded (videos are seeked).
    One read may decode at most :data:`MAX_READ_PIXELS` pixels; read a long capture a clip at a time.
    """
    manifest = directory if isinstance(directory, CaptureManifest) else read_manifest(directory)
    names = [e.name for e in manifest.cameras] if cameras is None else list(cameras)
    if not names or len(set(names)) != len(names):
        raise CaptureError(f"cameras must name distinct cameras of the capture, got {cameras!r}")
    entries = [manifest.camera(n) for n in names]
    window = frame_window(manifest, start, num_frames)
    _check_read_size(manifest, names, window)
    frames = {e.name: read_camera_frames(manifest, e.name, window.start, len(window)) for e in entries}
    depth = {e.name: read_camera_depth(manifest, e, window.start, len(window)) for e in entries if e.depth_type}
    return Capture(
        cameras={e.name: e.trajectory[window.start:window.stop] for e in entries},
        frames=frames,
        depth=depth or None,
        fps=manifest.fps,
        capture_id=manifest.capture_id,
        metadata=manifest.metadata,
    )


# --- writing -----------------------------------------------------------------------------------------
def _write_png(path: Path, image: np.ndarray) -> None:
    if not _cv2().imwrite(str(path), image):
        raise CaptureError(f"could not write {path}")


def _write_mp4(path: Path, frames: np.ndarray, fps: float) -> None:
    try:
        write_mp4(path, frames, fps)
    except OSError as exc:
        raise CaptureError(str(exc)) from None


def _depth_to_mm(depth: np.ndarray, name: str) -> np.ndarray:
    known = np.isfinite(depth) & (depth > 0)
    if np.any(depth[known] > 65.535):
        raise CaptureError(
            f"camera {name!r}: depth beyond 65.535 m cannot be stored as 16-bit millimetres; use depth='npy'"
        )
    mm = np.zeros(depth.shape, dtype=np.uint16)
    mm[known] = np.clip(np.rint(depth[known] * 1000.0), 1, 65535).astype(np.uint16)
    return mm


def camera_json(name: str, traj: Trajectory, media: dict, depth: dict | None) -> dict[str, Any]:
    K = traj.K[0].tolist() if np.all(traj.K == traj.K[0]) else traj.K.tolist()
    w2c = traj.w2c[0].tolist() if np.all(traj.w2c == traj.w2c[0]) else traj.w2c.tolist()
    return {
        "name": name,
        "width": traj.width,
        "height": traj.height,
        "K": K,
        "distortion": None if traj.distortion is None else traj.distortion.tolist(),
        "w2c": w2c,
        "timestamps": None if traj.timestamps is None else traj.timestamps.tolist(),
        "media": media,
        "depth": depth,
    }


def write_capture(
    capture: Capture,
    directory: str | os.PathLike,
    *,
    media: str = "png",
    depth: str = "npy",
    overwrite: bool = False,
) -> None:
    """Write ``capture`` as a capture directory.

    Args:
        capture: the capture to store.
        directory: created if missing; must not already hold a capture unless ``overwrite``.
        media: ``"png"`` (lossless PNG sequence ``CAM/rgb/000000.png``...) or ``"mp4"`` (lossy
            ``CAM/rgb.mp4``, H.264 yuv420p through PyAV; even image sides only).
        depth: ``"npy"`` (``CAM/depth.npy``, float32 metres, lossless) or ``"png16"`` (``CAM/depth/
            000000.png``, uint16 millimetres, 0 = unknown; depth is rounded to 1 mm and must be
            <= 65.535 m).
    The manifest is written last (atomically), so a directory without ``capture.json`` is incomplete.
    """
    if not isinstance(capture, Capture):
        raise CaptureError("write_capture needs a Capture")
    if media not in MEDIA_TYPES:
        raise CaptureError(f"media must be one of {MEDIA_TYPES}, got {media!r}")
    if depth not in ("npy", "png16"):
        raise CaptureError(f"depth must be 'npy' or 'png16', got {depth!r}")
    for name, traj in capture.cameras.items():
        if not CAMERA_NAME.match(name):
            raise CaptureError(f"camera name {name!r} must match {CAMERA_NAME.pattern} to be stored")
        if media == "mp4" and (traj.width % 2 or traj.height % 2):
            raise CaptureError(f"camera {name!r} is {traj.width}x{traj.height}: H.264 (yuv420p) mp4 media needs even "
                               "sides; write media='png'")
    directory = Path(directory)
    manifest_path = directory / MANIFEST_NAME
    if manifest_path.exists() and not overwrite:
        raise CaptureError(f"{directory} already holds a capture; pass overwrite=True to replace it")
    directory.mkdir(parents=True, exist_ok=True)
    if manifest_path.exists():
        manifest_path.unlink()  # the directory is incomplete until the new manifest lands
    cameras = []
    for name, traj in capture.cameras.items():
        cam_dir = directory / name
        cam_dir.mkdir(exist_ok=True)
        video = capture.frames[name]
        if media == "png":
            (cam_dir / "rgb").mkdir(exist_ok=True)
            for old in (cam_dir / "rgb").glob("*.png"):
                old.unlink()
            for i, frame in enumerate(video):
                _write_png(cam_dir / "rgb" / PNG_NAME.format(i), np.ascontiguousarray(frame[..., ::-1]))
            media_doc = {"type": "png", "path": f"{name}/rgb"}
        else:
            _write_mp4(cam_dir / "rgb.mp4", video, capture.fps)
            media_doc = {"type": "mp4", "path": f"{name}/rgb.mp4"}
        depth_doc = None
        if capture.has_depth(name):
            d = np.asarray(capture.depth[name], dtype=np.float32)
            if depth == "npy":
                np.save(cam_dir / "depth.npy", d, allow_pickle=False)
                depth_doc = {"type": "npy_m", "path": f"{name}/depth.npy"}
            else:
                mm = _depth_to_mm(d, name)
                (cam_dir / "depth").mkdir(exist_ok=True)
                for old in (cam_dir / "depth").glob("*.png"):
                    old.unlink()
                for i, frame in enumerate(mm):
                    _write_png(cam_dir / "depth" / PNG_NAME.format(i), frame)
                depth_doc = {"type": "png16_mm", "path": f"{name}/depth"}
        cameras.append(camera_json(name, traj, media_doc, depth_doc))
    doc = {
        "format": CAPTURE_FORMAT,
        "version": CAPTURE_VERSION,
        "capture_id": capture.capture_id,
        "fps": float(capture.fps),
        "num_frames": capture.num_frames,
        "metadata": capture.metadata,
        "cameras": cameras,
    }
    write_manifest(directory, doc)


def write_manifest(directory: Path, doc: dict[str, Any]) -> None:
    """Write ``doc`` as ``directory/capture.json`` atomically (temporary file, then rename); the media must
    be in place already (a directory is complete once its manifest lands)."""
    try:
        text = json.dumps(doc, indent=1, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise CaptureError(f"capture metadata must be JSON-serializable finite values: {exc}") from None
    tmp = directory / (MANIFEST_NAME + ".tmp")
    tmp.write_text(text + "\n", encoding="utf-8")
    os.replace(tmp, directory / MANIFEST_NAME)
