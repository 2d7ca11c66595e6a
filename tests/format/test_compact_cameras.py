"""Issue 13, item 2: compact cameras (FORMAT.md I.5.1, format 1.2, required flag bit 1).  Sizes and the
reprojection bound on real trajectories are measured by bench/bench_compact_cameras.py; here: versions and
flags, the 0.01 px rule and its float64 fallback, exact round trips on request, old readers refusing, and
no crash on any damage."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from format_strategies import load_vector_tool, simple_scene, trajectories
from vt4dcodec.cameras import Trajectory
from vt4dcodec.errors import FormatError, MalformedSectionError, UnsupportedFeatureError
from vt4dcodec.format import Scene, dumps, layout, loads, open_scene
from vt4dcodec.format.header import CameraLayout
from vt4dcodec.format.compact_cameras import (REPROJECTION_TOLERANCE_PX, pack_compact_cameras, reprojection_change,
                                              unpack_compact_cameras)
from vt4dcodec.format.sections import pack_cameras

mv = load_vector_tool()


def with_cameras(traj: Trajectory, encoding: str = "int8") -> Scene:
    base = simple_scene(ns=3, nd=2, d=4)
    return Scene(base.static_tokens, base.dynamic_tokens, traj, base.fingerprint, encoding=encoding)


def moving(frames=8, *, scale=1.0, size=64) -> Trajectory:
    """A smooth 8-frame orbit like the synthetic captures' (64x64, timestamps), translations x ``scale``."""
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    for i in range(frames):
        a = 0.03 * i
        w2c[i, :3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
        w2c[i, :3, 3] = np.array([0.17 + 0.003 * i, 0.69 - 0.002 * i, 4.38 - 0.026 * i]) * scale
    K = np.array([[79.75153014, 0, size / 2 - 0.5], [0, 79.75153014, size / 2 - 0.5], [0, 0, 1]])
    return Trajectory(np.tile(K, (frames, 1, 1)), w2c, size, size, timestamps=np.arange(frames) / 8.0)


@pytest.mark.parametrize("encoding,flags", [("int8", 2), ("float16", 2), ("int4-rans", 3)])
def test_compact_files_say_1_2_with_flag_bit_1(encoding, flags):
    f = open_scene(dumps(with_cameras(moving(), encoding), header="legacy"))
    assert f.version == (1, 2) and f.preamble.required_flags == flags and f.compact_cameras
    assert f.camera_encoding() == "compact-float32"
    default = open_scene(dumps(with_cameras(moving(), encoding)))  # the compact container of 1.3
    assert default.version == (1, 3) and default.preamble.required_flags == flags | 4 and default.compact_cameras
    assert default.camera_encoding() == "compact-float32-quaternion"
    legacy = open_scene(dumps(with_cameras(moving(), encoding), cameras="legacy", header="legacy"))
    assert legacy.version == (1, flags & 1) and not legacy.compact_cameras and legacy.camera_encoding() == "float64"


def test_compact_cameras_are_smaller_and_within_a_hundredth_of_a_pixel():
    scene = with_cameras(moving())
    sizes = {mode: open_scene(dumps(scene, cameras=mode)).sections[0].stored_length
             for mode in ("legacy", "exact", "compact")}
    assert sizes["compact"] < 0.6 * sizes["legacy"], sizes  # float64 ("exact") may not win: only float32 drops bits
    back = loads(dumps(scene)).cameras
    assert 0 < reprojection_change(scene.cameras, back) <= REPROJECTION_TOLERANCE_PX
    assert np.array_equal(back.timestamps, scene.cameras.timestamps)


def test_exact_mode_reads_back_bit_for_bit():
    scene = with_cameras(moving())
    assert loads(dumps(scene, cameras="exact")).cameras.equals(scene.cameras)
    assert open_scene(dumps(scene, cameras="exact")).camera_encoding() == "compact-float64"


def test_float32_that_would_move_pixels_falls_back_to_float64():
    """Regression guard: 10 km translations lose ~0.5 mm in float32, which moves a point 0.1 m away by more
    than 0.01 px: the writer must keep float64 there."""
    far = moving(scale=2500.0)
    f32 = unpack_compact_cameras(_f32(far), mv_layout(far))
    assert reprojection_change(far, f32) > REPROJECTION_TOLERANCE_PX
    f = open_scene(dumps(with_cameras(far)))
    assert f.camera_encoding() == "compact-float64" and f.cameras.equals(far)


def _f32(traj: Trajectory) -> bytes:
    from vt4dcodec.format.compact_cameras import _encode
    return _encode(traj, 4)


def mv_layout(traj: Trajectory):
    return pack_cameras(traj)[0]


def test_constant_intrinsics_and_static_pose_are_stored_once():
    static = Trajectory(np.tile(moving().K[:1], (8, 1, 1)), np.tile(moving().w2c[:1], (8, 1, 1)), 64, 64)
    raw = pack_compact_cameras(static, "exact")
    assert raw[:2] == bytes([8, 3]) and len(raw) == 2 + 8 * (5 + 12)
    assert unpack_compact_cameras(raw, mv_layout(static)).equals(static)
    zoom = Trajectory(moving().K * np.array([1, 1, 1.0]), moving().w2c, 64, 64)
    zoom.K[:, 0, 0] += np.arange(8)
    assert pack_compact_cameras(zoom, "exact")[1] == 0


@settings(max_examples=40, deadline=None)
@given(trajectories(), st.sampled_from(["compact", "exact"]))
def test_any_trajectory_round_trips_within_the_bound(traj, mode):
    back = loads(dumps(with_cameras(traj), cameras=mode)).cameras
    if mode == "exact":
        assert back.equals(traj)
    else:
        assert reprojection_change(traj, back) <= REPROJECTION_TOLERANCE_PX
    for a, b in ((traj.distortion, back.distortion), (traj.timestamps, back.timestamps)):
        assert (a is None and b is None) or np.array_equal(a, b)


def test_a_1_1_reader_refuses_compact_cameras_by_the_required_flag(monkeypatch):
    data = dumps(with_cameras(moving()), header="legacy")
    monkeypatch.setattr(layout, "KNOWN_REQUIRED_FLAGS", layout.FLAG_ENTROPY_CODED_TOKENS)
    with pytest.raises(UnsupportedFeatureError, match="upgrade"):
        loads(data)
    loads(dumps(with_cameras(moving()), cameras="legacy", header="legacy"))


def test_unknown_camera_mode_is_a_typed_error():
    with pytest.raises(FormatError, match="cameras"):
        dumps(with_cameras(moving()), cameras="float16")
    with pytest.raises(FormatError):
        pack_compact_cameras(moving(), "legacy")


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_any_cameras_payload_is_read_or_refused_with_a_typed_error(data):
    """Random bytes, random lengths and single-byte edits of a real payload, CRCs fixed so the decoder itself
    is exercised: a trajectory or a FormatError, never anything else."""
    header, sections = mv.split(dumps(with_cameras(moving(frames=3)), compression_level=None))
    cams = mv.find(sections, "CAMS")
    payload = bytearray(cams[3])
    how = data.draw(st.sampled_from(["flip", "random", "cut"]))
    if how == "flip":
        i = data.draw(st.integers(0, len(payload) - 1))
        payload[i] ^= data.draw(st.integers(1, 255))
    elif how == "random":
        payload = bytearray(data.draw(st.binary(min_size=0, max_size=len(payload) + 8)))
    else:
        payload = payload[:data.draw(st.integers(0, len(payload) - 1))]
    cams[3], cams[4] = bytes(payload), len(payload)
    try:
        loads(mv.rebuild(header, sections, minor=2, required_flags=layout.FLAG_COMPACT_CAMERAS))
    except FormatError:
        pass


def test_hostile_width_byte_is_refused_before_anything_is_allocated():
    header, sections = mv.split(dumps(with_cameras(moving(frames=3)), compression_level=None))
    cams = mv.find(sections, "CAMS")
    cams[3] = bytes([255]) + cams[3][1:]
    with pytest.raises(MalformedSectionError, match="precision"):
        loads(mv.rebuild(header, sections))


def _one_frame(K: list, w2c: list) -> Trajectory:
    return Trajectory(np.array([K], dtype=np.float64), np.array([w2c], dtype=np.float64), 1, 1)


# Regression: cameras where one float32 ulp of rotation moves a probe point about the 0.01 px tolerance
# (fy ~ 1,500-2,300 px, |t| 20-50 m, probes at 0.1 m).  The writer used to decide again from the decoded
# trajectory and choose differently: float32 matrices re-saved as float64 (the probe metric lifted points
# with R^T, so a float32 camera "moved" against itself), or as quaternions (the decoded rotation passed where
# the original had not); a loaded float32 scene then saved to other bytes (file length + 64).
SENSITIVE = [
    ([[2.311974851933834, 0.0, -0.44621759190925836], [0.0, 1669.5578810875593, -0.6786959824497463],
      [0.0, 0.0, 1.0]],
     [[1.0, 0.0, 0.0, 39.766861045437324], [0.0, -0.9485916724113482, -0.31650251030890963, -20.88052031541904],
      [0.0, 0.31650251030890963, -0.9485916724113482, -7.090325367154192], [0.0, 0.0, 0.0, 1.0]]),
    ([[1.429636424675265, 0.0, -0.7447586270078608], [0.0, 1483.5146163483134, -0.5549862681074551],
      [0.0, 0.0, 1.0]],
     [[0.9358016795238137, -0.312646458300236, -0.1628723693961875, 47.87584701651077],
      [0.2958967996287892, 0.9477554659136762, -0.11918330755684979, -25.235130749875736],
      [0.19162541733770494, 0.0633385265306134, 0.9794222432062084, 8.835738359885164], [0.0, 0.0, 0.0, 1.0]]),
]


@pytest.mark.parametrize("K,w2c", SENSITIVE)
@pytest.mark.parametrize("quaternions", [False, True])
def test_compact_cameras_are_a_fixed_point_on_ulp_sensitive_cameras(K, w2c, quaternions):
    traj = _one_frame(K, w2c)
    raw = pack_compact_cameras(traj, quaternions=quaternions)
    back = unpack_compact_cameras(raw, CameraLayout(1, 1, 1, 0, False), quaternions=quaternions)
    assert reprojection_change(traj, back) <= REPROJECTION_TOLERANCE_PX
    assert pack_compact_cameras(back, quaternions=quaternions) == raw
    scene = with_cameras(traj, encoding="float32")
    data = dumps(scene, cameras="compact")
    assert dumps(loads(data), cameras="compact") == data


def test_a_camera_does_not_move_against_itself():
    """The probe metric inverts the stored pose exactly: zero (to rounding) for a float32 rotation that is
    orthonormal only to ~1e-7, where R^T as the inverse gave several hundredths of a pixel."""
    traj = _one_frame(*SENSITIVE[0])
    r32 = Trajectory(traj.K, traj.w2c.astype(np.float32).astype(np.float64), 1, 1)
    assert reprojection_change(r32, r32) < 1e-6


@settings(max_examples=150, deadline=None)
@given(st.floats(0.5, 3.0), st.floats(100.0, 3000.0), st.floats(-3.0, 3.0),
       st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda v: np.linalg.norm(v) > 0.1),
       st.tuples(*[st.floats(-50.0, 50.0)] * 3), st.booleans())
