"""Header dictionary 2 (FORMAT.md I.3.2, format 1.6, required flag bit 7): the compact header of a learned-rans
file compressed with dictionary 1 followed by a header of today's multi-camera encodes."""

from __future__ import annotations

import zlib

import msgpack
import numpy as np
import pytest

from vt4dcodec import errors
from vt4dcodec.format import dumps, loads, open_scene
from vt4dcodec.format.header import (HEADER_DICTIONARY, HEADER_DICTIONARY_2, HEADER_DICTIONARY_2_TEMPLATE,
                                     compress_header, decompress_header)
from vt4dcodec.format.layout import FLAG_COMPACT_CONTAINER, FLAG_HEADER_DICTIONARY_2, parse_preamble

from test_learned import TABLES, make_scene


def test_dictionary_2_is_pinned():
    """FORMAT.md I.3.2: dictionary 1 then 540 bytes of shortest-form msgpack; 1,178 bytes, CRC-32 0xF52C3009."""
    assert HEADER_DICTIONARY_2[:638] == HEADER_DICTIONARY
    assert HEADER_DICTIONARY_2[638:] == msgpack.packb(HEADER_DICTIONARY_2_TEMPLATE, use_bin_type=True)
    assert len(HEADER_DICTIONARY_2) == 1178 and zlib.crc32(HEADER_DICTIONARY_2) == 0xF52C3009
    assert HEADER_DICTIONARY_2[638:657].hex(" ") == "87 ac 73 74 61 74 69 63 5f 73 68 61 70 65 92 cd 01 40 20"


def test_a_frame_reads_only_with_its_own_dictionary():
    raw = msgpack.packb({"encoding": "learned-rans", "metadata": {"vt4d": {"source_cameras": ["cam00", "cam01"]}}})
    for number in (1, 2):
        assert decompress_header(compress_header(raw, dictionary=number), dictionary=number) == raw
    assert len(compress_header(raw, dictionary=2)) < len(compress_header(raw, dictionary=1))


def multi_camera_scene(cameras: int = 10):
    scene = make_scene(quality=2)
    scene.metadata = {"vt4d": {"source_camera": "cam00", "clip_start": 0, "clip_frames": 2, "depth_source": "capture",
                               "source_cameras": [f"cam{i:02d}" for i in range(cameras)]}}
    return scene


def test_learned_files_take_dictionary_2_when_it_is_shorter_and_read_back():
    scene = multi_camera_scene()
    data = dumps(scene, tables=TABLES)
    pre = parse_preamble(data)
    assert pre.required_flags & FLAG_HEADER_DICTIONARY_2 and pre.required_flags & FLAG_COMPACT_CONTAINER
    assert pre.minor == 6
    old = dumps(scene, tables=TABLES, header_dictionary=1)
    assert not parse_preamble(old).required_flags & FLAG_HEADER_DICTIONARY_2
    assert len(data) < len(old) - 20  # the source-camera list and key names are matched
    a, b = loads(data, tables=TABLES), loads(old, tables=TABLES)
    assert a.metadata == b.metadata == scene.metadata
    assert np.array_equal(a.static_tokens, b.static_tokens)
    open_scene(data).verify()


def test_other_encodings_keep_dictionary_1_and_their_version():
    scene = make_scene(quality=None)
    scene.encoding = "int4"
    data = dumps(scene)
    pre = parse_preamble(data)
    assert not pre.required_flags & FLAG_HEADER_DICTIONARY_2 and pre.minor == 3
    forced = dumps(scene, header_dictionary=2)
    assert parse_preamble(forced).required_flags & FLAG_HEADER_DICTIONARY_2 and parse_preamble(forced).minor == 6
    assert np.array_equal(loads(forced).static_tokens, loads(data).static_tokens)


@pytest.mark.parametrize("kw", [dict(header_dictionary=3), dict(header_dictionary=True),
                                dict(header_dictionary=2, header="legacy")])
def test_bad_header_dictionary_options_are_refused(kw):
    with pytest.raises(errors.FormatError, match="header_dictionary"):
        dumps(make_scene(), tables=TABLES, **kw)
