"""Format 1.3, the compact container (FORMAT.md I.3.1, I.4.1, I.5.2): the writer's default, what it costs
besides the tokens, the legacy knob, and that damage anywhere still ends in a typed error."""

from __future__ import annotations

import hashlib
import math
import struct
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from format_strategies import load_vector_tool, simple_scene
from vt4dcodec.errors import FormatError, LimitExceededError, MalformedHeaderError, UnsupportedFeatureError
from vt4dcodec.format import ENCODINGS, ModelFingerprint, Provenance, Scene, dumps, loads, open_scene
from vt4dcodec.format import layout
from vt4dcodec.format.compact_cameras import (REPROJECTION_TOLERANCE_PX, quaternion_to_rotation,
                                              reprojection_change, rotation_to_quaternion)
from vt4dcodec.format.header import HEADER_DICTIONARY, compress_header, decompress_header
from vt4dcodec.synth import SynthConfig, generate_scene

mv = load_vector_tool()


def default_like_scene(camera: int = 0, seed: int = 0) -> Scene:
    """What `vt4d encode` writes for one camera of a held-out synthetic capture with vt4d-tiny: 8 frames at
    64x64 with timestamps, Z_s 64x32 and Z_d 32x32, int4-rans, provenance and the encoder's metadata."""
    cap = generate_scene(seed, split="test", config=SynthConfig(num_frames=8, height=64, width=64)).capture
    rng = np.random.default_rng(seed)
    fp = ModelFingerprint("vt4d-tiny", "0.4.0", hashlib.sha256(b"c%d" % seed).hexdigest(),
                          hashlib.sha256(b"w%d" % seed).hexdigest(), (64, 32), (32, 32))
    name = cap.camera_names[camera]
    return Scene(rng.standard_normal((64, 32)), rng.standard_normal((32, 32)), cap.cameras[name], fp,
                 metadata={"vt4d": {"source_camera": name, "clip_start": 0, "clip_frames": 8,
                                    "depth_source": "capture"}},
                 provenance=Provenance("0.1.0", "2026-11-29T23:47:02Z", cap.capture_id, "encoded"),
                 encoding="int4-rans")


@pytest.mark.parametrize("seed,camera", [(0, 0), (1, 3), (2, 9), (5, 5)])
def test_a_default_single_camera_scene_has_at_most_512_non_token_bytes(seed, camera):
    """Issue 13's target: file bytes minus the token sections, as `vt4d info --json` reports them."""
    scene = default_like_scene(camera, seed)
    f = open_scene(dumps(scene))
    non_token = f.nbytes - f.token_bytes
    assert f.version == (1, 3) and non_token <= 512, non_token
    legacy = open_scene(dumps(scene, header="legacy"))
    assert legacy.version == (1, 2) and legacy.nbytes - legacy.token_bytes > 1000  # what 1.2 spent
    assert f.header == legacy.header and f.fingerprint == scene.fingerprint  # binary digests read back as hex
    assert reprojection_change(scene.cameras, loads(dumps(scene)).cameras) <= REPROJECTION_TOLERANCE_PX


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize("cameras", ["compact", "exact", "legacy"])
def test_every_encoding_and_cameras_mode_round_trips_in_both_layouts(encoding, cameras):
    scene = default_like_scene()
    compact, legacy = loads(dumps(scene, encoding=encoding, cameras=cameras)), loads(
        dumps(scene, encoding=encoding, cameras=cameras, header="legacy"))
    assert np.array_equal(compact.static_tokens, legacy.static_tokens)
    assert np.array_equal(compact.dynamic_tokens, legacy.dynamic_tokens)
    assert compact.fingerprint == scene.fingerprint and compact.provenance == scene.provenance
    assert compact.metadata == scene.metadata
    if cameras == "compact":
        assert reprojection_change(scene.cameras, compact.cameras) <= REPROJECTION_TOLERANCE_PX
    else:  # float64 matrices: bit for bit in either layout
        assert compact.cameras.equals(scene.cameras) and legacy.cameras.equals(scene.cameras)


