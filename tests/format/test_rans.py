"""The entropy-coded encodings of format 1.1 (FORMAT.md I.6.1): the rANS coder, its frequency tables,
the int<b>-rans token payloads, the version/flag rules, and hostile sections; and the interleaved lanes of
format 1.5 (required flag bit 4)."""

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


def _python_decode(stream, freqs, count, lanes=1):
    data = bytes(stream)
    states = [int.from_bytes(data[4 * k:4 * k + 4], "little") for k in range(lanes)]
    if len(data) < 4 * lanes or min(states) < rans.STATE_LOWER:
        return rans_decode(stream, freqs, count, lanes)  # the shared checks before either loop
    return rans._decode_py(data, states, freqs, count)


def _outcome(decode, stream, freqs, count, lanes=1):
    try:
        return decode(stream, freqs, count, lanes).tolist()
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


def _reference_tokens(payload, encoding, rows, cols, lanes=False):
    """decode_rans_codes + dequantize: the step-by-step path that the one-pass compiled path must match."""
    from vt4dcodec.format.encodings import dequantize
    codes, scale, offset = decode_rans_codes(payload, encoding, rows, cols, lanes=lanes)
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


@settings(max_examples=120, deadline=None)
@given(st.sampled_from(RANS_ENCODINGS + ("int8", "float16")), st.integers(1, 24), st.integers(1, 24),
       st.integers(0, 2**32 - 1), st.booleans(), st.sampled_from([None, 1, 2, 4, 8, 32]), st.data())
def test_tokens_pair_equals_static_then_dynamic_even_when_damaged(encoding, ns, nd, seed, damage, lanes, data):
    """SceneFile.tokens() (one call for both int<b>-rans sections) gives the same arrays as static_tokens()
    then dynamic_tokens(), and for a damaged file the same first error (one chain each, or 1.5 lanes)."""
    scene = simple_scene(ns=ns, nd=nd, d=4, seed=seed % 1000)
    raw = bytearray(dumps(scene, encoding=encoding, rans_lanes=lanes))
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


# --- format 1.5: interleaved rANS lanes (FORMAT.md I.6.1, required flag bit 4) -----------------------------
lane_counts = st.one_of(st.integers(1, 9), st.sampled_from([16, 31, 32]))


