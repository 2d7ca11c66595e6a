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
