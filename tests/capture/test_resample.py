"""Fitting captures to a model resolution: undistort, resize, centre-crop, with intrinsics that match."""

import cv2
import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from vt4dcodec.cameras import Trajectory
from vt4dcodec.capture import Capture
from vt4dcodec.capture.resample import fit_capture, plan_fit, undistort_pixels
from vt4dcodec.errors import CaptureError
from vt4dcodec.model.geometry import scale_intrinsics

from capture_helpers import make_capture

DIST = np.array([-0.30, 0.09, -0.001, 0.003, -0.004])  # a strongly distorted webcam


def blob_image(W, H, centers, sigma):
    """(H, W, 3) uint8 white Gaussian blobs on black at sub-pixel ``centers`` (pixel-centre convention)."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    img = np.zeros((H, W))
    for cu, cv_ in centers:
        img += np.exp(-((u - cu) ** 2 + (v - cv_) ** 2) / (2 * sigma**2))
    return np.repeat(np.clip(np.rint(255 * img), 0, 255).astype(np.uint8)[..., None], 3, axis=2)


def centroid(img, guess, radius):
    g = img[..., 0].astype(np.float64)
    v, u = np.mgrid[0:g.shape[0], 0:g.shape[1]]
    m = (np.abs(u - guess[0]) <= radius) & (np.abs(v - guess[1]) <= radius)
    w = g * m
    return np.array([(w * u).sum() / w.sum(), (w * v).sum() / w.sum()])


@given(W=st.integers(8, 400), H=st.integers(8, 400), ow=st.integers(4, 128), oh=st.integers(4, 128))
def test_plan_covers_then_crops(W, H, ow, oh):
    plan = plan_fit(W, H, out_height=oh, out_width=ow)
    assert plan.scaled_width >= ow and plan.scaled_height >= oh
    assert plan.x0 + ow <= plan.scaled_width and plan.y0 + oh <= plan.scaled_height
    assert plan.scaled_width == ow or plan.scaled_height == oh or abs(plan.sx - plan.sy) < 0.1
    # the numpy intrinsics update equals the torch scale_intrinsics followed by the crop's shift
    K = np.array([[300.0, 1.0, W / 2], [0, 310.0, H / 2], [0, 0, 1]])
    expected = scale_intrinsics(torch.from_numpy(K), plan.sx, plan.sy).numpy()
    expected[:2, 2] -= (plan.x0, plan.y0)
    np.testing.assert_allclose(plan.intrinsics(K), expected, atol=1e-9)


@given(W=st.integers(8, 400), H=st.integers(8, 400), ow=st.integers(4, 128), oh=st.integers(4, 128))
def test_pad_plan_fits_inside_then_centres(W, H, ow, oh):
    plan = plan_fit(W, H, out_height=oh, out_width=ow, fit="pad")
    assert 1 <= plan.scaled_width <= ow and 1 <= plan.scaled_height <= oh
    assert plan.scaled_width == ow or plan.scaled_height == oh or abs(plan.sx - plan.sy) < 0.1
    assert plan.x0 <= 0 and plan.y0 <= 0  # the whole image is inside the output
    assert abs((-plan.x0) - (ow - plan.scaled_width - (-plan.x0))) <= 1  # centred: bars differ by <= 1 px
    assert abs((-plan.y0) - (oh - plan.scaled_height - (-plan.y0))) <= 1


def portrait_capture(W=54, H=96, distortion=None):
    """A portrait camera whose frame is red in its top fifth, blue in its bottom fifth, green between."""
    img = np.zeros((H, W, 3), np.uint8)
    img[: H // 5] = (255, 0, 0)
    img[H // 5: H - H // 5] = (0, 255, 0)
    img[H - H // 5:] = (0, 0, 255)
    K = np.array([[70.0, 0, (W - 1) / 2], [0, 70.0, (H - 1) / 2], [0, 0, 1]])
    traj = Trajectory(K=K, w2c=np.eye(4), width=W, height=H, distortion=distortion)
    return Capture(cameras={"c": traj}, frames={"c": img[None]})


@pytest.mark.parametrize("distortion", [None, np.array([1e-4, 0, 0, 0])])
def test_pad_keeps_the_whole_portrait_picture(distortion):
    """Portrait 9:16 into a square: crop cuts the red top and blue bottom away; pad keeps all three bands
    and puts black bars left and right, and the intrinsics say where every source pixel went."""
    cap = portrait_capture(distortion=distortion)
    crop = fit_capture(cap, height=32, width=32)
    pad = fit_capture(cap, height=32, width=32, fit="pad")
    assert pad.metadata["fit"]["mode"] == "pad"

    def share(frames, colour):
        return float(np.mean(np.all(np.abs(frames[0].astype(int) - colour) < 60, axis=-1)))

    assert share(crop.frames["c"], (255, 0, 0)) == 0 and share(crop.frames["c"], (0, 0, 255)) == 0
    assert share(pad.frames["c"], (255, 0, 0)) > 0.08 and share(pad.frames["c"], (0, 0, 255)) > 0.08
    plan = plan_fit(54, 96, out_height=32, out_width=32, fit="pad")
    assert (plan.scaled_width, plan.scaled_height, plan.x0, plan.y0) == (18, 32, -7, 0)
    frame = pad.frames["c"][0]
    assert not frame[:, :6].any() and not frame[:, 26:].any()  # black bars, a pixel away from the image edge
    assert frame[:, 8:24].min(axis=-1).max() == 0 and frame[:, 8:24].max(axis=-1).min() > 150  # the image
    # the corners of the source image map inside the output, where the fitted K projects them
    K = pad.cameras["c"].K[0]
    src_K = cap.cameras["c"].K[0]
    corners = np.array([[-0.5, -0.5], [53.5, 95.5]])
    rays = np.linalg.solve(src_K, np.c_[corners, np.ones(2)].T).T
    projected = (K @ rays.T).T[:, :2]
    np.testing.assert_allclose(projected, [[6.5, -0.5], [24.5, 31.5]], atol=1e-9)


def test_unknown_fit_is_refused():
    with pytest.raises(CaptureError, match="'crop'.*'pad'.*'squash'"):
        fit_capture(make_capture(T=1), height=8, width=8, fit="squash")
    with pytest.raises(CaptureError, match="fit must be"):
        plan_fit(10, 10, out_height=4, out_width=4, fit="letterbox")


@pytest.mark.parametrize("fit", ["crop", "pad"])
@pytest.mark.parametrize("out_h, out_w", [(64, 64), (48, 96), (120, 160), (300, 400)])
def test_fit_capture_moves_points_where_the_new_intrinsics_say(out_h, out_w, fit):
    """End to end: blobs at the distorted projections of known 3D points land, after undistortion,
    resizing and cropping, where the fitted pinhole camera projects those points."""
    W, H = 320, 240
    K = np.array([[260.0, 0.0, 161.3], [0.0, 258.0, 118.6], [0.0, 0.0, 1.0]])
    # well separated points that stay inside the central crop of every output aspect
    ideal = np.array([[120.0, 80.0], [200.0, 80.0], [160.4, 120.3], [120.0, 160.0], [200.0, 160.0]])
    rays = np.c_[np.linalg.solve(K, np.c_[ideal, np.ones(len(ideal))].T).T]
    seen = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, DIST)[0].reshape(-1, 2)
    img = blob_image(W, H, seen, sigma=2.5)
    traj = Trajectory(K=K, w2c=np.eye(4), width=W, height=H, distortion=DIST)
    cap = Capture(cameras={"c": traj}, frames={"c": img[None]})
    fitted = fit_capture(cap, height=out_h, width=out_w, fit=fit)
    out = fitted.cameras["c"]
    assert out.distortion is None and (out.width, out.height) == (out_w, out_h)
    assert fitted.frames["c"].shape == (1, out_h, out_w, 3)
    pred = (out.K[0] @ rays.T).T[:, :2]  # pinhole projection with the fitted intrinsics
    scale = plan_fit(W, H, out_height=out_h, out_width=out_w, fit=fit).sx
    for p in pred:
        c = centroid(fitted.frames["c"][0], p, radius=max(2, round(16 * scale)))
        assert np.linalg.norm(c - p) < 0.2, (c, p)
    # observations follow the same mapping
    mapped = plan_fit(W, H, out_height=out_h, out_width=out_w, fit=fit).points(undistort_pixels(seen, K, DIST))
    np.testing.assert_allclose(mapped, pred, atol=1e-6)


def test_undistort_pixels_agrees_with_kornia():
    from kornia.geometry.calibration import undistort_points

    K = np.array([[600.0, 0, 330.0], [0, 610.0, 250.0], [0, 0, 1]])
    pts = np.random.default_rng(1).uniform([150, 100], [500, 380], size=(30, 2))
    expected = undistort_points(*(torch.from_numpy(a) for a in (pts, K, DIST)), num_iters=40).numpy()
    np.testing.assert_allclose(undistort_pixels(pts, K, DIST), expected, atol=1e-4)


def test_fit_capture_frames_depth_and_timestamps():
    cap = make_capture(T=5, width=40, height=30)
    out = fit_capture(cap, height=16, width=16, num_frames=3, start=1)
    assert out.num_frames == 3
    for n, traj in out.cameras.items():
        np.testing.assert_array_equal(traj.timestamps, cap.cameras[n].timestamps[1:4])
        np.testing.assert_array_equal(traj.w2c, cap.cameras[n].w2c[1:4])
    d_in, d_out = cap.depth["cam_a"], out.depth["cam_a"]
    assert d_out.shape == (3, 16, 16) and d_out.dtype == np.float32
    assert set(np.unique(d_out)) <= set(np.unique(d_in[1:4]))  # nearest: no blended depths
    assert out.metadata["fit"] == {"height": 16, "width": 16, "start": 1, "num_frames": 3, "mode": "crop"}


def test_distorted_depth_is_resampled_without_blending():
    cap = make_capture(T=2, width=40, height=30)
    cams = {n: Trajectory(K=t.K, w2c=t.w2c, width=40, height=30, distortion=DIST) for n, t in cap.cameras.items()}
    cap = Capture(cameras=cams, frames=cap.frames, depth=cap.depth)
    for size in (12, 60):  # shrinking (area-averaged RGB first) and enlarging
        out = fit_capture(cap, height=size, width=size)
        d_in, d_out = cap.depth["cam_a"], out.depth["cam_a"]
        assert d_out.shape == (2, size, size)
        assert set(np.unique(d_out)) <= set(np.unique(d_in)) | {0.0}


def test_identity_fit_is_exact():
    cap = make_capture(T=2, width=20, height=10)
    out = fit_capture(cap, height=10, width=20)
    for n in cap.cameras:
        np.testing.assert_array_equal(out.frames[n], cap.frames[n])
        np.testing.assert_allclose(out.cameras[n].K, cap.cameras[n].K)


@pytest.mark.parametrize("kwargs", [
    dict(height=0, width=8), dict(height=8, width=8, num_frames=4), dict(height=8, width=8, start=3),
    dict(height=8, width=8, num_frames=0), dict(height=8, width=8, start=-1),
])
def test_fit_capture_rejects_bad_requests(kwargs):
    with pytest.raises(CaptureError):
        fit_capture(make_capture(T=3), **kwargs)
