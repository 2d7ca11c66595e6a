"""Binary layout of a v1 scene container: preamble and section table (FORMAT.md, "File layout").

All integers are little-endian.  Offsets are relative to the first byte of the container, so a
container embedded in a larger file (an archive record) reads identically when extracted.

Preamble (64 bytes)::

    off size field
      0    9 magic            89 56 54 34 44 0D 0A 1A 0A  ("\\x89VT4D\\r\\n\\x1a\\n")
      9    1 zero             00
     10    2 major            u16 = 1
     12    2 minor            u16 = 0 .. 6 (the lowest that describes the file)
     14    2 reserved         u16 = 0
     16    8 required_flags   u64 (bit 0 since 1.1, bit 1 since 1.2, bit 2 since 1.3, bit 3 since 1.4, bit 4
                                  since 1.5, bits 5 to 10 since 1.6: a reader refuses any set bit it does not know)
     24    8 optional_flags   u64 (none defined in 1.0: unknown bits are ignored)
     32    8 file_length      u64, total container bytes
     40    4 header_length    u32, msgpack header bytes (starts at offset 64)
     44    4 header_crc32     u32, CRC-32 of the header bytes
     48    4 section_count    u32
     52    4 table_crc32      u32, CRC-32 of the section table
     56    4 reserved         u32 = 0
     60    4 preamble_crc32   u32, CRC-32 of bytes 0..59

Section table entry (40 bytes), the table starting right after the header::

      0    4 type             4 ASCII letters/digits, e.g. "ZSTA"
      4    2 flags            u16, bit 0 = critical; other bits 0
      6    1 compression      u8, 0 = stored raw, 1 = one zstd frame
      7    1 reserved         u8 = 0
      8    8 offset           u64, container-relative, multiple of 64
     16    8 stored_length    u64, bytes in the file
     24    8 raw_length       u64, bytes after decompression (= stored_length when raw)
     32    4 crc32            u32, CRC-32 of the stored bytes
     36    4 reserved         u32 = 0

Compact section table entry (18 bytes; format 1.3, required flag bit 2), payloads packed back to back
except where an entry asks for 64-byte alignment::

      0    4 type             4 ASCII letters/digits
      4    1 flags            u8, bit 0 = critical, bit 1 = aligned (starts at a multiple of 64); other bits 0
      5    1 compression      u8, 0 = stored raw, 1 = one zstd frame
      6    4 stored_length    u32, bytes in the file
     10    4 raw_length       u32, bytes after decompression (= stored_length when raw)
     14    4 crc32            u32, CRC-32 of the stored bytes

CRC-32 is the ISO-HDLC / zlib / PNG CRC (polynomial 0xEDB88320 reflected, init and xorout 0xFFFFFFFF).
"""

from __future__ import annotations

import re
import struct
import zlib
from dataclasses import dataclass

from ..errors import (BadMagicError, ChecksumError, LimitExceededError, MalformedSectionError, TruncatedError,
                      UnsupportedFeatureError, UnsupportedVersionError)
from .limits import (MAX_HEADER_BYTES, MAX_SECTION_RAW_BYTES, MAX_SECTIONS, PREAMBLE_SIZE, SECTION_ALIGNMENT,
                     SECTION_ENTRY_SIZE)

__all__ = ["SCENE_MAGIC", "FORMAT_MAJOR", "FORMAT_MINOR", "KNOWN_REQUIRED_FLAGS", "Preamble", "SectionEntry",
           "crc32", "align", "pack_preamble", "parse_preamble", "pack_table", "parse_table", "FLAG_CRITICAL",
           "COMPRESSION_RAW", "COMPRESSION_ZSTD", "COMPRESSION_ZSTD_CAMERAS", "COMPRESSION_NAMES", "FLAG_CAMERA_DICTIONARY", "FLAG_ENTROPY_CODED_TOKENS", "FLAG_COMPACT_CAMERAS",
           "FLAG_COMPACT_CONTAINER", "FLAG_EXTRA_CAMERAS", "FLAG_RANS_LANES", "FLAG_LEARNED_TOKENS", "FLAG_FIXED_CAMERAS", "FLAG_HEADER_DICTIONARY_2", "FLAG_JOINT_CAMERAS", "FLAG_ADAPTIVE_TOKENS", "FLAG_ALIGNED", "COMPACT_ENTRY_SIZE", "entry_size",
           "BytesLike"]

# What the parsers read from: a whole file in memory, a mapped file, or a zero-copy slice of either.
BytesLike = bytes | bytearray | memoryview

