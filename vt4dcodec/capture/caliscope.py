"""Import a real multi-camera recording calibrated with caliscope (github.com/mprib/caliscope).

Expected layout (as in ``/work/shared/data/caliscope_4cam``)::

    camera_array.toml    [cameras.N]: matrix (3x3 K, px), distortions (k1 k2 p1 p2 k3), rotation (3x3)
                         and translation (metres), world-to-camera (x_cam = R x_world + t); size [W, H]
    timestamps.csv       sync_index, cam_id, frame_time (seconds): frame k of every mp4 belongs to
                         the k-th sync_index in ascending order
    videos/cam_N.mp4     the raw (distorted) frames the calibration applies to

``rotation_count`` is ignored: the calibration applies to the frames as stored.  The importer streams
each video once, keeps every ``frame_step``-th synchronized frame (up to ``num_frames``), undistorts,
resizes and centre-crops it to the model resolution (:mod:`vt4dcodec.capture.resample`), and returns
a :class:`Capture` whose cameras are static pinhole cameras named ``cam_N``.
"""

from __future__ import annotations

import csv
import os
import tomllib
from collections import defaultdict
from pathlib import Path

import numpy as np

from ..cameras import Trajectory
from ..errors import CameraError, CaptureError
from .capture import Capture
from .resample import FitPlan, FrameFitter, fit_trajectory, plan_fit

__all__ = ["read_caliscope_cameras", "read_caliscope_timestamps", "import_caliscope", "find_sample_capture"]

SAMPLE_ENV = "VT4D_CALISCOPE"  # where the caliscope_4cam sample recording lives, if not beside the repo


def find_sample_capture() -> Path | None:
    """The caliscope_4cam sample recording: ``$VT4D_CALISCOPE``, else ``shared/data/caliscope_4cam`` beside
    the repository (where CI and the development machines keep it), else None."""
    repo = Path(__file__).resolve().parents[2]
    candidates = [os.environ.get(SAMPLE_ENV), repo.parent / "shared" / "data" / "caliscope_4cam",
                  Path("/work/shared/data/caliscope_4cam")]
    for c in candidates:
        if c and (Path(c) / "camera_array.toml").is_file():
            return Path(c)
    return None

MAX_CSV_BYTES = 256 * 1024 * 1024


