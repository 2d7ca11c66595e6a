"""Section payloads: compression with a declared raw size, and the cameras section (FORMAT.md,
"Sections")."""

from __future__ import annotations

import functools
import io

import numpy as np
import zstandard

from ..cameras import Trajectory
from ..errors import CameraError, ChecksumError, LimitExceededError, MalformedSectionError, UnsupportedFeatureError
from .header import CameraLayout, per_thread
from .camera_dictionary import CAMERA_DICTIONARY
from .layout import COMPRESSION_RAW, COMPRESSION_ZSTD, COMPRESSION_ZSTD_CAMERAS, BytesLike, SectionEntry, crc32

__all__ = ["SECTION_CAMERAS", "SECTION_STATIC", "SECTION_DYNAMIC", "SECTION_STATIC_QUANT",
           "SECTION_DYNAMIC_QUANT", "SECTION_EXTRA_CAMERAS", "KNOWN_SECTIONS", "compress_payload", "section_payload",
           "pack_cameras", "unpack_cameras", "DEFAULT_MAX_DECODED_BYTES", "DECODED_CAMERA_BYTES_PER_FRAME",
           "check_decoded_budget", "decoded_budget", "compress_with_camera_dictionary", "CAMERA_DICTIONARY_LEVEL"]

SECTION_CAMERAS = "CAMS"
SECTION_STATIC = "ZSTA"
SECTION_DYNAMIC = "ZDYN"
SECTION_STATIC_QUANT = "QSTA"
SECTION_DYNAMIC_QUANT = "QDYN"
SECTION_EXTRA_CAMERAS = "XCAM"  # format 1.4, required flag bit 3: see extra_cameras.py
KNOWN_SECTIONS = (SECTION_CAMERAS, SECTION_EXTRA_CAMERAS, SECTION_STATIC_QUANT, SECTION_STATIC, SECTION_DYNAMIC_QUANT,
                  SECTION_DYNAMIC)

#: The default decoded-size budget of one scene read (FORMAT.md I.7, "Decoded-size budget"): 64 MiB, ~80 times
#: a paper-size float32 scene (1024 + 512 tokens of 64 floats: ~0.8 MB decoded).  Readers take
#: ``max_decoded_bytes=`` to raise it (``None``: no budget) for files they trust.
DEFAULT_MAX_DECODED_BYTES = 64 << 20
#: What one decoded camera costs a reader per frame: K (9) and w2c (16) float64, and a float64 timestamp.
DECODED_CAMERA_BYTES_PER_FRAME = 208


def decoded_budget(value: object) -> int | None:
    """``value`` checked as a ``max_decoded_bytes`` argument: a non-negative int or None (no budget)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"max_decoded_bytes must be a non-negative int or None, got {value!r}")
    return value


def check_decoded_budget(size: int, budget: int | None) -> None:
    """LimitExceededError, before anything is decompressed or decoded, when a scene's decoded size (FORMAT.md
    I.7: its sections' raw lengths, its float32 token matrices and its decoded cameras) exceeds ``budget``."""
    if budget is not None and size > budget:
        raise LimitExceededError(
            f"the scene decodes to {size:,} bytes (sections' raw lengths, float32 tokens, decoded cameras), over "
            f"the reader's budget of {budget:,}; if you trust the file, pass max_decoded_bytes={size} (or None)")


def compress_payload(raw: bytes, level: int | None, *, min_saving: float = 0.0) -> tuple[int, bytes]:
    """(compression code, stored bytes): zstd at ``level`` when it is smaller by more than ``min_saving``
    (a fraction of the raw length), else raw.  ``level=None`` always stores raw (aligned, so readers get
    zero-copy arrays)."""
    if level is None or not raw:
        return COMPRESSION_RAW, raw
    packed = _compressor(level).compress(raw)
    if len(packed) >= len(raw) or len(raw) - len(packed) < min_saving * len(raw):
        return COMPRESSION_RAW, raw
    return COMPRESSION_ZSTD, packed


