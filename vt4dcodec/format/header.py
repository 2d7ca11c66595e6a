"""The msgpack header of a v1 scene (FORMAT.md, "Header"): bounded parsing and exact validation.

The header is one msgpack map with exactly these keys (version 1.0)::

    static_shape   [N_s, d]          ints
    dynamic_shape  [N_d, d]          ints, same d
    encoding       "float32" | "float16" | "int8" | "int4" | "int2-rans" .. "int8-rans" (1.1)
    cameras        {num_frames: T, width: W, height: H, distortion_terms: 0|4|5|8|12|14,
                    has_timestamps: bool}
    fingerprint    {model_id, model_version, config_sha256, weights_sha256, static_shape,
                    dynamic_shape, token_dtype}
    provenance     nil | {library_version, created_utc, source_capture_id (str | nil), kind}
    metadata       map (user key/values)

A file whose minor version is newer than this reader's may add keys; they are ignored.

In a compact container (format 1.3, required flag bit 2) the stored header is one zstd frame of these msgpack
bytes, compressed with the spec-fixed raw-content dictionary :data:`HEADER_DICTIONARY` (FORMAT.md I.3.1): the
key names and the usual values cost a few bytes of match codes instead of their text.  There the two
fingerprint digests are 32-byte msgpack bin values instead of 64 hex digits (the only bin values allowed);
the reader turns them back into hex, so the parsed header is the 1.2 header.  A 1.6 file with required flag
bit 7 uses :data:`HEADER_DICTIONARY_2` instead (I.3.2): dictionary 1 followed by a header of today's
multi-camera learned-rans files, about 60 bytes less for a 10-camera header.
"""

from __future__ import annotations

import threading

from dataclasses import dataclass
from collections.abc import Callable
from typing import Any, TypeVar

import msgpack
import zstandard

from ..cameras import DISTORTION_LENGTHS
from ..errors import LimitExceededError, MalformedHeaderError
from .checks import exact_keys, require_bool, require_int, require_map, require_shape
from .encodings import ALL_ENCODINGS
from .rans_tokens import MAX_RANS_VALUES, RANS_BITS
from .fingerprint import ModelFingerprint, Provenance
from .layout import BytesLike
from .limits import (MAX_CONTAINER_ITEMS, MAX_FRAMES, MAX_HEADER_BYTES, MAX_HEADER_DEPTH, MAX_IMAGE_SIDE,
                     MAX_STRING_CHARS, MAX_TOKEN_DIM, MAX_TOKEN_VALUES, MAX_TOKENS)
from .metadata import normalize_metadata

__all__ = ["HeaderInfo", "CameraLayout", "pack_header", "unpack_header", "parse_header", "HEADER_DICTIONARY",
           "HEADER_DICTIONARY_2", "compress_header", "decompress_header"]

HEADER_KEYS = {"static_shape", "dynamic_shape", "encoding", "cameras", "fingerprint", "provenance", "metadata"}
CAMERA_KEYS = {"num_frames", "width", "height", "distortion_terms", "has_timestamps"}

# FORMAT.md I.3.1: the dictionary of the compact header is the msgpack encoding (shortest forms, keys in this
# order) of this template, a header as the reference encoder writes it.  Spec-fixed: changing one byte of it
# changes how every 1.3 file decodes, so it never changes (tests pin its length and CRC-32).
HEADER_DICTIONARY_TEMPLATE: dict[str, Any] = {
    "encodings": ["float32", "float16", "int8", "int4", "int2-rans", "int3-rans", "int5-rans", "int6-rans",
                  "int7-rans", "int8-rans"],
    "kinds": ["generated", "estimated", "source_cameras", "vt4d-test"],
    "static_shape": [64, 32], "dynamic_shape": [32, 32], "encoding": "int4-rans",
    "cameras": {"num_frames": 8, "width": 64, "height": 64, "distortion_terms": 0, "has_timestamps": True},
    "fingerprint": {"model_id": "vt4d-tiny", "model_version": "1.0.0", "config_sha256": "0123456789abcdef",
                    "weights_sha256": "0123456789abcdef", "static_shape": [64, 32], "dynamic_shape": [32, 32],
                    "token_dtype": "float32"},
    "provenance": {"library_version": "0.1.0", "created_utc": "2026-01-01T00:00:00Z",
                   "source_capture_id": "synth-test-000000", "kind": "encoded"},
    "metadata": {"vt4d": {"source_camera": "cam00", "clip_start": 0, "clip_frames": 8, "depth_source": "capture"}},
}
HEADER_DICTIONARY: bytes = msgpack.packb(HEADER_DICTIONARY_TEMPLATE, use_bin_type=True)
# FORMAT.md I.3.2 (format 1.6, required flag bit 7): header dictionary 2 is dictionary 1 followed by the msgpack
# encoding of this template, a header of a learned-rans multi-camera encode (its digests empty strings: they are
# random bytes no dictionary predicts).  Spec-fixed like dictionary 1 (tests pin its length and CRC-32).
HEADER_DICTIONARY_2_TEMPLATE: dict[str, Any] = {
    "static_shape": [320, 32], "dynamic_shape": [32, 32], "encoding": "learned-rans",
    "cameras": {"num_frames": 8, "width": 64, "height": 64, "distortion_terms": 0, "has_timestamps": True},
    "fingerprint": {"model_id": "vt4d-tiny", "model_version": "2.0.0", "config_sha256": "", "weights_sha256": "",
                    "static_shape": [320, 32], "dynamic_shape": [32, 32], "token_dtype": "float32"},
    "provenance": {"library_version": "0.1.0", "created_utc": "2026-12-01T00:00:00Z",
                   "source_capture_id": "synth-test-000000", "kind": "encoded"},
    "metadata": {"vt4d": {"source_camera": "cam00", "clip_start": 0, "clip_frames": 8, "depth_source": "capture",
                          "source_cameras": [f"cam{i:02d}" for i in range(10)]}},
}
HEADER_DICTIONARY_2: bytes = HEADER_DICTIONARY + msgpack.packb(HEADER_DICTIONARY_2_TEMPLATE, use_bin_type=True)
_HEADER_ZSTD_LEVEL = 19  # the header is a few hundred bytes: the strongest level costs nothing
_HEADER_DICTS = {number: zstandard.ZstdCompressionDict(data, dict_type=zstandard.DICT_TYPE_RAWCONTENT)
                 for number, data in ((1, HEADER_DICTIONARY), (2, HEADER_DICTIONARY_2))}


