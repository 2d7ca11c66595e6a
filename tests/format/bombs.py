"""Decompression bombs: small valid containers whose zstd sections declare (and really hold) many bytes of zeros
within the format's limits (issue 52: a 16.9 KB scene made ``load`` peak at 1,072 MB).  Shared by the
decoded-size budget tests and their subprocess memory probe."""

from __future__ import annotations

import numpy as np
import zstandard

from format_strategies import load_vector_tool, simple_scene
from vt4dcodec.format import dumps
from vt4dcodec.format.encodings import payload_size

MV = load_vector_tool()
_VALUE_BYTES = {"float32": 4.0, "float16": 2.0, "int8": 1.0, "int4": 0.5}


def token_bomb(encoding: str, rows: int, d: int = 1024) -> bytes:
    """A 1.0 container of ``encoding`` whose two token matrices are (rows, d) zeros, zstd-compressed (level 19:
    ~8 KB for 256 MiB), with valid quantization parameters (scale 1, offset 0) for the affine encodings."""
    header, sections = MV.split(dumps(simple_scene(ns=3, nd=2, d=4, encoding=encoding), header="legacy"))
    for name in ("static_shape", "dynamic_shape"):
        header[name] = header["fingerprint"][name] = [rows, d]
    size = payload_size(encoding, rows, d)
    frame = zstandard.ZstdCompressor(level=19).compress(bytes(size))
    for name in ("ZSTA", "ZDYN"):
        section = MV.find(sections, name)
        section[2], section[3], section[4] = 1, frame, size  # zstd, stored bytes, raw_length
    if encoding in ("int8", "int4"):
        quant = np.ones(d, "<f4").tobytes() + np.zeros(d, "<f4").tobytes()
        for name in ("QSTA", "QDYN"):
            section = MV.find(sections, name)
            section[2], section[3], section[4] = 0, quant, len(quant)
    return MV.rebuild(header, sections)


def rows_within(encoding: str, budget: int, d: int = 1024) -> int:
    """The most rows of a :func:`token_bomb` whose decoded size (FORMAT.md I.7: both sections' raw lengths and
    float32 matrices, plus small change for the cameras and quantization) stays within ``budget``."""
    return int((budget - (1 << 16)) // (2 * d * (_VALUE_BYTES[encoding] + 4)))


def the_issue_bomb() -> bytes:
    """Issue 52's bomb: float32 tokens, two (65536, 1024) matrices of zeros (2 x 256 MiB) in ~17 KB."""
    return token_bomb("float32", 1 << 16)


def camera_bomb(frames: int = 1 << 16) -> bytes:
    """A 1.0 container whose float64 cameras section holds ``frames`` copies of one valid pose (13 MB raw at
    the 65,536-frame limit), zstd-compressed to a few KB."""
    header, sections = MV.split(dumps(simple_scene(ns=3, nd=2, d=4, frames=2), header="legacy"))
    header["cameras"]["num_frames"] = frames
    k = np.tile(np.array([[50.0, 0, 16], [0, 50.0, 12], [0, 0, 1]]), (frames, 1, 1))
    raw = k.astype("<f8").tobytes() + np.tile(np.eye(4), (frames, 1, 1)).astype("<f8").tobytes()
    cams = MV.find(sections, "CAMS")
    cams[2], cams[3], cams[4] = 1, zstandard.ZstdCompressor(level=19).compress(raw), len(raw)
    return MV.rebuild(header, sections)