def test_versions_and_flags_the_writer_says():
    scene = simple_scene(ns=6, d=4)
    for kw, version, flags in (({}, (1, 3), 6), ({"encoding": "int4-rans"}, (1, 3), 7),
                               ({"cameras": "legacy"}, (1, 3), 4), ({"header": "legacy"}, (1, 2), 2),
                               ({"header": "legacy", "cameras": "legacy"}, (1, 0), 0),
                               ({"header": "legacy", "cameras": "legacy", "encoding": "int4-rans"}, (1, 1), 1)):
        f = open_scene(dumps(scene, **kw))
        assert (f.version, f.preamble.required_flags) == (version, flags), kw
        assert f.compact_container == bool(flags & 4)
    with pytest.raises(FormatError, match="header mode"):
        dumps(scene, header="tiny")


def test_a_1_2_reader_refuses_compact_containers_by_the_required_flag(monkeypatch):
    data = dumps(simple_scene())
    monkeypatch.setattr(layout, "KNOWN_REQUIRED_FLAGS", layout.FLAG_ENTROPY_CODED_TOKENS | layout.FLAG_COMPACT_CAMERAS)
    with pytest.raises(UnsupportedFeatureError, match="upgrade"):
        loads(data)
    loads(dumps(simple_scene(), header="legacy"))


def test_raw_fixed_width_tokens_stay_64_aligned_and_zero_copy():
    data = dumps(simple_scene(ns=5, nd=3, d=4, encoding="float32"), compression_level=None)
    f = open_scene(data)
    by_type = {e.type: e for e in f.sections}
    assert by_type["ZSTA"].aligned and by_type["ZSTA"].offset % 64 == 0 and by_type["ZDYN"].offset % 64 == 0
    assert not by_type["CAMS"].aligned and by_type["CAMS"].offset == 64 + f.preamble.header_length + 18 * 3
    z = f.static_tokens()
    assert not z.flags.owndata and not z.flags.writeable  # a view into the file's bytes
    rans = open_scene(dumps(simple_scene(ns=5, nd=3, d=4), encoding="int5-rans", compression_level=None))
    assert not any(e.aligned for e in rans.sections)  # rANS streams are read, never mapped: packed


def test_fixed_width_tokens_that_zstd_barely_shrinks_are_stored_raw_and_read_in_place():
    """A compact container keeps a fixed-width token array raw (aligned, zero-copy) unless zstd saves at
    least 1/8 of it: int8 codes of varied tokens shrink ~7 %, and decompressing them made a verified load
    1.3x slower than safetensors + zstd.  Compressible tokens are still compressed; legacy files unchanged."""
    from vt4dcodec.format.sections import COMPRESSION_RAW, COMPRESSION_ZSTD, compress_payload
    from vt4dcodec.format.writer import TOKEN_ZSTD_MIN_SAVING

    rng = np.random.default_rng(0)
    varied = simple_scene(ns=256, nd=128, d=64, encoding="int8")
    varied = Scene(rng.standard_normal((256, 64)).astype(np.float32), rng.standard_normal((128, 64)).astype(np.float32),
                   varied.cameras, varied.fingerprint, varied.metadata, varied.provenance, encoding="int8")
    f = open_scene(dumps(varied))
    by_type = {e.type: e for e in f.sections}
    for name in ("ZSTA", "ZDYN"):
        raw = bytes(f.raw_section(name))
        packed = compress_payload(raw, 9)[1]
        assert len(packed) < len(raw) and len(raw) - len(packed) < TOKEN_ZSTD_MIN_SAVING * len(raw)
        assert by_type[name].compression == COMPRESSION_RAW and by_type[name].aligned and by_type[name].offset % 64 == 0
    np.testing.assert_array_equal(loads(dumps(varied)).static_tokens, loads(dumps(varied, header="legacy")).static_tokens)
    legacy = open_scene(dumps(varied, header="legacy"))
    assert {e.type: e.compression for e in legacy.sections}["ZSTA"] == COMPRESSION_ZSTD  # 1.0-1.2 bytes as before
    flat = Scene(np.zeros((256, 64), np.float32), np.zeros((128, 64), np.float32), varied.cameras, varied.fingerprint,
                 varied.metadata, varied.provenance, encoding="int8")
    assert {e.type: e.compression for e in open_scene(dumps(flat)).sections}["ZSTA"] == COMPRESSION_ZSTD
    assert compress_payload(b"ab" * 64, 9, min_saving=0.99)[0] == COMPRESSION_RAW


