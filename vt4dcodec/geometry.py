"""Camera geometry on torch tensors: pixel grids, (un)projection, relative poses, the flow camera
motion induces (the paper's F_pose), Plücker ray maps and lens distortion.

Conventions are those of :mod:`vt4dcodec.cameras` (OpenCV pinhole): x right, y down, z forward;
pixel (u, v) = (column, row) has its centre at integer coordinates; ``K`` is in pixels; poses are
world-to-camera 4x4 matrices in metres (``x_cam = R @ x_world + t``).

Every function takes float32 or float64 tensors (numpy arrays are converted) and broadcasts leading
batch dimensions written ``...``.  Nothing here is learned; all of it is differentiable.
"""

from __future__ import annotations

import numpy as np
import torch
from kornia.geometry.calibration import distort_points as _kornia_distort_points
from kornia.geometry.calibration import undistort_points as _kornia_undistort_points

from .errors import CameraError

__all__ = [
    "scale_intrinsics",
    "crop_intrinsics",
    "pixel_grid",
    "unproject",
    "project",
    "invert_pose",
    "relative_pose",
    "transform_points",
    "camera_flow",
    "plucker_rays",
    "distort_points",
    "undistort_points",
    "opencv_to_opengl_c2w",
    "opengl_to_opencv_c2w",
    "pixels_to_grid",
    "grid_to_pixels",
    "backward_warp",
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


def crop_intrinsics(K, x0: float, y0: float) -> torch.Tensor:
    """Intrinsics after cropping the image so that pixel ``(x0, y0)`` becomes ``(0, 0)``."""
    K = _tensor(K)
    _check_square(K, 3, "K")
    out = K.clone()
    out[..., 0, 2] = K[..., 0, 2] - x0
    out[..., 1, 2] = K[..., 1, 2] - y0
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
    return torch.cat([d, m], dim=-1).movedim(-1, -3)


def _check_distortion(dist: torch.Tensor) -> None:
    if dist.shape[-1] not in (4, 5, 8, 12, 14):
        raise CameraError(f"distortion must have 4, 5, 8, 12 or 14 OpenCV terms, got {dist.shape[-1]}")


def distort_points(uv, K, dist) -> torch.Tensor:
    """Pixels of an ideal pinhole camera ``K`` -> pixels of the real (distorted) lens.

    Args:
        uv: (..., N, 2) undistorted pixel coordinates.
        K: (..., 3, 3) intrinsics (the same for both images, as in ``cv2.projectPoints``).
        dist: (..., n) OpenCV distortion terms ``k1 k2 p1 p2 [k3 ...]``.
    Returns:
        (..., N, 2) distorted pixel coordinates.
    """
    uv = _tensor(uv)
    K, dist = _tensor(K, like=uv), _tensor(dist, like=uv)
    _check_distortion(dist)
    return _kornia_distort_points(uv, K, dist)


def undistort_points(uv, K, dist, *, num_iters: int = 40) -> torch.Tensor:
    """Pixels of the real (distorted) lens -> pixels of the ideal pinhole camera ``K``.

    The inverse of :func:`distort_points` by fixed-point iteration (as ``cv2.undistortPoints`` with
    ``P=K``) with ``num_iters`` steps; for k1 down to -0.35 it recovers points within 31 degrees of
    the axis to < 1e-3 px (tested).  Beyond the radius where the lens model stops being monotone
    (strong barrel distortion, image corners) no inverse exists and the result is meaningless.
    """
    uv = _tensor(uv)
    K, dist = _tensor(K, like=uv), _tensor(dist, like=uv)
    _check_distortion(dist)
    return _kornia_undistort_points(uv, K, dist, num_iters=num_iters)


# --- convention conversions ----------------------------------------------------------------------
_FLIP_YZ = (1.0, -1.0, -1.0)


def opencv_to_opengl_c2w(c2w) -> torch.Tensor:
    """Camera-to-world (..., 4, 4) from OpenCV axes (x right, y down, z forward) to OpenGL/Blender
    axes (x right, y up, z backward): the camera's y and z axes flip; the centre is unchanged."""
    c2w = _tensor(c2w)
    _check_square(c2w, 4, "c2w")
    out = c2w.clone()
    out[..., :3, 1:3] = -c2w[..., :3, 1:3]
    return out


def opengl_to_opencv_c2w(c2w) -> torch.Tensor:
    """Inverse of :func:`opencv_to_opengl_c2w` (the same flip; it is its own inverse)."""
    return opencv_to_opengl_c2w(c2w)


def pixels_to_grid(uv, height: int, width: int) -> torch.Tensor:
    """Pixel coordinates (..., 2) -> ``torch.nn.functional.grid_sample`` coordinates in [-1, 1]
    (``align_corners=False``: -1 and 1 are the outer edges of the border pixels, so pixel centre
    u maps to ``(2u + 1) / W - 1``)."""
    uv = _tensor(uv)
    scale = uv.new_tensor([2.0 / width, 2.0 / height])
    return (uv + 0.5) * scale - 1.0


def grid_to_pixels(grid, height: int, width: int) -> torch.Tensor:
    """Inverse of :func:`pixels_to_grid`."""
    grid = _tensor(grid)
    scale = grid.new_tensor([width / 2.0, height / 2.0])
    return (grid + 1.0) * scale - 0.5


def backward_warp(image, flow) -> tuple[torch.Tensor, torch.Tensor]:
    """Sample ``image`` at ``p + flow(p)`` for every pixel p (bilinear).

    With ``image`` = frame t+1 and ``flow`` = the t -> t+1 flow (e.g. :func:`camera_flow`), the result
    predicts frame t wherever the scene point is visible in both frames.

    Args:
        image: (..., C, H', W') float image to sample.
        flow: (..., H, W, 2) displacements in pixels of ``image``.
    Returns:
        ``(warped, inside)``: (..., C, H, W) samples and (..., H, W) bool, true where ``p + flow``
        falls inside the image (outside samples are zero).
    """
    image = _tensor(image)
    flow = _tensor(flow, like=image)
    if image.ndim < 3 or flow.ndim < 3 or flow.shape[-1] != 2:
        raise CameraError(f"backward_warp needs image (..., C, H, W) and flow (..., H, W, 2), got "
                          f"{tuple(image.shape)} and {tuple(flow.shape)}")
    H, W = flow.shape[-3:-1]
    Hi, Wi = image.shape[-2:]
    target = pixel_grid(H, W, device=flow.device, dtype=flow.dtype) + flow
    batch = torch.broadcast_shapes(image.shape[:-3], flow.shape[:-3])
    img = image.expand(*batch, *image.shape[-3:]).reshape(-1, *image.shape[-3:])
    grid = pixels_to_grid(target, Hi, Wi).expand(*batch, H, W, 2).reshape(-1, H, W, 2)
    warped = torch.nn.functional.grid_sample(img, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    inside = ((target[..., 0] >= 0) & (target[..., 0] <= Wi - 1) & (target[..., 1] >= 0) & (target[..., 1] <= Hi - 1))
    return warped.reshape(*batch, image.shape[-3], H, W), inside.expand(*batch, H, W)
