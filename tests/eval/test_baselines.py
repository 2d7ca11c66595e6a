"""Baselines: exact forward warps of planes with known disparity, z-buffering, holes, nearest pose."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from vt4dcodec.cameras import Trajectory
from vt4dcodec.errors import Vt4dError
from vt4dcodec.eval.baselines import (
    BaselineError, forward_warp, mean_colour, nearest_frame_floats, nearest_source_frame, pose_distance, rgbd_floats,
    token_floats,
)

F, S, T = 32.0, 24, 3  # focal length px, image side px, frames


def _K(T: int = T) -> np.ndarray:
    return np.broadcast_to(np.array([[F, 0, (S - 1) / 2], [0, F, (S - 1) / 2], [0, 0, 1.0]]), (T, 3, 3)).copy()


def _traj(x_offsets: np.ndarray, rotations: np.ndarray | None = None) -> Trajectory:
    """Cameras at world x = offset, looking along +z (w2c translation = -R C)."""
    n = len(x_offsets)
    w2c = np.tile(np.eye(4), (n, 1, 1))
    if rotations is not None:
        w2c[:, :3, :3] = rotations
    centres = np.stack([x_offsets, np.zeros(n), np.zeros(n)], -1)
    w2c[:, :3, 3] = -np.einsum("tij,tj->ti", w2c[:, :3, :3], centres)
    return Trajectory(K=_K(n), w2c=w2c, width=S, height=S)


def _textured(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (T, S, S, 3), dtype=np.uint8)


def test_warp_into_the_same_camera_is_the_identity():
    frames = _textured()
    depth = np.random.default_rng(1).uniform(1, 5, (T, S, S)).astype(np.float32)
    cam = _traj(np.zeros(T))
    out = forward_warp(frames, depth, cam, cam)
    assert out.hole_fraction == 0.0
    np.testing.assert_array_equal(out.frames, frames)


def test_plane_shifts_by_its_exact_disparity_and_leaves_a_counted_hole_strip():
    # camera moved by b along +x sees a plane at depth z shifted by f * b / z = 4 px to the left
    frames, depth = _textured(), np.full((T, S, S), 2.0, np.float32)
    out = forward_warp(frames, depth, _traj(np.zeros(T)), _traj(np.full(T, 0.25)), inpaint=False)
    np.testing.assert_array_equal(out.frames[:, :, :S - 4], frames[:, :, 4:])
    assert out.holes[:, :, S - 4:].all() and not out.holes[:, :, :S - 4].any()
    assert (out.frames[:, :, S - 4:] == 0).all()
    assert out.hole_fraction == pytest.approx(4 / S)
    filled = forward_warp(frames, depth, _traj(np.zeros(T)), _traj(np.full(T, 0.25)))
    np.testing.assert_array_equal(filled.frames[:, :, :S - 4], frames[:, :, 4:])
    np.testing.assert_array_equal(filled.holes, out.holes)


def test_z_buffer_keeps_the_nearest_surface():
    frames = np.zeros((T, S, S, 3), np.uint8)
    frames[..., 2] = 200                       # far background: blue, z = 4 (shifts 2 px)
    depth = np.full((T, S, S), 4.0, np.float32)
    frames[:, 8:14, 8:14] = (255, 0, 0)        # near square: red, z = 1 (shifts 8 px)
    depth[:, 8:14, 8:14] = 1.0
    out = forward_warp(frames, depth, _traj(np.zeros(T)), _traj(np.full(T, 0.25)), inpaint=False)
    # the square lands at columns 0..5, over background pixels that also land there
    assert (out.frames[:, 8:14, 0:6] == (255, 0, 0)).all()
    assert (out.frames[:, :8, 0:S - 2] == (0, 0, 200)).all()
    # the background it uncovered is a hole (disocclusion), not red
    assert out.holes[:, 8:14, 6:12].all()


def test_unknown_depth_is_not_splatted():
    frames = _textured()
    depth = np.full((T, S, S), 3.0, np.float32)
    depth[:, :, :5] = 0.0
    depth[:, 0, 7] = np.nan
    cam = _traj(np.zeros(T))
    out = forward_warp(frames, depth, cam, cam, inpaint=False)
    assert out.holes[:, :, :5].all() and out.holes[:, 0, 7].all()
    assert out.holes.sum() == T * (S * 5 + 1)


def test_nearest_frame_picks_the_closest_pose():
    source = _traj(np.array([0.0, 0.5, 1.0]))
    frames = _textured()
    pred, idx = nearest_source_frame(frames, source, _traj(np.array([0.9, 0.1, 0.6])))
    np.testing.assert_array_equal(idx, [2, 0, 1])
    np.testing.assert_array_equal(pred, frames[[2, 0, 1]])


def test_nearest_frame_of_a_static_camera_is_the_same_time():
    frames = _textured()
    _, idx = nearest_source_frame(frames, _traj(np.zeros(T)), _traj(np.full(T, 0.3)))
    np.testing.assert_array_equal(idx, np.arange(T))


def _rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


@given(st.integers(0, 10_000), st.floats(-3, 3), st.floats(-3, 3))
def test_pose_distance_is_symmetric_and_adds_centre_distance_and_angle(seed, xa, xb):
    Ra, Rb = _rotation(seed), _rotation(seed + 1)
    a, b = _traj(np.array([xa]), Ra[None]), _traj(np.array([xb]), Rb[None])
    d_ab, d_ba = pose_distance(a.w2c, b.w2c), pose_distance(b.w2c, a.w2c)
    assert d_ab.shape == (1, 1)
    assert d_ab[0, 0] == pytest.approx(d_ba[0, 0], abs=1e-9)
    angle = np.arccos(np.clip((np.trace(Ra @ Rb.T) - 1) / 2, -1, 1))
    assert d_ab[0, 0] == pytest.approx(abs(xa - xb) + angle, abs=1e-6)
    assert pose_distance(a.w2c, a.w2c)[0, 0] == pytest.approx(0.0, abs=1e-6)


def test_sizes_in_floats():
    assert nearest_frame_floats(8, 64, 64) == 8 * 64 * 64 * 3
    assert rgbd_floats(8, 64, 64) == 8 * 64 * 64 * 4
    assert token_floats(64, 32, 32) == 3072


@pytest.mark.parametrize("bad", ["dtype", "shape", "depth", "target"])
def test_bad_inputs_raise_the_project_error(bad):
    frames, depth = _textured(), np.ones((T, S, S), np.float32)
    cam, target = _traj(np.zeros(T)), _traj(np.zeros(T))
    if bad == "dtype":
        frames = frames.astype(np.float32)
    elif bad == "shape":
        frames = frames[:, :-1]
    elif bad == "depth":
        depth = depth[:2]
    else:
        target = _traj(np.zeros(T - 1))
    with pytest.raises(BaselineError) as info:
        forward_warp(frames, depth, cam, target)
    assert isinstance(info.value, Vt4dError)
    if bad in ("dtype", "shape"):
        with pytest.raises(BaselineError):
            nearest_source_frame(frames, cam, target)


def test_surfel_footprint_closes_the_cracks_of_a_magnified_plane():
    # the target camera is twice as close to the plane: single-pixel splats leave every other row and
    # column empty, surfels of the projected size cover the whole view
    frames, depth = _textured(), np.full((T, S, S), 2.0, np.float32)
    near = _traj(np.zeros(T))
    w2c = np.tile(np.eye(4), (T, 1, 1))
    w2c[:, 2, 3] = -1.0  # camera centre at z = +1
    closer = Trajectory(K=_K(), w2c=w2c, width=S, height=S)
    single = forward_warp(frames, depth, near, closer, inpaint=False)
    surfels = forward_warp(frames, depth, near, closer, inpaint=False, footprint=True)
    assert single.hole_fraction > 0.5
    assert surfels.hole_fraction == 0.0
    # every target pixel shows one of the source pixels around its back-projection (x_s = (x_t + c) / 2)
    c = (S - 1) / 2
    back = (np.arange(S) + c) / 2
    for t in range(T):
        ok = np.zeros((S, S), bool)
        for ys in (np.floor(back), np.ceil(back)):
            for xs in (np.floor(back), np.ceil(back)):
                src = frames[t][ys.astype(int)[:, None], xs.astype(int)[None, :]]
                ok |= (surfels.frames[t] == src).all(-1)
        assert ok.all()


def test_mean_colour_is_a_flat_video_of_the_source_mean():
    frames = _textured()
    flat = mean_colour(frames)
    assert flat.shape == frames.shape and flat.dtype == np.uint8
    np.testing.assert_array_equal(flat[1, 5, 7], np.round(frames.reshape(-1, 3).mean(0)).astype(np.uint8))
    assert (flat == flat[0, 0, 0]).all()
    with pytest.raises(BaselineError):
        mean_colour(frames[..., :2])
