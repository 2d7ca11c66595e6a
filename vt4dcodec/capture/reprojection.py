"""Check a calibration against point observations: triangulate and measure reprojection error (numpy).

Used to verify that an importer interprets a real calibration correctly: corners observed by several
cameras are triangulated (linear DLT on normalized coordinates) with the imported cameras and
reprojected; a correct reading gives sub-pixel errors.
"""

from __future__ import annotations

import csv
import os
from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from ..errors import CaptureError
from .caliscope import read_caliscope_cameras, recording_file
from .capture import Capture
from .resample import plan_fit, undistort_pixels

__all__ = [
    "triangulate",
    "reproject",
    "read_caliscope_observations",
    "ReprojectionReport",
    "caliscope_reprojection",
]


def triangulate(K: np.ndarray, w2c: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation of one point seen by ``n >= 2`` pinhole cameras.

    Args:
        K: (n, 3, 3) intrinsics; w2c: (n, 4, 4) world-to-camera poses; uv: (n, 2) pixel observations.
    Returns:
        (3,) world point in metres.
    """
    xy1 = np.linalg.solve(K, np.concatenate([uv, np.ones((len(uv), 1))], axis=1)[..., None])[..., 0]
    P = w2c[:, :3, :]  # normalized cameras [R | t]
    A = np.concatenate([xy1[:, :1] * P[:, 2] - P[:, 0], xy1[:, 1:2] * P[:, 2] - P[:, 1]], axis=0)
    _, _, Vt = np.linalg.svd(A)
    X = Vt[-1]
    return X[:3] / X[3]


def reproject(K: np.ndarray, w2c: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(n, 2) pixels of world point ``X`` (3,) in n pinhole cameras (K (n,3,3), w2c (n,4,4))."""
    cam = w2c[:, :3, :3] @ X + w2c[:, :3, 3]
    pix = (K @ cam[..., None])[..., 0]
    return pix[:, :2] / pix[:, 2:3]


def read_caliscope_observations(path: str | os.PathLike) -> dict[tuple[int, int], dict[str, np.ndarray]]:
    """``xy.csv`` -> {(sync_index, keypoint_id): {cam_N: (2,) raw (distorted) pixel position}}."""
    csv_path = recording_file(path, "xy.csv", "point observations")
    obs: dict[tuple[int, int], dict[str, np.ndarray]] = defaultdict(dict)
    with csv_path.open(newline="", encoding="utf-8") as fh:
        for line, row in enumerate(csv.DictReader(fh), start=2):
            try:
                key = (int(row["sync_index"]), int(row["keypoint_id"]))
                uv = np.array([float(row["img_loc_x"]), float(row["img_loc_y"])])
                cam = f"cam_{int(row['cam_id'])}"
            except (KeyError, TypeError, ValueError):
                raise CaptureError(f"{csv_path}:{line}: malformed row") from None
            obs[key][cam] = uv
    return dict(obs)


@dataclass(frozen=True)
class ReprojectionReport:
    """Reprojection errors (pixels) of triangulated points in the images they were observed in."""

    errors: np.ndarray  # (M,) pixel distances, one per observation used
    num_points: int
    resolution: tuple[int, int]  # (width, height) the errors are measured in

    @property
    def median(self) -> float:
        return float(np.median(self.errors))

    @property
    def mean(self) -> float:
        return float(np.mean(self.errors))

    @property
    def p90(self) -> float:
        return float(np.percentile(self.errors, 90))

    def as_dict(self) -> dict:
        return {"median_px": self.median, "mean_px": self.mean, "p90_px": self.p90,
                "observations": int(self.errors.size), "points": self.num_points,
                "width": self.resolution[0], "height": self.resolution[1]}


def caliscope_reprojection(path: str | os.PathLike, capture: Capture | None = None) -> ReprojectionReport:
    """Triangulate the corners of ``path/xy.csv`` and report the reprojection error.

    With ``capture`` (from :func:`~vt4dcodec.capture.caliscope.import_caliscope`): observations are
    undistorted (``cv2.undistortPoints`` with ``P = K``) and mapped by the same resize + crop as the
    images, then triangulated and reprojected with the capture's cameras (errors in its pixels).
    Without: raw cameras at full resolution, reprojected through the lens distortion model.
    """
    import cv2

    raw = read_caliscope_cameras(path)
    obs = read_caliscope_observations(path)
    names = list(raw)
    undistorted: dict[str, dict[tuple[int, int], np.ndarray]] = {}
    for name in names:
        keys = [k for k, per in obs.items() if name in per]
        pts = np.array([obs[k][name] for k in keys]).reshape(-1, 2)
        traj = raw[name]
        und = undistort_pixels(pts, traj.K[0], traj.distortion) if len(pts) else pts
        if capture is not None:
            fitted = capture.cameras[name]
            und = plan_fit(traj.width, traj.height, out_height=fitted.height, out_width=fitted.width).points(und)
        undistorted[name] = dict(zip(keys, und))
    if capture is not None:
        K = {n: capture.cameras[n].K[0] for n in names}
        w2c = {n: capture.cameras[n].w2c[0] for n in names}
        size = (capture.cameras[names[0]].width, capture.cameras[names[0]].height)
    else:
        K = {n: raw[n].K[0] for n in names}
        w2c = {n: raw[n].w2c[0] for n in names}
        size = (raw[names[0]].width, raw[names[0]].height)
    errors, points = [], 0
    for key, per in obs.items():
        cams = [n for n in names if n in per]
        if len(cams) < 2:
            continue
        Ks, Ps = np.stack([K[n] for n in cams]), np.stack([w2c[n] for n in cams])
        X = triangulate(Ks, Ps, np.stack([undistorted[n][key] for n in cams]))
        points += 1
        if capture is not None:
            pred = reproject(Ks, Ps, X)
            seen = np.stack([undistorted[n][key] for n in cams])
        else:  # through the real lens, against the raw detections
            pred = np.stack([
                cv2.projectPoints(X[None], cv2.Rodrigues(w2c[n][:3, :3])[0], w2c[n][:3, 3], K[n],
                                  raw[n].distortion)[0].reshape(2)
                for n in cams
            ])
            seen = np.stack([per[n] for n in cams])
        errors.extend(np.linalg.norm(pred - seen, axis=1))
    if not errors:
        raise CaptureError(f"{path}: no point is observed by two cameras; cannot triangulate")
    return ReprojectionReport(np.asarray(errors), points, size)
