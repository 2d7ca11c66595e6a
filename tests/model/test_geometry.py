"""Camera geometry: conventions, round trips and the camera-induced flow (vt4dcodec.model.geometry)."""

import math

import cv2
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from vt4dcodec.errors import CameraError
from vt4dcodec.model.geometry import (
    camera_flow, invert_pose, pixel_grid, plucker_rays, project, relative_pose, scale_intrinsics, transform_points,
    unproject,
)

finite = dict(allow_nan=False, allow_infinity=False)


def make_K(fx, fy, cx, cy, skew=0.0, dtype=torch.float64):
    return torch.tensor([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=dtype)


def random_pose(rng, *, max_angle=math.pi, max_t=2.0):
    """A random rigid world-to-camera 4x4 (float64 numpy)."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    R, _ = cv2.Rodrigues(axis * rng.uniform(-max_angle, max_angle))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = rng.uniform(-max_t, max_t, size=3)
    return T


intrinsics = st.tuples(
    st.floats(20, 2000, **finite), st.floats(20, 2000, **finite),
    st.floats(-50, 500, **finite), st.floats(-50, 500, **finite), st.floats(-5, 5, **finite),
)


def test_pixel_grid_is_u_column_v_row():
    g = pixel_grid(3, 4)
    assert g.shape == (3, 4, 2)
    assert g[2, 1].tolist() == [1.0, 2.0]  # row 2, column 1 -> (u=1, v=2)


@given(k=intrinsics, seed=st.integers(0, 2**31 - 1), batch=st.integers(1, 3))
def test_project_unproject_round_trip(k, seed, batch):
    rng = np.random.default_rng(seed)
    K = make_K(*k).expand(batch, 3, 3)
    depth = torch.from_numpy(rng.uniform(0.05, 50.0, size=(batch, 5, 7)))
    pts = unproject(depth, K)
    assert pts.shape == (batch, 5, 7, 3)
    uv, z = project(pts, K)
    torch.testing.assert_close(uv, pixel_grid(5, 7, dtype=torch.float64).expand(batch, 5, 7, 2), atol=1e-8, rtol=0)
    torch.testing.assert_close(z, depth)
    # (..., N, 3) point lists project the same way
    uv_n, _ = project(pts.reshape(batch, -1, 3), K)
    torch.testing.assert_close(uv_n, uv.reshape(batch, -1, 2))


def test_project_matches_opencv():
    """(cv2.projectPoints ignores skew, so compare a skew-free camera.)"""
    rng = np.random.default_rng(0)
    K = np.array([[500.0, 0.0, 320.0], [0.0, 480.0, 240.0], [0.0, 0.0, 1.0]])
    pts = rng.uniform([-1, -1, 1], [1, 1, 5], size=(50, 3))
    cv_uv = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, None)[0].reshape(-1, 2)
    uv, _ = project(torch.from_numpy(pts), torch.from_numpy(K))
    np.testing.assert_allclose(uv.numpy(), cv_uv, atol=1e-9)


def test_float32_and_numpy_inputs():
    K = make_K(60, 60, 31.5, 31.5, dtype=torch.float32)
    depth = torch.full((64, 64), 2.0)
    pts = unproject(depth, K)
    assert pts.dtype == torch.float32
    uv, _ = project(pts, K)
    assert (uv - pixel_grid(64, 64)).abs().max() < 1e-4
    pts_np = unproject(np.full((4, 4), 1.0), K.numpy().astype(np.float64))
    assert pts_np.dtype == torch.float64


@given(seed=st.integers(0, 2**31 - 1))
def test_relative_pose_composition_and_inverse(seed):
    rng = np.random.default_rng(seed)
    a, b, c = (torch.from_numpy(random_pose(rng)) for _ in range(3))
    T_ab, T_bc, T_ac = relative_pose(a, b), relative_pose(b, c), relative_pose(a, c)
    torch.testing.assert_close(T_bc @ T_ab, T_ac, atol=1e-10, rtol=0)
    torch.testing.assert_close(relative_pose(b, a), torch.linalg.inv(T_ab), atol=1e-10, rtol=0)
    torch.testing.assert_close(relative_pose(a, a), torch.eye(4, dtype=torch.float64), atol=1e-12, rtol=0)
    torch.testing.assert_close(invert_pose(a), torch.linalg.inv(a), atol=1e-10, rtol=0)
    # T_ab maps camera-a coordinates of a world point to its camera-b coordinates
    X = torch.from_numpy(rng.normal(size=(6, 3)))
    xa, xb = transform_points(a, X), transform_points(b, X)
    torch.testing.assert_close(transform_points(T_ab, xa), xb, atol=1e-10, rtol=0)


@given(sx=st.floats(0.25, 4.0, **finite), sy=st.floats(0.25, 4.0, **finite), k=intrinsics,
       seed=st.integers(0, 2**31 - 1))
@settings(max_examples=30)
def test_scale_intrinsics_matches_cv2_resize(sx, sy, k, seed):
    """Project a point with K and with scale_intrinsics(K): sampling a resized coordinate ramp (cv2,
    bilinear) at the new pixel must give back the original pixel coordinate."""
    W, H = 40, 30
    W2, H2 = max(2, round(W * sx)), max(2, round(H * sy))
    sx, sy = W2 / W, H2 / H
    ramp_u = np.tile(np.arange(W, dtype=np.float32), (H, 1))
    ramp_v = np.tile(np.arange(H, dtype=np.float32)[:, None], (1, W))
    big_u = cv2.resize(ramp_u, (W2, H2), interpolation=cv2.INTER_LINEAR)
    big_v = cv2.resize(ramp_v, (W2, H2), interpolation=cv2.INTER_LINEAR)
    K = make_K(*k)
    K2 = scale_intrinsics(K, sx, sy)
    rng = np.random.default_rng(seed)
    # a world point that lands on an interior pixel centre of the resized image
    u2, v2 = int(rng.integers(2, W2 - 2)), int(rng.integers(2, H2 - 2))
    u_src, v_src = (u2 + 0.5) / sx - 0.5, (v2 + 0.5) / sy - 0.5
    if not (0 <= u_src <= W - 1 and 0 <= v_src <= H - 1):
        return
    p = torch.linalg.solve(K, torch.tensor([u_src, v_src, 1.0], dtype=torch.float64)) * 1.7  # any depth
    uv2, _ = project(p[None], K2)
    assert abs(uv2[0, 0].item() - u2) < 1e-6 and abs(uv2[0, 1].item() - v2) < 1e-6
    assert abs(big_u[v2, u2] - u_src) < 1e-3 and abs(big_v[v2, u2] - v_src) < 1e-3


def test_camera_flow_identity_and_translation():
    K = make_K(100, 90, 31.5, 23.5)
    depth = torch.full((48, 64), 4.0, dtype=torch.float64)
    eye = torch.eye(4, dtype=torch.float64)
    flow, valid = camera_flow(depth, K, K, eye, eye)
    assert valid.all() and flow.abs().max() < 1e-12
    # camera moves b metres to its right: static points move left by fx * b / z
    b = 0.2
    moved = eye.clone()
    moved[0, 3] = -b
    flow, valid = camera_flow(depth, K, K, eye, moved)
    torch.testing.assert_close(flow[..., 0], torch.full_like(depth, -100 * b / 4.0))
    assert flow[..., 1].abs().max() < 1e-12


@given(seed=st.integers(0, 2**31 - 1))
@settings(max_examples=30)
def test_camera_flow_matches_world_point_reprojection(seed):
    """F_pose equals the pixel of the same world point in frame t+1 (independent numpy path)."""
    rng = np.random.default_rng(seed)
    H, W = 6, 8
    K0 = np.array([[40.0, 0, 3.5], [0, 42.0, 2.5], [0, 0, 1]])
    K1 = np.array([[55.0, 0.5, 4.0], [0, 50.0, 3.0], [0, 0, 1]])
    w0, w1 = random_pose(rng, max_angle=0.3, max_t=0.3), random_pose(rng, max_angle=0.3, max_t=0.3)
    depth = rng.uniform(1.0, 5.0, size=(H, W))
    depth[0, 0] = 0.0  # unknown depth
    flow, valid = camera_flow(torch.from_numpy(depth), torch.from_numpy(K0), torch.from_numpy(K1),
                              torch.from_numpy(w0), torch.from_numpy(w1))
    assert not valid[0, 0]
    c2w0 = np.linalg.inv(w0)
    for v in range(H):
        for u in range(W):
            if depth[v, u] == 0:
                continue
            x_cam = np.linalg.solve(K0, [u, v, 1.0]) * depth[v, u]
            X = c2w0[:3, :3] @ x_cam + c2w0[:3, 3]
            x1 = w1[:3, :3] @ X + w1[:3, 3]
            assert bool(valid[v, u]) == (x1[2] > 1e-6)
            if x1[2] > 1e-6:
                p = K1 @ (x1 / x1[2])
                np.testing.assert_allclose(flow[v, u].numpy(), p[:2] - [u, v], atol=1e-8)


def test_camera_flow_points_behind_next_camera_are_invalid():
    K = make_K(50, 50, 2, 2)
    depth = torch.ones((5, 5), dtype=torch.float64)
    eye = torch.eye(4, dtype=torch.float64)
    ahead = eye.clone()
    ahead[2, 3] = -2.0  # camera t+1 is 2 m further forward: the plane at 1 m is behind it
    _, valid = camera_flow(depth, K, K, eye, ahead)
    assert not valid.any()


@given(seed=st.integers(0, 2**31 - 1))
@settings(max_examples=30)
def test_plucker_rays_pass_through_unprojected_points(seed):
    rng = np.random.default_rng(seed)
    H, W = 5, 6
    K = make_K(30, 32, 2.5, 2.0)
    w2c = torch.from_numpy(random_pose(rng))
    rays = plucker_rays(K, w2c, H, W)
    assert rays.shape == (6, H, W)
    d, m = rays[:3].permute(1, 2, 0), rays[3:].permute(1, 2, 0)
    torch.testing.assert_close(torch.linalg.vector_norm(d, dim=-1), torch.ones(H, W, dtype=torch.float64))
    depth = torch.from_numpy(rng.uniform(0.5, 3.0, size=(H, W)))
    X = transform_points(invert_pose(w2c), unproject(depth, K))  # world points on those rays
    o = invert_pose(w2c)[:3, 3]
    dirs = (X - o) / torch.linalg.vector_norm(X - o, dim=-1, keepdim=True)
    torch.testing.assert_close(dirs, d, atol=1e-10, rtol=0)
    torch.testing.assert_close(torch.linalg.cross(X, d, dim=-1), m, atol=1e-10, rtol=0)  # moment: any point on the ray


def test_plucker_rays_batch():
    K = make_K(30, 30, 2, 2).expand(2, 3, 3)
    w2c = torch.eye(4, dtype=torch.float64).expand(2, 4, 4)
    rays = plucker_rays(K, w2c, 5, 5)
    assert rays.shape == (2, 6, 5, 5)
    torch.testing.assert_close(rays[:, :3, 2, 2], torch.tensor([[0, 0, 1.0]] * 2, dtype=torch.float64))


@pytest.mark.parametrize("call", [
    lambda: unproject(torch.ones(4, 4), torch.eye(4)),
    lambda: project(torch.ones(4, 2), torch.eye(3)),
    lambda: scale_intrinsics(torch.eye(3), 0.0, 1.0),
    lambda: pixel_grid(0, 4),
    lambda: relative_pose(torch.eye(3), torch.eye(4)),
])
def test_bad_shapes_raise_camera_error(call):
    with pytest.raises(CameraError):
        call()


def _backward_warp(image: torch.Tensor, flow: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Bilinear samples of (C, H, W) ``image`` at p + flow(p), and where that lies inside the image."""
    H, W = flow.shape[:2]
    target = pixel_grid(H, W, dtype=flow.dtype) + flow
    grid = (target + 0.5) * target.new_tensor([2.0 / W, 2.0 / H]) - 1.0  # align_corners=False
    warped = torch.nn.functional.grid_sample(image[None], grid[None], mode="bilinear", padding_mode="zeros",
                                             align_corners=False)[0]
    inside = (target[..., 0] >= 0) & (target[..., 0] <= W - 1) & (target[..., 1] >= 0) & (target[..., 1] <= H - 1)
    return warped, inside


def test_backward_warp_with_camera_flow_reproduces_frame_t():
    """A fronto-parallel plane seen by a camera that moves sideways and forward: frame t+1 is the plane
    texture rendered analytically; warping it by F_pose gives frame t's rendering wherever visible."""
    H, W, z = 24, 32, 3.0
    K = make_K(30, 30, 15.5, 11.5)
    eye = torch.eye(4, dtype=torch.float64)
    w1 = eye.clone()
    w1[:3, 3] = torch.tensor([-0.25, 0.1, -0.5])  # camera moved right, up and forward

    def render(w2c):  # texture (2 X + Y, X - Y) on the world plane Z = z (linear -> bilinear-exact)
        c2w = invert_pose(w2c)
        xy = unproject(torch.ones(H, W, dtype=torch.float64), K)  # rays with z = 1 in camera frame
        d = xy @ c2w[:3, :3].T
        s = (z - c2w[2, 3]) / d[..., 2]
        X = c2w[:3, 3] + s[..., None] * d
        return torch.stack([2 * X[..., 0] + X[..., 1], X[..., 0] - X[..., 1]])

    depth_t = torch.full((H, W), z, dtype=torch.float64)
    flow, valid = camera_flow(depth_t, K, K, eye, w1)
    warped, inside = _backward_warp(render(w1), flow)
    ok = valid & inside
    assert ok.float().mean() > 0.5
    torch.testing.assert_close(warped[:, ok], render(eye)[:, ok], atol=1e-9, rtol=0)
