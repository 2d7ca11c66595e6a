"""Flow-propagated tracks (model.inputs.tracks): rigid-motion accuracy, validity rules, seeds, bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from vt4dcodec.errors import Vt4dError
from vt4dcodec.model.inputs.motion import estimate_flows
from vt4dcodec.model.inputs.tracks import (
    PADDING_SEED_FRAME,
    TrackInputError,
    bilinear_sample,
    propagate_tracks,
    sample_seeds,
)

H = W = 64
T = 8


def rigid(t: int) -> np.ndarray:
    """2x3 affine of a rigid image motion at frame t: rotation 1.5 deg/frame about (30, 34), drift (0.7, -0.4) px/frame."""
    angle = np.deg2rad(1.5 * t)
    c, s = np.cos(angle), np.sin(angle)
    centre = np.array([30.0, 34.0])
    R = np.array([[c, -s], [s, c]])
    b = centre - R @ centre + np.array([0.7, -0.4]) * t
    return np.hstack([R, b[:, None]])


def apply(A: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return pts @ A[:, :2].T + A[:, 2]


def invert(A: np.ndarray) -> np.ndarray:
    return cv2.invertAffineTransform(A)


def compose(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A after B."""
    M = np.vstack([A, [0, 0, 1]]) @ np.vstack([B, [0, 0, 1]])
    return M[:2]


def rigid_flows() -> tuple[np.ndarray, np.ndarray]:
    """Exact (T-1, H, W, 2) forward and backward flows of the rigid motion ``rigid``."""
    gx, gy = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    grid = np.stack([gx, gy], -1).reshape(-1, 2)
    fwd, bwd = [], []
    for t in range(T - 1):
        step = compose(rigid(t + 1), invert(rigid(t)))  # frame t -> t+1
        fwd.append((apply(step, grid) - grid).reshape(H, W, 2))
        bwd.append((apply(invert(step), grid) - grid).reshape(H, W, 2))
    return np.stack(fwd).astype(np.float32), np.stack(bwd).astype(np.float32)


