"""Writing scenes: :func:`dumps` builds the container bytes, :func:`save` writes them."""

from __future__ import annotations

import errno
import os
from typing import BinaryIO

from ..errors import FormatError
from .encodings import ENCODINGS, encode_tokens
from .header import HeaderInfo, pack_header
from .encodings import is_entropy_coded
from .layout import (FLAG_ENTROPY_CODED_TOKENS, FORMAT_MAJOR, Preamble, SectionEntry, align, crc32, pack_preamble, pack_table)
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
          compression_level: int | None = DEFAULT_COMPRESSION_LEVEL, groups: int = 1) -> bytes:
    """The complete ``.vt4d`` bytes of ``scene``.

    The file says the lowest format version that describes it: 1.0 for the float, int8 and int4
    encodings (byte-identical to a 1.0 writer's output), 1.1 with required flag bit 0 for ``int<b>-rans``.

    Args:
        encoding: token encoding; defaults to ``scene.encoding``.
        compression_level: zstd level for every section (a section that does not shrink is stored raw);
            ``None`` stores every section raw and 64-byte aligned, for zero-copy reading.
        groups: channel groups sharing one scale/offset in the ``int<b>-rans`` encodings (1 = one pair per
            token matrix, d = per channel; must divide d).  Ignored by the other encodings.
    """
    if not isinstance(scene, Scene):
        raise FormatError(f"expected a Scene, got {type(scene).__name__}")
    encoding = scene.encoding if encoding is None else encoding
    if encoding not in ENCODINGS:
        raise FormatError(f"unknown token encoding {encoding!r}; choose one of {ENCODINGS}")
    layout, cams = pack_cameras(scene.cameras)
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
    if entropy_coded:
        return build_container(header, sections, minor=1, required_flags=FLAG_ENTROPY_CODED_TOKENS)
    return build_container(header, sections, minor=0)


def save(scene: Scene, path_or_file: str | os.PathLike[str] | BinaryIO, *, encoding: str | None = None,
         compression_level: int | None = DEFAULT_COMPRESSION_LEVEL, groups: int = 1) -> int:
    """Write ``scene`` to a path (atomically: temp file + rename) or a binary file object.

    Returns the number of bytes written.  See :func:`dumps` for the options.
    """
    data = dumps(scene, encoding=encoding, compression_level=compression_level, groups=groups)
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
