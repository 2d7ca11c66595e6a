"""The extra cameras section ``XCAM`` (FORMAT.md I.5.3, format 1.4, required flag bit 3): the trajectories of
the further cameras of a multi-camera encode, in encoding order (the first encoded camera is ``CAMS``).

Raw payload (little-endian)::

    u8   N                 number of trajectories, 1..63
    u32  length[N]         bytes of each record
    record[0] .. record[N-1], back to back, exactly length[i] bytes each

Each record is one trajectory's ``K`` and ``w2c`` in the encoding the file uses for ``CAMS``: with required
flag bit 1 a compact cameras payload (I.5.1; quaternion poses, I.5.2, in a compact container) without
distortion or timestamps, else the I.5 float64 ``K`` then ``w2c``.  Every record shares the header's frame
count and image size and ``CAMS``' timestamps; extra cameras carry no distortion.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from ..cameras import Trajectory
from ..errors import FormatError, LimitExceededError, MalformedSectionError
from .compact_cameras import pack_compact_cameras, unpack_compact_cameras
from .header import CameraLayout
from .joint_cameras import joint_camera_count, pack_joint_cameras, unpack_joint_cameras
from .layout import BytesLike
from .limits import MAX_EXTRA_CAMERAS
from .sections import SECTION_EXTRA_CAMERAS, pack_cameras, unpack_cameras

__all__ = ["SECTION_EXTRA_CAMERAS", "pack_extra_cameras", "unpack_extra_cameras", "extra_camera_records",
           "extra_cameras_max_raw_length", "joint_extra_cameras", "extra_camera_count"]


def extra_cameras_max_raw_length(num_frames: int) -> int:
    """The most raw bytes an ``XCAM`` section can hold for ``num_frames`` frames: 63 records of the I.5
    float64 ``K`` and ``w2c`` (a compact record is never longer), checked before anything is decompressed."""
    return 1 + MAX_EXTRA_CAMERAS * (4 + 8 * 25 * num_frames)


def pack_extra_cameras(extras: Sequence[Trajectory], mode: str = "compact", *, quaternions: bool = False,
                       fixed: bool = False) -> bytes:
    """The ``XCAM`` payload of ``extras`` (1..63 trajectories), each record encoded as ``CAMS`` is for the
    same ``save(cameras=mode)``: ``"legacy"`` the I.5 float64 ``K`` and ``w2c``; ``"compact"`` / ``"exact"`` a
    compact cameras payload (:func:`pack_compact_cameras`, ``quaternions`` in a compact container).
    Distortion and timestamps are not stored (the scene has none and ``CAMS``' for its extra cameras)."""
    if not 1 <= len(extras) <= MAX_EXTRA_CAMERAS:
        raise FormatError(f"an extra cameras section holds 1 to {MAX_EXTRA_CAMERAS} trajectories, got {len(extras)}")
    records = []
    for traj in extras:
        bare = traj if traj.timestamps is None and traj.distortion is None else replace(
            traj, timestamps=None, distortion=None)
        records.append(pack_cameras(bare)[1] if mode == "legacy" else
                       pack_compact_cameras(bare, mode, quaternions=quaternions, fixed=fixed))
    return bytes([len(records)]) + struct.pack(f"<{len(records)}I", *map(len, records)) + b"".join(records)


def joint_extra_cameras(payload: bytes, num_frames: int, width: int, height: int) -> bytes | None:
    """The joint layout (I.5.5, required flag bit 9) of an I.5.3 ``XCAM`` payload whose records are all fixed
    point, or None when one is not."""
    records = [bytes(payload[offset:offset + length]) for offset, length in extra_camera_records(payload)]
    return pack_joint_cameras(records, num_frames, width, height)


def extra_camera_count(raw: BytesLike, *, joint: bool = False) -> int:
    """How many trajectories an ``XCAM`` payload holds: its count after checking the length table (I.5.3), or
    with ``joint`` (required flag bit 9) the count byte of the I.5.5 layout; nothing is decoded."""
    return joint_camera_count(bytes(raw[:1])) if joint else len(extra_camera_records(raw))


def extra_camera_records(raw: BytesLike) -> list[tuple[int, int]]:
    """(offset, length) of each record of an ``XCAM`` payload, after checking its count and length table:
    ``N`` in 1..63 (``LimitExceededError`` above), the table inside the payload, the lengths adding up to
    exactly the rest of it.  Nothing is decoded."""
    if len(raw) < 1:
        raise MalformedSectionError("extra cameras section is 0 bytes; it needs at least its count byte")
    count = raw[0]
    if count == 0:
        raise MalformedSectionError("extra cameras section holds 0 trajectories (the section is present only "
                                    "with at least one)")
    if count > MAX_EXTRA_CAMERAS:
        raise LimitExceededError(f"extra cameras section holds {count} trajectories; the limit is {MAX_EXTRA_CAMERAS}")
    start = 1 + 4 * count
    if len(raw) < start:
        raise MalformedSectionError(f"extra cameras section is {len(raw)} bytes, too short for the lengths of "
                                    f"its {count} records ({start} bytes)")
    lengths = struct.unpack_from(f"<{count}I", raw, 1)
    if sum(lengths) != len(raw) - start:
        raise MalformedSectionError(f"extra cameras records add up to {sum(lengths)} bytes but the section holds "
                                    f"{len(raw) - start} after its length table")
    out, pos = [], start
    for length in lengths:
        out.append((pos, length))
        pos += length
    return out


def _decode_record(record: BytesLike, index: int, layout: CameraLayout, timestamps: np.ndarray | None, *,
                   compact_cameras: bool, quaternions: bool, fixed: bool = False) -> Trajectory:
    bare = CameraLayout(layout.num_frames, layout.width, layout.height, 0, False)
    try:
        traj = (unpack_compact_cameras(record, bare, quaternions=quaternions, fixed=fixed) if compact_cameras
                else unpack_cameras(record, bare))
    except MalformedSectionError as exc:
        raise MalformedSectionError(f"extra camera {index} (XCAM record {index}): {exc}") from None
    return traj if timestamps is None else replace(traj, timestamps=timestamps)


def unpack_extra_cameras(raw: BytesLike, layout: CameraLayout, timestamps: np.ndarray | None, *,
                         compact_cameras: bool, quaternions: bool = False, fixed: bool = False,
                         joint: bool = False, index: int | None = None) -> tuple[Trajectory, ...]:
    """Decode an ``XCAM`` payload: every trajectory, or with ``index`` that one alone (after checking the
    count and length table).  ``compact_cameras``: required flag bit 1 (records are I.5.1 payloads);
    ``quaternions``: a compact container (layout flag bit 2 allowed); ``timestamps``: ``CAMS``' own, which
    every extra camera shares; ``joint``: required flag bit 9, the I.5.5 layout (decoded whole, then the
    records it gives are read as I.5.4 records).  Any problem is a MalformedSectionError (LimitExceededError for
    N over 63)."""
    if joint:
        coded = unpack_joint_cameras(bytes(raw), layout.num_frames, layout.width, layout.height)
        if index is not None and not 0 <= index < len(coded):
            raise FormatError(f"extra camera {index} does not exist: the file holds {len(coded)}")
        return tuple(_decode_record(coded[i], i, layout, timestamps, compact_cameras=True, quaternions=True,
                                    fixed=True) for i in (range(len(coded)) if index is None else [index]))
    records = extra_camera_records(raw)
    view = memoryview(raw)
    chosen = range(len(records)) if index is None else [index]
    if index is not None and not 0 <= index < len(records):
        raise FormatError(f"extra camera {index} does not exist: the file holds {len(records)}")
    return tuple(_decode_record(view[records[i][0]:records[i][0] + records[i][1]], i, layout, timestamps,
                                compact_cameras=compact_cameras, quaternions=quaternions, fixed=fixed)
                 for i in chosen)
