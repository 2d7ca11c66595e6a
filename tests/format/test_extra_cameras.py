"""Format 1.4, the extra cameras section XCAM (FORMAT.md I.5.3, required flag bit 3): the trajectories of every
further camera of a multi-camera encode round-trip as CAMS does, in both layouts; a file without them keeps
its 1.0-1.3 bytes; every malformed section, flag or version is refused with its typed error."""

from __future__ import annotations

import struct
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from format_strategies import camera, load_vector_tool, rig_scene, simple_scene
from vt4dcodec.errors import (FormatError, LimitExceededError, MalformedSectionError, UnsupportedFeatureError)
from vt4dcodec.format import ENCODINGS, Scene, dumps, load, loads, open_scene, verify
from vt4dcodec.format import layout
from vt4dcodec.format.compact_cameras import CAMERA_MODES, REPROJECTION_TOLERANCE_PX, reprojection_change
from vt4dcodec.format.extra_cameras import extra_cameras_max_raw_length
from vt4dcodec.format.limits import MAX_EXTRA_CAMERAS

mv = load_vector_tool()
LAYOUTS = ("compact", "legacy")


def assert_extras_round_trip(a: Scene, b: Scene, cameras: str) -> None:
    assert len(b.extra_cameras) == len(a.extra_cameras) and isinstance(b.extra_cameras, tuple)
    for x, y in zip(a.extra_cameras, b.extra_cameras):
        assert (y.width, y.height, y.distortion) == (x.width, x.height, None)
        assert (y.timestamps is None) == (b.cameras.timestamps is None)
        assert y.timestamps is None or np.array_equal(y.timestamps, b.cameras.timestamps)
        if cameras == "compact":  # as CAMS: float32 only where no probe point moves more than 0.01 px
            assert reprojection_change(x, y) <= REPROJECTION_TOLERANCE_PX
        else:  # float64 records: bit for bit
            assert y.equals(x)


# --- round trips ----------------------------------------------------------------------------------------------
@settings(max_examples=60, deadline=None)
@given(st.integers(1, 6), st.integers(1, 8), st.integers(0, 2**32 - 1), st.sampled_from(CAMERA_MODES),
       st.sampled_from(LAYOUTS), st.booleans(), st.sampled_from([None, 9]))
def test_any_extra_cameras_round_trip_as_cams_does(frames, count, seed, cameras, header, timestamps, level):
    scene = rig_scene(count, frames, seed, timestamps=timestamps, encoding="float32")
    data = dumps(scene, cameras=cameras, header=header, compression_level=level)
    f = open_scene(data)
    assert f.version == (1, 4) and f.preamble.required_flags & layout.FLAG_EXTRA_CAMERAS
    assert [e.type for e in f.sections][:2] == ["CAMS", "XCAM"] and f.num_extra_cameras == count
    back = loads(data)
    assert_extras_round_trip(scene, back, cameras)
    assert np.array_equal(back.static_tokens, scene.static_tokens)
    if cameras != "compact":
        assert back == scene
    assert dumps(back, cameras=cameras, header=header, compression_level=level) == data  # a fixed point
    verify(data)


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_every_encoding_keeps_its_flags_beside_bit_3(encoding):
    scene = rig_scene(3, encoding=encoding)
    for header, cameras, flags in (("compact", "compact", 14), ("compact", "legacy", 12), ("legacy", "compact", 10),
                                   ("legacy", "legacy", 8)):
        f = open_scene(dumps(scene, header=header, cameras=cameras))
        rans = 1 if encoding.endswith("-rans") else 0
        assert f.version == (1, 4) and f.preamble.required_flags == flags | rans, (header, cameras)
        assert_extras_round_trip(scene, f.to_scene(), cameras)


@pytest.mark.parametrize("header", LAYOUTS)
@pytest.mark.parametrize("cameras", CAMERA_MODES)
def test_without_extra_cameras_the_file_is_what_1_3_wrote(header, cameras):
    """Lowest-version rule: no extra cameras, no XCAM, no bit 3, the minor version and bytes of before."""
    scene = simple_scene(encoding="int4-rans")
    data = dumps(scene, header=header, cameras=cameras)
    same = Scene(scene.static_tokens, scene.dynamic_tokens, scene.cameras, scene.fingerprint, encoding="int4-rans",
                 extra_cameras=[])
    assert dumps(same, header=header, cameras=cameras) == data
    f = open_scene(data)
    assert f.version[1] <= 3 and not f.has_extra_cameras and "XCAM" not in [e.type for e in f.sections]
    assert f.extra_cameras == () and f.num_extra_cameras == 0 and loads(data).extra_cameras == ()


