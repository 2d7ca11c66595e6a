"""Writing scenes: :func:`dumps` builds the container bytes, :func:`save` writes them."""

from __future__ import annotations

import errno
import os
from collections.abc import Sequence
from typing import BinaryIO

import numpy as np

from ..errors import FormatError
from .encodings import ALL_ENCODINGS, encode_tokens
from .header import HeaderInfo, compress_header, pack_header
from .encodings import is_entropy_coded, is_learned
from .learned import EntropyTables, encode_learned_tokens, find_tables
from .compact_cameras import CAMERA_MODES, pack_compact_cameras
from .extra_cameras import SECTION_EXTRA_CAMERAS, joint_extra_cameras, pack_extra_cameras
from .layout import (COMPRESSION_RAW, COMPRESSION_ZSTD_CAMERAS, FLAG_CAMERA_DICTIONARY, FLAG_COMPACT_CAMERAS, FLAG_COMPACT_CONTAINER, FLAG_ENTROPY_CODED_TOKENS,
                     FLAG_HEADER_DICTIONARY_2,
                     FLAG_ADAPTIVE_TOKENS, FLAG_EXTRA_CAMERAS, FLAG_FIXED_CAMERAS, FLAG_JOINT_CAMERAS, FLAG_LEARNED_TOKENS, FLAG_RANS_LANES, FORMAT_MAJOR, Preamble, SectionEntry, align, crc32,
                     entry_size, pack_preamble, pack_table)
from .rans_tokens import check_lanes, policy_lanes
from .limits import PREAMBLE_SIZE
from .scene import Scene, normalize_extra_cameras
from .sections import (SECTION_CAMERAS, SECTION_DYNAMIC, SECTION_DYNAMIC_QUANT, SECTION_STATIC,
                       SECTION_STATIC_QUANT, compress_payload, compress_with_camera_dictionary, pack_cameras)

__all__ = ["dumps", "save", "build_container", "DEFAULT_COMPRESSION_LEVEL", "HEADER_MODES"]

HEADER_MODES = ("compact", "legacy")  # what save(header=...) offers: see dumps

DEFAULT_COMPRESSION_LEVEL = 9  # zstd level; see docs/benchmarks/format.md for the size/speed trade


TOKEN_ZSTD_MIN_SAVING = 0.125  # compact containers: fixed-width token arrays stay raw unless zstd saves this much

# (type, critical, compression, stored bytes, raw length[, aligned])
SectionParts = tuple[str, bool, int, bytes, int] | tuple[str, bool, int, bytes, int, bool]


def build_container(header: bytes, sections: Sequence[SectionParts], *,
                    minor: int = 0, required_flags: int = 0, optional_flags: int = 0,
                    compact_layout: bool | None = None) -> bytes:
    """Lay out a container from already-encoded parts.

    ``sections`` holds ``(type, critical, compression, stored_bytes, raw_length[, aligned])`` in file order;
    ``aligned`` counts in a compact container only (required flag bit 2: 18-byte entries, payloads packed,
    an aligned one at the next multiple of 64; the header given is stored as it is, already compressed).
    Used by :func:`dumps` and by the test-vector generator (which builds deliberately unusual files, and
    may ask with ``compact_layout`` for the other table layout than the flags say).
    """
    compact = bool(required_flags & FLAG_COMPACT_CONTAINER) if compact_layout is None else compact_layout
    table_end = PREAMBLE_SIZE + len(header) + entry_size(FLAG_COMPACT_CONTAINER if compact else 0) * len(sections)
    entries, cursor = [], table_end
    for section in sections:
        name, critical, compression, stored, raw_length = section[0], section[1], section[2], section[3], section[4]
        aligned = not compact or any(section[5:])
        offset = align(cursor) if aligned else cursor
        entries.append(SectionEntry(name, critical, compression, offset, len(stored), raw_length, crc32(stored),
                                    aligned))
        cursor = offset + len(stored)
    file_length = cursor
    table = pack_table(entries, compact=compact)
    preamble = pack_preamble(Preamble(FORMAT_MAJOR, minor, required_flags, optional_flags, file_length,
                                      len(header), crc32(header), len(entries), crc32(table)))
    out = bytearray(file_length)
    out[:PREAMBLE_SIZE] = preamble
    out[PREAMBLE_SIZE:PREAMBLE_SIZE + len(header)] = header
    out[PREAMBLE_SIZE + len(header):table_end] = table
    for entry, section in zip(entries, sections):
        out[entry.offset:entry.offset + entry.stored_length] = section[3]
    return bytes(out)


