"""Round trips of arbitrary scenes through every encoding, destination and reading path."""

from __future__ import annotations

import io

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from format_strategies import scenes, simple_scene, token_matrix
from vt4dcodec.format import ENCODINGS, dumps, load, loads, max_abs_error, open_scene, save, verify
from vt4dcodec.format.encodings import decode_tokens, encode_tokens
from vt4dcodec.format.compact_cameras import CAMERA_MODES, REPROJECTION_TOLERANCE_PX, reprojection_change

BIG = float(np.float32(3e38))


def assert_same_scene(a, b, *, exact_tokens: bool, exact_cameras: bool = True) -> None:
    assert b.fingerprint.matches(a.fingerprint)
    assert b.metadata == a.metadata
    assert b.provenance == a.provenance
    if exact_cameras:
        assert b.cameras.equals(a.cameras)
    else:  # compact cameras (format 1.2): float32 only where no probe point moves more than 0.01 px
        assert reprojection_change(a.cameras, b.cameras) <= REPROJECTION_TOLERANCE_PX
        assert np.array_equal(b.cameras.distortion, a.cameras.distortion) if a.cameras.distortion is not None \
            else b.cameras.distortion is None
        assert np.array_equal(b.cameras.timestamps, a.cameras.timestamps) if a.cameras.timestamps is not None \
            else b.cameras.timestamps is None
    for x, y in ((a.static_tokens, b.static_tokens), (a.dynamic_tokens, b.dynamic_tokens)):
        assert y.dtype == np.float32 and y.shape == x.shape
        if exact_tokens:
            assert np.array_equal(x, y)
        else:
            assert np.all(np.abs(x.astype(np.float64) - y) <= max_abs_error(x, a.encoding))


@given(scenes(), st.sampled_from([None, 1, 9]), st.sampled_from(CAMERA_MODES))
def test_any_scene_round_trips_within_its_encodings_bound(scene, level, cameras):
    data = dumps(scene, compression_level=level, cameras=cameras)
    back = loads(data)
    assert back.encoding == scene.encoding
    assert_same_scene(scene, back, exact_tokens=scene.encoding == "float32", exact_cameras=cameras != "compact")
    verify(data)
    if scene.encoding == "float32":  # a fixed point: the decoded scene writes the same bytes again
        assert dumps(back, compression_level=level, cameras=cameras) == data


@given(st.integers(1, 40), st.integers(1, 8), st.sampled_from(["int8", "int4"]), st.data())
def test_affine_error_bound_holds_for_extreme_ranges(rows, cols, enc, data):
    x = data.draw(token_matrix(rows, cols, st.floats(-BIG, BIG, allow_nan=False, width=32)))
    enc_tokens = encode_tokens(x, enc)
    y = decode_tokens(enc_tokens.tokens, enc_tokens.quant, enc, rows, cols)
    assert np.all(np.abs(x.astype(np.float64) - y) <= max_abs_error(x, enc))


@given(st.integers(1, 30), st.integers(1, 6), st.data())
def test_float16_error_bound(rows, cols, data):
    x = data.draw(token_matrix(rows, cols, st.floats(-65504, 65504, allow_nan=False, width=32)))
    e = encode_tokens(x, "float16")
    y = decode_tokens(e.tokens, None, "float16", rows, cols)
    assert np.all(np.abs(x.astype(np.float64) - y) <= max_abs_error(x, "float16"))


def test_int8_rounding_is_half_to_even_and_deterministic():
    # channel range 0..255 gives scale 1: codes equal the rounded values, ties to even
    x = np.array([[0.0], [255.0], [2.5], [3.5], [100.5]], np.float32)
    e = encode_tokens(x, "int8")
    assert list(np.frombuffer(e.tokens, np.uint8)) == [0, 255, 2, 4, 100]
    assert encode_tokens(x, "int8") == e


def test_int4_nibble_order_is_low_first():
    x = np.array([[0.0, 15.0, 1.0]], np.float32).T.reshape(3, 1)  # one channel, codes 0, 15, 1
    e = encode_tokens(x, "int4")
    assert e.tokens == bytes([0x0 | (15 << 4), 0x1])


