"""Camera geometry on torch tensors: pixel grids, (un)projection, relative poses, the flow camera
motion induces (the paper's F_pose) and Plücker ray maps.

Conventions are those of :mod:`vt4dcodec.cameras` (OpenCV pinhole): x right, y down, z forward;
pixel (u, v) = (column, row) has its centre at integer coordinates; ``K`` is in pixels; poses are
world-to-camera 4x4 matrices in metres (``x_cam = R @ x_world + t``).

Every function takes float32 or float64 tensors (numpy arrays are converted) and broadcasts leading
batch dimensions written ``...``.  Nothing here is learned; all of it is differentiable.
"""

from __future__ import annotations

import numpy as np
import torch

from vt4dcodec.errors import CameraError

__all__ = [
    "scale_intrinsics",
    "pixel_grid",
    "unproject",
    "project",
    "invert_pose",
    "relative_pose",
    "transform_points",
    "camera_flow",
    "plucker_rays",
]

# Points closer to the image plane than this (metres along z) count as "not in front" of a camera.
MIN_DEPTH = 1e-6


def _tensor(x, *, like: torch.Tensor | None = None) -> torch.Tensor:
    """``x`` as a floating tensor (float64 for numpy input unless ``like`` gives a dtype/device)."""
    if isinstance(x, torch.Tensor):
        t = x
    else:
        t = torch.as_tensor(np.asarray(x))
    if like is not None:
        return t.to(device=like.device, dtype=like.dtype)
    if not t.is_floating_point():
        t = t.to(torch.float64)
    return t


def _check_square(m: torch.Tensor, n: int, what: str) -> None:
    if m.ndim < 2 or tuple(m.shape[-2:]) != (n, n):
        raise CameraError(f"{what} must have shape (..., {n}, {n}), got {tuple(m.shape)}")


def scale_intrinsics(K, sx: float, sy: float) -> torch.Tensor:
    """Intrinsics after resizing the image by ``(sx, sy)`` (new_width / width, new_height / height).

    Pixel centres map as ``u' = (u + 0.5) * sx - 0.5`` (the mapping of ``cv2.resize``), so
    ``fx' = fx * sx``, ``s' = s * sx``, ``cx' = (cx + 0.5) * sx - 0.5`` and likewise for y.

    Args:
        K: (..., 3, 3) intrinsics in pixels.
        sx, sy: positive scale factors.
    Returns:
        (..., 3, 3) intrinsics of the resized image, same dtype as ``K``.
    """
    K = _tensor(K)
    _check_square(K, 3, "K")
    if not (sx > 0 and sy > 0):
        raise CameraError(f"scale factors must be positive, got sx={sx}, sy={sy}")
    out = K.clone()
    out[..., 0, :] = K[..., 0, :] * sx
    out[..., 1, :] = K[..., 1, :] * sy
    out[..., 0, 2] = (K[..., 0, 2] + 0.5) * sx - 0.5
    out[..., 1, 2] = (K[..., 1, 2] + 0.5) * sy - 0.5
    return out


def pixel_grid(height: int, width: int, device=None, dtype=None) -> torch.Tensor:
    """(H, W, 2) pixel-centre coordinates: ``grid[v, u] = (u, v)`` (u = column, v = row)."""
    if height <= 0 or width <= 0:
        raise CameraError(f"image size must be positive, got {width}x{height}")
    dtype = dtype or torch.get_default_dtype()
    v, u = torch.meshgrid(
        torch.arange(height, device=device, dtype=dtype),
        torch.arange(width, device=device, dtype=dtype),
        indexing="ij",
    )
    return torch.stack([u, v], dim=-1)