@dataclass(frozen=True)
class CameraLayout:
    """What the header says about the cameras section."""

    num_frames: int
    width: int
    height: int
    distortion_terms: int
    has_timestamps: bool

    @property
    def raw_length(self) -> int:
        """Bytes of the cameras section: K (T*9), w2c (T*16), distortion, timestamps; float64 each."""
        t = self.num_frames
        return 8 * (25 * t + self.distortion_terms + (t if self.has_timestamps else 0))

    def to_dict(self) -> dict[str, Any]:
        return {"num_frames": self.num_frames, "width": self.width, "height": self.height,
                "distortion_terms": self.distortion_terms, "has_timestamps": self.has_timestamps}


@dataclass(frozen=True)
class HeaderInfo:
    """The validated header."""

    static_shape: tuple[int, int]
    dynamic_shape: tuple[int, int]
    encoding: str
    cameras: CameraLayout
    fingerprint: ModelFingerprint
    provenance: Provenance | None
    metadata: dict[str, Any]
    raw: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        return {
            "static_shape": list(self.static_shape), "dynamic_shape": list(self.dynamic_shape),
            "encoding": self.encoding, "cameras": self.cameras.to_dict(),
            "fingerprint": self.fingerprint.to_dict(),
            "provenance": None if self.provenance is None else self.provenance.to_dict(),
            "metadata": self.metadata,
        }


DIGEST_KEYS = ("config_sha256", "weights_sha256")


def pack_header(info: HeaderInfo, *, binary_digests: bool = False) -> bytes:
    """Canonical msgpack bytes of the header (keys in the order of HEADER_KEYS listing above).
    ``binary_digests``: the fingerprint's SHA-256 digests as 32-byte bin values (a compact header, I.3.1)."""
    header = info.to_dict()
    if binary_digests:
        header["fingerprint"] = dict(header["fingerprint"], **{k: bytes.fromhex(header["fingerprint"][k])
                                                               for k in DIGEST_KEYS})
    data: bytes = msgpack.packb(header, use_bin_type=True)
    if len(data) > MAX_HEADER_BYTES:
        raise LimitExceededError(f"the header would be {len(data)} bytes, over the {MAX_HEADER_BYTES} limit")
    return data


def compress_header(raw: bytes, dictionary: int = 1) -> bytes:
    """The stored form of a compact header (FORMAT.md I.3.1): one zstd frame with a spec-fixed raw-content
    dictionary (``dictionary`` 1, or 2 in a file with required flag bit 7, I.3.2), its content size declared, no
    dictionary id and no checksum (the header CRC covers it)."""
    cctx = per_thread(f"header_cctx{dictionary}", lambda: zstandard.ZstdCompressor(
        level=_HEADER_ZSTD_LEVEL, dict_data=_HEADER_DICTS[dictionary], write_content_size=True, write_checksum=False,
        write_dict_id=False))
    packed: bytes = cctx.compress(raw)
    return packed


_local = threading.local()
_T = TypeVar("_T")