def test_constant_channel_has_zero_scale_and_exact_values():
    x = np.full((5, 2), 3.25, np.float32)
    for enc in ("int8", "int4"):
        e = encode_tokens(x, enc)
        assert np.array_equal(decode_tokens(e.tokens, e.quant, enc, 5, 2), x)


def test_float16_refuses_out_of_range_tokens():
    from vt4dcodec.errors import FormatError

    scene = simple_scene()
    scene.static_tokens[0, 0] = 70000.0
    with pytest.raises(FormatError, match="float16"):
        dumps(scene, encoding="float16")


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_path_file_object_and_bytes_give_the_same_scene(tmp_path, encoding):
    scene = simple_scene(encoding=encoding)
    path = tmp_path / "s.vt4d"
    n = save(scene, path)
    assert n == path.stat().st_size
    buf = io.BytesIO()
    buf.write(b"prefix")
    assert save(scene, buf) == n
    buf.seek(6)
    from_file = load(buf)
    assert buf.tell() == 6 + n  # reads exactly the container, nothing after it
    data = path.read_bytes()
    for other in (load(path), load(str(path)), from_file, loads(data), load(memoryview(data)), load(bytearray(data))):
        assert_same_scene(scene, other, exact_tokens=encoding == "float32")


def test_container_is_position_independent():
    data = dumps(simple_scene())
    embedded = b"x" * 1000 + data + b"y" * 33
    assert dumps(loads(embedded[1000:1000 + len(data)])) == data


def test_raw_float32_tokens_are_zero_copy_views():
    data = dumps(simple_scene(ns=8, d=16), encoding="float32", compression_level=None)
    f = open_scene(data)
    z = f.static_tokens()
    assert not z.flags.owndata and not z.flags.writeable
    assert np.shares_memory(z, np.frombuffer(data, np.uint8))
    entry = next(e for e in f.sections if e.type == "ZSTA")
    assert entry.offset % 64 == 0


def test_lazy_open_reads_each_token_section_alone():
    scene = simple_scene(encoding="int8")
    f = open_scene(dumps(scene))
    assert f.static_shape == scene.static_shape and f.num_frames == 2 and f.encoding == "int8"
    codes = f.dynamic_tokens(dequantize=False)
    assert codes.dtype == np.uint8 and codes.shape == scene.dynamic_shape
    scale, offset = f.quantization("dynamic")
    assert np.allclose(offset + scale * codes.astype(np.float64), f.dynamic_tokens(), atol=1e-6)
    summary = f.summary()
    assert summary["frames"] == 2 and summary["encoding"] == "int8"
    assert summary["fingerprint"] == scene.fingerprint.to_dict()
    import json

    json.dumps(summary)


def test_paper_size_int8_scene_is_under_110_kb():
    rng = np.random.default_rng(1)
    base = simple_scene(ns=1024, nd=512, d=64, frames=32)
    base.static_tokens = rng.standard_normal((1024, 64)).astype(np.float32)
    assert len(dumps(base, encoding="int8")) < 110_000
    assert len(dumps(base, encoding="int8", compression_level=None)) < 110_000


@settings(max_examples=20)
@given(st.sampled_from(ENCODINGS), st.integers(1, 3))
def test_requantizing_a_decoded_scene_is_stable(encoding, seed):
    scene = simple_scene(seed=seed, encoding=encoding)
    once = loads(dumps(scene))
    twice = loads(dumps(once))
    assert_same_scene(once, twice, exact_tokens=encoding in ("float32", "float16"))


def test_fast_float16_conversion_matches_numpy_for_every_finite_half():
    from vt4dcodec.format.encodings import float16_to_float32

    bits = np.arange(1 << 16, dtype=np.uint16)
    bits = bits[(bits & 0x7C00) != 0x7C00]
    ref = bits.view(np.float16).astype(np.float32)
    assert np.array_equal(float16_to_float32(bits.view(np.float16)).view(np.uint32), ref.view(np.uint32))