def _pixels_to_normalized(uv: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """Normalized image coordinates (x/z, y/z) of pixels ``uv`` (..., 2); ``K`` broadcasts as (..., 3, 3)."""
    fx, fy, s = K[..., 0, 0], K[..., 1, 1], K[..., 0, 1]
    cx, cy = K[..., 0, 2], K[..., 1, 2]
    y = (uv[..., 1] - cy) / fy
    x = (uv[..., 0] - cx - s * y) / fx
    return torch.stack([x, y], dim=-1)


def unproject(depth, K) -> torch.Tensor:
    """Back-project a depth map to camera-space points.

    Args:
        depth: (..., H, W) z-depth in metres (distance along the optical axis, not along the ray).
        K: (..., 3, 3) intrinsics in pixels; its batch dims broadcast with depth's.
    Returns:
        (..., H, W, 3) points in the camera frame (metres); ``points[..., v, u, 2] == depth[..., v, u]``.
    """
    depth = _tensor(depth)
    K = _tensor(K, like=depth)
    _check_square(K, 3, "K")
    if depth.ndim < 2:
        raise CameraError(f"depth must have shape (..., H, W), got {tuple(depth.shape)}")
    H, W = depth.shape[-2:]
    grid = pixel_grid(H, W, device=depth.device, dtype=depth.dtype)
    xy = _pixels_to_normalized(grid, K[..., None, None, :, :])  # (..., H, W, 2)
    xy = torch.broadcast_to(xy, (*torch.broadcast_shapes(xy.shape[:-1], depth.shape), 2))
    return torch.cat([xy * depth[..., None], depth[..., None].expand(xy.shape[:-1] + (1,))], dim=-1)


def _expand_to_points(K: torch.Tensor, points: torch.Tensor, what: str = "K") -> torch.Tensor:
    """Insert singleton dims into a (..., r, c) matrix so it broadcasts over the per-point dims.

    The matrix's batch dims match the points' leading dims; the remaining dims of ``points``
    (before the last coordinate axis) are per-point: (..., N) or (..., H, W).
    """
    per_point = points.ndim - 1 - (K.ndim - 2)
    if per_point < 0:
        raise CameraError(f"{what} has more batch dims {tuple(K.shape[:-2])} than points {tuple(points.shape)}")
    return K.reshape(K.shape[:-2] + (1,) * per_point + K.shape[-2:])


def project(points, K) -> tuple[torch.Tensor, torch.Tensor]:
    """Project camera-space points to pixels.

    Args:
        points: (..., N, 3) or (..., H, W, 3) camera-frame points in metres.
        K: (..., 3, 3) intrinsics whose batch dims are the points' leading ``...`` dims.
    Returns:
        ``(uv, z)``: (..., N, 2) or (..., H, W, 2) pixel coordinates and (..., N) / (..., H, W) depth.
        Where ``|z| < MIN_DEPTH`` the division uses ``MIN_DEPTH`` (keeps values finite); check ``z``.
    """
    points = _tensor(points)
    K = _tensor(K, like=points)
    _check_square(K, 3, "K")
    if points.shape[-1] != 3:
        raise CameraError(f"points must have shape (..., 3), got {tuple(points.shape)}")
    Kp = _expand_to_points(K, points)
    z = points[..., 2]
    z_safe = torch.where(z.abs() < MIN_DEPTH, torch.full_like(z, MIN_DEPTH), z)
    x, y = points[..., 0] / z_safe, points[..., 1] / z_safe
    u = Kp[..., 0, 0] * x + Kp[..., 0, 1] * y + Kp[..., 0, 2]
    v = Kp[..., 1, 1] * y + Kp[..., 1, 2]
    return torch.stack([u, v], dim=-1), z


def invert_pose(T) -> torch.Tensor:
    """Inverse of rigid 4x4 transforms (..., 4, 4): ``[R t] -> [R^T, -R^T t]``."""
    T = _tensor(T)
    _check_square(T, 4, "pose")
    R, t = T[..., :3, :3], T[..., :3, 3:]
    Rt = R.transpose(-1, -2)
    out = torch.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3:] = -Rt @ t
    out[..., 3, 3] = 1
    return out