SCENE_MAGIC = b"\x89VT4D\r\n\x1a\n"
FORMAT_MAJOR = 1
# 1.1 adds the entropy-coded token encodings (required flag bit 0), 1.2 compact cameras (bit 1), 1.3 the compact
# container (bit 2): zstd header with a spec-fixed dictionary, 18-byte table entries, unaligned payloads; 1.4 the
# extra cameras section (bit 3): the trajectories of the further cameras of a multi-camera encode; 1.5 interleaved
# rANS lanes in the entropy-coded token sections (bit 4, only beside bit 0); 1.6 learned-rans tokens (bit 5),
# fixed-point cameras (bit 6) and, added within 1.6, header dictionary 2 for the compact header (bit 7, beside bit 2)
FORMAT_MINOR = 6
FLAG_ENTROPY_CODED_TOKENS = 1 << 0  # required flag: token sections use an int<b>-rans encoding (1.1)
FLAG_COMPACT_CAMERAS = 1 << 1  # required flag: the cameras section uses the compact encoding (1.2, I.5.1)
FLAG_COMPACT_CONTAINER = 1 << 2  # required flag: compact header, table and quaternion poses (1.3, I.3.1, I.4.1)
FLAG_EXTRA_CAMERAS = 1 << 3  # required flag: the file holds the extra cameras section XCAM (1.4, I.5.3)
FLAG_RANS_LANES = 1 << 4  # required flag: entropy-coded token payloads hold K interleaved rANS lanes (1.5, I.6.1)
FLAG_FIXED_CAMERAS = 1 << 6  # required flag: compact cameras may hold fixed-point records, P = 0 (1.6, I.5.4)
FLAG_LEARNED_TOKENS = 1 << 5  # required flag: tokens coded with the model's entropy tables, learned-rans (1.6, I.6.2)
FLAG_HEADER_DICTIONARY_2 = 1 << 7  # required flag: the compact header uses header dictionary 2 (1.6, I.3.2)
FLAG_CAMERA_DICTIONARY = 1 << 8  # required flag: sections may use compression 2, the camera dictionary (1.6, I.4.2)
FLAG_JOINT_CAMERAS = 1 << 9  # required flag: XCAM codes its fixed-point records jointly (1.6, I.5.5)
FLAG_ADAPTIVE_TOKENS = 1 << 10  # required flag: learned-rans token streams use adaptive rows (1.6, I.6.2)
KNOWN_REQUIRED_FLAGS = (FLAG_ENTROPY_CODED_TOKENS | FLAG_COMPACT_CAMERAS | FLAG_COMPACT_CONTAINER
                        | FLAG_EXTRA_CAMERAS | FLAG_RANS_LANES | FLAG_LEARNED_TOKENS
                        | FLAG_FIXED_CAMERAS | FLAG_HEADER_DICTIONARY_2 | FLAG_CAMERA_DICTIONARY | FLAG_JOINT_CAMERAS
                        | FLAG_ADAPTIVE_TOKENS)
# The version that introduced each required flag: in a file that says an older minor version the flag is
# unknown, and the file is refused as a reader of that version would (UnsupportedFeatureError).  Bit 1 keeps its
# 1.2 rule (MalformedHeaderError in files below 1.2, checked by the reader), which its golden vectors pin.
FLAG_SINCE_MINOR = {FLAG_COMPACT_CONTAINER: 3, FLAG_EXTRA_CAMERAS: 4, FLAG_RANS_LANES: 5, FLAG_LEARNED_TOKENS: 6,
                    FLAG_FIXED_CAMERAS: 6, FLAG_HEADER_DICTIONARY_2: 6, FLAG_CAMERA_DICTIONARY: 6,
                    FLAG_JOINT_CAMERAS: 6, FLAG_ADAPTIVE_TOKENS: 6}
FLAG_CRITICAL = 0x0001
FLAG_ALIGNED = 0x0002  # compact table entries only: the payload starts at a multiple of 64
COMPACT_ENTRY_SIZE = 18
COMPRESSION_RAW, COMPRESSION_ZSTD = 0, 1
COMPRESSION_ZSTD_CAMERAS = 2  # a zstd frame compressed with the camera dictionary (1.6, required flag bit 8, I.4.2)
COMPRESSION_NAMES = {COMPRESSION_RAW: "raw", COMPRESSION_ZSTD: "zstd", COMPRESSION_ZSTD_CAMERAS: "zstd-cameras"}

