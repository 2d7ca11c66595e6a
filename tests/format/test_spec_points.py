"""FORMAT.md Part I points an independent reader tripped on: the text now says what the
reference does, and these tests pin the reference to the text."""

from __future__ import annotations

import msgpack
import pytest

from format_strategies import load_vector_tool, simple_scene
from vt4dcodec.errors import LimitExceededError, MalformedHeaderError
from vt4dcodec.format import ModelFingerprint, Provenance, dumps, loads
from vt4dcodec.format.header import unpack_header

MV = load_vector_tool()


def _with_header(edit, header_mode: str = "compact") -> bytes:
    header, sections = MV.split(dumps(simple_scene(provenance=Provenance("0.1", "2026-01-01T00:00:00Z", None,
                                                                             "encoded")), header=header_mode))
    return MV.rebuild(edit(header), sections)


@pytest.mark.parametrize("stamp", ["2026-02-30T00:00:00Z", "2026-01-01T24:00:00Z", "2026-01-01T00:00:60Z",
                                   "2026-13-01T00:00:00Z", "2025-02-29T12:00:00Z"])
def test_created_utc_must_be_a_real_instant(stamp):
    """"Text": a valid calendar date and time; the pattern alone let 2026-02-30 through."""
    def edit(h):
        h["provenance"]["created_utc"] = stamp
        return h
    with pytest.raises(MalformedHeaderError):
        loads(_with_header(edit))
    loads(_with_header(lambda h: h))  # the untouched file reads
    Provenance("0.1", "2024-02-29T23:59:59.123456789Z", None, "encoded")  # leap day, 9 fraction digits


def test_header_nesting_counts_maps_and_arrays_not_scalars():
    """I.3: 16 levels of containers, a scalar inside the innermost is fine; 17 containers are not."""
    def nested(levels: int):  # the top-level map is level 1
        value: object = 1
        for _ in range(levels - 1):
            value = [value]
        return {"x": value}
    unpack_header(msgpack.packb(nested(16)))
    with pytest.raises(LimitExceededError):
        unpack_header(msgpack.packb(nested(17)))


def test_metadata_limit_measures_the_canonical_re_encoding():
    """I.9: 262,144 bytes of the canonical encoding; wider stored forms do not count."""
    n = 40000  # stored as uint64 (9 bytes each): 360 kB; canonical (1 byte each): 40 kB
    canonical = msgpack.packb([1] * n)
    wide = canonical[:3] + b"".join(b"\xcf" + (1).to_bytes(8, "big") for _ in range(n))

    def edit(h, compact=False):
        h["metadata"] = {"wide": "PLACEHOLDER"}
        raw = msgpack.packb(MV.binary_digests(h) if compact else h, use_bin_type=True)  # I.3.1: bin digests
        return raw.replace(msgpack.packb("PLACEHOLDER"), wide)
    data = _with_header(edit, "legacy")
    assert len(data) > 262_144 + 90_000  # the stored metadata alone is 360,003 bytes
    assert loads(data).metadata["wide"] == [1] * n
    # the same header inside a compact container
    assert loads(_with_header(lambda h: edit(h, compact=True))).metadata["wide"] == [1] * n

    def too_big(h):
        h["metadata"] = {"big": ["x" * 60000] * 5}
        return msgpack.packb(MV.binary_digests(h), use_bin_type=True)
    with pytest.raises(LimitExceededError):
        loads(_with_header(too_big))


@pytest.mark.parametrize("text,ok", [("model\u0085x", True), ("caf\u00e9", True), ("tab\there", False),
                                     ("del\x7f", False), ("nul\x00", False)])
def test_no_control_characters_means_c0_and_del(text, ok):
    """"Text": C0 controls and DEL are rejected, C1 (U+0080..U+009F) and the rest are allowed."""
    fp = simple_scene().fingerprint
    args = dict(fp.to_dict(), model_id=text)
    if ok:
        ModelFingerprint.from_dict(args)
    else:
        with pytest.raises(MalformedHeaderError):
            ModelFingerprint.from_dict(args)


def test_declared_raw_lengths_are_bounded_by_the_header_before_decompression():
    """An 18 KB scene with two zstd sections of zeros declaring 256 MiB each made
    `load` allocate ~1 GB.  Now raw lengths are checked against the header before decompressing."""
    import tracemalloc

    import zstandard

    from vt4dcodec.errors import MalformedSectionError

    header, sections = MV.split(dumps(simple_scene(encoding="int8")))
    size = 64 << 20
    bomb = zstandard.ZstdCompressor(level=19).compress(bytes(size))
    for name in ("ZSTA", "ZDYN"):
        s = MV.find(sections, name)
        s[2], s[3], s[4] = 1, bomb, size  # zstd, stored bytes, raw_length
    data = MV.rebuild(header, sections)
    assert len(data) < 64_000
    tracemalloc.start()
    try:
        with pytest.raises(MalformedSectionError, match="header implies"):
            loads(data)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 << 20, peak


# --- issue 52: the spec and the library agree ----------------------------------------------------------
def _with_stored_header(edit_frame) -> bytes:
    """A compact container whose stored header (the zstd frame of I.3.1) is ``edit_frame(frame)``."""
    from vt4dcodec.format.header import compress_header

    header, sections = MV.split(dumps(simple_scene(provenance=Provenance("0.1", "2026-01-01T00:00:00Z", None,
                                                                           "encoded"))))
    frame = compress_header(msgpack.packb(MV.binary_digests(header), use_bin_type=True))
    return MV.rebuild_1_3(edit_frame(frame), sections, compress=False)