def _lane_symbols(data, max_size=600):
    alphabet = data.draw(st.integers(1, 511))
    symbols = np.array(data.draw(st.lists(st.integers(0, alphabet - 1), min_size=1, max_size=max_size)))
    if data.draw(st.booleans()):  # skewed: long runs of one symbol, rare others (2-byte renormalisations)
        symbols[: symbols.size * 9 // 10] = symbols[0]
    return symbols, normalize_counts(np.bincount(symbols, minlength=alphabet))


@settings(max_examples=150)
@given(lane_counts, st.data())
def test_lane_streams_round_trip_and_both_coders_agree_byte_for_byte(lanes, data):
    """Any K, any alphabet up to 511 symbols, n below, at and above K: the compiled and pure-Python encoders
    write the same bytes, and the compiled decoder, the pure-Python one and the plain-loop reference of
    FORMAT.md I.6.1 (lane k mod K) all give the symbols back."""
    symbols, freqs = _lane_symbols(data)
    stream = rans_encode(symbols, freqs, lanes)
    assert stream == rans._encode_py(symbols, freqs, lanes)
    assert np.array_equal(rans_decode(stream, freqs, symbols.size, lanes), symbols)
    assert np.array_equal(_python_decode(stream, freqs, symbols.size, lanes), symbols)
    assert _spec_lane_decode(stream, freqs, symbols.size, lanes) == symbols.tolist()


def _spec_lane_decode(stream, freqs, count, lanes):
    """FORMAT.md I.6.1's lane loop, as written there."""
    M, L = PROB_SCALE, rans.STATE_LOWER
    cum = [sum(freqs[:s]) for s in range(len(freqs))]
    x = [int.from_bytes(stream[4 * j:4 * j + 4], "little") for j in range(lanes)]
    pos, out = 4 * lanes, []
    for k in range(count):
        j = k % lanes
        slot = x[j] % M
        s = next(t for t in range(len(freqs)) if cum[t] <= slot < cum[t] + freqs[t])
        x[j] = freqs[s] * (x[j] // M) + slot - cum[s]
        while x[j] < L:
            x[j], pos = x[j] * 256 + stream[pos], pos + 1
        out.append(s)
    assert pos == len(stream) and x == [L] * lanes
    return out


@given(st.lists(st.integers(0, 40), min_size=1, max_size=300))
def test_one_lane_is_the_single_chain_stream(symbols):
    symbols = np.array(symbols)
    freqs = normalize_counts(np.bincount(symbols, minlength=41))
    assert rans_encode(symbols, freqs, 1) == rans_encode(symbols, freqs)


def test_idle_lanes_start_and_end_in_l():
    """K > n: lanes with no symbol keep their initial state L, and the stream is just the states."""
    freqs = normalize_counts(np.array([3, 1]))
    stream = rans_encode(np.array([0, 1, 0]), freqs, 8)
    assert all(int.from_bytes(stream[4 * j:4 * j + 4], "little") == rans.STATE_LOWER for j in range(3, 8))
    assert rans_decode(stream, freqs, 3, 8).tolist() == [0, 1, 0]


@settings(max_examples=300)
@given(lane_counts, st.lists(st.integers(0, 7), min_size=2, max_size=300), st.data())
def test_compiled_and_python_lane_decoders_agree_on_damaged_streams(lanes, symbols, data):
    """Same symbols or the same typed error (and message) for any cut, extension, flipped byte, wrong count
    or wrong lane count; never an untyped error."""
    symbols = np.array(symbols)
    freqs = normalize_counts(np.bincount(symbols, minlength=8))
    stream = bytearray(rans_encode(symbols, freqs, lanes))
    kind = data.draw(st.sampled_from(["cut", "extend", "flip", "state", "lanes"]))
    read_lanes = lanes
    if kind == "cut":
        stream = stream[:data.draw(st.integers(0, len(stream) - 1))]
    elif kind == "extend":
        stream += bytes(data.draw(st.lists(st.integers(0, 255), min_size=1, max_size=4)))
    elif kind == "flip":
        stream[data.draw(st.integers(0, len(stream) - 1))] ^= data.draw(st.integers(1, 255))
    elif kind == "state":  # one lane's initial state: below L, at L, or anything
        struct.pack_into("<I", stream, 4 * data.draw(st.integers(0, lanes - 1)),
                         data.draw(st.sampled_from([0, rans.STATE_LOWER - 1, rans.STATE_LOWER, 2**32 - 1])))
    else:
        read_lanes = data.draw(st.integers(1, 32).filter(lambda k: k != lanes))
    count = symbols.size + data.draw(st.sampled_from([0, 0, 0, -1, 1, 1000]))
    assert (_outcome(rans_decode, bytes(stream), freqs, count, read_lanes)
            == _outcome(_python_decode, bytes(stream), freqs, count, read_lanes))


@needs_native
@settings(max_examples=100)
@given(lane_counts, st.lists(st.integers(0, 9), min_size=1, max_size=300),
       st.lists(st.integers(0, 30), min_size=1, max_size=300), st.integers(1, 32))
def test_two_lane_streams_encoded_together_equal_each_encoded_alone(lanes, a, b, other):
    a, b = np.array(a), np.array(b)
    fa, fb = normalize_counts(np.bincount(a, minlength=10)), normalize_counts(np.bincount(b, minlength=31))
    assert (rans.rans_encode_many([(a, fa), (b, fb)], lanes=[lanes, other])
            == [rans._encode_py(a, fa, lanes), rans._encode_py(b, fb, other)])


def test_lane_counts_outside_1_to_32_are_refused_by_the_coder():
    for bad in (0, 33, -1, True, 2.0):
        with pytest.raises(ValueError):
            rans_encode(np.array([0, 1]), [PROB_SCALE // 2] * 2, bad)
        with pytest.raises(ValueError):
            rans_decode(bytes(8 * 33), [PROB_SCALE // 2] * 2, 2, bad)


def _lane_tokens(encoding, rows, cols, seed, narrow):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((rows, cols)).astype(np.float32)
    if narrow:  # favours centre prediction
        x = (np.arange(cols) * 10.0 + 0.01 * x).astype(np.float32)
    return x


def _all_decoders_outcome(payload, encoding, rows, cols):
    """The one-pass compiled path, the step-by-step path and the pure-Python coder: each gives the same
    float32 tokens or the same typed error and message."""
    outcomes = [_tokens_outcome(lambda p, e, r, c: decode_tokens(p, None, e, r, c, lanes=True), payload, encoding,
                                rows, cols),
                _tokens_outcome(lambda p, e, r, c: _reference_tokens(p, e, r, c, lanes=True), payload, encoding,
                                rows, cols)]
    native = rans.NATIVE
    rans.NATIVE = False
    try:
        outcomes.append(_tokens_outcome(lambda p, e, r, c: decode_tokens(p, None, e, r, c, lanes=True), payload,
                                        encoding, rows, cols))
    finally:
        rans.NATIVE = native
    assert outcomes[0] == outcomes[1] == outcomes[2], outcomes
    return outcomes[0]


@settings(max_examples=120, deadline=None)
@given(st.sampled_from(RANS_ENCODINGS), st.integers(1, 30), st.sampled_from([1, 2, 3, 4, 8]), lane_counts,
       st.sampled_from([1, 2]), st.integers(0, 2**32 - 1), st.booleans())
def test_lane_payloads_round_trip_in_every_decoder(encoding, rows, cols, lanes, groups, seed, narrow):
    """Random K, n (multiples of K or not, rows of cols a multiple of K or not), alphabets of 2..8 bits,
    both predictions: every decoder gives the same tokens, within the documented error."""
    from vt4dcodec.format.rans_tokens import encode_rans_tokens
    groups = groups if cols % groups == 0 else 1
    x = _lane_tokens(encoding, rows, cols, seed, narrow)
    payload = encode_rans_tokens(x, encoding, groups, lanes=lanes)
    got = _all_decoders_outcome(payload, encoding, rows, cols)
    y = np.frombuffer(got, np.float32).reshape(rows, cols)
    assert np.all(np.abs(x.astype(np.float64) - y) <= max_abs_error(x, encoding, groups=groups))
    codes = decode_rans_codes(payload, encoding, rows, cols, lanes=True)[0]
    assert codes.max() < (1 << RANS_BITS[encoding])


@settings(max_examples=150, deadline=None)
@given(st.sampled_from(RANS_ENCODINGS), st.integers(1, 40), st.sampled_from([3, 4, 8]), lane_counts,
       st.integers(0, 2**32 - 1), st.booleans(), st.integers(0, 10_000), st.integers(1, 255),
       st.sampled_from(["flip", "cut", "extend"]))
def test_damaged_lane_payloads_are_typed_errors_alike_in_every_decoder(encoding, rows, cols, lanes, seed, narrow,
                                                                       where, xor, kind):
    """Any flipped byte (the K byte, a state, the shared bytes, the table), cut or extension of a 1.5 payload:
    the same tokens or the same FormatError (class and message) from every decoder; never a crash or hang."""
    from vt4dcodec.format.rans_tokens import encode_rans_tokens
    payload = bytearray(encode_rans_tokens(_lane_tokens(encoding, rows, cols, seed, narrow), encoding, lanes=lanes))
    if kind == "flip":
        payload[where % len(payload)] ^= xor
    elif kind == "cut":
        payload = payload[:where % len(payload)]
    else:
        payload += bytes([xor]) * (1 + where % 3)
    _all_decoders_outcome(bytes(payload), encoding, rows, cols)


@settings(max_examples=150)
@given(st.binary(max_size=160), st.sampled_from(RANS_ENCODINGS))
def test_arbitrary_lane_payloads_only_raise_format_errors(blob, encoding):
    try:
        codes, scale, offset = decode_rans_codes(blob, encoding, 3, 4, lanes=True)
    except FormatError:
        return
    assert codes.shape == (3, 4) and codes.max() < (1 << RANS_BITS[encoding]) and np.all(np.isfinite(scale))


@pytest.mark.parametrize("lanes, error, match", [
    (0, MalformedSectionError, "0 rANS lanes"), (33, MalformedSectionError, "33 rANS lanes"),
    (255, MalformedSectionError, "255 rANS lanes"), (None, TruncatedError, "before its rANS lane count"),
])
def test_lane_count_byte_is_checked(lanes, error, match):
    from vt4dcodec.format.rans_tokens import _parse_payload, encode_rans_tokens
    good = encode_rans_tokens(simple_scene(ns=16, d=4, seed=5).static_tokens, "int4-rans", lanes=4)
    at = len(good) - len(_parse_payload(good, "int4-rans", 16, 4, lanes=True).stream) - 1  # right after the table
    assert good[at] == 4
    bad = good[:at] if lanes is None else good[:at] + bytes([lanes]) + good[at + 1:]
    with pytest.raises(error, match=match):
        decode_rans_codes(bad, "int4-rans", 16, 4, lanes=True)
    with pytest.raises(error, match=match):
        decode_tokens(bad, None, "int4-rans", 16, 4, lanes=True)


def test_writer_policy_lanes_only_for_big_matrices():
    """Lanes where they pay: 8 for a matrix of 2^15 values or more (K = 1 for a smaller one beside it); a
    scene with two smaller matrices keeps the 1.1-1.4 bytes and version."""
    from vt4dcodec.format.rans_tokens import DEFAULT_LANES, LANES_MIN_VALUES, _parse_payload
    small = simple_scene(ns=64, nd=32, d=8, seed=1)
    assert dumps(small, encoding="int5-rans") == dumps(small, encoding="int5-rans", rans_lanes=0)
    assert open_scene(dumps(small, encoding="int5-rans")).version == (1, 3)
    for ns, nd, want in ((LANES_MIN_VALUES // 64, 8, (DEFAULT_LANES, 1)),
                         (LANES_MIN_VALUES // 64 - 1, LANES_MIN_VALUES // 64, (1, DEFAULT_LANES))):
        scene = simple_scene(ns=ns, nd=nd, d=64, seed=2)
        f = open_scene(dumps(scene, encoding="int5-rans"))
        assert f.version == (1, 5) and f.rans_lanes
        assert f.preamble.required_flags == (layout.FLAG_ENTROPY_CODED_TOKENS | layout.FLAG_COMPACT_CAMERAS
                                             | layout.FLAG_COMPACT_CONTAINER | layout.FLAG_RANS_LANES)
        got = tuple(_parse_payload(f.raw_section(name), "int5-rans", *shape, lanes=True).lanes
                    for name, shape in (("ZSTA", f.static_shape), ("ZDYN", f.dynamic_shape)))
        assert got == want
        assert np.array_equal(f.tokens()[0], loads(dumps(scene, encoding="int5-rans", rans_lanes=0)).static_tokens)
    big = simple_scene(ns=LANES_MIN_VALUES // 64, nd=8, d=64, seed=3)
    assert open_scene(dumps(big, encoding="int5-rans", rans_lanes=0)).version == (1, 3)
    assert open_scene(dumps(big, encoding="int8")).version == (1, 3)  # not entropy-coded: no lanes


@pytest.mark.parametrize("header, cameras, flags", [
    ("compact", "compact", 0b10111), ("legacy", "compact", 0b10011), ("legacy", "legacy", 0b10001)])
def test_explicit_lanes_make_1_5_files_in_every_layout(header, cameras, flags):
    scene = simple_scene(ns=7, nd=3, d=4, seed=4)
    for lanes in (1, 3, 32):
        data = dumps(scene, encoding="int6-rans", rans_lanes=lanes, header=header, cameras=cameras)
        f = open_scene(data)
        assert f.version == (1, 5) and f.preamble.required_flags == flags
        assert np.array_equal(loads(data).static_tokens, loads(dumps(scene, encoding="int6-rans")).static_tokens)
    assert dumps(scene, encoding="int8", rans_lanes=4) == dumps(scene, encoding="int8")  # ignored there


@pytest.mark.parametrize("bad", [-1, 33, True, 2.0, "4"])
def test_bad_rans_lanes_argument_is_a_format_error(bad):
    with pytest.raises(FormatError, match="rans_lanes"):
        dumps(simple_scene(d=4), encoding="int4-rans", rans_lanes=bad)


def test_a_1_4_reader_refuses_lane_files_by_the_required_flag(monkeypatch):
    data = dumps(simple_scene(), encoding="int4-rans", rans_lanes=4)
    loads(data)
    monkeypatch.setattr(layout, "KNOWN_REQUIRED_FLAGS", layout.KNOWN_REQUIRED_FLAGS & ~layout.FLAG_RANS_LANES)
    with pytest.raises(UnsupportedFeatureError, match="upgrade"):
        loads(data)


@needs_native
@pytest.mark.parametrize("encoding, lanes, cols, groups, narrow", [
    ("int5-rans", 8, 64, 1, False), ("int5-rans", 4, 64, 1, True), ("int5-rans", 8, 64, 4, True),
    ("int8-rans", 8, 32, 1, True), ("int8-rans", 4, 32, 2, False), ("int2-rans", 8, 8, 1, False),
    ("int4-rans", 3, 12, 1, True), ("int6-rans", 16, 48, 3, False), ("int7-rans", 2, 10, 1, True),
])
def test_compiled_lane_fast_path_matches_the_reference_on_big_matrices(encoding, lanes, cols, groups, narrow):
    """Matrices big enough that the compiled decoder's branch-free rounds (whole rows where K divides d, with
    the byte-wide symbol map where the alphabet allows, and centre codes) do almost all the work: the same
    tokens as the step-by-step path and the pure-Python coder, clean and with damage late in the stream."""
    from vt4dcodec.format.rans_tokens import encode_rans_tokens
    rows = 8192 // cols
    x = _lane_tokens(encoding, rows, cols, 7, narrow)
    if narrow and encoding == "int8-rans":  # wide enough residuals to use symbols above 255 (16-bit map)
        x[::5] += np.float32(3.0)
    payload = encode_rans_tokens(x, encoding, groups, lanes=lanes)
    clean = _all_decoders_outcome(payload, encoding, rows, cols)
    assert isinstance(clean, bytes)
    rng = np.random.default_rng(11)
    for where in (*rng.integers(len(payload) - 40, len(payload), 3), len(payload) // 2):
        bad = bytearray(payload)
        bad[int(where)] ^= 0x24
        _all_decoders_outcome(bytes(bad), encoding, rows, cols)
    _all_decoders_outcome(payload[:-3], encoding, rows, cols)


@needs_native
@pytest.mark.parametrize("lanes", [2, 3, 4, 8, 32])
def test_compiled_lane_encoder_refuses_symbols_without_a_frequency(lanes):
    """In its rounds of K symbols too (the bad symbol deep inside a long run), and beside a good stream."""
    good = np.zeros(500, np.int64)
    for bad_symbol, freqs in ((2, [PROB_SCALE, 0, 0]), (3, [PROB_SCALE // 2, PROB_SCALE // 2])):
        bad = good.copy()
        bad[250] = bad_symbol
        with pytest.raises(ValueError):
            rans_encode(bad, freqs, lanes)
        with pytest.raises(ValueError):
            rans.rans_encode_many([(good, [PROB_SCALE, 0, 0]), (bad, freqs)], lanes=[lanes, 1])