def test_float16_section_holding_infinity_is_refused():
    from vt4dcodec.errors import MalformedSectionError

    payload = np.array([1.0, np.inf], "<f2").tobytes()
    with pytest.raises(MalformedSectionError, match="non-finite"):
        decode_tokens(payload, None, "float16", 1, 2)


def test_scene_equality_compares_contents():
    a, b = simple_scene(seed=3, encoding="float32"), simple_scene(seed=3, encoding="float32")
    assert a == b
    b.dynamic_tokens = b.dynamic_tokens + 1
    assert a != b
    assert loads(dumps(a)) == a


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_loaded_scene_tokens_are_writable(encoding):
    scene = loads(dumps(simple_scene(encoding=encoding), compression_level=None))
    assert scene.static_tokens.flags.writeable and scene.dynamic_tokens.flags.writeable


@pytest.mark.parametrize("enc", ["int8", "int4", "int8-rans", "int2-rans"])
def test_error_bound_covers_a_scale_that_underflows_to_zero(enc):
    """lo = 0, hi = 2^-149: scale = f32(2^-149 / (2^b - 1)) = 0, so every code is 0 and the top value
    decodes 2^-149 off (found by hypothesis; FORMAT.md I.6, the (2^b - 1) * 2^-150 term)."""
    x = np.array([[0.0], [2.0**-149]], np.float32)
    e = encode_tokens(x, enc)
    y = decode_tokens(e.tokens, e.quant, enc, 2, 1)
    assert np.all(np.abs(x.astype(np.float64) - y) <= max_abs_error(x, enc))


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 200), st.integers(1, 70), st.sampled_from([4, 8]),
       st.floats(-12, 3), st.floats(-4, 36))
def test_compiled_dequantization_is_the_formula_bit_for_bit(seed, rows, cols, bits, log_scale, log_offset):
    """int8 / int4 dequantization through the compiled per-column table gather gives f32(offset + scale * q)
    exactly as the float64 formula does, including offsets and scales near float32's range (where a table
    value overflows, the formula path refuses the section as before)."""

    rng = np.random.default_rng(seed)
    codes = rng.integers(0, 1 << bits, (rows, cols), dtype=np.uint8)
    scale = (rng.random(cols) * 10.0 ** log_scale).astype(np.float32)
    offset = (rng.normal(size=cols) * 10.0 ** log_offset).astype(np.float32)
    _assert_compiled_is_formula(codes, scale, offset, bits)


def _assert_compiled_is_formula(codes, scale, offset, bits):
    from vt4dcodec.errors import MalformedSectionError
    from vt4dcodec.format import encodings

    native = encodings._native_dequantize
    assert native is not None, "the compiled extension is part of the test install"
    outcomes = []
    for compiled in (native, None):
        encodings._native_dequantize = compiled
        try:
            outcomes.append(encodings.dequantize(codes, scale, offset, bits, f"int{bits}").view(np.int32))
        except MalformedSectionError:
            outcomes.append(None)
        finally:
            encodings._native_dequantize = native
    assert (outcomes[0] is None) == (outcomes[1] is None)
    assert outcomes[0] is None or np.array_equal(outcomes[0], outcomes[1])


@pytest.mark.parametrize("offset", [np.finfo(np.float32).max, -np.finfo(np.float32).max, 3.0e38, 0.0])
def test_compiled_dequantization_at_float32s_edge(offset):
    """Table values at float32's largest finite value, and just beyond it in float64 where float32 rounding
    brings them back to it (numpy's f32 cast does; the compiled path hands those tables to the formula path):
    the same bits or the same refusal either way."""
    codes = np.arange(256, dtype=np.uint8).reshape(16, 16)
    f32max = float(np.finfo(np.float32).max)
    for scale in (0.0, 1e22, 1e29, 1e31, 1e36):
        s = np.full(16, scale, np.float32)
        o = np.full(16, offset, np.float32)
        _assert_compiled_is_formula(codes, s, o, 8)
    assert f32max + 1e29 > f32max and np.float32(f32max + 1e29) == np.float32(f32max)
