"""Target trajectory presets, spec parsing and the trajectory JSON file."""

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vt4dcodec.cameras import Trajectory, look_at
from vt4dcodec.capture.trajectories import (
    PRESETS, load_trajectory, make_trajectory, parse_trajectory_spec, save_trajectory,
    slerp_rotation,
)
from vt4dcodec.errors import CameraError, TrajectoryError

finite = dict(allow_nan=False, allow_infinity=False)


def reference(seed=0, T=6):
    """A camera at a random position looking at a random point (w2c from look_at)."""
    rng = np.random.default_rng(seed)
    center = rng.uniform(-3, 3, 3)
    target = center + rng.normal(size=3)
    w2c = look_at(center, target, up=np.array([0.0, -1.0, 0.1]))
    K = np.array([[60.0, 0, 31.5], [0, 62.0, 23.5], [0, 0, 1]])
    return Trajectory(K=np.stack([K] * T), w2c=np.stack([w2c] * T), width=64, height=48,
                      timestamps=np.arange(T) / 8.0)


def pixel_of(traj, i, X):
    x = traj.w2c[i, :3, :3] @ X + traj.w2c[i, :3, 3]
    p = traj.K[i] @ x
    return p[:2] / p[2], x[2]


def forward(traj, i):
    return traj.w2c[i, 2, :3]  # camera z axis in world coordinates