def per_thread(key: str, make: Callable[[], _T]) -> _T:
    """This thread's object ``key``, made by ``make`` on first use: zstd contexts, whose creation (a dictionary
    loaded, tables allocated) costs more than compressing or decompressing a header or a small section, and
    which are not thread-safe (a reused context gives the same bytes)."""
    obj: _T | None = getattr(_local, key, None)
    if obj is None:
        obj = make()
        setattr(_local, key, obj)
    return obj


def decompress_header(stored: BytesLike, dictionary: int = 1) -> bytes:
    """The msgpack bytes of a compact header, bounded: the frame MUST declare its content size, at most
    1 MiB, and hold exactly that many bytes; nothing may follow the frame.  ``dictionary``: the header
    dictionary the file names (2 with required flag bit 7, I.3.2; else 1)."""
    try:
        declared = zstandard.frame_content_size(stored)
    except zstandard.ZstdError as exc:
        raise MalformedHeaderError(f"the compact header is not a zstd frame ({exc})") from None
    if declared < 0:
        raise MalformedHeaderError("the compact header's zstd frame does not declare its content size")
    if declared > MAX_HEADER_BYTES:
        raise LimitExceededError(f"the compact header declares {declared} bytes; the limit is {MAX_HEADER_BYTES}")
    if stored[4] & 0x03:  # Frame_Header_Descriptor's Dictionary_ID_Flag (RFC 8878 3.1.1.1.1)
        raise MalformedHeaderError("the compact header's zstd frame carries a dictionary id; I.3.1 forbids one "
                                   "(its dictionary is fixed by the format and has none)")
    dctx = per_thread(f"header_dctx{dictionary}", lambda: zstandard.ZstdDecompressor(dict_data=_HEADER_DICTS[dictionary]))
    frame = dctx.decompressobj(read_across_frames=False)
    try:
        out = frame.decompress(bytes(stored))  # libzstd refuses output beyond the declared content size
    except zstandard.ZstdError as exc:
        raise MalformedHeaderError(f"the compact header's zstd frame is corrupt ({exc})") from None
    if not frame.eof or len(out) != declared:
        raise MalformedHeaderError(f"the compact header's zstd frame yields {len(out)} bytes, not the {declared} "
                                   "it declares")
    if frame.unused_data:
        raise MalformedHeaderError(f"{len(frame.unused_data)} bytes follow the compact header's zstd frame")
    return out


def _refuse_ext(code: int, data: bytes) -> Any:
    raise MalformedHeaderError(f"the header uses msgpack extension type {code}; extension types are not allowed")


def _pairs_no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out = dict(pairs)
    if len(out) != len(pairs):
        raise MalformedHeaderError("the header has a map with a duplicated key")
    return out


def unpack_header(raw: BytesLike, *, binary_digests: bool = False) -> dict[str, Any]:
    """Decode header bytes with hard limits: size, string/array/map lengths, no bin or ext, depth.
    ``binary_digests`` (a compact header, I.3.1): the two fingerprint digests MUST be 32-byte bin values,
    returned as 64 lowercase hex digits; bin anywhere else is still refused."""
    if len(raw) > MAX_HEADER_BYTES:
        raise LimitExceededError(f"header is {len(raw)} bytes; the limit is {MAX_HEADER_BYTES}")
    try:
        value = msgpack.unpackb(
            bytes(raw), raw=False, strict_map_key=True, ext_hook=_refuse_ext, use_list=True,
            object_pairs_hook=_pairs_no_duplicates,
            max_str_len=MAX_STRING_CHARS, max_bin_len=32 if binary_digests else 0, max_array_len=MAX_CONTAINER_ITEMS,
            max_map_len=MAX_CONTAINER_ITEMS, max_ext_len=0,
        )
    except MalformedHeaderError:
        raise
    except (ValueError, TypeError, RecursionError, msgpack.exceptions.UnpackException) as exc:
        detail = str(exc)[:120] or "undecodable bytes"
        raise MalformedHeaderError(f"the header is not valid bounded msgpack ({type(exc).__name__}: {detail})") from None
    digests: tuple[Any, ...] = ()
    if binary_digests and isinstance(value, dict) and isinstance(value.get("fingerprint"), dict):
        digests = tuple(value["fingerprint"].get(key) for key in DIGEST_KEYS)  # bin allowed here (_hex_digests checks)
    bin_elsewhere = _scan(value, digests)
    header = require_map(value, "header")
    if binary_digests:
        header = _hex_digests(header)
    if bin_elsewhere:
        raise MalformedHeaderError("the header holds a msgpack bin value; bin is allowed only for the two "
                                   "fingerprint digests of a compact header")
    return header


