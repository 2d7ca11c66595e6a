"""Compression 2, the camera dictionary (FORMAT.md I.4.2, required flag bit 8): the writer's policy, round trips,
and what a reader refuses."""

from __future__ import annotations

import numpy as np
import pytest
import zstandard
from hypothesis import given, settings
from hypothesis import strategies as st

from format_strategies import load_vector_tool
from vt4dcodec import errors
from vt4dcodec.format import dumps, loads, open_scene
from vt4dcodec.format.camera_dictionary import CAMERA_DICTIONARY
from vt4dcodec.format.layout import (COMPRESSION_ZSTD_CAMERAS, FLAG_CAMERA_DICTIONARY, FLAG_HEADER_DICTIONARY_2,
                                     parse_preamble)

mv = load_vector_tool()


def rig_scene(seed: int, cameras: int = 4):
    """The learned test scene with ``cameras`` turning, gliding cameras (the first the reference)."""
    rng = np.random.default_rng(seed)
    scene = mv.learned_scene(quality=1)
    scene.cameras = mv.gliding(8)
    scene.extra_cameras = tuple(mv.shifted(mv.gliding(8), float(dx)) for dx in rng.choice([0.25, -0.5, 0.75, 1.5],
                                                                                           cameras - 1, replace=False))
    return scene


def compressions(data: bytes) -> dict[str, int]:
    return {e.type: e.compression for e in open_scene(data).sections}


@pytest.mark.parametrize("cameras", [1, 4])
def test_learned_files_use_it_where_it_is_shorter_and_read_back_the_same(cameras):
    tables = mv.learned_tables()
    scene = rig_scene(cameras, cameras)
    plain = dumps(scene, tables=tables, camera_dictionary=False)
    packed = dumps(scene, tables=tables)
    used = compressions(packed)
    assert (used["CAMS"] == COMPRESSION_ZSTD_CAMERAS or used.get("XCAM") == COMPRESSION_ZSTD_CAMERAS) == \
        bool(parse_preamble(packed).required_flags & FLAG_CAMERA_DICTIONARY)
    assert len(packed) <= len(plain)
    if cameras == 4:
        assert used["XCAM"] == COMPRESSION_ZSTD_CAMERAS and len(packed) < len(plain)
    a, b = loads(packed, tables=tables), loads(plain, tables=tables)
    assert np.array_equal(a.cameras.w2c, b.cameras.w2c) and np.array_equal(a.cameras.timestamps, b.cameras.timestamps)
    assert all(np.array_equal(x.w2c, y.w2c) and np.array_equal(x.K, y.K) for x, y in zip(a.extra_cameras, b.extra_cameras))
    assert dumps(a, tables=tables) == packed  # a loaded file saves to the same bytes


def test_the_choice_is_the_callers():
    """True in any compact container (the file then says 1.6), False never, and never when every section is raw
    or in the 1.0-1.2 layout."""
    int8 = mv.scene(4, 2, 3, frames=8)
    int8.cameras = mv.gliding(8)
    int8.extra_cameras = (mv.shifted(mv.gliding(8), 0.5), mv.shifted(mv.gliding(8), -0.5))
    default = dumps(int8, encoding="int8")
    assert not parse_preamble(default).required_flags & FLAG_CAMERA_DICTIONARY  # the policy: learned-rans only
    forced = dumps(int8, encoding="int8", camera_dictionary=True)
    pre = parse_preamble(forced)
    if COMPRESSION_ZSTD_CAMERAS in compressions(forced).values():
        assert pre.required_flags & FLAG_CAMERA_DICTIONARY and pre.minor == 6
    assert np.array_equal(loads(forced).cameras.w2c, loads(default).cameras.w2c)
    tables = mv.learned_tables()
    assert COMPRESSION_ZSTD_CAMERAS not in compressions(dumps(rig_scene(0), tables=tables, camera_dictionary=False)).values()
    assert COMPRESSION_ZSTD_CAMERAS not in compressions(dumps(rig_scene(0), tables=tables, compression_level=None)).values()
    with pytest.raises(errors.FormatError, match="compact"):
        dumps(int8, encoding="int8", header="legacy", camera_dictionary=True)
    with pytest.raises(errors.FormatError, match="camera_dictionary"):
        dumps(int8, encoding="int8", camera_dictionary=1)


def test_a_frame_that_names_a_dictionary_is_refused_with_either_compression():
    tables = mv.learned_tables()
    data = dumps(rig_scene(1), tables=tables)
    header, sections = mv.split(data)
    raw = bytes(open_scene(data).raw_section("CAMS"))
    pre = parse_preamble(data)
    for compression in (2, 1):
        bad = [list(s) for s in sections]
        cams = mv.find(bad, "CAMS")
        cams[2] = compression
        cams[3] = zstandard.ZstdCompressor(level=3, dict_data=zstandard.ZstdCompressionDict(CAMERA_DICTIONARY),
                                           write_dict_id=True, write_content_size=True).compress(raw)
        with pytest.raises(errors.MalformedSectionError, match="dictionary id"):
            loads(mv.rebuild_1_3(header, bad, minor=6, required_flags=pre.required_flags & ~FLAG_HEADER_DICTIONARY_2),
                  tables=tables)  # the header compressed again with dictionary 1


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 6))
def test_round_trip_property(seed, cameras):
    """Any rig of the test scene: the dictionary-compressed file reads the cameras of the plain one and re-saves
    to its own bytes."""
    tables = mv.learned_tables()
    scene = rig_scene(seed % 1000, min(cameras, 5))
    packed = dumps(scene, tables=tables)
    plain = loads(dumps(scene, tables=tables, camera_dictionary=False), tables=tables)
    back = loads(packed, tables=tables)
    assert np.array_equal(back.cameras.K, plain.cameras.K) and np.array_equal(back.cameras.w2c, plain.cameras.w2c)
    assert dumps(back, tables=tables) == packed
