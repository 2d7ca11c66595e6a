"""Adaptive rows of learned-rans token streams (format 1.6, required flag bit 10, FORMAT.md I.6.2): the C coder
and the pure-Python reference agree, the rule is the spec's, the writer's policy, the flag's checks and damaged
payloads. Tables are made with numpy (no model, no torch)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vt4dcodec import errors
from vt4dcodec.format import dumps, loads, open_scene, rans
from vt4dcodec.format.layout import FLAG_ADAPTIVE_TOKENS

from test_learned import NS, TABLES, laplace_table, make_scene


def random_rows(rng: np.random.Generator, rows: int, alphabet: int) -> np.ndarray:
    """(rows, alphabet) tables: each a run of n >= 1 positive frequencies summing to 2^14, then zeros."""
    out = np.zeros((rows, alphabet), np.int64)
    for t in range(rows):
        n = int(rng.integers(1, alphabet + 1))
        w = rng.random(n) ** 3 + 1e-3
        f = np.maximum(1, np.floor(w / w.sum() * 16384)).astype(np.int64)
        f[np.argmax(f)] += 16384 - f.sum()
        out[t, :n] = f
    return out


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 500), st.integers(1, 40))
def test_adaptive_coder_c_and_python_agree(seed, n, alphabet):
    rng = np.random.default_rng(seed)
    tables = random_rows(rng, int(rng.integers(1, 6)), alphabet)
    ctx = rng.integers(0, len(tables), n)
    counts = (tables > 0).sum(axis=1)
    symbols = np.array([rng.integers(0, counts[t]) if rng.random() < 0.4 else 0 for t in ctx], np.int64)
    stream = rans.rans_encode_ctx(symbols, ctx, tables, adaptive=True)
    assert stream == rans._encode_ctx_py(symbols, ctx.astype(np.uint16), tables.astype(np.uint32), True)
    assert np.array_equal(rans.rans_decode_ctx(stream, ctx, tables, adaptive=True), symbols)
    x = int.from_bytes(stream[:4], "little")
    assert np.array_equal(rans._decode_ctx_py(stream, x, ctx.astype(np.uint16), tables.astype(np.uint32), None, True),
                          symbols)


def test_the_rows_follow_the_spec_rule():
    """FORMAT.md I.6.2's arithmetic by hand for one row of 3 symbols: a = 4 F, D = n + k + 3, the starts."""
    row = np.array([[4096, 8192, 4096]])
    rows = rans.AdaptiveRows(row)
    assert rows.starts(0) == [0, (16384 * 16381 >> 16) + 1, (49152 * 16381 >> 16) + 2, 16384]
    rows.update(0, 2)  # D = 3 + 0 + 3 = 6: a[1], a[2] fall by a fifth-ish (floor(a / 6))
    assert rows._row(0)[0] == [0, 16384 - 16384 // 6, 49152 - 49152 // 6, 65536]
    rows.update(0, 0)  # D = 7: a[1], a[2] rise towards 2^16
    a1, a2 = 16384 - 16384 // 6, 49152 - 49152 // 6
    assert rows._row(0)[0] == [0, a1 + (65536 - a1) // 7, a2 + (65536 - a2) // 7, 65536]
    starts = rows.starts(0)
    assert starts[0] == 0 and starts[-1] == 16384 and all(b > a for a, b in zip(starts, starts[1:]))


def test_a_row_that_sees_one_symbol_codes_it_cheaper():
    table = np.stack([laplace_table(3, 1.0)])
    symbols = np.full(400, 6)  # the row's last symbol, rare under the table, every time
    fixed = rans.rans_encode_ctx(symbols, np.zeros(400), table)
    adaptive = rans.rans_encode_ctx(symbols, np.zeros(400), table, adaptive=True)
    assert len(adaptive) < len(fixed) / 4


def test_every_frequency_stays_positive_after_a_long_run():
    """After thousands of one symbol the others keep frequency >= 1, so a later different symbol still codes."""
    table = np.stack([laplace_table(2, 0.5)])
    symbols = np.concatenate([np.full(5000, 2), [0, 4, 1]])
    stream = rans.rans_encode_ctx(symbols, np.zeros(symbols.size), table, adaptive=True)
    assert np.array_equal(rans.rans_decode_ctx(stream, np.zeros(symbols.size), table, adaptive=True), symbols)


def test_a_symbol_beyond_the_rows_run_is_refused():
    table = np.zeros((1, 7), np.int64)
    table[0, :3] = laplace_table(1, 1.0)
    with pytest.raises(ValueError, match="frequency 0"):
        rans.rans_encode_ctx(np.array([4]), np.zeros(1), table, adaptive=True)
    with pytest.raises(ValueError, match="frequency 0"):
        rans._encode_ctx_py(np.array([4]), np.zeros(1, np.uint16), table.astype(np.uint32), True)


# --- files ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("choice", [None, True, False])
def test_files_read_back_with_and_without_adaptive_rows(choice):
    scene = make_scene(3)
    data = dumps(scene, tables=TABLES, adaptive_tokens=choice)
    f = open_scene(data, tables=TABLES)
    back = loads(data, tables=TABLES)
    reference = loads(dumps(scene, tables=TABLES, adaptive_tokens=False), tables=TABLES)
    assert np.array_equal(back.static_tokens, reference.static_tokens)
    assert np.array_equal(back.dynamic_tokens, reference.dynamic_tokens)
    if choice is not None:
        assert f.adaptive_tokens is choice
    assert dumps(back, tables=TABLES, adaptive_tokens=choice) == data  # loading and saving keeps the bytes


def test_the_policy_takes_the_shorter_streams():
    for seed in range(6):
        scene = make_scene(seed)
        lengths = {a: open_scene(dumps(scene, tables=TABLES, adaptive_tokens=a), tables=TABLES).token_bytes
                   for a in (False, True)}
        chosen = open_scene(dumps(scene, tables=TABLES), tables=TABLES)
        assert chosen.adaptive_tokens == (lengths[True] < lengths[False])
        assert chosen.token_bytes == min(lengths.values())


def test_skewed_tokens_are_shorter_with_adaptive_rows():
    """Tokens whose codes sit at one value the tables make rare: the rows learn it (the case of a real recording
    whose channels are zero more or less often than the training set's)."""
    scene = make_scene(0)
    scene.static_tokens[:] = 0.49  # code 4 at level 2 (step 1/8: 3.92 -> 4) everywhere, rare under the tables
    scene.dynamic_tokens[:] = -0.49
    fixed = open_scene(dumps(scene, tables=TABLES, adaptive_tokens=False), tables=TABLES).token_bytes
    chosen = open_scene(dumps(scene, tables=TABLES), tables=TABLES)
    assert chosen.adaptive_tokens and chosen.token_bytes < fixed - 2


def test_adaptive_tokens_must_be_a_bool_or_none():
    with pytest.raises(errors.FormatError, match="adaptive_tokens"):
        dumps(make_scene(0), tables=TABLES, adaptive_tokens=1)


def test_damaged_adaptive_payloads_give_only_library_errors():
    scene = make_scene(5)
    data = bytearray(dumps(scene, tables=TABLES, adaptive_tokens=True, compression_level=None))
    f = open_scene(bytes(data), tables=TABLES)
    entry = next(e for e in f.sections if e.type == "ZSTA")
    rng = np.random.default_rng(0)
    outcomes = set()
    for _ in range(300):
        bad = bytearray(data)
        k = entry.offset + 2 + int(rng.integers(0, entry.stored_length - 2))
        bad[k] ^= 1 << int(rng.integers(0, 8))
        try:
            loads(bytes(bad), tables=TABLES)
            outcomes.add("read")
        except errors.FormatError as e:
            outcomes.add(type(e).__name__)
    assert outcomes <= {"ChecksumError"}  # the section CRC catches a flipped bit first
    payload = bytes(f.raw_section("ZSTA"))
    from vt4dcodec.format.learned import decode_learned_tokens
    for _ in range(300):
        bad_payload = bytearray(payload)
        bad_payload[2 + int(rng.integers(0, len(payload) - 2))] ^= 1 << int(rng.integers(0, 8))
        try:
            decode_learned_tokens(bytes(bad_payload), TABLES, NS, 4, "static", views=1, adaptive=True)
        except errors.FormatError:
            pass


def test_flag_checks():
    """Bit 10 without bit 5 is a header inconsistent with its flags; the reader reports the flag."""
    scene = make_scene(1)
    data = dumps(scene, tables=TABLES, adaptive_tokens=True)
    assert open_scene(data, tables=TABLES).preamble.required_flags & FLAG_ADAPTIVE_TOKENS
    int4 = dumps(scene, encoding="int4")
    assert not open_scene(int4).adaptive_tokens
