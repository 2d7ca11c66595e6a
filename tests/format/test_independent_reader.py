"""A second, minimal reader written only from FORMAT.md (struct, zlib, msgpack, zstandard; no
vt4dcodec.format import) must decode every valid vector to its expected content, and (Part II) read
every valid archive vector and reject every invalid one with the error class section 10.1 names.
This keeps the prose specification and the implementation honest with each other."""

from __future__ import annotations

import io
import json
import math
import re
import struct
import zlib
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np
import pytest
import zstandard
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from format_strategies import REPO

VECTORS = REPO / "spec" / "vectors"
SIGNATURE = bytes.fromhex("8956543444 0d0a1a0a".replace(" ", ""))


def align64(n: int) -> int:
    return (n + 63) // 64 * 64


# FORMAT.md I.3.1: the header dictionary is the shortest-form msgpack of this JSON value, keys in order
HEADER_DICTIONARY = msgpack.packb(
    {"encodings": ["float32", "float16", "int8", "int4", "int2-rans", "int3-rans", "int5-rans", "int6-rans",
                   "int7-rans", "int8-rans"],
     "kinds": ["generated", "estimated", "source_cameras", "vt4d-test"],
     "static_shape": [64, 32], "dynamic_shape": [32, 32], "encoding": "int4-rans",
     "cameras": {"num_frames": 8, "width": 64, "height": 64, "distortion_terms": 0, "has_timestamps": True},
     "fingerprint": {"model_id": "vt4d-tiny", "model_version": "1.0.0", "config_sha256": "0123456789abcdef",
                     "weights_sha256": "0123456789abcdef", "static_shape": [64, 32], "dynamic_shape": [32, 32],
                     "token_dtype": "float32"},
     "provenance": {"library_version": "0.1.0", "created_utc": "2026-01-01T00:00:00Z",
                    "source_capture_id": "synth-test-000000", "kind": "encoded"},
     "metadata": {"vt4d": {"source_camera": "cam00", "clip_start": 0, "clip_frames": 8,
                           "depth_source": "capture"}}})
assert len(HEADER_DICTIONARY) == 638 and zlib.crc32(HEADER_DICTIONARY) == 0xC95A6BEA  # as FORMAT.md says
# FORMAT.md I.3.2: header dictionary 2 is dictionary 1 followed by the shortest-form msgpack of this JSON value
HEADER_DICTIONARY_2 = HEADER_DICTIONARY + msgpack.packb(
    {"static_shape": [320, 32], "dynamic_shape": [32, 32], "encoding": "learned-rans",
     "cameras": {"num_frames": 8, "width": 64, "height": 64, "distortion_terms": 0, "has_timestamps": True},
     "fingerprint": {"model_id": "vt4d-tiny", "model_version": "2.0.0", "config_sha256": "", "weights_sha256": "",
                     "static_shape": [320, 32], "dynamic_shape": [32, 32], "token_dtype": "float32"},
     "provenance": {"library_version": "0.1.0", "created_utc": "2026-12-01T00:00:00Z",
                    "source_capture_id": "synth-test-000000", "kind": "encoded"},
     "metadata": {"vt4d": {"source_camera": "cam00", "clip_start": 0, "clip_frames": 8, "depth_source": "capture",
                           "source_cameras": ["cam00", "cam01", "cam02", "cam03", "cam04", "cam05", "cam06",
                                              "cam07", "cam08", "cam09"]}}})
assert len(HEADER_DICTIONARY_2) == 1178 and zlib.crc32(HEADER_DICTIONARY_2) == 0xF52C3009  # as FORMAT.md says


def compact_header(stored: bytes, dictionary_2: bool = False) -> bytes:
    """FORMAT.md I.3.1: one zstd frame, content size declared (<= 1 MiB), raw-content dictionary (I.3.2's
    dictionary 2 with required flag bit 7)."""
    declared = zstandard.frame_content_size(stored)
    assert 0 <= declared <= 1 << 20
    dictionary = zstandard.ZstdCompressionDict(HEADER_DICTIONARY_2 if dictionary_2 else HEADER_DICTIONARY,
                                               dict_type=zstandard.DICT_TYPE_RAWCONTENT)
    frame = zstandard.ZstdDecompressor(dict_data=dictionary).decompressobj()
    out = frame.decompress(stored)
    assert frame.eof and len(out) == declared and not frame.unused_data
    return out


def _camera_dictionary() -> bytes:
    """FORMAT.md I.4.2: the camera dictionary, read from the hex block of its own text (32 lines of 64 digits)."""
    text = (REPO / "FORMAT.md").read_text()
    section = text[text.index("### I.4.2 The camera dictionary"):]
    block = section[section.index("```\n") + 4:]
    block = block[:block.index("```")]
    dictionary = bytes.fromhex("".join(block.split()))
    crc = re.search(r"CRC-32\s+`0x([0-9A-F]{8})`", section)
    assert crc is not None and len(dictionary) == 1024 and zlib.crc32(dictionary) == int(crc.group(1), 16)
    return dictionary


CAMERA_DICTIONARY = _camera_dictionary()


def read_scene(data: bytes) -> dict:
    """FORMAT.md I.10, steps 1-6 (without the rejection checks an independent reader would also need)."""
    assert data[:9] == SIGNATURE and data[9] == 0
    major, minor = struct.unpack_from("<HH", data, 10)
    required, optional, file_length, header_length, header_crc, count, table_crc, _, pre_crc = struct.unpack_from(
        "<QQQIIIIII", data, 16)
    assert zlib.crc32(data[:60]) == pre_crc and major == 1 and 0 <= required < 2048 and file_length == len(data)
    compact = bool(required & 4)  # I.3.1, I.4.1: the compact container of 1.3
    assert minor >= 3 or not compact
    assert minor >= 4 or not required & 8  # I.5.3: extra cameras since 1.4
    assert minor >= 5 or not required & 16  # I.6.1: rANS lanes since 1.5
    assert required & 1 or not required & 16  # ... only beside bit 0
    assert minor >= 6 or not required & 32  # I.6.2: learned-rans since 1.6, never beside bit 0
    assert not (required & 32 and required & 1)
    assert minor >= 6 or not required & 64  # I.5.4: fixed-point cameras since 1.6, in compact containers
    assert not required & 64 or (required & 6) == 6
    assert minor >= 6 or not required & 128  # I.3.2: header dictionary 2 since 1.6, in compact containers
    assert not required & 128 or required & 4
    assert minor >= 6 or not required & 256  # I.4.2: the camera dictionary since 1.6, in compact containers
    assert not required & 256 or required & 4
    assert minor >= 6 or not required & 1024  # I.6.2: adaptive rows since 1.6, only beside bit 5
    assert not required & 1024 or required & 32
    assert minor >= 6 or not required & 512  # I.5.5: joint extra cameras since 1.6, beside bits 3 and 6
    assert not required & 512 or (required & 72) == 72
    header_bytes = data[64:64 + header_length]
    assert zlib.crc32(header_bytes) == header_crc
    header = msgpack.unpackb(compact_header(header_bytes, bool(required & 128)) if compact else header_bytes,
                             raw=False)
    if compact:  # I.3.1: the two digests are 32-byte bin values; as hex they read as in I.8
        fp = header["fingerprint"]
        assert all(isinstance(fp[k], bytes) and len(fp[k]) == 32 for k in ("config_sha256", "weights_sha256"))
        header["fingerprint"] = dict(fp, config_sha256=fp["config_sha256"].hex(), weights_sha256=fp["weights_sha256"].hex())
    table_start = 64 + header_length
    size = 18 if compact else 40
    table = data[table_start:table_start + size * count]
    assert zlib.crc32(table) == table_crc
    sections, cursor = {}, table_start + size * count
    for i in range(count):
        if compact:  # no offsets: packed, or at the next multiple of 64 when the aligned bit says so
            code, flags, comp, stored, raw, crc = struct.unpack_from("<4sBBIII", table, 18 * i)
            assert flags < 4
            offset = align64(cursor) if flags & 2 else cursor
        else:
            code, flags, comp, _, offset, stored, raw, crc, _ = struct.unpack_from("<4sHBBQQQII", table, 40 * i)
            assert offset == align64(cursor)
        assert not any(data[cursor:offset])  # padding is zero
        payload = data[offset:offset + stored]
        assert zlib.crc32(payload) == crc
        cursor = offset + stored
        if not flags & 1:
            continue  # ancillary: skip
        assert comp in (0, 1) or (comp == 2 and required & 256)
        if comp:  # I.4, I.4.2: one frame naming no dictionary; compression 2 with the camera dictionary
            assert zstandard.get_frame_parameters(payload).dict_id == 0
            dictionary = zstandard.ZstdCompressionDict(CAMERA_DICTIONARY, dict_type=zstandard.DICT_TYPE_FULLDICT)
            decompressor = zstandard.ZstdDecompressor(dict_data=dictionary) if comp == 2 else zstandard.ZstdDecompressor()
            payload = decompressor.stream_reader(io.BytesIO(payload)).read(raw + 1)
        assert len(payload) == raw
        sections[code.decode()] = payload
    assert cursor == file_length
    learned = header["encoding"] == "learned-rans"
    assert bool(required & 32) == learned
    entropy = header["encoding"].endswith("-rans") and not learned
    assert bool(required & 1) == entropy and (minor >= 1 or not entropy)
    assert minor >= 2 or not required & 2  # compact cameras (I.5.1) since 1.2
    assert ("XCAM" in sections) == bool(required & 8)  # I.5.3: present exactly with required flag bit 3
    return {"minor": minor, "optional": optional, "required": required, "header": header, "sections": sections}


def compact_block(raw: bytes, pos: int, records: int, count: int, width: int) -> tuple[list[list[float]], int]:
    """FORMAT.md I.5.1 "Blocks": byte planes back to the predicted integers, undo the prediction, reinterpret."""
    n = records * count
    planes = raw[pos:pos + width * n]
    assert len(planes) == width * n
    e = [sum(planes[b * n + k] << (8 * b) for b in range(width)) for k in range(n)]
    mask, fmt = (1 << (8 * width)) - 1, {4: "<If", 8: "<Qd"}[width]
    u, out = [0] * count, []
    for r in range(records):
        u = [(u[j] + e[r * count + j]) & mask if r else e[j] for j in range(count)]
        out.append([struct.unpack(fmt[0] + fmt[2], struct.pack(fmt[:2], x))[0] for x in u])
    return out, pos + width * n


