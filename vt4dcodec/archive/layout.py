"""Byte layout of a ``.vt4da`` archive: header, commit slots, record frames, index block, footer.

Everything is little-endian; checksums are CRC-32 (``zlib.crc32``, the PNG/zip polynomial).  The
normative description with byte offsets is FORMAT.md, Part II; this module is its code.

File picture::

    [header 160 B: preamble 32 B | commit slot A 64 B | commit slot B 64 B]
    [frame][frame]...[index block][footer 64 B]      <- commit 1
    [frame]...[index block][footer 64 B]             <- commit 2 (appended)

Nothing here does I/O; parsers take ``bytes`` and raise :class:`~vt4dcodec.errors.ArchiveError`
subclasses.
"""

from __future__ import annotations

import re
import struct
import zlib
from dataclasses import dataclass

from ..errors import ArchiveError, FormatError, BadMagicError, ChecksumError, LimitExceededError, TruncatedError
from ..errors import UnsupportedVersionError

__all__ = [
    "ARCHIVE_MAGIC", "ARCHIVE_EXTENSION", "VERSION_MAJOR", "VERSION_MINOR",
    "PREAMBLE_SIZE", "SLOT_SIZE", "SLOT_OFFSETS", "HEADER_SIZE", "FRAME_HEADER_SIZE",
    "INDEX_HEADER_SIZE", "INDEX_ENTRY_SIZE", "FOOTER_SIZE",
    "MAX_KEY_BYTES", "MAX_SUMMARY_BYTES", "MAX_SCENES", "MAX_RECORD_BYTES", "MAX_GENERATION",
    "FLAG_SEGMENTED", "FLAG_V12", "KNOWN_FLAGS", "MAX_TAIL_BYTES", "MIN_TAIL_BYTES", "MANIFEST_HEADER_SIZE", "SEGMENT_REF_SIZE", "MAX_SEGMENTS",
    "Commit", "FrameHeader", "crc32", "check_key",
    "pack_preamble", "parse_preamble", "pack_slot", "parse_slot", "pack_footer", "parse_footer", "is_footer",
    "pack_frame_header", "parse_frame_header",
    "FRAME_MAGIC", "INDEX_MAGIC", "FOOTER_MAGIC",
]

# --- constants ------------------------------------------------------------------------------------
ARCHIVE_MAGIC = b"\x89V4A\r\n\x1a\n"  #: 8 bytes, PNG-style: high bit, name, CRLF, ^Z, LF
ARCHIVE_EXTENSION = ".vt4da"
VERSION_MAJOR, VERSION_MINOR = 1, 2  #: what this implementation writes by default (it reads every 1.x)
#: required flag bit 0 (preamble, footer, slot): the commit's index block is a segment manifest
#: (FORMAT.md Part II section 5.5, version 1.1).  In the preamble it says commits may use it.
FLAG_SEGMENTED = 0x1
#: required flag bit 1 (version 1.2): in a footer or slot, the commit's tail length ``T`` is stored (a light
#: commit when ``T`` > 0, FORMAT.md Part II 5.7) and its index segments may be compressed (5.6); in the
#: preamble, commits may use both
FLAG_V12 = 0x2
KNOWN_FLAGS = FLAG_SEGMENTED | FLAG_V12
MAX_TAIL_BYTES = 1 << 18  #: the tail of a light commit (262,144 bytes)
MIN_TAIL_BYTES = 64  #: a tail holds at least the footer of the full commit it follows
MANIFEST_HEADER_SIZE = 32
SEGMENT_REF_SIZE = 32
MAX_SEGMENTS = 64  #: index segments one commit may name

PREAMBLE_SIZE = 32
SLOT_SIZE = 64
SLOT_OFFSETS = (32, 96)
HEADER_SIZE = 160  #: first record frame starts here
FRAME_HEADER_SIZE = 32
INDEX_HEADER_SIZE = 32
INDEX_ENTRY_SIZE = 48
FOOTER_SIZE = 64

SLOT_MAGIC = b"V4AP"
FRAME_MAGIC = b"V4AR"
INDEX_MAGIC = b"V4AI"
MANIFEST_MAGIC = b"V4AM"
FOOTER_MAGIC = b"V4AFOOT\x00"
FOOTER_END_MAGIC = b"V4AE"