_PREAMBLE = struct.Struct("<9sBHHHQQQIIIIII")
_ENTRY = struct.Struct("<4sHBBQQQII")
_COMPACT_ENTRY = struct.Struct("<4sBBIII")
_TYPE = re.compile(rb"[A-Za-z0-9]{4}")
assert _PREAMBLE.size == PREAMBLE_SIZE and _ENTRY.size == SECTION_ENTRY_SIZE
assert _COMPACT_ENTRY.size == COMPACT_ENTRY_SIZE


def entry_size(required_flags: int) -> int:
    """Bytes of one section-table entry: 18 in a compact container (required flag bit 2), else 40."""
    return COMPACT_ENTRY_SIZE if required_flags & FLAG_COMPACT_CONTAINER else SECTION_ENTRY_SIZE


def crc32(data: BytesLike) -> int:
    return zlib.crc32(data) & 0xFFFFFFFF


def align(n: int) -> int:
    """Round ``n`` up to the section alignment (64)."""
    return -(-n // SECTION_ALIGNMENT) * SECTION_ALIGNMENT


@dataclass(frozen=True)
class Preamble:
    major: int
    minor: int
    required_flags: int
    optional_flags: int
    file_length: int
    header_length: int
    header_crc32: int
    section_count: int
    table_crc32: int


@dataclass(frozen=True)
class SectionEntry:
    type: str
    critical: bool
    compression: int
    offset: int
    stored_length: int
    raw_length: int
    crc32: int
    aligned: bool = True  # starts at a multiple of 64 (always in the 40-byte table; per entry in the compact one)


def pack_preamble(p: Preamble) -> bytes:
    body = _PREAMBLE.pack(SCENE_MAGIC, 0, p.major, p.minor, 0, p.required_flags, p.optional_flags,
                          p.file_length, p.header_length, p.header_crc32, p.section_count, p.table_crc32, 0, 0)
    return body[:-4] + struct.pack("<I", crc32(body[:-4]))


def check_magic(data: BytesLike) -> None:
    """Raise BadMagicError (with a diagnosis) unless ``data`` starts with the scene signature."""
    head = bytes(data[:len(SCENE_MAGIC)])
    if head == SCENE_MAGIC:
        return
    if len(head) < len(SCENE_MAGIC) and SCENE_MAGIC.startswith(head) and head:
        raise TruncatedError(f"the data ends after {len(head)} bytes, inside the vt4d signature")
    first = bytes(data[:16])
    if first.startswith(b"\x89VT4D"):
        raise BadMagicError(
            "the vt4d signature is damaged: line endings were converted (text-mode transfer?); "
            "copy the file again in binary mode"
        )
    if first.startswith(b"\x09VT4D") or first.startswith(b"VT4D"):
        raise BadMagicError("the vt4d signature lost its high bit (7-bit transfer?); copy the file in binary mode")
    if first.startswith((b"\x89VT4", b"\x89V4")):
        raise BadMagicError(
            f"this is a vt4d file of another kind (signature {first[:9]!r}), not a single scene; "
            "archives are read with vt4dcodec.archive (`vt4d ls FILE`)"
        )
    raise BadMagicError(f"not a .vt4d scene: the file starts with {first!r}, expected {SCENE_MAGIC!r}")


def parse_preamble(data: BytesLike) -> Preamble:
    """Parse and check the 64-byte preamble (signature, CRC, version, flags, declared sizes)."""
    check_magic(data)
    if len(data) < PREAMBLE_SIZE:
        raise TruncatedError(f"the data ends after {len(data)} bytes, inside the {PREAMBLE_SIZE}-byte preamble")
    raw = bytes(data[:PREAMBLE_SIZE])
    (_, zero, major, minor, res16, req, opt, file_length, header_length, header_crc, count, table_crc,
     res32, stored_crc) = _PREAMBLE.unpack(raw)
    if crc32(raw[:-4]) != stored_crc:
        raise ChecksumError("the preamble checksum does not match (bytes 0..59 are damaged)")
    if zero or res16 or res32:
        raise MalformedSectionError("reserved preamble bytes must be zero")
    if major != FORMAT_MAJOR:
        raise UnsupportedVersionError(
            f"format version {major}.{minor} is not supported: this reader handles major version "
            f"{FORMAT_MAJOR}; upgrade vt4dcodec to read it"
        )
    unknown = req & ~KNOWN_REQUIRED_FLAGS
    if unknown:
        raise UnsupportedFeatureError(
            f"the file requires feature flag(s) 0x{unknown:016x} this reader does not know; upgrade vt4dcodec"
        )
    for flag, since in FLAG_SINCE_MINOR.items():
        if req & flag and minor < since:
            raise UnsupportedFeatureError(
                f"the file says format 1.{minor}, which has no required flag 0x{flag:x} (defined from 1.{since} on)")
    if header_length > MAX_HEADER_BYTES:
        raise LimitExceededError(f"header length {header_length} exceeds the {MAX_HEADER_BYTES}-byte limit")
    if count > MAX_SECTIONS:
        raise LimitExceededError(f"{count} sections exceed the limit of {MAX_SECTIONS}")
    table_end = PREAMBLE_SIZE + header_length + count * entry_size(req)
    if file_length < table_end:
        raise MalformedSectionError(
            f"declared file length {file_length} is shorter than its own header and section table ({table_end})"
        )
    return Preamble(major, minor, req, opt, file_length, header_length, header_crc, count, table_crc)


def pack_table(entries: list[SectionEntry], *, compact: bool = False) -> bytes:
    if compact:
        return b"".join(
            _COMPACT_ENTRY.pack(e.type.encode("ascii"), (FLAG_CRITICAL if e.critical else 0)
                                | (FLAG_ALIGNED if e.aligned else 0), e.compression, e.stored_length, e.raw_length,
                                e.crc32)
            for e in entries
        )
    return b"".join(
        _ENTRY.pack(e.type.encode("ascii"), FLAG_CRITICAL if e.critical else 0, e.compression, 0, e.offset,
                    e.stored_length, e.raw_length, e.crc32, 0)
        for e in entries
    )


def parse_table(raw: BytesLike, count: int, table_end: int, file_length: int, *,
                compact: bool = False, camera_dictionary: bool = False) -> list[SectionEntry]:
    """Parse ``count`` entries and check the canonical layout: each payload starts at the 64-aligned end
    of the previous one (the first after the table), no overlap, and the last one ends the container.

    ``compact`` (format 1.3): 18-byte entries without offsets; each payload starts right where the previous
    one ended (the first right after the table), or at the next multiple of 64 when its entry says aligned.
    ``camera_dictionary`` (required flag bit 8): compression 2 is known too."""
    entries: list[SectionEntry] = []
    cursor = table_end
    seen: set[str] = set()
    known_flags = FLAG_CRITICAL | (FLAG_ALIGNED if compact else 0)
    for i in range(count):
        if compact:
            tcode, flags, comp, stored, rawlen, crc = _COMPACT_ENTRY.unpack_from(raw, i * COMPACT_ENTRY_SIZE)
            res8 = res32 = 0
            offset = expected_offset = align(cursor) if flags & FLAG_ALIGNED else cursor
        else:
            tcode, flags, comp, res8, offset, stored, rawlen, crc, res32 = _ENTRY.unpack_from(raw, i * SECTION_ENTRY_SIZE)
            expected_offset = align(cursor)
        if not _TYPE.fullmatch(tcode):
            raise MalformedSectionError(f"section {i} has an invalid type code {tcode!r}")
        name = tcode.decode("ascii")
        if name in seen:
            raise MalformedSectionError(f"section {name} appears twice")
        seen.add(name)
        if flags & ~known_flags or res8 or res32:
            raise MalformedSectionError(f"section {name} sets reserved bits or bytes")
        if comp not in (COMPRESSION_RAW, COMPRESSION_ZSTD) and not (camera_dictionary and comp == COMPRESSION_ZSTD_CAMERAS):
            if flags & FLAG_CRITICAL:
                raise UnsupportedFeatureError(f"critical section {name} uses unknown compression {comp}")
        if rawlen > MAX_SECTION_RAW_BYTES:
            raise LimitExceededError(f"section {name} declares {rawlen} raw bytes, over the {MAX_SECTION_RAW_BYTES} limit")
        if offset != expected_offset:
            raise MalformedSectionError(
                f"section {name} starts at {offset}; the layout requires {expected_offset} "
                "(64-aligned, in table order, no overlap or gaps)"
            )
        end = offset + stored
        if end > file_length:
            raise MalformedSectionError(f"section {name} ({offset}..{end}) runs past the container end {file_length}")
        if comp == COMPRESSION_RAW and stored != rawlen:
            raise MalformedSectionError(f"raw section {name}: stored length {stored} != raw length {rawlen}")
        entries.append(SectionEntry(name, bool(flags & FLAG_CRITICAL), comp, offset, stored, rawlen, crc,
                                    not compact or bool(flags & FLAG_ALIGNED)))
        cursor = end
    last_end = entries[-1].offset + entries[-1].stored_length if entries else table_end
    if last_end != file_length:
        raise MalformedSectionError(f"the last section ends at {last_end} but the container is {file_length} bytes")
    return entries