@pytest.mark.parametrize("dict_id", [0, 7])
def test_a_compact_header_frame_with_a_dictionary_id_is_rejected(dict_id):
    """I.3.1 (52.1): the frame MUST NOT carry a dictionary id, whatever its value."""
    def with_id(frame: bytes) -> bytes:
        fhd = frame[4]
        assert fhd & 0x03 == 0  # the reference writer writes none
        at = 5 if fhd & 0x20 else 6  # after the Window_Descriptor unless Single_Segment_flag
        return frame[:4] + bytes([fhd | 0x01]) + frame[5:at] + bytes([dict_id]) + frame[at:]
    loads(_with_stored_header(lambda f: f))
    with pytest.raises(MalformedHeaderError, match="dictionary id"):
        loads(_with_stored_header(with_id))


@pytest.mark.parametrize("field", ["library_version", "source_capture_id"])
@pytest.mark.parametrize("text", ["v1\n", "cap\x00", "del\x7f"])
def test_provenance_strings_have_no_control_characters(field, text):
    """I.9 (52.3): like the fingerprint's strings, written down now."""
    def edit(h):
        h["provenance"][field] = text
        return h
    with pytest.raises(MalformedHeaderError):
        loads(_with_header(edit))
    args = dict(library_version="0.1", created_utc="2026-01-01T00:00:00Z", source_capture_id=None, kind="encoded")
    with pytest.raises(MalformedHeaderError):
        Provenance(**dict(args, **{field: text}))
    Provenance(**dict(args, **{field: "caf\u00e9 \u0085 ok"}))


@pytest.mark.parametrize("n, ok", [(29_000, True), (29_200, False)])
def test_metadata_floats_count_as_float64(n, ok):
    """I.9 (52.4): the canonical size counts every float as 9 bytes, whatever width it is stored in:
    29,200 float32 values of 0.5 are 146,006 bytes stored, 262,806 canonical (over 262,144)."""
    def edit(h):
        h["metadata"] = {"f": "PLACEHOLDER"}
        raw = msgpack.packb(MV.binary_digests(h), use_bin_type=True)
        return raw.replace(msgpack.packb("PLACEHOLDER"), msgpack.packb([0.5] * n, use_single_float=True))
    assert len(msgpack.packb({"f": [0.5] * n})) == 6 + 9 * n
    data = _with_header(edit)
    if ok:
        assert loads(data).metadata["f"] == [0.5] * n
    else:
        with pytest.raises(LimitExceededError):
            loads(data)


def test_rans_payload_cut_inside_its_head_is_truncated():
    """I.11 (52.2): a 1.1 entropy-coded payload that ends inside its group count, parameters, centre codes
    or frequency table, or before its 4-byte initial state, is TruncatedError (the table said
    MalformedSectionError; every reader so far raised TruncatedError)."""
    from vt4dcodec.errors import TruncatedError
    from vt4dcodec.format.rans_tokens import _parse_payload

    header, sections = MV.split(dumps(MV.narrow_scene(24, 16), encoding="int5-rans", rans_lanes=0))  # 1.1 payloads
    for name, rows, mode in (("ZSTA", 24, 1), ("ZDYN", 16, 0)):
        payload = MV.find(sections, name)[3]
        assert MV.find(sections, name)[2] == 0 and payload[10] == mode  # raw; 1 group; prediction mode
        head = len(payload) - len(_parse_payload(payload, "int5-rans", rows, 4).stream)
        for cut in range(head + 4):
            bad = [list(s) for s in sections]
            MV.find(bad, name)[3:5] = [payload[:cut], cut]
            with pytest.raises(TruncatedError):
                loads(MV.rebuild(header, bad))


@pytest.mark.parametrize("stamp, ok", [("0000-01-01T00:00:00Z", False), ("0001-01-01T00:00:00Z", True),
                                       ("9999-12-31T23:59:59.999999999Z", True)])
def test_created_utc_years_run_from_0001_to_9999(stamp, ok):
    """"Text" (52.11): ISO 8601's year 0000 needs an agreement between the parties; this format has none."""
    if ok:
        Provenance("0.1", stamp, None, "encoded")
    else:
        with pytest.raises(MalformedHeaderError):
            Provenance("0.1", stamp, None, "encoded")


@pytest.mark.parametrize("what", ["string", "array", "map"])
def test_header_string_array_map_over_65536_is_malformed_not_a_limit(what):
    """I.7 / I.11 (52.7): these are the header's msgpack rules, so MalformedHeaderError."""
    big = {"string": "x" * 65_537, "array": [0] * 65_537, "map": {f"k{i}": 0 for i in range(65_537)}}[what]

    def edit(h):
        h["metadata"] = {"big": big}
        return msgpack.packb(MV.binary_digests(h), use_bin_type=True)
    with pytest.raises(MalformedHeaderError):
        loads(_with_header(edit))


def test_a_1_5_header_holds_exactly_the_1_0_keys():
    """I.3 (52.7): the key set holds in every minor version the document describes, 1.5 included."""
    data = MV.lanes_valid_vectors()["int4_rans_lanes_1_and_32"][0]
    assert loads(data) is not None
    header, sections = MV.split(data)
    with pytest.raises(MalformedHeaderError, match="unknown key"):
        loads(MV.rebuild_1_3(dict(header, extra=1), sections, minor=5, required_flags=MV.LANE_FLAGS))