def read_caliscope_cameras(path: str | os.PathLike) -> dict[str, Trajectory]:
    """Calibration of ``camera_array.toml``: ``cam_N`` -> one-frame Trajectory at the raw video size,
    with its distortion terms.  Cameras marked ``ignore = true`` are skipped."""
    path = Path(path)
    toml_path = path / "camera_array.toml" if path.is_dir() else path
    if not toml_path.is_file():
        raise CaptureError(f"{toml_path}: missing caliscope calibration (camera_array.toml)")
    try:
        doc = tomllib.loads(toml_path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise CaptureError(f"{toml_path}: not valid TOML ({exc})") from None
    cams = doc.get("cameras")
    if not isinstance(cams, dict) or not cams:
        raise CaptureError(f"{toml_path}: no [cameras.N] tables")
    out: dict[str, tuple[int, Trajectory]] = {}
    for key, cam in cams.items():
        where = f"{toml_path.name} [cameras.{key}]"
        if not isinstance(cam, dict):
            raise CaptureError(f"{where}: must be a table")
        if cam.get("ignore") is True:
            continue
        try:
            cam_id = int(cam.get("cam_id", key))
            K = np.asarray(cam["matrix"], dtype=np.float64)
            dist = np.asarray(cam["distortions"], dtype=np.float64)
            R = np.asarray(cam["rotation"], dtype=np.float64)
            t = np.asarray(cam["translation"], dtype=np.float64).reshape(-1)
            width, height = (int(v) for v in cam["size"])
        except KeyError as exc:
            raise CaptureError(f"{where}: missing key {exc}") from None
        except (TypeError, ValueError) as exc:
            raise CameraError(f"{where}: malformed calibration ({exc})") from None
        if R.shape != (3, 3) or t.shape != (3,):
            raise CameraError(f"{where}: rotation must be 3x3 and translation 3 numbers")
        w2c = np.eye(4)
        w2c[:3, :3], w2c[:3, 3] = R, t
        try:
            traj = Trajectory(K=K, w2c=w2c, width=width, height=height, distortion=dist)
        except CameraError as exc:
            raise CameraError(f"{where}: {exc}") from None
        out[f"cam_{cam_id}"] = (cam_id, traj)
    return {name: traj for name, (_, traj) in sorted(out.items(), key=lambda kv: kv[1][0])}


def recording_file(path: str | os.PathLike, name: str, what: str) -> Path:
    """``path/name`` (or ``path`` itself when it is a file), checked to exist and be of sane size."""
    path = Path(path)
    file = path / name if path.is_dir() else path
    if not file.is_file():
        raise CaptureError(f"{file}: missing {name} ({what})")
    if file.stat().st_size > MAX_CSV_BYTES:
        raise CaptureError(f"{file}: larger than {MAX_CSV_BYTES} bytes")
    return file


def read_caliscope_timestamps(path: str | os.PathLike) -> tuple[list[int], dict[str, np.ndarray]]:
    """``timestamps.csv`` -> (ascending sync indices, ``cam_N`` -> (S,) frame times in seconds).

    Every camera must have exactly one frame per sync index."""
    csv_path = recording_file(path, "timestamps.csv", "frame synchronisation")
    times: dict[str, dict[int, float]] = defaultdict(dict)
    with csv_path.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        if reader.fieldnames is None or not {"sync_index", "cam_id", "frame_time"} <= set(reader.fieldnames):
            raise CaptureError(f"{csv_path}: needs columns sync_index, cam_id, frame_time")
        for line, row in enumerate(reader, start=2):
            try:
                sync, cam, t = int(row["sync_index"]), int(row["cam_id"]), float(row["frame_time"])
            except (TypeError, ValueError):
                raise CaptureError(f"{csv_path}:{line}: malformed row {row}") from None
            if not np.isfinite(t):
                raise CaptureError(f"{csv_path}:{line}: non-finite frame_time")
            name = f"cam_{cam}"
            if sync in times[name]:
                raise CaptureError(f"{csv_path}:{line}: {name} has two frames at sync_index {sync}")
            times[name][sync] = t
    syncs = sorted({s for per_cam in times.values() for s in per_cam})
    if not syncs:
        raise CaptureError(f"{csv_path}: no frames")
    out = {}
    for name, per_cam in times.items():
        missing = [s for s in syncs if s not in per_cam]
        if missing:
            raise CaptureError(f"{csv_path}: {name} has no frame at sync_index {missing[:5]}")
        out[name] = np.array([per_cam[s] for s in syncs])
    return syncs, out


def _stream_fitted_frames(video: Path, keep: list[int], total: int, fitter: FrameFitter,
                          plan: FitPlan, where: str) -> np.ndarray:
    """Decode ``video`` up to the last frame in ``keep``; undistort + fit the frames in ``keep``.

    The frame count the container declares must equal ``total`` (the synchronized frame count);
    a video that ends early is caught while decoding."""
    import cv2

    if not video.is_file():
        raise CaptureError(f"{where}: missing video {video}")
    cap = cv2.VideoCapture(str(video))
    if not cap.isOpened():
        raise CaptureError(f"{where}: cannot open {video}")
    out = np.empty((len(keep), plan.out_height, plan.out_width, 3), dtype=np.uint8)
    wanted = {k: j for j, k in enumerate(keep)}
    try:
        declared = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        if declared != total:
            raise CaptureError(f"{where}: {video.name} declares {declared} frames but timestamps.csv lists {total}")
        for i in range(max(keep) + 1):
            ok, bgr = cap.read()
            if not ok:
                raise CaptureError(f"{where}: {video.name} ends after {i} frames; timestamps.csv lists {total}")
            if bgr.shape[:2] != (plan.in_height, plan.in_width):
                raise CaptureError(f"{where}: {video.name} is {bgr.shape[1]}x{bgr.shape[0]} but calibrated "
                                   f"for {plan.in_width}x{plan.in_height}")
            if i in wanted:
                rgb = np.ascontiguousarray(bgr[..., ::-1])
                out[wanted[i]] = fitter.image(rgb)
    finally:
        cap.release()
    return out


def import_caliscope(
    path: str | os.PathLike,
    *,
    height: int = 64,
    width: int = 64,
    num_frames: int | None = None,
    frame_step: int = 1,
    fit: str = "crop",
) -> Capture:
    """Import a caliscope recording as an undistorted, resized, centre-cropped capture.

    Args:
        path: the recording directory (camera_array.toml, timestamps.csv, videos/cam_N.mp4).
        height, width: output resolution in pixels (resize the shorter side, then centre-crop).
        num_frames: keep at most this many synchronized frames (default: all).
        frame_step: keep every ``frame_step``-th synchronized frame (fps divides accordingly).
        fit: ``"crop"`` (centre-crop) or ``"pad"`` (letterbox) to the output size (:mod:`.resample`).
    Returns:
        A Capture with static pinhole cameras ``cam_N`` (K in output pixels, no distortion),
        per-camera timestamps in seconds from the first frame, fps from the median frame interval.
    """
    path = Path(path)
    if not path.is_dir():
        raise CaptureError(f"{path}: not a directory")
    if isinstance(frame_step, bool) or not isinstance(frame_step, int) or frame_step < 1:
        raise CaptureError(f"frame_step must be a positive integer, got {frame_step!r}")
    calib = read_caliscope_cameras(path)
    syncs, times = read_caliscope_timestamps(path)
    missing = sorted(set(calib) - set(times))
    if missing:
        raise CaptureError(f"{path}: cameras {missing} have calibration but no timestamps")
    keep = list(range(0, len(syncs), frame_step))
    if num_frames is not None:
        if isinstance(num_frames, bool) or not isinstance(num_frames, int) or num_frames < 1:
            raise CaptureError(f"num_frames must be a positive integer, got {num_frames!r}")
        keep = keep[:num_frames]
    t0 = min(float(t.min()) for name, t in times.items() if name in calib)
    cameras, frames = {}, {}
    for name, traj in calib.items():
        plan = plan_fit(traj.width, traj.height, out_height=height, out_width=width, fit=fit)
        fitter = FrameFitter(traj.K[0], traj.distortion, plan)
        frames[name] = _stream_fitted_frames(path / "videos" / f"{name}.mp4", keep, len(syncs), fitter,
                                             plan, f"camera {name!r}")
        T = len(keep)
        full = Trajectory(K=np.broadcast_to(traj.K[0], (T, 3, 3)), w2c=np.broadcast_to(traj.w2c[0], (T, 4, 4)),
                          width=traj.width, height=traj.height, timestamps=times[name][keep] - t0)
        cameras[name] = fit_trajectory(full, plan)
    mean_times = np.mean([times[n] for n in calib], axis=0)
    intervals = np.diff(mean_times[keep])
    fps = float(1.0 / np.median(intervals)) if len(intervals) and np.median(intervals) > 0 else 1.0
    metadata = {
        "source": "caliscope",
        "source_path": str(path),
        "sync_indices": [syncs[k] for k in keep],
        "raw_size": {n: [t.width, t.height] for n, t in calib.items()},
        "fit": {"height": height, "width": width, "frame_step": frame_step, "num_frames": len(keep), "mode": fit},
    }
    return Capture(cameras=cameras, frames=frames, fps=fps, capture_id=path.name, metadata=metadata)
