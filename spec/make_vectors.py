#!/usr/bin/env python
"""Regenerate the golden test vectors of the .vt4d scene container, deterministically.

    python spec/make_vectors.py            # rewrite spec/vectors/
    python spec/make_vectors.py --check    # exit 1 if the committed vectors differ from what this makes

Valid vectors: ``valid/NAME.vt4d`` + ``valid/NAME.expected.json`` (decoded content: header fields,
cameras, tokens as exact float32 values in decimal and a SHA-256 of their little-endian bytes).
Invalid vectors: ``invalid/NAME.vt4d`` + ``invalid/NAME.expected.json`` naming the error class a reader
MUST raise (any conforming reader must reject the file; the class names are this library's).

Token values are small dyadic rationals, so every platform computes them exactly.  zstd output can change
with the libzstd version; MANIFEST.json records the version used, and the byte-equality test only
compares zstd-bearing vectors when the versions match (their decoded content is always compared).
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import struct
import sys
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import zstandard

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT.parent))

from vt4dcodec.cameras import Trajectory  # noqa: E402
from vt4dcodec.format import (EntropyTables, ModelFingerprint, Provenance, Scene, open_scene,  # noqa: E402
                              set_tables_resolver)
from vt4dcodec.format import learned as _learned  # noqa: E402
from vt4dcodec.format import compact_cameras as _cc  # noqa: E402
from vt4dcodec.format.compact_cameras import fixed_exponents as _fixed_exponents  # noqa: E402
from vt4dcodec.format.compact_cameras import pack_compact_cameras  # noqa: E402
from vt4dcodec.format.camera_dictionary import CAMERA_DICTIONARY  # noqa: E402
from vt4dcodec.format.header import compress_header, decompress_header  # noqa: E402
from vt4dcodec.format.layout import (COMPRESSION_ZSTD_CAMERAS, FLAG_ADAPTIVE_TOKENS, FLAG_CAMERA_DICTIONARY,  # noqa: E402
                                     FLAG_COMPACT_CAMERAS, FLAG_COMPACT_CONTAINER,
                                     FLAG_ENTROPY_CODED_TOKENS, FLAG_EXTRA_CAMERAS, FLAG_FIXED_CAMERAS,
                                     FLAG_HEADER_DICTIONARY_2, FLAG_JOINT_CAMERAS, FLAG_LEARNED_TOKENS,
                                     FLAG_RANS_LANES, PREAMBLE_SIZE,
                                     crc32, entry_size, parse_preamble, parse_table)
from vt4dcodec.format.rans import STATE_LOWER, pack_table, rans_encode, rans_encode_ctx  # noqa: E402
from vt4dcodec.format.rans import parse_table as parse_rans_table  # noqa: E402
from vt4dcodec.format.rans_tokens import decode_rans_codes, encode_rans_tokens  # noqa: E402
from vt4dcodec.format.writer import build_container  # noqa: E402
from vt4dcodec.format.writer import dumps as _dumps  # noqa: E402

# every vector but learned_rans_adaptive is coded with the model's fixed rows (required flag bit 10 clear), the
# bytes of the first 1.6 text: the writer's policy would use adaptive rows where they are shorter
dumps = functools.partial(_dumps, adaptive_tokens=False)

VECTORS = ROOT / "vectors"

#: invalid vector name -> the same bytes with the one defect its name gives repaired (a valid scene).  Filled
#: by the generators; tests/format/test_vectors.py checks every entry loads, which proves the vector is
#: rejected for that defect and not for another one made along with it.  Not written to spec/vectors.
REPAIRED: dict[str, bytes] = {}


# --- deterministic scene content ---------------------------------------------------------------------
def dumps_1_1(*args: Any, **kw: Any) -> bytes:
    """The writer with the 1.0 cameras section: the vectors made before format 1.2 keep their bytes."""
    return dumps(*args, cameras="legacy", header="legacy", **kw)


def dumps_1_2(*args: Any, **kw: Any) -> bytes:
    """The writer with the 1.0 to 1.2 header and table: the vectors made for format 1.2 keep their bytes."""
    return dumps(*args, header="legacy", **kw)


def _fixed_exponents_1_6(traj: Trajectory, *, centre: bool = False) -> tuple[int, int, int]:
    """The 1.6 writer's fixed-point camera exponents (FORMAT.md I.5.4: finer centre-pose steps than the writer uses now)."""
    e_k, e_r, e_t = _fixed_exponents(traj, centre=centre)
    return (e_k + 7, e_r + 1, e_t) if centre else (e_k, e_r, e_t)


def dumps_1_6(*args: Any, **kw: Any) -> bytes:
    """The 1.6 writer: header dictionary 1 and its fixed-point camera steps, so the vectors made for format 1.6
    keep their bytes."""
    _cc.fixed_exponents = _fixed_exponents_1_6
    try:
        return dumps(*args, header_dictionary=1, joint_cameras=False, **kw)
    finally:
        _cc.fixed_exponents = _fixed_exponents


def tokens(rows: int, cols: int, salt: int) -> np.ndarray:
    """Exact dyadic values in [-4, 4): ((7i + 13j + salt) mod 32 - 16) / 4."""
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    return (((7 * i + 13 * j + salt) % 32 - 16) / 4.0).astype(np.float32)


def cameras(frames: int, *, distortion: list[float] | None = None, timestamps: bool = False) -> Trajectory:
    K = np.array([[100.0, 0.0, 31.5], [0.0, 100.0, 23.5], [0.0, 0.0, 1.0]])
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    w2c[:, 0, 3] = np.arange(frames) * 0.25  # a camera sliding along x, quarter-metre steps
    w2c[:, 2, 3] = 2.0
    ts = np.arange(frames) / 8.0 if timestamps else None
    return Trajectory(K=np.tile(K, (frames, 1, 1)), w2c=w2c, width=64, height=48,
                      distortion=None if distortion is None else np.array(distortion), timestamps=ts)


def fingerprint(static_shape: tuple[int, int], dynamic_shape: tuple[int, int]) -> ModelFingerprint:
    return ModelFingerprint("vt4d-test", "1.0", hashlib.sha256(b"config").hexdigest(),
                            hashlib.sha256(b"weights").hexdigest(), static_shape, dynamic_shape)


def scene(ns: int, nd: int, d: int, frames: int = 1, **kw: Any) -> Scene:
    cam_kw = {k: kw.pop(k) for k in ("distortion", "timestamps") if k in kw}
    return Scene(tokens(ns, d, 1), tokens(nd, d, 5), cameras(frames, **cam_kw), fingerprint((ns, d), (nd, d)), **kw)


PROVENANCE = Provenance("0.1.0", "2026-01-01T00:00:00Z", "capture-0001", "encoded")


# --- container surgery (also used by the tests) ------------------------------------------------------
def split(data: bytes) -> tuple[dict, list[list]]:
    """(header map, sections as [type, critical, compression, stored bytes, raw_length]) of a container; in
    a compact container (1.3) the header is decompressed and each section also carries its aligned flag."""
    pre = parse_preamble(data)
    compact = bool(pre.required_flags & FLAG_COMPACT_CONTAINER)
    stored = data[PREAMBLE_SIZE:PREAMBLE_SIZE + pre.header_length]
    dictionary = 2 if pre.required_flags & FLAG_HEADER_DICTIONARY_2 else 1  # required flag bit 7 (I.3.2)
    header = msgpack.unpackb(decompress_header(stored, dictionary) if compact else stored, raw=False)
    if compact:  # the digests are 32-byte bin values there (I.3.1): give the map of the 1.2 header
        header["fingerprint"] = dict(header["fingerprint"], **{k: header["fingerprint"][k].hex() for k in DIGESTS})
    start = PREAMBLE_SIZE + pre.header_length
    end = start + pre.section_count * entry_size(pre.required_flags)
    entries = parse_table(data[start:end], pre.section_count, end, pre.file_length, compact=compact,
                          camera_dictionary=bool(pre.required_flags & FLAG_CAMERA_DICTIONARY))
    return header, [[e.type, e.critical, e.compression, data[e.offset:e.offset + e.stored_length], e.raw_length]
                    + ([e.aligned] if compact else []) for e in entries]


def rebuild(header: dict | bytes, sections: list[list], **kw: Any) -> bytes:
    """A container with correct checksums from a header (map or raw msgpack bytes) and sections.

    Without ``minor`` / ``required_flags`` the preamble says 1.0 with no flags, unless the sections came
    from a 1.2 file with compact cameras (a ``CAMS`` raw length below the 1.0 length the header implies,
    which only the compact encoding has): then 1.2 with flag bit 1 (and bit 0 for an ``-rans`` encoding),
    as the writer would say; with an ``XCAM`` section 1.4 with flag bit 3 too (and bit 0 for ``-rans``);
    sections from a compact container (with their aligned flag) make one again."""
    if "minor" not in kw and "required_flags" not in kw and any(len(s) == 6 for s in sections):
        return rebuild_1_3(header, sections, **kw)  # split() of a compact container: build one again
    raw = header if isinstance(header, bytes) else msgpack.packb(header, use_bin_type=True)
    if "minor" not in kw and "required_flags" not in kw:
        rans = FLAG_ENTROPY_CODED_TOKENS if str(_header_map(header).get("encoding", "")).endswith("-rans") else 0
        compact_cams = FLAG_COMPACT_CAMERAS if _compact_cameras(header, sections) else 0
        if _extra_cameras(sections):
            kw = dict(kw, minor=4, required_flags=FLAG_EXTRA_CAMERAS | compact_cams | rans)
        elif compact_cams:
            kw = dict(kw, minor=2, required_flags=compact_cams | rans)
    return build_container(raw, [tuple(s) for s in sections], **kw)


DIGESTS = ("config_sha256", "weights_sha256")


def binary_digests(header: dict) -> dict:
    """The header map with the fingerprint's hex digests as 32-byte bin values, as a compact header holds them."""
    fp = header["fingerprint"]
    return dict(header, fingerprint=dict(fp, **{k: bytes.fromhex(fp[k]) for k in DIGESTS if isinstance(fp[k], str)}))


def rebuild_1_3(header: dict | bytes, sections: list[list], *, compress: bool = True, minor: int | None = None,
                required_flags: int | None = None, **kw: Any) -> bytes:
    """A compact container (1.3) with correct checksums: the header map (its digests made binary) or raw
    msgpack bytes, compressed with the spec dictionary, or with ``compress=False`` ``header`` bytes stored as
    they are.  Required flags default to bit 2 and bit 1 (and bit 0 for an ``int<b>-rans`` encoding, bit 5 for
    ``learned-rans``), and bit 3 with an ``XCAM`` section; the minor version to 3, or 4 with an ``XCAM`` section,
    or 6 for ``learned-rans``."""
    raw = header if isinstance(header, bytes) else msgpack.packb(binary_digests(header), use_bin_type=True)
    encoding = str(_header_map(header).get("encoding", ""))
    learned = encoding == "learned-rans"  # format 1.6 (I.6.2): bit 5, never bit 0
    camera_dictionary = any(s[2] == COMPRESSION_ZSTD_CAMERAS for s in sections)  # bit 8 (I.4.2)
    if minor is None:
        minor = 6 if learned or camera_dictionary else 4 if _extra_cameras(sections) else 3
    if required_flags is None:
        rans = encoding.endswith("-rans") and not learned
        legacy_cameras = _legacy_cameras(header, sections)  # bit 1 unless CAMS is known to be the 1.0 section
        required_flags = (FLAG_COMPACT_CONTAINER | (0 if legacy_cameras else FLAG_COMPACT_CAMERAS)
                          | (FLAG_ENTROPY_CODED_TOKENS if rans else 0) | (FLAG_LEARNED_TOKENS if learned else 0)
                          | (FLAG_FIXED_CAMERAS if learned and not legacy_cameras else 0)
                          | (FLAG_EXTRA_CAMERAS if _extra_cameras(sections) else 0)
                          | (FLAG_CAMERA_DICTIONARY if camera_dictionary else 0))
    stored = compress_header(raw) if compress else raw
    return build_container(stored, [tuple(s) for s in sections], minor=minor, required_flags=required_flags, **kw)


def _header_map(header: dict | bytes) -> dict:
    if isinstance(header, dict):
        return header
    try:
        value = msgpack.unpackb(header, raw=False, strict_map_key=False)
    except Exception:  # a deliberately broken header: no version to infer
        return {}
    return value if isinstance(value, dict) else {}


def _extra_cameras(sections: list[list]) -> bool:
    return any(s[0] == "XCAM" for s in sections)


def _compact_cameras(header: dict | bytes, sections: list[list]) -> bool:
    return _legacy_cameras(header, sections) is False


def _legacy_cameras(header: dict | bytes, sections: list[list]) -> bool | None:
    """Whether CAMS has the 1.0 length the header implies (the compact encoding is always shorter); None when
    the header or CAMS cannot be read."""
    try:
        cams = _header_map(header)["cameras"]
        t = cams["num_frames"]
        legacy = 8 * (25 * t + cams["distortion_terms"] + (t if cams["has_timestamps"] else 0))
        return bool(find(sections, "CAMS")[4] >= legacy)
    except (KeyError, TypeError, StopIteration):
        return None


