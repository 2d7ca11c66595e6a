"""The entropy-coded encodings of format 1.1 (FORMAT.md I.6.1): the rANS coder, its frequency tables,
the int<b>-rans token payloads, the version/flag rules, and hostile sections."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from format_strategies import simple_scene, token_matrix
from vt4dcodec.errors import FormatError, MalformedSectionError, TruncatedError, UnsupportedFeatureError
from vt4dcodec.format import dumps, loads, max_abs_error, open_scene
from vt4dcodec.format import layout
from vt4dcodec.format.encodings import decode_tokens, encode_tokens
from vt4dcodec.format import rans
from vt4dcodec.format.rans import PROB_SCALE, normalize_counts, pack_table, parse_table, rans_decode, rans_encode
from vt4dcodec.format.rans_tokens import MAX_RANS_VALUES, RANS_BITS, RANS_ENCODINGS, decode_rans_codes

counts_lists = st.lists(st.integers(0, 1000), min_size=1, max_size=80).filter(lambda c: sum(c) > 0)


@given(counts_lists)
def test_normalized_frequencies_sum_to_m_and_keep_every_present_symbol(counts):
    freqs = normalize_counts(np.array(counts))
    assert sum(freqs) == PROB_SCALE and len(freqs) == len(counts)
    assert all((f > 0) == (c > 0) for f, c in zip(freqs, counts))
    assert normalize_counts(np.array(counts)) == freqs  # deterministic


@given(counts_lists)
def test_frequency_table_bytes_round_trip(counts):
    freqs = normalize_counts(np.array(counts))
    raw = pack_table(freqs)
    assert parse_table(raw + b"tail", len(freqs)) == (freqs, len(raw))


@given(st.data())
def test_rans_round_trip_of_any_symbol_sequence(data):
    alphabet = data.draw(st.integers(1, 300))
    symbols = np.array(data.draw(st.lists(st.integers(0, alphabet - 1), min_size=1, max_size=400)))
    freqs = normalize_counts(np.bincount(symbols, minlength=alphabet))
    stream = rans_encode(symbols, freqs)
    assert np.array_equal(rans_decode(stream, freqs, symbols.size), symbols)


def test_skewed_sources_cost_about_their_entropy():
    rng = np.random.default_rng(0)
    p = np.array([0.7, 0.2, 0.05, 0.05])
    symbols = rng.choice(4, size=20000, p=p)
    freqs = normalize_counts(np.bincount(symbols, minlength=4))
    entropy_bytes = -(np.log2(p[symbols])).sum() / 8
    assert len(rans_encode(symbols, freqs)) <= entropy_bytes * 1.01 + 8


@given(st.lists(st.integers(0, 5), min_size=2, max_size=200), st.data())
def test_every_truncated_or_extended_stream_is_a_typed_error(symbols, data):
    symbols = np.array(symbols)
    freqs = normalize_counts(np.bincount(symbols, minlength=6))
    stream = rans_encode(symbols, freqs)
    cut = data.draw(st.integers(0, len(stream) - 1))
    for bad in (stream[:cut], stream + bytes([data.draw(st.integers(0, 255))])):
        try:
            out = rans_decode(bad, freqs, symbols.size)
        except (TruncatedError, MalformedSectionError):
            continue
        # the only way to survive: a one-symbol table (the stream carries nothing) -- not the case here
        assert len(set(symbols.tolist())) == 1 and np.array_equal(out, symbols)


@pytest.mark.parametrize("table, why", [
    (b"\x00\x00", "header"), (b"\x00\x00\x00\x00", "count 0"), (b"\x00\x00\x01\x00", "cut short"),
    (b"\x00\x00\x01\x00\x80\x80\x80\x01", "4-byte varint"), (b"\x00\x00\x02\x00\x80\x00\x00", "redundant zero"),
    (b"\x00\x00\x01\x00\x81\x80\x01", "above M"), (b"\x00\x00\x01\x00\x7f", "sum"),
    (b"\x03\x00\x02\x00\x80\x40\x80\x40", "outside the alphabet"),
])
def test_malformed_frequency_tables_are_refused(table, why):
    with pytest.raises((MalformedSectionError, TruncatedError)):
        parse_table(table, 4)


@settings(max_examples=40)
@given(st.sampled_from(RANS_ENCODINGS), st.integers(1, 6), st.sampled_from([1, 2, 3, 6]), st.data())
def test_round_trip_within_the_documented_error_for_any_grouping(encoding, rows, groups, data):
    x = data.draw(token_matrix(rows, 6, st.floats(-1e6, 1e6, allow_nan=False, width=32)))
    enc = encode_tokens(x, encoding, groups=groups)
    assert enc.quant is None and enc.tokens == encode_tokens(x.copy(), encoding, groups=groups).tokens
    y = decode_tokens(enc.tokens, None, encoding, rows, 6)
    assert y.dtype == np.float32 and np.all(np.abs(x.astype(np.float64) - y) <= max_abs_error(x, encoding,
                                                                                                groups=groups))
    codes, _, _ = decode_rans_codes(enc.tokens, encoding, rows, 6)
    assert codes.max() < (1 << RANS_BITS[encoding])


def test_per_channel_grouping_matches_int8_codes_exactly():
    x = simple_scene(ns=40, d=8).static_tokens
    a = decode_tokens(encode_tokens(x, "int8-rans", groups=8).tokens, None, "int8-rans", 40, 8)
    e = encode_tokens(x, "int8")
    assert np.array_equal(a, decode_tokens(e.tokens, e.quant, "int8", 40, 8))


def _mode(payload: bytes) -> int:
    groups = struct.unpack_from("<H", payload)[0]
    return payload[2 + 8 * groups]


def test_narrow_channels_use_centre_prediction_and_iid_tokens_do_not():
    rng = np.random.default_rng(3)
    narrow = (rng.uniform(-1, 1, 32)[None, :] + rng.normal(0, 0.01, (64, 32))).astype(np.float32)
    wide = rng.normal(0, 1, (64, 32)).astype(np.float32)
    pn, pw = encode_tokens(narrow, "int6-rans").tokens, encode_tokens(wide, "int6-rans").tokens
    assert _mode(pn) == 1 and _mode(pw) == 0
    assert len(pn) < 0.5 * len(pw)  # same bits, same distortion bound, far fewer bytes
    for p, x in ((pn, narrow), (pw, wide)):
        assert np.all(np.abs(decode_tokens(p, None, "int6-rans", 64, 32) - x) <= max_abs_error(x, "int6-rans"))


def test_rans_files_say_1_1_with_the_flag_and_others_stay_1_0():
    """With the 1.0 cameras section and header (cameras="legacy", header="legacy"); compact cameras make every
    file 1.2 and the compact container 1.3 (test_compact_cameras, test_compact_container)."""
    scene = simple_scene(ns=6, d=4)
    for encoding in ("float32", "float16", "int8", "int4"):
        f = open_scene(dumps(scene, encoding=encoding, cameras="legacy", header="legacy"))
        assert f.version == (1, 0) and f.preamble.required_flags == 0
    for encoding in RANS_ENCODINGS:
        data = dumps(scene, encoding=encoding, groups=2, cameras="legacy", header="legacy")
        f = open_scene(data)
        assert f.version == (1, 1) and f.preamble.required_flags == layout.FLAG_ENTROPY_CODED_TOKENS
        assert {e.type for e in f.sections} == {"CAMS", "ZSTA", "ZDYN"}
        assert loads(data).encoding == encoding


def test_a_1_0_reader_refuses_entropy_coded_files_by_the_required_flag(monkeypatch):
    data = dumps(simple_scene(), encoding="int4-rans", cameras="legacy", header="legacy")
    monkeypatch.setattr(layout, "KNOWN_REQUIRED_FLAGS", 0)
    with pytest.raises(UnsupportedFeatureError, match="upgrade"):
        loads(data)
    loads(dumps(simple_scene(), encoding="int8", cameras="legacy", header="legacy"))


def test_lazy_access_codes_and_group_parameters():
    scene = simple_scene(ns=10, nd=5, d=4, seed=2)
    f = open_scene(dumps(scene, encoding="int5-rans", groups=2))
    codes = f.static_tokens(dequantize=False)
    scale, offset = f.quantization("static")
    assert codes.dtype == np.uint8 and codes.shape == (10, 4) and scale.shape == offset.shape == (4,)
    assert scale[0] == scale[1] and scale[2] == scale[3]
    expected = (offset.astype(np.float64) + scale.astype(np.float64) * codes).astype(np.float32)
    assert np.array_equal(expected, f.static_tokens())


def test_bad_group_argument_is_a_format_error():
    with pytest.raises(FormatError, match="groups"):
        dumps(simple_scene(d=4), encoding="int4-rans", groups=3)


def test_single_symbol_matrix_at_the_limit_decodes_without_a_per_symbol_loop(monkeypatch):
    rows = MAX_RANS_VALUES // 64
    payload = encode_tokens(np.zeros((rows, 64), np.float32), "int3-rans").tokens
    assert len(payload) < 40

    def per_symbol_path(*_):
        raise AssertionError("a one-symbol stream must not enter the per-symbol decoding loop")

    # deterministic, not timed: the loop's set-up (_cumulative) must never run for one certain symbol
    monkeypatch.setattr(rans, "_cumulative", per_symbol_path)
    assert decode_rans_codes(payload, "int3-rans", rows, 64)[0].sum() == 0


@settings(max_examples=150)
@given(st.binary(max_size=120), st.sampled_from(RANS_ENCODINGS))
def test_arbitrary_payloads_only_raise_format_errors(blob, encoding):
    try:
        codes, scale, offset = decode_rans_codes(blob, encoding, 3, 4)
    except FormatError:
        return
    assert codes.shape == (3, 4) and codes.max() < (1 << RANS_BITS[encoding]) and np.all(np.isfinite(scale))


@settings(max_examples=60)
@given(st.integers(0, 10_000), st.sampled_from(RANS_ENCODINGS))
def test_damaged_payload_bytes_are_rejected_or_stay_in_range(position, encoding):
    x = simple_scene(ns=16, d=4, seed=5).static_tokens
    payload = bytearray(encode_tokens(x, encoding).tokens)
    payload[position % len(payload)] ^= 0x5A
    try:
        y = decode_tokens(bytes(payload), None, encoding, 16, 4)
    except FormatError:
        return
    assert y.shape == (16, 4) and np.all(np.isfinite(y))  # only a parameter byte changed: still a valid matrix


# --- the compiled coder (_rans_native.c) against the pure-Python reference, byte for byte ---------------
needs_native = pytest.mark.skipif(not rans.NATIVE, reason="the compiled rANS coder is not built")


def test_the_compiled_coder_is_built():
    """`pip install` builds _rans_native.c (a C compiler is on every supported machine and in CI); without
    it entropy-coded files read ~1,000x slower.  Set VT4D_ALLOW_PURE_PYTHON_RANS=1 to accept the fallback."""
    import os
    if os.environ.get("VT4D_ALLOW_PURE_PYTHON_RANS") == "1":
        pytest.skip("pure-Python rANS accepted by VT4D_ALLOW_PURE_PYTHON_RANS")
    assert rans.NATIVE, "vt4dcodec/format/_rans_native.c was not compiled: reinstall with a C compiler"


def _python_decode(stream, freqs, count):
    data = bytes(stream)
    if len(data) < 4 or int.from_bytes(data[:4], "little") < rans.STATE_LOWER:
        return rans_decode(stream, freqs, count)  # the shared checks before either loop
    return rans._decode_py(data, int.from_bytes(data[:4], "little"), freqs, count)


def _outcome(decode, stream, freqs, count):
    try:
        return decode(stream, freqs, count).tolist()
    except (TruncatedError, MalformedSectionError) as exc:
        return type(exc).__name__, str(exc)


@needs_native
@settings(max_examples=200)
@given(st.data())
def test_compiled_and_python_coders_write_the_same_bytes(data):
    alphabet = data.draw(st.integers(1, 511))
    symbols = np.array(data.draw(st.lists(st.integers(0, alphabet - 1), min_size=1, max_size=600)))
    if data.draw(st.booleans()):  # skewed: long runs of one symbol, rare others (2-byte renormalisations)
        symbols[: symbols.size * 9 // 10] = symbols[0]
    freqs = normalize_counts(np.bincount(symbols, minlength=alphabet))
    stream = rans_encode(symbols, freqs)
    assert stream == rans._encode_py(symbols, freqs)
    assert np.array_equal(_python_decode(stream, freqs, symbols.size), symbols)


@needs_native
@settings(max_examples=200)
@given(st.lists(st.integers(0, 7), min_size=2, max_size=300), st.data())
def test_compiled_and_python_decoders_agree_on_damaged_streams(symbols, data):
    """Same symbols or the same typed error (and message) for any cut, extension or flipped byte."""
    symbols = np.array(symbols)
    freqs = normalize_counts(np.bincount(symbols, minlength=8))
    stream = bytearray(rans_encode(symbols, freqs))
    kind = data.draw(st.sampled_from(["cut", "extend", "flip"]))
    if kind == "cut":
        stream = stream[:data.draw(st.integers(0, len(stream) - 1))]
    elif kind == "extend":
        stream += bytes(data.draw(st.lists(st.integers(0, 255), min_size=1, max_size=4)))
    else:
        stream[data.draw(st.integers(0, len(stream) - 1))] ^= data.draw(st.integers(1, 255))
    count = symbols.size + data.draw(st.sampled_from([0, 0, 0, -1, 1, 1000]))
    assert (_outcome(rans_decode, bytes(stream), freqs, count)
            == _outcome(_python_decode, bytes(stream), freqs, count))


@needs_native
def test_compiled_encoder_refuses_symbols_without_a_frequency():
    with pytest.raises(ValueError):
        rans_encode(np.array([0, 1, 2]), [PROB_SCALE, 0, 0])
    with pytest.raises(ValueError):
        rans_encode(np.array([0, 3]), [PROB_SCALE // 2, PROB_SCALE // 2])


@given(st.integers(2, 8), st.integers(1, 60), st.integers(1, 8), st.integers(0, 2**32 - 1), st.booleans())
def test_histogram_median_is_the_sorted_columns_lower_median(bits, rows, cols, seed, repeated):
    from vt4dcodec.format.rans_tokens import lower_median_codes
    codes = np.random.default_rng(seed).integers(0, 1 << bits, (rows, cols)).astype(np.uint8)
    if repeated:
        codes[: rows // 2 + 1] = codes[0]
    assert np.array_equal(lower_median_codes(codes, bits), np.sort(codes, axis=0)[(rows - 1) // 2])


@needs_native
@given(st.integers(2, 8), st.integers(1, 60), st.integers(1, 8), st.integers(0, 2**32 - 1))
def test_compiled_column_histograms_count_like_bincount(bits, rows, cols, seed):
    from vt4dcodec.format.rans_tokens import column_histograms
    codes = np.random.default_rng(seed).integers(0, 1 << bits, (rows, cols)).astype(np.uint8)
    keyed = codes.astype(np.intp) + np.arange(cols) * (1 << bits)
    expect = np.bincount(keyed.reshape(-1), minlength=cols << bits).reshape(cols, 1 << bits)
    assert np.array_equal(column_histograms(codes, bits), expect)
    if bits < 8:
        codes[-1, -1] = 1 << bits
        with pytest.raises(ValueError):
            column_histograms(codes, bits)


def _reference_tokens(payload, encoding, rows, cols):
    """decode_rans_codes + dequantize: the step-by-step path that the one-pass compiled path must match."""
    from vt4dcodec.format.encodings import dequantize
    codes, scale, offset = decode_rans_codes(payload, encoding, rows, cols)
    return dequantize(codes, scale, offset, RANS_BITS[encoding], encoding)


def _tokens_outcome(decode, payload, encoding, rows, cols):
    try:
        return decode(payload, encoding, rows, cols).tobytes()
    except FormatError as exc:
        return type(exc).__name__, str(exc)


@needs_native
@settings(max_examples=120, deadline=None)
@given(st.sampled_from(RANS_ENCODINGS), st.integers(1, 30), st.sampled_from([1, 2, 4]), st.integers(0, 2**32 - 1),
       st.booleans(), st.integers(-1, 10_000), st.integers(1, 255))
def test_one_pass_compiled_decode_matches_the_step_by_step_path(encoding, rows, groups, seed, narrow, where, xor):
    """Bit-identical float32 tokens, or the same typed error and message, for clean and damaged payloads
    (where = -1: clean; else the byte at where mod length is XORed with xor)."""
    from vt4dcodec.format.rans_tokens import _parse_payload, decode_rans_tokens
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((rows, 4)).astype(np.float32)
    if narrow:  # favours centre prediction
        x = (np.arange(4) * 10.0 + 0.01 * x).astype(np.float32)
    payload = bytearray(encode_tokens(x, encoding, groups=groups).tokens)
    if where >= 0:
        payload[where % len(payload)] ^= xor
    if where < 0 and sum(1 for f in _parse_payload(bytes(payload), encoding, rows, 4).freqs if f) > 1:
        assert decode_rans_tokens(bytes(payload), encoding, rows, 4) is not None  # the one-pass path ran
    assert (_tokens_outcome(decode_tokens_any, bytes(payload), encoding, rows, 4)
            == _tokens_outcome(_reference_tokens, bytes(payload), encoding, rows, 4))


def decode_tokens_any(payload, encoding, rows, cols):
    return decode_tokens(payload, None, encoding, rows, cols)


def _sequential_tokens(f):
    return f.static_tokens(), f.dynamic_tokens()


def _pair_outcome(read, f):
    try:
        return [t.tobytes() for t in read(f)]
    except FormatError as exc:
        return type(exc).__name__, str(exc)


@settings(max_examples=80, deadline=None)
@given(st.sampled_from(RANS_ENCODINGS + ("int8", "float16")), st.integers(1, 24), st.integers(1, 24),
       st.integers(0, 2**32 - 1), st.booleans(), st.data())
def test_tokens_pair_equals_static_then_dynamic_even_when_damaged(encoding, ns, nd, seed, damage, data):
    """SceneFile.tokens() (one interleaved pass for both int<b>-rans sections) gives the same arrays as
    static_tokens() then dynamic_tokens(), and for a damaged file the same first error."""
    scene = simple_scene(ns=ns, nd=nd, d=4, seed=seed % 1000)
    raw = bytearray(dumps(scene, encoding=encoding))
    if damage:
        f = open_scene(bytes(raw))
        entry = f._by_type[data.draw(st.sampled_from(["ZSTA", "ZDYN"]))]
        at = entry.offset + data.draw(st.integers(0, entry.stored_length - 1))
        raw[at] ^= data.draw(st.integers(1, 255))
        # keep the section CRC right, so the damage reaches the decoder
        entry_index = f.sections.index(entry)
        new_crc = layout.crc32(bytes(raw[entry.offset:entry.offset + entry.stored_length]))
        table_at = layout.PREAMBLE_SIZE + f.preamble.header_length
        size = layout.entry_size(f.preamble.required_flags)  # 18 bytes (crc at 14) in a 1.3 compact container
        struct.pack_into("<I", raw, table_at + size * entry_index + (14 if f.compact_container else 32), new_crc)
        struct.pack_into("<I", raw, 52, layout.crc32(bytes(raw[table_at:table_at + size * len(f.sections)])))
        struct.pack_into("<I", raw, 60, layout.crc32(bytes(raw[:60])))
    f = open_scene(bytes(raw))
    assert _pair_outcome(lambda g: g.tokens(), f) == _pair_outcome(_sequential_tokens, f)


@settings(max_examples=300)
@given(st.lists(st.integers(0, 2**21), min_size=1, max_size=600).filter(lambda c: sum(c) > 0), st.booleans())
def test_vectorised_normalisation_equals_the_plain_loop(counts, sparse):
    if sparse:  # many rare symbols next to a dominant one: the lifting step runs
        counts = [2**21] + [1 if c % 3 == 0 else 0 for c in counts]
    assert normalize_counts(np.array(counts)) == rans._normalize_counts_py(counts)


def test_normalisation_of_an_alphabet_larger_than_half_of_m_takes_the_plain_loop():
    counts = [1] * 8193 + [9000]  # ~385 symbols floor to 0 and must be lifted
    assert normalize_counts(np.array(counts)) == rans._normalize_counts_py(counts)


@settings(max_examples=100, deadline=None)
@given(st.sampled_from(RANS_ENCODINGS), st.integers(1, 40), st.integers(1, 6), st.sampled_from([1, 2]),
       st.integers(0, 2**32 - 1), st.sampled_from(["iid", "same-centre", "narrow"]))
def test_equal_centre_shortcut_writes_the_bytes_of_coding_both_predictions(encoding, rows, half_d, groups, seed, kind):
    from vt4dcodec.format.rans_tokens import encode_rans_tokens
    rng = np.random.default_rng(seed)
    d = 2 * half_d
    x = rng.standard_normal((rows, d)).astype(np.float32)
    if kind == "same-centre":  # every channel the same values, permuted: equal medians, different columns
        x = np.stack([rng.permutation(x[:, 0]) for _ in range(d)], axis=1)
    elif kind == "narrow":
        x = (np.arange(d) * 5.0 + 0.01 * x).astype(np.float32)
    assert (encode_rans_tokens(x, encoding, groups) == encode_rans_tokens(x, encoding, groups, _shortcut=False))


@given(counts_lists)
def test_vectorised_table_packing_equals_the_plain_loop(counts):
    freqs = normalize_counts(np.array(counts))
    assert pack_table(freqs) == rans._pack_table_py(freqs)


@needs_native
@settings(max_examples=100)
@given(st.lists(st.integers(0, 9), min_size=1, max_size=300), st.lists(st.integers(0, 30), min_size=1, max_size=300))
def test_two_streams_encoded_together_equal_each_encoded_alone(a, b):
    a, b = np.array(a), np.array(b)
    fa, fb = normalize_counts(np.bincount(a, minlength=10)), normalize_counts(np.bincount(b, minlength=31))
    assert rans.rans_encode_many([(a, fa), (b, fb)]) == [rans._encode_py(a, fa), rans._encode_py(b, fb)]
