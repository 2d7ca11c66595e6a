"""Joint extra cameras (FORMAT.md I.5.5, format 1.6, required flag bit 9): an ``XCAM`` payload that codes the
fixed-point records (I.5.4) of all its cameras together, as one bit string of Exp-Golomb residuals.

Payload::

    u8   N                    number of cameras, 1..63
    bits (most significant bit of each byte first, zero bits to the end of the last byte):
         18 x u5              the Exp-Golomb order of each residual group
         N x camera           4 layout bits, 3 exponents, intrinsics and pose residuals

Each camera's integers are those of its I.5.4 record (same layout flags, exponents, records, and the same
prediction from the records before), so decoding gives back N I.5.4 records, which are read as I.5.4 says.
What the joint coding adds: residuals cost whole bits instead of whole bytes, the orders are chosen once for
the section (per residual group: a record position 0, 1, 2 or later crossed with quaternion and the three
position values), the exponents are differences from the camera before, and the first intrinsics record is
predicted across cameras (the camera before, when it has the same intrinsics exponent) or from the image
(``fy`` from ``fx``, the principal point at the image centre).
"""

from __future__ import annotations

from collections.abc import Sequence

from ..errors import LimitExceededError, MalformedSectionError
from .compact_cameras import (CENTRE_POSES, CONSTANT_INTRINSICS, CUBIC_PREDICTION, FIXED_POINT, MAX_EXPONENT,
                              QUATERNION_POSES, STATIC_POSE, _fixed_block, _predicted, _read_fixed_ints,
                              _zigzag)
from .limits import MAX_EXTRA_CAMERAS

__all__ = ["GROUPS", "pack_joint_cameras", "unpack_joint_cameras", "joint_camera_count"]

GROUPS = 18          # intrinsics record 0, later intrinsics records, 4 pose positions x (quaternion, x, y, z)
ORDER_BITS = 5       # each group's Exp-Golomb order, 0..31
EXPONENT_BITS = 6    # the first camera's exponents, 0..52
MAX_PREFIX = 58      # a residual of a valid record has z < 2^58 (FORMAT.md I.5.4), so a prefix of <= 58 zeros
_LAYOUT_BITS = (CONSTANT_INTRINSICS, STATIC_POSE, CENTRE_POSES, CUBIC_PREDICTION)  # the 4 stored layout bits


def _group(block: str, r: int, j: int) -> int:
    """The residual group of value ``j`` of record ``r`` of the intrinsics (``"K"``) or pose block."""
    if block == "K":
        return 0 if r == 0 else 1
    return 2 + 4 * min(r, 3) + (0 if j < 4 else j - 3)


def _first_intrinsics(row: list[int], j: int, e_k: int, width: int, height: int,
                      before: tuple[int, list[int]] | None) -> int:
    """The prediction of value j of the first intrinsics record (fx, s, cx, fy, cy) from the values before it
    in the record and, when the camera before has the same exponent e_K, from that camera's first record;
    else from the image: s = 0, cx = (W - 1) / 2, fy = fx, cy = (H - 1) / 2 (fx: 0)."""
    if before is not None and before[0] == e_k:
        prev = before[1]
        return row[0] + prev[3] - prev[0] if j == 3 else prev[j]
    return (0, 0, ((width - 1) << e_k) >> 1, row[0] if row else 0, ((height - 1) << e_k) >> 1)[j]


