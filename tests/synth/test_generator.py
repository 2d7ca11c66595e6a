"""The generator's ground truth is exact: warping, masks, camera-induced flow, determinism, shapes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from vt4dcodec.errors import Vt4dError
from vt4dcodec.model.geometry import camera_flow
from vt4dcodec.synth import SynthConfig, SynthError, generate_scene

from .helpers import SMALL, SMALL_STATIC, backward_warp, scene


def _camera_flow_np(sc, name: str) -> tuple[np.ndarray, np.ndarray]:
    cam = sc.capture.cameras[name]
    depth = torch.from_numpy(sc.capture.depth[name][:-1]).double()
    flow, valid = camera_flow(depth, torch.from_numpy(cam.K[:-1]), torch.from_numpy(cam.K[1:]),
                              torch.from_numpy(cam.w2c[:-1]), torch.from_numpy(cam.w2c[1:]))
    return flow.numpy(), valid.numpy()


def test_default_scene_contract_shapes_and_dtypes():
    sc = generate_scene(0)
    cfg = SynthConfig()
    cap = sc.capture
    assert cap.camera_names == [f"cam{i:02d}" for i in range(cfg.num_cameras)]
    assert cap.fps == cfg.fps and cap.capture_id == "synth-train-000000"
    T, H, W = cfg.num_frames, cfg.height, cfg.width
    for name in cap.camera_names:
        assert cap.frames[name].shape == (T, H, W, 3) and cap.frames[name].dtype == np.uint8
        d = cap.depth[name]
        assert d.shape == (T, H, W) and d.dtype == np.float32
        assert np.all(np.isfinite(d)) and d.min() > 0.1 and d.max() < 40.0   # metres, a room
        assert sc.flow[name].shape == (T - 1, H, W, 2) and sc.flow[name].dtype == np.float32
        assert sc.flow_valid[name].shape == (T - 1, H, W) and sc.flow_valid[name].dtype == bool
        assert sc.dynamic_mask[name].shape == (T, H, W) and sc.dynamic_mask[name].dtype == bool
        assert sc.object_ids[name].shape == (T, H, W) and sc.object_ids[name].dtype == np.int16
        assert sc.object_ids[name].min() >= 0 and sc.object_ids[name].max() <= len(sc.objects)
    # the cameras all look at the action: every object is seen by some camera
    seen = set(np.unique(np.concatenate([sc.object_ids[n].ravel() for n in cap.camera_names])))
    assert seen >= set(range(1, len(sc.objects) + 1))
    assert 2 <= len(sc.objects) <= 4
    # varied focal lengths, and the cameras move smoothly
    fx = [cap.cameras[n].K[0, 0, 0] for n in cap.camera_names]
    assert np.ptp(fx) > 1.0
    centers = np.stack([cap.cameras[n].centers for n in cap.camera_names])      # (C, T, 3)
    steps = np.linalg.norm(np.diff(centers, axis=1), axis=-1)
    assert steps.max() < 0.2 and steps.max() > 0.0


@settings(max_examples=4)
@given(seed=st.integers(0, 10_000), split=st.sampled_from(["train", "test"]))
def test_deterministic_from_seed_split_config(seed, split):
    a = generate_scene(seed, split=split, config=SMALL)
    b = generate_scene(seed, split=split, config=SMALL)
    for name in a.capture.camera_names:
        assert np.array_equal(a.capture.frames[name], b.capture.frames[name])
        assert np.array_equal(a.capture.depth[name], b.capture.depth[name])
        assert np.array_equal(a.flow[name], b.flow[name])
        assert np.array_equal(a.object_ids[name], b.object_ids[name])
        assert a.capture.cameras[name].equals(b.capture.cameras[name])
    other = generate_scene(seed + 1, split=split, config=SMALL)
    assert not np.array_equal(a.capture.frames["cam00"], other.capture.frames["cam00"])


def test_split_changes_the_scene():
    a, b = scene(3, "train"), scene(3, "test")
    assert not set(a.textures) & set(b.textures)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_warping_next_frame_by_gt_flow_reproduces_frame_where_visible(seed):
    sc = scene(seed)
    errors, still, shifted = [], [], []
    for name in sc.capture.camera_names:
        video = sc.capture.frames[name].astype(np.float64) / 255.0
        for t in range(video.shape[0] - 1):
            flow = sc.flow[name][t]
            valid = sc.flow_valid[name][t]
            warped = backward_warp(video[t + 1], flow)
            errors.append(np.abs(warped - video[t]).mean(-1)[valid])
            still.append(np.abs(video[t + 1] - video[t]).mean(-1)[valid])
            shifted.append(np.abs(backward_warp(video[t + 1], flow + 1.5) - video[t]).mean(-1)[valid])
    err, still, shifted = map(np.concatenate, (errors, still, shifted))
    assert err.size > 0.6 * 3 * 3 * 32 * 32            # most pixels stay visible frame to frame
    # residual error comes from texture resampling and shading of rotating objects only
    assert err.mean() < 0.012 and np.median(err) < 0.006, (err.mean(), np.median(err))
    assert err.mean() < 0.6 * shifted.mean()              # a 1.5 px wrong flow is clearly worse
    assert err.mean() <= still.mean()


def test_flow_valid_marks_occlusions_consistently():
    """Where valid, the moved point lands on the same object id in frame t+1."""
    for seed in range(3):
        sc = scene(seed)
        for name in sc.capture.camera_names:
            ids = sc.object_ids[name]
            for t in range(ids.shape[0] - 1):
                valid = sc.flow_valid[name][t]
                flow = sc.flow[name][t]
                v, u = np.nonzero(valid)
                x = np.rint(u + flow[v, u, 0]).astype(int)
                y = np.rint(v + flow[v, u, 1]).astype(int)
                assert np.array_equal(ids[t + 1][y, x], ids[t][v, u])


@pytest.mark.parametrize("seed", [0, 4, 5])
def test_masks_cover_exactly_the_moving_objects(seed):
    sc = scene(seed)
    moving_pixels = 0
    for name in sc.capture.camera_names:
        mask, ids = sc.dynamic_mask[name], sc.object_ids[name]
        assert np.array_equal(mask, ids > 0)          # every object of a dynamic scene moves
        # geometric check: outside the mask the scene is static, so GT flow == camera-induced flow ...
        cam_flow, cam_valid = _camera_flow_np(sc, name)
        assert cam_valid.all()
        diff = np.linalg.norm(sc.flow[name] - cam_flow, axis=-1)
        static = ~mask[:-1]
        assert diff[static].max() < 0.05
        # ... and inside it the pixels move on their own (beyond what the camera explains)
        inside = mask[:-1]
        if inside.sum() > 20:
            assert np.mean(diff[inside] > 0.01) > 0.9
        moving_pixels += inside.sum()
    assert moving_pixels > 0


def test_static_scene_gt_flow_equals_camera_flow():
    for seed in (0, 1):
        sc = scene(seed, config=SMALL_STATIC)
        assert all(o["motion"] == "static" for o in sc.objects)
        for name in sc.capture.camera_names:
            assert not sc.dynamic_mask[name].any()
            flow, valid = _camera_flow_np(sc, name)
            assert valid.all()
            assert np.abs(flow - sc.flow[name]).max() < 0.05
            assert np.abs(sc.flow[name]).max() > 0.05      # the cameras do move


def test_fixed_cameras_static_scene_has_zero_flow():
    cfg = SynthConfig(num_cameras=2, num_frames=3, height=24, width=24, static=True, camera_motion=False)
    sc = generate_scene(9, config=cfg)
    for name in sc.capture.camera_names:
        assert np.abs(sc.flow[name]).max() < 1e-6
        assert np.array_equal(sc.capture.frames[name][0], sc.capture.frames[name][1])
        assert sc.flow_valid[name].all()


def test_nonsquare_and_other_sizes():
    cfg = SynthConfig(num_cameras=2, num_frames=2, height=20, width=36, num_objects=(1, 1), fps=12.0)
    sc = generate_scene(1, split="test", config=cfg)
    assert sc.capture.frames["cam01"].shape == (2, 20, 36, 3)
    assert sc.flow["cam01"].shape == (1, 20, 36, 2)
    assert len(sc.objects) == 1


@pytest.mark.parametrize("kwargs", [
    {"num_cameras": 0}, {"num_frames": 1}, {"height": 1}, {"width": 10**6}, {"num_objects": (3, 2)},
    {"num_objects": (-1, 2)}, {"fps": 0.0}, {"fps": float("nan")}, {"num_cameras": True},
])
def test_bad_config_is_rejected(kwargs):
    with pytest.raises(SynthError):
        SynthConfig(**kwargs)


@pytest.mark.parametrize("seed, split", [(-1, "train"), (1.5, "train"), (0, "val"), (True, "train")])
def test_bad_seed_or_split_is_rejected(seed, split):
    with pytest.raises(Vt4dError):
        generate_scene(seed, split=split, config=SMALL)