def _hex_digests(header: dict[str, Any]) -> dict[str, Any]:
    fp = header.get("fingerprint")
    if not isinstance(fp, dict):
        return header  # the header checks name what is wrong
    fp = dict(fp)
    for key in DIGEST_KEYS:
        value = fp.get(key)
        if not isinstance(value, bytes) or len(value) != 32:
            raise MalformedHeaderError(f"fingerprint.{key} of a compact header must be a 32-byte bin value (I.3.1), "
                                       f"got {type(value).__name__}{f' of {len(value)} bytes' if isinstance(value, bytes) else ''}")
        fp[key] = value.hex()
    return dict(header, fingerprint=fp)


def _scan(value: Any, digests: tuple[Any, ...]) -> bool:
    """One walk over a decoded header: LimitExceededError where it nests deeper than MAX_HEADER_DEPTH, and
    whether it holds a bin value other than the objects ``digests`` (the compact header's two fingerprint
    digests, checked by :func:`_hex_digests`), which the caller refuses after the digests' own checks."""
    stack = [(value, 1)]
    bin_elsewhere = False
    while stack:
        item, depth = stack.pop()
        if isinstance(item, (dict, list)):
            if depth > MAX_HEADER_DEPTH:
                raise LimitExceededError(f"the header nests deeper than {MAX_HEADER_DEPTH} levels")
            for child in item.values() if isinstance(item, dict) else item:
                if isinstance(child, (dict, list)):
                    stack.append((child, depth + 1))
                elif isinstance(child, bytes) and not any(child is d for d in digests):
                    bin_elsewhere = True
    return bin_elsewhere


def parse_header(raw: BytesLike, *, newer_minor: bool = False, compressed: bool = False,
                 dictionary: int = 1) -> HeaderInfo:
    """Decode and validate a header.  ``newer_minor``: the file's minor version is newer than this
    reader's, so unknown keys are tolerated (known keys are still checked exactly).  ``compressed``: the
    stored header of a compact container (format 1.3), decompressed first with header dictionary
    ``dictionary`` (1, or 2 with required flag bit 7)."""
    h = (unpack_header(decompress_header(raw, dictionary), binary_digests=True) if compressed
         else unpack_header(raw))
    exact_keys(h, HEADER_KEYS, "header", allow_extra=newer_minor)
    static_shape = require_shape(h["static_shape"], "static_shape", MAX_TOKENS, MAX_TOKEN_DIM, MAX_TOKEN_VALUES,
                                 LimitExceededError)
    dynamic_shape = require_shape(h["dynamic_shape"], "dynamic_shape", MAX_TOKENS, MAX_TOKEN_DIM,
                                  MAX_TOKEN_VALUES, LimitExceededError)
    if static_shape[1] != dynamic_shape[1]:
        raise MalformedHeaderError(f"static tokens have d = {static_shape[1]} but dynamic tokens d = {dynamic_shape[1]}")
    encoding = h["encoding"]
    if encoding not in ALL_ENCODINGS:
        raise MalformedHeaderError(f"encoding {encoding!r:.40} is not one of {ALL_ENCODINGS}")
    if encoding in RANS_BITS and max(static_shape[0] * static_shape[1], dynamic_shape[0] * dynamic_shape[1]) > MAX_RANS_VALUES:
        raise LimitExceededError(f"encoding {encoding} allows at most {MAX_RANS_VALUES} values per token matrix")
    cam = require_map(h["cameras"], "cameras")
    exact_keys(cam, CAMERA_KEYS, "cameras", allow_extra=newer_minor)
    layout = CameraLayout(
        num_frames=require_int(cam["num_frames"], "cameras.num_frames", 1, MAX_FRAMES, LimitExceededError),
        width=require_int(cam["width"], "cameras.width", 1, MAX_IMAGE_SIDE, LimitExceededError),
        height=require_int(cam["height"], "cameras.height", 1, MAX_IMAGE_SIDE, LimitExceededError),
        distortion_terms=require_int(cam["distortion_terms"], "cameras.distortion_terms", 0, 14),
        has_timestamps=require_bool(cam["has_timestamps"], "cameras.has_timestamps"),
    )
    if layout.distortion_terms not in (0, *DISTORTION_LENGTHS):
        raise MalformedHeaderError(
            f"cameras.distortion_terms = {layout.distortion_terms}; allowed: 0 or one of {DISTORTION_LENGTHS}"
        )
    fingerprint = ModelFingerprint.from_dict(h["fingerprint"], allow_extra=newer_minor)
    if fingerprint.static_shape != static_shape or fingerprint.dynamic_shape != dynamic_shape:
        raise MalformedHeaderError(
            f"token shapes {static_shape} / {dynamic_shape} differ from the model fingerprint's "
            f"{fingerprint.static_shape} / {fingerprint.dynamic_shape}"
        )
    prov = h["provenance"]
    provenance = None if prov is None else Provenance.from_dict(prov, allow_extra=newer_minor)
    metadata = normalize_metadata(h["metadata"])
    return HeaderInfo(static_shape, dynamic_shape, encoding, layout, fingerprint, provenance, metadata, h)