def test_four_static_extra_cameras_cost_a_few_hundred_bytes():
    """The budget of issue 13 (512 non-token bytes) is for one camera; each extra static camera adds its
    K and pose record (50 bytes as float32 quaternions) and 4 bytes of length, before zstd."""
    rng = np.random.default_rng(7)
    base = rig_scene(0, frames=8, encoding="int4-rans")
    extras = [camera(rng, 8, static=True) for _ in range(4)]
    with_extras = Scene(base.static_tokens, base.dynamic_tokens, base.cameras, base.fingerprint,
                        encoding="int4-rans", extra_cameras=extras)
    without, with_ = len(dumps(base)), len(dumps(with_extras))
    xcam = next(e for e in open_scene(dumps(with_extras)).sections if e.type == "XCAM")
    assert xcam.raw_length == 1 + 4 * 4 + 4 * 50 and with_ - without == 18 + xcam.stored_length


# --- the Scene field -------------------------------------------------------------------------------------------
def test_scene_field_is_a_tuple_sharing_the_cameras_timestamps():
    scene = rig_scene(2)
    assert isinstance(scene.extra_cameras, tuple) and scene.num_cameras == 3
    assert all(np.array_equal(x.timestamps, scene.cameras.timestamps) for x in scene.extra_cameras)  # given
    # without timestamps: they take cameras' own
    equal = replace(scene.extra_cameras[0], timestamps=scene.cameras.timestamps.copy())
    again = Scene(scene.static_tokens, scene.dynamic_tokens, scene.cameras, scene.fingerprint,
                  extra_cameras=(equal,))
    assert np.array_equal(again.extra_cameras[0].timestamps, scene.cameras.timestamps)
    assert simple_scene().extra_cameras == () and simple_scene().num_cameras == 1
    assert "2 extra cameras" in repr(scene)


def test_scene_equality_compares_extra_cameras_in_order():
    a = rig_scene(2, encoding="float32")
    b = rig_scene(2, encoding="float32")
    assert a == b
    b.extra_cameras = b.extra_cameras[::-1]
    assert a != b
    b.extra_cameras = b.extra_cameras[:1]
    assert a != b


def _bad(scene: Scene, extras, error=FormatError, match=None):
    with pytest.raises(error, match=match):
        Scene(scene.static_tokens, scene.dynamic_tokens, scene.cameras, scene.fingerprint, extra_cameras=extras)


def test_scene_refuses_extra_cameras_the_section_cannot_store():
    scene = rig_scene(1, frames=3)
    cam = scene.extra_cameras[0]
    _bad(scene, cam, match="tuple")  # one trajectory, not a sequence of them
    _bad(scene, (cam for _ in range(2)), match="tuple")
    _bad(scene, [cam, "cam01"], match=r"extra_cameras\[1\] must be a vt4dcodec.cameras.Trajectory")
    _bad(scene, [cam[:2]], match="2 frames but cameras has 3")
    _bad(scene, [replace(cam, width=cam.width + 1)], match="33x24 px")
    _bad(scene, [replace(cam, height=cam.height * 2)], match="32x48 px")
    _bad(scene, [replace(cam, distortion=np.zeros(4))], match="distortion")
    _bad(scene, [replace(cam, timestamps=np.arange(3) + 1.0)], match="timestamps other than")
    no_ts = rig_scene(1, frames=3, timestamps=False)
    _bad(no_ts, [replace(cam, timestamps=np.arange(3) / 30.0)], match="timestamps other than")
    _bad(scene, [cam] * (MAX_EXTRA_CAMERAS + 1), error=LimitExceededError, match="63")
    assert len(Scene(scene.static_tokens, scene.dynamic_tokens, scene.cameras, scene.fingerprint,
                     extra_cameras=[cam] * MAX_EXTRA_CAMERAS).extra_cameras) == 63