def test_compact_cameras_of_any_steep_camera_are_a_fixed_point(fx, fy, angle, axis, t, quaternions):
    axis = np.array(axis) / np.linalg.norm(axis)
    A = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + np.sin(angle) * A + (1 - np.cos(angle)) * A @ A  # Rodrigues
    w2c = np.eye(4)
    w2c[:3, :3], w2c[:3, 3] = R, t
    traj = _one_frame([[fx, 0, 0], [0, fy, 0], [0, 0, 1]], w2c.tolist())
    raw = pack_compact_cameras(traj, quaternions=quaternions)
    back = unpack_compact_cameras(raw, CameraLayout(1, 1, 1, 0, False), quaternions=quaternions)
    assert pack_compact_cameras(back, quaternions=quaternions) == raw


@settings(max_examples=120, deadline=None)
@given(trajectories(), st.integers(0, 2**32 - 1), st.sampled_from(["compact", "exact"]), st.integers(0, 6))
def test_compiled_camera_check_decides_as_the_trajectory_checks(traj, seed, mode, flips):
    """A decoded trajectory that the compiled check (compact_cameras._native_valid) passes is the one the
    Trajectory constructor builds from the same arrays, and damage it does not pass gives the constructor's
    error: the same outcome, valid or not, with and without the compiled check."""
    from vt4dcodec.format import compact_cameras as cc

    assert cc._native_valid is not None
    raw = bytearray(pack_compact_cameras(traj, mode, quaternions=True))
    rng = np.random.default_rng(seed)
    for _ in range(flips):  # damage a few bytes past the precision and layout bytes
        if len(raw) > 2:
            raw[int(rng.integers(2, len(raw)))] ^= 1 << int(rng.integers(0, 8))
    layout = CameraLayout(traj.num_frames, traj.width, traj.height,
                          0 if traj.distortion is None else len(traj.distortion), traj.timestamps is not None)
    outcomes = []
    native = cc._native_valid
    for compiled in (native, None):
        cc._native_valid = compiled
        try:
            t = unpack_compact_cameras(bytes(raw), layout, quaternions=True)
            outcomes.append(("ok", t.K.tobytes(), t.w2c.tobytes(), t.width, t.height,
                             None if t.timestamps is None else t.timestamps.tobytes(),
                             None if t.distortion is None else t.distortion.tobytes(),
                             t.K.flags.c_contiguous and t.w2c.flags.c_contiguous))
        except FormatError as exc:
            outcomes.append((type(exc).__name__, str(exc)))
        finally:
            cc._native_valid = native
    assert outcomes[0] == outcomes[1]