MAX_KEY_BYTES = 1024  #: UTF-8 bytes of one scene key
MAX_SUMMARY_BYTES = 65536  #: msgpack bytes of one record summary
MAX_SCENES = 1 << 24  #: scenes in one archive (16,777,216)
MAX_RECORD_BYTES = 1 << 40  #: one record payload (1 TiB)
MAX_GENERATION = (1 << 64) - 1  #: the u64 generation counter; a writer refuses to commit past it

_KEY_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9._\-]*(/[A-Za-z0-9_][A-Za-z0-9._\-]*)*")


def crc32(data: bytes | memoryview) -> int:
    """CRC-32 (ISO-HDLC, as zip/PNG) of ``data`` as an unsigned 32-bit int."""
    return zlib.crc32(data) & 0xFFFFFFFF


def check_key(key: str) -> bytes:
    """Validate a scene key and return its UTF-8 bytes.

    Keys are 1..1024 bytes of ``[A-Za-z0-9._-]`` segments joined by ``/``; each segment starts with
    a letter, digit or underscore (so no ``..``, no absolute paths: keys are safe as file names).
    """
    if not isinstance(key, str):
        raise ArchiveError(f"scene key must be a str, got {type(key).__name__}")
    raw = key.encode("utf-8", "surrogatepass")
    if not 1 <= len(raw) <= MAX_KEY_BYTES:
        raise ArchiveError(f"scene key must be 1..{MAX_KEY_BYTES} bytes, got {len(raw)}")
    if not _KEY_RE.fullmatch(key):
        raise ArchiveError(
            f"invalid scene key {key!r}: use letters, digits, '.', '_', '-' in '/'-separated "
            "segments that start with a letter, digit or '_'"
        )
    return raw


# --- preamble -----------------------------------------------------------------------------------
_PREAMBLE = struct.Struct("<8sHHI16x")  # magic, major, minor, flags, reserved


def pack_preamble(minor: int = VERSION_MINOR) -> bytes:
    """Version 1.1 archives set required flag bit 0 (commits may use segmented indexes), 1.2 also bit 1
    (light commits, compressed segments); 1.0: none."""
    flags = (FLAG_SEGMENTED if minor >= 1 else 0) | (FLAG_V12 if minor >= 2 else 0)
    return _PREAMBLE.pack(ARCHIVE_MAGIC, VERSION_MAJOR, minor, flags)


def preamble_minor(data: bytes) -> int:
    """The minor version a (checked) preamble declares."""
    return int(_PREAMBLE.unpack_from(data)[2])


def parse_preamble(data: bytes) -> int:
    """Check the 32-byte preamble: magic, supported major version, no unknown required flags.

    Returns the required flags (bit 0: commits may use segmented indexes)."""
    if len(data) < PREAMBLE_SIZE:
        raise TruncatedError(f"archive is {len(data)} bytes, shorter than its {PREAMBLE_SIZE}-byte preamble")
    magic, major, _minor, flags = _PREAMBLE.unpack_from(data)
    if magic != ARCHIVE_MAGIC:
        raise BadMagicError("not a vt4d archive (bad magic; expected \\x89V4A\\r\\n\\x1a\\n)")
    if major != VERSION_MAJOR:
        raise UnsupportedVersionError(f"archive major version {major}; this reader reads {VERSION_MAJOR}")
    if flags & ~KNOWN_FLAGS:
        raise UnsupportedVersionError(f"archive sets unknown required flags 0x{flags & ~KNOWN_FLAGS:08x}")
    return int(flags)


# --- commits (footer and the two header slots hold the same fields) -----------------------------
@dataclass(frozen=True)
class Commit:
    """One committed state: where its index lives and how to check it.

    ``footer_offset`` is where the 64-byte footer of this commit starts; the committed file content
    ends at ``footer_offset + FOOTER_SIZE``.  A light commit (version 1.2, ``tail_length`` > 0) names an
    earlier full commit's index block; the ``tail_length`` bytes between that block and its own footer
    hold the frames committed since (FORMAT.md Part II 5.7).
    """

    generation: int
    index_offset: int
    index_length: int
    index_crc32: int
    scene_count: int
    flags: int = 0  #: FLAG_SEGMENTED: the index block is a segment manifest (1.1); FLAG_V12: a 1.2 commit
    tail_length: int = 0  #: ``T`` (1.2): bytes from the end of the index block to this footer

    @property
    def segmented(self) -> bool:
        return bool(self.flags & FLAG_SEGMENTED)

    @property
    def v12(self) -> bool:
        """A version 1.2 commit: its segments may be compressed, and it may be light."""
        return bool(self.flags & FLAG_V12)

    @property
    def light(self) -> bool:
        return self.tail_length > 0

    @property
    def footer_offset(self) -> int:
        return self.index_offset + self.index_length + self.tail_length

    @property
    def end(self) -> int:
        return self.footer_offset + FOOTER_SIZE


