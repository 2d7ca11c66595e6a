"""Source preprocessing (model.inputs.preprocess.prepare_source): the encoder's inputs from a calibrated clip."""

from __future__ import annotations

import numpy as np
import pytest

from vt4dcodec.cameras import Trajectory
from vt4dcodec.errors import Vt4dError
from vt4dcodec.model.inputs.preprocess import prepare_source, undistort_clip
from vt4dcodec.model.inputs.source_inputs import SourceBatch, SourceInputs

from test_motion import iou, plane_scene  # noqa: E402  (hand-made scene, same directory)

T, H, W = 8, 64, 64


def scene_inputs(seed: int = 0, static: bool = False):
    s = plane_scene(seed, static)
    return s, Trajectory(K=s["K"], w2c=s["w2c"], width=W, height=H)


def test_prepare_source_shapes_and_contract():
    s, traj = scene_inputs()
    src = prepare_source(s["frames"], traj, s["depth"], latent_hw=(16, 16), num_tracks=32, seed=3)
    assert isinstance(src, SourceInputs)
    assert src.motion_mask.shape == (T, 16, 16) and src.motion_mask.dtype == np.float32
    assert src.motion_mask.min() >= 0 and src.motion_mask.max() <= 1
    assert src.track_xy.shape == (32, T, 2) and src.track_valid.shape == (32, T)
    assert src.track_xy.dtype == np.float32 and src.track_valid.dtype == bool
    assert np.all(src.track_xy >= -0.5) and np.all(src.track_xy <= 15.5)
    np.testing.assert_array_equal(src.frames, s["frames"])
    # the latent mask covers the card: its area fraction matches the pixel mask's
    gt_latent = s["dyn"].reshape(T, 16, 4, 16, 4).mean((2, 4))
    assert iou(src.motion_mask > 0.5, gt_latent > 0.5) > 0.5
    # tracks start on the moving card and are valid there for most of the clip
    assert src.track_valid.mean() > 0.5
    batch = SourceBatch.collate([src, src])
    assert batch.track_xy.shape == (2, 32, T, 2)


def test_tracks_follow_the_card_in_latent_units():
    s, traj = scene_inputs(1)
    src = prepare_source(s["frames"], traj, s["depth"], num_tracks=16, seed=0)
    velocity = np.array([0.12, 0.03, 0.0])  # the card's world motion per frame (plane_scene)
    errors = []
    for i, t in zip(*np.nonzero(src.track_valid[:, :-1] & src.track_valid[:, 1:])):
        u, v = (src.track_xy[i, t] + 0.5) * 4 - 0.5  # latent px -> image px
        z = s["depth"][t, int(round(v)), int(round(u))]
        ray = np.linalg.inv(s["K"][t]) @ np.array([u, v, 1.0])
        world = np.linalg.inv(s["w2c"][t]) @ np.r_[ray * z, 1.0]
        moved = s["w2c"][t + 1] @ np.r_[world[:3] + velocity, 1.0]
        uv = s["K"][t + 1] @ moved[:3]
        expected = (uv[:2] / uv[2] + 0.5) / 4 - 0.5
        errors.append(np.linalg.norm(src.track_xy[i, t + 1] - expected))
    assert len(errors) > 20
    # one latent px = 4 image px; DIS on the card errs by well under an image pixel
    assert np.median(errors) < 0.1 and np.max(errors) < 0.5, (np.median(errors), np.max(errors))


def test_same_seed_same_output_and_seed_changes_tracks():
    s, traj = scene_inputs()
    a = prepare_source(s["frames"], traj, s["depth"], num_tracks=24, seed=5)
    b = prepare_source(s["frames"], traj, s["depth"], num_tracks=24, seed=5)
    c = prepare_source(s["frames"], traj, s["depth"], num_tracks=24, seed=6)
    np.testing.assert_array_equal(a.track_xy, b.track_xy)
    np.testing.assert_array_equal(a.motion_mask, b.motion_mask)
    assert not np.array_equal(a.track_xy, c.track_xy)


def test_static_clip_gives_padding_tracks():
    s, traj = scene_inputs(0, static=True)
    src = prepare_source(s["frames"], traj, s["depth"], num_tracks=10)
    assert src.motion_mask.max() < 0.25
    assert src.track_xy.shape == (10, T, 2) and not src.track_valid.any()


def test_no_motion_isolation_ablation_uses_a_mask_of_ones():
    s, traj = scene_inputs()
    src = prepare_source(s["frames"], traj, None, latent_hw=(8, 8), num_tracks=40, motion_isolation=False)
    assert src.motion_mask.shape == (T, 8, 8) and np.all(src.motion_mask == 1.0)
    assert src.track_valid.any(axis=1).all()  # seeds everywhere, tracks still flow-propagated
    assert np.all(src.track_xy <= 7.5)


def test_estimated_depth_path():
    s, traj = scene_inputs()
    src = prepare_source(s["frames"], traj, None, num_tracks=8, depth_range=(1.0, 20.0))
    assert src.motion_mask.shape == (T, 16, 16) and src.motion_mask.max() > 0.5


def test_distorted_trajectory_is_undistorted_first():
    s, _ = scene_inputs()
    dist = np.array([-0.05, 0.01, 0.0, 0.0])
    traj = Trajectory(K=s["K"], w2c=s["w2c"], width=W, height=H, distortion=dist)
    frames, depth = undistort_clip(s["frames"], traj, s["depth"])
    assert frames.shape == s["frames"].shape and depth.shape == s["depth"].shape
    assert not np.array_equal(frames, s["frames"])
    # the principal point does not move under radial distortion
    np.testing.assert_array_equal(frames[:, 31:33, 31:33], s["frames"][:, 31:33, 31:33])
    src = prepare_source(s["frames"], traj, s["depth"], num_tracks=4)
    np.testing.assert_array_equal(src.frames, frames)
    plain = Trajectory(K=s["K"], w2c=s["w2c"], width=W, height=H)
    same, same_depth = undistort_clip(s["frames"], plain, s["depth"])
    assert same is s["frames"] and same_depth is s["depth"]


@pytest.mark.parametrize(
    "change",
    [
        lambda a: a.update(frames=a["frames"][:, :, :32]),
        lambda a: a.update(frames=a["frames"][:4]),
        lambda a: a.update(trajectory="not a trajectory"),
        lambda a: a.update(depth=a["depth"][:3]),
        lambda a: a.update(num_tracks=-1),
        lambda a: a.update(num_tracks=True),
        lambda a: a.update(latent_hw=(0, 16)),
    ],
)
def test_bad_inputs_raise_vt4d_errors(change):
    s, traj = scene_inputs()
    args = dict(frames=s["frames"], trajectory=traj, depth=s["depth"])
    change(args)
    with pytest.raises(Vt4dError):
        prepare_source(**args)


def test_bad_latent_size_in_the_ablation_raises():
    s, traj = scene_inputs()
    with pytest.raises(Vt4dError):
        prepare_source(s["frames"], traj, None, latent_hw=(100, 100), motion_isolation=False)