def test_header_dictionary_is_pinned():
    """Spec-fixed (FORMAT.md I.3.1): changing one byte changes how every 1.3 file decodes."""
    assert len(HEADER_DICTIONARY) == 638 and zlib.crc32(HEADER_DICTIONARY) == 0xC95A6BEA


def test_compact_header_frame_rules():
    raw = b"\x80"  # an empty map
    assert decompress_header(compress_header(raw)) == raw
    with pytest.raises(LimitExceededError):
        decompress_header(compress_header(b"\x80" + bytes(1 << 20)))
    with pytest.raises(MalformedHeaderError, match="follow"):
        decompress_header(compress_header(raw) + compress_header(raw))
    with pytest.raises(MalformedHeaderError, match="not a zstd frame"):
        decompress_header(raw)


@settings(max_examples=150, deadline=None)
@given(st.data())
def test_damaged_compact_header_only_raises_format_errors(data):
    """Byte edits inside the stored (compressed) header, CRCs fixed so decompression itself is attacked:
    a header or a FormatError, never anything else, and nothing large allocated (the frame is bounded)."""
    good = dumps(simple_scene(provenance=Provenance("0.1.0", "2026-01-01T00:00:00Z", "cap", "encoded")))
    pre = layout.parse_preamble(good)
    stored = bytearray(good[64:64 + pre.header_length])
    for _ in range(data.draw(st.integers(1, 4))):
        stored[data.draw(st.integers(0, len(stored) - 1))] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(len(stored) - 3, len(stored)))
    _, sections = mv.split(good)
    try:
        loads(mv.rebuild_1_3(bytes(stored[:cut]), sections, compress=False))
    except FormatError:
        pass


def test_quaternions_round_trip_and_keep_their_sign_from_frame_to_frame():
    rng = np.random.default_rng(3)
    q = rng.standard_normal((50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = quaternion_to_rotation(q)
    assert np.allclose(np.einsum("nji,njk->nik", R, R), np.eye(3), atol=1e-12) and np.allclose(np.linalg.det(R), 1)
    back = rotation_to_quaternion(R)
    assert np.allclose(quaternion_to_rotation(back), R, atol=1e-12)
    smooth = quaternion_to_rotation(np.cumsum(np.full((20, 4), 0.05), axis=0) + [1, 0, 0, 0])
    signs = rotation_to_quaternion(smooth)
    assert np.all(np.einsum("ni,ni->n", signs[1:], signs[:-1]) > 0)
    # the formula normalises: any non-zero scale of q is the same rotation
    assert np.allclose(quaternion_to_rotation(3.0 * q), R, atol=1e-12)


def _quaternion_one_by_one(R: np.ndarray, continuous: bool) -> np.ndarray:
    """The writer's rotation -> quaternion in plain Python floats, one rotation at a time: Shepperd's method from
    the first largest of (trace, R00, R11, R22), the norm summed w^2, x^2, y^2, z^2 in that order, each sign
    flipped by a negative dot product with the (signed) quaternion before, or a negative w."""
    out, previous = [], (1.0, 0.0, 0.0, 0.0)
    for m in R.tolist():
        diag = [(m[0][0] + m[1][1]) + m[2][2], m[0][0], m[1][1], m[2][2]]
        k = diag.index(max(diag))
        if k == 0:
            w = 0.5 * math.sqrt(max(1.0 + diag[0], 0.0))
            q = [w, (m[2][1] - m[1][2]) / (4 * w), (m[0][2] - m[2][0]) / (4 * w), (m[1][0] - m[0][1]) / (4 * w)]
        elif k == 1:
            x = 0.5 * math.sqrt(max(((1.0 + m[0][0]) - m[1][1]) - m[2][2], 0.0))
            q = [(m[2][1] - m[1][2]) / (4 * x), x, (m[0][1] + m[1][0]) / (4 * x), (m[0][2] + m[2][0]) / (4 * x)]
        elif k == 2:
            y = 0.5 * math.sqrt(max(((1.0 - m[0][0]) + m[1][1]) - m[2][2], 0.0))
            q = [(m[0][2] - m[2][0]) / (4 * y), (m[0][1] + m[1][0]) / (4 * y), y, (m[1][2] + m[2][1]) / (4 * y)]
        else:
            z = 0.5 * math.sqrt(max(((1.0 - m[0][0]) - m[1][1]) + m[2][2], 0.0))
            q = [(m[1][0] - m[0][1]) / (4 * z), (m[0][2] + m[2][0]) / (4 * z), (m[1][2] + m[2][1]) / (4 * z), z]
        norm = math.sqrt(((q[0] * q[0] + q[1] * q[1]) + q[2] * q[2]) + q[3] * q[3])
        v = [c / norm for c in q]
        dot = ((v[0] * previous[0] + v[1] * previous[1]) + v[2] * previous[2]) + v[3] * previous[3]
        if dot < 0:
            v = [-c for c in v]
        out.append(v)
        previous = v if continuous else (1.0, 0.0, 0.0, 0.0)
    return np.array(out)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 40), st.booleans())
