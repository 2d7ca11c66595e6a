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
import numpy as np
import pytest
import zstandard
from hypothesis import given, settings
from hypothesis import strategies as st

from format_strategies import REPO, simple_scene
from vt4dcodec.format import Scene, dumps, loads  # only to make files and compare; the reader above is independent

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
    assert zlib.crc32(data[:60]) == pre_crc and major == 1 and required in (0, 1) and file_length == len(data)
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
    entropy = header["encoding"].endswith("-rans")
    assert (required == 1) == entropy and (minor >= 1 or not entropy)
    return {"minor": minor, "optional": optional, "header": header, "sections": sections}


def read_varint(raw: bytes, pos: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = raw[pos]
        value |= (byte & 0x7F) << shift
        pos, shift = pos + 1, shift + 7
        if byte < 0x80:
            assert shift <= 21 and not (byte == 0 and shift > 7)
            return value, pos


def rans_codes(raw: bytes, bits: int, rows: int, cols: int) -> tuple[list[int], list[float], list[float]]:
    """FORMAT.md I.6.1: (codes in row-major order, per-channel scale, per-channel offset)."""
    M, L = 1 << 14, 1 << 23
    (groups,) = struct.unpack_from("<H", raw, 0)
    scale = struct.unpack_from(f"<{groups}f", raw, 2)
    offset = struct.unpack_from(f"<{groups}f", raw, 2 + 4 * groups)
    pos = 2 + 8 * groups
    mode, pos = raw[pos], pos + 1
    centre = list(raw[pos:pos + cols]) if mode == 1 else None
    pos += cols if mode == 1 else 0
    alphabet = (1 << bits) if mode == 0 else (2 << bits) - 1
    first, count = struct.unpack_from("<HH", raw, pos)
    pos += 4
    freq = [0] * alphabet
    for k in range(count):
        freq[first + k], pos = read_varint(raw, pos)
    assert sum(freq) == M
    cum = [sum(freq[:s]) for s in range(alphabet)]
    x, pos = struct.unpack_from("<I", raw, pos)[0], pos + 4
    symbols = []
    for _ in range(rows * cols):
        slot = x % M
        s = max(t for t in range(alphabet) if freq[t] and cum[t] <= slot)
        x = freq[s] * (x // M) + slot - cum[s]
        while x < L:
            x, pos = x * 256 + raw[pos], pos + 1
        symbols.append(s)
    assert pos == len(raw) and x == L
    codes = symbols if mode == 0 else [s - (1 << bits) + 1 + centre[k % cols] for k, s in enumerate(symbols)]
    assert all(0 <= q < (1 << bits) for q in codes)
    width = cols // groups
    return codes, [scale[c // width] for c in range(cols)], [offset[c // width] for c in range(cols)]


def decode_tokens(scene: dict, tok: str, quant: str, shape: list[int]) -> list[list[float]]:
    enc, (rows, cols) = scene["header"]["encoding"], shape
    n, raw = rows * cols, scene["sections"][tok]
    if enc == "float32":
        values = list(struct.unpack(f"<{n}f", raw))
    elif enc == "float16":
        values = list(struct.unpack(f"<{n}e", raw))
    else:
        if enc.endswith("-rans"):
            codes, scale, offset = rans_codes(raw, int(enc[3]), rows, cols)
        else:
            q = scene["sections"][quant]
            scale, offset = struct.unpack(f"<{cols}f", q[:4 * cols]), struct.unpack(f"<{cols}f", q[4 * cols:])
        if enc == "int8":
            codes = list(raw)
        elif enc == "int4":
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


@settings(max_examples=25, deadline=None)
@given(st.sampled_from([f"int{b}-rans" for b in range(2, 9)]), st.integers(1, 40), st.sampled_from([1, 2, 4]),
       st.integers(0, 2**32 - 1), st.booleans())
def test_format_md_alone_reads_what_the_writer_makes_in_every_rans_encoding(encoding, rows, groups, seed, narrow):
    """The library's compiled rANS encoder writes streams that the spec-only decoder above reads to the
    library's own decoded values (both predictions: ``narrow`` channels favour centre prediction)."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((rows, 4)).astype(np.float32)
    if narrow:
        x = (np.arange(4) * 10.0 + 0.01 * x).astype(np.float32)
    scene = simple_scene(ns=rows, nd=3, d=4, seed=seed % 1000)
    scene = Scene(x, scene.dynamic_tokens, scene.cameras, scene.fingerprint)
    data = dumps(scene, encoding=encoding, groups=groups)
    mine = read_scene(data)
    ours = loads(data)
    for tok, shape_key, want in (("ZSTA", "static", ours.static_tokens), ("ZDYN", "dynamic", ours.dynamic_tokens)):
        got = decode_tokens(mine, tok, tok.replace("Z", "Q", 1), mine["header"][f"{shape_key}_shape"])
        assert np.array_equal(np.array(got, dtype=np.float32), want)