def test_the_writer_checks_extra_cameras_again():
    """A scene is mutable: an extra camera swapped in after construction is checked when written."""
    scene = rig_scene(1, frames=3)
    scene.extra_cameras = (scene.extra_cameras[0][:2],)
    with pytest.raises(FormatError, match="2 frames"):
        dumps(scene)


def test_63_extra_cameras_is_the_most_a_file_holds():
    scene = rig_scene(1, frames=2)
    full = Scene(scene.static_tokens, scene.dynamic_tokens, scene.cameras, scene.fingerprint, encoding="float32",
                 extra_cameras=scene.extra_cameras * MAX_EXTRA_CAMERAS)
    for header in LAYOUTS:
        assert loads(dumps(full, header=header, cameras="exact")) == full
        assert open_scene(dumps(full, header=header)).num_extra_cameras == 63


# --- lazy and partial reads ----------------------------------------------------------------------------------
def _with_record(data: bytes, index: int, record: bytes) -> bytes:
    header, sections = mv.split(data)
    xcam = mv.find(sections, "XCAM")
    raw = bytes(open_scene(data).raw_section("XCAM"))
    records = _records(raw)
    records[index] = record
    xcam[2:5] = [0, _pack(records), len(_pack(records))]
    return mv.rebuild(header, sections)


def _records(raw: bytes) -> list[bytes]:
    count = raw[0]
    lengths = struct.unpack_from(f"<{count}I", raw, 1)
    out, pos = [], 1 + 4 * count
    for n in lengths:
        out.append(raw[pos:pos + n])
        pos += n
    return out


def _pack(records: list[bytes]) -> bytes:
    return bytes([len(records)]) + struct.pack(f"<{len(records)}I", *map(len, records)) + b"".join(records)


def _nan_focal(record: bytes) -> bytes:
    """A compact record (I.5.1) whose fx (value 0 of the intrinsics block, not predicted) has its two highest
    bytes set: sign, exponent all ones and a non-zero fraction, a NaN bit pattern."""
    out = bytearray(record)
    P, F = out[0], out[1]
    assert F & 1, "a record with one intrinsics record (constant K): byte plane b starts at 2 + 5 b"
    for b in (P - 1, P - 2):
        out[2 + 5 * b] = 0xFF
    return bytes(out)


@pytest.mark.parametrize("header", LAYOUTS)
def test_lazy_open_counts_and_decodes_one_extra_camera_alone(header):
    scene = rig_scene(3, frames=4, encoding="float32")
    data = dumps(scene, header=header, cameras="exact")
    f = open_scene(data)
    assert f.has_extra_cameras and f.num_extra_cameras == 3 and f._extra_cameras is None  # nothing decoded
    assert f.extra_camera(2).equals(scene.extra_cameras[2]) and f._extra_cameras is None
    assert all(a.equals(b) for a, b in zip(f.extra_cameras, scene.extra_cameras))
    assert f.extra_camera(1) is f.extra_cameras[1]  # decoded once, then cached
    for index in (3, -1):
        with pytest.raises(FormatError, match="does not exist"):
            f.extra_camera(index)
        with pytest.raises(FormatError, match="does not exist"):
            open_scene(data).extra_camera(index)
    with pytest.raises(FormatError, match="no extra cameras"):
        open_scene(dumps(simple_scene())).extra_camera(0)
    # a damaged record 1: records 0 and 2 still read alone; everything else refuses the file
    damaged = _with_record(data, 1, _nan_focal(_records(bytes(f.raw_section("XCAM")))[1]))
    g = open_scene(damaged)
    assert g.extra_camera(0).equals(scene.extra_cameras[0]) and g.extra_camera(2).equals(scene.extra_cameras[2])
    for read in (lambda: g.extra_camera(1), lambda: g.extra_cameras, lambda: load(damaged), lambda: verify(damaged)):
        with pytest.raises(MalformedSectionError, match="extra camera 1"):
            read()


# --- rejections --------------------------------------------------------------------------------------------------
@pytest.fixture(params=[("compact", "compact"), ("compact", "legacy"), ("legacy", "compact"), ("legacy", "legacy")],
                ids=lambda p: f"{p[0]}-header-{p[1]}-cameras")
