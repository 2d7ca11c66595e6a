"""Reading scenes: :func:`open_scene` (lazy), :func:`load` / :func:`loads` (everything), :func:`verify`."""

from __future__ import annotations

import os
from typing import Any, BinaryIO

import numpy as np

from ..cameras import Trajectory
from ..errors import (ChecksumError, EntropyTablesError, FormatError, LimitExceededError, MalformedHeaderError,
                      MalformedSectionError, TruncatedError,
                      UnsupportedFeatureError)
from .encodings import codes_from_payload, decode_tokens, is_affine, is_entropy_coded, is_learned, parse_quant, payload_size
from .learned import MAX_LEARNED_VALUES, EntropyTables, decode_learned_tokens, find_tables, parse_learned_payload
from .rans_tokens import decode_rans_codes, decode_rans_token_pair
from .fingerprint import ModelFingerprint, Provenance
from .header import HeaderInfo, parse_header
from .compact_cameras import unpack_compact_cameras
from .extra_cameras import (SECTION_EXTRA_CAMERAS, extra_camera_count, extra_cameras_max_raw_length,
                            unpack_extra_cameras)
from .layout import (COMPRESSION_NAMES, FLAG_COMPACT_CAMERAS, FLAG_COMPACT_CONTAINER, FLAG_ENTROPY_CODED_TOKENS, FLAG_EXTRA_CAMERAS,
                     FLAG_CAMERA_DICTIONARY, FLAG_FIXED_CAMERAS, FLAG_ADAPTIVE_TOKENS, FLAG_HEADER_DICTIONARY_2, FLAG_JOINT_CAMERAS, FLAG_LEARNED_TOKENS, FLAG_RANS_LANES, FORMAT_MINOR, BytesLike, Preamble, SectionEntry, crc32, entry_size,
                     parse_preamble, parse_table)
from .rans_tokens import MAX_LANES
from .limits import PREAMBLE_SIZE
from .scene import Scene
from .sections import (DECODED_CAMERA_BYTES_PER_FRAME, DEFAULT_MAX_DECODED_BYTES, KNOWN_SECTIONS, SECTION_CAMERAS,
                       SECTION_DYNAMIC, SECTION_DYNAMIC_QUANT, SECTION_STATIC, SECTION_STATIC_QUANT,
                       check_decoded_budget, decoded_budget, section_payload, unpack_cameras)

__all__ = ["SceneFile", "open_scene", "load", "loads", "verify", "read_container_bytes", "open_binary", "is_url"]

_TOKENS = {"static": (SECTION_STATIC, SECTION_STATIC_QUANT), "dynamic": (SECTION_DYNAMIC, SECTION_DYNAMIC_QUANT)}


def is_url(source: Any) -> bool:
    """True for an fsspec URL (``http://``, ``s3://``, ``memory://``...); ``file://`` counts as a path."""
    return isinstance(source, str) and "://" in source and not source.startswith("file://")


def open_binary(source: "str | os.PathLike[str]", **storage_options: Any) -> BinaryIO:
    """A binary file object for a local path, a ``file://`` path or an fsspec URL (fsspec is needed for
    URLs only: ``pip install "vt4dcodec[remote]"``).  ``storage_options`` go to fsspec."""
    if isinstance(source, str) and source.startswith("file://"):
        source = source[len("file://"):]
    if not is_url(source):
        return open(source, "rb")
    try:
        import fsspec
    except ImportError:
        raise UnsupportedFeatureError(f"reading {source} needs fsspec: pip install \"vt4dcodec[remote]\"") from None
    fh: BinaryIO = fsspec.open(source, "rb", **storage_options).open()
    return fh