def read_cameras(scene: dict, raw: bytes | None = None, *, extra: bool = False) -> dict:
    """The cameras section: I.5 (float64 throughout) or, with required flag bit 1, I.5.1 (compact); with
    ``extra`` one record of the extra cameras section (I.5.3): the same encoding, without distortion and
    timestamps."""
    cams, raw = scene["header"]["cameras"], scene["sections"]["CAMS"] if raw is None else raw
    t, n, has_ts = cams["num_frames"], cams["distortion_terms"], cams["has_timestamps"]
    if extra:
        n, has_ts = 0, False
    if not scene["required"] & 2:
        assert len(raw) == 8 * (25 * t + n + (t if has_ts else 0))
        values = struct.unpack(f"<{len(raw) // 8}d", raw)
        K = [[list(values[9 * f + 3 * r: 9 * f + 3 * r + 3]) for r in range(3)] for f in range(t)]
        w2c = [[list(values[9 * t + 16 * f + 4 * r: 9 * t + 16 * f + 4 * r + 4]) for r in range(4)] for f in range(t)]
        tail = values[25 * t:]
    elif raw[0] == 0:  # I.5.4 (1.6, required flag bit 6): fixed point, predicted, zigzag varint residuals
        assert scene["required"] & 64
        flags, exps = raw[1], list(raw[2:5])
        # bit 2 must be set; bit 3 centres, bit 4 cubic prediction, bit 5 fixed-point timestamps; 6, 7 undefined
        assert flags & 4 and flags < 64 and max(exps) <= 52 and (has_ts or not flags & 32)
        n_k, n_w = (1 if flags & 1 else t), (1 if flags & 2 else t)

        def block(pos: int, records: int, scale: list[int]) -> tuple[list[list[float]], int]:
            k: list[list[int]] = []
            for r in range(records):
                row: list[int] = []
                for j in range(len(scale)):
                    z, pos = read_varint(raw, pos, limit=70)
                    if r == 0:
                        pred = 0
                    elif r == 1:
                        pred = k[0][j]
                    elif r == 2 or not flags & 16:
                        pred = 2 * k[r - 1][j] - k[r - 2][j]
                    else:  # bit 4: cubic
                        pred = 3 * k[r - 1][j] - 3 * k[r - 2][j] + k[r - 3][j]
                    row.append(pred + (z >> 1 if z % 2 == 0 else -(z >> 1) - 1))
                    assert abs(row[-1]) <= 2 ** 53
                k.append(row)
            return [[v * 2.0 ** -e for v, e in zip(row, scale)] for row in k], pos

        kv, pos = block(5, n_k, [exps[0]] * 5)
        poses, pos = block(pos, n_w, [exps[1]] * 4 + [exps[2]] * 3)
        pv = [quaternion_pose(p) for p in poses]
        if flags & 8:  # centre poses: t[i] = 0 - ((R[i][0]*c[0] + R[i][1]*c[1]) + R[i][2]*c[2])
            for p, (c0, c1, c2) in zip(pv, (q[4:] for q in poses)):
                for i in range(3):
                    p[4 * i + 3] = 0.0 - ((p[4 * i] * c0 + p[4 * i + 1] * c1) + p[4 * i + 2] * c2)
        distortion = struct.unpack(f"<{n}d", raw[pos:pos + 8 * n])
        pos += 8 * n
        if flags & 32:  # u8 e_s, then T varints predicted like the records
            assert raw[pos] <= 52
            stamps, end = block(pos + 1, t, [raw[pos]])
            assert end == len(raw)
            tail = distortion + tuple(v for (v,) in stamps)
        else:
            assert len(raw) - pos == 8 * (t if has_ts else 0)
            tail = distortion + struct.unpack(f"<{(len(raw) - pos) // 8}d", raw[pos:])
        K = [[[k[0], k[1], k[2]], [0.0, k[3], k[4]], [0.0, 0.0, 1.0]] for k in (kv[f % n_k] for f in range(t))]
        w2c = [[p[0:4], p[4:8], p[8:12], [0.0, 0.0, 0.0, 1.0]] for p in (pv[f % n_w] for f in range(t))]
    else:
        width, flags = raw[0], raw[1]
        assert width in (4, 8) and flags < (8 if scene["required"] & 4 else 4)  # bit 2: I.5.2, 1.3 only
        n_k, n_w = (1 if flags & 1 else t), (1 if flags & 2 else t)
        m = 7 if flags & 4 else 12
        assert len(raw) == 2 + width * (5 * n_k + m * n_w) + 8 * (n + (t if has_ts else 0))
        kv, pos = compact_block(raw, 2, n_k, 5, width)
        pv, pos = compact_block(raw, pos, n_w, m, width)
        if flags & 4:
            pv = [quaternion_pose(p) for p in pv]
        K = [[[k[0], k[1], k[2]], [0.0, k[3], k[4]], [0.0, 0.0, 1.0]] for k in (kv[f % n_k] for f in range(t))]
        w2c = [[p[0:4], p[4:8], p[8:12], [0.0, 0.0, 0.0, 1.0]] for p in (pv[f % n_w] for f in range(t))]
        tail = struct.unpack(f"<{(len(raw) - pos) // 8}d", raw[pos:])
    values = [v for m in K + w2c for row in m for v in row] + list(tail)
    assert all(math.isfinite(v) for v in values)
    return {"K": K, "w2c": w2c, "distortion": list(tail[:n]) or None,
            "timestamps": list(tail[n:]) if has_ts else None}


def read_extra_cameras(scene: dict) -> list[dict]:
    """FORMAT.md I.5.3: u8 N (1..63), N u32 record lengths, then the records back to back, each one camera's
    K and w2c as read_cameras reads CAMS; none without required flag bit 3."""
    raw = scene["sections"].get("XCAM")
    if raw is None:
        return []
    if scene["required"] & 512:  # I.5.5: the joint layout, decoded to I.5.4 records
        return [read_cameras(scene, record, extra=True) for record in joint_records(scene, raw)]
    count = raw[0]
    assert 1 <= count <= 63 and len(raw) >= 1 + 4 * count
    lengths = struct.unpack_from(f"<{count}I", raw, 1)
    assert 1 + 4 * count + sum(lengths) == len(raw)
    out, pos = [], 1 + 4 * count
    for length in lengths:
        out.append(read_cameras(scene, raw[pos:pos + length], extra=True))
        pos += length
    return out


def joint_records(scene: dict, raw: bytes) -> list[bytes]:
    """FORMAT.md I.5.5: u8 N, then a bit string (most significant bit first) of 18 u(5) group orders and per
    camera 4 layout bits, 3 exponents and the Exp-Golomb residuals of its integers; returns each camera's I.5.4
    record (P = 0, F, exponents, zigzag LEB128 residuals of the I.5.4 prediction)."""
    cams = scene["header"]["cameras"]
    t, width, height = cams["num_frames"], cams["width"], cams["height"]
    count = raw[0]
    assert 1 <= count <= 63
    bits = "".join(f"{b:08b}" for b in raw[1:])
    pos = 0

    def u(n: int) -> int:
        nonlocal pos
        assert pos + n <= len(bits)
        value = int(bits[pos:pos + n], 2) if n else 0
        pos += n
        return value

    def eg(k: int) -> int:
        z0 = 0
        while u(1) == 0:
            z0 += 1
            assert z0 <= 58
        q = 2 ** z0 + u(z0) - 1
        return q * 2 ** k + u(k)

    def s(z: int) -> int:
        return z // 2 if z % 2 == 0 else -(z + 1) // 2

    def zigzag_leb128(d: int) -> bytes:
        z, out = (2 * d if d >= 0 else -2 * d - 1), b""
        while z >= 128:
            out, z = out + bytes([z % 128 + 128]), z // 128
        return out + bytes([z])

    def temporal(k: list[list[int]], r: int, j: int, cubic: bool) -> int:  # I.5.4: 0, k[r-1], linear or cubic
        weights = ([], [1], [2, -1], [3, -3, 1] if cubic else [2, -1])[min(r, 3)]
        return sum(w * k[r - 1 - i][j] for i, w in enumerate(weights))

    orders = [u(5) for _ in range(18)]
    records: list[bytes] = []
    before_exps: list[int] | None = None
    before_k0: list[int] | None = None
    for c in range(count):
        b0, b1, b3, b4 = u(1), u(1), u(1), u(1)
        flags = b0 + 2 * b1 + 4 + 8 * b3 + 16 * b4
        exps = [u(6) for _ in range(3)] if c == 0 else [e + s(eg(0)) for e in before_exps]
        assert all(0 <= e <= 52 for e in exps)
        blocks = []
        for block, n, m in (("K", 1 if b0 else t, 5), ("P", 1 if b1 else t, 7)):
            k: list[list[int]] = []
            for r in range(n):
                row: list[int] = []
                for j in range(m):
                    if block == "K":
                        g = 0 if r == 0 else 1
                    else:
                        g = 2 + 4 * min(r, 3) + (0 if j < 4 else j - 3)
                    if block == "K" and r == 0:
                        if c > 0 and before_exps[0] == exps[0]:
                            fx_, s_, cx_, fy_, cy_ = before_k0
                            p = [fx_, s_, cx_, None, cy_][j] if j != 3 else row[0] + fy_ - fx_
                        else:
                            p = [0, 0, (width - 1) * 2 ** exps[0] // 2, None, (height - 1) * 2 ** exps[0] // 2][j] \
                                if j != 3 else row[0]
                    else:
                        p = temporal(k + [row], r, j, bool(b4))
                    row.append(p + s(eg(orders[g])))
                    assert abs(row[-1]) <= 2 ** 53
                k.append(row)
            blocks.append(k)
        before_exps, before_k0 = exps, blocks[0][0]
        body = b""
        for k in blocks:
            for r, row in enumerate(k):
                for j, v in enumerate(row):
                    body += zigzag_leb128(v - temporal(k, r, j, bool(b4)))
        records.append(bytes([0, flags, *exps]) + body)
    assert len(bits) - pos < 8 and not any(int(b) for b in bits[pos:])  # zero bits to the end of the last byte
    return records


def quaternion_pose(p: list[float]) -> list[float]:
    """FORMAT.md I.5.2: (qw, qx, qy, qz, t0, t1, t2) -> the 12 values of w2c rows 0..2, operation by operation."""
    w, x, y, z, t0, t1, t2 = p
    n = ((w * w + x * x) + y * y) + z * z
    assert n != 0
    s = 2 / n
    return [1 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y), t0,
            s * (x * y + w * z), 1 - s * (x * x + z * z), s * (y * z - w * x), t1,
            s * (x * z - w * y), s * (y * z + w * x), 1 - s * (x * x + y * y), t2]