# slot: magic, index crc, generation, footer offset, index offset, index length, scene count, flags
# (1.1; reserved zero in 1.0), tail length (1.2; reserved before), pad, crc
_SLOT = struct.Struct("<4sIQQQQQII4xI")
# footer: magic, major, minor, flags, generation, index offset, index length, scene count, index crc,
# end magic, tail length (1.2; reserved before), footer crc
_FOOTER = struct.Struct("<8sHHIQQQQI4sII")
assert _SLOT.size == SLOT_SIZE and _FOOTER.size == FOOTER_SIZE


def _check_commit_fields(c: Commit) -> Commit:
    if c.index_offset < HEADER_SIZE:
        raise ArchiveError(f"commit index offset {c.index_offset} lies inside the archive header")
    if c.scene_count > MAX_SCENES:
        raise LimitExceededError(f"commit claims {c.scene_count} scenes (limit {MAX_SCENES})")
    if c.flags & ~KNOWN_FLAGS:
        raise UnsupportedVersionError(f"commit sets unknown required flags 0x{c.flags & ~KNOWN_FLAGS:08x}")
    if c.tail_length > MAX_TAIL_BYTES:
        raise LimitExceededError(f"light commit's tail of {c.tail_length} bytes exceeds {MAX_TAIL_BYTES}")
    if 0 < c.tail_length < MIN_TAIL_BYTES:
        raise ArchiveError(f"light commit's tail of {c.tail_length} bytes cannot hold the footer it follows")
    if c.segmented:  # manifest (32 + 32 m bytes, m >= 1) + the newest segment (>= 32 bytes)
        if c.index_length < MANIFEST_HEADER_SIZE + SEGMENT_REF_SIZE + INDEX_HEADER_SIZE:
            raise ArchiveError(f"segmented index block of {c.index_length} bytes is too short")
        return c
    min_len = INDEX_HEADER_SIZE + (0 if c.v12 else INDEX_ENTRY_SIZE * c.scene_count)
    if c.index_length < min_len:
        raise ArchiveError(f"index of {c.index_length} bytes cannot hold {c.scene_count} scenes")
    return c


def pack_slot(c: Commit) -> bytes:
    body = _SLOT.pack(SLOT_MAGIC, c.index_crc32, c.generation, c.footer_offset, c.index_offset,
                      c.index_length, c.scene_count, c.flags, c.tail_length, 0)
    return body[:-4] + struct.pack("<I", crc32(body[:-4]))


def parse_slot(data: bytes) -> Commit | None:
    """A header commit slot, or None if it is empty/torn (wrong magic or checksum)."""
    if len(data) < SLOT_SIZE:
        return None
    magic, icrc, gen, footer_off, ioff, ilen, count, flags, tail, scrc = _SLOT.unpack_from(data)
    if magic != SLOT_MAGIC or crc32(data[: SLOT_SIZE - 4]) != scrc:
        return None
    c = Commit(gen, ioff, ilen, icrc, count, flags, tail if flags & FLAG_V12 else 0)
    if footer_off != c.footer_offset:
        return None
    try:
        return _check_commit_fields(c)
    except FormatError:  # unusable: a reader that needs it reports the preamble's or footer's error
        return None


def pack_footer(c: Commit) -> bytes:
    minor = 2 if c.flags & FLAG_V12 else 1 if c.flags else 0  # a 1.0 reader can read an unsegmented commit
    body = _FOOTER.pack(FOOTER_MAGIC, VERSION_MAJOR, minor, c.flags, c.generation, c.index_offset,
                        c.index_length, c.scene_count, c.index_crc32, FOOTER_END_MAGIC, c.tail_length, 0)
    return body[:-4] + struct.pack("<I", crc32(body[:-4]))