def read_container_bytes(source: Any, **storage_options: Any) -> BytesLike:
    """The container bytes of ``source`` (a path, an fsspec URL, a bytes-like object, or a binary file
    object; ``storage_options`` go to fsspec for a URL).

    A path, URL or bytes must hold exactly one container.  A file object is read from its current position
    for the container's declared length only.  Nothing is read or allocated beyond what the preamble
    declares and the real data holds, so a wrong or hostile file costs at most its own size.
    """
    if isinstance(source, (bytes, bytearray, memoryview)):
        return source
    if is_url(source):
        with open_binary(source, **storage_options) as fh:
            data = read_container_bytes(fh)
            if fh.read(1):
                raise MalformedSectionError(f"unexpected bytes follow the container's declared end in {source}")
            return data
    if isinstance(source, str) and source.startswith("file://"):
        source = source[len("file://"):]
    if isinstance(source, (str, os.PathLike)):
        with open(source, "rb") as fh:
            head = fh.read(PREAMBLE_SIZE)
            pre = parse_preamble(head)
            size = os.fstat(fh.fileno()).st_size
            if size > pre.file_length:
                raise MalformedSectionError(
                    f"{size - pre.file_length} unexpected bytes follow the container's declared end {pre.file_length}"
                )
            return head + _read_exactly(fh, pre.file_length - PREAMBLE_SIZE)
    if hasattr(source, "read"):
        head = source.read(PREAMBLE_SIZE)
        if not isinstance(head, (bytes, bytearray)):
            raise FormatError("the file object must be opened in binary mode ('rb')")
        pre = parse_preamble(head)  # raises typed errors on short or bad data
        return bytes(head) + _read_exactly(source, pre.file_length - PREAMBLE_SIZE)
    raise FormatError(f"cannot read a scene from {type(source).__name__}; pass a path, bytes or a binary file")


def _read_exactly(fh: BinaryIO, n: int) -> bytes:
    chunks, left = [], n
    while left > 0:
        chunk = fh.read(min(left, 1 << 24))  # bounded reads: never allocate a claimed size up front
        if not chunk:
            raise TruncatedError(f"the file ends {left} bytes before the container's declared end")
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


