"""Camera conventions shared by every part of vt4dcodec (numpy only; no torch).

Conventions (normative text in FORMAT.md, "Camera conventions"):

* OpenCV pinhole: x right, y down, z forward; pixel (u, v) has its centre at integer coordinates,
  so the top-left pixel's centre is (0, 0).
* Intrinsics ``K`` in pixels: ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` with ``fx, fy > 0``.
* Extrinsics are world-to-camera 4x4 matrices in metres: ``x_cam = R @ x_world + t``.
* Optional OpenCV distortion coefficients in OpenCV order ``k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4
  [tx ty]]]]`` (4, 5, 8, 12 or 14 terms), applying to the stored image size.
* One pose (and one K) per frame; optional timestamps in seconds, non-decreasing.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import CameraError, TrajectoryError

__all__ = ["Trajectory", "validate_intrinsics", "validate_w2c", "look_at", "parse_numbers", "DISTORTION_LENGTHS"]

DISTORTION_LENGTHS = (4, 5, 8, 12, 14)
ROTATION_TOLERANCE = 1e-4  # max |R^T R - I| entry accepted as orthonormal
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_EYE3 = np.eye(3)


def parse_numbers(value: Any, shape: tuple[int, ...] | None, where: str,
                  error: type[CameraError] = CameraError) -> np.ndarray:
    """A (nested) JSON list of numbers as float64, optionally of exactly ``shape``; strings, booleans,
    objects and ragged lists raise ``error`` naming ``where``."""
    try:
        raw = np.asarray(value)
        if raw.dtype.kind not in "iuf":
            raise TypeError
        arr = raw.astype(np.float64)
    except (ValueError, TypeError, OverflowError):
        raise error(f"{where} must be a (nested) list of numbers") from None
    if shape is not None and arr.shape != shape:
        raise error(f"{where} has shape {arr.shape}, expected {shape}")
    return arr


def validate_intrinsics(K: np.ndarray, *, what: str = "K") -> np.ndarray:
    """Return ``K`` as float64 (..., 3, 3) after checking finiteness, layout and positive focal lengths."""
    K = np.asarray(K, dtype=np.float64)
    if K.shape[-2:] != (3, 3):
        raise CameraError(f"{what} must have shape (..., 3, 3), got {K.shape}")
    if not np.isfinite(K).all():
        raise CameraError(f"{what} holds non-finite values (NaN or inf)")
    if (K[..., 0, 0] <= 0).any() or (K[..., 1, 1] <= 0).any():
        raise CameraError(f"{what}: focal lengths fx and fy must be positive pixels")
    if (K[..., 1, 0] != 0).any() or (K[..., 2, :2] != 0).any() or (K[..., 2, 2] != 1).any():
        raise CameraError(f"{what} must be upper triangular with K[2, 2] == 1 (OpenCV pinhole)")
    return K


def validate_w2c(w2c: np.ndarray, *, what: str = "w2c") -> np.ndarray:
    """Return world-to-camera poses as float64 (..., 4, 4) after checking they are rigid transforms."""
    w2c = np.asarray(w2c, dtype=np.float64)
    if w2c.shape[-2:] != (4, 4):
        raise CameraError(f"{what} must have shape (..., 4, 4), got {w2c.shape}")
    if not np.isfinite(w2c).all():
        raise CameraError(f"{what} holds non-finite values (NaN or inf)")
    if (w2c[..., 3, :] != _LAST_ROW).any():
        raise CameraError(f"{what}: the last row of every pose must be exactly [0, 0, 0, 1]")
    R = w2c[..., :3, :3]
    # entries below 1e150 cannot overflow R^T R; huge ones give inf or NaN there, refused by name below
    quiet = contextlib.nullcontext() if float(np.abs(R).max(initial=0.0)) < 1e150 else \
        np.errstate(over="ignore", invalid="ignore")
    with quiet:
        gram = np.matmul(np.swapaxes(R, -1, -2), R)
        gram -= _EYE3
        err = float(np.abs(gram).max(initial=0.0))
        det = np.linalg.det(R) if err <= ROTATION_TOLERANCE else None
    if not err <= ROTATION_TOLERANCE:  # NaN-safe: a NaN error is not within the tolerance
        raise CameraError(
            f"{what}: rotation is not orthonormal (max |R^T R - I| = {err:.2e} > {ROTATION_TOLERANCE})"
        )
    if det is None or not (det > 0).all():
        raise CameraError(f"{what}: rotation has determinant -1 (a reflection), not a rotation")
    return w2c



def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """World-to-camera poses (..., 4, 4) of cameras at ``eye`` (..., 3) looking at ``target`` (..., 3), the
    image's up along ``up`` ((3,) or (..., 3)): z towards the target, y down (opposite ``up``), x right.

    Raises TrajectoryError where a target is its camera's centre or a camera looks along ``up``.
    """
    eye = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    eye = np.broadcast_to(eye, forward.shape)
    distance = np.linalg.norm(forward, axis=-1, keepdims=True)
    if np.any(distance < 1e-12):
        raise TrajectoryError("look-at target coincides with the camera centre")
    forward = forward / distance
    right = np.cross(forward, np.broadcast_to(np.asarray(up, dtype=np.float64), forward.shape))
    norm = np.linalg.norm(right, axis=-1, keepdims=True)
    if np.any(norm < 1e-9):
        raise TrajectoryError("look-at direction is parallel to the up vector")
    right = right / norm
    down = np.cross(forward, right)
    R = np.stack([right, down, forward], axis=-2)  # rows: camera axes in world coordinates
    w2c = np.zeros(forward.shape[:-1] + (4, 4))
    w2c[..., :3, :3] = R
    w2c[..., :3, 3] = -np.einsum("...ij,...j->...i", R, eye)
    w2c[..., 3, 3] = 1.0
    return w2c


@dataclass(frozen=True)
class Trajectory:
    """A camera along a video: one pinhole camera per frame.

    Attributes:
        K: (T, 3, 3) float64 intrinsics in pixels.
        w2c: (T, 4, 4) float64 world-to-camera poses in metres.
        width, height: image size in pixels that ``K`` refers to.
        distortion: optional (n,) float64 OpenCV distortion terms, n in (4, 5, 8, 12, 14).
        timestamps: optional (T,) float64 seconds, non-decreasing.
    """

    K: np.ndarray
    w2c: np.ndarray
    width: int
    height: int
    distortion: np.ndarray | None = None
    timestamps: np.ndarray | None = None

    def __post_init__(self) -> None:
        K = validate_intrinsics(self.K)
        w2c = validate_w2c(self.w2c)
        if K.ndim == 2:
            K = np.broadcast_to(K, (w2c.shape[0], 3, 3)) if w2c.ndim == 3 else K[None]
        if w2c.ndim == 2:
            w2c = w2c[None]
        if K.ndim != 3 or w2c.ndim != 3:
            raise CameraError("K must be (T, 3, 3) or (3, 3) and w2c (T, 4, 4) or (4, 4)")
        if K.shape[0] != w2c.shape[0]:
            raise CameraError(f"K has {K.shape[0]} frames but w2c has {w2c.shape[0]}")
        if w2c.shape[0] < 1:
            raise CameraError("a trajectory needs at least one frame")
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
                raise CameraError(f"{name} must be a positive integer number of pixels, got {v!r}")
        dist = self.distortion
        if dist is not None:
            dist = np.asarray(dist, dtype=np.float64).reshape(-1)
            if dist.shape[0] not in DISTORTION_LENGTHS:
                raise CameraError(
                    f"distortion must have one of {DISTORTION_LENGTHS} OpenCV terms, got {dist.shape[0]}"
                )
            if not np.all(np.isfinite(dist)):
                raise CameraError("distortion holds non-finite values")
        ts = self.timestamps
        if ts is not None:
            ts = np.asarray(ts, dtype=np.float64).reshape(-1)
            if ts.shape[0] != w2c.shape[0]:
                raise CameraError(f"{ts.shape[0]} timestamps for {w2c.shape[0]} frames")
            if not np.all(np.isfinite(ts)) or np.any(np.diff(ts) < 0):
                raise CameraError("timestamps must be finite seconds and non-decreasing")
        object.__setattr__(self, "K", np.ascontiguousarray(K))
        object.__setattr__(self, "w2c", np.ascontiguousarray(w2c))
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "distortion", dist)
        object.__setattr__(self, "timestamps", ts)

    @classmethod
    def _checked_elsewhere(cls, K: np.ndarray, w2c: np.ndarray, width: int, height: int,
                           timestamps: np.ndarray | None) -> "Trajectory":
        """A trajectory of arrays a decoder has already checked against every convention above (C-contiguous
        float64 (T, 3, 3) and (T, 4, 4), a positive integer size, (T,) timestamps or None, no distortion),
        without checking them a second time."""
        obj = object.__new__(cls)
        for name, value in (("K", K), ("w2c", w2c), ("width", int(width)), ("height", int(height)),
                            ("distortion", None), ("timestamps", timestamps)):
            object.__setattr__(obj, name, value)
        return obj

    @property
    def num_frames(self) -> int:
        return int(self.w2c.shape[0])

    def __len__(self) -> int:
        return self.num_frames

    @property
    def c2w(self) -> np.ndarray:
        """(T, 4, 4) camera-to-world poses."""
        return np.linalg.inv(self.w2c)

    @property
    def centers(self) -> np.ndarray:
        """(T, 3) camera centres in world coordinates (metres)."""
        R, t = self.w2c[:, :3, :3], self.w2c[:, :3, 3]
        centers: np.ndarray = -np.einsum("tji,tj->ti", R, t)
        return centers

    def __getitem__(self, idx: Any) -> "Trajectory":
        """Frames ``idx`` (an int, slice or index array) as a new trajectory."""
        sel = np.arange(self.num_frames)[idx]
        sel = np.atleast_1d(sel)
        return Trajectory(
            K=self.K[sel], w2c=self.w2c[sel], width=self.width, height=self.height,
            distortion=self.distortion,
            timestamps=None if self.timestamps is None else self.timestamps[sel],
        )

    def equals(self, other: "Trajectory", atol: float = 0.0) -> bool:
        """True when both describe the same cameras (within ``atol``)."""
        def close(a: np.ndarray | None, b: np.ndarray | None) -> bool:
            if a is None or b is None:
                return a is None and b is None
            return a.shape == b.shape and bool(np.allclose(a, b, atol=atol, rtol=0))
        return (
            self.width == other.width and self.height == other.height
            and close(self.K, other.K) and close(self.w2c, other.w2c)
            and close(self.distortion, other.distortion) and close(self.timestamps, other.timestamps)
        )