@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("T", [1, 2, 7])
def test_every_preset_gives_valid_rotations_and_length(preset, T):
    ref = reference(1)
    kw = {"target": make_trajectory("orbit", ref, num_frames=2, degrees=60)[1]} if preset == "interpolate" else {}
    traj = make_trajectory(preset, ref, num_frames=T, **kw)
    assert traj.num_frames == T and (traj.width, traj.height) == (ref.width, ref.height)
    R = traj.w2c[:, :3, :3]
    np.testing.assert_allclose(np.swapaxes(R, 1, 2) @ R, np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(traj.w2c[0], ref.w2c[0], atol=1e-9)  # every preset starts at the reference
    assert traj.distortion is None


def test_default_length_and_timestamps_follow_reference():
    ref = reference()
    traj = make_trajectory("pan", ref)
    assert traj.num_frames == ref.num_frames
    np.testing.assert_array_equal(traj.timestamps, ref.timestamps)
    assert make_trajectory("pan", ref, num_frames=3).timestamps is None


@given(seed=st.integers(0, 10_000), degrees=st.floats(-170, 170, **finite), distance=st.floats(0.2, 10, **finite))
@settings(max_examples=30)
def test_orbit_keeps_look_at_point_fixed_in_the_image(seed, degrees, distance):
    ref = reference(seed)
    traj = make_trajectory("orbit", ref, num_frames=5, degrees=degrees, distance=distance)
    pivot = ref.centers[0] + distance * forward(ref, 0)
    for i in range(5):
        uv, z = pixel_of(traj, i, pivot)
        np.testing.assert_allclose(uv, ref.K[0, :2, 2], atol=1e-7)
        assert z == pytest.approx(distance)
    # the camera travelled along a circle: chord = 2 d sin(angle / 2)
    chord = np.linalg.norm(traj.centers[-1] - traj.centers[0])
    assert chord == pytest.approx(2 * distance * abs(math.sin(math.radians(degrees) / 2)), abs=1e-9)


def test_orbit_positive_degrees_moves_right():
    ref = reference(3)
    traj = make_trajectory("orbit", ref, num_frames=2, degrees=10)
    move = traj.centers[1] - traj.centers[0]
    assert move @ ref.w2c[0, 0, :3] > 0  # along the camera's +x (right)


@pytest.mark.parametrize("preset, sign", [("dolly_in", 1.0), ("dolly_out", -1.0)])
def test_dolly_moves_along_the_optical_axis(preset, sign):
    ref = reference(2)
    traj = make_trajectory(preset, ref, num_frames=4, metres=0.9)
    np.testing.assert_allclose(traj.centers[-1] - traj.centers[0], sign * 0.9 * forward(ref, 0), atol=1e-12)
    np.testing.assert_allclose(traj.w2c[:, :3, :3], np.broadcast_to(ref.w2c[0, :3, :3], (4, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(np.diff(traj.centers, axis=0), axis=1), 0.3, atol=1e-12)


@pytest.mark.parametrize("preset, axis_row, sign", [("pan", 0, 1.0), ("tilt", 1, -1.0)])
def test_pan_and_tilt_rotate_about_the_centre(preset, axis_row, sign):
    """pan +deg turns right (forward gains +x), tilt +deg looks up (forward gains -y)."""
    ref = reference(4)
    traj = make_trajectory(preset, ref, num_frames=3, degrees=40)
    np.testing.assert_allclose(traj.centers, np.broadcast_to(ref.centers[0], (3, 3)), atol=1e-12)
    f = forward(traj, 2)
    assert math.degrees(math.acos(np.clip(f @ forward(ref, 0), -1, 1))) == pytest.approx(40)
    assert sign * (f @ ref.w2c[0, axis_row, :3]) > 0


def test_crane_moves_up_and_keeps_looking_at_the_point():
    ref = reference(5)
    traj = make_trajectory("crane", ref, num_frames=4, metres=1.2, distance=3.0)
    look = ref.centers[0] + 3.0 * forward(ref, 0)
    up = -ref.w2c[0, 1, :3]
    np.testing.assert_allclose(traj.centers[-1] - traj.centers[0], 1.2 * up, atol=1e-12)
    for i in range(4):
        uv, _ = pixel_of(traj, i, look)
        np.testing.assert_allclose(uv, ref.K[0, :2, 2], atol=1e-7)


@given(seed=st.integers(0, 10_000))
@settings(max_examples=20)
def test_interpolate_hits_both_ends_and_moves_smoothly(seed):
    ref, other = reference(seed), reference(seed + 1)
    K1 = other.K[0].copy()
    K1[0, 0] = 90.0
    target = Trajectory(K=K1, w2c=other.w2c[0], width=64, height=48)
    traj = make_trajectory("interpolate", ref, num_frames=9, target=target)
    np.testing.assert_allclose(traj.w2c[-1], other.w2c[0], atol=1e-9)
    np.testing.assert_allclose(traj.K[-1], K1)
    np.testing.assert_allclose(traj.K[4, 0, 0], (60 + 90) / 2)
    steps = np.linalg.norm(np.diff(traj.centers, axis=0), axis=1)
    np.testing.assert_allclose(steps, steps[0], atol=1e-9)  # centre moves linearly
    # rotation steps are equal angles (SLERP)
    R = traj.w2c[:, :3, :3]
    angles = [np.arccos(np.clip((np.trace(R[i + 1] @ R[i].T) - 1) / 2, -1, 1)) for i in range(8)]
    np.testing.assert_allclose(angles, angles[0], atol=1e-6)
    # a bare 4x4 pose works as the target too
    np.testing.assert_allclose(make_trajectory("interpolate", ref, num_frames=2, target=other.w2c[0]).w2c[-1],
                               other.w2c[0], atol=1e-9)


def test_slerp_takes_the_short_way():
    R0 = np.eye(3)
    R1 = look_at(np.zeros(3), np.array([1.0, 0, 0.2]), np.array([0, -1.0, 0]))[:3, :3]
    mid = slerp_rotation(R0, R1, 0.5)
    a01 = np.arccos((np.trace(R1 @ R0.T) - 1) / 2)
    a0m = np.arccos((np.trace(mid @ R0.T) - 1) / 2)
    assert a0m == pytest.approx(a01 / 2)


@pytest.mark.parametrize("call", [
    lambda r: make_trajectory("zoom", r),
    lambda r: make_trajectory("orbit", r, radius=3),
    lambda r: make_trajectory("orbit", r, distance=-1),
    lambda r: make_trajectory("orbit", r, degrees=float("nan")),
    lambda r: make_trajectory("pan", r, degrees="ten"),
    lambda r: make_trajectory("pan", r, num_frames=0),
    lambda r: make_trajectory("pan", r, num_frames=2.5),
    lambda r: make_trajectory("pan", r, target=r),
    lambda r: make_trajectory("interpolate", r),
    lambda r: make_trajectory("interpolate", r, target=np.eye(3)),
    lambda r: make_trajectory("interpolate", r, target=Trajectory(K=r.K[0], w2c=r.w2c[0], width=10, height=10)),
])
def test_bad_presets_raise_trajectory_error(call):
    with pytest.raises(TrajectoryError):
        call(reference())


def test_parse_trajectory_spec():
    assert parse_trajectory_spec("orbit:degrees=30,distance=2") == ("orbit", {"degrees": 30, "distance": 2})
    assert parse_trajectory_spec(" static ") == ("static", {})
    assert parse_trajectory_spec("dolly_in:metres=0.25,num_frames=8") == ("dolly_in", {"metres": 0.25, "num_frames": 8})
    preset, params = parse_trajectory_spec("tilt:degrees=-1e1")
    assert make_trajectory(preset, reference(), **params).num_frames == 6
    for bad in ["", "zoom", "orbit:degrees", "orbit:degrees=abc", "orbit:radius=2", "orbit:degrees=1,degrees=2",
                "pan:degrees=inf", "orbit:=3"]:
        with pytest.raises(TrajectoryError):
            parse_trajectory_spec(bad)


@given(seed=st.integers(0, 10_000), preset=st.sampled_from([p for p in PRESETS if p != "interpolate"]),
       T=st.integers(1, 6), with_ts=st.booleans(), with_dist=st.booleans())
@settings(max_examples=25)
def test_save_load_round_trip(tmp_path_factory, seed, preset, T, with_ts, with_dist):
    traj = make_trajectory(preset, reference(seed, T=T))
    traj = Trajectory(K=traj.K, w2c=traj.w2c, width=traj.width, height=traj.height,
                      timestamps=traj.timestamps if with_ts else None,
                      distortion=np.array([0.1, -0.01, 0.001, 0.002]) if with_dist else None)
    path = tmp_path_factory.mktemp("traj") / "t.json"
    save_trajectory(traj, path)
    assert load_trajectory(path).equals(traj)  # exact: JSON floats round-trip


@pytest.mark.parametrize("change", [
    lambda d: d.update(format="x"),
    lambda d: d.update(version=9),
    lambda d: d.update(num_frames=0),
    lambda d: d.update(num_frames=2),
    lambda d: d["w2c"][0].__setitem__(0, [2.0, 0, 0, 0]),
    lambda d: d["K"][0].__setitem__(0, [float("nan"), 0, 0]),
    lambda d: d.update(width=-3),
    lambda d: d.update(K="no"),
    lambda d: d.update(distortion=[1.0]),
])
def test_bad_trajectory_files(tmp_path, change):
    path = tmp_path / "t.json"
    save_trajectory(reference(T=3), path)
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))
    with pytest.raises(TrajectoryError):
        load_trajectory(path)
    assert issubclass(TrajectoryError, CameraError)


def test_trajectory_file_not_json(tmp_path):
    path = tmp_path / "t.json"
    path.write_text("{not json")
    with pytest.raises(TrajectoryError, match="JSON"):
        load_trajectory(path)


@given(value=st.recursive(
    st.none() | st.booleans() | st.integers(-10**20, 10**20) | st.floats() | st.text(max_size=4),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=4), inner, max_size=3),
    max_leaves=8), key=st.sampled_from(["format", "version", "width", "height", "num_frames", "K", "w2c",
                                        "distortion", "timestamps"]))
@settings(max_examples=60)
def test_fuzzed_trajectory_documents_fail_cleanly(value, key):
    from vt4dcodec.capture.trajectories import trajectory_from_json, trajectory_to_json

    doc = trajectory_to_json(reference(T=2))
    doc[key] = value
    try:
        trajectory_from_json(doc)
    except TrajectoryError:
        pass
