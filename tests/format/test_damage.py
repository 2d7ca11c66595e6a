"""Damaged and hostile files: every failure is a typed FormatError, fast, without big allocations."""

from __future__ import annotations

import struct
import tracemalloc

import msgpack
import numpy as np
import pytest
import zstandard
from hypothesis import given
from hypothesis import strategies as st

from format_strategies import load_vector_tool, rig_scene, simple_scene
from vt4dcodec.errors import (BadMagicError, FormatError, LimitExceededError, MalformedHeaderError,
                              MalformedSectionError, TruncatedError)
from vt4dcodec.format import dumps, load, loads, open_scene, verify

mv = load_vector_tool()
SMALL = {
    "zstd": dumps(simple_scene(ns=3, nd=2, d=3, frames=2, encoding="int4", metadata={"k": [1, 2]})),
    "raw": dumps(simple_scene(ns=3, nd=2, d=3, frames=1, encoding="float32"), compression_level=None),
    "rans": dumps(simple_scene(ns=5, nd=2, d=3, frames=1, encoding="int5-rans"), compression_level=None),
    # the 1.0-1.2 layout (msgpack header, 40-byte entries, aligned payloads) stays as well guarded
    "raw_legacy": dumps(simple_scene(ns=3, nd=2, d=3, frames=1, encoding="float32"), compression_level=None,
                        header="legacy"),
    "zstd_legacy": dumps(simple_scene(ns=3, nd=2, d=3, frames=2, encoding="int4", metadata={"k": [1, 2]}),
                         header="legacy"),
    # format 1.5: entropy-coded tokens in interleaved rANS lanes (K = 3 over 15 and 6 codes), both layouts
    "rans_lanes": dumps(simple_scene(ns=5, nd=2, d=3, frames=1, encoding="int5-rans"), compression_level=None,
                        rans_lanes=3),
    "rans_lanes_legacy": dumps(simple_scene(ns=5, nd=2, d=3, frames=1, encoding="int6-rans"), rans_lanes=4,
                               header="legacy", cameras="legacy"),
    # format 1.4: the extra cameras section (XCAM) in both layouts, zstd and raw
    "extra_cameras": dumps(rig_scene(2, frames=2, ns=3, nd=2, d=3, encoding="int4")),
    "extra_cameras_raw_legacy": dumps(rig_scene(2, frames=2, ns=3, nd=2, d=3, encoding="float32"),
                                      compression_level=None, header="legacy", cameras="legacy"),
}


@pytest.mark.parametrize("kind", sorted(SMALL))
def test_every_truncation_point_raises_a_typed_error(kind):
    data = SMALL[kind]
    for cut in range(len(data)):
        with pytest.raises(FormatError) as info:
            open_scene(data[:cut]).verify()
        # an empty input is simply not a vt4d file; any prefix of one is reported as cut short
        assert isinstance(info.value, TruncatedError if cut else BadMagicError), (cut, info.value)


@pytest.mark.parametrize("kind", sorted(SMALL))
def test_every_single_byte_change_is_detected_by_verify(kind):
    data = bytearray(SMALL[kind])
    for i in range(len(data)):
        for mask in (0x01, 0x80):
            data[i] ^= mask
            with pytest.raises(FormatError):
                verify(bytes(data))
            data[i] ^= mask


@given(st.data())
def test_random_byte_flips_never_return_silently_wrong_tokens(data):
    original = SMALL["zstd"]
    good = loads(original)
    damaged = bytearray(original)
    for _ in range(data.draw(st.integers(1, 8))):
        damaged[data.draw(st.integers(0, len(damaged) - 1))] ^= data.draw(st.integers(1, 255))
    try:
        back = loads(bytes(damaged))
    except FormatError:
        return
    assert bytes(damaged) == original  # flips that cancelled out
    assert np.array_equal(back.static_tokens, good.static_tokens)


def _peak_kib(fn) -> float:
    tracemalloc.start()
    try:
        with pytest.raises(FormatError) as info:
            fn()
        return tracemalloc.get_traced_memory()[1] / 1024, info.value
    finally:
        tracemalloc.stop()


def test_absurd_token_shape_fails_fast_without_allocating():
    header, sections = mv.split(SMALL["raw"])
    header["static_shape"] = [1 << 40, 3]
    header["fingerprint"]["static_shape"] = [1 << 40, 3]
    peak, err = _peak_kib(lambda: load(mv.rebuild(header, sections)))
    assert isinstance(err, LimitExceededError) and peak < 512