#: zstd level of sections compressed with the camera dictionary: they are small (a few hundred bytes), so the
#: strongest level costs nothing that shows and saves ~20 bytes a 10-camera XCAM over level 9
CAMERA_DICTIONARY_LEVEL = 19
@functools.cache
def _camera_dict() -> zstandard.ZstdCompressionDict:
    """The camera dictionary as zstd loads it: a full (ZDICT) dictionary, its entropy tables and content both used."""
    return zstandard.ZstdCompressionDict(CAMERA_DICTIONARY, dict_type=zstandard.DICT_TYPE_FULLDICT)


def compress_with_camera_dictionary(raw: bytes) -> bytes:
    """One zstd frame of ``raw`` compressed with the camera dictionary (FORMAT.md I.4.2): its content size
    declared, no dictionary id, no checksum."""
    cctx = per_thread("cctx_cameras", lambda: zstandard.ZstdCompressor(
        level=CAMERA_DICTIONARY_LEVEL, dict_data=_camera_dict(), write_content_size=True, write_checksum=False,
        write_dict_id=False))
    return cctx.compress(raw)


def _compressor(level: int) -> zstandard.ZstdCompressor:
    """This thread's zstd compressor at ``level`` (content size declared, no checksum)."""
    return per_thread(f"cctx{level}", lambda: zstandard.ZstdCompressor(level=level, write_content_size=True,
                                                                       write_checksum=False))


def section_payload(container: BytesLike, entry: SectionEntry, *, check_crc: bool = True) -> bytes | memoryview:
    """The raw (decompressed) bytes of a section, as a zero-copy memoryview when stored raw.

    Checks the CRC-32 of the stored bytes first, then decompresses at most ``raw_length`` bytes, so a
    decompression bomb stops at the declared size (the zstd frame's own size field is never trusted).
    """
    stored = memoryview(container)[entry.offset:entry.offset + entry.stored_length]
    if check_crc and crc32(stored) != entry.crc32:
        raise ChecksumError(
            f"section {entry.type} is damaged: CRC-32 0x{crc32(stored):08x} != stored 0x{entry.crc32:08x}"
        )
    if entry.compression == COMPRESSION_RAW:
        return stored
    if entry.compression == COMPRESSION_ZSTD_CAMERAS:  # known only beside required flag bit 8 (parse_table)
        return _bounded_zstd(stored, entry, dictionary=True)
    if entry.compression != COMPRESSION_ZSTD:
        raise UnsupportedFeatureError(f"section {entry.type} uses unknown compression {entry.compression}")
    return _bounded_zstd(stored, entry)


def _decompressor(dictionary: bool) -> zstandard.ZstdDecompressor:
    """A zstd decompressor, with the camera dictionary for compression 2."""
    return zstandard.ZstdDecompressor(dict_data=_camera_dict()) if dictionary else zstandard.ZstdDecompressor()


