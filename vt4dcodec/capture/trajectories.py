"""Target camera trajectories: presets (orbit, dolly, pan, tilt, crane, static, interpolation) and a
small JSON file format for saving and loading any :class:`~vt4dcodec.cameras.Trajectory` (numpy only).

All presets start at the reference camera's first pose and use its first ``K`` and image size; they
produce pinhole cameras (no distortion).  Directions are in the reference camera's own frame, since
a capture's world frame has no agreed "up":

* ``static``: the first pose repeated.
* ``orbit``: rotate about the axis through the look-at point ``distance`` metres ahead on the optical
  axis, parallel to the camera's y (down) axis, by ``degrees`` in total; positive moves the camera to
  its right (the view keeps the look-at point at the same pixel).
* ``dolly_in`` / ``dolly_out``: move ``metres`` forward / backward along the optical axis.
* ``pan``: turn about the camera centre around its y axis by ``degrees`` (positive = turn right).
* ``tilt``: turn about the camera centre around its x axis by ``degrees`` (positive = look up).
* ``crane``: move ``metres`` up (along the first camera's -y axis) while turning to keep looking at
  the point ``distance`` metres ahead of the first camera.
* ``interpolate``: from the first pose to ``target`` (a Trajectory, its first frame, or a 4x4
  world-to-camera matrix): rotation by SLERP, camera centre and intrinsics by linear interpolation.

The motion is spread linearly over ``num_frames`` frames (default: the reference's frame count);
frame 0 is the start pose and the last frame the full motion.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..cameras import Trajectory, look_at, parse_numbers
from ..errors import CameraError, TrajectoryError
from .targets import check_camera_spec

__all__ = [
    "PRESETS",
    "PRESET_PARAMS",
    "make_trajectory",
    "parse_trajectory_spec",
    "check_trajectory_spec",
    "SPEC_PRESETS",
    "PRESET_SUMMARY",
    "describe_spec_presets",
    "save_trajectory",
    "load_trajectory",
    "trajectory_to_json",
    "trajectory_from_json",
    "slerp_rotation",
]

# preset -> parameter names with their defaults (metres and degrees)
PRESET_PARAMS: dict[str, dict[str, float]] = {
    "static": {},
    "orbit": {"degrees": 30.0, "distance": 2.0},
    "dolly_in": {"metres": 0.5},
    "dolly_out": {"metres": 0.5},
    "pan": {"degrees": 30.0},
    "tilt": {"degrees": 20.0},
    "crane": {"metres": 0.5, "distance": 2.0},
    "interpolate": {},
}
PRESETS: tuple[str, ...] = tuple(PRESET_PARAMS)
# A spec string ("orbit:degrees=30") can name every preset but interpolate, which needs a target camera
# (Python: make_trajectory("interpolate", ref, target=...); command line: a saved trajectory JSON).
SPEC_PRESETS: tuple[str, ...] = tuple(p for p in PRESETS if p != "interpolate")
# one line per preset for --help (the motion itself is described in the module docstring)
PRESET_SUMMARY: dict[str, str] = {
    "static": "the first source pose held still",
    "orbit": "circle DISTANCE m ahead by DEGREES (positive: to the camera's right)",
    "dolly_in": "move METRES forward along the optical axis",
    "dolly_out": "move METRES backward along the optical axis",
    "pan": "turn about the camera centre by DEGREES (positive: right)",
    "tilt": "turn about the camera centre by DEGREES (positive: up)",
    "crane": "rise METRES while looking at the point DISTANCE m ahead",
}

MAX_TRAJECTORY_FRAMES = 100_000
MAX_TRAJECTORY_FILE_BYTES = 64 * 1024 * 1024
TRAJECTORY_FORMAT = "vt4d-trajectory"
TRAJECTORY_VERSION = 1


# --- rotation helpers --------------------------------------------------------------------------------
def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """3x3 rotation by ``angle`` radians about unit ``axis`` (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    Kx = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * Kx + (1 - math.cos(angle)) * (Kx @ Kx)


def _rotation_to_quaternion(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a 3x3 rotation (Shepperd's method, numerically stable)."""
    tr = np.trace(R)
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    return q / np.linalg.norm(q)


def _quaternion_to_rotation(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def slerp_rotation(R0: np.ndarray, R1: np.ndarray, s: float) -> np.ndarray:
    """Spherical linear interpolation between rotations (shortest arc); s in [0, 1]."""
    q0, q1 = _rotation_to_quaternion(R0), _rotation_to_quaternion(R1)
    dot = float(np.dot(q0, q1))
    if dot < 0:
        q1, dot = -q1, -dot
    if dot > 0.9995:  # nearly equal: linear interpolation is exact enough and avoids 0/0
        q = q0 + s * (q1 - q0)
    else:
        theta = math.acos(min(dot, 1.0))
        q = (math.sin((1 - s) * theta) * q0 + math.sin(s * theta) * q1) / math.sin(theta)
    return _quaternion_to_rotation(q)


def _w2c_from_c2w(c2w: np.ndarray) -> np.ndarray:
    R, c = c2w[:3, :3], c2w[:3, 3]
    w2c = np.eye(4)
    w2c[:3, :3] = R.T
    w2c[:3, 3] = -R.T @ c
    return w2c


def _orthonormalize(w2c: np.ndarray) -> np.ndarray:
    """Remove round-off drift from a pose's rotation (nearest rotation by SVD)."""
    U, _, Vt = np.linalg.svd(w2c[:3, :3])
    R = U @ Vt
    out = w2c.copy()
    out[:3, :3] = R
    out[3] = [0.0, 0.0, 0.0, 1.0]
    return out


# --- presets -------------------------------------------------------------------------------------
def _check_params(preset: str, params: dict[str, Any]) -> dict[str, float]:
    allowed = PRESET_PARAMS[preset]
    unknown = sorted(set(params) - set(allowed))
    if unknown:
        raise TrajectoryError(
            f"preset {preset!r} takes parameters {sorted(allowed) or 'none'}; unknown: {unknown}"
        )
    out = dict(allowed)
    for k, v in params.items():
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
            raise TrajectoryError(f"parameter {k!r} must be a number, got {v!r}")
        if not math.isfinite(float(v)):
            raise TrajectoryError(f"parameter {k!r} must be finite, got {v!r}")
        out[k] = float(v)
    if "distance" in out and out["distance"] <= 0:
        raise TrajectoryError(f"distance must be positive metres, got {out['distance']}")
    return out


def _target_pose(target: Any, reference: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """(w2c, K) of the interpolation target."""
    if target is None:
        raise TrajectoryError("preset 'interpolate' needs a target camera (target=Trajectory or 4x4 w2c)")
    if isinstance(target, Trajectory):
        if (target.width, target.height) != (reference.width, reference.height):
            raise TrajectoryError(
                f"target camera is {target.width}x{target.height} but the reference is "
                f"{reference.width}x{reference.height}"
            )
        return target.w2c[0], target.K[0]
    try:
        probe = Trajectory(K=reference.K[0], w2c=np.asarray(target, dtype=np.float64),
                           width=reference.width, height=reference.height)
    except (CameraError, ValueError, TypeError) as exc:
        raise TrajectoryError(f"target must be a Trajectory or a 4x4 world-to-camera pose: {exc}") from None
    return probe.w2c[0], reference.K[0]


def make_trajectory(
    preset: str,
    reference: Trajectory,
    *,
    num_frames: int | None = None,
    target: Any = None,
    **params: float,
) -> Trajectory:
    """Build a target trajectory from a preset (see the module docstring for each preset's motion).

    Args:
        preset: one of :data:`PRESETS`.
        reference: the camera to start from (its first pose, first ``K`` and image size).
        num_frames: length of the result (default: ``reference.num_frames``).
        target: for ``interpolate`` only: the end camera.
        params: the preset's parameters (:data:`PRESET_PARAMS`), metres and degrees.
    Returns:
        A pinhole :class:`Trajectory` of ``num_frames`` frames, with the reference's timestamps when
        the lengths agree.
    Raises:
        TrajectoryError: unknown preset, unknown or non-finite parameter, bad target or length.
    """
    if preset not in PRESET_PARAMS:
        raise TrajectoryError(f"unknown trajectory preset {preset!r}; choose one of {', '.join(PRESETS)}")
    if not isinstance(reference, Trajectory):
        raise TrajectoryError("reference must be a vt4dcodec.cameras.Trajectory")
    if target is not None and preset != "interpolate":
        raise TrajectoryError(f"preset {preset!r} takes no target camera")
    p = _check_params(preset, params)
    T = reference.num_frames if num_frames is None else num_frames
    if isinstance(T, bool) or not isinstance(T, (int, np.integer)) or not 1 <= T <= MAX_TRAJECTORY_FRAMES:
        raise TrajectoryError(f"num_frames must be an integer in [1, {MAX_TRAJECTORY_FRAMES}], got {T!r}")
    T = int(T)

    w2c0, K0 = reference.w2c[0], reference.K[0]
    c2w0 = np.linalg.inv(w2c0)
    down, forward = c2w0[:3, 1], c2w0[:3, 2]
    center0 = c2w0[:3, 3]
    fractions = np.linspace(0.0, 1.0, T) if T > 1 else np.zeros(1)
    K = np.broadcast_to(K0, (T, 3, 3)).copy()
    poses = np.empty((T, 4, 4))
    if preset == "interpolate":
        w2c1, K1 = _target_pose(target, reference)
        R0, R1 = w2c0[:3, :3], w2c1[:3, :3]
        c1 = -R1.T @ w2c1[:3, 3]
    for i, s in enumerate(fractions):
        if preset == "static":
            pose = w2c0
        elif preset == "orbit":
            pivot = center0 + p["distance"] * forward
            # rotating about -down moves the camera to its right while it keeps facing the pivot
            Rot = _axis_angle(-down, math.radians(p["degrees"]) * s)
            c2w = np.eye(4)
            c2w[:3, :3] = Rot @ c2w0[:3, :3]
            c2w[:3, 3] = pivot + Rot @ (center0 - pivot)
            pose = _w2c_from_c2w(c2w)
        elif preset in ("dolly_in", "dolly_out"):
            sign = 1.0 if preset == "dolly_in" else -1.0
            c2w = c2w0.copy()
            c2w[:3, 3] = center0 + sign * p["metres"] * s * forward
            pose = _w2c_from_c2w(c2w)
        elif preset in ("pan", "tilt"):
            angle = math.radians(p["degrees"]) * s
            local = _axis_angle([0, 1, 0], angle) if preset == "pan" else _axis_angle([1, 0, 0], angle)
            c2w = c2w0.copy()
            c2w[:3, :3] = c2w0[:3, :3] @ local
            pose = _w2c_from_c2w(c2w)
        elif preset == "crane":
            look = center0 + p["distance"] * forward
            pose = look_at(center0 - p["metres"] * s * down, look, -down)
        else:  # interpolate
            R = slerp_rotation(R0, R1, float(s))
            c = (1 - s) * center0 + s * c1
            pose = np.eye(4)
            pose[:3, :3] = R
            pose[:3, 3] = -R @ c
            K[i] = (1 - s) * K0 + s * K1
        poses[i] = _orthonormalize(pose)
    timestamps = reference.timestamps if reference.timestamps is not None and T == reference.num_frames else None
    try:
        return Trajectory(K=K, w2c=poses, width=reference.width, height=reference.height, timestamps=timestamps)
    except CameraError as exc:  # e.g. a crane that passes through its own look-at point
        raise TrajectoryError(f"preset {preset!r} produced invalid cameras: {exc}") from None


def _parse_number(text: str, key: str) -> float | int:
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        raise TrajectoryError(f"parameter {key!r}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise TrajectoryError(f"parameter {key!r} must be finite, got {text!r}")
    return value


def parse_trajectory_spec(spec: str) -> tuple[str, dict[str, float | int]]:
    """Parse ``"preset[:key=value,key=value]"`` (e.g. ``"orbit:degrees=30,distance=2"``).

    Returns ``(preset, params)``; the preset (one of :data:`SPEC_PRESETS`) and parameter names are checked
    against :data:`PRESET_PARAMS` (``num_frames`` is also accepted and returned in ``params``).
    """
    if not isinstance(spec, str) or not spec.strip():
        raise TrajectoryError("empty trajectory spec; expected e.g. 'orbit:degrees=30,distance=2'")
    preset, _, rest = spec.strip().partition(":")
    preset = preset.strip()
    if preset in PRESET_PARAMS and preset not in SPEC_PRESETS:
        raise TrajectoryError(f"preset {preset!r} needs a target camera, which a spec cannot give: save the "
                              "trajectory as JSON (save_trajectory) and pass its path")
    if preset not in SPEC_PRESETS:
        raise TrajectoryError(f"unknown trajectory preset {preset!r}; choose one of {', '.join(SPEC_PRESETS)} "
                              "(their parameters: `vt4d decode --help`)")
    params: dict[str, float | int] = {}
    if rest.strip():
        for item in rest.split(","):
            key, eq, value = item.partition("=")
            key = key.strip()
            if not eq or not key:
                raise TrajectoryError(f"bad trajectory parameter {item!r}; expected key=value")
            if key in params:
                raise TrajectoryError(f"parameter {key!r} given twice")
            if key not in PRESET_PARAMS[preset] and key != "num_frames":
                raise TrajectoryError(
                    f"preset {preset!r} takes parameters {sorted(PRESET_PARAMS[preset]) or 'none'}; "
                    f"unknown: {key!r}"
                )
            params[key] = _parse_number(value.strip(), key)
    return preset, params


def _format_default(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else str(value)


def describe_spec_presets(indent: str = "  ") -> str:
    """The presets a spec string can name, each with its parameters and their defaults, one per line
    (the ``--help`` of ``vt4d decode`` and ``vt4d generate``)."""
    rows = []
    for name in SPEC_PRESETS:
        params = ",".join(f"{k}={_format_default(v)}" for k, v in PRESET_PARAMS[name].items())
        rows.append((f"{name}:{params}" if params else name, PRESET_SUMMARY[name]))
    width = max(len(spec) for spec, _ in rows) + 2
    return "\n".join(f"{indent}{spec:<{width}}{text}" for spec, text in rows)


def check_trajectory_spec(spec: str) -> None:
    """Check a command-line trajectory spec without a reference camera, so that a bad spec fails before
    any work: ``"source"``, an existing trajectory JSON file (read and checked), or a preset spec whose
    name, parameter names and values are valid.  Raises :class:`TrajectoryError`."""
    if spec == "source":
        return
    if spec.startswith("camera:"):
        check_camera_spec(spec)
        return
    if spec.endswith(".json") or os.path.isfile(spec):
        load_trajectory(spec)  # FileNotFoundError (exit 3) or TrajectoryError
        return
    preset, params = parse_trajectory_spec(spec)
    frames = params.pop("num_frames", None)
    if frames is not None and (not isinstance(frames, int) or not 1 <= frames <= MAX_TRAJECTORY_FRAMES):
        raise TrajectoryError(f"num_frames must be an integer in [1, {MAX_TRAJECTORY_FRAMES}], got {frames!r}")
    _check_params(preset, params)


# --- files -------------------------------------------------------------------------------------------
def trajectory_to_json(traj: Trajectory) -> dict[str, Any]:
    """The JSON document of a trajectory (see :func:`save_trajectory`)."""
    return {
        "format": TRAJECTORY_FORMAT,
        "version": TRAJECTORY_VERSION,
        "width": traj.width,
        "height": traj.height,
        "num_frames": traj.num_frames,
        "K": traj.K.tolist(),
        "w2c": traj.w2c.tolist(),
        "distortion": None if traj.distortion is None else traj.distortion.tolist(),
        "timestamps": None if traj.timestamps is None else traj.timestamps.tolist(),
    }


def _array(doc: dict, key: str, shape: tuple[int, ...], *, optional: bool = False) -> np.ndarray | None:
    value = doc.get(key)
    if value is None:
        if optional:
            return None
        raise TrajectoryError(f"trajectory: missing {key!r}")
    return parse_numbers(value, shape or None, f"trajectory: {key!r}", TrajectoryError)


def trajectory_from_json(doc: Any) -> Trajectory:
    """Inverse of :func:`trajectory_to_json`, with every field checked."""
    if not isinstance(doc, dict):
        raise TrajectoryError("trajectory file must hold a JSON object")
    if doc.get("format") != TRAJECTORY_FORMAT:
        raise TrajectoryError(f"not a trajectory file (format is {doc.get('format')!r}, expected {TRAJECTORY_FORMAT!r})")
    if doc.get("version") != TRAJECTORY_VERSION:
        raise TrajectoryError(f"unsupported trajectory version {doc.get('version')!r}")
    T = doc.get("num_frames")
    if isinstance(T, bool) or not isinstance(T, int) or not 1 <= T <= MAX_TRAJECTORY_FRAMES:
        raise TrajectoryError(f"trajectory: num_frames must be an integer in [1, {MAX_TRAJECTORY_FRAMES}]")
    K = _array(doc, "K", (T, 3, 3))
    w2c = _array(doc, "w2c", (T, 4, 4))
    dist = _array(doc, "distortion", (), optional=True)
    ts = _array(doc, "timestamps", (T,), optional=True)
    try:
        return Trajectory(K=K, w2c=w2c, width=doc.get("width"), height=doc.get("height"),
                          distortion=dist, timestamps=ts)
    except CameraError as exc:
        raise TrajectoryError(f"trajectory: {exc}") from None


def save_trajectory(traj: Trajectory, path: str | os.PathLike) -> None:
    """Write ``traj`` as JSON: ``{"format": "vt4d-trajectory", "version": 1, "width", "height",
    "num_frames", "K": (T,3,3), "w2c": (T,4,4) world-to-camera metres, "distortion": null | [n],
    "timestamps": null | [T] seconds}``.  Floats are written with full (round-trip) precision."""
    if not isinstance(traj, Trajectory):
        raise TrajectoryError("save_trajectory needs a Trajectory")
    Path(path).write_text(json.dumps(trajectory_to_json(traj), indent=1) + "\n", encoding="utf-8")


def load_trajectory(path: str | os.PathLike) -> Trajectory:
    """Read a trajectory written by :func:`save_trajectory` (TrajectoryError if malformed)."""
    size = os.path.getsize(path)
    if size > MAX_TRAJECTORY_FILE_BYTES:
        raise TrajectoryError(f"trajectory file is {size} bytes; the limit is {MAX_TRAJECTORY_FILE_BYTES}")
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TrajectoryError(f"trajectory file is not valid JSON: {exc}") from None
    return trajectory_from_json(doc)
