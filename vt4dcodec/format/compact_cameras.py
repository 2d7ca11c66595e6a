"""Compact cameras (FORMAT.md I.5.1, format 1.2, required flag bit 1): the cameras section with one
intrinsics record for a constant K and one pose for a static camera, float32 (or float64) values,
each record predicted from the one before and stored byte plane by byte plane, so the section's zstd
frame finds the runs that smooth trajectories leave.

Payload (little-endian)::

    u8  precision P      4 (float32) or 8 (float64)
    u8  layout flags     bit 0: one intrinsics record for every frame; bit 1: one pose for every frame
    intrinsics block     nK records of (fx, s, cx, fy, cy), predicted + byte planes (below)
    pose block           nP records of w2c rows 0..2 (12 values, row-major), predicted + byte planes
    distortion           distortion_terms float64 (as in 1.0)
    timestamps           T float64 if has_timestamps (as in 1.0)

A block of n records of m values: let u[r, j] be the P-byte unsigned integer whose bytes are value j of
record r.  The writer stores e[0, j] = u[0, j] and e[r, j] = (u[r, j] - u[r-1, j]) mod 2^(8P); then
byte k of every e (row-major order) for k = 0, then k = 1, ... (byte planes).  The reader inverts both.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..cameras import Trajectory
from ..errors import CameraError, FormatError, MalformedSectionError
from .header import CameraLayout
from .layout import BytesLike

__all__ = ["CAMERA_MODES", "COMPACT_PRECISIONS", "REPROJECTION_TOLERANCE_PX", "pack_compact_cameras",
           "unpack_compact_cameras", "compact_camera_bytes", "reprojection_change"]

CAMERA_MODES = ("compact", "exact", "legacy")  # what save() offers: see writer.dumps
COMPACT_PRECISIONS = (4, 8)
CONSTANT_INTRINSICS, STATIC_POSE = 1 << 0, 1 << 1
KNOWN_LAYOUT_FLAGS = CONSTANT_INTRINSICS | STATIC_POSE
INTRINSIC_VALUES, POSE_VALUES = 5, 12
REPROJECTION_TOLERANCE_PX = 0.01  # float32 is used only when no probe point moves more than this
PROBE_DEPTHS_M = (0.1, 1.0, 10.0, 100.0)  # the reference writer's probe points (FORMAT.md I.5.1)
PROBE_GRID = 5

_UINT: dict[int, np.dtype[Any]] = {4: np.dtype("<u4"), 8: np.dtype("<u8")}
_FLOAT: dict[int, np.dtype[Any]] = {4: np.dtype("<f4"), 8: np.dtype("<f8")}


def _intrinsic_records(K: np.ndarray) -> np.ndarray:
    return np.stack([K[:, 0, 0], K[:, 0, 1], K[:, 0, 2], K[:, 1, 1], K[:, 1, 2]], axis=1)


def _pack_block(records: np.ndarray, precision: int) -> bytes:
    values = np.ascontiguousarray(records, dtype=_FLOAT[precision])
    u = values.view(_UINT[precision])
    e = u.copy()
    e[1:] = u[1:] - u[:-1]  # unsigned arithmetic wraps mod 2^(8P)
    planes = e.reshape(-1).view(np.uint8).reshape(-1, precision).T
    return np.ascontiguousarray(planes).tobytes()


def _unpack_block(raw: bytes, records: int, values: int, precision: int) -> np.ndarray:
    planes = np.frombuffer(raw, dtype=np.uint8).reshape(precision, records * values)
    e = np.ascontiguousarray(planes.T).reshape(-1).view(_UINT[precision]).reshape(records, values)
    u: np.ndarray = np.cumsum(e, axis=0, dtype=_UINT[precision])  # wraps mod 2^(8P), inverting the difference
    out: np.ndarray = u.view(_FLOAT[precision]).astype(np.float64)
    return out


def _flags(traj: Trajectory) -> int:
    flags = 0
    if np.array_equal(traj.K, np.broadcast_to(traj.K[:1], traj.K.shape)):
        flags |= CONSTANT_INTRINSICS
    if np.array_equal(traj.w2c, np.broadcast_to(traj.w2c[:1], traj.w2c.shape)):
        flags |= STATIC_POSE
    return flags


def compact_camera_bytes(T: int, precision: int, flags: int, distortion_terms: int, has_timestamps: bool) -> int:
    """The raw length of a compact cameras section."""
    n_k = 1 if flags & CONSTANT_INTRINSICS else T
    n_p = 1 if flags & STATIC_POSE else T
    return 2 + precision * (INTRINSIC_VALUES * n_k + POSE_VALUES * n_p) + 8 * (distortion_terms
                                                                           + (T if has_timestamps else 0))


def _encode(traj: Trajectory, precision: int) -> bytes:
    flags = _flags(traj)
    K = traj.K[:1] if flags & CONSTANT_INTRINSICS else traj.K
    w2c = traj.w2c[:1] if flags & STATIC_POSE else traj.w2c
    parts = [bytes([precision, flags]), _pack_block(_intrinsic_records(K), precision),
             _pack_block(w2c[:, :3, :].reshape(len(w2c), POSE_VALUES), precision)]
    for extra in (traj.distortion, traj.timestamps):
        if extra is not None:
            parts.append(np.ascontiguousarray(extra, dtype="<f8").tobytes())
    return b"".join(parts)


def reprojection_change(a: Trajectory, b: Trajectory) -> float:
    """The largest pixel distance between where camera ``a`` and camera ``b`` (same frame) put the same
    world point, over the reference writer's probe points: a 5 x 5 grid over each frame's image
    (corner pixels' outer edges included) lifted through ``a`` to depths 0.1, 1, 10 and 100 m.
    Distortion is ignored (the compact encoding stores it unchanged)."""
    W, H = a.width, a.height
    u, v = np.meshgrid(np.linspace(-0.5, W - 0.5, PROBE_GRID), np.linspace(-0.5, H - 0.5, PROBE_GRID))
    pix = np.stack([u.ravel(), v.ravel(), np.ones(u.size)])                  # (3, P)
    rays = np.linalg.solve(a.K, np.broadcast_to(pix, (a.num_frames, *pix.shape)))  # (T, 3, P), z = 1
    worst = 0.0
    for z in PROBE_DEPTHS_M:
        cam_a = rays * z
        world = np.einsum("tji,tjp->tip", a.w2c[:, :3, :3], cam_a - a.w2c[:, :3, 3:])  # R^T (x - t)
        cam_b = np.einsum("tij,tjp->tip", b.w2c[:, :3, :3], world) + b.w2c[:, :3, 3:]
        proj = np.einsum("tij,tjp->tip", b.K, cam_b)
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = proj[:, :2] / proj[:, 2:]
        d = np.abs(uv - pix[None, :2])
        worst = max(worst, float(np.nanmax(d)) if np.isfinite(d).all() else float("inf"))
    return worst


def pack_compact_cameras(traj: Trajectory, mode: str = "compact") -> bytes:
    """The compact cameras payload of ``traj``.  ``mode`` "exact": float64 (the trajectory reads back
    bit for bit); "compact": float32 when the decoded trajectory is valid and moves no probe point more
    than 0.01 px (:func:`reprojection_change`), else float64."""
    if mode not in ("compact", "exact"):
        raise FormatError(f"compact camera mode must be 'compact' or 'exact', got {mode!r}")
    if mode == "compact":
        raw = _encode(traj, 4)
        try:
            back = _decode(raw, traj.num_frames, traj.width, traj.height,
                           0 if traj.distortion is None else len(traj.distortion), traj.timestamps is not None)
        except MalformedSectionError:
            back = None  # float32 breaks a convention (a value beyond its range, a rotation at the tolerance)
        if back is not None and reprojection_change(traj, back) <= REPROJECTION_TOLERANCE_PX:
            return raw
    return _encode(traj, 8)


def _decode(raw: BytesLike, T: int, width: int, height: int, distortion_terms: int, has_timestamps: bool) -> Trajectory:
    raw = bytes(raw)
    if len(raw) < 2:
        raise MalformedSectionError(f"compact cameras section is {len(raw)} bytes; it needs at least 2")
    precision, flags = raw[0], raw[1]
    if precision not in COMPACT_PRECISIONS:
        raise MalformedSectionError(f"compact cameras: precision {precision} is not 4 (float32) or 8 (float64)")
    if flags & ~KNOWN_LAYOUT_FLAGS:
        raise MalformedSectionError(f"compact cameras: layout flags 0x{flags:02x} set undefined bits")
    need = compact_camera_bytes(T, precision, flags, distortion_terms, has_timestamps)
    if len(raw) != need:
        raise MalformedSectionError(f"compact cameras section is {len(raw)} bytes; its header and layout "
                                    f"byte need {need}")
    n_k = 1 if flags & CONSTANT_INTRINSICS else T
    n_p = 1 if flags & STATIC_POSE else T
    pos = 2
    kv = _unpack_block(raw[pos:pos + precision * INTRINSIC_VALUES * n_k], n_k, INTRINSIC_VALUES, precision)
    pos += precision * INTRINSIC_VALUES * n_k
    pv = _unpack_block(raw[pos:pos + precision * POSE_VALUES * n_p], n_p, POSE_VALUES, precision)
    pos += precision * POSE_VALUES * n_p
    tail = np.frombuffer(raw[pos:], dtype="<f8").astype(np.float64)
    K = np.zeros((n_k, 3, 3))
    K[:, 0, 0], K[:, 0, 1], K[:, 0, 2], K[:, 1, 1], K[:, 1, 2] = kv.T
    K[:, 2, 2] = 1.0
    w2c = np.zeros((n_p, 4, 4))
    w2c[:, :3, :] = pv.reshape(n_p, 3, 4)
    w2c[:, 3, 3] = 1.0
    try:
        return Trajectory(K=np.repeat(K, T // n_k, axis=0), w2c=np.repeat(w2c, T // n_p, axis=0), width=width,
                          height=height, distortion=tail[:distortion_terms] if distortion_terms else None,
                          timestamps=tail[distortion_terms:] if has_timestamps else None)
    except CameraError as exc:
        raise MalformedSectionError(f"cameras section breaks the camera conventions: {exc}") from None


def unpack_compact_cameras(raw: BytesLike, layout: CameraLayout) -> Trajectory:
    """Rebuild the trajectory from a compact cameras payload; any problem is a MalformedSectionError."""
    return _decode(raw, layout.num_frames, layout.width, layout.height, layout.distortion_terms,
                   layout.has_timestamps)
