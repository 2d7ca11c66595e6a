"""vt4dcodec.reference: the renderer's depth reference point, and the world-origin check before encoding."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vt4dcodec import reference
from vt4dcodec.cameras import Trajectory, look_at
from vt4dcodec.errors import FormatError

UP = np.array([0.0, 0.0, 1.0])
K = np.array([[50.0, 0.0, 31.5], [0.0, 50.0, 31.5], [0.0, 0.0, 1.0]])


def camera(eye, target, frames: int = 4) -> Trajectory:
    w2c = np.repeat(look_at(np.asarray(eye, float), np.asarray(target, float), UP)[None], frames, axis=0)
    return Trajectory(K=np.repeat(K[None], frames, axis=0), w2c=w2c, width=64, height=64)


def depth_of(point, trajectory: Trajectory) -> np.ndarray:
    """z of a world point in each frame of the trajectory."""
    w2c = np.asarray(trajectory.w2c, float)
    return w2c[:, 2, :3] @ np.asarray(point, float) + w2c[:, 2, 3]


def test_an_origin_in_front_of_every_camera_stays():
    ring = [camera([4 * np.cos(a), 4 * np.sin(a), 1.5], [0, 0, 0.4]) for a in (0.0, 2.0, 4.0)]
    assert not reference.needs_reference(ring)


@pytest.mark.parametrize("eye", [[0.0, 0.0, 0.0], [0.2, 0.0, 0.1]])
def test_an_origin_at_or_beside_a_camera_is_moved(eye):
    assert reference.needs_reference([camera(eye, [4.0, 0.0, 0.0])])


def test_an_origin_behind_a_camera_is_moved():
    assert reference.needs_reference([camera([3.0, 0.0, 1.0], [6.0, 0.0, 1.0])])


def test_converging_cameras_give_the_point_they_look_at():
    target = np.array([1.0, -2.0, 0.5])
    ring = [camera(target + [3 * np.cos(a), 3 * np.sin(a), 1.0], target) for a in (0.3, 1.9, 3.5, 5.0)]
    np.testing.assert_allclose(reference.reference_point(ring), target, atol=1e-9)


def test_one_camera_gives_the_point_the_default_depth_ahead():
    cam = camera([1.0, 1.0, 1.0], [5.0, 1.0, 1.0])
    point = reference.reference_point([cam])
    np.testing.assert_allclose(point, [1.0 + reference.DEFAULT_REFERENCE_DEPTH, 1.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(depth_of(point, cam), reference.DEFAULT_REFERENCE_DEPTH, atol=1e-9)


def test_cameras_that_diverge_fall_back_to_the_default_depth():
    """Axes that meet behind a camera give no reference there: the default point ahead of the first camera."""
    a = camera([0.0, 0.0, 1.0], [-3.0, -3.0, 1.0])
    b = camera([1.0, 0.0, 1.0], [4.0, -3.0, 1.0])
    point = reference.reference_point([a, b])
    np.testing.assert_allclose(depth_of(point, a), reference.DEFAULT_REFERENCE_DEPTH, atol=1e-9)


def test_metadata_round_trip_in_millimetres():
    point = np.array([0.1384, -0.0543, 4.8639])
    stored = reference.centre_to_metadata(point)
    assert stored == [138, -54, 4864] and all(type(v) is int for v in stored)
    got = reference.centre_from_metadata({"vt4d": {reference.CENTRE_KEY: stored}})
    np.testing.assert_allclose(got, [0.138, -0.054, 4.864])
    assert reference.centre_from_metadata({"vt4d": {"source_camera": "cam00"}}) is None
    assert reference.centre_from_metadata(None) is None and reference.centre_from_metadata({}) is None


@pytest.mark.parametrize("value", [[1, 2], [1, 2, 3, 4], [1.5, 2, 3], [True, 0, 0], "1,2,3", None,
                                   [0, 0, 10 ** 9 + 1]])
def test_a_malformed_reference_point_is_a_format_error(value):
    with pytest.raises(FormatError, match="centre_mm"):
        reference.centre_from_metadata({"vt4d": {reference.CENTRE_KEY: value}})


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-5, 5), min_size=3, max_size=3), st.lists(st.floats(-5, 5), min_size=3, max_size=3),
       st.floats(0.0, 6.28), st.floats(-1.2, 1.2))
def test_moving_the_origin_keeps_every_point_where_the_camera_sees_it(point, world, yaw, pitch):
    """x_moved = x_world - point: the camera coordinates of every world point are unchanged."""
    eye = np.array([6 * np.cos(yaw), 6 * np.sin(yaw), 6 * np.sin(pitch)])
    w2c = look_at(eye, np.zeros(3), UP)
    moved = reference.move_origin(w2c, np.asarray(point))
    x = np.asarray(world)
    np.testing.assert_allclose(moved[:3, :3] @ (x - point) + moved[:3, 3], w2c[:3, :3] @ x + w2c[:3, 3], atol=1e-9)
    assert reference.move_origin(w2c, None) is w2c
    assert reference.move_origin(w2c.astype(np.float32), np.asarray(point)).dtype == np.float32


def test_an_origin_moved_to_a_point_ahead_has_that_depth_and_the_same_intrinsics():
    cam = camera([0.0, 0.0, 0.0], [4.0, 0.0, 0.0])
    moved = dataclasses.replace(cam, w2c=reference.move_origin(cam.w2c, np.array([4.0, 0.0, 0.0])))
    np.testing.assert_array_equal(moved.K, cam.K)
    np.testing.assert_allclose(moved.w2c[:, 2, 3], 4.0, atol=1e-12)


def test_model_centre_follows_the_reference_frame():
    ring = [camera([4 * np.cos(a), 4 * np.sin(a), 1.5], [0.5, 0.0, 0.4]) for a in (0.0, 2.0, 4.0)]
    assert reference.model_centre("origin", ring) is None  # the origin is in front: left alone
    moved = reference.model_centre("cameras", ring)  # always the cameras' point, to the millimetre
    np.testing.assert_allclose(moved, [0.5, 0.0, 0.4], atol=6e-4)
    assert np.all(np.abs(moved * 1000 - np.round(moved * 1000)) < 1e-9)
    at_camera = [camera([0.0, 0.0, 0.0], [4.0, 0.0, 0.0])]
    np.testing.assert_allclose(reference.model_centre("origin", at_camera), [4.0, 0.0, 0.0])
    w2c = np.stack([np.asarray(t.w2c) for t in ring])  # arrays (V, T, 4, 4) as the training data has them
    np.testing.assert_array_equal(reference.model_centre("cameras", w2c), moved)
    with pytest.raises(ValueError, match="reference_frame"):
        reference.model_centre("floor", ring)