def test_vectorised_quaternions_are_the_one_by_one_bits(seed, n, continuous):
    """rotation_to_quaternion (vectorised) gives the bits of the scalar reference: the writer's bytes (and so
    a saved file's) do not depend on how many frames are converted at once or on the BLAS a machine has."""
    rng = np.random.default_rng(seed)
    q = np.cumsum(rng.normal(scale=0.4, size=(n, 4)), axis=0) + rng.normal(size=4)
    q[rng.random(n) < 0.1, rng.integers(0, 4)] = 0.0  # half turns and axis-aligned rotations
    R = quaternion_to_rotation(q)
    got = rotation_to_quaternion(R, continuous=continuous)
    assert np.array_equal(got.view(np.int64), _quaternion_one_by_one(R, continuous).view(np.int64))


def test_quaternion_formula_is_the_one_format_md_writes():
    """I.5.2, operation for operation in Python floats: the same bits as the vectorised reader."""
    w, x, y, z = 0.5, -0.25, 0.125, 0.8
    n = ((w * w + x * x) + y * y) + z * z
    s = 2 / n
    spec = [1 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y),
            s * (x * y + w * z), 1 - s * (x * x + z * z), s * (y * z - w * x),
            s * (x * z - w * y), s * (y * z + w * x), 1 - s * (x * x + y * y)]
    assert quaternion_to_rotation(np.array([[w, x, y, z]]))[0].ravel().tolist() == spec


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 40), st.booleans(), st.sampled_from(["rotations", "any", "tiny", "huge"]))
def test_compiled_quaternion_paths_are_numpys_bits(seed, n, continuous, kind):
    """The compiled quaternion <-> rotation conversions (vt4dcodec.format._rans_native) give numpy's bits for
    rotations, arbitrary matrices and quaternions of any scale, zeros and half turns included; a non-finite
    input goes to numpy's path, so both agree there too."""
    from vt4dcodec.format import compact_cameras as cc

    assert cc._native_rotations is not None and cc._native_quaternions is not None
    rng = np.random.default_rng(seed)
    scale = {"rotations": 1.0, "any": 1.0, "tiny": 1e-160, "huge": 1e150}[kind]
    q = rng.normal(size=(n, 4)) * scale
    q[rng.random(n) < 0.15, rng.integers(0, 4)] = 0.0
    if rng.random() < 0.1:
        q[rng.integers(0, n)] = [np.nan, np.inf, 0.0, 0.0][rng.integers(0, 4)]
    R = rng.normal(size=(n, 3, 3)) if kind == "any" else quaternion_to_rotation(q)
    native = (cc._native_rotations, cc._native_quaternions)
    results = []
    for compiled in (True, False):
        cc._native_rotations, cc._native_quaternions = native if compiled else (None, None)
        try:
            with np.errstate(all="ignore"):
                results.append((quaternion_to_rotation(q), rotation_to_quaternion(R, continuous=continuous)))
        finally:
            cc._native_rotations, cc._native_quaternions = native
    for a, b in zip(*results):  # the same bits; a NaN's payload is not the formula's (readers refuse NaN poses)
        assert np.all((a.view(np.int64) == b.view(np.int64)) | (np.isnan(a) & np.isnan(b)))