def patch_preamble(data: bytes, offset: int, fmt: str, value: int, *, fix_crc: bool = True) -> bytes:
    """Overwrite one preamble field (struct ``fmt`` at ``offset``) and recompute the preamble CRC."""
    out = bytearray(data)
    struct.pack_into(fmt, out, offset, value)
    if fix_crc:
        struct.pack_into("<I", out, 60, crc32(out[:60]))
    return bytes(out)


def patch_entry(data: bytes, index: int, field_offset: int, fmt: str, value: int) -> bytes:
    """Overwrite one field of section-table entry ``index`` and fix the table CRC in the preamble."""
    pre = parse_preamble(data)
    start = PREAMBLE_SIZE + pre.header_length
    size = entry_size(pre.required_flags)
    out = bytearray(data)
    struct.pack_into(fmt, out, start + index * size + field_offset, value)
    table = out[start:start + pre.section_count * size]
    return patch_preamble(bytes(out), 52, "<I", crc32(table))


def find(sections: list[list], name: str) -> list:
    return next(s for s in sections if s[0] == name)


# --- the vectors -------------------------------------------------------------------------------------
def valid_vectors() -> dict[str, tuple[bytes, str]]:
    out = {
        "float32_raw_minimal": (dumps_1_1(scene(2, 1, 3), encoding="float32", compression_level=None),
                                "smallest useful file: float32 tokens, every section stored raw (the "
                                "FORMAT.md hex dump)"),
        "float16_zstd_timestamps": (dumps_1_1(scene(8, 4, 4, frames=3, timestamps=True), encoding="float16"),
                                    "float16 tokens, zstd sections, three frames with timestamps"),
        "int8_distortion_metadata": (
            dumps_1_1(scene(16, 8, 4, frames=2, distortion=[0.01, -0.002, 0.0005, 0.0, 0.001],
                        metadata={"scene": "ramp", "tags": ["a", "b"], "nested": {"n": 3, "x": 0.5, "ok": True,
                                                                             "none": None}},
                        provenance=PROVENANCE), encoding="int8"),
            "int8 per-channel affine tokens, 5 OpenCV distortion terms, metadata and provenance"),
        "int4_odd_count": (dumps_1_1(scene(3, 1, 3, frames=2, provenance=Provenance(
            "0.1.0", "2026-01-01T00:00:00.5Z", None, "generated")), encoding="int4"),
                           "int4 with an odd number of codes per section (last high nibble is padding)"),
    }
    # A newer minor version (1.7) with an unknown optional flag, an unknown header key and an unknown
    # ancillary section: a 1.0 reader MUST read it and ignore all three.
    base = dumps_1_1(scene(4, 2, 2, provenance=PROVENANCE), encoding="int8", compression_level=None)
    header, sections = split(base)
    header["future_key"] = {"anything": [1, 2]}
    sections.insert(2, ["xTRA", False, 0, b"ancillary bytes a 1.0 reader skips", 34])
    sections.append(["xZZZ", False, 7, b"unknown compression is fine when ancillary", 99])
    out["future_minor_ancillary"] = (rebuild(header, sections, minor=7, optional_flags=1 << 40),
                                     "minor version 7, unknown optional flag, unknown header key and two "
                                     "unknown ancillary sections (one with an unknown compression code)")
    out.update(rans_valid_vectors())
    out.update(lanes_valid_vectors())
    out.update(compact_valid_vectors())
    out.update(container_valid_vectors())
    out.update(extra_cameras_valid_vectors())
    out.update(learned_valid_vectors())
    return out


# --- format 1.6: learned-rans tokens with a model's tables (FORMAT.md I.6.2) -----------------------------------
LEARNED_TABLES_FILE = "tables/vt4d-test-learned.json"
CONTEXT_TABLES_FILE = "tables/vt4d-test-learned-context.json"
PARTNER_TABLES_FILE = "tables/vt4d-test-learned-partners.json"