def read_varint(raw: bytes, pos: int, limit: int = 21) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = raw[pos]
        value |= (byte & 0x7F) << shift
        pos, shift = pos + 1, shift + 7
        if byte < 0x80:
            assert shift <= limit and not (byte == 0 and shift > 7)
            return value, pos


def rans_codes(raw: bytes, bits: int, rows: int, cols: int, lanes: bool = False) -> tuple[list[int], list[float],
                                                                                           list[float]]:
    """FORMAT.md I.6.1: (codes in row-major order, per-channel scale, per-channel offset); ``lanes``: the file
    sets required flag bit 4 (1.5), so a lane count K follows the table and the stream has K lanes."""
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
    K = 1
    if lanes:  # 1.5: u8 K, then K initial states, lane 0 first, and one shared byte stream
        K, pos = raw[pos], pos + 1
        assert 1 <= K <= 32
    assert len(raw) >= pos + 4 * K
    x, pos = list(struct.unpack_from(f"<{K}I", raw, pos)), pos + 4 * K
    assert all(v >= L for v in x)
    symbols = []
    for k in range(rows * cols):
        j = k % K  # symbol k is lane (k mod K)'s
        slot = x[j] % M
        s = max(t for t in range(alphabet) if freq[t] and cum[t] <= slot)
        x[j] = freq[s] * (x[j] // M) + slot - cum[s]
        while x[j] < L:
            x[j], pos = x[j] * 256 + raw[pos], pos + 1
        symbols.append(s)
    assert pos == len(raw) and all(v == L for v in x)  # every lane, those without a symbol too
    codes = symbols if mode == 0 else [s - (1 << bits) + 1 + centre[k % cols] for k, s in enumerate(symbols)]
    assert all(0 <= q < (1 << bits) for q in codes)
    width = cols // groups
    return codes, [scale[c // width] for c in range(cols)], [offset[c // width] for c in range(cols)]


def learned_values(raw: bytes, tables: dict, tok: str, rows: int, cols: int, views: int,
                   adaptive: bool = False) -> list[float]:
    """FORMAT.md I.6.2: u8 level, u8 V, one rANS chain whose symbol k = i d + c uses the frequency row of its
    class (MEAN / CHANGE by the origin of static token i for V cameras, DYNAMIC) and channel; codes from the
    half-ranges the rows' symbol counts give; value f32(q * step). With ``adaptive`` (required flag bit 10) each
    row keeps a[0..n] and k, starting at 4 F(i) and 0, and moves towards each symbol it codes."""
    M, L = 1 << 14, 1 << 23
    assert len(raw) >= 6
    level, V = raw[0], raw[1]
    assert level < len(tables["steps"]) and V == views
    freqs = tables["freqs"][level]  # [class][channel] -> the positive run of the row
    half = [[(len(freqs[k][c]) - 1) // 2 for c in range(cols)] for k in (0, 2)]  # Q_s, Q_d per channel
    assert all(len(freqs[1][c]) == 4 * half[0][c] + 1 for c in range(cols))
    assert len(freqs) in (3, 5, 11) and all(len(freqs[k][c]) == len(freqs[0][c]) for k in range(3, len(freqs))
                                            for c in range(cols))
    partners = tables.get("partners")  # C = 11: each channel's partner channel, -1 or an earlier one
    assert (partners is not None) == (len(freqs) == 11)
    assert partners is None or (len(partners) == cols and all(-1 <= r < c for c, r in enumerate(partners)))
    static = tok == "ZSTA"
    origin = tables["origins"][V - 1] if static else None
    x, pos, codes = struct.unpack_from("<I", raw, 2)[0], 6, []
    assert x >= L
    previous = None  # the previous MEAN token (C = 5 or 11: context-coded MEAN tokens)
    state: dict[tuple[int, int], tuple[list[int], list[int]]] = {}  # adaptive rows: (class, channel) -> a, [k]

    def sign(v: int) -> int:
        return (v > 0) - (v < 0)

    for k in range(rows * cols):
        i, c = divmod(k, cols)
        cls = (0 if origin[i] == i else 1) if static else 2
        if cls == 0 and len(freqs) > 3:
            a = sign(codes[previous * cols + c]) if previous is not None else 0
            b = sign(codes[i * cols + partners[c]]) if partners is not None and partners[c] >= 0 else 0
            # the table of I.6.2: rows b = -1, 0, +1, columns a = -1, 0, +1
            cls = ((5, 6, 7), (3, 0, 4), (8, 9, 10))[b + 1][a + 1]
        if static and c == cols - 1 and origin[i] == i:
            previous = i
        f = freqs[cls][c]
        slot = x % M
        if adaptive:
            n = len(f)
            a, seen = state.setdefault((cls, c), ([4 * sum(f[:j]) for j in range(n + 1)], [0]))
            start = [a[j] * (M - n) // 2**16 + j for j in range(n + 1)]
            s = max(t for t in range(n) if start[t] <= slot)
            x = (start[s + 1] - start[s]) * (x // M) + slot - start[s]
            D = n + seen[0] + 3
            seen[0] += 1
            for j in range(1, n):
                a[j] = a[j] - a[j] // D if j <= s else a[j] + (2**16 - a[j]) // D
        else:
            cum = [sum(f[:s]) for s in range(len(f))]
            s = max(t for t in range(len(f)) if cum[t] <= slot)
            x = f[s] * (x // M) + slot - cum[s]
        while x < L:
            x, pos = x * 256 + raw[pos], pos + 1
        Q = half[0 if static else 1][c]
        q = s - Q if cls != 1 else codes[origin[i] * cols + c] + s - 2 * Q
        assert -Q <= q <= Q
        codes.append(q)
    assert pos == len(raw) and x == L
    steps = tables["steps"][level][0 if static else 1]
    return [struct.unpack("<f", struct.pack("<f", q * steps[k % cols]))[0] for k, q in enumerate(codes)]


LEARNED_TABLES = json.loads((VECTORS / "tables" / "vt4d-test-learned.json").read_text())
# every test model's tables (I.6.2 "Test model", "Context test model"), found by the file's fingerprint
TEST_TABLES = [json.loads(path.read_text()) for path in sorted((VECTORS / "tables").glob("*.json"))]


def decode_tokens(scene: dict, tok: str, quant: str, shape: list[int]) -> list[list[float]]:
    enc, (rows, cols) = scene["header"]["encoding"], shape
    n, raw = rows * cols, scene["sections"][tok]
    if enc == "learned-rans":  # the tables of the model the fingerprint names: here the test model's file
        tables = [t for t in TEST_TABLES if t["fingerprint"] == scene["header"]["fingerprint"]]
        assert len(tables) == 1
        views = 1 + (struct.unpack_from("<B", scene["sections"]["XCAM"], 0)[0] if "XCAM" in scene["sections"] else 0)
        values = learned_values(raw, tables[0], tok, rows, cols, views, bool(scene["required"] & 1024))
    elif enc == "float32":
        values = list(struct.unpack(f"<{n}f", raw))
    elif enc == "float16":
        values = list(struct.unpack(f"<{n}e", raw))
    else:
        if enc.endswith("-rans"):
            codes, scale, offset = rans_codes(raw, int(enc[3]), rows, cols, bool(scene["required"] & 16))
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
    cams = read_cameras(scene)
    for key in ("K", "w2c", "distortion", "timestamps"):
        assert cams[key] == expected["cameras"][key], key
    extras = read_extra_cameras(scene)
    assert [{"K": x["K"], "w2c": x["w2c"]} for x in extras] == expected.get("extra_cameras", [])


@settings(max_examples=40, deadline=None)
@given(st.sampled_from([f"int{b}-rans" for b in range(2, 9)]), st.integers(1, 40), st.sampled_from([1, 2, 4]),
       st.integers(0, 2**32 - 1), st.booleans(), st.sampled_from([None, 0, 1, 2, 3, 4, 8, 32]))
def test_format_md_alone_reads_what_the_writer_makes_in_every_rans_encoding(encoding, rows, groups, seed, narrow,
                                                                            lanes):
    """The library's compiled rANS encoder writes streams that the spec-only decoder above reads to the
    library's own decoded values (both predictions: ``narrow`` channels favour centre prediction; with
    ``lanes`` 1..32 the 1.5 lane layout, I.6.1).  The library is imported here only to make and compare files;
    the reader above uses none of it."""
    from format_strategies import simple_scene
    from vt4dcodec.format import Scene, dumps, loads

    rng = np.random.default_rng(seed)
    x = rng.standard_normal((rows, 4)).astype(np.float32)
    if narrow:
        x = (np.arange(4) * 10.0 + 0.01 * x).astype(np.float32)
    scene = simple_scene(ns=rows, nd=3, d=4, seed=seed % 1000)
    scene = Scene(x, scene.dynamic_tokens, scene.cameras, scene.fingerprint)
    data = dumps(scene, encoding=encoding, groups=groups, rans_lanes=lanes)
    mine = read_scene(data)
    assert bool(mine["required"] & 16) == bool(lanes) and (mine["minor"] == 5) == bool(lanes)
    ours = loads(data)
    for tok, shape_key, want in (("ZSTA", "static", ours.static_tokens), ("ZDYN", "dynamic", ours.dynamic_tokens)):
        got = decode_tokens(mine, tok, tok.replace("Z", "Q", 1), mine["header"][f"{shape_key}_shape"])
        assert np.array_equal(np.array(got, dtype=np.float32), want)


def _random_poses(rng: np.random.Generator, frames: int) -> np.ndarray:
    """(frames, 4, 4) world-to-camera poses: per frame a uniformly random rotation (from a unit quaternion)
    and a translation in [-5, 5] m, drawn in that order."""
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    for i in range(frames):
        q = rng.standard_normal(4)
        w, x, y, z = q / np.linalg.norm(q)
        w2c[i, :3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                          [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                          [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
        w2c[i, :3, 3] = rng.uniform(-5, 5, 3)
    return w2c


@settings(max_examples=25, deadline=None)
@given(st.integers(1, 12), st.integers(0, 2**32 - 1), st.sampled_from(["compact", "exact"]), st.booleans(),
       st.booleans(), st.booleans(), st.sampled_from(["compact", "legacy"]))
def test_format_md_alone_reads_compact_cameras_the_writer_makes(frames, seed, mode, static, zoom, timestamps,
                                                                header):
    """I.5.1, I.5.2: the spec-only cameras reader above decodes the library's compact cameras section (float32
    or float64, constant or per-frame K, static or moving pose, matrices or quaternions in a 1.3 compact
    container) to exactly the library's own trajectory."""
    from format_strategies import simple_scene
    from vt4dcodec.cameras import Trajectory
    from vt4dcodec.format import Scene, dumps, loads

    rng = np.random.default_rng(seed)
    w2c = _random_poses(rng, frames)
    if static:
        w2c[:] = w2c[0]
    K = np.tile(np.array([[80.0, 0.0, 31.5], [0.0, 80.0, 31.5], [0.0, 0.0, 1.0]]), (frames, 1, 1))
    if zoom:
        K[:, 0, 0] = K[:, 1, 1] = rng.uniform(40, 200, frames)
    traj = Trajectory(K=K, w2c=w2c, width=64, height=64,
                      timestamps=np.cumsum(rng.uniform(0, 0.1, frames)) if timestamps else None)
    base = simple_scene(ns=3, nd=2, d=4, seed=seed % 1000)
    data = dumps(Scene(base.static_tokens, base.dynamic_tokens, traj, base.fingerprint), cameras=mode,
                 header=header)
    mine, ours = read_cameras(read_scene(data)), loads(data).cameras
    assert np.array_equal(np.array(mine["K"]), ours.K) and np.array_equal(np.array(mine["w2c"]), ours.w2c)
    assert (mine["timestamps"] is None) == (ours.timestamps is None)
    if timestamps:
        assert np.array_equal(mine["timestamps"], ours.timestamps)
    if mode == "exact":
        assert np.array_equal(ours.K, traj.K) and np.array_equal(ours.w2c, traj.w2c)


@settings(max_examples=25, deadline=None)
@given(st.integers(1, 6), st.integers(1, 5), st.integers(0, 2**32 - 1), st.sampled_from(["compact", "exact", "legacy"]),
       st.sampled_from(["compact", "legacy"]), st.booleans())
def test_format_md_alone_reads_the_extra_cameras_the_writer_makes(frames, count, seed, mode, header, timestamps):
    """I.5.3: the spec-only reader above decodes every extra camera of the library's XCAM section (in each
    cameras mode and both layouts) to exactly the library's own trajectories, which share CAMS' timestamps."""
    from format_strategies import simple_scene
    from vt4dcodec.cameras import Trajectory
    from vt4dcodec.format import Scene, dumps, loads

    rng = np.random.default_rng(seed)

    def camera() -> Trajectory:
        w2c = _random_poses(rng, frames)
        if rng.integers(2):
            w2c[:] = w2c[0]
        K = np.tile(np.array([[80.0, 0.0, 31.5], [0.0, 80.0, 31.5], [0.0, 0.0, 1.0]]), (frames, 1, 1))
        K[:, 0, 0] = K[:, 1, 1] = rng.uniform(40, 200, 1 if rng.integers(2) else frames)
        return Trajectory(K=K, w2c=w2c, width=64, height=64)

    first = camera()
    if timestamps:
        first = Trajectory(first.K, first.w2c, 64, 64, timestamps=np.cumsum(rng.uniform(0, 0.1, frames)))
    base = simple_scene(ns=3, nd=2, d=4, seed=seed % 1000)
    scene = Scene(base.static_tokens, base.dynamic_tokens, first, base.fingerprint,
                  extra_cameras=[camera() for _ in range(count)])
    data = dumps(scene, cameras=mode, header=header)
    mine, ours = read_extra_cameras(read_scene(data)), loads(data)
    assert len(mine) == len(ours.extra_cameras) == count
    for got, want in zip(mine, ours.extra_cameras):
        assert np.array_equal(np.array(got["K"]), want.K) and np.array_equal(np.array(got["w2c"]), want.w2c)
        assert want.timestamps is ours.cameras.timestamps or np.array_equal(want.timestamps, ours.cameras.timestamps)
    if mode != "compact":  # float64 records: bit for bit
        assert all(a.equals(b) for a, b in zip(ours.extra_cameras, scene.extra_cameras))


# --- Part II: archives, read from FORMAT.md alone (struct, zlib, zstandard; no vt4dcodec import) ------
ARCHIVES = VECTORS / "archive"


class Rejected(Exception):
    """FORMAT.md says a reader MUST reject this file; ``kind`` is the section 10.1 error class."""

    def __init__(self, kind: str):
        super().__init__(kind)
        self.kind = kind


KEY = re.compile(rb"[A-Za-z0-9_][A-Za-z0-9._-]*(?:/[A-Za-z0-9_][A-Za-z0-9._-]*)*")  # 5.4
TAIL_MAX = 262144  # 5.7, 10


def _valid_key(key: bytes) -> bool:
    """5.4: 1..1024 bytes of UTF-8 matching SEG(/SEG)* (ASCII by the pattern, so valid UTF-8)."""
    return 1 <= len(key) <= 1024 and KEY.fullmatch(key) is not None


def _field_error(ioff: int, ilen: int, count: int, flags: int, tail: int) -> str | None:
    """6.1 field checks of a footer or slot -> None, or the class step 3 raises for a footer at the end."""
    if count > 2**24 or tail > TAIL_MAX:
        return "LimitExceededError"
    min_len = 96 if flags & 1 else 32 if flags & 2 else 32 + 48 * count  # manifest / 1.2 / 1.0 and 1.1
    if ioff < 160 or ilen < min_len or 0 < tail < 64:
        return "ArchiveError"
    return None


def _end(commit: tuple[int, ...]) -> int:
    """6.1: the commit's end, its footer offset (index offset + index length + T) + 64."""
    _gen, ioff, ilen, _icrc, _count, _flags, tail = commit
    return ioff + ilen + tail + 64


def _commit(b: bytes) -> tuple[int, ...] | None:
    """A written footer (section 6; step 3) -> (generation, index offset, index length, index crc, count,
    flags, T), or None if it is not one (magics or CRC fail); raises if it is one that fails section 6 or 6.1."""
    magic, major, _minor, flags, gen, ioff, ilen, count, icrc, end, tail, crc = struct.unpack(
        "<8sHHIQQQQI4sII", b)  # section 6: index CRC at 48, "V4AE" at 52, T (1.2) at 56, CRC at 60
    if magic != b"V4AFOOT\0" or end != b"V4AE" or zlib.crc32(b[:60]) != crc:
        return None
    if major != 1 or flags & ~3:
        raise Rejected("UnsupportedVersionError")
    tail = tail if flags & 2 else 0  # otherwise reserved, and T is 0
    error = _field_error(ioff, ilen, count, flags, tail)
    if error:
        raise Rejected(error)
    return gen, ioff, ilen, icrc, count, flags, tail


def _slot_commits(data: bytes) -> list[tuple[int, ...]]:
    """3.2: the valid slots (magic, CRC, footer offset relation, known flags, 6.1 field checks)."""
    out: list[tuple[int, ...]] = []
    for off in (32, 96):
        magic, icrc, gen, foff, ioff, ilen, count, flags, tail, _res, crc = struct.unpack_from(
            "<4sIQQQQQIIII", data, off)
        tail = tail if flags & 2 else 0  # offset 52: T when commit flag bit 1, else reserved
        if (magic == b"V4AP" and zlib.crc32(data[off:off + 60]) == crc and not flags & ~3
                and foff == ioff + ilen + tail and _field_error(ioff, ilen, count, flags, tail) is None):
            out.append((gen, ioff, ilen, icrc, count, flags, tail))
    return out


def _index(block: bytes, bound: int, segment: bool, count: int | None = None) -> dict[bytes, tuple[int, int, int, bytes]]:
    """Sections 5.1/5.2 (+ 5.5 prefix-coded summaries in segments) of one index block: key -> (payload
    offset, length, crc, summary bytes); payloads must end by ``bound``; ``count``: the reference's entry
    count a segment's own count must equal (5.5)."""
    if len(block) < 32:
        raise Rejected("ArchiveError")
    magic, esize, n, kb, sb = struct.unpack_from("<4sIQQQ", block)
    if magic != b"V4AI" or esize != 48 or 32 + 48 * n + kb + sb != len(block) or count not in (None, n):
        raise Rejected("ArchiveError")
    keys, out, koff, soff, prev, spans = block[32 + 48 * n:32 + 48 * n + kb], {}, 0, 0, None, []
    blob, summary = block[32 + 48 * n + kb:], b""
    for i in range(n):
        poff, plen, pcrc, klen, flags, ko, so, slen, res = struct.unpack_from("<QQIHHQQII", block, 32 + 48 * i)
        prefixed = segment and flags == 1
        if (flags and not prefixed) or (res and not prefixed) or klen < 1 or ko != koff or so != soff or slen > 65536:
            raise Rejected("ArchiveError")
        if prefixed and (i % 16 == 0 or not 1 <= res <= min(slen, len(summary))):
            raise Rejected("ArchiveError")
        summary = (summary[:res] if prefixed else b"") + blob[so:so + slen - res]
        if poff < 192 or poff > bound or plen > bound - poff:
            raise Rejected("ArchiveError")
        key = keys[ko:ko + klen]
        if prev is not None and key <= prev:
            raise Rejected("DuplicateKeyError" if key == prev else "ArchiveError")
        if not _valid_key(key):
            raise Rejected("ArchiveError")
        out[key], prev, koff, soff = (poff, plen, pcrc, summary), key, koff + klen, soff + slen - res
        spans.append((poff, plen))
    spans.sort()
    if any(a + n > b for (a, n), (b, _) in zip(spans, spans[1:])):
        raise Rejected("OverlappingRecordsError")
    if koff != kb or soff != sb:
        raise Rejected("ArchiveError")
    return out


def _inflate(stored: bytes, count: int) -> bytes:
    """5.6: a compressed segment (its 32 + Z stored bytes) -> the R bytes of its index block."""
    if len(stored) < 32:
        raise Rejected("ArchiveError")
    magic, _res, raw, z, _res2 = struct.unpack_from("<4sIQQQ", stored)
    if magic != b"V4AZ" or z < 1 or len(stored) != 32 + z or raw < 32 + 48 * count:
        raise Rejected("ArchiveError")
    if raw > 64 * z:  # checked before decompressing: no decompression bomb
        raise Rejected("LimitExceededError")
    frame = stored[32:]
    try:
        params = zstandard.get_frame_parameters(frame)
        if params.content_size != raw or params.dict_id != 0:  # declared (CONTENTSIZE_UNKNOWN != raw), no dictionary
            raise Rejected("ArchiveError")
        inflater = zstandard.ZstdDecompressor().decompressobj()
        out = inflater.decompress(frame)
    except zstandard.ZstdError:
        raise Rejected("ArchiveError") from None
    if not inflater.eof or inflater.unused_data or len(out) != raw:  # the only frame, exactly R bytes
        raise Rejected("ArchiveError")
    return out


def _manifest(data: bytes, ioff: int, ilen: int, cflags: int, count: int | None) -> dict[bytes, tuple[int, int, int, bytes]]:
    """5.5 (+ 5.6): the manifest at ``ioff`` with its segment 0 and the older segments -> key -> entry of
    the newest segment holding it. Its scene count MUST equal ``count`` (the footer's) or, with ``count``
    None (the manifest a light commit names, 5.7), the distinct keys of its segments."""
    block = data[ioff:ioff + ilen]
    magic, m, total = struct.unpack_from("<4sIQ", block)
    if magic != b"V4AM" or not 1 <= m <= 64 or 32 + 32 * m > ilen or count not in (None, total):
        raise Rejected("ArchiveError")
    refs, limit = [], ioff
    for k in range(m):  # every reference is checked before any segment is read
        off, length, n, crc, sflags = struct.unpack_from("<QQQII", block, 32 + 32 * k)
        sflags = sflags if cflags & 2 else 0  # 5.6: without commit flag bit 1 the field is reserved, ignored
        if sflags & ~1:  # 1.2: bit 0 = compressed, other bits MUST be 0
            raise Rejected("ArchiveError")
        if n > 2**24:
            raise Rejected("LimitExceededError")
        if k == 0 and (off, off + length) != (ioff + 32 + 32 * m, ioff + ilen):  # ends where the index block ends
            raise Rejected("ArchiveError")
        if k and (off < 160 or off + length > limit):
            raise Rejected("ArchiveError")
        if length < (33 if sflags & 1 else 32 + 48 * n):  # 5.5 for plain segments, Z >= 1 for compressed (5.6)
            raise Rejected("ArchiveError")
        limit = off if k else limit
        refs.append((off, length, n, crc, sflags))
    entries: dict[bytes, tuple[int, int, int, bytes]] = {}
    for off, length, n, crc, sflags in refs:
        stored = data[off:off + length]
        if zlib.crc32(stored) != crc:
            raise Rejected("IndexChecksumError")
        segment = _inflate(stored, n) if sflags & 1 else stored
        for key, value in _index(segment, off, segment=True, count=n).items():
            entries.setdefault(key, value)  # the newest segment holding a key wins
    if len(entries) != total:
        raise Rejected("ArchiveError")
    return entries


def _journal(tail: bytes, pos: int) -> tuple[int, int, list[tuple[bytes, int, int, int]]]:
    """5.7: the journal at ``pos`` of the tail -> (block length L, commit start, [(key, S, payload CRC, P)]).
    Its length is found by walking its entries (an item running past the tail's end: ArchiveError); then its
    CRC (IndexChecksumError); then its fields (n >= 1, the stored L equal to the walked one: ArchiveError)."""
    if len(tail) - pos < 16:
        raise Rejected("ArchiveError")
    _magic, n, start = struct.unpack_from("<4sIQ", tail, pos)
    at, entries = pos + 16, []
    for _ in range(n):  # u16 K, the key, u32 S, u32 payload CRC, u64 P
        if len(tail) - at < 2:
            raise Rejected("ArchiveError")
        (k,) = struct.unpack_from("<H", tail, at)
        if len(tail) - at < 2 + k + 16:
            raise Rejected("ArchiveError")
        s, pcrc, p = struct.unpack_from("<IIQ", tail, at + 2 + k)
        entries.append((tail[at + 2:at + 2 + k], s, pcrc, p))
        at += 2 + k + 16
    if len(tail) - at < 8:  # u32 L, u32 CRC
        raise Rejected("ArchiveError")
    length, crc = struct.unpack_from("<II", tail, at)
    if zlib.crc32(tail[pos:at + 4]) != crc:  # CRC-32 of bytes 0..L-5
        raise Rejected("IndexChecksumError")
    if n < 1 or length != at + 8 - pos:
        raise Rejected("ArchiveError")
    return length, start, entries


def _tail(data: bytes, start: int, length: int) -> list[tuple[bytes, tuple[int, int, int, bytes]]]:
    """5.7: the tail's items (footers, record frames, journals) -> [(key, entry)] of its record frames in file
    order. Every frame is listed by a journal: a journal lists exactly the frames since the previous footer
    (its commit start right after that footer), no footer follows a frame, and the last item is a journal."""
    tail, pos, out = data[start:start + length], 0, []
    after_footer: int | None = None  # the file offset right after the previous footer in the tail
    since: list[tuple[int, bytes, int, int, int]] = []  # frames since it: (offset, key, S, payload CRC, P)
    last = None  # the kind of the previous item
    while pos < length:
        if tail[pos:pos + 8] == b"V4AFOOT\0":  # an earlier commit's footer, skipped
            item = tail[pos:pos + 64]
            if len(item) < 64 or item[52:56] != b"V4AE" or zlib.crc32(item[:60]) != struct.unpack_from("<I", item, 60)[0]:
                raise Rejected("ArchiveError")
            if last == "frame":  # a footer MUST NOT follow a frame
                raise Rejected("ArchiveError")
            pos += 64
            after_footer, since, last = start + pos, [], "footer"
        elif tail[pos:pos + 4] == b"V4AR":  # a record frame (section 4)
            if length - pos < 32:
                raise Rejected("ArchiveError")
            _magic, k, flags, s, pcrc, p, meta = struct.unpack_from("<4sHHIIQI", tail, pos)
            if not 1 <= k <= 1024 or flags or s > 65536 or p > 2**40:  # section 4's limits, flags 0
                raise Rejected("ArchiveError")
            if 32 + k + s + p > length - pos:  # entirely inside the tail
                raise Rejected("ArchiveError")
            key, summary = tail[pos + 32:pos + 32 + k], tail[pos + 32 + k:pos + 32 + k + s]
            if not _valid_key(key):
                raise Rejected("ArchiveError")
            if zlib.crc32(tail[pos:pos + 24] + key + summary) != meta:
                raise Rejected("IndexChecksumError")
            out.append((key, (start + pos + 32 + k + s, p, pcrc, summary)))
            since.append((start + pos, key, s, pcrc, p))
            pos += 32 + k + s + p
            last = "frame"
        elif tail[pos:pos + 4] == b"V4AJ":  # a journal
            size, commit_start, listed = _journal(tail, pos)
            if after_footer is None or commit_start != after_footer or listed != [f[1:] for f in since]:
                raise Rejected("ArchiveError")
            pos += size
            last = "journal"
        else:
            raise Rejected("ArchiveError")
    if last != "journal":  # the tail's last item MUST be a journal
        raise Rejected("ArchiveError")
    return out


def read_archive(data: bytes) -> tuple[int, dict[str, bytes]]:
    """FORMAT.md Part II section 7 -> (generation, {key: payload})."""
    size = len(data)
    if size >= 8 and data[:8] != b"\x89V4A\r\n\x1a\n":
        raise Rejected("BadMagicError")
    if size < 256:
        raise Rejected("TruncatedError")
    _magic, major, _minor, flags = struct.unpack_from("<8sHHI", data)  # step 2: always
    if major != 1 or flags & ~3:
        raise Rejected("UnsupportedVersionError")
    commit = _commit(data[-64:])  # step 3
    slots = _slot_commits(data)
    if commit is None or _end(commit) != size:
        commit = max((c for c in slots if _end(c) <= size), default=None)
    if any(_end(c) > size and (commit is None or c[0] > commit[0]) for c in slots):  # step 4: truncation
        raise Rejected("ArchiveTruncatedError")
    if commit is None:
        raise Rejected("NoCommitError")  # step 5
    gen, ioff, ilen, icrc, count, cflags, tail = commit
    if zlib.crc32(data[ioff:ioff + ilen]) != icrc:  # step 6
        raise Rejected("IndexChecksumError")
    if not cflags & 1:  # a 1.0 index block (of this commit, or the one a light commit names)
        if struct.unpack_from("<Q", data, ioff + 8)[0] > 2**24:
            raise Rejected("LimitExceededError")
        entries = _index(data[ioff:ioff + ilen], ioff, segment=False)
    else:  # section 5.5: manifest + newest segment, older segments newest first
        entries = _manifest(data, ioff, ilen, cflags, None if tail else count)
    if tail:  # 5.7: each tail frame in file order replaces the entry of its key
        entries.update(_tail(data, ioff + ilen, tail))
    if len(entries) != count:
        raise Rejected("ArchiveError")
    out = {}
    for key, (poff, plen, pcrc, summary) in entries.items():  # step 7
        payload = data[poff:poff + plen]
        if zlib.crc32(payload) != pcrc:
            raise Rejected("RecordChecksumError")
        # verify (5.3, section 4): the frame before the payload holds the same key and summary bytes (S may be 0)
        if data[poff - len(summary):poff] != summary or data[poff - len(summary) - len(key):poff - len(summary)] != key:
            raise Rejected("ArchiveError")
        out[key.decode()] = payload
    return gen, out


ARCHIVE_EXPECTED = json.loads((ARCHIVES / "expected.json").read_text())


@pytest.mark.parametrize("name", sorted(ARCHIVE_EXPECTED), ids=lambda n: n.removesuffix(".vt4da"))
def test_format_md_alone_reads_or_rejects_every_archive_vector(name):
    import hashlib

    expected, data = ARCHIVE_EXPECTED[name], (ARCHIVES / name).read_bytes()
    if expected["valid"]:
        gen, records = read_archive(data)
        assert gen == expected["generation"]
        assert {k: hashlib.sha256(v).hexdigest() for k, v in records.items()} == expected["records"]
    else:
        with pytest.raises(Rejected) as info:
            read_archive(data)
        # section 10.1 names the class; "ArchiveError" is the catch-all (any structural violation)
        assert info.value.kind == expected["error"] or expected["error"] == "ArchiveError", info.value.kind


# --- hand-built 1.2 archives (FORMAT.md II 3-6 as bytes) until the 1.2 vectors exist ----------------------
def _frame(key: bytes, payload: bytes, summary: bytes = b"") -> bytes:
    """Section 4: a record frame."""
    head = struct.pack("<4sHHIIQ", b"V4AR", len(key), 0, len(summary), zlib.crc32(payload), len(payload))
    return head + struct.pack("<II", zlib.crc32(head + key + summary), 0) + key + summary + payload


def _index_block(entries: dict[bytes, tuple[int, int, int, bytes]]) -> bytes:
    """5.1/5.2: a plain index block of key -> (payload offset, length, crc, summary), no prefix coding."""
    table, kb, sb = b"", b"", b""
    for key in sorted(entries):
        poff, plen, pcrc, summary = entries[key]
        table += struct.pack("<QQIHHQQII", poff, plen, pcrc, len(key), 0, len(kb), len(sb), len(summary), 0)
        kb, sb = kb + key, sb + summary
    return struct.pack("<4sIQQQ", b"V4AI", 48, len(entries), len(kb), len(sb)) + table + kb + sb


def _zsegment(block: bytes, raw: int | None = None, frame: bytes | None = None) -> bytes:
    """5.6: a compressed segment (V4AZ header + one zstd frame declaring its content size)."""
    frame = zstandard.ZstdCompressor(level=19).compress(block) if frame is None else frame
    return struct.pack("<4sIQQQ", b"V4AZ", 0, len(block) if raw is None else raw, len(frame), 0) + frame


JournalEntries = list[tuple[bytes, int, int, int]]  # 5.7: (key, S, payload CRC, P) per frame


def _journal_block(start: int, frames: JournalEntries) -> bytes:
    """5.7: a journal (V4AJ) of the frames [(key, S, payload CRC, P)] of a light commit starting at ``start``."""
    body = struct.pack("<4sIQ", b"V4AJ", len(frames), start)
    body += b"".join(struct.pack("<H", len(k)) + k + struct.pack("<IIQ", s, c, p) for k, s, c, p in frames)
    body += struct.pack("<I", len(body) + 8)  # block length L, from the magic to the end of the CRC
    return body + struct.pack("<I", zlib.crc32(body))


def _footer(gen: int, ioff: int, ilen: int, count: int, icrc: int, flags: int, tail: int = 0) -> bytes:
    """Section 6: a footer (T at 56 with flag bit 1)."""
    minor = 2 if flags & 2 else 1 if flags & 1 else 0
    b = struct.pack("<8sHHIQQQQI4sI", b"V4AFOOT\0", 1, minor, flags, gen, ioff, ilen, count, icrc, b"V4AE", tail)
    return b + struct.pack("<I", zlib.crc32(b))


class _Writer:
    """Appends frames and commits (plain, segmented with optional V4AZ segments, light) per FORMAT.md II."""

    def __init__(self, preamble_flags: int = 3, minor: int = 2):
        self.data = bytearray(struct.pack("<8sHHI16x", b"\x89V4A\r\n\x1a\n", 1, minor, preamble_flags) + bytes(128))
        self.entries: dict[bytes, tuple[int, int, int, bytes]] = {}  # the current scenes
        self.changed: set[bytes] = set()  # keys written since the last full commit
        self.segments: list[tuple[int, ...]] = []  # (offset, length, count, crc, segment flags), newest first
        self.full: tuple[int, int, int, int] | None = None  # the last full commit's (ioff, ilen, icrc, flags)
        self.gen = -1
        self.frames: dict[bytes, int] = {}  # key -> offset of its last frame
        self.start = 0  # the offset right after the last footer: the next commit's start
        self.pending: JournalEntries = []  # (key, S, payload CRC, P) of the frames since it
        self.journals: list[int] = []  # offsets of the journals written

    def add(self, key: bytes, payload: bytes, summary: bytes = b"") -> None:
        self.frames[key] = off = len(self.data)
        self.data += _frame(key, payload, summary)
        self.entries[key] = (off + 32 + len(key) + len(summary), len(payload), zlib.crc32(payload), summary)
        self.changed.add(key)
        self.pending.append((key, len(summary), zlib.crc32(payload), len(payload)))

    def _commit(self, ioff: int, ilen: int, icrc: int, flags: int, tail: int = 0) -> None:
        self.gen += 1
        self.data += _footer(self.gen, ioff, ilen, len(self.entries), icrc, flags, tail)
        slot = struct.pack("<4sIQQQQQIII", b"V4AP", icrc, self.gen, ioff + ilen + tail, ioff, ilen,
                           len(self.entries), flags, tail, 0)
        at = 32 + 64 * (self.gen % 2)
        self.data[at:at + 64] = slot + struct.pack("<I", zlib.crc32(slot))
        self.start, self.pending = len(self.data), []

    def commit_plain(self, flags: int = 0) -> None:
        ioff, block = len(self.data), _index_block(self.entries)
        self.data += block
        self.full, self.changed, self.segments = (ioff, len(block), zlib.crc32(block), flags), set(), []
        self._commit(ioff, len(block), zlib.crc32(block), flags)

    def commit_segmented(self, flags: int = 3, compress: bool = False, mutate: Callable[[bytes, bytes], bytes] | None = None, sflags: int | None = None,
                         total: int | None = None) -> None:
        ioff, m = len(self.data), len(self.segments) + 1
        seg_off = ioff + 32 + 32 * m
        block = _index_block({k: self.entries[k] for k in self.changed})
        stored = _zsegment(block) if compress else block
        stored = mutate(block, stored) if mutate else stored
        sflags = int(compress) if sflags is None else sflags
        self.segments.insert(0, (seg_off, len(stored), len(self.changed), zlib.crc32(stored), sflags))
        manifest = struct.pack("<4sIQ16x", b"V4AM", m, len(self.entries) if total is None else total)
        manifest += b"".join(struct.pack("<QQQII", *ref) for ref in self.segments)
        index = manifest + stored
        self.data += index
        self.full, self.changed = (ioff, len(index), zlib.crc32(index), flags), set()
        self._commit(ioff, len(index), zlib.crc32(index), flags)

    def commit_light(self, journal: bool = True, mutate: Callable[[int, JournalEntries], bytes] | None = None) -> None:
        """5.7: the journal of the frames since the last footer (``mutate(start, frames)`` builds another one
        instead; ``journal=False``: none), then the footer naming the last full commit's index block."""
        assert self.full is not None
        if journal:
            self.journals.append(len(self.data))
            self.data += mutate(self.start, self.pending) if mutate else _journal_block(self.start, self.pending)
        ioff, ilen, icrc, flags = self.full
        self._commit(ioff, ilen, icrc, flags | 2, len(self.data) - ioff - ilen)


def _summary(key: bytes) -> bytes:
    return bytes(msgpack.packb({"bytes": 9, "kind": key.decode()}))


def _light_archive(first: dict[str, Any] | None = None, second: dict[str, Any] | None = None,
                   third: dict[str, Any] | None = None, fourth: dict[str, Any] | None = None) -> _Writer:
    """gen 0 empty; gen 1 a, b in a segment (compressed unless ``first`` says); gen 2 c in a plain segment 0
    over it (``second``: commit_segmented arguments); gen 3 light: a replaced without summary; gen 4 light: d
    without summary (``third``, ``fourth``: commit_light arguments)."""
    w = _Writer()
    w.commit_plain()
    w.add(b"a", b"payload-a", _summary(b"a"))
    w.add(b"dir/b", b"payload-b", _summary(b"b"))
    w.commit_segmented(**{"compress": True, **(first or {})})
    w.add(b"c", b"payload-c", _summary(b"c"))
    w.commit_segmented(**(second or {}))
    w.add(b"a", b"payload-a2")
    w.commit_light(**(third or {}))
    w.add(b"d", b"payload-d")
    w.commit_light(**(fourth or {}))
    return w


LIGHT_RECORDS = {"a": b"payload-a2", "dir/b": b"payload-b", "c": b"payload-c", "d": b"payload-d"}


def _resign_footer(data: bytes, **fields: int) -> bytes:
    """The last footer with ``fields`` (count, flags, tail) changed and its CRC made to hold again."""
    foot = bytearray(data[-64:])
    for name, (fmt, at) in {"count": ("<Q", 40), "flags": ("<I", 12), "tail": ("<I", 56)}.items():
        if name in fields:
            struct.pack_into(fmt, foot, at, fields[name])
    struct.pack_into("<I", foot, 60, zlib.crc32(foot[:60]))
    return data[:-64] + bytes(foot)


def _reject(data: bytes | bytearray) -> str:
    with pytest.raises(Rejected) as info:
        read_archive(bytes(data))
    return info.value.kind


def test_format_md_alone_reads_hand_built_1_2_archives() -> None:
    """II 5.6/5.7 (1.2): light commits over a manifest with a compressed older segment, a replace in the tail,
    records without summaries; the commit is found at the end, through a slot (uncommitted bytes follow), and a
    cut-off commit is ArchiveTruncatedError."""
    w = _light_archive()
    data, want = bytes(w.data), LIGHT_RECORDS
    assert read_archive(data) == (4, want)
    # 5.7: each light commit's journal ends where its footer starts, and its commit start follows the last footer
    assert [data[j:j + 4] for j in w.journals] == [b"V4AJ"] * 2
    assert [data[j + 8:j + 16] for j in w.journals] == [struct.pack("<Q", w.frames[k]) for k in (b"a", b"d")]
    assert read_archive(data + _frame(b"e", b"uncommitted")[:40]) == (4, want)  # slot A: gen 4 with its T
    assert _reject(data[:-10]) == "ArchiveTruncatedError"
    # the state after the first light commit: slot B holds gen 3; gen 4's bytes cut and slot A cleared
    gen3 = bytearray(data[:w.frames[b"d"]])
    gen3[32:96] = bytes(64)
    assert read_archive(bytes(gen3)) == (3, {k: v for k, v in want.items() if k != "d"})
    # a light commit naming a plain (1.0) index block: the generation-0 empty index, flags 2 only
    p = _Writer()
    p.commit_plain(flags=2)
    p.add(b"x", b"payload-x")
    p.commit_light()
    assert read_archive(bytes(p.data)) == (1, {"x": b"payload-x"})
    p.add(b"y", b"payload-y", _summary(b"y"))
    p.add(b"x", b"payload-x2")  # two frames in one light commit, the second replacing an earlier tail frame
    p.commit_light()
    assert read_archive(bytes(p.data)) == (2, {"x": b"payload-x2", "y": b"payload-y"})
    # a full 1.2 commit whose segment 0 is compressed
    z = _Writer()
    z.commit_plain()
    z.add(b"k", b"payload-k")
    z.commit_segmented(compress=True)
    assert read_archive(bytes(z.data)) == (1, {"k": b"payload-k"})


def test_format_md_alone_rejects_damaged_hand_built_1_2_archives() -> None:
    """The 10.2 1.2 rejections (light_tail_checksum, light_tail_too_long, light_tail_garbage, light_count,
    compressed_ratio, compressed_size_mismatch) and their neighbours, on hand-built archives."""
    w = _light_archive()
    data, d, a2 = bytes(w.data), w.frames[b"d"], w.frames[b"a"]
    read_archive(data)
    meta = bytearray(data)
    meta[d + 24] ^= 1
    assert _reject(meta) == "IndexChecksumError"  # light_tail_checksum
    assert _reject(_resign_footer(data, tail=262145)) == "LimitExceededError"  # light_tail_too_long
    assert _reject(_resign_footer(data, tail=63)) == "ArchiveError"  # T in 1..63
    garbage = bytearray(data)
    garbage[d:d + 4] = b"V4AX"
    assert _reject(garbage) == "ArchiveError"  # light_tail_garbage
    torn = bytearray(data)
    torn[a2 - 64 + 60] ^= 1  # gen 2's footer at the start of the tail: its CRC fails
    assert _reject(torn) == "ArchiveError"
    long_frame = bytearray(data)
    struct.pack_into("<Q", long_frame, d + 16, 10**6)  # payload length past the tail (meta CRC then fails too)
    assert _reject(long_frame) == "ArchiveError"
    bad_key = bytearray(data)
    bad_key[d + 32] = ord(".")  # key ".": not a 5.4 key (checked before the meta CRC, in 5.7's order)
    assert _reject(bad_key) == "ArchiveError"
    assert _reject(_resign_footer(data, count=5)) == "ArchiveError"  # light_count
    assert _reject(_resign_footer(data, flags=3 | 4)) == "UnsupportedVersionError"
    # without flag bit 1 T is 0, so the footer names another end: step 3 takes slot A (gen 4, the same commit)
    assert read_archive(_resign_footer(data, flags=1)) == (4, LIGHT_RECORDS)
    preamble = bytearray(data)
    preamble[12] = 7
    assert _reject(preamble) == "UnsupportedVersionError"

    def ratio(block: bytes, stored: bytes) -> bytes:  # compressed_ratio: R > 64 x Z
        return struct.pack("<4sIQQQ", b"V4AZ", 0, 64 * (len(stored) - 32) + 1, len(stored) - 32, 0) + stored[32:]

    def damaged(mutate: Callable[[bytes, bytes], bytes]) -> bytes:  # gen 1's compressed segment (ref 1 of the manifest gen 4 names)
        return bytes(_light_archive(first={"mutate": mutate}).data)

    assert _reject(damaged(ratio)) == "LimitExceededError"  # compressed_ratio
    assert _reject(damaged(lambda b, s: _zsegment(b + b"\0", raw=len(b)))) == "ArchiveError"  # size mismatch
    assert _reject(damaged(lambda b, s: _zsegment(b[:-1], raw=len(b)))) == "ArchiveError"  # ... the other way
    assert _reject(damaged(lambda b, s: _zsegment(
        b, frame=zstandard.ZstdCompressor(write_content_size=False).compress(b)))) == "ArchiveError"
    assert _reject(damaged(lambda b, s: _zsegment(
        b, frame=zstandard.ZstdCompressor().compress(b) + zstandard.ZstdCompressor().compress(b"")))) == "ArchiveError"
    assert _reject(damaged(lambda b, s: b"V4AY" + s[4:])) == "ArchiveError"
    assert _reject(damaged(lambda b, s: _zsegment(b, raw=32 + 48 * 2 - 1))) == "ArchiveError"  # R < 32 + 48 n
    assert _reject(damaged(lambda b, s: s[:-1])) == "ArchiveError"  # stored length != 32 + Z
    assert _reject(_light_archive(first={"sflags": 3}).data) == "ArchiveError"  # unknown segment flag bit
    # the manifest gen 4 names says 4 scenes (the light footer's count) over 3 distinct keys
    assert _reject(_light_archive(second={"total": 4}).data) == "ArchiveError"
    # a 1.1 commit (no flag bit 1) whose segment reference sets the compressed bit
    old = _Writer(preamble_flags=1, minor=1)
    old.commit_plain()
    old.add(b"k", b"payload-k")
    old.commit_segmented(flags=1, compress=True)
    assert _reject(old.data) == "ArchiveError"  # 5.6: the field is reserved there, so a V4AZ is read as a V4AI
    # ... and a plain segment in a 1.1 commit whose reserved segment-flags field is not zero: ignored (5.6)
    old = _Writer(preamble_flags=1, minor=1)
    old.commit_plain()
    old.add(b"k", b"payload-k")
    old.commit_segmented(flags=1, sflags=0xFFFFFFFF)
    assert read_archive(bytes(old.data)) == (1, {"k": b"payload-k"})
    # 5.6: the segment CRC is checked first: a damaged magic or R of a compressed segment is IndexChecksumError
    seg = w.segments[-1][0]  # gen 1's compressed segment (the oldest the manifest names)
    assert data[seg:seg + 4] == b"V4AZ"
    for at, value in ((seg, b"V4AY"), (seg + 8, struct.pack("<Q", 2**40))):
        bad = bytearray(data)
        bad[at:at + len(value)] = value
        assert _reject(bad) == "IndexChecksumError"


def test_format_md_alone_rejects_hand_built_1_2_archive_journals() -> None:
    """5.7 journals (light_journal_mismatch and its neighbours): a journal whose CRC fails, one listing a wrong
    frame or commit start, a tail ending with a frame, a footer right after a frame."""
    w = _light_archive()
    data, j4 = bytes(w.data), w.journals[-1]
    for at in (j4 + 16 + 2 + 1 + 4, len(data) - 64 - 4, len(data) - 64 - 8):  # payload CRC of d, the CRC, L
        bad = bytearray(data)
        bad[at] ^= 1
        assert _reject(bad) == "IndexChecksumError"
    bad = bytearray(data)
    bad[w.journals[0] + 8] ^= 1  # gen 3's journal (its commit start), inside gen 4's tail: its CRC fails too
    assert _reject(bad) == "IndexChecksumError"

    def listing(change: Callable[[int, JournalEntries], tuple[int, JournalEntries]]) -> bytes:  # gen 4's journal
        return bytes(_light_archive(fourth={"mutate": lambda start, f: _journal_block(*change(start, f))}).data)

    assert read_archive(listing(lambda start, f: (start, f))) == (4, LIGHT_RECORDS)  # the builder's own journal
    wrong = {  # light_journal_mismatch: each one lists a wrong frame, or the frames from a wrong start
        "payload crc": lambda start, f: (start, [(k, s, c ^ 1, p) for k, s, c, p in f]),
        "payload length": lambda start, f: (start, [(k, s, c, p + 1) for k, s, c, p in f]),
        "summary length": lambda start, f: (start, [(k, s + 1, c, p) for k, s, c, p in f]),
        "key": lambda start, f: (start, [(b"e", s, c, p) for k, s, c, p in f]),
        "extra frame": lambda start, f: (start, f + f),
        "commit start": lambda start, f: (start - 64, f),
        "gen 3's frame": lambda start, f: (start, [(b"a", 0, zlib.crc32(b"payload-a2"), 10)]),
    }
    for name, change in wrong.items():
        assert _reject(listing(change)) == "ArchiveError", name
    assert _reject(listing(lambda start, f: (start, []))) == "ArchiveError"  # n = 0 (at least 1)
    stored_length = bytearray(data)  # the stored L is not the walked length; the CRC made to hold again
    struct.pack_into("<I", stored_length, len(data) - 64 - 8, struct.unpack_from("<I", data, len(data) - 72)[0] + 1)
    struct.pack_into("<I", stored_length, len(data) - 68, zlib.crc32(stored_length[j4:len(data) - 68]))
    assert _reject(stored_length) == "ArchiveError"
    past = bytearray(data)  # an entry count the tail cannot hold: the walk runs past the tail's end
    struct.pack_into("<I", past, j4 + 4, 1000)
    assert _reject(past) == "ArchiveError"
    # a tail ending with a frame: gen 4 writes no journal
    assert _reject(_light_archive(fourth={"journal": False}).data) == "ArchiveError"
    # a footer right after a frame: gen 3 writes no journal, gen 4 does
    assert _reject(_light_archive(third={"journal": False}).data) == "ArchiveError"
    # swapped entries of a two-frame light commit over a plain (1.0) empty index
    p = _Writer()
    p.commit_plain(flags=2)
    p.add(b"x", b"payload-x")
    p.add(b"y", b"payload-y")
    p.commit_light(mutate=lambda start, f: _journal_block(start, f[::-1]))
    assert _reject(p.data) == "ArchiveError"


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 2), st.integers(0, 2**32 - 1), st.booleans())
def test_format_md_alone_reads_what_the_writer_makes_in_learned_rans(quality, seed, two_cameras):
    """learned-rans (I.6.2) as the library writes it, at either level of the test model, with one camera
    (a frame copy coded given its origin) or two: the spec-only decoder gives the library's own values."""
    from format_strategies import load_vector_tool

    mv = load_vector_tool()
    _spec_reads_the_writers_tokens(mv, mv.learned_scene(quality=quality), mv.learned_tables(), seed, two_cameras)


def _spec_reads_the_writers_tokens(mv, scene, tables, seed: int, two_cameras: bool,
                                   adaptive: bool | None = None) -> None:
    """Random tokens (beyond +-1: clipped to +-Q) in ``scene``, one or two cameras, written with ``tables`` (and
    ``adaptive_tokens=adaptive``): the spec-only decoder gives the library's own values."""
    from vt4dcodec.format import dumps, loads

    rng = np.random.default_rng(seed)
    scene.static_tokens = rng.uniform(-1.2, 1.2, scene.static_tokens.shape).astype(np.float32)
    scene.dynamic_tokens = rng.uniform(-1, 1, scene.dynamic_tokens.shape).astype(np.float32)
    if two_cameras:
        scene.extra_cameras = (mv.shifted(mv.cameras(2), 0.5),)
    data = dumps(scene, tables=tables, adaptive_tokens=adaptive)
    mine = read_scene(data)
    ours = loads(data, tables=tables)
    assert adaptive is None or bool(mine["required"] & 1024) == adaptive
    for tok, shape_key, want in (("ZSTA", "static", ours.static_tokens), ("ZDYN", "dynamic", ours.dynamic_tokens)):
        assert decode_tokens(mine, tok, tok, mine["header"][f"{shape_key}_shape"]) == want.tolist()


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.booleans())
def test_format_md_alone_reads_partner_channel_tokens(seed, two_cameras):
    """Tables of 11 classes (I.6.2, partner channels) as the library writes them, with one camera (a frame copy
    between two MEAN tokens) or two: the spec-only decoder gives the library's own values."""
    from format_strategies import load_vector_tool

    mv = load_vector_tool()
    _spec_reads_the_writers_tokens(mv, mv.partner_scene(quality=1), mv.partner_tables(), seed, two_cameras)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.booleans())
def test_format_md_alone_reads_context_coded_mean_tokens(seed, two_cameras):
    """Tables of 5 classes (I.6.2, context-coded MEAN tokens) as the library writes them, with one camera (a
    frame copy between two MEAN tokens, which the previous-MEAN rule skips) or two: the spec-only decoder
    gives the library's own values."""
    from format_strategies import load_vector_tool

    mv = load_vector_tool()
    _spec_reads_the_writers_tokens(mv, mv.context_scene(quality=1), mv.context_tables(), seed, two_cameras)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.booleans(), st.sampled_from(["plain", "context", "partner"]))
def test_format_md_alone_reads_adaptive_rows(seed, two_cameras, kind):
    """Adaptive rows (I.6.2, required flag bit 10) with tables of 3, 5 and 11 classes, as the library writes
    them: the spec-only decoder, which follows the text's a[i] and D rule, gives the library's own values."""
    from format_strategies import load_vector_tool

    mv = load_vector_tool()
    scene, tables = {"plain": (mv.learned_scene(quality=1 + seed % 2), mv.learned_tables()),
                     "context": (mv.context_scene(quality=1), mv.context_tables()),
                     "partner": (mv.partner_scene(quality=1), mv.partner_tables())}[kind]
    _spec_reads_the_writers_tokens(mv, scene, tables, seed, two_cameras, adaptive=True)


def _smooth_camera(rng: np.random.Generator, frames: int, f: float, size: int,
                   timestamps: np.ndarray | None = None) -> object:
    """A camera turning and accelerating smoothly (as the synthetic rigs' do): quaternion and position each a
    quadratic in the frame index plus a little noise."""
    from vt4dcodec.cameras import Trajectory
    from vt4dcodec.format.compact_cameras import quaternion_to_rotation

    i = np.arange(frames)[:, None]
    q = rng.normal(size=4) + i * rng.normal(scale=0.03, size=4) + i * i * rng.normal(scale=0.002, size=4)
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    w2c[:, :3, :3] = quaternion_to_rotation(q + rng.normal(scale=1e-4, size=q.shape))
    w2c[:, :3, 3] = rng.uniform(-6, 6, 3) + i * rng.normal(scale=0.05, size=3) + i * i * rng.normal(scale=0.004, size=3)
    K = np.tile(np.array([[f, 0, size / 2 - 0.5], [0, f, size / 2 - 0.5], [0, 0, 1]]), (frames, 1, 1))
    return Trajectory(K=K, w2c=w2c, width=size, height=size, timestamps=timestamps)


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 12), st.integers(0, 2**32 - 1), st.sampled_from([None, 8.0, 30.0]), st.integers(0, 2),
       st.sampled_from([(40.0, 32), (60.0, 64), (900.0, 640)]))
# regression: a pose of half a turn (w = 0) whose quaternion's sign flipped between the rotation and the one it
# decoded to, so the writer did not choose its own payload again and fell back to float64 matrices
@example(frames=1, seed=117, fps=None, extras=0, camera=(40.0, 32))
def test_format_md_alone_reads_the_fixed_point_cameras_the_writer_makes(frames, seed, fps, extras, camera):
    """I.5.4 as the library writes a learned-rans file's cameras (camera centres, cubic prediction, fixed-point
    timestamps where the writer chooses them, in CAMS and XCAM records): the spec-only reader above gets the
    library's own trajectories bit for bit, t = -R c included."""
    from format_strategies import load_vector_tool
    from vt4dcodec.format import dumps, loads

    mv = load_vector_tool()
    rng = np.random.default_rng(seed)
    scene = mv.learned_scene(quality=2)
    scene.cameras = _smooth_camera(rng, frames, *camera, timestamps=None if fps is None else np.arange(frames) / fps)
    scene.extra_cameras = tuple(_smooth_camera(rng, frames, *camera) for _ in range(extras))
    tables = mv.learned_tables()
    data = dumps(scene, tables=tables)
    mine, ours = read_scene(data), loads(data, tables=tables)
    assert mine["sections"]["CAMS"][0] == 0  # fixed point: these cameras keep the 0.01 px bound
    if fps == 8.0:  # camera centres and (i / 8 s being k * 2^-3) fixed-point timestamps; cubic when shorter
        assert mine["sections"]["CAMS"][1] & 0x28 == 0x28
    for got, want in zip([read_cameras(mine), *read_extra_cameras(mine)], [ours.cameras, *ours.extra_cameras]):
        assert np.array_equal(np.array(got["K"]), want.K) and np.array_equal(np.array(got["w2c"]), want.w2c)
        assert not np.signbit(np.array(got["w2c"])[:, :3, 3][np.array(got["w2c"])[:, :3, 3] == 0]).any()
    if fps is not None:
        assert read_cameras(mine)["timestamps"] == ours.cameras.timestamps.tolist() == scene.cameras.timestamps.tolist()


ARCHIVE_KEYS = ["a", "b", "c", "dir/d", "dir/e.1", "F_2", "g-3", "h"]


@pytest.mark.parametrize("version", [(1, 2), (1, 1)], ids=["1.2", "1.1"])
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.lists(st.tuples(st.sampled_from(ARCHIVE_KEYS), st.integers(1, 3000), st.booleans()),
                         min_size=1, max_size=20), min_size=1, max_size=16),
       st.integers(0, 2**32 - 1))
def test_format_md_alone_reads_what_the_archive_writer_makes(tmp_path_factory, version, commits, seed):
    """The library's archive writer, used only as a black box to make files (random commits of 1-20 appends of
    random payloads, replaces among them; light commits, journals and full ones as the writer chooses): the
    spec-only reader above returns the last commit's generation and exactly the last committed payload of
    every key."""
    import random

    from vt4dcodec.archive import ArchiveWriter

    rng = random.Random(seed)
    path = tmp_path_factory.mktemp("archive") / "a.vt4da"
    want: dict[str, bytes] = {}
    writer = ArchiveWriter(path, "w", durable=False, version=version)
    try:
        for batch in commits:
            pending: dict[str, bytes] = {}
            for key, size, replace in batch:
                payload = rng.randbytes(size)
                writer.append(key, payload, validate=False, replace=replace or key in want or key in pending)
                pending[key] = payload
            generation = writer.commit()
            want.update(pending)
            assert read_archive(path.read_bytes()) == (generation, want)
    finally:
        writer.close(commit=False)
    data = path.read_bytes()
    assert struct.unpack_from("<HH", data, 8) == version
    assert read_archive(data) == (generation, want)


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 10), st.integers(0, 2**32 - 1), st.integers(1, 5), st.booleans(),
       st.sampled_from([(40.0, 32), (60.0, 64), (900.0, 640)]))