def is_footer(data: bytes) -> bool:
    """Whether 64 bytes are a written footer: both magics and the footer CRC hold (FORMAT.md Part II 7,
    step 3).  Such a footer must then pass the version and field checks (:func:`parse_footer`); bytes
    that are not one (a torn or missing footer) send a reader to the header slots."""
    return (len(data) == FOOTER_SIZE and data[:8] == FOOTER_MAGIC and data[52:56] == FOOTER_END_MAGIC
            and crc32(data[: FOOTER_SIZE - 4]) == struct.unpack_from("<I", data, FOOTER_SIZE - 4)[0])


def parse_footer(data: bytes) -> Commit:
    """Parse a 64-byte footer; raise ArchiveError (ChecksumError for a bad CRC) if it is not one."""
    if len(data) != FOOTER_SIZE:
        raise TruncatedError(f"footer must be {FOOTER_SIZE} bytes, got {len(data)}")
    magic, major, _minor, flags, gen, ioff, ilen, count, icrc, end_magic, tail, fcrc = _FOOTER.unpack(data)
    if magic != FOOTER_MAGIC or end_magic != FOOTER_END_MAGIC:
        raise ArchiveError("no archive footer at the end of the file (not committed, or not an archive)")
    if crc32(data[: FOOTER_SIZE - 4]) != fcrc:
        raise ArchiveFooterChecksumError("archive footer checksum mismatch")
    if major != VERSION_MAJOR:
        raise UnsupportedVersionError(f"archive footer major version {major}; this reader reads {VERSION_MAJOR}")
    if flags & ~KNOWN_FLAGS:
        raise UnsupportedVersionError(f"archive footer sets unknown required flags 0x{flags & ~KNOWN_FLAGS:08x}")
    return _check_commit_fields(Commit(gen, ioff, ilen, icrc, count, flags, tail if flags & FLAG_V12 else 0))


class ArchiveFooterChecksumError(ArchiveError, ChecksumError):
    """The archive footer's CRC does not match (torn write or corruption)."""


# --- record frames --------------------------------------------------------------------------------
@dataclass(frozen=True)
class FrameHeader:
    """Decoded fixed part of a record frame; the payload starts ``payload_start`` bytes in."""

    key_len: int
    summary_len: int
    payload_crc32: int
    payload_len: int
    meta_crc32: int

    @property
    def payload_start(self) -> int:
        return FRAME_HEADER_SIZE + self.key_len + self.summary_len

    @property
    def total(self) -> int:
        return self.payload_start + self.payload_len


# magic, key len, flags, summary len, payload crc, payload len, meta crc, reserved
_FRAME = struct.Struct("<4sHHIIQI4x")
assert _FRAME.size == FRAME_HEADER_SIZE


def pack_frame_header(key: bytes, summary: bytes, payload_crc: int, payload_len: int) -> bytes:
    """The 32-byte frame header; ``meta_crc32`` covers header bytes 0..24 + key + summary."""
    head = struct.pack("<4sHHIIQ", FRAME_MAGIC, len(key), 0, len(summary), payload_crc, payload_len)
    meta = crc32(head + key + summary)
    return head + struct.pack("<I4x", meta)


def parse_frame_header(data: bytes) -> FrameHeader:
    """Parse the fixed 32 bytes of a frame (limits checked; the meta CRC is checked by the caller)."""
    if len(data) < FRAME_HEADER_SIZE:
        raise TruncatedError("record frame header is truncated")
    magic, key_len, flags, summary_len, pcrc, plen, mcrc = _FRAME.unpack_from(data)
    if magic != FRAME_MAGIC:
        raise ArchiveError("not a record frame (bad magic)")
    if flags != 0:
        raise UnsupportedVersionError(f"record frame sets unknown flags 0x{flags:04x}")
    if not 1 <= key_len <= MAX_KEY_BYTES:
        raise LimitExceededError(f"record key length {key_len} outside 1..{MAX_KEY_BYTES}")
    if summary_len > MAX_SUMMARY_BYTES:
        raise LimitExceededError(f"record summary length {summary_len} > {MAX_SUMMARY_BYTES}")
    if plen > MAX_RECORD_BYTES:
        raise LimitExceededError(f"record payload length {plen} > {MAX_RECORD_BYTES}")
    return FrameHeader(key_len, summary_len, pcrc, plen, mcrc)


def frame_meta_crc(header: bytes, key: bytes, summary: bytes) -> int:
    """The CRC a frame's ``meta_crc32`` field must hold."""
    return crc32(header[:24] + key + summary)
