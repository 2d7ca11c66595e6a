"""A second, minimal reader written only from FORMAT.md (struct, zlib, msgpack, zstandard; no
vt4dcodec.format import) must decode every valid vector to its expected content.  This keeps the prose
specification and the implementation honest with each other."""

from __future__ import annotations

import io
import json
import math
import struct
import zlib

import msgpack
import pytest
import zstandard

from format_strategies import REPO

VECTORS = REPO / "spec" / "vectors"
SIGNATURE = bytes.fromhex("8956543444 0d0a1a0a".replace(" ", ""))


def align64(n: int) -> int:
    return (n + 63) // 64 * 64


def read_scene(data: bytes) -> dict:
    """FORMAT.md I.10, steps 1-6 (without the rejection checks an independent reader would also need)."""
    assert data[:9] == SIGNATURE and data[9] == 0
    major, minor = struct.unpack_from("<HH", data, 10)
    required, optional, file_length, header_length, header_crc, count, table_crc, _, pre_crc = struct.unpack_from(
        "<QQQIIIIII", data, 16)
    assert zlib.crc32(data[:60]) == pre_crc and major == 1 and required == 0 and file_length == len(data)
    header_bytes = data[64:64 + header_length]
    assert zlib.crc32(header_bytes) == header_crc
    header = msgpack.unpackb(header_bytes, raw=False)
    table_start = 64 + header_length
    table = data[table_start:table_start + 40 * count]
    assert zlib.crc32(table) == table_crc
    sections, expected_offset = {}, align64(table_start + 40 * count)
    for i in range(count):
        code, flags, comp, _, offset, stored, raw, crc, _ = struct.unpack_from("<4sHBBQQQII", table, 40 * i)
        assert offset == expected_offset
        payload = data[offset:offset + stored]
        assert zlib.crc32(payload) == crc
        expected_offset = align64(offset + stored)
        if not flags & 1:
            continue  # ancillary: skip
        if comp == 1:
            payload = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(payload)).read(raw + 1)
        assert len(payload) == raw
        sections[code.decode()] = payload
    return {"minor": minor, "optional": optional, "header": header, "sections": sections}


def decode_tokens(scene: dict, tok: str, quant: str, shape: list[int]) -> list[list[float]]:
    enc, (rows, cols) = scene["header"]["encoding"], shape
    n, raw = rows * cols, scene["sections"][tok]
    if enc == "float32":
        values = list(struct.unpack(f"<{n}f", raw))
    elif enc == "float16":
        values = list(struct.unpack(f"<{n}e", raw))
    else:
        q = scene["sections"][quant]
        scale, offset = struct.unpack(f"<{cols}f", q[:4 * cols]), struct.unpack(f"<{cols}f", q[4 * cols:])
        if enc == "int8":
            codes = list(raw)
        else:
            codes = [c for b in raw for c in (b & 0x0F, b >> 4)][:n]
        # f32(f64(offset) + f64(scale) * q): round the binary64 result to binary32
        values = [struct.unpack("<f", struct.pack("<f", offset[k % cols] + scale[k % cols] * c))[0]
                  for k, c in enumerate(codes)]
    return [values[r * cols:(r + 1) * cols] for r in range(rows)]


@pytest.mark.parametrize("path", sorted((VECTORS / "valid").glob("*.vt4d")), ids=lambda p: p.stem)
def test_format_md_alone_reads_every_valid_vector(path):
    expected = json.loads(path.with_name(path.stem + ".expected.json").read_text())
    scene = read_scene(path.read_bytes())
    h = scene["header"]
    assert h["encoding"] == expected["encoding"] and h["fingerprint"] == expected["fingerprint"]
    assert h["metadata"] == expected["metadata"] and h["provenance"] == expected["provenance"]
    for tok, quant, shape_key in (("ZSTA", "QSTA", "static"), ("ZDYN", "QDYN", "dynamic")):
        got = decode_tokens(scene, tok, quant, h[f"{shape_key}_shape"])
        assert got == expected[f"{shape_key}_tokens"]
    cams, t = h["cameras"], h["cameras"]["num_frames"]
    values = struct.unpack(f"<{len(scene['sections']['CAMS']) // 8}d", scene["sections"]["CAMS"])
    K = [[list(values[9 * f + 3 * r: 9 * f + 3 * r + 3]) for r in range(3)] for f in range(t)]
    w2c = [[list(values[9 * t + 16 * f + 4 * r: 9 * t + 16 * f + 4 * r + 4]) for r in range(4)] for f in range(t)]
    assert K == expected["cameras"]["K"] and w2c == expected["cameras"]["w2c"]
    n = cams["distortion_terms"]
    dist = list(values[25 * t:25 * t + n]) or None
    ts = list(values[25 * t + n:]) if cams["has_timestamps"] else None
    assert dist == expected["cameras"]["distortion"] and ts == expected["cameras"]["timestamps"]
    assert all(math.isfinite(v) for v in values)