def test_shape_product_limit():
    header, sections = mv.split(SMALL["raw"])
    header["static_shape"] = header["fingerprint"]["static_shape"] = [1 << 20, 4096]
    with pytest.raises(LimitExceededError, match="more than"):
        load(mv.rebuild(header, sections))


def test_zstd_bomb_stops_at_the_declared_size():
    header, sections = mv.split(SMALL["raw"])
    bomb = zstandard.ZstdCompressor(level=3, write_content_size=False).compress(b"\0" * (64 << 20))
    cams = mv.find(sections, "CAMS")
    cams[2], cams[3] = 1, bomb
    peak, err = _peak_kib(lambda: load(mv.rebuild(header, sections)))
    assert isinstance(err, MalformedSectionError) and "decompresses to more than" in str(err)
    assert peak < 4096  # the 64 MiB payload is never materialised


def test_zstd_frame_claiming_a_huge_content_size_is_refused_before_decompressing():
    header, sections = mv.split(SMALL["raw"])
    frame = zstandard.ZstdCompressor(level=3).compress(b"\0" * (64 << 20))
    cams = mv.find(sections, "CAMS")
    cams[2], cams[3] = 1, frame
    peak, err = _peak_kib(lambda: load(mv.rebuild(header, sections)))
    assert isinstance(err, MalformedSectionError) and peak < 4096


def test_header_bombs():
    _, sections = mv.split(SMALL["raw"])
    nested = b"\x91" * 100_000 + b"\x00"  # 100k nested one-element arrays
    for raw, error in ((nested, MalformedHeaderError), (b"\xdf\xff\xff\xff\xff", MalformedHeaderError),
                       (b"\xdb\xff\xff\xff\xff", MalformedHeaderError),
                       (msgpack.packb({"a": "x" * 70000}), MalformedHeaderError),
                       (msgpack.packb([1, 2]), MalformedHeaderError), (msgpack.packb({1: 2}), MalformedHeaderError)):
        peak, err = _peak_kib(lambda: load(mv.rebuild(raw, sections)))
        assert isinstance(err, (error, LimitExceededError)), err
        assert peak < 4096


def test_header_length_beyond_the_data_is_truncation_not_allocation():
    data = mv.patch_preamble(SMALL["raw"], 40, "<I", 1 << 20)
    with pytest.raises(FormatError):
        load(data)


def test_file_length_claim_larger_than_the_data():
    data = mv.patch_preamble(SMALL["raw"], 32, "<Q", 1 << 62)
    with pytest.raises(TruncatedError):
        load(data)


def test_stream_declaring_a_huge_length_reads_in_bounded_chunks():
    import io

    data = mv.patch_preamble(SMALL["raw"], 32, "<Q", 1 << 40)
    with pytest.raises(TruncatedError):
        load(io.BytesIO(data))


def test_reserved_table_bytes_and_section_flags_are_checked():
    data = SMALL["raw_legacy"]
    with pytest.raises(MalformedSectionError, match="reserved"):
        load(mv.patch_entry(data, 0, 36, "<I", 1))
    with pytest.raises(MalformedSectionError, match="reserved"):
        load(mv.patch_entry(data, 0, 4, "<H", 0x8001))
    with pytest.raises(MalformedSectionError, match="reserved"):
        load(mv.patch_entry(data, 0, 4, "<H", 0x0003))  # bit 1 (aligned) exists in compact tables only
    with pytest.raises(MalformedSectionError, match="critical"):
        load(mv.patch_entry(data, 0, 4, "<H", 0))
    compact = SMALL["raw"]  # 18-byte entries: flags is one byte at offset 4
    with pytest.raises(MalformedSectionError, match="reserved"):
        load(mv.patch_entry(compact, 0, 4, "<B", 0x05))
    with pytest.raises(MalformedSectionError, match="critical"):
        load(mv.patch_entry(compact, 0, 4, "<B", 0x00))


def test_known_section_not_allowed_for_the_encoding():
    header, sections = mv.split(SMALL["raw"])  # float32: QSTA not allowed
    with pytest.raises(MalformedSectionError, match="not allowed"):
        load(mv.rebuild(header, sections + [["QSTA", True, 0, b"\0" * 24, 24]]))


def test_non_finite_float_tokens_are_refused():
    header, sections = mv.split(SMALL["raw"])
    zsta = mv.find(sections, "ZSTA")
    zsta[3] = struct.pack("<f", float("inf")) + zsta[3][4:]
    with pytest.raises(MalformedSectionError, match="non-finite"):
        load(mv.rebuild(header, sections))