def good(request):
    """(file, header map, sections) of a 2-extra-camera scene (one moving, one static), raw sections, in
    either layout with compact or 1.0 cameras."""
    header_mode, cameras = request.param
    data = dumps(rig_scene(2, frames=2, encoding="int8"), header=header_mode, cameras=cameras,
                 compression_level=None)
    header, sections = mv.split(data)
    return data, header, sections


def _rebuild(good, sections, **kw) -> bytes:
    """The good file's layout with other sections (flags and minor inferred, or as given)."""
    data, header, _ = good
    if open_scene(data).compact_container:
        return mv.rebuild_1_3(header, sections, **kw)
    return mv.rebuild(header, sections, **kw)


def _xcam(good, payload: bytes, **kw) -> bytes:
    bad = [list(s) for s in good[2]]
    mv.find(bad, "XCAM")[2:5] = [0, payload, len(payload)]
    return _rebuild(good, bad, **kw)


def _refused(data: bytes, error, match=None) -> None:
    for read in (loads, lambda d: open_scene(d).verify()):
        with pytest.raises(error, match=match) as info:
            read(data)
        assert type(info.value) is error, info.value


def test_the_good_fixture_reads(good):
    data, header, sections = good
    assert _rebuild(good, sections) == mv.rebuild(header, sections) == data and loads(data).num_cameras == 3


def test_bad_count(good):
    data = good[0]
    raw = bytes(open_scene(data).raw_section("XCAM"))
    records = _records(raw)
    _refused(_xcam(good, b"\x00"), MalformedSectionError, "0 trajectories")
    _refused(_xcam(good, b"\x00" + raw[1:]), MalformedSectionError, "0 trajectories")
    if open_scene(data).compact_cameras:  # 64 float64 records would exceed the section's bound (below) first
        _refused(_xcam(good, bytes([64]) + struct.pack("<64I", *[len(records[0])] * 64) + records[0] * 64),
                 LimitExceededError, "limit is 63")
    _refused(_xcam(good, bytes([64]) + bytes(4 * 64)), LimitExceededError, "limit is 63")
    _refused(_xcam(good, b"\xff" + raw[1:]), LimitExceededError, "255 trajectories")
    _refused(_xcam(good, bytes([3]) + raw[1:]), MalformedSectionError, "add up to")  # lengths misread
    _refused(_xcam(good, bytes([1]) + raw[1:]), MalformedSectionError, "add up to")


def test_truncated_and_trailing_bytes(good):
    raw = bytes(open_scene(good[0]).raw_section("XCAM"))
    _refused(_xcam(good, b""), MalformedSectionError, "0 bytes")
    for cut in range(1, 9):  # inside the length table
        _refused(_xcam(good, raw[:cut]), MalformedSectionError, "too short")
    for cut in range(9, len(raw)):  # inside the records
        _refused(_xcam(good, raw[:cut]), MalformedSectionError, "add up to")
    _refused(_xcam(good, raw + b"\x00"), MalformedSectionError, "add up to")


def test_record_length_mismatch(good):
    data = good[0]
    f = open_scene(data)
    records = _records(bytes(f.raw_section("XCAM")))
    for bad, match in (([records[0] + b"\x00", records[1]], "extra camera 0"),
                       ([records[0], records[1][:-1]], "extra camera 1"),
                       ([records[0], b""], "extra camera 1"),
                       ([records[0][:1], records[1]], "extra camera 0"),
                       ([records[0], records[1] + bytes(32)], "extra camera 1")):  # 4 distortion terms
        _refused(_xcam(good, _pack(bad)), MalformedSectionError, match)


def test_frame_count_mismatch(good):
    """A record of another trajectory length than the header's T (the only frame count there is)."""
    f = open_scene(good[0])
    three = dumps(rig_scene(2, frames=3, encoding="int8"), header="compact" if f.compact_container else "legacy",
                  cameras="compact" if f.compact_cameras else "legacy")
    long_record = _records(bytes(open_scene(three).raw_section("XCAM")))[0]  # 3 frames, moving
    records = _records(bytes(f.raw_section("XCAM")))
    _refused(_xcam(good, _pack([records[0], long_record])), MalformedSectionError, "extra camera 1")