def relative_pose(w2c_a, w2c_b) -> torch.Tensor:
    """``T_ab = w2c_b @ inv(w2c_a)`` (..., 4, 4): maps camera-a coordinates to camera-b coordinates."""
    w2c_a = _tensor(w2c_a)
    w2c_b = _tensor(w2c_b, like=w2c_a)
    _check_square(w2c_b, 4, "w2c_b")
    return w2c_b @ invert_pose(w2c_a)


def transform_points(T, points) -> torch.Tensor:
    """Apply rigid transforms ``T`` (..., 4, 4) to points (..., N, 3) or (..., H, W, 3)."""
    points = _tensor(points)
    T = _tensor(T, like=points)
    _check_square(T, 4, "T")
    Tp = _expand_to_points(T, points, "T")
    return (Tp[..., :3, :3] @ points[..., None])[..., 0] + Tp[..., :3, 3]


def camera_flow(depth_t, K_t, K_t1, w2c_t, w2c_t1) -> tuple[torch.Tensor, torch.Tensor]:
    """Optical flow induced by camera motion alone (the paper's F_pose, Sec. 3.2).

    ``F_pose(p) = proj_{t+1}(T_{t->t+1} unproj_t(p, D_t(p))) - p`` for every pixel p of frame t,
    i.e. where a static scene point seen at p in frame t appears in frame t+1.

    Args:
        depth_t: (..., H, W) z-depth of frame t in metres (<= 0 or non-finite = unknown).
        K_t, K_t1: (..., 3, 3) intrinsics of frames t and t+1.
        w2c_t, w2c_t1: (..., 4, 4) world-to-camera poses of frames t and t+1.
    Returns:
        ``(flow, valid)``: (..., H, W, 2) pixel displacement (du, dv) and (..., H, W) bool, true where
        the depth is known and the point lies in front of camera t+1.  Points that leave the image are
        still valid (their flow points outside); zero where invalid.
    """
    depth_t = _tensor(depth_t)
    known = torch.isfinite(depth_t) & (depth_t > 0)
    depth = torch.where(known, depth_t, torch.ones_like(depth_t))
    points_t = unproject(depth, K_t)
    T = relative_pose(_tensor(w2c_t, like=depth), _tensor(w2c_t1, like=depth))
    points_t1 = transform_points(T, points_t)
    uv, z = project(points_t1, K_t1)
    grid = pixel_grid(depth.shape[-2], depth.shape[-1], device=depth.device, dtype=depth.dtype)
    valid = known & (z > MIN_DEPTH)
    flow = torch.where(valid[..., None], uv - grid, torch.zeros_like(uv))
    return flow, valid


def plucker_rays(K, w2c, height: int, width: int) -> torch.Tensor:
    """Plücker ray map of a camera: per pixel ``(d, o x d)`` in world coordinates.

    Args:
        K: (..., 3, 3) intrinsics in pixels for an image of ``height`` x ``width``.
        w2c: (..., 4, 4) world-to-camera poses (metres).
    Returns:
        (..., 6, H, W): channels 0-2 the unit direction d of the ray through each pixel centre,
        channels 3-5 the moment o x d with o the camera centre in world coordinates.
    """
    K = _tensor(K)
    w2c = _tensor(w2c, like=K)
    _check_square(K, 3, "K")
    _check_square(w2c, 4, "w2c")
    grid = pixel_grid(height, width, device=K.device, dtype=K.dtype)
    xy = _pixels_to_normalized(grid, K[..., None, None, :, :])  # (..., H, W, 2)
    d_cam = torch.cat([xy, torch.ones_like(xy[..., :1])], dim=-1)
    c2w = invert_pose(w2c)
    R = c2w[..., None, None, :3, :3]
    d = (R @ d_cam[..., None])[..., 0]
    d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True)
    o = c2w[..., None, None, :3, 3].expand_as(d)
    m = torch.linalg.cross(o, d, dim=-1)
    rays = torch.cat([d, m], dim=-1)
    n = rays.ndim  # movedim(-1, -3), spelled with non-negative axes (the ONNX exporter mis-writes negative ones)
    return rays.permute(*range(n - 3), n - 1, n - 3, n - 2)
