"""True 2-D tracks are exact: one frame on they are the generator's exact flow, and visible exactly where
the flow is valid; the scene setup is what the generator renders; bad queries raise SynthError."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from vt4dcodec.errors import Vt4dError
from vt4dcodec.synth import SynthConfig, SynthError, generate_scene, scene_setup, true_tracks
from vt4dcodec.synth.tracks import setup_of, surface_ids

from .helpers import SMALL, SMALL_STATIC, scene


def _all_pixel_tracks(sc, name: str, t0: int, setup=None, surfaces=None):
    T, H, W = sc.capture.depth[name].shape
    v, u = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    q = np.stack([u.ravel(), v.ravel(), np.full(H * W, t0)], -1)
    xy, vis = true_tracks(sc, name, q, setup=setup, surfaces=surfaces)
    return q, xy, vis


def _check_against_flow(sc) -> None:
    setup = setup_of(sc)
    for name in sc.capture.camera_names:
        T, H, W = sc.capture.depth[name].shape
        surf = surface_ids(setup, name, sc.capture.depth[name], sc.object_ids[name])
        for t0 in range(T - 1):
            q, xy, vis = _all_pixel_tracks(sc, name, t0, setup, surf)
            flow = sc.flow[name][t0].reshape(-1, 2)
            valid = sc.flow_valid[name][t0].reshape(-1)
            assert np.array_equal(vis[:, t0 + 1], valid)
            assert np.abs(xy[valid, t0 + 1] - q[valid, :2] - flow[valid]).max(initial=0.0) < 1e-3
            assert np.array_equal(xy[:, t0], q[:, :2]) and vis[:, t0].all()


def test_one_frame_on_the_tracks_are_the_exact_flow():
    _check_against_flow(scene(3, "test", SynthConfig(num_cameras=2, num_frames=4, height=40, width=48)))


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10_000), split=st.sampled_from(["train", "test"]),
       size=st.tuples(st.integers(6, 24), st.integers(6, 24)), frames=st.integers(2, 4),
       static=st.booleans(), camera_motion=st.booleans())
def test_tracks_equal_flow_property(seed, split, size, frames, static, camera_motion):
    config = SynthConfig(num_cameras=1, num_frames=frames, height=size[0], width=size[1], static=static,
                         camera_motion=camera_motion)
    _check_against_flow(generate_scene(seed, split=split, config=config))


def test_still_camera_static_background_does_not_move():
    sc = scene(5, "train", SynthConfig(num_cameras=1, num_frames=5, height=24, width=24, camera_motion=False))
    q, xy, vis = _all_pixel_tracks(sc, "cam00", 2)
    background = sc.object_ids["cam00"][2].reshape(-1) == 0
    assert background.any()
    assert np.abs(xy[background] - q[background, None, :2]).max() < 1e-4
    # and nothing moves in a static scene under a still camera
    sc = scene(5, "train", SynthConfig(num_cameras=1, num_frames=3, height=24, width=24, camera_motion=False,
                                       static=True))
    q, xy, vis = _all_pixel_tracks(sc, "cam00", 0)
    assert np.abs(xy - q[:, None, :2]).max() < 1e-4 and vis.all()


def test_moving_objects_carry_their_points_over_several_frames():
    """A tracked object point stays on its object wherever it is visible (its surface id there)."""
    sc = scene(1, "train", SynthConfig(num_cameras=2, num_frames=6, height=48, width=48))
    setup = setup_of(sc)
    checked = 0
    for name in sc.capture.camera_names:
        ids = sc.object_ids[name]
        t0 = 0
        v, u = np.nonzero(ids[t0] > 0)
        if not len(u):
            continue
        q = np.stack([u, v, np.zeros_like(u)], -1)
        xy, vis = true_tracks(sc, name, q, setup=setup)
        for t in range(1, ids.shape[0]):
            rows = np.flatnonzero(vis[:, t])
            px = np.rint(xy[rows, t]).astype(int)
            on = ids[t, px[:, 1], px[:, 0]] == ids[t0, v[rows], u[rows]]
            assert on.mean() > 0.97     # nearest pixel: object borders may round onto a neighbour
            checked += len(rows)
    assert checked > 50


def test_scene_setup_is_what_the_generator_renders():
    config = SynthConfig(num_cameras=2, num_frames=3, height=16, width=16)
    sc = generate_scene(9, split="test", config=config)
    setup = scene_setup(9, split="test", config=config)
    assert sorted(setup.cameras) == sc.capture.camera_names
    for name, traj in setup.cameras.items():
        assert np.array_equal(traj.K, sc.capture.cameras[name].K)
        assert np.array_equal(traj.w2c, sc.capture.cameras[name].w2c)
    assert len(setup.layout.objects) == len(sc.objects)
    assert [o.shape for o in setup.layout.objects] == [o["shape"] for o in sc.objects]
    assert np.array_equal(setup.times, np.arange(3) / config.fps)
    assert setup_of(sc).layout.room_half == setup.layout.room_half


@pytest.mark.parametrize("queries, match", [
    (np.zeros((3, 2), np.int64), "shape"),
    (np.zeros(3, np.int64), "shape"),
    (np.array([[1.5, 2, 0]]), "integer"),
    (np.array([[np.nan, 2, 0]]), "integer"),
    (np.array([["a", "b", "c"]]), "integer"),
    (np.array([[32, 0, 0]]), "outside"),
    (np.array([[0, -1, 0]]), "outside"),
    (np.array([[0, 0, 4]]), "outside"),
])
def test_bad_queries_raise_synth_error(queries, match):
    sc = scene(0, "train", SMALL)
    with pytest.raises(SynthError, match=match) as info:
        true_tracks(sc, "cam00", queries)
    assert isinstance(info.value, Vt4dError) and isinstance(info.value, ValueError)


def test_unknown_camera_and_missing_config_raise_synth_error():
    sc = scene(0, "train", SMALL_STATIC)
    with pytest.raises(SynthError, match="camera"):
        true_tracks(sc, "cam99", [[0, 0, 0]])
    xy, vis = true_tracks(sc, "cam01", [[3, 4, 1]])        # float-valued integers and lists are fine
    assert xy.shape == (1, 4, 2) and vis.shape == (1, 4) and xy[0, 1].tolist() == [3.0, 4.0]
    stripped = generate_scene(0, config=SynthConfig(num_cameras=1, num_frames=2, height=8, width=8))
    stripped.capture.metadata = {}
    with pytest.raises(SynthError, match="config"):
        true_tracks(stripped, "cam00", [[0, 0, 0]])