class _Bits:
    def __init__(self) -> None:
        self.bits: list[int] = []

    def put(self, value: int, n: int) -> None:
        self.bits.extend((value >> (n - 1 - i)) & 1 for i in range(n))

    def exp_golomb(self, z: int, k: int) -> None:
        q = (z >> k) + 1
        self.put(0, q.bit_length() - 1)
        self.put(q, q.bit_length())
        self.put(z & ((1 << k) - 1), k)

    def tobytes(self) -> bytes:
        padded = self.bits + [0] * (-len(self.bits) % 8)
        return int("".join(map(str, padded)) or "0", 2).to_bytes(len(padded) // 8, "big")


def exp_golomb_bits(z: int, k: int) -> int:
    """Bits of the order-k Exp-Golomb code of ``z`` >= 0."""
    return 2 * ((z >> k) + 1).bit_length() - 1 + k


class _Reader:
    def __init__(self, data: bytes) -> None:
        self.data, self.pos, self.end = data, 0, 8 * len(data)

    def get(self, n: int) -> int:
        if self.pos + n > self.end:
            raise MalformedSectionError("joint extra cameras: the bit string ends inside a value")
        value = 0
        for _ in range(n):
            value = (value << 1) | (self.data[self.pos >> 3] >> (7 - (self.pos & 7))) & 1
            self.pos += 1
        return value

    def exp_golomb(self, k: int) -> int:
        zeros = 0
        while not self.get(1):
            zeros += 1
            if zeros > MAX_PREFIX:
                raise MalformedSectionError(f"joint extra cameras: a residual's prefix is longer than {MAX_PREFIX} "
                                            f"zero bits")
        q = ((1 << zeros) | self.get(zeros)) - 1
        return (q << k) | self.get(k)


def _unzigzag(z: int) -> int:
    return z >> 1 if not z & 1 else -(z >> 1) - 1


def _record_ints(record: bytes, T: int) -> tuple[int, tuple[int, int, int], list[list[int]], list[list[int]]] | None:
    """(flags, exponents, intrinsics integers, pose integers) of an I.5.4 record without timestamps or
    distortion, or None when ``record`` is not one (a float record)."""
    if len(record) < 5 or record[0] != FIXED_POINT:
        return None
    flags, exps = record[1], (record[2], record[3], record[4])
    cubic = bool(flags & CUBIC_PREDICTION)
    kv, pos = _read_fixed_ints(record, 5, 1 if flags & CONSTANT_INTRINSICS else T, 5, cubic)
    pv, pos = _read_fixed_ints(record, pos, 1 if flags & STATIC_POSE else T, 7, cubic)
    return (flags, exps, kv, pv) if pos == len(record) else None


def _residuals(cameras: list[tuple[int, tuple[int, int, int], list[list[int]], list[list[int]]]],
               width: int, height: int) -> list[list[tuple[int, int]]]:
    """Per camera, the (group, zigzag residual) of each of its values in coding order."""
    out = []
    before: tuple[int, list[int]] | None = None
    for flags, exps, kv, pv in cameras:
        cubic = bool(flags & CUBIC_PREDICTION)
        values = []
        for block, k in (("K", kv), ("P", pv)):
            for r, row in enumerate(k):
                for j, v in enumerate(row):
                    p = (_first_intrinsics(row[:j], j, exps[0], width, height, before) if block == "K" and r == 0
                         else _predicted(k, r, j, cubic))
                    values.append((_group(block, r, j), _zigzag(v - p)))
        before = (exps[0], kv[0])
        out.append(values)
    return out


def pack_joint_cameras(records: Sequence[bytes], num_frames: int, width: int, height: int) -> bytes | None:
    """The I.5.5 payload of the ``XCAM`` records ``records`` (1..63 I.5.4 records without timestamps or
    distortion, as :func:`~vt4dcodec.format.extra_cameras.pack_extra_cameras` writes them), or None when a
    record is not fixed point (the section then keeps the I.5.3 layout)."""
    if not 1 <= len(records) <= MAX_EXTRA_CAMERAS:
        return None
    cameras = []
    for record in records:
        parsed = _record_ints(bytes(record), num_frames)
        if parsed is None or not parsed[0] & QUATERNION_POSES or parsed[0] & ~(QUATERNION_POSES | sum(_LAYOUT_BITS)):
            return None
        cameras.append(parsed)
    residuals = _residuals(cameras, width, height)
    by_group: list[list[int]] = [[] for _ in range(GROUPS)]
    for values in residuals:
        for group, z in values:
            by_group[group].append(z)
    orders = [min(range(1 << ORDER_BITS), key=lambda k: sum(exp_golomb_bits(z, k) for z in zs)) if zs else 0
              for zs in by_group]
    out = _Bits()
    for k in orders:
        out.put(k, ORDER_BITS)
    previous: tuple[int, int, int] | None = None
    for (flags, exps, _, _), values in zip(cameras, residuals):
        for bit in _LAYOUT_BITS:
            out.put(1 if flags & bit else 0, 1)
        for i, e in enumerate(exps):
            if previous is None:
                out.put(e, EXPONENT_BITS)
            else:
                out.exp_golomb(_zigzag(e - previous[i]), 0)
        previous = exps
        for group, z in values:
            out.exp_golomb(z, orders[group])
    return bytes([len(records)]) + out.tobytes()


def _read_body(bits: _Reader, count: int, num_frames: int, width: int, height: int) -> list[bytes]:
    """The group orders and ``count`` cameras of an I.5.5 body from ``bits``, as I.5.4 records."""
    orders = [bits.get(ORDER_BITS) for _ in range(GROUPS)]
    records = []
    before: tuple[int, list[int]] | None = None
    previous: tuple[int, int, int] | None = None
    for _ in range(count):
        flags = QUATERNION_POSES | sum(bit for bit in _LAYOUT_BITS if bits.get(1))
        if previous is None:
            e3 = (bits.get(EXPONENT_BITS), bits.get(EXPONENT_BITS), bits.get(EXPONENT_BITS))
        else:
            e3 = (previous[0] + _unzigzag(bits.exp_golomb(0)), previous[1] + _unzigzag(bits.exp_golomb(0)),
                  previous[2] + _unzigzag(bits.exp_golomb(0)))
        if not all(0 <= e <= MAX_EXPONENT for e in e3):
            raise MalformedSectionError(f"joint extra cameras: an exponent is outside 0..{MAX_EXPONENT}")
        cubic = bool(flags & CUBIC_PREDICTION)
        blocks: list[list[list[int]]] = []
        for block, n, m in (("K", 1 if flags & CONSTANT_INTRINSICS else num_frames, 5),
                            ("P", 1 if flags & STATIC_POSE else num_frames, 7)):
            k: list[list[int]] = []
            for r in range(n):
                row: list[int] = []
                for j in range(m):
                    p = (_first_intrinsics(row, j, e3[0], width, height, before) if block == "K" and r == 0
                         else _predicted(k + [row], r, j, cubic))
                    row.append(p + _unzigzag(bits.exp_golomb(orders[_group(block, r, j)])))
                    if abs(row[-1]) > 1 << 53:
                        raise MalformedSectionError("joint extra cameras: a fixed-point value exceeds 2^53")
                k.append(row)
            blocks.append(k)
        before, previous = (e3[0], blocks[0][0]), e3
        records.append(bytes([FIXED_POINT, flags, *e3]) + _fixed_block(blocks[0], cubic) + _fixed_block(blocks[1], cubic))
    return records


def joint_camera_count(raw: bytes) -> int:
    """The count byte N of an I.5.5 payload, checked: MalformedSectionError for an empty payload or N = 0,
    LimitExceededError above 63."""
    if not raw or raw[0] == 0:
        raise MalformedSectionError("joint extra cameras: the section holds 0 trajectories or is empty")
    if raw[0] > MAX_EXTRA_CAMERAS:
        raise LimitExceededError(f"joint extra cameras: the section holds {raw[0]} trajectories; the limit is "
                                 f"{MAX_EXTRA_CAMERAS}")
    return int(raw[0])


def unpack_joint_cameras(raw: bytes, num_frames: int, width: int, height: int) -> list[bytes]:
    """The I.5.4 records an I.5.5 payload codes (each then read as I.5.4 says); MalformedSectionError for a
    count of 0, a bit string that ends inside a value, an exponent above 52, a prefix of more than 58 zeros, a
    value beyond 2^53, non-zero padding or bytes after it (LimitExceededError for a count above 63)."""
    raw = bytes(raw)
    count = joint_camera_count(raw)
    bits = _Reader(raw[1:])
    records = _read_body(bits, count, num_frames, width, height)
    padding = bits.end - bits.pos
    if padding >= 8:
        raise MalformedSectionError(f"joint extra cameras: {padding // 8} byte(s) follow the bit string")
    if padding and bits.get(padding):
        raise MalformedSectionError("joint extra cameras: the padding after the bit string is not zero")
    return records