def _laplace_row(q: int, width: float, change: bool) -> list[int]:
    """A positive run of 2q+1 (4q+1 for a change) frequencies summing to 2^14, peaked at the middle."""
    n = (4 if change else 2) * q + 1
    p = np.exp(-np.abs(np.arange(n) - n // 2) / width)
    f = np.floor(p / p.sum() * (16384 - n)).astype(np.int64) + 1
    f[n // 2] += 16384 - int(f.sum())
    return [int(v) for v in f]


def learned_tables() -> EntropyTables:
    """The test model's entropy tables: 2 levels, d = 2, N_s = 3 (one camera: token 2 is a frame copy of
    token 0), N_d = 1; steps 1/2 and 1/4 (level 0), 1/8 (level 1), Z_d one step coarser."""
    steps = np.array([[[0.5, 0.25], [0.5, 0.5]], [[0.125, 0.125], [0.25, 0.125]]], np.float32)
    q = np.floor(1 / steps.astype(np.float64) + 0.5).astype(int)
    freqs = np.zeros((2, 3, 2, 4 * int(q[:, 0].max()) + 1), np.int64)
    for level in range(2):
        for c in range(2):
            for cls, (g, change) in enumerate(((0, False), (0, True), (1, False))):
                row = _laplace_row(int(q[level, g, c]), 0.7 + c, change)
                freqs[level, cls, c, :len(row)] = row
    origins = np.tile(np.arange(3), (64, 1))
    origins[0, 2] = 0
    return EntropyTables(steps, freqs, origins, fingerprint((3, 2), (1, 2)))


def _tilted_row(q: int, width: float, lean: int) -> list[int]:
    """A positive run of 2q+1 frequencies summing to 2^14, peaked at symbol q + lean (a MEAN_AFTER_* row)."""
    n = 2 * q + 1
    p = np.exp(-np.abs(np.arange(n) - (q + lean)) / width)
    f = np.floor(p / p.sum() * (16384 - n)).astype(np.int64) + 1
    f[q + lean] += 16384 - int(f.sum())
    return [int(v) for v in f]


def context_tables() -> EntropyTables:
    """The context test model's tables (FORMAT.md I.6.2, 5 classes): 1 level, d = 2, N_s = 4 (one camera:
    token 2 is a frame copy of token 0, so token 3's previous MEAN token is 1), N_d = 1; steps 1/4 (Z_s) and
    1/2 (Z_d); MEAN_AFTER_NEGATIVE rows peak at code -1, MEAN_AFTER_POSITIVE rows at +1."""
    steps = np.array([[[0.25, 0.25], [0.5, 0.5]]], np.float32)
    freqs = np.zeros((1, 5, 2, 17), np.int64)
    for c in range(2):
        for cls, row in enumerate((_laplace_row(4, 0.8 + c, False), _laplace_row(4, 0.8 + c, True),
                                   _laplace_row(2, 0.8 + c, False), _tilted_row(4, 0.8, -1), _tilted_row(4, 0.8, 1))):
            freqs[0, cls, c, :len(row)] = row
    origins = np.tile(np.arange(4), (64, 1))
    origins[0, 2] = 0
    fp = ModelFingerprint("vt4d-test-context", "1.0", hashlib.sha256(b"config-context").hexdigest(),
                          hashlib.sha256(b"weights-context").hexdigest(), (4, 2), (1, 2))
    return EntropyTables(steps, freqs, origins, fp)


def partner_tables() -> EntropyTables:
    """The partner test model's tables (FORMAT.md I.6.2, 11 classes): 1 level, d = 3 with partners (-1, 0, 0),
    N_s = 4 (one camera: token 2 is a frame copy of token 0), N_d = 1; steps 1/4 (Z_s) and 1/2 (Z_d); the rows
    of classes 3 and 4 peak at codes -1 and +1, those of classes 5-7 at -2, -1, 0 and of 8-10 at 0, +1, +2."""
    steps = np.array([[[0.25, 0.25, 0.25], [0.5, 0.5, 0.5]]], np.float32)
    freqs = np.zeros((1, 11, 3, 17), np.int64)
    leans = (None, None, None, -1, 1, -2, -1, 0, 0, 1, 2)
    for c in range(3):
        for cls, lean in enumerate(leans):
            row = (_laplace_row(4, 0.8 + c, False), _laplace_row(4, 0.8 + c, True),
                   _laplace_row(2, 0.8 + c, False))[cls] if lean is None else _tilted_row(4, 0.8, lean)
            freqs[0, cls, c, :len(row)] = row
    origins = np.tile(np.arange(4), (64, 1))
    origins[0, 2] = 0
    fp = ModelFingerprint("vt4d-test-partners", "1.0", hashlib.sha256(b"config-partners").hexdigest(),
                          hashlib.sha256(b"weights-partners").hexdigest(), (4, 3), (1, 3))
    return EntropyTables(steps, freqs, origins, fp, partners=np.array([-1, 0, 0]))


def partner_scene(**kw: Any) -> Scene:
    zs = np.array([[0.5, -0.3, 0.25], [0.75, 0.5, -0.25], [0.45, -0.2, 0.3], [-0.2, -0.5, 0.0]], np.float32)
    zd = np.array([[0.4, -0.6, 0.1]], np.float32)  # token 2 a copy of token 0
    return Scene(zs, zd, cameras(2), partner_tables().fingerprint, encoding="learned-rans", **kw)


def context_scene(**kw: Any) -> Scene:
    zs = np.array([[0.5, -0.3], [0.75, -0.5], [0.45, -0.2], [0.2, 0.05]], np.float32)  # token 2 a copy of token 0
    zd = np.array([[0.4, -0.6]], np.float32)
    return Scene(zs, zd, cameras(2), context_tables().fingerprint, encoding="learned-rans", **kw)


def install_spec_tables() -> None:
    """Let readers find the test model's tables by its fingerprint, as an installed model's are found (the
    vectors' expected content, tests/format). Other fingerprints go to the resolver installed before."""
    previous = _learned._resolver
    if getattr(previous, "spec_tables", False):
        return
    known = {t.fingerprint: t for t in (learned_tables(), context_tables(), partner_tables())}

    def resolve(fp: ModelFingerprint) -> EntropyTables | None:
        return known[fp] if fp in known else previous(fp) if previous is not None else None

    resolve.spec_tables = True  # type: ignore[attr-defined]
    set_tables_resolver(resolve)


def learned_tables_json(tables: EntropyTables) -> dict[str, Any]:
    """The tables as spec/vectors stores them: each frequency row as its positive run only."""
    out = {"fingerprint": tables.fingerprint.to_dict(), "steps": tables.steps.astype(np.float64).tolist(),
           "freqs": [[[[int(v) for v in row if v] for row in cls] for cls in level] for level in tables.freqs],
           "origins": tables.origins.tolist()}
    if tables.partners is not None:
        out["partners"] = tables.partners.tolist()
    return out


def learned_scene(**kw: Any) -> Scene:
    zs = np.array([[0.6, -0.3], [-0.95, 0.1], [0.55, -0.05]], np.float32)  # token 2 a copy of token 0
    zd = np.array([[0.2, -0.7]], np.float32)
    return Scene(zs, zd, cameras(2), fingerprint((3, 2), (1, 2)), encoding="learned-rans", **kw)


def gliding(frames: int) -> Trajectory:
    """A camera turning smoothly about y (quaternion (16, 0, i, 0), the rotation by FORMAT.md I.5.2's formula)
    while its centre glides with constant acceleration, timestamps i / 8 s: the writer stores it with camera
    centres, cubic prediction and fixed-point timestamps (FORMAT.md I.5.4, layout flags 0x3d)."""
    from vt4dcodec.format.compact_cameras import centre_translation, quaternion_to_rotation

    i = np.arange(frames, dtype=np.float64)
    R = quaternion_to_rotation(np.stack([np.full(frames, 16.0), 0 * i, i, 0 * i], axis=1))
    centre = np.stack([0.25 * i + 0.03125 * i * i, 0 * i, -2.0 - 0.125 * i], axis=1)
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    w2c[:, :3, :3], w2c[:, :3, 3] = R, centre_translation(R, centre)
    K = np.array([[100.0, 0.0, 31.5], [0.0, 100.0, 23.5], [0.0, 0.0, 1.0]])
    return Trajectory(K=np.tile(K, (frames, 1, 1)), w2c=w2c, width=64, height=48, timestamps=i / 8.0)


def learned_valid_vectors() -> dict[str, tuple[bytes, str]]:
    tables = learned_tables()
    two = learned_scene(provenance=PROVENANCE)
    two.extra_cameras = (shifted(cameras(2), 0.5),)
    gliding_scene = learned_scene(quality=2)
    gliding_scene.cameras = gliding(8)
    moving = dumps_1_6(gliding_scene, tables=tables, compression_level=None)
    cams = open_scene(moving).raw_section("CAMS")
    assert cams[:2] == bytes([0, 0x3d]), "constant K, quaternion poses, centres, cubic, fixed-point timestamps"
    return {
        "learned_rans_mean_context": (
            dumps(context_scene(quality=1), tables=context_tables(), compression_level=None, header_dictionary=1),
            "1.6: learned-rans with tables of 5 classes (spec/vectors/tables/vt4d-test-learned-context.json): MEAN "
            "tokens 1 and 3 coded given the previous MEAN token's code (token 2, a frame copy of token 0, is "
            "skipped), every section raw"),
        "learned_rans_camera_dictionary": (
            camera_dictionary_vector(tables),
            "1.6 with required flag bit 8: CAMS and XCAM (the turning camera and two shifted copies) compressed with "
            "the camera dictionary (compression 2, I.4.2), the tokens raw"),
        "learned_rans_partner_context": (
            dumps(partner_scene(quality=1), tables=partner_tables(), compression_level=None, header_dictionary=1),
            "1.6: learned-rans with tables of 11 classes (spec/vectors/tables/vt4d-test-learned-partners.json): "
            "MEAN values of channels 1 and 2 coded given the sign of their token's code in channel 0 as well as "
            "the previous MEAN token's, every section raw"),
        "learned_rans_moving_camera": (
            moving, "1.6: fixed-point cameras (I.5.4) of a turning, accelerating camera: camera centres (t = -R c), "
                    "cubic prediction and fixed-point timestamps (layout flags 0x3d), every section raw"),
        "learned_rans_one_camera": (
            dumps_1_6(learned_scene(quality=1), tables=tables, compression_level=None),
            "1.6: learned-rans at quality level index 0 of the test model (spec/vectors/tables/vt4d-test-learned.json); "
            "static token 2 is a frame copy of token 0 (class CHANGE)"),
        "learned_rans_fine_level": (
            dumps_1_6(learned_scene(quality=2), tables=tables),
            "1.6: learned-rans at level index 1 (steps 1/8, Z_d 1/4 and 1/8), zstd on the other sections"),
        "learned_rans_two_cameras": (
            dumps_1_6(two, quality=2, tables=tables),
            "1.6 with an extra camera (V = 2): the origins row of two cameras, every static token MEAN"),
        "learned_rans_adaptive": (
            adaptive_vector(tables),
            "1.6 with required flag bit 10: the scene of learned_rans_one_camera with adaptive rows (I.6.2), every "
            "section raw"),
        "learned_rans_joint_cameras": (
            joint_cameras_vector(tables),
            "1.6 with required flag bit 9: the turning camera of learned_rans_moving_camera with two extra cameras in "
            "the joint XCAM layout (I.5.5), one shifted (its first intrinsics record predicted from the camera "
            "before) and one shifted with fx = fy = 120, every section raw"),
        "learned_rans_header_dictionary_2": (
            dictionary_2_vector(tables),
            "1.6 with required flag bit 7: the compact header compressed with header dictionary 2 (I.3.2); the "
            "turning camera of learned_rans_moving_camera in the writer's coarser centre-pose steps, every "
            "section raw"),
    }


def camera_dictionary_vector(tables: EntropyTables) -> bytes:
    """The turning camera of learned_rans_moving_camera with two shifted copies as extra cameras, written by the
    writer's policy: its camera sections compressed with the camera dictionary (FORMAT.md I.4.2)."""
    scene = learned_scene(quality=1)
    scene.cameras = gliding(8)
    scene.extra_cameras = tuple(shifted(gliding(8), dx) for dx in (0.5, -0.75))
    data = dumps(scene, tables=tables, header_dictionary=1, joint_cameras=False)
    header, sections = split(data)
    assert [s[2] for s in sections] == [2, 2, 0, 0], "CAMS and XCAM with the camera dictionary, tokens raw"
    assert parse_preamble(data).required_flags & FLAG_CAMERA_DICTIONARY
    return data


def adaptive_vector(tables: EntropyTables) -> bytes:
    """learned_rans_one_camera's scene with adaptive rows (FORMAT.md I.6.2, required flag bit 10)."""
    data = dumps_1_6(learned_scene(quality=1), tables=tables, compression_level=None, adaptive_tokens=True)
    fixed = dumps_1_6(learned_scene(quality=1), tables=tables, compression_level=None)
    assert parse_preamble(data).required_flags & FLAG_ADAPTIVE_TOKENS
    assert open_scene(data).raw_section("ZSTA") != open_scene(fixed).raw_section("ZSTA"), "the rows must adapt"
    return data


def joint_cameras_vector(tables: EntropyTables) -> bytes:
    """The turning camera of learned_rans_moving_camera with two shifted copies (the second with fx = fy = 120) as
    extra cameras, their XCAM in the joint layout (FORMAT.md I.5.5), every section raw."""
    scene = learned_scene(quality=1)
    scene.cameras = gliding(8)
    scene.extra_cameras = (shifted(gliding(8), 0.5), shifted(gliding(8), -0.75, fx=120.0))
    data = dumps(scene, tables=tables, compression_level=None, header_dictionary=1, joint_cameras=True)
    assert parse_preamble(data).required_flags & FLAG_JOINT_CAMERAS
    xcam = bytes(open_scene(data).raw_section("XCAM"))
    assert xcam[0] == 2 and (8 * len(xcam) - 8) % 8 == 0
    return data


def dictionary_2_vector(tables: EntropyTables) -> bytes:
    """The moving-camera learned scene as the writer makes it now, with header dictionary 2 (I.3.2)."""
    gliding_scene = learned_scene(quality=2)
    gliding_scene.cameras = gliding(8)
    data = dumps(gliding_scene, tables=tables, compression_level=None, header_dictionary=2)
    assert parse_preamble(data).required_flags & FLAG_HEADER_DICTIONARY_2
    return data


def joint_body_bits(data: bytes) -> int:
    """How many bits the joint XCAM body of ``data`` holds (FORMAT.md I.5.5), by the library's reader."""
    from vt4dcodec.format import joint_cameras

    header = open_scene(data)
    cams = header.cameras
    xcam = bytes(header.raw_section("XCAM"))
    reader = joint_cameras._Reader(xcam[1:])
    joint_cameras._read_body(reader, xcam[0], cams.num_frames, cams.width, cams.height)
    return reader.pos


def learned_invalid_vectors() -> dict[str, tuple[bytes, str, str]]:
    tables = learned_tables()
    good = dumps_1_6(learned_scene(quality=2), tables=tables, compression_level=None)
    header, sections = split(good)
    payload = bytes(find(sections, "ZSTA")[3])
    out: dict[str, tuple[bytes, str, str]] = {}

    def with_payload(name: str, bad_payload: bytes, error: str, why: str) -> None:
        bad = [list(x) for x in sections]
        find(bad, "ZSTA")[3:5] = [bad_payload, len(bad_payload)]
        out[f"learned_rans_{name}"] = (rebuild(header, bad), error, why)
        REPAIRED[f"learned_rans_{name}"] = good

    with_payload("short_payload", payload[:5], "TruncatedError", "a 5-byte ZSTA payload: no room for the rANS state")
    with_payload("level_beyond_tables", bytes([2]) + payload[1:], "MalformedSectionError",
                 "level index 2 of a model with 2 levels")
    with_payload("views_mismatch", payload[:1] + bytes([2]) + payload[2:], "MalformedSectionError",
                 "V = 2 in a file without extra cameras")
    with_payload("trailing_byte", payload + b"\x00", "MalformedSectionError", "one byte after the rANS stream")
    with_payload("truncated_stream", payload[:-1], "TruncatedError", "the rANS stream lost its last byte")
    level, q = 1, 8  # Q_s of level 1: the MEAN codes 0 (symbol 8), the CHANGE code +2Q past its origin's 0
    ctx = tables.contexts("static", 1)
    symbols = np.where(ctx // 2 == 1, 4 * q, q)
    forged = rans_encode_ctx(symbols.reshape(-1), ctx.reshape(-1), tables.freqs[level].reshape(-1, tables.freqs.shape[3]))
    with_payload("change_code_out_of_range", bytes([level, 1]) + forged, "MalformedSectionError",
                 "token 2's CHANGE symbol 4Q puts its code at +2Q = 16, outside -8 .. 8")
    dictionary = camera_dictionary_vector(tables)
    pre = parse_preamble(dictionary)
    out["camera_dictionary_without_flag"] = (
        patch_preamble(dictionary, 16, "<Q", pre.required_flags & ~FLAG_CAMERA_DICTIONARY), "UnsupportedFeatureError",
        "CAMS and XCAM use compression 2 with required flag bit 8 clear: a compression code the file does not "
        "announce (critical sections)")
    REPAIRED["camera_dictionary_without_flag"] = dictionary
    d_header, d_sections = split(dictionary)
    frame = zstandard.ZstdCompressor(level=19, dict_data=zstandard.ZstdCompressionDict(CAMERA_DICTIONARY),
                                     write_content_size=True, write_dict_id=True).compress(bytes(
                                         open_scene(dictionary).raw_section("CAMS")))
    bad = [list(x) for x in d_sections]
    find(bad, "CAMS")[3] = frame
    out["camera_dictionary_frame_with_dictionary_id"] = (
        rebuild_1_3(d_header, bad, minor=6, required_flags=pre.required_flags), "MalformedSectionError",
        "the CAMS frame names a dictionary id (the camera dictionary's own): section frames name none")
    REPAIRED["camera_dictionary_frame_with_dictionary_id"] = dictionary
    legacy = dumps_1_2(scene(2, 1, 3), encoding="int8")
    out["camera_dictionary_flag_without_compact_container"] = (
        patch_preamble(patch_preamble(legacy, 12, "<H", 6), 16, "<Q", parse_preamble(legacy).required_flags
                       | FLAG_CAMERA_DICTIONARY), "MalformedHeaderError",
        "required flag bit 8 (the camera dictionary) in a 1.0-1.2 layout, which has no compression 2")
    REPAIRED["camera_dictionary_flag_without_compact_container"] = legacy
    out["learned_rans_without_flag"] = (patch_preamble(good, 16, "<Q", FLAG_COMPACT_CONTAINER | FLAG_COMPACT_CAMERAS
                                                       | FLAG_FIXED_CAMERAS),
                                        "MalformedHeaderError", "encoding learned-rans with required flag bit 5 clear")
    REPAIRED["learned_rans_without_flag"] = good
    out["learned_rans_with_bit_0"] = (
        patch_preamble(good, 16, "<Q", FLAG_COMPACT_CONTAINER | FLAG_COMPACT_CAMERAS | FLAG_LEARNED_TOKENS
                       | FLAG_FIXED_CAMERAS | FLAG_ENTROPY_CODED_TOKENS), "MalformedHeaderError",
        "required flag bit 0 (int<b>-rans payloads) beside bit 5")
    REPAIRED["learned_rans_with_bit_0"] = good
    out["learned_rans_flag_in_1_5"] = (patch_preamble(good, 12, "<H", 5), "UnsupportedFeatureError",
                                       "required flag bit 5 in a file that says 1.5")
    REPAIRED["learned_rans_flag_in_1_5"] = good
    # fixed-point cameras (I.5.4): the learned file's CAMS is P = 0
    cams = bytes(find(sections, "CAMS")[3])
    assert cams[0] == 0, "the test trajectory is stored in fixed point"

    def with_cams(name: str, payload: bytes, why: str) -> None:
        bad = [list(x) for x in sections]
        find(bad, "CAMS")[2:5] = [0, payload, len(payload)]
        out[f"fixed_cameras_{name}"] = (rebuild(header, bad), "MalformedSectionError", why)
        REPAIRED[f"fixed_cameras_{name}"] = good

    with_cams("without_quaternion_flag", cams[:1] + bytes([cams[1] & ~4]) + cams[2:],
              "a fixed-point record without layout flag bit 2 (quaternion poses)")
    with_cams("exponent_53", cams[:2] + bytes([53]) + cams[3:], "e_K = 53, above 52")
    with_cams("varint_past_end", cams[:-1], "the section lost its last byte: the last varint runs past its end")
    with_cams("trailing_byte", cams + b"\x00", "one byte after the timestamps")
    assert cams[1] & 8, "the test trajectory is stored with camera centres"
    for bit in (6, 7):
        with_cams(f"undefined_flag_bit_{bit}", cams[:1] + bytes([cams[1] | 1 << bit]) + cams[2:],
                  f"layout flag bit {bit} in a fixed-point record (bits 6 and 7 are undefined)")
    with_cams("timestamps_flag_without_timestamps", cams[:1] + bytes([cams[1] | 32]) + cams[2:],
              "layout flag bit 5 (fixed-point timestamps) in a record of a trajectory without timestamps")
    # bits 3..5 are defined for fixed-point records only: in a float32 record (valid in a bit-6 file) they stay
    # reserved, so the float32 payload the writer makes without bit 6 repairs these
    f32 = pack_compact_cameras(learned_scene().cameras, quaternions=True)
    assert f32[0] == 4 and f32[1] < 8
    for bit, name in ((3, "centre"), (4, "cubic"), (5, "timestamps")):
        with_cams(f"{name}_flag_in_float_record", f32[:1] + bytes([f32[1] | 1 << bit]) + f32[2:],
                  f"layout flag bit {bit} in a float32 (P = 4) record: bits 3..7 stay reserved there")
        repaired = [list(x) for x in sections]
        find(repaired, "CAMS")[2:5] = [0, f32, len(f32)]
        REPAIRED[f"fixed_cameras_{name}_flag_in_float_record"] = rebuild(header, repaired)
    # fixed-point timestamps (bit 5): the moving camera's CAMS ends in e_s = 3 and 8 varints (0, 1, then 0s)
    moving_scene = learned_scene(quality=2)
    moving_scene.cameras = gliding(8)
    moving = dumps_1_6(moving_scene, tables=tables, compression_level=None)
    m_header, m_sections = split(moving)
    m_cams = bytes(find(m_sections, "CAMS")[3])
    assert m_cams[1] & 32 and m_cams[-9:] == bytes([3, 0, 2, 0, 0, 0, 0, 0, 0])
    bad = [list(x) for x in m_sections]
    payload = m_cams[:-9] + bytes([53]) + m_cams[-8:]
    find(bad, "CAMS")[2:5] = [0, payload, len(payload)]
    out["fixed_cameras_timestamp_exponent_53"] = (rebuild(m_header, bad), "MalformedSectionError",
                                                  "fixed-point timestamps with e_s = 53, above 52")
    REPAIRED["fixed_cameras_timestamp_exponent_53"] = moving
    out["fixed_cameras_flag_without_compact_container"] = (
        patch_preamble(dumps_1_2(learned_scene(quality=2), tables=tables, compression_level=None), 16, "<Q",
                       FLAG_COMPACT_CAMERAS | FLAG_LEARNED_TOKENS | (1 << 6)),
        "MalformedHeaderError", "required flag bit 6 (fixed-point cameras) without bit 2 (compact container)")
    REPAIRED["fixed_cameras_flag_without_compact_container"] = dumps_1_2(learned_scene(quality=2), tables=tables,
                                                                         compression_level=None)
    # joint extra cameras (required flag bit 9, I.5.5)
    joint = joint_cameras_vector(tables)
    j_pre = parse_preamble(joint)
    j_header, j_sections = split(joint)
    xcam = bytes(find(j_sections, "XCAM")[3])
    body_bits = joint_body_bits(joint)
    assert 8 * (len(xcam) - 1) - body_bits >= 1, "the vector's body leaves padding bits to damage"

    def with_xcam(name: str, payload: bytes, error: str, why: str) -> None:
        bad = [list(x) for x in j_sections]
        find(bad, "XCAM")[3:5] = [payload, len(payload)]
        out[f"joint_cameras_{name}"] = (rebuild_1_3(j_header, bad, minor=6, required_flags=j_pre.required_flags),
                                        error, why)
        REPAIRED[f"joint_cameras_{name}"] = joint

    def bits_of(payload: bytes) -> str:
        return "".join(f"{b:08b}" for b in payload[1:])

    def from_bits(count: int, bits: str) -> bytes:
        bits += "0" * (-len(bits) % 8)
        return bytes([count]) + bytes(int(bits[i:i + 8], 2) for i in range(0, len(bits), 8))

    body = bits_of(xcam)
    with_xcam("count_0", bytes([0]) + xcam[1:], "MalformedSectionError", "N = 0")
    with_xcam("count_64", bytes([64]) + xcam[1:], "LimitExceededError", "N = 64, above 63")
    with_xcam("truncated", xcam[:-1], "MalformedSectionError", "the body lost its last byte: it ends inside a value")
    with_xcam("trailing_byte", xcam + b"\x00", "MalformedSectionError", "a zero byte after the body's last byte")
    padded = body[:body_bits] + "1" + body[body_bits + 1:]
    with_xcam("padding_bit_set", from_bits(2, padded), "MalformedSectionError",
              "the first padding bit after the body is 1")
    at = 90 + 4  # after the 18 orders and camera 0's 4 layout bits: e_K, u(6)
    with_xcam("exponent_53", from_bits(2, body[:at] + "110101" + body[at + 6:]), "MalformedSectionError",
              "camera 0's e_K = 53, above 52")
    head = body[:at + 18]  # camera 0's orders, layout bits and exponents, then its fx residual (group 0, order o[0])
    with_xcam("prefix_59_zeros", from_bits(1, head + "0" * 59 + "1" + "0" * 59), "MalformedSectionError",
              "camera 0's fx residual starts with 59 zero bits, above the 58 a valid record can need")
    orders_zero = "0" * 90 + body[90:at + 18]  # every group order 0: fx is s(eg(0)) from the prediction 0
    z = 2 * (2**53 + 1)
    big = "0" * ((z + 1).bit_length() - 1) + format(z + 1, "b")
    with_xcam("value_beyond_2_53", from_bits(1, orders_zero + big), "MalformedSectionError",
              "camera 0's fx = 2^53 + 1, above 2^53")
    out["joint_cameras_flag_clear"] = (
        patch_preamble(joint, 16, "<Q", j_pre.required_flags & ~FLAG_JOINT_CAMERAS), "MalformedSectionError",
        "a joint XCAM read as I.5.3: its N = 2 lengths do not add up to the rest of the payload")
    REPAIRED["joint_cameras_flag_clear"] = joint
    one = dumps(learned_scene(quality=2), tables=tables, compression_level=None, header_dictionary=1)
    out["joint_cameras_flag_without_extra_cameras"] = (
        patch_preamble(one, 16, "<Q", parse_preamble(one).required_flags | FLAG_JOINT_CAMERAS), "MalformedHeaderError",
        "required flag bit 9 (joint extra cameras) in a file without bit 3 (no XCAM)")
    REPAIRED["joint_cameras_flag_without_extra_cameras"] = one
    # adaptive rows (required flag bit 10, I.6.2)

    def with_flags(name: str, good: bytes, flags: int, error: str, why: str, minor: int | None = None) -> None:
        """``good`` with its required flags (and minor version) patched, the preamble checksum redone."""
        out[name] = (patch_preamble(good if minor is None else patch_preamble(good, 12, "<H", minor), 16, "<Q", flags),
                     error, why)
        REPAIRED[name] = good

    adaptive = adaptive_vector(tables)
    with_flags("learned_rans_adaptive_flag_clear", adaptive, parse_preamble(adaptive).required_flags
               & ~FLAG_ADAPTIVE_TOKENS, "TruncatedError", "a ZSTA stream coded with adaptive rows read with the "
               "model's fixed rows (required flag bit 10 clear): it runs out of bytes after 5 of its 6 symbols")
    int4 = dumps(scene(2, 1, 3), encoding="int4", compression_level=None)
    with_flags("learned_rans_adaptive_without_learned", int4, parse_preamble(int4).required_flags
               | FLAG_ADAPTIVE_TOKENS, "MalformedHeaderError", "required flag bit 10 (adaptive rows) in an int4 "
               "file that says 1.6, without bit 5 (learned-rans tokens)", minor=6)
    # header dictionary 2 (required flag bit 7, I.3.2)
    legacy = dumps_1_2(learned_scene(quality=2), tables=tables, compression_level=None)
    out["header_dictionary_2_without_compact_container"] = (
        patch_preamble(legacy, 16, "<Q", FLAG_COMPACT_CAMERAS | FLAG_LEARNED_TOKENS | FLAG_HEADER_DICTIONARY_2),
        "MalformedHeaderError", "required flag bit 7 (header dictionary 2) without bit 2 (compact container)")
    REPAIRED["header_dictionary_2_without_compact_container"] = legacy
    with_2 = dictionary_2_vector(tables)
    flags_2 = parse_preamble(with_2).required_flags
    out["header_dictionary_2_flag_clear"] = (
        patch_preamble(with_2, 16, "<Q", flags_2 & ~FLAG_HEADER_DICTIONARY_2), "MalformedHeaderError",
        "a header compressed with dictionary 2 in a file without required flag bit 7: read with dictionary 1, "
        "its frame does not decode to a header")
    REPAIRED["header_dictionary_2_flag_clear"] = with_2
    with_1 = dumps(learned_scene(quality=2), tables=tables, compression_level=None, header_dictionary=1)
    out["header_dictionary_2_flag_on_dictionary_1_header"] = (
        patch_preamble(with_1, 16, "<Q", parse_preamble(with_1).required_flags | FLAG_HEADER_DICTIONARY_2),
        "MalformedHeaderError", "required flag bit 7 on a header compressed with dictionary 1: read with "
        "dictionary 2, its frame does not decode to a header")
    REPAIRED["header_dictionary_2_flag_on_dictionary_1_header"] = with_1
    return out


# --- format 1.2: compact cameras (FORMAT.md I.5.1) -----------------------------------------------------
def orbit(frames: int, *, zoom: bool = False, timestamps: bool = True) -> Trajectory:
    """A camera turning about y through rotations with exact rational entries (Pythagorean triples, so
    every platform computes the same float64 values) while it backs away: some values fall from frame to
    frame, so the predicted differences wrap modulo 2^32.  ``zoom``: fx and fy change every frame."""
    triples = [(1, 0, 1), (4, 3, 5), (12, 5, 13), (15, 8, 17), (24, 7, 25), (21, 20, 29), (40, 9, 41), (35, 12, 37)]
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    K = np.tile(np.array([[100.0, 0.0, 31.5], [0.0, 100.0, 23.5], [0.0, 0.0, 1.0]]), (frames, 1, 1))
    for i in range(frames):
        a, b, c = triples[i % len(triples)]
        cos, sin = a / c, b / c
        w2c[i, :3, :3] = [[cos, 0.0, sin], [0.0, 1.0, 0.0], [-sin, 0.0, cos]]
        w2c[i, :3, 3] = [0.1 * i, -0.05 * i, 3.0 - 0.25 * i]
        if zoom:
            K[i, 0, 0] = K[i, 1, 1] = 100.0 + 7.25 * i
    return Trajectory(K=K, w2c=w2c, width=64, height=48, timestamps=np.arange(frames) / 30.0 if timestamps else None)


def with_cameras(s: Scene, traj: Trajectory) -> Scene:
    return Scene(s.static_tokens, s.dynamic_tokens, traj, s.fingerprint, s.metadata, s.provenance, s.encoding)


def compact_valid_vectors() -> dict[str, tuple[bytes, str]]:
    return {
        "compact_cameras_static_f32": (
            dumps_1_2(scene(2, 1, 3), encoding="float32", compression_level=None),
            "1.2: compact cameras, one frame (constant K and static pose, P = 4), every section raw (the "
            "FORMAT.md I.5.1 example)"),
        "compact_cameras_orbit_f32_zstd": (
            dumps_1_2(with_cameras(scene(8, 4, 4, provenance=PROVENANCE), orbit(8)), encoding="int8"),
            "1.2: compact cameras, 8 frames of an orbit rounded to float32 (constant K, moving pose, "
            "timestamps), zstd sections"),
        "compact_cameras_orbit_f32_raw": (
            dumps_1_2(with_cameras(scene(8, 4, 4), orbit(8)), encoding="int8", compression_level=None),
            "1.2: the same orbit with every section raw: the byte planes of the predicted records are "
            "readable in the file"),
        "compact_cameras_zoom_exact_f64": (
            dumps_1_2(with_cameras(scene(4, 2, 4), orbit(5, zoom=True)), encoding="float16", cameras="exact"),
            "1.2: compact cameras in float64 (P = 8, bit-exact), per-frame intrinsics (zoom), moving pose"),
        "compact_cameras_distortion_timestamps": (
            dumps_1_2(scene(4, 2, 4, frames=3, distortion=[0.01, -0.002, 0.0005, 0.0, 0.001], timestamps=True),
                  encoding="int4", compression_level=None),
            "1.2: compact cameras with 5 distortion terms and timestamps stored as float64 after the blocks"),
        "compact_cameras_with_rans": (
            dumps_1_2(with_cameras(scene(16, 8, 4, provenance=PROVENANCE), orbit(4)), encoding="int4-rans"),
            "1.2: compact cameras and entropy-coded tokens: required flags 3"),
    }


def compact_block(values: np.ndarray, width: int) -> bytes:
    """FORMAT.md I.5.1, written from the text: predicted records, then byte planes."""
    u = np.ascontiguousarray(values, dtype={4: "<f4", 8: "<f8"}[width]).view({4: "<u4", 8: "<u8"}[width])
    e = u.copy()
    e[1:] = u[1:] - u[:-1]
    return np.ascontiguousarray(e.reshape(-1).view(np.uint8).reshape(-1, width).T).tobytes()


def compact_payload(width: int, flags: int, k: list[list[float]], poses: list[list[float]],
                    tail: list[float] = ()) -> bytes:
    return (bytes([width, flags]) + compact_block(np.array(k, np.float64), width)
            + compact_block(np.array(poses, np.float64), width) + np.array(tail, "<f8").tobytes())


def compact_invalid_vectors() -> dict[str, tuple[bytes, str, str]]:
    good = dumps_1_2(scene(4, 2, 4, frames=2, provenance=PROVENANCE), encoding="int8", compression_level=None)
    header, sections = split(good)
    out: dict[str, tuple[bytes, str, str]] = {}
    K = [100.0, 0.0, 31.5, 100.0, 23.5]
    pose = [[1.0, 0.0, 0.0, 0.25 * i, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 2.0] for i in range(2)]

    def with_cams(name: str, payload: bytes, error: str, why: str, **kw: Any) -> None:
        bad = [list(s) for s in sections]
        cams = find(bad, "CAMS")
        cams[3], cams[4] = payload, len(payload)
        out[f"compact_cameras_{name}"] = (rebuild(header, bad, **kw), error, why)
        # a payload defect: the writer's own payload repairs it; a flag or version defect: the writer's flags
        REPAIRED[f"compact_cameras_{name}"] = rebuild(header, sections)

    assert find(sections, "CAMS")[3] == compact_payload(4, 1, [K], pose)  # the writer and the text agree
    with_cams("precision_2", bytes([2, 1]) + compact_payload(4, 1, [K], pose)[2:],
              "MalformedSectionError", "value width P = 2 (only 4 and 8 are defined)")
    with_cams("undefined_layout_flag", compact_payload(4, 1 | 4, [K], pose), "MalformedSectionError",
              "layout flag bit 2 set")
    with_cams("one_byte_short", compact_payload(4, 1, [K], pose)[:-1], "MalformedSectionError",
              "the section is one byte shorter than P, F and the header give")
    with_cams("one_byte_long", compact_payload(4, 1, [K], pose) + b"\0", "MalformedSectionError",
              "one byte after the last pose")
    with_cams("empty", b"", "MalformedSectionError", "a cameras section of 0 bytes (no room for P and F)")
    with_cams("flags_say_static", compact_payload(4, 3, [K], pose), "MalformedSectionError",
              "flag bit 1 (one pose) with two poses stored: the length does not match")
    with_cams("nan_focal", compact_payload(4, 1, [[float("nan")] + K[1:]], pose), "MalformedSectionError",
              "fx is a float32 NaN")
    with_cams("inf_translation", compact_payload(8, 1, [K], [pose[0], pose[1][:3] + [float("inf")] + pose[1][4:]]),
              "MalformedSectionError", "t[0] of frame 1 is +infinity (float64)")
    with_cams("zero_focal", compact_payload(4, 1, [[0.0] + K[1:]], pose), "MalformedSectionError", "fx = 0")
    with_cams("scaled_rotation", compact_payload(4, 1, [K], [pose[0], [2.0] + pose[1][1:]]),
              "MalformedSectionError", "R[0][0] = 2 in frame 1: not a rotation")
    legacy = find(split(dumps_1_1(scene(4, 2, 4, frames=2), compression_level=None))[1], "CAMS")[3]
    assert legacy[0] == 0  # the low byte of fx = 100.0 as float64
    with_cams("legacy_layout_under_flag", legacy, "MalformedSectionError",
              "required flag bit 1 but the 1.0 float64 cameras section (P reads as 0)", minor=2, required_flags=2)
    legacy_sections = [list(x) for x in sections]
    find(legacy_sections, "CAMS")[3:5] = [legacy, len(legacy)]
    REPAIRED["compact_cameras_legacy_layout_under_flag"] = rebuild(header, legacy_sections, minor=0, required_flags=0)
    with_cams("without_flag", compact_payload(4, 1, [K], pose), "MalformedSectionError",
              "a compact cameras section in a 1.0 file without flag bit 1 (the 1.0 length does not match)",
              minor=0, required_flags=0)
    with_cams("in_1_1_file", compact_payload(4, 1, [K], pose), "MalformedHeaderError",
              "required flag bit 1 in a file that says minor version 1", minor=1, required_flags=2)
    with_cams("unknown_flag_bit_2", compact_payload(4, 1, [K], pose), "UnsupportedFeatureError",
              "required flag bit 2 (undefined in 1.2) beside bit 1", minor=2, required_flags=2 | 4,
              compact_layout=False)
    ts_header = dict(header, cameras=dict(header["cameras"], has_timestamps=True))
    bad = [list(x) for x in sections]
    cams = find(bad, "CAMS")
    cams[3] = compact_payload(4, 1, [K], pose, [1.0, 0.5])
    cams[4] = len(cams[3])
    cams[3] = compact_payload(4, 1, [K], pose, [0.5, 1.0])
    cams[4] = len(cams[3])
    REPAIRED["compact_cameras_decreasing_timestamps"] = rebuild(ts_header, bad)
    cams[3] = compact_payload(4, 1, [K], pose, [1.0, 0.5])
    cams[4] = len(cams[3])
    out["compact_cameras_decreasing_timestamps"] = (rebuild(ts_header, bad), "MalformedSectionError",
                                                    "timestamps 1.0 then 0.5 after the blocks")
    return out


# --- format 1.3: the compact container (FORMAT.md I.3.1, I.4.1, I.5.2) ------------------------------------
ENCODER_METADATA = {"vt4d": {"source_camera": "cam00", "clip_start": 0, "clip_frames": 8, "depth_source": "capture"}}


def container_valid_vectors() -> dict[str, tuple[bytes, str]]:
    base = scene(4, 2, 2, provenance=PROVENANCE)
    header, sections = split(dumps(base, encoding="int8", compression_level=None))
    header["future_key"] = {"anything": [1, 2]}
    sections.insert(2, ["xTRA", False, 0, b"ancillary bytes a 1.3 reader skips", 34, True])
    sections.append(["xZZZ", False, 7, b"unknown compression is fine when ancillary", 99, False])
    return {
        "compact_container_minimal": (
            dumps(scene(2, 1, 3), encoding="float32", compression_level=None),
            "1.3: compact container, one frame (quaternion pose), float32 tokens stored raw and 64-aligned, "
            "the cameras section packed right after the table (the FORMAT.md I.4.1 example)"),
        "compact_container_orbit_rans": (
            dumps(with_cameras(scene(64, 32, 4, provenance=PROVENANCE, metadata=ENCODER_METADATA), orbit(8)),
                  encoding="int4-rans"),
            "1.3: what the encoder writes by default: int4-rans tokens, 8 frames of an orbit as float32 "
            "quaternions with timestamps, provenance and the encoder's vt4d metadata; nothing aligned"),
        "compact_container_int8_distortion": (
            dumps(with_cameras(scene(16, 8, 4, metadata={"scene": "ramp"}), orbit(3)), encoding="int8",
                  compression_level=None),
            "1.3: int8 tokens stored raw (aligned) with their quantization sections packed between them"),
        "compact_container_exact_f64": (
            dumps(with_cameras(scene(4, 2, 4), orbit(5, zoom=True)), encoding="float16", cameras="exact"),
            "1.3: compact container with float64 matrix poses (cameras=\"exact\", bit for bit), zoom, zstd"),
        "compact_container_legacy_cameras": (
            dumps(scene(4, 2, 4, frames=2, provenance=PROVENANCE), encoding="int4", cameras="legacy"),
            "1.3: compact header and table with the 1.0 float64 cameras section: required flags 4 only"),
        "compact_container_future_minor": (
            rebuild_1_3(header, sections, minor=9, optional_flags=1 << 40, required_flags=6),
            "minor version 9 with the compact container: an unknown optional flag, header key and two "
            "unknown ancillary sections (one aligned, one with an unknown compression code)"),
    }


def container_invalid_vectors() -> dict[str, tuple[bytes, str, str]]:
    good = dumps(with_cameras(scene(4, 2, 4, provenance=PROVENANCE), orbit(2)), encoding="int8",
                 compression_level=None)
    header, sections = split(good)
    raw_header = msgpack.packb(binary_digests(header), use_bin_type=True)
    stored = compress_header(raw_header)
    out: dict[str, tuple[bytes, str, str]] = {}

    def add(name: str, data: bytes, error: str, why: str) -> None:
        out[f"compact_container_{name}"] = (data, error, why)
        REPAIRED.setdefault(f"compact_container_{name}", good)  # the good file with one change, unless given

    add("header_not_zstd", rebuild_1_3(raw_header, sections, compress=False), "MalformedHeaderError",
        "required flag bit 2 but the header is plain msgpack, not a zstd frame")
    no_size = zstandard.ZstdCompressor(write_content_size=False).compress(raw_header)
    add("header_no_content_size", rebuild_1_3(no_size, sections, compress=False), "MalformedHeaderError",
        "the header's zstd frame does not declare its content size")
    add("header_trailing_frame", rebuild_1_3(stored + b"\x50\x2a\x4d\x18" + bytes(4), sections, compress=False),
        "MalformedHeaderError", "an empty skippable frame after the header's zstd frame")
    huge = zstandard.ZstdCompressor(level=19).compress(b"\x80" + bytes(1 << 20))
    add("header_declares_over_1_mib", rebuild_1_3(huge, sections, compress=False), "LimitExceededError",
        "the header's zstd frame declares 1 MiB + 1 bytes")
    fhd = stored[4]
    assert fhd & 0x23 == 0x20  # single segment (no window byte), no dictionary id: the id byte goes after fhd
    with_id = stored[:4] + bytes([fhd | 0x01, 0]) + stored[5:]
    add("header_dictionary_id", rebuild_1_3(with_id, sections, compress=False), "MalformedHeaderError",
        "the header's zstd frame carries a 1-byte dictionary id (0): I.3.1 forbids one, whatever its value")
    REPAIRED["compact_container_header_dictionary_id"] = rebuild_1_3(stored, sections, compress=False)
    add("header_unknown_key", rebuild_1_3(dict(header, extra=1), sections), "MalformedHeaderError",
        "an unknown key inside the compressed header of a 1.3 file")
    add("header_bin_type", rebuild_1_3(msgpack.packb(binary_digests(dict(header, metadata={"x": b"bytes"})),
                                                     use_bin_type=True), sections), "MalformedHeaderError",
        "a msgpack bin value in the metadata of a compressed header (bin is for the two digests only)")
    add("hex_digest", rebuild_1_3(msgpack.packb(header, use_bin_type=True), sections), "MalformedHeaderError",
        "the fingerprint digests as 64 hex digits inside a compact header (I.3.1 wants 32-byte bin values)")
    short = binary_digests(header)
    short["fingerprint"]["weights_sha256"] = short["fingerprint"]["weights_sha256"][:31]
    add("digest_31_bytes", rebuild_1_3(msgpack.packb(short, use_bin_type=True), sections), "MalformedHeaderError",
        "weights_sha256 as a 31-byte bin value")
    add("in_1_2_file", rebuild_1_3(header, sections, minor=2), "UnsupportedFeatureError",
        "required flag bit 2 in a file that says minor version 2 (unknown there)")
    add("table_flag_bit_2", patch_entry(good, 0, 4, "<B", 0x05), "MalformedSectionError",
        "a compact table entry sets flag bit 2")
    data = bytearray(good)
    zsta_at = parse_table_offsets(good)[[x[0] for x in sections].index("ZSTA")]
    assert zsta_at % 64 == 0 and not data[zsta_at - 1]
    data[zsta_at - 1] = 0x01
    add("nonzero_padding", bytes(data), "MalformedSectionError", "the padding before an aligned section is not zero")
    K = [100.0, 0.0, 31.5, 100.0, 23.5]
    t = [0.0, 0.0, 3.0]

    ts = [0.0, 1 / 30]  # orbit(2) has timestamps: they follow the blocks (I.5.1)

    def with_cams(name: str, payload: bytes, why: str, repaired: bytes) -> None:
        for target, stored in ((out, payload), (REPAIRED, repaired)):
            bad = [list(x) for x in sections]
            cams = find(bad, "CAMS")
            cams[2:5] = [0, stored, len(stored)]
            data = rebuild_1_3(header, bad)
            if target is out:
                add(name, data, "MalformedSectionError", why)
            else:
                REPAIRED[f"compact_container_{name}"] = data

    quat = [1.0, 0.0, 0.0, 0.0] + t
    with_cams("quaternion_zero_norm", compact_payload(4, 1 | 4, [K], [quat, [0.0] * 4 + t], ts),
              "the second pose's quaternion is (0, 0, 0, 0)", compact_payload(4, 1 | 4, [K], [quat, quat], ts))
    matrix = [1.0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 3.0]
    with_cams("quaternion_matrix_length", compact_payload(4, 1 | 4, [K], [matrix] * 2, ts),
              "layout flag bit 2 with 12-value pose records: the length does not match",
              compact_payload(4, 1, [K], [matrix] * 2, ts))
    with_cams("cameras_flag_bit_3", compact_payload(4, 1 | 8, [K], [matrix] * 2, ts),
              "compact cameras layout flag bit 3 (undefined in 1.3)", compact_payload(4, 1, [K], [matrix] * 2, ts))
    return out


# --- format 1.4: extra cameras (FORMAT.md I.5.3) --------------------------------------------------------------
def shifted(traj: Trajectory, dx: float, *, turn: tuple[int, int, int] | None = None, fx: float | None = None,
            static: bool = False) -> Trajectory:
    """Another camera of the same rig: ``traj`` moved ``dx`` metres along its x axis (exact in binary), turned
    about y by the Pythagorean triple ``turn`` (a, b, c: cos = a / c, sin = b / c), with focal length ``fx``;
    ``static``: every frame takes frame 0's pose.  No timestamps (an extra camera shares CAMS' own)."""
    w2c, K = traj.w2c.copy(), traj.K.copy()
    if static:
        w2c[:] = w2c[0]
    if turn is not None:
        a, b, c = turn
        w2c[:, :3, :3] = np.array([[a / c, 0.0, b / c], [0.0, 1.0, 0.0], [-b / c, 0.0, a / c]]) @ w2c[:, :3, :3]
    w2c[:, 0, 3] += dx
    if fx is not None:
        K[:, 0, 0] = K[:, 1, 1] = fx
    return Trajectory(K=K, w2c=w2c, width=traj.width, height=traj.height)


def with_extra(s: Scene, cams: Trajectory, extras: list[Trajectory]) -> Scene:
    return Scene(s.static_tokens, s.dynamic_tokens, cams, s.fingerprint, s.metadata, s.provenance, s.encoding,
                 extra_cameras=extras)


RIG_METADATA = {"vt4d": {"source_camera": "cam00", "clip_start": 0, "clip_frames": 8, "depth_source": "capture",
                         "source_cameras": ["cam00", "cam01", "cam02", "cam03"]}}


def extra_cameras_valid_vectors() -> dict[str, tuple[bytes, str]]:
    one = cameras(1)
    minimal = with_extra(scene(2, 1, 3), one, [shifted(one, -0.5), shifted(one, 0.0, turn=(4, 3, 5), fx=120.0)])
    rig = orbit(8)
    rig_scene = with_extra(scene(64, 32, 4, provenance=PROVENANCE, metadata=RIG_METADATA), rig,
                           [shifted(rig, -0.25), shifted(rig, 0.5, turn=(12, 5, 13)),
                            shifted(rig, 1.0, turn=(24, 7, 25), static=True)])
    two = cameras(2, timestamps=True)
    pair = with_extra(scene(4, 2, 4, frames=2, provenance=PROVENANCE), two,
                      [shifted(two, 0.25), shifted(two, -0.75, turn=(15, 8, 17), static=True)])
    zoom = orbit(5, zoom=True)
    return {
        "extra_cameras_minimal": (
            dumps(minimal, encoding="float32", compression_level=None),
            "1.4: the compact_container_minimal scene with 2 extra static cameras (one shifted, one turned with "
            "another focal length), every section raw (the FORMAT.md I.5.3 example)"),
        "extra_cameras_orbit_rans": (
            dumps(rig_scene, encoding="int4-rans"),
            "1.4: a 4-camera encode as the encoder writes it: int4-rans tokens, 8 frames of an orbit with "
            "timestamps in CAMS, 3 extra cameras (two moving, one static) as float32 quaternions, zstd"),
        "extra_cameras_exact_f64": (
            dumps(with_extra(scene(4, 2, 4), zoom, [shifted(zoom, 0.5), shifted(zoom, -0.5, turn=(4, 3, 5))]),
                  encoding="float16", cameras="exact"),
            "1.4: compact container, cameras=\"exact\": CAMS and both extra cameras as float64 matrices with "
            "per-frame intrinsics (zoom), bit for bit"),
        "extra_cameras_legacy_layout": (
            dumps(pair, encoding="int8", cameras="legacy", header="legacy", compression_level=None),
            "1.4 in the 1.0 layout (msgpack header, 40-byte entries, 64-aligned payloads) with the 1.0 float64 "
            "cameras section: required flags 8 only; the extra cameras are I.5 float64 K and w2c"),
        "extra_cameras_legacy_header_compact_cameras": (
            dumps(pair, encoding="int4", header="legacy"),
            "1.4 in the 1.0-1.2 layout with compact cameras (required flags 10): float32 matrix records, no "
            "quaternions (those need a compact container)"),
    }


def extra_cameras_invalid_vectors() -> dict[str, tuple[bytes, str, str]]:
    two = cameras(2)
    good_scene = with_extra(scene(4, 2, 4, frames=2, provenance=PROVENANCE), two,
                            [shifted(two, 0.25), shifted(two, -0.75, static=True)])
    good = dumps(good_scene, encoding="int8", compression_level=None)
    header, sections = split(good)
    legacy = dumps(good_scene, encoding="int8", compression_level=None, header="legacy", cameras="legacy")
    legacy_header, legacy_sections = split(legacy)
    xcam = find(sections, "XCAM")[3]
    records = [xcam[9:9 + struct.unpack_from("<I", xcam, 1)[0]], xcam[9 + struct.unpack_from("<I", xcam, 1)[0]:]]
    K = [100.0, 0.0, 31.5, 100.0, 23.5]
    out: dict[str, tuple[bytes, str, str]] = {}

    def add(name: str, data: bytes, error: str, why: str) -> None:
        out[f"extra_cameras_{name}"] = (data, error, why)
        REPAIRED.setdefault(f"extra_cameras_{name}", good)  # the good file with one change, unless given

    def with_xcam(name: str, payload: bytes, error: str, why: str, *, legacy_layout: bool = False,
                  repaired: bytes | None = None) -> None:
        for stored in (repaired, payload):
            if stored is None:
                REPAIRED[f"extra_cameras_{name}"] = legacy if legacy_layout else good
                continue
            bad = [list(x) for x in (legacy_sections if legacy_layout else sections)]
            find(bad, "XCAM")[2:5] = [0, stored, len(stored)]
            data = rebuild(legacy_header if legacy_layout else header, bad)
            if stored is payload:
                add(name, data, error, why)
            else:
                REPAIRED[f"extra_cameras_{name}"] = data

    def pack(*recs: bytes) -> bytes:
        return bytes([len(recs)]) + struct.pack(f"<{len(recs)}I", *map(len, recs)) + b"".join(recs)

    assert xcam == pack(*records)  # the writer and the text agree
    add("flag_without_section", rebuild_1_3(header, [x for x in sections if x[0] != "XCAM"], minor=4,
                                            required_flags=FLAG_COMPACT_CONTAINER | FLAG_COMPACT_CAMERAS
                                            | FLAG_EXTRA_CAMERAS),
        "MalformedSectionError", "required flag bit 3 but no XCAM section")
    add("section_without_flag", rebuild_1_3(header, sections, minor=4,
                                            required_flags=FLAG_COMPACT_CONTAINER | FLAG_COMPACT_CAMERAS),
        "MalformedSectionError", "an XCAM section in a file whose required flag bit 3 is clear")
    add("in_1_3_file", rebuild_1_3(header, sections, minor=3), "UnsupportedFeatureError",
        "required flag bit 3 in a file that says minor version 3 (unknown there)")
    ancillary = [list(x) for x in sections]
    find(ancillary, "XCAM")[1] = False
    add("ancillary", rebuild(header, ancillary), "MalformedSectionError", "the XCAM section is marked ancillary")
    with_xcam("count_zero", b"\x00", "MalformedSectionError", "N = 0 (the section exists only with extra cameras)")
    with_xcam("count_64", bytes([64]) + struct.pack("<64I", *([len(records[1])] * 64)) + records[1] * 64,
              "LimitExceededError", "64 extra cameras (the limit is 63)")
    with_xcam("table_cut_short", xcam[:6], "MalformedSectionError", "N = 2 but only 5 bytes of length table follow")
    with_xcam("trailing_byte", xcam + b"\x00", "MalformedSectionError",
              "one byte after the last record (the lengths do not add up to the section)")
    with_xcam("record_one_byte_long", pack(records[0], records[1] + b"\x00"), "MalformedSectionError",
              "record 1 is one byte longer than its P, F and the header give (the lengths agree with it)")
    with_xcam("record_empty", pack(records[0], b""), "MalformedSectionError",
              "record 1 is 0 bytes (no room for P and F)")
    with_xcam("nan_focal", pack(records[0], compact_payload(4, 3, [[float("nan")] + K[1:]],
                                                            [[1.0, 0, 0, -0.75, 0, 1.0, 0, 0, 0, 0, 1.0, 2.0]])),
              "MalformedSectionError", "record 1's fx is a float32 NaN",
              repaired=pack(records[0], compact_payload(4, 3, [K], [[1.0, 0, 0, -0.75, 0, 1.0, 0, 0, 0, 0, 1.0, 2.0]])))
    with_xcam("distortion_in_record", pack(records[0], records[1] + np.zeros(4, "<f8").tobytes()),
              "MalformedSectionError", "record 1 carries 4 float64 distortion terms, which extra cameras do not have")
    first = find(legacy_sections, "XCAM")[3][9:9 + 400]  # 2 frames of I.5 float64 K and w2c
    three = cameras(3)
    with_xcam("legacy_three_frames", pack(first, np.concatenate([three.K.ravel(), three.w2c.ravel()]).astype("<f8")
                                          .tobytes()), "MalformedSectionError",
              "a float64 record of 3 frames in a 2-frame file", legacy_layout=True,
              repaired=pack(first, np.concatenate([three.K[:2].ravel(), three.w2c[:2].ravel()]).astype("<f8")
                            .tobytes()))
    with_xcam("legacy_compact_record", pack(first, records[1]), "MalformedSectionError",
              "a compact cameras record in a file without required flag bit 1 (its records are I.5 float64)",
              legacy_layout=True)
    return out


# --- format 1.1: entropy-coded tokens ------------------------------------------------------------------
def rans_valid_vectors() -> dict[str, tuple[bytes, str]]:
    constant = scene(6, 3, 2, provenance=PROVENANCE)
    constant.dynamic_tokens[:] = 0.75
    i, c = np.meshgrid(np.arange(12), np.arange(4), indexing="ij")
    narrow = scene(12, 3, 4, frames=1)
    narrow.static_tokens[:] = (c / 4.0 - 0.5 + ((i * (c + 1)) % 3 - 1) / 64.0).astype(np.float32)
    return {
        "int5_rans_centre_prediction": (
            dumps_1_1(narrow, encoding="int5-rans", compression_level=None),
            "1.1: int5-rans where Z_s's channels each span a narrow range: coded as residuals from per-channel "
            "centre codes (prediction 1); Z_d without prediction"),
        "int4_rans_one_group": (dumps_1_1(scene(16, 8, 4), encoding="int4-rans", compression_level=None),
                                "1.1: int4-rans, one scale/offset per token matrix, every section raw"),
        "int6_rans_channel_groups": (
            dumps_1_1(scene(24, 8, 4, frames=2, timestamps=True, provenance=PROVENANCE), encoding="int6-rans",
                  groups=2, compression_level=None),
            "1.1: int6-rans with 2 channel groups of 2 channels each"),
        "int3_rans_constant_matrix": (
            dumps_1_1(constant, encoding="int3-rans", compression_level=None),
            "1.1: int3-rans; Z_d is constant (scale 0, a one-symbol frequency table, a 4-byte stream)"),
        "int8_rans_centre_prediction_511": int8_rans_prediction_vector(),
    }


def int8_rans_prediction_vector() -> tuple[bytes, str]:
    """int8-rans with centre prediction, built by hand so it does not depend on the writer's choice of
    mode: its static stream's residual symbols run from 5 to 510 of the 511-symbol alphabet (0..510), so a
    reader that keeps symbols in bytes decodes every other vector and fails here (issue 15)."""
    base = scene(8, 4, 4, provenance=PROVENANCE)
    header, sections = split(dumps_1_1(base, encoding="int8-rans", compression_level=None))
    centres = [10, 250, 128, 0]
    codes = [[255, 0, 128, 255], [254, 1, 0, 0], [200, 250, 255, 7], [10, 5, 127, 1],
             [0, 255, 129, 128], [11, 249, 64, 3], [255, 2, 192, 254], [9, 251, 128, 2]]
    symbols = [q - centres[k] + 255 for row in codes for k, q in enumerate(row)]
    assert (min(symbols), max(symbols)) == (5, 510)  # the range the description and FORMAT.md I.13 give
    used = sorted(set(symbols))
    freqs = [0] * 511
    for sym in used:
        freqs[sym] = 16384 // len(used)
    freqs[used[0]] += 16384 - sum(freqs)
    head = struct.pack("<Hff", 1, 1 / 128, -1.0) + bytes([1]) + bytes(centres)
    payload = rans_payload(head, freqs, symbols)
    find(sections, "ZSTA")[2:5] = [0, payload, len(payload)]
    return (rebuild(header, sections, minor=1, required_flags=1),
            "1.1: int8-rans with centre prediction (prediction 1): residual symbols 5..510 of the "
            "511-symbol alphabet; a reader storing symbols in bytes fails only here")


def rans_payload(head: bytes, freqs: list[int], codes: list[int]) -> bytes:
    """A token payload from its parts: group count + parameters, table, stream (for hand-made damage)."""
    return head + pack_table(freqs) + rans_encode(np.array(codes), freqs)


def rans_invalid_vectors() -> dict[str, tuple[bytes, str, str]]:
    good = dumps_1_1(scene(4, 2, 4, provenance=PROVENANCE), encoding="int2-rans", compression_level=None)
    header, sections = split(good)
    out: dict[str, tuple[bytes, str, str]] = {}

    head = struct.pack("<HffB", 1, 0.5, -1.0, 0)  # one group: scale 0.5, offset -1; no prediction
    codes = [0, 1, 2, 3] * 4
    full = rans_payload(head, [4096] * 4, codes)

    def with_payload(name: str, payload: bytes, error: str, why: str, repaired: bytes = full) -> None:
        for target, stored in ((out, payload), (REPAIRED, repaired)):
            bad = [list(s) for s in sections]
            find(bad, "ZSTA")[3:5] = [stored, len(stored)]
            data = rebuild(header, bad, minor=1, required_flags=1)
            if target is out:
                out[name] = (data, error, why)
            else:
                REPAIRED[name] = data
    with_payload("rans_table_bad_sum", head + b"\x00\x00\x04\x00" + bytes([0x80, 0x20] * 3 + [0x7F]) +
                 rans_encode(np.array(codes), [4096] * 4), "MalformedSectionError",
                 "frequency table sums to 12,415, not 16,384")
    with_payload("rans_table_outside_alphabet", head + b"\x02\x00\x04\x00" + bytes([0x80, 0x20] * 4) +
                 rans_encode(np.array(codes), [4096] * 4), "MalformedSectionError",
                 "a 2-bit alphabet (symbols 0..3) but the table covers symbols 2..5")
    with_payload("rans_table_overlong_varint", head + b"\x00\x00\x01\x00\x80\x80\x81\x00" + b"\x00\x00\x80\x00",
                 "MalformedSectionError", "a 4-byte varint in the frequency table")
    with_payload("rans_truncated_stream", full[:-1], "TruncatedError", "the rANS stream lost its last byte")
    with_payload("rans_trailing_stream_bytes", full + b"\x00", "MalformedSectionError",
                 "one byte after the end of the rANS stream")
    forged = bytearray(full)
    forged[-1] ^= 0x01  # the lowest bit of the last renormalisation byte ends up in the final state
    with_payload("rans_bad_final_state", bytes(forged),
                 "MalformedSectionError", "a stream whose state never returns to L (forged bytes)")
    with_payload("rans_state_below_l", head + pack_table([4096] * 4) + b"\x00\x00\x00\x00",
                 "MalformedSectionError", "initial rANS state 0, below L = 2^23")
    with_payload("rans_bad_groups", struct.pack("<HffffffB", 3, *[0.5] * 3, *[-1.0] * 3, 0) + pack_table([4096] * 4) +
                 rans_encode(np.array(codes), [4096] * 4), "MalformedSectionError", "3 channel groups for d = 4")
    with_payload("rans_nan_scale", struct.pack("<HffB", 1, float("nan"), -1.0, 0) + pack_table([4096] * 4) +
                 rans_encode(np.array(codes), [4096] * 4), "MalformedSectionError", "the group's scale is NaN")
    centred = struct.pack("<HffB", 1, 0.5, -1.0, 1)  # prediction 1: 4 centre codes follow
    with_payload("rans_unknown_prediction", struct.pack("<HffB", 1, 0.5, -1.0, 2) + pack_table([4096] * 4) +
                 rans_encode(np.array(codes), [4096] * 4), "MalformedSectionError", "prediction mode 2")
    with_payload("rans_centre_out_of_range", centred + bytes([0, 1, 4, 3]) +
                 rans_payload(b"", [0, 0, 0, 16384], [3] * 16),
                 "MalformedSectionError", "centre code 4 in a 2-bit alphabet",
                 centred + bytes([0, 1, 3, 3]) + rans_payload(b"", [0, 0, 0, 16384], [3] * 16))
    with_payload("rans_residual_out_of_range", centred + bytes([3, 3, 3, 3]) +
                 rans_payload(b"", [0] * 4 + [16384, 0, 0], [4] * 16), "MalformedSectionError",
                 "residual symbol 4 (+1) on centre code 3 gives code 4 in a 2-bit alphabet",
                 centred + bytes([2, 2, 2, 2]) + rans_payload(b"", [0] * 4 + [16384, 0, 0], [4] * 16))
    REPAIRED.update(dict.fromkeys(("rans_without_flag", "rans_in_1_0_file", "rans_with_quant_section",
                                   "rans_too_many_values"), good))
    out["rans_without_flag"] = (patch_preamble(good, 16, "<Q", 0), "MalformedHeaderError",
                                "int2-rans tokens but required flag bit 0 is clear")
    out["rans_in_1_0_file"] = (patch_preamble(good, 12, "<H", 0), "MalformedHeaderError",
                               "int2-rans tokens in a file that says version 1.0")
    int8 = dumps_1_1(scene(4, 2, 4), encoding="int8", compression_level=None)
    REPAIRED["flag_without_rans"] = patch_preamble(int8, 12, "<H", 1)  # the 1.1 file, without flag bit 0
    out["flag_without_rans"] = (patch_preamble(patch_preamble(int8, 12, "<H", 1), 16, "<Q", 1),
                                "MalformedHeaderError", "required flag bit 0 set on an int8 file")
    quant = [list(s) for s in sections]
    quant.insert(1, ["QSTA", True, 0, bytes(32), 32])
    out["rans_with_quant_section"] = (rebuild(header, quant, minor=1, required_flags=1), "MalformedSectionError",
                                      "a QSTA section next to int2-rans tokens")
    fp = dict(header["fingerprint"], static_shape=[1 << 20, 4])
    out["rans_too_many_values"] = (rebuild(dict(header, static_shape=[1 << 20, 4], fingerprint=fp), sections,
                                           minor=1, required_flags=1), "LimitExceededError",
                                   "2^22 values in one int2-rans matrix (the limit is 2^21)")
    return out


# --- format 1.5: interleaved rANS lanes (FORMAT.md I.6.1, required flag bit 4) -------------------------------
LANE_FLAGS = FLAG_COMPACT_CONTAINER | FLAG_COMPACT_CAMERAS | FLAG_ENTROPY_CODED_TOKENS | FLAG_RANS_LANES


def narrow_scene(rows: int, dynamic_rows: int) -> Scene:
    """Z_s with narrow channels (centre prediction pays), Z_d the usual ramp (it does not)."""
    s = scene(rows, dynamic_rows, 4, provenance=PROVENANCE)
    i, c = np.meshgrid(np.arange(rows), np.arange(4), indexing="ij")
    s.static_tokens[:] = (c / 4.0 - 0.5 + ((i * (c + 1)) % 3 - 1) / 64.0).astype(np.float32)
    return s


def lanes_valid_vectors() -> dict[str, tuple[bytes, str]]:
    both = dumps(narrow_scene(24, 16), encoding="int5-rans", rans_lanes=4)
    prediction = [split(both)[1][k][3][2 + 8] for k in (1, 2)]  # (sections CAMS, ZSTA, ZDYN; G = 1)
    assert [x[0] for x in split(both)[1]] == ["CAMS", "ZSTA", "ZDYN"] and prediction == [1, 0], prediction
    # one section a single chain (K = 1), the other 32 lanes for 16 codes: lanes 16..31 decode nothing
    base = scene(16, 4, 4, provenance=PROVENANCE)
    header, sections = split(dumps(base, encoding="int4-rans", rans_lanes=1))
    for name, tokens, lanes in (("ZSTA", base.static_tokens, 1), ("ZDYN", base.dynamic_tokens, 32)):
        payload = encode_rans_tokens(tokens, "int4-rans", 1, lanes=lanes)
        find(sections, name)[3:5] = [payload, len(payload)]
    return {
        "int5_rans_lanes_both_predictions": (
            both, "1.5: int5-rans with 4 interleaved rANS lanes in both token sections (required flag bit 4, flags "
                  "23): Z_s coded as residuals from centre codes (prediction 1), Z_d without prediction; "
                  "compact container"),
        "int3_rans_lanes_3_uneven": (
            dumps(scene(5, 2, 4, frames=2, timestamps=True), encoding="int3-rans", rans_lanes=3, cameras="legacy",
                  header="legacy"),
            "1.5 in the 1.0-1.2 layout (required flags 17): int3-rans with K = 3 lanes over 20 and 8 codes, "
            "neither a multiple of 3 (lanes 0 and 1 decode one code more than lane 2)"),
        "int4_rans_lanes_1_and_32": (
            rebuild_1_3(header, sections, minor=5, required_flags=LANE_FLAGS),
            "1.5: int4-rans whose Z_s payload says K = 1 (one chain, the 1.1 stream after its K byte) and Z_d "
            "K = 32 for 16 codes: lanes 16 to 31 decode nothing, start and end in state L"),
    }


def lanes_invalid_vectors() -> dict[str, tuple[bytes, str, str]]:
    good = dumps(scene(4, 2, 4, provenance=PROVENANCE), encoding="int2-rans", compression_level=None, rans_lanes=4)
    header, sections = split(good)
    out: dict[str, tuple[bytes, str, str]] = {}

    head = struct.pack("<HffB", 1, 0.5, -1.0, 0) + pack_table([4096] * 4)  # G = 1, P = 0, uniform 2-bit table
    codes = np.array([0, 1, 2, 3] * 4)
    stream = rans_encode(codes, [4096] * 4, 4)

    def with_payload(name: str, payload: bytes, error: str, why: str) -> None:
        for target, stored in ((out, payload), (REPAIRED, head + bytes([4]) + stream)):
            bad = [list(x) for x in sections]
            find(bad, "ZSTA")[3:5] = [stored, len(stored)]
            data = rebuild_1_3(header, bad, minor=5, required_flags=LANE_FLAGS)
            if target is out:
                out[f"rans_lanes_{name}"] = (data, error, why)
            else:
                REPAIRED[f"rans_lanes_{name}"] = data
    written = find(sections, "ZSTA")[3]  # the writer and the text agree: K = 4 right after the table
    table_end = 11 + parse_rans_table(written[11:], 4)[1]  # (G = 1 and P = 0 there too)
    assert written[10] == 0 and written[table_end] == 4 and len(written) >= table_end + 1 + 16
    assert decode_rans_codes(head + bytes([4]) + stream, "int2-rans", 4, 4, lanes=True)[0].reshape(-1).tolist() \
        == codes.tolist()
    with_payload("zero", head + bytes([0]) + stream, "MalformedSectionError", "lane count K = 0")
    with_payload("33", head + bytes([33]) + stream, "MalformedSectionError", "lane count K = 33 (at most 32)")
    with_payload("count_missing", head, "TruncatedError", "the payload ends after the frequency table, before K")
    with_payload("states_cut_short", head + bytes([4]) + stream[:15], "TruncatedError",
                 "K = 4 but the stream ends inside the fourth initial state (15 bytes)")
    low = bytearray(stream)
    struct.pack_into("<I", low, 8, STATE_LOWER - 1)
    with_payload("state_below_l", head + bytes([4]) + bytes(low), "MalformedSectionError",
                 "the initial state of lane 2 is L - 1")
    forged = bytearray(stream)
    forged[4] ^= 0x01  # lane 1's lowest state bit: it runs through lane 1's steps to its final state
    with_payload("bad_final_state", head + bytes([4]) + bytes(forged), "MalformedSectionError",
                 "lane 1 ends in state L + 256 (the lowest bit of its initial state flipped): every lane MUST end in L")
    with_payload("truncated_stream", head + bytes([4]) + stream[:-1], "TruncatedError",
                 "the shared byte stream lost its last byte")
    with_payload("trailing_byte", head + bytes([4]) + stream + b"\x00", "MalformedSectionError",
                 "one byte after the end of the shared byte stream")
    REPAIRED["rans_lanes_in_1_4_file"] = rebuild_1_3(header, sections, minor=5, required_flags=LANE_FLAGS)
    out["rans_lanes_in_1_4_file"] = (rebuild_1_3(header, sections, minor=4, required_flags=LANE_FLAGS),
                                     "UnsupportedFeatureError",
                                     "required flag bit 4 in a file that says minor version 4 (unknown there)")
    int8 = dumps(scene(4, 2, 4), encoding="int8", compression_level=None)
    REPAIRED["rans_lanes_flag_without_rans"] = patch_preamble(patch_preamble(int8, 12, "<H", 5), 16, "<Q",
                                                              FLAG_COMPACT_CONTAINER | FLAG_COMPACT_CAMERAS)
    out["rans_lanes_flag_without_rans"] = (
        patch_preamble(patch_preamble(int8, 12, "<H", 5), 16, "<Q", FLAG_COMPACT_CONTAINER | FLAG_COMPACT_CAMERAS
                       | FLAG_RANS_LANES), "MalformedHeaderError",
        "required flag bit 4 (rANS lanes) on an int8 file, without bit 0")
    constant = scene(3, 2, 2)
    constant.static_tokens[:] = 0.5
    constant.dynamic_tokens[:] = 0.75
    old = dumps(constant, encoding="int3-rans", rans_lanes=0)  # streams 00 00 80 00: one chain, no K byte
    assert find(split(old)[1], "ZSTA")[3].endswith(b"\x00\x00\x80\x00")
    REPAIRED["rans_lanes_flag_on_1_1_payloads"] = old
    out["rans_lanes_flag_on_1_1_payloads"] = (
        patch_preamble(patch_preamble(old, 12, "<H", 5), 16, "<Q", LANE_FLAGS), "MalformedSectionError",
        "required flag bit 4 on a file whose payloads have no K byte: K reads as the stream's first byte, 0")
    return out


def invalid_vectors() -> dict[str, tuple[bytes, str, str]]:
    good = dumps_1_1(scene(4, 2, 4, provenance=PROVENANCE), encoding="int8", compression_level=None)
    header, sections = split(good)
    out: dict[str, tuple[bytes, str, str]] = {}

    def add(name: str, data: bytes, error: str, why: str) -> None:
        out[name] = (data, error, why)
        REPAIRED[name] = good  # each is the good file with one change

    def with_header(**changes: Any) -> bytes:
        h = dict(header, **changes)
        return rebuild(h, sections)

    add("bad_magic", b"\x89PNG\r\n\x1a\n" + good[8:], "BadMagicError", "a PNG signature, not vt4d")
    add("text_mode_damage", good.replace(b"\r\n", b"\n", 1), "BadMagicError",
        "CR LF in the signature became LF (text-mode transfer)")
    add("truncated", good[: len(good) - 5], "TruncatedError", "the last 5 bytes are missing")
    add("empty", b"", "BadMagicError", "zero bytes")
    add("trailing_bytes", good + b"\0", "MalformedSectionError", "one byte after the declared end")
    add("major_2", patch_preamble(good, 10, "<H", 2), "UnsupportedVersionError", "major version 2")
    add("unknown_required_flag", patch_preamble(good, 16, "<Q", 1 << 3), "UnsupportedFeatureError",
        "required feature flag bit 3 (unknown in 1.0)")
    add("preamble_checksum", patch_preamble(good, 24, "<Q", 1, fix_crc=False), "ChecksumError",
        "an optional-flags byte changed without updating the preamble CRC")
    flipped = bytearray(good)
    flipped[PREAMBLE_SIZE + 10] ^= 0x01
    add("header_checksum", bytes(flipped), "ChecksumError", "one header bit flipped")
    zsta = find(sections, "ZSTA")
    bad = [list(s) for s in sections]
    find(bad, "ZSTA")[3] = bytes([zsta[3][0] ^ 0x80]) + zsta[3][1:]
    data = bytearray(rebuild(header, bad))
    # restore the original CRC in the table so only the payload is damaged
    parse_preamble(bytes(data))
    idx = [s[0] for s in sections].index("ZSTA")
    data = patch_entry(bytes(data), idx, 32, "<I", crc32(zsta[3]))
    add("section_checksum", data, "ChecksumError", "one bit of a static-token code flipped")
    add("header_too_large", patch_preamble(good, 40, "<I", (1 << 20) + 1), "LimitExceededError",
        "the preamble claims a header of 1 MiB + 1 bytes")
    deep: Any = 0
    for _ in range(20):
        deep = [deep]
    add("header_too_deep", with_header(metadata={"deep": deep}), "LimitExceededError",
        "metadata nested 21 levels deep")
    raw_ext = msgpack.packb(dict(header, metadata={"x": msgpack.ExtType(5, b"abc")}), use_bin_type=True)
    add("header_ext_type", rebuild(raw_ext, sections), "MalformedHeaderError", "a msgpack extension type")
    raw_bin = msgpack.packb(dict(header, metadata={"x": b"bytes"}), use_bin_type=True)
    add("header_bin_type", rebuild(raw_bin, sections), "MalformedHeaderError", "a msgpack bin value")
    add("header_unknown_key", with_header(extra=1), "MalformedHeaderError",
        "an unknown header key in a 1.0 file")
    h = dict(header)
    del h["provenance"]
    add("header_missing_key", rebuild(h, sections), "MalformedHeaderError", "no provenance key")
    add("header_not_msgpack", rebuild(b"\xc1" * 8, sections), "MalformedHeaderError",
        "0xC1 is never valid msgpack")
    raw_dup = msgpack.packb(header, use_bin_type=True)
    raw_dup = b"\x88" + raw_dup[1:] + msgpack.packb("encoding") + msgpack.packb("float32")  # 8 pairs, one twice
    add("header_duplicate_key", rebuild(raw_dup, sections), "MalformedHeaderError", "the key 'encoding' twice")
    add("header_array_bomb", rebuild(b"\xdd\xff\xff\xff\xff", sections), "MalformedHeaderError",
        "an array32 claiming 2^32-1 elements in 5 bytes")
    fp = dict(header["fingerprint"], static_shape=[1 << 40, 4])
    add("absurd_shape", with_header(static_shape=[1 << 40, 4], fingerprint=fp), "LimitExceededError",
        "2^40 static tokens")
    add("fingerprint_shape_mismatch", with_header(fingerprint=dict(header["fingerprint"], static_shape=[5, 4])),
        "MalformedHeaderError", "the fingerprint's token shape differs from the header's")
    add("bad_sha256", with_header(fingerprint=dict(header["fingerprint"], weights_sha256="XYZ")),
        "MalformedHeaderError", "weights_sha256 is not 64 hex digits")
    names = [s[0] for s in sections]
    add("overlapping_sections", patch_entry(good, 2, 8, "<Q", parse_table_offsets(good)[1]),
        "MalformedSectionError", "section 2 starts inside section 1")
    add("section_out_of_file", patch_entry(good, len(sections) - 1, 16, "<Q", 1 << 40),
        "MalformedSectionError", "the last section claims 2^40 stored bytes")
    add("decompression_bomb_declared", patch_entry(good, names.index("ZSTA"), 24, "<Q", 1 << 40),
        "LimitExceededError", "a section declares 2^40 raw bytes")
    bomb = [list(s) for s in sections]
    zeros = zstandard.ZstdCompressor(level=19, write_content_size=False).compress(b"\0" * (64 << 20))
    find(bomb, "CAMS")[2:5] = [1, zeros, find(bomb, "CAMS")[4]]
    add("decompression_bomb_frame", rebuild(header, bomb), "MalformedSectionError",
        "a zstd frame without a size field that inflates to 64 MiB, declared as 200 bytes")
    liar = [list(s) for s in sections]
    find(liar, "CAMS")[2:4] = [1, zstandard.ZstdCompressor().compress(b"\0" * 4096)]
    add("zstd_size_mismatch", rebuild(header, liar), "MalformedSectionError",
        "the zstd frame declares 4096 bytes, the table 200")
    trail = [list(s) for s in sections]
    skippable = b"\x50\x2a\x4d\x18" + bytes(4)  # an empty skippable frame (RFC 8878 3.1.2)
    find(trail, "CAMS")[2:4] = [1, zstandard.ZstdCompressor(level=3).compress(find(sections, "CAMS")[3]) + skippable]
    add("zstd_trailing_frame", rebuild(header, trail), "MalformedSectionError",
        "a valid zstd frame followed by an empty skippable frame: a section is exactly one frame")
    add("unknown_critical_section", rebuild(header, sections + [["FUTR", True, 0, b"x", 1]]),
        "UnsupportedFeatureError", "a critical section type unknown to 1.0")
    add("missing_section", rebuild(header, [s for s in sections if s[0] != "QSTA"]), "MalformedSectionError",
        "int8 tokens without their quantization section")
    add("duplicate_section", rebuild(header, sections + [find(sections, "ZDYN")]), "MalformedSectionError",
        "ZDYN twice")
    short = [list(s) for s in sections]
    find(short, "ZSTA")[3:5] = [zsta[3][:-1], zsta[4] - 1]
    add("section_wrong_size", rebuild(header, short), "MalformedSectionError", "ZSTA one byte short for 4x4")
    padded = bytearray(good)
    padded[parse_table_offsets(good)[0] - 1] = 0xAA
    add("nonzero_padding", bytes(padded), "MalformedSectionError", "a padding byte before the first section is set")
    nan_q = [list(s) for s in sections]
    qsta = find(nan_q, "QSTA")
    qsta[3] = np.full(qsta[4] // 4, np.nan, "<f4").tobytes()
    add("nan_quantization", rebuild(header, nan_q), "MalformedSectionError", "scale and offset are NaN")
    cams = [list(s) for s in sections]
    cam = np.frombuffer(find(cams, "CAMS")[3], "<f8").copy()
    cam[9] = 2.0  # w2c[0, 0, 0]: the rotation is no longer orthonormal
    find(cams, "CAMS")[3] = cam.tobytes()
    add("bad_rotation", rebuild(header, cams), "MalformedSectionError", "w2c[0] has a scaled rotation")
    out.update(rans_invalid_vectors())
    out.update(learned_invalid_vectors())
    out.update(lanes_invalid_vectors())
    out.update(compact_invalid_vectors())
    out.update(container_invalid_vectors())
    out.update(extra_cameras_invalid_vectors())
    return out


def parse_table_offsets(data: bytes) -> list[int]:
    pre = parse_preamble(data)
    start = PREAMBLE_SIZE + pre.header_length
    end = start + pre.section_count * entry_size(pre.required_flags)
    return [e.offset for e in parse_table(data[start:end], pre.section_count, end, pre.file_length,
                                          compact=bool(pre.required_flags & FLAG_COMPACT_CONTAINER))]


# --- expected content ----------------------------------------------------------------------------
def float_list(a: np.ndarray) -> list:
    return np.asarray(a, np.float64).tolist()


def expected_content(data: bytes, description: str) -> dict[str, Any]:
    f = open_scene(data)
    s = f.to_scene()
    cams = s.cameras
    return {
        "description": description,
        "file_sha256": hashlib.sha256(data).hexdigest(),
        "bytes": len(data),
        "version": list(f.version),
        "encoding": f.encoding,
        "static_shape": list(f.static_shape),
        "dynamic_shape": list(f.dynamic_shape),
        "fingerprint": f.fingerprint.to_dict(),
        "provenance": None if f.provenance is None else f.provenance.to_dict(),
        "metadata": f.metadata,
        "cameras": {"width": cams.width, "height": cams.height, "K": float_list(cams.K), "w2c": float_list(cams.w2c),
                    "distortion": None if cams.distortion is None else float_list(cams.distortion),
                    "timestamps": None if cams.timestamps is None else float_list(cams.timestamps)},
        "static_tokens": float_list(s.static_tokens),
        "dynamic_tokens": float_list(s.dynamic_tokens),
        "static_tokens_sha256": hashlib.sha256(s.static_tokens.astype("<f4").tobytes()).hexdigest(),
        "dynamic_tokens_sha256": hashlib.sha256(s.dynamic_tokens.astype("<f4").tobytes()).hexdigest(),
        "sections": [e.type for e in f.sections],
    } | ({"extra_cameras": [{"K": float_list(x.K), "w2c": float_list(x.w2c)} for x in s.extra_cameras]}
         if f.has_extra_cameras else {})


def uses_zstd(data: bytes) -> bool:
    try:
        return any(s[2] == 1 for s in split(data)[1])
    except Exception:  # invalid vectors may not even split; compare those byte for byte
        return False


def generate() -> dict[str, bytes]:
    """Every vector file (relative path -> bytes), including expected JSON, the manifest and the test model's
    entropy tables (format 1.6)."""
    install_spec_tables()
    files: dict[str, bytes] = {LEARNED_TABLES_FILE: _json(learned_tables_json(learned_tables())),
                               CONTEXT_TABLES_FILE: _json(learned_tables_json(context_tables())),
                               PARTNER_TABLES_FILE: _json(learned_tables_json(partner_tables()))}
    manifest: dict[str, Any] = {"zstd_version": ".".join(map(str, zstandard.ZSTD_VERSION)),
                                "valid": {}, "invalid": {}}
    for name, (data, why) in valid_vectors().items():
        files[f"valid/{name}.vt4d"] = data
        files[f"valid/{name}.expected.json"] = _json(expected_content(data, why))
        manifest["valid"][name] = {"uses_zstd": uses_zstd(data)}
    for name, (data, error, why) in invalid_vectors().items():
        files[f"invalid/{name}.vt4d"] = data
        files[f"invalid/{name}.expected.json"] = _json({"error": error, "description": why,
                                                        "file_sha256": hashlib.sha256(data).hexdigest()})
        manifest["invalid"][name] = {"uses_zstd": uses_zstd(data), "error": error}
    files["MANIFEST.json"] = _json(manifest)
    return files


def _json(obj: Any) -> bytes:
    return (json.dumps(obj, indent=1, sort_keys=True) + "\n").encode()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="compare instead of writing")
    args = parser.parse_args()
    files = generate()
    if args.check:
        bad = [p for p, b in files.items() if not (VECTORS / p).is_file() or (VECTORS / p).read_bytes() != b]
        for p in bad:
            print(f"differs: spec/vectors/{p}")
        return 1 if bad else 0
    for sub in ("valid", "invalid", "tables"):
        (VECTORS / sub).mkdir(parents=True, exist_ok=True)
        for old in (VECTORS / sub).iterdir():
            if f"{sub}/{old.name}" not in files:
                old.unlink()
    for p, b in files.items():
        (VECTORS / p).write_bytes(b)
    print(f"wrote {len(files)} files under {VECTORS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