def test_int4_padding_nibble_must_be_zero():
    header, sections = mv.split(dumps(simple_scene(ns=3, nd=1, d=3, encoding="int4"), compression_level=None))
    zsta = mv.find(sections, "ZSTA")  # 9 codes: the last byte's high nibble is padding
    zsta[3] = zsta[3][:-1] + bytes([zsta[3][-1] | 0xF0])
    with pytest.raises(MalformedSectionError, match="nibble"):
        load(mv.rebuild(header, sections))


def test_wrong_input_types():
    with pytest.raises(FormatError):
        loads("not bytes")  # type: ignore[arg-type]
    with pytest.raises(FormatError):
        load(12345)  # type: ignore[arg-type]


def test_a_big_wrong_file_is_refused_from_its_first_bytes(tmp_path):
    path = tmp_path / "video.mp4"
    path.write_bytes(b"\0\0\0\x18ftypmp42" + b"\0" * (1 << 20))
    peak, err = _peak_kib(lambda: load(path))
    assert isinstance(err, BadMagicError) and peak < 256


def test_path_with_trailing_bytes_or_cut_short(tmp_path):
    path = tmp_path / "s.vt4d"
    path.write_bytes(SMALL["raw"] + b"\0")
    with pytest.raises(MalformedSectionError, match="unexpected bytes"):
        load(path)
    path.write_bytes(SMALL["raw"][:-1])
    with pytest.raises(TruncatedError):
        load(path)


def test_non_contiguous_buffer_is_a_typed_error():
    arr = np.frombuffer(SMALL["raw"], np.uint8)[::2]
    with pytest.raises(FormatError):
        load(memoryview(arr))


@given(st.binary(max_size=200))
def test_arbitrary_bytes_only_ever_raise_format_errors(blob):
    for data in (blob, SMALL["raw"][:64] + blob, SMALL["zstd"][:100] + blob):
        with pytest.raises(FormatError):
            load(data)


@given(st.integers(0, 10**6), st.binary(min_size=1, max_size=16))
def test_spliced_garbage_inside_a_valid_file_is_rejected(position, garbage):
    data = SMALL["zstd"]
    at = position % len(data)
    spliced = data[:at] + garbage + data[at + len(garbage):]
    if spliced == data:
        return
    with pytest.raises(FormatError):
        load(spliced)


SKIPPABLE_FRAME = b"\x50\x2a\x4d\x18" + (0).to_bytes(4, "little")  # an empty skippable frame (RFC 8878 3.1.2)


@pytest.mark.parametrize("content_size", [True, False])  # the one-shot path and the bounded stream path
@pytest.mark.parametrize("tail", ["skippable", "second frame", "garbage"])
def test_zstd_section_is_exactly_one_frame(content_size, tail):
    """FORMAT.md I.4: the stored bytes are exactly one zstd frame; bytes after it are an error (they were
    silently ignored before)."""
    header, sections = mv.split(SMALL["raw"])
    cams = mv.find(sections, "CAMS")
    frame = zstandard.ZstdCompressor(level=3, write_content_size=content_size).compress(bytes(cams[3]))
    cams[2], cams[3] = 1, frame
    good = load(mv.rebuild(header, sections))
    assert good.cameras.K.shape == load(SMALL["raw"]).cameras.K.shape
    extra = {"skippable": SKIPPABLE_FRAME, "second frame": frame, "garbage": b"\x01\x02\x03"}[tail]
    cams[3] = frame + extra
    # with a declared size the frame decodes in one shot and the tail is named; without one the bounded
    # stream reader may already stop on it (reading on, or failing on the garbage) -- rejected either way
    with pytest.raises(MalformedSectionError, match="follow the zstd frame" if content_size else None):
        load(mv.rebuild(header, sections))


def test_quantization_parameters_beyond_float32_are_refused_without_numeric_warnings():
    """Regression (fuzz campaign): scales and offsets whose tokens overflow float32 printed numpy
    RuntimeWarnings on the way to the MalformedSectionError."""
    import warnings

    from vt4dcodec.format.encodings import dequantize

    codes = np.full((2, 3), 255, np.uint8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(MalformedSectionError, match="non-finite"):
            dequantize(codes, np.full(3, 3e38, np.float32), np.full(3, 3e38, np.float32), 8, "int8")