def test_table_crc_covers_the_18_byte_entries():
    data = bytearray(dumps(simple_scene()))
    pre = layout.parse_preamble(bytes(data))
    table_at = 64 + pre.header_length
    struct.pack_into("<I", data, table_at + 6, struct.unpack_from("<I", data, table_at + 6)[0] + 1)
    with pytest.raises(FormatError, match="table"):
        loads(bytes(data))


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 10), st.booleans())
def test_saving_a_loaded_scene_again_gives_the_same_bytes(seed, frames, float32_matrices):
    """The writer's quaternions are the ones it finds again from the rotations they decode to (and a file of
    float32 matrices stays one), so load + save is a fixed point and resaving never drifts."""
    from vt4dcodec.cameras import Trajectory

    rng = np.random.default_rng(seed)
    q = rng.standard_normal((frames, 4))
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    w2c[:, :3, :3] = quaternion_to_rotation(q)
    w2c[:, :3, 3] = rng.uniform(-3, 3, (frames, 3))
    if float32_matrices:
        w2c = w2c.astype(np.float32).astype(np.float64)
    K = np.tile(np.array([[60.0, 0.0, 31.5], [0.0, 60.0, 31.5], [0.0, 0.0, 1.0]]), (frames, 1, 1))
    base = simple_scene(ns=2, nd=1, d=2)
    scene = Scene(base.static_tokens, base.dynamic_tokens, Trajectory(K, w2c, 64, 64), base.fingerprint)
    if float32_matrices:
        scene = loads(dumps(scene, header="legacy"))  # a 1.2 file of float32 matrices, read back
    first = dumps(scene)
    assert dumps(loads(first)) == first


@pytest.mark.parametrize("distance, focal", [(3.0, 220.0), (1e5, 1e6), (1e9, 50.0)])
def test_a_saved_file_saves_again_to_the_same_cameras_payload_near_and_far(distance, focal):
    """The writer accepts a float32 quaternion payload without a second probe pass only where the probe test of a
    camera against itself can measure nothing but rounding; far away or with a long focal length it makes the
    whole choice again, and either way a decoded trajectory gives the same payload."""
    from vt4dcodec.cameras import Trajectory
    from vt4dcodec.format.compact_cameras import _decode, _self_change_is_noise, pack_compact_cameras

    K = np.tile(np.array([[focal, 0, 31.5], [0, focal, 31.5], [0, 0, 1.0]]), (6, 1, 1))
    w2c = np.tile(np.eye(4), (6, 1, 1))
    w2c[:, :3, :3] = quaternion_to_rotation(np.cumsum(np.full((6, 4), 0.02), axis=0) + [1.0, 0.1, 0.0, 0.0])
    w2c[:, 0, 3] = distance + np.linspace(0.0, 0.5, 6)
    traj = Trajectory(K=K, w2c=w2c, width=64, height=64)
    raw = pack_compact_cameras(traj, quaternions=True)
    back = _decode(raw, 6, 64, 64, 0, False, quaternions=raw[1] & 4 != 0)
    assert _self_change_is_noise(back) == (distance < 10)
    assert pack_compact_cameras(back, quaternions=True) == raw
