"""The renderer's depth reference: the world point the tokens' depths are measured from.

VideoTok4D places each static token on its cell's ray at the depth of the world origin in the token's encoded
camera (its z in that camera, at least 0.1 m) times a learned factor in [e^-2, e^2] (``model/renderer.py``,
``anchor_depths``). In the captures it was trained on, the origin is the floor below the point the cameras look
at, 2.8-5.6 m ahead of a moving camera. A real capture's world frame is its calibration's: the origin may sit at
a camera (OpenCV stereo and caliscope calibrations, structure-from-motion's first image) or in the cameras'
plane (LLFF's recentred poses). There the reference collapses to 0.1 m, every token lands within 0.74 m of the
lens, and a moving camera's own view loses ~9 dB (``bench/probes/probe_world_origin.py``).

So the codec checks the origin before encoding. When it is less than :data:`MIN_REFERENCE_DEPTH` in front of
an encoded camera at any frame of the clip (or behind one), the encoder and the renderer work in the world frame
moved so that its origin is a **reference point** (:func:`reference_point`): the point nearest to the encoded
cameras' optical axes over the clip, where they meet at least :data:`MIN_REFERENCE_DEPTH` in front of every
encoded camera; otherwise the point :data:`DEFAULT_REFERENCE_DEPTH` ahead of the first encoded camera at the
clip's middle frame. The file records the point (``metadata["vt4d"]["centre_mm"]``: integer millimetres,
FORMAT.md I.9) and the decoder renders every trajectory in the same moved frame; the stored cameras stay in the
capture's own frame. A clip whose origin is in front of every encoded camera encodes exactly as before, and a
file without the key decodes as before. Torch-free.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import numpy as np

from .errors import FormatError

__all__ = ["MIN_REFERENCE_DEPTH", "DEFAULT_REFERENCE_DEPTH", "CENTRE_KEY", "REFERENCE_FRAMES", "needs_reference",
           "reference_point", "model_centre", "centre_from_metadata", "centre_to_metadata", "move_origin",
           "move_trajectory"]

MIN_REFERENCE_DEPTH = 0.5  # metres: an origin nearer than this to an encoded camera's image plane is moved
DEFAULT_REFERENCE_DEPTH = 4.0  # metres ahead of the first encoded camera: the training rigs' median origin depth
MIN_AXIS_SPREAD = 0.01  # smallest eigenvalue of the mean of (I - a a^T) over the axes a: about 8 degrees apart
CENTRE_KEY = "centre_mm"
MAX_CENTRE_MM = 10 ** 9  # 1,000 km: a stored reference point beyond this is refused
REFERENCE_FRAMES = ("origin", "cameras")  # ModelConfig.reference_frame


def _w2c(trajectories: Sequence[Any]) -> np.ndarray:
    """(V, T, 4, 4) float64 world-to-camera matrices of trajectories of one length."""
    return np.stack([np.asarray(t.w2c, np.float64).reshape(-1, 4, 4) for t in trajectories])


def needs_reference(trajectories: Sequence[Any] | np.ndarray) -> bool:
    """Whether the world origin is less than MIN_REFERENCE_DEPTH in front of (or behind) any of ``trajectories``
    (the encoded cameras of one clip, or their w2c (V, T, 4, 4)) at any frame: z of the origin in camera =
    w2c[2, 3]."""
    return bool((_as_w2c(trajectories)[..., 2, 3] < MIN_REFERENCE_DEPTH).any())


def _as_w2c(trajectories: Sequence[Any] | np.ndarray) -> np.ndarray:
    if isinstance(trajectories, np.ndarray):
        return np.asarray(trajectories, np.float64).reshape(trajectories.shape[0], -1, 4, 4)
    return _w2c(trajectories)


def reference_point(trajectories: Sequence[Any] | np.ndarray) -> np.ndarray:
    """(3,) float64 world point, metres: where the encoded cameras' optical axes (every frame) come nearest to
    each other, when they spread at least MIN_AXIS_SPREAD and that point lies MIN_REFERENCE_DEPTH or more in front
    of every camera at every frame; else DEFAULT_REFERENCE_DEPTH ahead of the first camera at its middle frame.
    ``trajectories``: the encoded cameras of one clip, or their w2c (V, T, 4, 4)."""
    per_camera = _as_w2c(trajectories)
    w2c = per_camera.reshape(-1, 4, 4)
    R, t = w2c[:, :3, :3], w2c[:, :3, 3]
    centres = -np.einsum("nji,nj->ni", R, t)  # camera centres, world
    axes = R[:, 2]  # optical axes (unit rows of R), world
    projectors = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]  # (n, 3, 3): distance to each axis
    A = projectors.mean(0)
    if np.linalg.eigvalsh(A)[0] >= MIN_AXIS_SPREAD:
        point = np.linalg.solve(A, np.einsum("nij,nj->i", projectors, centres) / len(centres))
        if np.all(np.einsum("nij,j->ni", R, point)[:, 2] + t[:, 2] >= MIN_REFERENCE_DEPTH):
            return point
    first = per_camera[0]
    mid = first[first.shape[0] // 2]
    return -mid[:3, :3].T @ mid[:3, 3] + DEFAULT_REFERENCE_DEPTH * mid[2, :3]


def model_centre(reference_frame: str, trajectories: Sequence[Any] | np.ndarray) -> np.ndarray | None:
    """The point a model works from for these encoded cameras (one clip), rounded to the millimetre as the file
    stores it, or None (the world origin). ``reference_frame`` (``ModelConfig.reference_frame``): ``"origin"``,
    the world origin unless :func:`needs_reference`; ``"cameras"``, always :func:`reference_point` (a model
    trained in that frame, so that it never sees the capture's own origin). The codec and the training data both
    take it from here."""
    if reference_frame not in REFERENCE_FRAMES:
        raise ValueError(f"reference_frame must be one of {REFERENCE_FRAMES}, got {reference_frame!r}")
    if reference_frame == "cameras" or needs_reference(trajectories):
        return np.asarray(centre_to_metadata(reference_point(trajectories)), np.float64) / 1000.0
    return None


def centre_to_metadata(point: np.ndarray) -> list[int]:
    """The point as the file stores it: whole millimetres."""
    return [int(v) for v in np.round(np.asarray(point, np.float64) * 1000.0)]


def centre_from_metadata(metadata: dict[str, Any] | None) -> np.ndarray | None:
    """The reference point a file records (metres, (3,) float64), or None: the world origin. FormatError for a
    value that is not three integers of at most MAX_CENTRE_MM in magnitude."""
    info = (metadata or {}).get("vt4d")
    if not isinstance(info, dict) or CENTRE_KEY not in info:
        return None
    value = info[CENTRE_KEY]
    if (not isinstance(value, list) or len(value) != 3
            or not all(isinstance(v, int) and not isinstance(v, bool) and abs(v) <= MAX_CENTRE_MM for v in value)):
        raise FormatError(f"metadata vt4d.{CENTRE_KEY} must be three integers (millimetres, |v| <= {MAX_CENTRE_MM}), "
                          f"got {value!r}")
    return np.asarray(value, np.float64) / 1000.0


def move_origin(w2c: np.ndarray, point: np.ndarray | None) -> np.ndarray:
    """World-to-camera matrices (..., 4, 4) in the frame whose origin is ``point`` (world, metres): x_world =
    x_moved + point, so w2c_moved = w2c [[I, point], [0, 1]]; ``point`` None: ``w2c`` unchanged. The dtype is
    kept."""
    if point is None:
        return w2c
    w2c = np.asarray(w2c)
    moved = np.array(w2c, np.float64, copy=True)
    moved[..., :3, 3] = moved[..., :3, 3] + np.einsum("...ij,j->...i", moved[..., :3, :3], np.asarray(point,
                                                                                                       np.float64))
    return moved.astype(w2c.dtype)


def move_trajectory(trajectory: Any, point: np.ndarray | None) -> Any:
    """A trajectory (any dataclass with ``w2c``, e.g. :class:`~vt4dcodec.cameras.Trajectory`) in the frame whose
    origin is ``point`` (:func:`move_origin`); ``point`` None: the trajectory itself."""
    return trajectory if point is None else dataclasses.replace(trajectory, w2c=move_origin(trajectory.w2c, point))
