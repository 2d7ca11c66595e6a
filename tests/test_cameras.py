"""Trajectory: the one camera convention type (OpenCV pinhole, world-to-camera, metres, pixels)."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from vt4dcodec.cameras import Trajectory, look_at, validate_w2c
from vt4dcodec.errors import CameraError, TrajectoryError

K0 = np.array([[50.0, 0.0, 31.5], [0.0, 50.0, 31.5], [0.0, 0.0, 1.0]])


def rotation(q):
    q = np.asarray(q, float)
    q = q / np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


quats = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1)
vecs = st.lists(st.floats(-10, 10), min_size=3, max_size=3)


def pose(q, t):
    w2c = np.eye(4)
    w2c[:3, :3] = rotation(q)
    w2c[:3, 3] = t
    return w2c


@given(st.lists(st.tuples(quats, vecs), min_size=1, max_size=6))
def test_valid_poses_round_trip_centres_and_slices(poses):
    w2c = np.stack([pose(q, t) for q, t in poses])
    traj = Trajectory(K=K0, w2c=w2c, width=64, height=64)
    assert traj.num_frames == len(poses) and traj.K.shape == (len(poses), 3, 3)
    # the centre maps to the camera origin
    for i in range(len(poses)):
        c = np.append(traj.centers[i], 1.0)
        assert np.allclose((traj.w2c[i] @ c)[:3], 0.0, atol=1e-9)
    assert np.allclose(traj.c2w @ traj.w2c, np.eye(4), atol=1e-9)
    assert traj[-1:].equals(Trajectory(K=K0, w2c=w2c[-1], width=64, height=64))


@pytest.mark.parametrize("mutate, message", [
    (lambda K, w: (K * np.nan, w), "non-finite"),
    (lambda K, w: (K * np.array([[-1, 1, 1], [1, 1, 1], [1, 1, 1]]), w), "focal"),
    (lambda K, w: (K + np.array([[0, 0, 0], [0, 0, 0], [0.1, 0, 0]]), w), "upper triangular"),
    (lambda K, w: (K, w * np.array([1, 1, 1, 1.0])[:, None] * 1.01 + 0 * w), "last row|orthonormal"),
    (lambda K, w: (K, np.diag([1.0, 1.0, -1.0, 1.0])), "reflection"),
    (lambda K, w: (K, np.diag([1.1, 1.0, 1.0, 1.0])), "orthonormal"),
    (lambda K, w: (np.stack([K, K]), np.stack([w, w, w])), "frames"),
])
def test_bad_cameras_raise_camera_error(mutate, message):
    K, w2c = mutate(K0.copy(), np.eye(4))
    with pytest.raises(CameraError, match=message):
        Trajectory(K=K, w2c=w2c, width=64, height=64)


@pytest.mark.parametrize("kwargs, message", [
    (dict(width=0), "width"), (dict(height=True), "height"),
    (dict(distortion=np.zeros(3)), "distortion"), (dict(distortion=[np.inf, 0, 0, 0]), "non-finite"),
    (dict(timestamps=[0.0, 1.0]), "timestamps"), (dict(timestamps=[np.nan]), "timestamps"),
])
def test_bad_sizes_distortion_and_timestamps(kwargs, message):
    base = dict(K=K0, w2c=np.eye(4), width=64, height=64)
    with pytest.raises(CameraError, match=message):
        Trajectory(**{**base, **kwargs})


def test_look_at_puts_the_target_on_the_axis_and_up_upwards_for_one_camera_or_many():
    rng = np.random.default_rng(0)
    eye, target = rng.uniform(-3, 3, (5, 3)), rng.uniform(-1, 1, (5, 3))
    up = np.array([0.0, 0.0, 1.0])
    w2c = look_at(eye, target, up)
    for i in range(5):
        one = look_at(eye[i], target[i], up)
        np.testing.assert_array_equal(one, w2c[i])  # a batch is its cameras, one by one
        validate_w2c(one)
        cam = one[:3, :3] @ target[i] + one[:3, 3]
        np.testing.assert_allclose(cam[:2], 0.0, atol=1e-12)  # on the optical axis, in front
        assert cam[2] > 0
        assert (one[:3, :3] @ up)[1] < 0  # world up points up the image (y down)
    with pytest.raises(TrajectoryError, match="coincides"):
        look_at(eye[0], eye[0], up)
    with pytest.raises(TrajectoryError, match="parallel"):
        look_at(np.zeros(3), np.array([0.0, 0.0, 2.0]), up)


def test_huge_rotation_entries_are_refused_by_name_without_numeric_warnings():
    """Regression (fuzz campaign): entries near the float64 limit overflowed R^T R with a RuntimeWarning, and
    a NaN in the check would have compared as within the tolerance."""
    import warnings

    from vt4dcodec.cameras import validate_w2c
    from vt4dcodec.errors import CameraError

    for value in (1e200, 1e308, np.nan):
        w2c = np.eye(4)
        w2c[:3, :3] = [[value, value, 0.0], [value, -value, 0.0], [0.0, 0.0, 1.0]]
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with pytest.raises(CameraError):
                validate_w2c(w2c)