# regression: an extra camera of focal length 24 px on a 64-pixel image (106 degrees across) misses the fixed-point
# tolerance by 0.001 px (its exponents do not count the image edge's magnification of a rotation error), so the
# writer keeps the per-camera layout -- a file the spec-only reader must still read bit for bit
@example(frames=8, seed=6369, extras=1, same_lens=False, camera=(60.0, 64))
def test_format_md_alone_reads_joint_extra_cameras(frames, seed, extras, same_lens, camera):
    """I.5.5 as the library writes it when asked (``joint_cameras=True``): the spec-only reader decodes the joint
    XCAM to its I.5.4 records and gets the library's trajectories bit for bit -- cameras of one lens (the first
    intrinsics record predicted from the camera before) and of different focal lengths and image-centre
    principal points (predicted from the image), moving and static. Every camera no wider than 90 degrees gets
    fixed-point records, so the joint layout; a wider one may fall back to float32 (I.5.4's tolerance), and
    the file is read alike."""
    from format_strategies import load_vector_tool
    from vt4dcodec.format import dumps, loads

    mv = load_vector_tool()
    rng = np.random.default_rng(seed)
    f, size = camera
    scene = mv.learned_scene(quality=2)
    scene.cameras = _smooth_camera(rng, frames, f, size)
    others = []
    for i in range(extras):
        cam = _smooth_camera(rng, frames, f if same_lens else f * rng.uniform(0.4, 2.5), size)
        if i % 2:  # a static camera: one pose record
            cam = type(cam)(K=cam.K, w2c=np.repeat(cam.w2c[:1], frames, axis=0), width=size, height=size)
        others.append(cam)
    scene.extra_cameras = tuple(others)
    tables = mv.learned_tables()
    data = dumps(scene, tables=tables, joint_cameras=True)
    mine, ours = read_scene(data), loads(data, tables=tables)
    if all(float(c.K[0, 0, 0]) >= size / 2 for c in (scene.cameras, *others)):
        assert mine["required"] & 512  # every record is fixed point, so the joint layout is used
    for got, want in zip(read_extra_cameras(mine), ours.extra_cameras, strict=True):
        assert np.array_equal(np.array(got["K"]), want.K) and np.array_equal(np.array(got["w2c"]), want.w2c)
    assert dumps(ours, tables=tables, joint_cameras=True) == data  # loading and saving gives the same bytes