def _stored_header(raw: bytes, dictionary: int | None, learned: bool) -> tuple[bytes, bool]:
    """(the compact header's zstd frame, whether it uses header dictionary 2).  ``dictionary`` None, the policy:
    learned-rans files (1.6 already) take dictionary 2 (required flag bit 7, I.3.2) when it makes the header
    shorter; files of the other encodings keep dictionary 1 and the lowest version that describes them."""
    if dictionary == 2:
        return compress_header(raw, dictionary=2), True
    stored = compress_header(raw)
    if dictionary is None and learned:
        stored_2 = compress_header(raw, dictionary=2)
        if len(stored_2) < len(stored):
            return stored_2, True
    return stored, False


def dumps(scene: Scene, *, encoding: str | None = None,
          compression_level: int | None = DEFAULT_COMPRESSION_LEVEL, groups: int = 1,
          cameras: str = "compact", header: str = "compact", rans_lanes: int | None = None,
          quality: int | None = None, tables: EntropyTables | None = None,
          header_dictionary: int | None = None, camera_dictionary: bool | None = None,
          joint_cameras: bool | None = None, adaptive_tokens: bool | None = None) -> bytes:
    """The complete ``.vt4d`` bytes of ``scene``.

    The file says the lowest format version that describes it: 1.5 with required flag bit 4 when its
    ``int<b>-rans`` token sections use interleaved rANS lanes (``rans_lanes``); else 1.4 with required flag
    bit 3 when the scene has ``extra_cameras`` (in either layout; their ``XCAM`` section follows ``CAMS``, each
    trajectory stored as ``cameras`` says); else 1.3 with required flag bit 2 for the compact container (the
    default); else 1.2 with required flag bit 1 for compact cameras; otherwise 1.0 for the float, int8 and
    int4 encodings (byte-identical to a 1.0 writer's output), 1.1 with required flag bit 0 for ``int<b>-rans``
    (bit 0 is set in 1.2 to 1.5 files too).

    Args:
        encoding: token encoding; defaults to ``scene.encoding``.
        compression_level: zstd level for every section (a section that does not shrink is stored raw; in a
            compact container a fixed-width token section that zstd shrinks by less than 1/8 is stored raw
            and aligned too, for zero-copy reading); ``None`` stores every section raw and 64-byte aligned.
        groups: channel groups sharing one scale/offset in the ``int<b>-rans`` encodings (1 = one pair per
            token matrix, d = per channel; must divide d).  Ignored by the other encodings.
        cameras: how the cameras section stores the trajectory (FORMAT.md I.5, I.5.1): ``"compact"``
            (format 1.2: float32 when no reprojection moves more than 0.01 px, else float64; one record for
            a constant K or a static pose), ``"exact"`` (format 1.2, float64: reads back bit for bit) or
            ``"legacy"`` (the 1.0 float64 section, for readers older than 1.2).  In a compact container
            ``"compact"`` may store rotations as float32 quaternions (FORMAT.md I.5.2) under the same 0.01 px rule.
            Each extra camera (FORMAT.md I.5.3) is stored the same way, its precision chosen on its own.
        header: ``"compact"`` (format 1.3, FORMAT.md I.3.1 and I.4.1: the header as one zstd frame with the
            spec-fixed dictionary and binary digests, 18-byte table entries, payloads packed except raw fixed-width token arrays,
            which stay 64-aligned for zero-copy reading) or ``"legacy"`` (the msgpack header, 40-byte entries
            and 64-aligned payloads of 1.0 to 1.2, for readers older than 1.3; with ``cameras="legacy"`` too,
            the file reads in 1.0 and 1.1 readers).
        rans_lanes: the rANS lanes of the ``int<b>-rans`` token sections (FORMAT.md I.6.1; ignored by the other
            encodings).  ``None``, the writer's policy: 8 lanes for a token matrix of 2^15 values or more (a
            paper-size scene: ~2.6x the decoding speed of one chain), 1 for a smaller one in the same file, and
            no lanes at all (the 1.1 layout, byte for byte as before 1.5) when both matrices are smaller.
            ``0``: no lanes (for readers older than 1.5).  ``1`` to ``32``: that many lanes in both sections
            (format 1.5, required flag bit 4).
        quality, tables: ``learned-rans`` only (format 1.6, required flag bit 5, FORMAT.md I.6.2): the quality
            level (1 = the coarsest; default ``scene.quality``) and the entropy tables of the scene's model
            (default: the installed model's, found by fingerprint; EntropyTablesError without them).
        header_dictionary: the dictionary of a compact header.  ``None``, the writer's policy: header dictionary
            2 (format 1.6, required flag bit 7, FORMAT.md I.3.2) for ``learned-rans`` files when it makes the
            header shorter (about 60 bytes for a 10-camera encode), else dictionary 1 (I.3.1), so files of the
            other encodings keep their version.  ``1``: always dictionary 1 (files that readers of the first 1.6
            text read); ``2``: always dictionary 2 (then the file says 1.6).  Only with ``header="compact"``.
        camera_dictionary: whether the cameras sections (``CAMS``, ``XCAM``) may be compressed with the camera
            dictionary (format 1.6, required flag bit 8, compression 2, FORMAT.md I.4.2), which holds the entropy
            tables of typical fixed-point camera records: a 10-camera ``XCAM`` ~70 bytes shorter than zstd alone.
            ``None``, the writer's policy: for ``learned-rans`` files (already 1.6) with fixed-point cameras,
            where it makes the section shorter; ``True``: the same for any file in a compact container (then it
            says 1.6 when it is used); ``False``: never.  Not with ``compression_level=None`` (every section raw).
        joint_cameras: whether ``XCAM`` may code its fixed-point records jointly (format 1.6, required flag bit 9,
            FORMAT.md I.5.5): Exp-Golomb residuals in one bit string, exponents and the first intrinsics
            predicted across cameras, about 140 bytes shorter for a 10-camera rig.  ``None``, the writer's
            policy: where every extra camera is fixed point and it makes the section shorter; ``True``: wherever
            every extra camera is fixed point; ``False``: never (the I.5.3 layout).  Fixed-point cameras are
            the writer's choice for ``learned-rans`` files in a compact container with ``cameras="compact"``.
        adaptive_tokens: whether the ``learned-rans`` token streams use adaptive rows (format 1.6, required flag
            bit 10, FORMAT.md I.6.2): each (class, channel) row of the model's tables learns the file's symbols as
            it codes them, a file 4-14 % shorter.  ``None``, the writer's policy: where it makes the two token
            sections shorter together; ``True``: always; ``False``: never.  ``learned-rans`` only.
    """
    if not isinstance(scene, Scene):
        raise FormatError(f"expected a Scene, got {type(scene).__name__}")
    encoding = scene.encoding if encoding is None else encoding
    if encoding not in ALL_ENCODINGS:
        raise FormatError(f"unknown token encoding {encoding!r}; choose one of {ALL_ENCODINGS}")
    if cameras not in CAMERA_MODES:
        raise FormatError(f"unknown cameras mode {cameras!r}; choose one of {CAMERA_MODES}")
    if header not in HEADER_MODES:
        raise FormatError(f"unknown header mode {header!r}; choose one of {HEADER_MODES}")
    check_lanes(rans_lanes)
    if header_dictionary not in (None, 1, 2) or isinstance(header_dictionary, bool):
        raise FormatError(f"header_dictionary must be None, 1 or 2, got {header_dictionary!r}")
    if header_dictionary == 2 and header != "compact":
        raise FormatError("header_dictionary=2 needs header='compact' (only a compact header has a dictionary)")
    if camera_dictionary is not None and not isinstance(camera_dictionary, bool):
        raise FormatError(f"camera_dictionary must be None, True or False, got {camera_dictionary!r}")
    if joint_cameras is not None and not isinstance(joint_cameras, bool):
        raise FormatError(f"joint_cameras must be None, True or False, got {joint_cameras!r}")
    if adaptive_tokens is not None and not isinstance(adaptive_tokens, bool):
        raise FormatError(f"adaptive_tokens must be None, True or False, got {adaptive_tokens!r}")
    if camera_dictionary and header != "compact":
        raise FormatError("the camera dictionary (compression 2) exists only in compact containers: header='compact'")
    learned = is_learned(encoding)
    if learned:
        tables = find_tables(scene.fingerprint, tables)
        quality = scene.quality if quality is None else quality
        if quality is None:
            raise FormatError(f"learned-rans needs a quality level (1 to {tables.levels})")
        if isinstance(quality, bool) or not isinstance(quality, int) or not 1 <= quality <= tables.levels:
            raise FormatError(f"quality must be a level from 1 to {tables.levels}, got {quality!r}")
    entropy_coded = is_entropy_coded(encoding)
    matrices = (scene.static_tokens, scene.dynamic_tokens)
    if not entropy_coded or rans_lanes == 0:
        lanes: list[int | None] = [None, None]
    elif rans_lanes is not None:
        lanes = [rans_lanes, rans_lanes]
    else:  # the policy: lanes only where they pay, so small scenes keep their 1.1-1.4 bytes and version
        lanes = [policy_lanes(int(np.size(m))) for m in matrices]
        if any(k is not None for k in lanes):
            lanes = [1 if k is None else k for k in lanes]
    compact = header == "compact"
    # learned-rans files (already 1.6) store their cameras in fixed point where it keeps the 0.01 px bound (I.5.4)
    fixed = learned and compact and cameras == "compact"
    use_camera_dictionary = compact and compression_level is not None and (
        camera_dictionary if camera_dictionary is not None else fixed)
    layout, cams = pack_cameras(scene.cameras)
    if cameras != "legacy":
        cams = pack_compact_cameras(scene.cameras, cameras, quaternions=compact, fixed=fixed)
    head = pack_header(HeaderInfo(scene.static_shape, scene.dynamic_shape, encoding, layout, scene.fingerprint,
                                  scene.provenance, scene.metadata, {}), binary_digests=compact)
    dictionary_2 = False
    if compact:
        head, dictionary_2 = _stored_header(head, header_dictionary, learned)
    parts = [(SECTION_CAMERAS, cams)]
    # re-checked here: a scene is mutable, and an extra camera must still fit the cameras it is stored beside
    extras = normalize_extra_cameras(scene.cameras, scene.extra_cameras)
    if extras:
        parts.append((SECTION_EXTRA_CAMERAS, pack_extra_cameras(extras, cameras, quaternions=compact, fixed=fixed)))
    adaptive = False
    if learned:
        assert tables is not None and quality is not None
        choices = (False, True) if adaptive_tokens is None else (adaptive_tokens,)
        coded = {a: [encode_learned_tokens(tokens, tables, quality - 1, 1 + len(extras), which, a)
                     for tokens, which in zip(matrices, ("static", "dynamic"))] for a in choices}
        # the policy (None): adaptive rows where the two streams are shorter together
        adaptive = adaptive_tokens if adaptive_tokens is not None else (
            sum(map(len, coded[True])) < sum(map(len, coded[False])))
        parts += [(SECTION_STATIC, coded[adaptive][0]), (SECTION_DYNAMIC, coded[adaptive][1])]
    else:
        for tokens, tok_name, quant_name, k in ((scene.static_tokens, SECTION_STATIC, SECTION_STATIC_QUANT, lanes[0]),
                                                (scene.dynamic_tokens, SECTION_DYNAMIC, SECTION_DYNAMIC_QUANT,
                                                 lanes[1])):
            enc = encode_tokens(tokens, encoding, groups=groups, lanes=k)
            if enc.quant is not None:
                parts.append((quant_name, enc.quant))
            parts.append((tok_name, enc.tokens))
    sections: list[SectionParts] = []
    joint = False
    for name, raw in parts:
        tokens_section = name in (SECTION_STATIC, SECTION_DYNAMIC)
        # rANS streams are incompressible: their sections are stored raw without trying zstd (FORMAT.md I.6.1)
        level = None if (entropy_coded or learned) and tokens_section else compression_level
        # in a compact container a fixed-width token array is worth zstd only when it saves 1/8 of it: raw,
        # it is read in place (aligned), while decompressing e.g. int8 tokens, which zstd shrinks by ~7 %,
        # costs a verified load a sixth of its time (bench/bench_format.py)
        saving = TOKEN_ZSTD_MIN_SAVING if compact and tokens_section else 0.0
        compression, stored = compress_payload(raw, level, min_saving=saving)
        if use_camera_dictionary and name in (SECTION_CAMERAS, SECTION_EXTRA_CAMERAS) and raw:
            packed = compress_with_camera_dictionary(raw)
            if len(packed) < len(stored):
                compression, stored = COMPRESSION_ZSTD_CAMERAS, packed
        if name == SECTION_EXTRA_CAMERAS and fixed and joint_cameras is not False:
            joint_raw = joint_extra_cameras(raw, layout.num_frames, layout.width, layout.height)
            if joint_raw is not None:
                joint_compression, joint_stored = compress_payload(joint_raw, compression_level)
                if joint_cameras or len(joint_stored) < len(stored):
                    raw, compression, stored, joint = joint_raw, joint_compression, joint_stored, True
        # a compact container aligns only what a reader can use in place: raw fixed-width token arrays
        aligned = tokens_section and not (entropy_coded or learned) and compression == COMPRESSION_RAW
        sections.append((name, True, compression, stored, len(raw), aligned))
    flags = ((FLAG_ENTROPY_CODED_TOKENS if entropy_coded else 0) | (FLAG_COMPACT_CAMERAS if cameras != "legacy" else 0)
             | (FLAG_COMPACT_CONTAINER if compact else 0) | (FLAG_EXTRA_CAMERAS if extras else 0)
             | (FLAG_RANS_LANES if lanes[0] is not None else 0) | (FLAG_LEARNED_TOKENS if learned else 0)
             | (FLAG_FIXED_CAMERAS if fixed else 0) | (FLAG_HEADER_DICTIONARY_2 if dictionary_2 else 0)
             | (FLAG_CAMERA_DICTIONARY if any(part[2] == COMPRESSION_ZSTD_CAMERAS for part in sections) else 0)
             | (FLAG_JOINT_CAMERAS if joint else 0) | (FLAG_ADAPTIVE_TOKENS if adaptive else 0))
    minor = (6 if learned or dictionary_2 or flags & FLAG_CAMERA_DICTIONARY else 5 if flags & FLAG_RANS_LANES else 4 if flags & FLAG_EXTRA_CAMERAS else 3 if compact
             else 2 if flags & FLAG_COMPACT_CAMERAS else 1 if flags else 0)
    return build_container(head, sections, minor=minor, required_flags=flags)