def test_record_structure_and_values(good):
    data = good[0]
    f = open_scene(data)
    records = _records(bytes(f.raw_section("XCAM")))
    rec = bytearray(records[0])
    if not f.compact_cameras:  # I.5 float64: fx of frame 0 is value 0
        for value, match in ((float("nan"), "non-finite"), (float("inf"), "non-finite"), (0.0, "focal")):
            rec[:8] = struct.pack("<d", value)
            _refused(_xcam(good, _pack([bytes(rec), records[1]])), MalformedSectionError, match)
        rec = bytearray(records[0])
        rec[9 * 2 * 8:9 * 2 * 8 + 8] = struct.pack("<d", 2.0)  # w2c[0][0][0] = 2: not a rotation
        _refused(_xcam(good, _pack([bytes(rec), records[1]])), MalformedSectionError, "orthonormal")
        return
    P, F = rec[0], rec[1]
    for byte0, match in ((2, "precision"), (0, "precision")):
        _refused(_xcam(good, _pack([bytes([byte0]) + bytes(rec[1:]), records[1]])), MalformedSectionError, match)
    _refused(_xcam(good, _pack([bytes([P, F | 8]) + bytes(rec[2:]), records[1]])), MalformedSectionError, "layout")
    if not f.compact_container:  # quaternion poses need a compact container (I.5.2), in XCAM as in CAMS
        _refused(_xcam(good, _pack([bytes([P, F | 4]) + bytes(rec[2:]), records[1]])), MalformedSectionError,
                 "compact container")
    _refused(_xcam(good, _pack([_nan_focal(bytes(rec)), records[1]])), MalformedSectionError, "non-finite")


def test_flag_and_section_must_agree(good):
    data, header, sections = good
    flags = layout.parse_preamble(data).required_flags
    without = [s for s in sections if s[0] != "XCAM"]
    _refused(_rebuild(good, without, minor=4, required_flags=flags), MalformedSectionError, "lacks required section")
    _refused(_rebuild(good, sections, minor=4, required_flags=flags & ~layout.FLAG_EXTRA_CAMERAS),
             MalformedSectionError, "required flag bit 3 is clear")
    ancillary = [list(s) for s in sections]
    mv.find(ancillary, "XCAM")[1] = False
    _refused(_rebuild(good, ancillary), MalformedSectionError, "critical")
    _refused(_rebuild(good, sections + [mv.find(sections, "XCAM")]), MalformedSectionError, "twice")


@pytest.mark.parametrize("minor", [0, 1, 2, 3])
def test_bit_3_in_a_file_of_an_older_minor_is_an_unknown_flag(good, minor):
    """As a reader of that version refuses it (in a compact container below 1.3 bit 2 is named first)."""
    _refused(mv.patch_preamble(good[0], 12, "<H", minor), UnsupportedFeatureError, "no required flag")


def test_newer_minor_with_extra_cameras_reads(good):
    data = good[0]
    assert loads(mv.patch_preamble(data, 12, "<H", 9)).num_cameras == 3


def test_a_1_3_reader_refuses_extra_cameras_by_the_required_flag(monkeypatch):
    data, plain = dumps(rig_scene(1)), dumps(simple_scene())
    monkeypatch.setattr(layout, "KNOWN_REQUIRED_FLAGS", layout.KNOWN_REQUIRED_FLAGS & ~layout.FLAG_EXTRA_CAMERAS)
    with pytest.raises(UnsupportedFeatureError, match="upgrade"):
        loads(data)
    loads(plain)


def test_declared_raw_length_is_bounded_before_decompressing(good):
    """XCAM's raw_length is checked against 1 + 63 (4 + 200 T) before any zstd frame is touched."""
    import zstandard

    data, header, sections = good
    frames = open_scene(data).num_frames
    limit = extra_cameras_max_raw_length(frames)
    assert limit == 1 + 63 * (4 + 200 * frames)
    bad = [list(s) for s in sections]
    size = 16 << 20
    mv.find(bad, "XCAM")[2:5] = [1, zstandard.ZstdCompressor(level=19).compress(bytes(size)), size]
    _refused(mv.rebuild(header, bad), MalformedSectionError, "header implies")