class SceneFile:
    """A parsed container: preamble, header and section table are checked on open; sections are read,
    checksummed and decoded only when asked for.

    Attributes:
        header: the decoded msgpack header (dict).
        preamble: the parsed preamble (version, flags, sizes).
        sections: the section table entries in file order.
        max_decoded_bytes: the decoded-size budget (FORMAT.md I.7): no section is decompressed when the scene
            would decode to more (LimitExceededError); None reads any size.
    """

    def __init__(self, data: BytesLike, *, tables: EntropyTables | None = None,
                 max_decoded_bytes: int | None = DEFAULT_MAX_DECODED_BYTES) -> None:
        self._tables = tables
        self.max_decoded_bytes = decoded_budget(max_decoded_bytes)
        if not isinstance(data, bytes):
            try:
                data = memoryview(data).cast("B")
            except TypeError as exc:
                raise FormatError(f"the data must be a contiguous bytes-like object ({exc})") from None
        self._data = data
        pre = parse_preamble(data)
        if len(data) < pre.file_length:
            raise TruncatedError(
                f"the data is {len(data)} bytes but the container declares {pre.file_length}; the file is cut short"
            )
        if len(data) > pre.file_length:
            raise MalformedSectionError(
                f"{len(data) - pre.file_length} unexpected bytes follow the container's declared end {pre.file_length}"
            )
        header_raw = data[PREAMBLE_SIZE:PREAMBLE_SIZE + pre.header_length]
        if crc32(header_raw) != pre.header_crc32:
            raise ChecksumError("the header checksum does not match: the header bytes are damaged")
        table_start = PREAMBLE_SIZE + pre.header_length
        table_end = table_start + pre.section_count * entry_size(pre.required_flags)
        table_raw = data[table_start:table_end]
        if crc32(table_raw) != pre.table_crc32:
            raise ChecksumError("the section table checksum does not match: the table is damaged")
        self.preamble: Preamble = pre
        compact = bool(pre.required_flags & FLAG_COMPACT_CONTAINER)
        dictionary_2 = bool(pre.required_flags & FLAG_HEADER_DICTIONARY_2)
        if dictionary_2 and not compact:
            raise MalformedHeaderError("required flag bit 7 (header dictionary 2) is set without bit 2 (compact "
                                       "container): only a compact header is compressed with a dictionary")
        camera_dictionary = bool(pre.required_flags & FLAG_CAMERA_DICTIONARY)
        if camera_dictionary and not compact:
            raise MalformedHeaderError("required flag bit 8 (the camera dictionary) is set without bit 2 (compact "
                                       "container)")
        self._info: HeaderInfo = parse_header(header_raw, newer_minor=pre.minor > FORMAT_MINOR, compressed=compact,
                                              dictionary=2 if dictionary_2 else 1)
        self._check_encoding_version()
        self._table_end = table_end
        self.sections: list[SectionEntry] = parse_table(table_raw, pre.section_count, table_end, pre.file_length,
                                                        compact=compact, camera_dictionary=camera_dictionary)
        self._by_type = {e.type: e for e in self.sections}
        self._check_section_set()
        self._decoded_bytes = self._declared_decoded_bytes()
        self._cameras: Trajectory | None = None
        self._extra_cameras: tuple[Trajectory, ...] | None = None

    # --- structure ---------------------------------------------------------------------------------
    def _check_encoding_version(self) -> None:
        """Entropy-coded encodings exist from 1.1 on and are announced by required flag bit 0 (and the
        flag announces nothing else); compact cameras (required flag bit 1) exist from 1.2 on; rANS lanes
        (required flag bit 4, 1.5) only beside bit 0 (the minor version of bits 2 to 4 is parse_preamble's)."""
        if self.preamble.required_flags & FLAG_COMPACT_CAMERAS and self.preamble.minor < 2:
            raise MalformedHeaderError(
                f"required flag bit 1 (compact cameras) was introduced in format 1.2 but the file says "
                f"1.{self.preamble.minor}")
        entropy = is_entropy_coded(self._info.encoding)
        flagged = bool(self.preamble.required_flags & FLAG_ENTROPY_CODED_TOKENS)
        if entropy and self.preamble.minor < 1:
            raise MalformedHeaderError(
                f"encoding {self._info.encoding} was introduced in format 1.1 but the file says 1.{self.preamble.minor}")
        if entropy != flagged:
            raise MalformedHeaderError(
                f"encoding {self._info.encoding} {'requires' if entropy else 'must not set'} required feature flag "
                "bit 0 (entropy-coded tokens)")
        if self.rans_lanes and not flagged:
            raise MalformedHeaderError(
                "required flag bit 4 (rANS lanes) is set without bit 0 (entropy-coded tokens), which it needs")
        if self.fixed_cameras and not (self.compact_container and self.compact_cameras):
            raise MalformedHeaderError("required flag bit 6 (fixed-point cameras) is set without bits 1 and 2 "
                                       "(compact cameras in a compact container), which it needs")
        if self.joint_cameras and not (self.fixed_cameras and self.has_extra_cameras):
            raise MalformedHeaderError("required flag bit 9 (joint extra cameras) is set without bits 3 and 6 "
                                       "(extra cameras, fixed-point cameras), which it needs")
        learned = is_learned(self._info.encoding)
        if learned != bool(self.preamble.required_flags & FLAG_LEARNED_TOKENS):
            raise MalformedHeaderError(
                f"encoding {self._info.encoding} {'requires' if learned else 'must not set'} required feature flag "
                "bit 5 (learned-rans tokens)")
        if self.adaptive_tokens and not learned:
            raise MalformedHeaderError("required flag bit 10 (adaptive rows) is set without bit 5 (learned-rans "
                                       "tokens), which it needs")

    def _check_section_set(self) -> None:
        required = {SECTION_CAMERAS, SECTION_STATIC, SECTION_DYNAMIC}
        if is_affine(self._info.encoding):
            required |= {SECTION_STATIC_QUANT, SECTION_DYNAMIC_QUANT}
        if self.has_extra_cameras:
            required.add(SECTION_EXTRA_CAMERAS)
        for entry in self.sections:
            if entry.type in required:
                if not entry.critical:
                    raise MalformedSectionError(f"section {entry.type} must be marked critical")
            elif entry.type == SECTION_EXTRA_CAMERAS:
                raise MalformedSectionError(
                    f"section {entry.type} (extra cameras) is present but required flag bit 3 is clear")
            elif entry.type in KNOWN_SECTIONS:
                raise MalformedSectionError(
                    f"section {entry.type} is not allowed with encoding {self._info.encoding}"
                )
            elif entry.critical:
                raise UnsupportedFeatureError(
                    f"the file holds critical section {entry.type!r} this reader does not know; upgrade vt4dcodec"
                )
        missing = required - set(self._by_type)
        if missing:
            raise MalformedSectionError(f"the file lacks required section(s) {sorted(missing)}")
        self._check_raw_lengths()

    def _check_raw_lengths(self) -> None:
        """Every known section's ``raw_length`` against what the header implies, *before* anything is
        decompressed (FORMAT.md I.11): a tiny file cannot make a reader allocate more than its tokens,
        cameras and quantization need (an 18 KB scene must not make it allocate two declared 256 MiB sections)."""
        d = self._info.static_shape[1]
        limits = {SECTION_CAMERAS: self._info.cameras.raw_length,
                  SECTION_EXTRA_CAMERAS: extra_cameras_max_raw_length(self._info.cameras.num_frames)}
        for name, (rows, cols) in ((SECTION_STATIC, self._info.static_shape),
                                   (SECTION_DYNAMIC, self._info.dynamic_shape)):
            if is_learned(self._info.encoding):  # I.6.2: level, views, state, <= 2 bytes a code
                if rows * cols > MAX_LEARNED_VALUES:
                    raise LimitExceededError(f"{rows * cols} learned-rans values in one matrix exceed the limit of "
                                             f"{MAX_LEARNED_VALUES}")
                limits[name] = 2 + 4 + 2 * rows * cols
            elif is_entropy_coded(self._info.encoding):  # I.6.1: parameters, table, [K, K - 1 more states,] <= 2 bytes a code
                limits[name] = (2 + 8 * cols + 1 + cols + 4 + 3 * 511 + 4 + 2 * rows * cols
                                + (1 + 4 * (MAX_LANES - 1) if self.rans_lanes else 0))
            else:
                limits[name] = payload_size(self._info.encoding, rows, cols)
        if is_affine(self._info.encoding):
            limits[SECTION_STATIC_QUANT] = limits[SECTION_DYNAMIC_QUANT] = 8 * d
        for entry in self.sections:
            limit = limits.get(entry.type)
            if limit is not None and entry.raw_length > limit:
                raise MalformedSectionError(
                    f"section {entry.type} declares {entry.raw_length} raw bytes; the header implies "
                    f"{'at most ' if entry.type in (SECTION_STATIC, SECTION_DYNAMIC) and is_entropy_coded(self._info.encoding) else ''}"
                    f"{limit}")

    def _declared_decoded_bytes(self) -> int:
        """FORMAT.md I.7, decoded-size budget: the raw lengths of the sections a reader decodes, the float32 token
        matrices and one decoded camera (the extra cameras are added once ``XCAM`` says how many)."""
        (ns, ds), (nd, dd) = self._info.static_shape, self._info.dynamic_shape
        return (sum(e.raw_length for e in self.sections if e.type in KNOWN_SECTIONS) + 4 * (ns * ds + nd * dd)
                + DECODED_CAMERA_BYTES_PER_FRAME * self._info.cameras.num_frames)

    def raw_section(self, name: str) -> bytes | memoryview:
        """The decompressed, checksum-verified bytes of section ``name`` (a zero-copy view when stored raw);
        LimitExceededError first when the scene's decoded size exceeds :attr:`max_decoded_bytes`."""
        entry = self._by_type.get(name)
        if entry is None:
            raise MalformedSectionError(f"the file has no section {name!r}; it has {[e.type for e in self.sections]}")
        check_decoded_budget(self._decoded_bytes, self.max_decoded_bytes)
        return section_payload(self._data, entry)

    # --- header fields -----------------------------------------------------------------------------
    @property
    def header(self) -> dict[str, Any]:
        return self._info.raw

    @property
    def version(self) -> tuple[int, int]:
        return self.preamble.major, self.preamble.minor

    @property
    def fingerprint(self) -> ModelFingerprint:
        return self._info.fingerprint

    @property
    def metadata(self) -> dict[str, Any]:
        return self._info.metadata

    @property
    def provenance(self) -> Provenance | None:
        return self._info.provenance

    @property
    def encoding(self) -> str:
        return self._info.encoding

    @property
    def num_frames(self) -> int:
        return self._info.cameras.num_frames

    @property
    def static_shape(self) -> tuple[int, int]:
        return self._info.static_shape

    @property
    def dynamic_shape(self) -> tuple[int, int]:
        return self._info.dynamic_shape

    @property
    def nbytes(self) -> int:
        return self.preamble.file_length

    @property
    def compact_cameras(self) -> bool:
        """Whether the cameras section uses the compact encoding (format 1.2, required flag bit 1)."""
        return bool(self.preamble.required_flags & FLAG_COMPACT_CAMERAS)

    @property
    def compact_container(self) -> bool:
        """Whether the file is a compact container (format 1.3, required flag bit 2): zstd header with the
        spec-fixed dictionary, 18-byte table entries, packed payloads, quaternion poses allowed."""
        return bool(self.preamble.required_flags & FLAG_COMPACT_CONTAINER)

    @property
    def rans_lanes(self) -> bool:
        """Whether the entropy-coded token payloads hold interleaved rANS lanes (format 1.5, required flag bit 4:
        each payload says its lane count K, FORMAT.md I.6.1)."""
        return bool(self.preamble.required_flags & FLAG_RANS_LANES)

    @property
    def fixed_cameras(self) -> bool:
        """Whether compact camera records may be fixed point (format 1.6, required flag bit 6, FORMAT.md I.5.4)."""
        return bool(self.preamble.required_flags & FLAG_FIXED_CAMERAS)

    @property
    def joint_cameras(self) -> bool:
        """Whether ``XCAM`` codes its fixed-point records jointly (format 1.6, required flag bit 9, FORMAT.md I.5.5)."""
        return bool(self.preamble.required_flags & FLAG_JOINT_CAMERAS)

    @property
    def adaptive_tokens(self) -> bool:
        """Whether the learned-rans token streams use adaptive rows (format 1.6, required flag bit 10,
        FORMAT.md I.6.2)."""
        return bool(self.preamble.required_flags & FLAG_ADAPTIVE_TOKENS)

    @property
    def has_extra_cameras(self) -> bool:
        """Whether the file holds the extra cameras section (format 1.4, required flag bit 3)."""
        return bool(self.preamble.required_flags & FLAG_EXTRA_CAMERAS)

    @property
    def num_extra_cameras(self) -> int:
        """How many extra cameras the file holds (0 without the section); reads the section's count and length
        table only (checksum-verified), no trajectory is decoded."""
        if not self.has_extra_cameras:
            return 0
        if self._extra_cameras is not None:
            return len(self._extra_cameras)
        return extra_camera_count(self.raw_section(SECTION_EXTRA_CAMERAS), joint=self.joint_cameras)

    @property
    def token_bytes(self) -> int:
        """Stored bytes of the token sections (``ZSTA``, ``ZDYN``; the ``Q`` sections are not counted)."""
        return sum(e.stored_length for e in self.sections if e.type in (SECTION_STATIC, SECTION_DYNAMIC))

    # --- sections ----------------------------------------------------------------------------------
    @property
    def cameras(self) -> Trajectory:
        """The source camera trajectory (K, w2c, size, distortion, timestamps)."""
        if self._cameras is None:
            raw = self.raw_section(SECTION_CAMERAS)
            if self.compact_cameras:
                self._cameras = unpack_compact_cameras(raw, self._info.cameras, quaternions=self.compact_container,
                                                       fixed=self.fixed_cameras)
            else:
                self._cameras = unpack_cameras(raw, self._info.cameras)
        return self._cameras

    @property
    def extra_cameras(self) -> tuple[Trajectory, ...]:
        """The trajectories of the further encoded cameras, in encoding order (``()`` without the section);
        each shares :attr:`cameras`' timestamps (so decoding them decodes ``CAMS`` too)."""
        if self._extra_cameras is None:
            if not self.has_extra_cameras:
                self._extra_cameras = ()
            else:
                self._extra_cameras = self._unpack_extra_cameras(None)
        return self._extra_cameras

    def extra_camera(self, index: int) -> Trajectory:
        """Extra camera ``index`` (0-based) alone: the section's count and length table are checked and only
        that record is decoded."""
        if self._extra_cameras is not None:
            if not 0 <= index < len(self._extra_cameras):
                raise FormatError(f"extra camera {index} does not exist: the file holds {len(self._extra_cameras)}")
            return self._extra_cameras[index]
        if not self.has_extra_cameras:
            raise FormatError(f"extra camera {index} does not exist: the file holds no extra cameras")
        return self._unpack_extra_cameras(index)[0]

    def _unpack_extra_cameras(self, index: int | None) -> tuple[Trajectory, ...]:
        raw = self.raw_section(SECTION_EXTRA_CAMERAS)
        count = extra_camera_count(raw, joint=self.joint_cameras)
        extras = count * DECODED_CAMERA_BYTES_PER_FRAME * self._info.cameras.num_frames
        check_decoded_budget(self._decoded_bytes + extras, self.max_decoded_bytes)
        return unpack_extra_cameras(raw, self._info.cameras, self.cameras.timestamps,
                                    compact_cameras=self.compact_cameras, quaternions=self.compact_container,
                                    fixed=self.fixed_cameras, joint=self.joint_cameras, index=index)

    def quantization(self, which: str) -> tuple[np.ndarray, np.ndarray]:
        """(scale, offset) float32 (d,) of the "static" or "dynamic" tokens (affine encodings only; for
        ``int<b>-rans`` each channel gets its group's pair)."""
        tok_name, quant_name = _TOKENS[which]
        if is_learned(self.encoding):
            raise FormatError("learned-rans tokens have per-model quantizer steps, not per-file parameters "
                              "(SceneFile.entropy_tables().steps)")
        if is_entropy_coded(self.encoding):
            rows, cols = self.static_shape if which == "static" else self.dynamic_shape
            return decode_rans_codes(self.raw_section(tok_name), self.encoding, rows, cols, lanes=self.rans_lanes)[1:]
        if not is_affine(self.encoding):
            raise FormatError(f"encoding {self.encoding} has no quantization parameters")
        return parse_quant(self.raw_section(quant_name), self.static_shape[1])

    @property
    def quality(self) -> int | None:
        """The quality level (1 = the coarsest) of a ``learned-rans`` file, read from the checksum-verified
        ``ZSTA`` payload without the model's tables; None for the other encodings."""
        if not is_learned(self.encoding):
            return None
        return parse_learned_payload(self.raw_section(SECTION_STATIC))[0] + 1

    def entropy_tables(self) -> EntropyTables:
        """The entropy tables the ``learned-rans`` tokens need: those given to :func:`open_scene`, else the
        installed model's with this file's fingerprint (EntropyTablesError when there is none)."""
        self._tables = find_tables(self.fingerprint, self._tables)
        return self._tables

    def _tokens(self, which: str, dequantize: bool) -> np.ndarray:
        tok_name, quant_name = _TOKENS[which]
        rows, cols = self.static_shape if which == "static" else self.dynamic_shape
        payload = self.raw_section(tok_name)
        if is_learned(self.encoding):
            tokens, _ = decode_learned_tokens(payload, self.entropy_tables(), rows, cols, which,
                                              views=1 + self.num_extra_cameras, adaptive=self.adaptive_tokens)
            return tokens
        if not dequantize:
            return codes_from_payload(payload, self.encoding, rows, cols, lanes=self.rans_lanes)
        quant = self.raw_section(quant_name) if is_affine(self.encoding) else None
        return decode_tokens(payload, quant, self.encoding, rows, cols, lanes=self.rans_lanes)

    def static_tokens(self, dequantize: bool = True) -> np.ndarray:
        """Z_s as (N_s, d) float32 (zero-copy read-only view for raw-stored float32); with
        ``dequantize=False`` the stored values (float32, float16, or uint8 codes for int8/int4/int<b>-rans)."""
        return self._tokens("static", dequantize)

    def dynamic_tokens(self, dequantize: bool = True) -> np.ndarray:
        """Z_d as (N_d, d) float32; see :meth:`static_tokens`."""
        return self._tokens("dynamic", dequantize)

    def tokens(self, dequantize: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(Z_s, Z_d) exactly as :meth:`static_tokens` and :meth:`dynamic_tokens` give them (same values,
        same errors in the same order); for ``int<b>-rans`` both sections are decoded in one interleaved
        pass of the compiled coder, ~1.4x faster than one after the other (with rANS lanes, format 1.5, each
        section is fast on its own)."""
        if dequantize and is_entropy_coded(self.encoding):
            try:
                pair = decode_rans_token_pair([(self.raw_section(SECTION_STATIC), *self.static_shape),
                                               (self.raw_section(SECTION_DYNAMIC), *self.dynamic_shape)], self.encoding,
                                              lanes=self.rans_lanes)
            except FormatError:
                pair = None  # decode one by one below, so the first problem in file order is the one raised
            if pair is not None:
                return pair[0], pair[1]
        return self.static_tokens(dequantize), self.dynamic_tokens(dequantize)

    def verify(self) -> None:
        """Check every byte: padding is zero, every section's checksum, size, and decoded content
        (including ancillary sections' checksums).  Raises the FormatError subclass of the first problem."""
        end = self._table_end
        for entry in self.sections:
            if any(self._data[end:entry.offset]):
                raise MalformedSectionError(f"padding before section {entry.type} is not zero")
            end = entry.offset + entry.stored_length
            if entry.type not in KNOWN_SECTIONS:
                if crc32(self._data[entry.offset:end]) != entry.crc32:
                    raise ChecksumError(f"ancillary section {entry.type} is damaged (CRC-32 mismatch)")
        if is_learned(self.encoding):
            try:
                self.entropy_tables()
            except EntropyTablesError:  # without the model: every byte but the token codes (FORMAT.md I.6.2)
                _ = (self.cameras, self.extra_cameras)  # decoded and checked
                views = 1 + self.num_extra_cameras
                for name in (SECTION_STATIC, SECTION_DYNAMIC):
                    level, stored = parse_learned_payload(self.raw_section(name))
                    if stored != views:
                        raise MalformedSectionError(f"learned-rans payload of {name} says {stored} encoded cameras; "
                                                    f"the file has {views}")
                self._verified_scene = None
                return
        self._verified_scene = self.to_scene()

    def to_scene(self) -> Scene:
        """Decode everything into a :class:`Scene` (tokens dequantized to float32, writable arrays)."""
        # Every part was validated while decoding (shapes, finiteness, cameras, header), so skip re-checks.
        # Tokens are owned, writable arrays (raw float32 sections would otherwise be read-only views).
        static, dynamic = self.tokens()
        return Scene._from_verified(
            static_tokens=static if static.flags.writeable else static.copy(),
            dynamic_tokens=dynamic if dynamic.flags.writeable else dynamic.copy(), cameras=self.cameras,
            fingerprint=self.fingerprint, metadata=dict(self.metadata), provenance=self.provenance,
            encoding=self.encoding, extra_cameras=self.extra_cameras, quality=self.quality)

    def summary(self) -> dict[str, Any]:
        """A JSON-able overview: format_version, bytes, frames, width, height, static_shape, dynamic_shape,
        encoding, fingerprint (dict), source_capture_id, kind, created_utc, metadata_keys, sections."""
        prov = self.provenance
        cams = self._info.cameras
        return {
            "format_version": f"{self.preamble.major}.{self.preamble.minor}",
            "bytes": self.nbytes,
            "frames": cams.num_frames, "width": cams.width, "height": cams.height,
            "static_shape": list(self.static_shape), "dynamic_shape": list(self.dynamic_shape),
            "encoding": self.encoding,
            **({"quality": self.quality} if is_learned(self.encoding) else {}),
            "fingerprint": self.fingerprint.to_dict(),
            "source_capture_id": None if prov is None else prov.source_capture_id,
            "kind": None if prov is None else prov.kind,
            "created_utc": None if prov is None else prov.created_utc,
            "metadata_keys": sorted(self.metadata),
            "sections": [{"type": e.type, "critical": e.critical, "stored_bytes": e.stored_length,
                          "raw_bytes": e.raw_length, "compression": COMPRESSION_NAMES.get(e.compression, str(e.compression))}
                         for e in self.sections],
        }

    def camera_encoding(self) -> str:
        """"float64" (the 1.0 cameras section) or "compact-float32" / "compact-float64" (I.5.1) /
        "compact-fixed-point" (I.5.4, files with required flag bit 6), read from the checksum-verified section's
        first byte, with "-quaternion" when the poses are quaternions (I.5.2)."""
        if not self.compact_cameras:
            return "float64"
        payload = self.raw_section(SECTION_CAMERAS)
        widths = {4: "compact-float32", 8: "compact-float64", **({0: "compact-fixed-point"} if self.fixed_cameras else {})}
        name = widths.get(payload[0] if len(payload) else -1, "compact-invalid")
        return name + ("-quaternion" if len(payload) > 1 and payload[1] & 4 and self.compact_container else "")

    def __repr__(self) -> str:
        return (f"<SceneFile v{self.preamble.major}.{self.preamble.minor} {self.nbytes} bytes, {self.encoding}, "
                f"Z_s {self.static_shape}, Z_d {self.dynamic_shape}, {self.num_frames} frames>")


def open_scene(source: Any, *, tables: EntropyTables | None = None,
               max_decoded_bytes: int | None = DEFAULT_MAX_DECODED_BYTES, **storage_options: Any) -> SceneFile:
    """Open a scene lazily from a path, fsspec URL, bytes-like object or binary file: the preamble, header
    and section table are parsed and checked now; sections are decoded on access.  ``tables``: the entropy
    tables of a ``learned-rans`` file's model (default: the installed model's, found by fingerprint).
    ``max_decoded_bytes``: the decoded-size budget (FORMAT.md I.7; default 64 MiB, None for none): a scene that
    would decode to more raises LimitExceededError before any section is decompressed.
    ``storage_options`` go to fsspec for a URL."""
    return SceneFile(read_container_bytes(source, **storage_options), tables=tables,
                     max_decoded_bytes=max_decoded_bytes)


def load(source: Any, *, tables: EntropyTables | None = None,
         max_decoded_bytes: int | None = DEFAULT_MAX_DECODED_BYTES, **storage_options: Any) -> Scene:
    """Read and fully validate a scene (path, URL, bytes or binary file): everything
    :meth:`SceneFile.verify` checks, then decode (a ``learned-rans`` file needs its model's tables:
    EntropyTablesError without them).  ``max_decoded_bytes``: as for :func:`open_scene`."""
    f = open_scene(source, tables=tables, max_decoded_bytes=max_decoded_bytes, **storage_options)
    f.verify()
    if f._verified_scene is None:
        f.entropy_tables()  # raises: the tokens cannot be decoded without them
        raise AssertionError("unreachable: verify decoded the tokens whenever the tables are at hand")
    return f._verified_scene


def loads(data: bytes, *, tables: EntropyTables | None = None,
          max_decoded_bytes: int | None = DEFAULT_MAX_DECODED_BYTES) -> Scene:
    """:func:`load` from bytes."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise FormatError(f"loads() takes bytes, got {type(data).__name__}")
    return load(data, tables=tables, max_decoded_bytes=max_decoded_bytes)


def verify(source: Any, *, tables: EntropyTables | None = None,
           max_decoded_bytes: int | None = DEFAULT_MAX_DECODED_BYTES, **storage_options: Any) -> None:
    """Check a whole scene file (path, URL, bytes or binary file); raises the FormatError subclass
    describing the first problem. A ``learned-rans`` file whose model is not at hand is checked except for
    its token codes (FORMAT.md I.6.2).  ``max_decoded_bytes``: as for :func:`open_scene` (a scene over the
    budget raises LimitExceededError)."""
    open_scene(source, tables=tables, max_decoded_bytes=max_decoded_bytes, **storage_options).verify()

