"""Joint extra cameras (FORMAT.md I.5.5, required flag bit 9): the XCAM records of a learned-rans file coded
together as Exp-Golomb bits decode to exactly the I.5.4 records the writer chose; the writer uses the layout
only where it is shorter; damaged payloads give only library errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from format_strategies import load_vector_tool
from vt4dcodec.cameras import Trajectory
from vt4dcodec.errors import FormatError, LimitExceededError, MalformedSectionError
from vt4dcodec.format import dumps, loads, open_scene
from vt4dcodec.format.compact_cameras import quaternion_to_rotation
from vt4dcodec.format.extra_cameras import extra_camera_records, pack_extra_cameras
from vt4dcodec.format.joint_cameras import exp_golomb_bits, pack_joint_cameras, unpack_joint_cameras
from vt4dcodec.format.layout import FLAG_JOINT_CAMERAS, parse_preamble
from vt4dcodec.synth import generate_scene

mv = load_vector_tool()
TABLES = mv.learned_tables()


def smooth(rng: np.random.Generator, frames: int, f: float, size: int, *, static: bool = False) -> Trajectory:
    i = np.arange(frames)[:, None]
    q = rng.normal(size=4) + i * rng.normal(scale=0.03, size=4) + i * i * rng.normal(scale=0.002, size=4)
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    w2c[:, :3, :3] = quaternion_to_rotation(q)
    w2c[:, :3, 3] = rng.uniform(-6, 6, 3) + i * rng.normal(scale=0.05, size=3) + i * i * rng.normal(scale=0.004, size=3)
    if static:
        w2c = np.repeat(w2c[:1], frames, axis=0)
    K = np.tile(np.array([[f, 0, size / 2 - 0.5], [0, f, size / 2 - 0.5], [0, 0, 1]]), (frames, 1, 1))
    return Trajectory(K=K, w2c=w2c, width=size, height=size)


def records_of(extras: list[Trajectory]) -> list[bytes]:
    raw = pack_extra_cameras(extras, "compact", quaternions=True, fixed=True)
    return [raw[o:o + n] for o, n in extra_camera_records(raw)]


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 9), st.integers(0, 2**32 - 1), st.integers(1, 6), st.sampled_from([(40.0, 32), (900.0, 640)]))
def test_joint_layout_gives_back_the_records(frames, seed, count, lens):
    rng = np.random.default_rng(seed)
    extras = [smooth(rng, frames, lens[0] * rng.choice([1.0, 1.0, 1.7]), lens[1], static=bool(rng.integers(2)))
              for _ in range(count)]
    records = records_of(extras)
    payload = pack_joint_cameras(records, frames, lens[1], lens[1])
    assert payload is not None and payload[0] == count
    assert unpack_joint_cameras(payload, frames, lens[1], lens[1]) == records


def test_a_synthetic_rig_costs_fewer_bytes_and_reads_back_bit_for_bit():
    capture = generate_scene(1000, split="test").capture
    scene = mv.learned_scene(quality=2)
    cams = list(capture.cameras.values())
    scene.cameras, scene.extra_cameras = cams[0], tuple(cams[1:])
    joint, separate = dumps(scene, tables=TABLES), dumps(scene, tables=TABLES, joint_cameras=False)
    assert parse_preamble(joint).required_flags & FLAG_JOINT_CAMERAS
    assert not parse_preamble(separate).required_flags & FLAG_JOINT_CAMERAS
    assert len(joint) <= len(separate) - 100  # 9 moving cameras: ~140 bytes fewer (FORMAT.md I.5.5)
    a, b = loads(joint, tables=TABLES), loads(separate, tables=TABLES)
    for x, y in zip(a.extra_cameras, b.extra_cameras):
        assert np.array_equal(x.K, y.K) and np.array_equal(x.w2c, y.w2c)
    assert dumps(a, tables=TABLES) == joint  # loading and saving writes the same bytes
    f = open_scene(joint)
    assert f.num_extra_cameras == 9 and f.extra_camera(4).w2c.tobytes() == b.extra_cameras[4].w2c.tobytes()


def test_a_float_record_keeps_the_separate_layout():
    """A camera that fixed point cannot hold (its centre 2^53 steps away) keeps I.5.3, even when asked for joint."""
    rng = np.random.default_rng(0)
    far = smooth(rng, 4, 60.0, 64)
    w2c = far.w2c.copy()
    w2c[:, :3, 3] += 1e12
    scene = mv.learned_scene(quality=2)
    scene.cameras = smooth(rng, 4, 60.0, 64)
    scene.extra_cameras = (smooth(rng, 4, 60.0, 64), Trajectory(K=far.K, w2c=w2c, width=64, height=64))
    data = dumps(scene, tables=TABLES, joint_cameras=True)
    assert not parse_preamble(data).required_flags & FLAG_JOINT_CAMERAS
    xcam = bytes(open_scene(data).raw_section("XCAM"))
    assert [xcam[o] != 0 for o, _ in extra_camera_records(xcam)] == [False, True]  # fixed point, then a float record
    assert len(loads(data, tables=TABLES).extra_cameras) == 2


def test_other_files_never_use_it():
    scene = mv.scene(2, 1, 3)
    scene.extra_cameras = (smooth(np.random.default_rng(0), 1, 60.0, 64),)
    scene.cameras = smooth(np.random.default_rng(1), 1, 60.0, 64)
    for kw in ({}, {"joint_cameras": True}):  # int8: no fixed-point cameras, so no joint layout
        assert not parse_preamble(dumps(scene, encoding="int8", **kw)).required_flags & FLAG_JOINT_CAMERAS
    with pytest.raises(FormatError, match="joint_cameras"):
        dumps(scene, encoding="int8", joint_cameras=1)


def test_exp_golomb_lengths():
    assert [exp_golomb_bits(z, 0) for z in (0, 1, 2, 3, 6, 7)] == [1, 3, 3, 5, 5, 7]
    assert [exp_golomb_bits(z, 2) for z in (0, 3, 4, 11, 12)] == [3, 3, 5, 5, 7]


def test_count_rules():
    with pytest.raises(MalformedSectionError):
        unpack_joint_cameras(b"", 1, 8, 8)
    with pytest.raises(MalformedSectionError):
        unpack_joint_cameras(b"\x00", 1, 8, 8)
    with pytest.raises(LimitExceededError):
        unpack_joint_cameras(b"\x40" + bytes(20), 1, 8, 8)


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_damaged_payloads_give_only_library_errors(data):
    """Flipped, cut and appended bytes in a joint XCAM: a FormatError, or records that read as I.5.4 records."""
    rng = np.random.default_rng(data.draw(st.integers(0, 2**16)))
    records = records_of([smooth(rng, 5, 60.0, 64, static=bool(i % 2)) for i in range(3)])
    payload = bytearray(pack_joint_cameras(records, 5, 64, 64))
    for _ in range(data.draw(st.integers(1, 4))):
        kind = data.draw(st.sampled_from(["flip", "cut", "append"]))
        if kind == "flip" and payload:
            at = data.draw(st.integers(0, len(payload) - 1))
            payload[at] ^= 1 << data.draw(st.integers(0, 7))
        elif kind == "cut" and payload:
            del payload[data.draw(st.integers(0, len(payload) - 1)):]
        else:
            payload += bytes(data.draw(st.lists(st.integers(0, 255), max_size=4)))
    scene = mv.learned_scene(quality=2)
    scene.cameras = smooth(rng, 5, 60.0, 64)
    scene.extra_cameras = tuple(smooth(rng, 5, 60.0, 64) for _ in range(3))
    good = dumps(scene, tables=TABLES, joint_cameras=True, compression_level=None)
    header, sections = mv.split(good)
    mv.find(sections, "XCAM")[3:5] = [bytes(payload), len(payload)]
    bad = mv.rebuild_1_3(header, sections, minor=6, required_flags=parse_preamble(good).required_flags)
    try:
        out = loads(bad, tables=TABLES)
    except FormatError:
        return
    assert all(np.isfinite(c.w2c).all() for c in out.extra_cameras)
