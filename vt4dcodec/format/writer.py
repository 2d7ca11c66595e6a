"""Writing scenes: :func:`dumps` builds the container bytes, :func:`save` writes them."""

from __future__ import annotations

import errno
import os
from typing import BinaryIO

from ..errors import FormatError
from .encodings import ENCODINGS, encode_tokens
from .header import HeaderInfo, pack_header
from .encodings import is_entropy_coded
from .compact_cameras import CAMERA_MODES, pack_compact_cameras
from .layout import (FLAG_COMPACT_CAMERAS, FLAG_ENTROPY_CODED_TOKENS, FORMAT_MAJOR, Preamble, SectionEntry, align, crc32,
                     pack_preamble, pack_table)
from .limits import PREAMBLE_SIZE, SECTION_ENTRY_SIZE
from .scene import Scene
from .sections import (SECTION_CAMERAS, SECTION_DYNAMIC, SECTION_DYNAMIC_QUANT, SECTION_STATIC,
                       SECTION_STATIC_QUANT, compress_payload, pack_cameras)

__all__ = ["dumps", "save", "build_container", "DEFAULT_COMPRESSION_LEVEL"]

DEFAULT_COMPRESSION_LEVEL = 9  # zstd level; see docs/benchmarks/format.md for the size/speed trade


def build_container(header: bytes, sections: list[tuple[str, bool, int, bytes, int]], *,
                    minor: int = 0, required_flags: int = 0, optional_flags: int = 0) -> bytes:
    """Lay out a container from already-encoded parts.

    ``sections`` holds ``(type, critical, compression, stored_bytes, raw_length)`` in file order.  Used by
    :func:`dumps` and by the test-vector generator (which builds deliberately unusual files).
    """
    table_end = PREAMBLE_SIZE + len(header) + SECTION_ENTRY_SIZE * len(sections)
    entries, offset = [], align(table_end)
    for name, critical, compression, stored, raw_length in sections:
        entries.append(SectionEntry(name, critical, compression, offset, len(stored), raw_length, crc32(stored)))
        offset = align(offset + len(stored))
    file_length = entries[-1].offset + entries[-1].stored_length if entries else table_end
    table = pack_table(entries)
    preamble = pack_preamble(Preamble(FORMAT_MAJOR, minor, required_flags, optional_flags, file_length,
                                      len(header), crc32(header), len(entries), crc32(table)))
    out = bytearray(file_length)
    out[:PREAMBLE_SIZE] = preamble
    out[PREAMBLE_SIZE:PREAMBLE_SIZE + len(header)] = header
    out[PREAMBLE_SIZE + len(header):table_end] = table
    for entry, (_, _, _, stored, _) in zip(entries, sections):
        out[entry.offset:entry.offset + len(stored)] = stored
    return bytes(out)


def dumps(scene: Scene, *, encoding: str | None = None,
          compression_level: int | None = DEFAULT_COMPRESSION_LEVEL, groups: int = 1,
          cameras: str = "compact") -> bytes:
    """The complete ``.vt4d`` bytes of ``scene``.

    The file says the lowest format version that describes it: 1.2 with required flag bit 1 for compact
    cameras (the default); otherwise 1.0 for the float, int8 and int4 encodings (byte-identical to a 1.0
    writer's output), 1.1 with required flag bit 0 for ``int<b>-rans`` (bit 0 is set in 1.2 files too).

    Args:
        encoding: token encoding; defaults to ``scene.encoding``.
        compression_level: zstd level for every section (a section that does not shrink is stored raw);
            ``None`` stores every section raw and 64-byte aligned, for zero-copy reading.
        groups: channel groups sharing one scale/offset in the ``int<b>-rans`` encodings (1 = one pair per
            token matrix, d = per channel; must divide d).  Ignored by the other encodings.
        cameras: how the cameras section stores the trajectory (FORMAT.md I.5, I.5.1): ``"compact"``
            (format 1.2: float32 when no reprojection moves more than 0.01 px, else float64; one record for
            a constant K or a static pose), ``"exact"`` (format 1.2, float64: reads back bit for bit) or
            ``"legacy"`` (the 1.0 float64 section, for readers older than 1.2).
    """
    if not isinstance(scene, Scene):
        raise FormatError(f"expected a Scene, got {type(scene).__name__}")
    encoding = scene.encoding if encoding is None else encoding
    if encoding not in ENCODINGS:
        raise FormatError(f"unknown token encoding {encoding!r}; choose one of {ENCODINGS}")
    if cameras not in CAMERA_MODES:
        raise FormatError(f"unknown cameras mode {cameras!r}; choose one of {CAMERA_MODES}")
    layout, cams = pack_cameras(scene.cameras)
    if cameras != "legacy":
        cams = pack_compact_cameras(scene.cameras, cameras)
    header = pack_header(HeaderInfo(scene.static_shape, scene.dynamic_shape, encoding, layout, scene.fingerprint,
                                    scene.provenance, scene.metadata, {}))
    parts = [(SECTION_CAMERAS, cams)]
    for tokens, tok_name, quant_name in ((scene.static_tokens, SECTION_STATIC, SECTION_STATIC_QUANT),
                                         (scene.dynamic_tokens, SECTION_DYNAMIC, SECTION_DYNAMIC_QUANT)):
        enc = encode_tokens(tokens, encoding, groups=groups)
        if enc.quant is not None:
            parts.append((quant_name, enc.quant))
        parts.append((tok_name, enc.tokens))
    sections = []
    entropy_coded = is_entropy_coded(encoding)
    for name, raw in parts:
        # rANS streams are incompressible: their sections are stored raw without trying zstd (FORMAT.md I.6.1)
        level = None if entropy_coded and name in (SECTION_STATIC, SECTION_DYNAMIC) else compression_level
        compression, stored = compress_payload(raw, level)
        sections.append((name, True, compression, stored, len(raw)))
    flags = (FLAG_ENTROPY_CODED_TOKENS if entropy_coded else 0) | (FLAG_COMPACT_CAMERAS if cameras != "legacy" else 0)
    minor = 2 if flags & FLAG_COMPACT_CAMERAS else 1 if flags else 0
    return build_container(header, sections, minor=minor, required_flags=flags)


def save(scene: Scene, path_or_file: str | os.PathLike[str] | BinaryIO, *, encoding: str | None = None,
         compression_level: int | None = DEFAULT_COMPRESSION_LEVEL, groups: int = 1, cameras: str = "compact") -> int:
    """Write ``scene`` to a path (atomically: temp file + rename) or a binary file object.

    Returns the number of bytes written.  See :func:`dumps` for the options.
    """
    data = dumps(scene, encoding=encoding, compression_level=compression_level, groups=groups, cameras=cameras)
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