def save(scene: Scene, path_or_file: str | os.PathLike[str] | BinaryIO, *, encoding: str | None = None,
         compression_level: int | None = DEFAULT_COMPRESSION_LEVEL, groups: int = 1, cameras: str = "compact",
         header: str = "compact", rans_lanes: int | None = None, quality: int | None = None,
         tables: EntropyTables | None = None, header_dictionary: int | None = None,
         camera_dictionary: bool | None = None, joint_cameras: bool | None = None,
         adaptive_tokens: bool | None = None) -> int:
    """Write ``scene`` to a path (atomically: temp file + rename) or a binary file object.

    Returns the number of bytes written.  See :func:`dumps` for the options.
    """
    data = dumps(scene, encoding=encoding, compression_level=compression_level, groups=groups, cameras=cameras,
                 header=header, rans_lanes=rans_lanes, quality=quality, tables=tables,
                 header_dictionary=header_dictionary, camera_dictionary=camera_dictionary,
                 joint_cameras=joint_cameras, adaptive_tokens=adaptive_tokens)
    if hasattr(path_or_file, "write"):
        path_or_file.write(data)
        return len(data)
    path = os.fspath(path_or_file)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):  # name the folder, not the temp file the write would have failed on
        raise FileNotFoundError(errno.ENOENT, f"cannot write {path}: no such folder (create it first)", folder)
    tmp = f"{path}.tmp-{os.getpid()}"
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return len(data)