def _bounded_zstd(stored: memoryview, entry: SectionEntry, *, dictionary: bool = False) -> bytes:
    try:
        declared = zstandard.frame_content_size(stored)
        dict_id = zstandard.get_frame_parameters(stored).dict_id
    except zstandard.ZstdError as exc:
        raise MalformedSectionError(f"section {entry.type} is not a zstd frame: {exc}") from None
    if dict_id:  # FORMAT.md I.4.2: a frame names no dictionary (the compression code does)
        raise MalformedSectionError(f"section {entry.type}: its zstd frame carries a dictionary id ({dict_id}); "
                                    f"section frames carry none")
    if declared not in (-1, entry.raw_length):  # -1: the frame does not declare its size
        raise MalformedSectionError(
            f"section {entry.type}: zstd frame declares {declared} bytes but the table declares {entry.raw_length}"
        )
    if declared == entry.raw_length:
        # The frame declares exactly the table's size, so a one-shot decompression allocates no more than
        # that (libzstd refuses output that differs from the declared content size).  One decompression
        # context per thread: creating one costs more than decompressing a small section.
        dctx = per_thread("dctx_cameras" if dictionary else "dctx", lambda: _decompressor(dictionary))
        try:
            frame = dctx.decompressobj(read_across_frames=False)  # first frame only; the rest is unused_data
            out = frame.decompress(stored)
        except zstandard.ZstdError as exc:
            raise MalformedSectionError(f"section {entry.type}: corrupt zstd data ({exc})") from None
        if len(out) == entry.raw_length and frame.eof:
            _reject_trailing(frame.unused_data, entry)
            return out
    reader = _decompressor(dictionary).stream_reader(io.BytesIO(stored), read_across_frames=False)
    chunks, total = [], 0
    try:
        while total <= entry.raw_length:
            chunk = reader.read(entry.raw_length + 1 - total)
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
    except zstandard.ZstdError as exc:
        raise MalformedSectionError(f"section {entry.type}: corrupt zstd data ({exc})") from None
    if total != entry.raw_length:
        raise MalformedSectionError(
            f"section {entry.type} decompresses to {'more than ' if total > entry.raw_length else ''}"
            f"{min(total, entry.raw_length) if total > entry.raw_length else total} bytes; "
            f"the table declares {entry.raw_length}"
        )
    # The first frame yields exactly raw_length bytes (checked above with bounded reads), so decoding it
    # once more to find where it ends allocates no more than that.
    frame = _decompressor(dictionary).decompressobj(read_across_frames=False)
    try:
        frame.decompress(stored)
    except zstandard.ZstdError as exc:
        raise MalformedSectionError(f"section {entry.type}: corrupt zstd data ({exc})") from None
    _reject_trailing(frame.unused_data, entry)
    return b"".join(chunks)


def _reject_trailing(unused: bytes, entry: SectionEntry) -> None:
    """FORMAT.md I.4: the stored bytes are exactly one zstd frame; anything after it (another frame, a
    skippable frame, garbage) is an error."""
    if unused:
        raise MalformedSectionError(
            f"section {entry.type}: {len(unused)} bytes follow the zstd frame; a section holds exactly one frame")


def pack_cameras(traj: Trajectory) -> tuple[CameraLayout, bytes]:
    """The cameras section: K (T,3,3), w2c (T,4,4), distortion (n,), timestamps (T,) as little-endian
    float64, row-major, concatenated in that order (absent parts take no bytes)."""
    parts = [traj.K, traj.w2c]
    if traj.distortion is not None:
        parts.append(traj.distortion)
    if traj.timestamps is not None:
        parts.append(traj.timestamps)
    raw = b"".join(np.ascontiguousarray(p, dtype="<f8").tobytes() for p in parts)
    layout = CameraLayout(traj.num_frames, traj.width, traj.height,
                          0 if traj.distortion is None else int(traj.distortion.shape[0]),
                          traj.timestamps is not None)
    return layout, raw


def unpack_cameras(raw: BytesLike, layout: CameraLayout) -> Trajectory:
    """Rebuild the trajectory; any convention violation becomes MalformedSectionError."""
    if len(raw) != layout.raw_length:
        raise MalformedSectionError(
            f"cameras section is {len(raw)} bytes; the header's layout needs {layout.raw_length}"
        )
    values = np.frombuffer(raw, dtype="<f8")
    t, n = layout.num_frames, layout.distortion_terms
    K = values[: 9 * t].reshape(t, 3, 3)
    w2c = values[9 * t: 25 * t].reshape(t, 4, 4)
    dist = values[25 * t: 25 * t + n] if n else None
    ts = values[25 * t + n:] if layout.has_timestamps else None
    try:
        return Trajectory(K=K, w2c=w2c, width=layout.width, height=layout.height, distortion=dist, timestamps=ts)
    except CameraError as exc:
        raise MalformedSectionError(f"cameras section breaks the camera conventions: {exc}") from None