def rigid_video(seed: int = 0) -> np.ndarray:
    """(T, H, W, 3) uint8: a smooth random texture moved by ``rigid`` (frame t = texture under rigid(t))."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.random((H * 2, W * 2, 3)).astype(np.float32), (0, 0), 1.5)
    tex = np.clip((tex - tex.mean()) / tex.std() * 0.22 + 0.5, 0, 1)
    frames = []
    for t in range(T):
        # frame pixel p shows the texture at rigid(t)^-1 (p) + (W/2, H/2) (the centre of the big texture)
        M = compose(np.array([[1, 0, W / 2], [0, 1, H / 2]], np.float64), invert(rigid(t)))
        img = cv2.warpAffine(tex, M, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
        frames.append(np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8))
    return np.stack(frames)


def truth(seed_frames: np.ndarray, seed_xy: np.ndarray) -> np.ndarray:
    """(N, T, 2) exact image positions of the seeds under the rigid motion."""
    out = np.zeros((len(seed_frames), T, 2))
    for i, (s, p) in enumerate(zip(seed_frames, seed_xy)):
        base = apply(invert(rigid(s)), p[None])  # reference-frame point
        for t in range(T):
            out[i, t] = apply(rigid(t), base)[0]
    return out


def central_seeds(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    frames = rng.integers(0, T, size=n)
    xy = rng.uniform(22, 42, size=(n, 2))
    return frames, xy


def track_errors(tracks, expected: np.ndarray) -> np.ndarray:
    err = np.linalg.norm(tracks.xy - expected, axis=-1)
    return err[tracks.valid]


def test_tracks_follow_exact_rigid_flow_within_a_pixel_over_eight_frames():
    fwd, bwd = rigid_flows()
    frames, xy = central_seeds(64, np.random.default_rng(0))
    tracks = propagate_tracks(frames, xy, fwd, bwd)
    assert tracks.valid.mean() > 0.95  # a rigid, fully visible motion keeps (almost) every track
    err = track_errors(tracks, truth(frames, xy))
    assert err.max() < 1.0, err.max()
    assert err.mean() < 0.05  # bilinear sampling of a smooth field: far below a pixel


def test_tracks_with_dis_flow_on_rigid_motion_stay_close():
    video = rigid_video()
    fwd, bwd = estimate_flows(video)
    frames, xy = central_seeds(64, np.random.default_rng(1))
    tracks = propagate_tracks(frames, xy, fwd, bwd)
    err = track_errors(tracks, truth(frames, xy))
    assert tracks.valid.mean() > 0.8
    # measured ~0.2 px mean / < 1 px p95 (docs/motion.md); the bound leaves room for DIS variation
    assert np.median(err) < 0.5 and np.percentile(err, 95) < 1.5, (np.median(err), np.percentile(err, 95))


def test_latent_scale_maps_cell_centres_and_flow():
    # uniform flow of 4 px/frame at pixel res = 1 latent px/frame at scale 4
    fwd = np.zeros((T - 1, H, W, 2), np.float32)
    fwd[..., 0] = 4.0
    bwd = -fwd
    tracks = propagate_tracks(np.array([0]), np.array([[2.0, 5.0]]), fwd, bwd, scale=4.0)
    np.testing.assert_allclose(tracks.xy[0, :, 0][tracks.valid[0]], 2.0 + np.arange(tracks.valid[0].sum()), atol=1e-5)
    np.testing.assert_allclose(tracks.xy[0, :, 1], 5.0, atol=1e-5)
    # 16 latent columns: x = 2 + t stays inside until t = 7 (x = 9)
    assert tracks.valid[0].all()


def test_leaving_the_frame_invalidates_and_stays_invalid():
    fwd = np.zeros((T - 1, H, W, 2), np.float32)
    fwd[..., 0] = 3.0
    bwd = -fwd
    tracks = propagate_tracks(np.array([0, 7]), np.array([[56.0, 10.0], [5.0, 10.0]]), fwd, bwd)
    # forward from x=56: 59, 62, 65 (out) -> valid for t = 0..2 only
    assert tracks.valid[0].tolist() == [True, True, True, False, False, False, False, False]
    # backward from x=5 at t=7: 2, -1 (out) -> valid for t = 6, 7
    assert tracks.valid[1].tolist() == [False] * 6 + [True, True]
    assert np.all(np.isfinite(tracks.xy))
    # an invalid position repeats the last valid one
    np.testing.assert_allclose(tracks.xy[0, 3:, 0], 62.0)


def test_forward_backward_check_invalidates_occluded_points():
    # a 16x16 square moves 4 px right per frame over a static background
    fwd = np.zeros((T - 1, H, W, 2), np.float32)
    bwd = np.zeros_like(fwd)
    for t in range(T - 1):
        x0 = 10 + 4 * t
        fwd[t, 20:36, x0 : x0 + 16, 0] = 4.0
        bwd[t, 20:36, x0 + 4 : x0 + 20, 0] = -4.0
    # background point just right of the square at t=0 gets covered at t=1; a square point stays valid
    tracks = propagate_tracks(np.array([0, 0, 0]), np.array([[27.0, 28.0], [12.0, 28.0], [50.0, 50.0]]), fwd, bwd)
    assert tracks.valid[0].tolist() == [True] + [False] * 7  # occluded at t=1
    assert tracks.valid[1].all()  # rides on the square
    np.testing.assert_allclose(tracks.xy[1, :, 0], 12.0 + 4 * np.arange(T), atol=1e-5)
    assert tracks.valid[2].all()  # far background, never occluded


def test_padding_tracks_are_invalid_everywhere():
    fwd = np.zeros((T - 1, H, W, 2), np.float32)
    frames, xy = sample_seeds(np.zeros((T, 16, 16), np.float32), 5, rng=np.random.default_rng(0))
    assert (frames == PADDING_SEED_FRAME).all()
    tracks = propagate_tracks(frames, xy, fwd, fwd, scale=4.0)
    assert tracks.xy.shape == (5, T, 2) and not tracks.valid.any()


@given(st.integers(0, 2**32 - 1), st.integers(0, 40), st.floats(0.0, 1.0))
def test_seeds_come_from_masked_cells_and_are_deterministic(seed, n, density):
    rng = np.random.default_rng(seed)
    mask = (rng.random((T, 16, 16)) < density * 0.2).astype(np.float32) * rng.random((T, 16, 16)).astype(np.float32)
    f1, xy1 = sample_seeds(mask, n, rng=np.random.default_rng(seed))
    f2, xy2 = sample_seeds(mask, n, rng=np.random.default_rng(seed))
    np.testing.assert_array_equal(f1, f2)
    np.testing.assert_array_equal(xy1, xy2)
    assert f1.shape == (n,) and xy1.shape == (n, 2)
    if not (mask > 0).any():
        assert (f1 == PADDING_SEED_FRAME).all()
        return
    cell = np.clip(np.round(xy1).astype(int), 0, 15)
    assert (mask[f1, cell[:, 1], cell[:, 0]] > 0).all()
    if n <= (mask > 0).sum():
        assert len({(a, b, c) for a, (b, c) in zip(f1, cell)}) == n  # no repeated cell while there are enough


@given(st.integers(0, 2**32 - 1), st.integers(1, 6), st.floats(0.5, 4.0))
def test_validity_is_monotone_away_from_the_seed_and_positions_stay_inside(seed, n_frames, scale):
    rng = np.random.default_rng(seed)
    Hs, Ws = 12, 10
    fwd = (rng.normal(size=(n_frames - 1, Hs, Ws, 2)) * 2).astype(np.float32)
    bwd = (-fwd + rng.normal(size=fwd.shape) * 0.5).astype(np.float32)
    n = 9
    frames = rng.integers(-1, n_frames, size=n)
    xy = rng.uniform(-1, 4, size=(n, 2))
    tracks = propagate_tracks(frames, xy, fwd, bwd, scale=scale)
    assert tracks.xy.shape == (n, n_frames, 2) and tracks.valid.shape == (n, n_frames)
    assert np.all(np.isfinite(tracks.xy))
    assert np.all(tracks.xy >= -0.5 - 1e-5)
    assert np.all(tracks.xy[..., 0] <= Ws / scale - 0.5 + 1e-5) and np.all(tracks.xy[..., 1] <= Hs / scale - 0.5 + 1e-5)
    for i in range(n):
        s = frames[i]
        if s < 0:
            assert not tracks.valid[i].any()
            continue
        after, before = tracks.valid[i, s:], tracks.valid[i, : s + 1][::-1]
        for run in (after, before):  # once invalid, invalid for good in that direction
            assert not np.any(np.diff(run.astype(int)) > 0)


def test_zero_flow_keeps_tracks_in_place():
    fwd = np.zeros((T - 1, H, W, 2), np.float32)
    frames, xy = np.array([0, 3, 7]), np.array([[1.0, 2.0], [10.5, 3.25], [15.0, 15.0]])
    tracks = propagate_tracks(frames, xy, fwd, fwd, scale=4.0)
    assert tracks.valid.all()
    np.testing.assert_allclose(tracks.xy, np.repeat(xy[:, None], T, 1), atol=1e-5)


def test_bilinear_sample_is_exact_on_affine_fields():
    gx, gy = np.meshgrid(np.arange(7.0), np.arange(5.0))
    field = np.stack([2 * gx + 1, -gy + 3 * gx], -1)
    pts = np.array([[0.0, 0.0], [2.5, 1.25], [6.0, 4.0], [3.3, 0.7]])
    expected = np.stack([2 * pts[:, 0] + 1, -pts[:, 1] + 3 * pts[:, 0]], -1)
    np.testing.assert_allclose(bilinear_sample(field, pts), expected, atol=1e-5)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(seed_frames=np.array([0]), seed_xy=np.zeros((2, 2))),
        dict(seed_frames=np.array([9]), seed_xy=np.zeros((1, 2))),
        dict(seed_frames=np.array([-2]), seed_xy=np.zeros((1, 2))),
        dict(seed_frames=np.array([0.5]), seed_xy=np.zeros((1, 2))),
        dict(seed_frames=np.array([0]), seed_xy=np.array([[np.nan, 0.0]])),
        dict(seed_frames=np.array([0]), seed_xy=np.zeros((1, 2)), scale=0.0),
        dict(seed_frames=np.array([0]), seed_xy=np.zeros((1, 2)), scale=(1.0, 2.0, 3.0)),
        dict(seed_frames=np.array([0]), seed_xy=np.zeros((1, 2)), fb_tolerance=-1.0),
    ],
)
def test_bad_track_inputs_raise_vt4d_errors(kwargs):
    fwd = np.zeros((3, 8, 8, 2), np.float32)
    with pytest.raises(TrackInputError):
        propagate_tracks(flow_fwd=fwd, flow_bwd=fwd, **kwargs)


def test_bad_flows_and_masks_raise_vt4d_errors():
    good = np.zeros((3, 8, 8, 2), np.float32)
    with pytest.raises(Vt4dError):
        propagate_tracks(np.array([0]), np.zeros((1, 2)), good, good[:2])
    with pytest.raises(Vt4dError):
        propagate_tracks(np.array([0]), np.zeros((1, 2)), good[..., :1], good[..., :1])
    bad = good.copy()
    bad[0, 0, 0, 0] = np.inf
    with pytest.raises(Vt4dError):
        propagate_tracks(np.array([0]), np.zeros((1, 2)), bad, good)
    with pytest.raises(Vt4dError):
        sample_seeds(np.zeros((4, 4)), 3, rng=np.random.default_rng(0))
    with pytest.raises(Vt4dError):
        sample_seeds(np.zeros((2, 4, 4)), -1, rng=np.random.default_rng(0))
