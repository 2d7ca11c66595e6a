"""Compact cameras (FORMAT.md I.5.1, format 1.2, required flag bit 1): the cameras section with one
intrinsics record for a constant K and one pose for a static camera, float32 (or float64) values,
each record predicted from the one before and stored byte plane by byte plane, so the section's zstd
frame finds the runs that smooth trajectories leave.

Payload (little-endian)::

    u8  precision P      4 (float32) or 8 (float64)
    u8  layout flags     bit 0: one intrinsics record for every frame; bit 1: one pose for every frame;
                         bit 2 (format 1.3, compact containers only): poses as quaternion + translation
    intrinsics block     nK records of (fx, s, cx, fy, cy), predicted + byte planes (below)
    pose block           nP records of w2c rows 0..2 (12 values, row-major), or with bit 2 of
                         (qw, qx, qy, qz, tx, ty, tz) (7 values), predicted + byte planes
    distortion           distortion_terms float64 (as in 1.0)
    timestamps           T float64 if has_timestamps (as in 1.0)

A block of n records of m values: let u[r, j] be the P-byte unsigned integer whose bytes are value j of
record r.  The writer stores e[0, j] = u[0, j] and e[r, j] = (u[r, j] - u[r-1, j]) mod 2^(8P); then
byte k of every e (row-major order) for k = 0, then k = 1, ... (byte planes).  The reader inverts both.

Quaternion poses (FORMAT.md I.5.2): R is rebuilt from (qw, qx, qy, qz) widened to float64 by one fixed
formula (:func:`quaternion_to_rotation`), so every reader computes the same bits; a rotation costs 4 values
instead of 9, which is what brings a default 8-frame scene's non-token bytes under 512.

Fixed-point records (FORMAT.md I.5.4, format 1.6, required flag bit 6): P = 0, integers k * 2^-e predicted
from the records before them, zigzag varint residuals.  Their layout flags may also set bit 3 (the pose
stores the camera centre c, and t = -R c by :func:`centre_translation`: the rotation's rounding error is then
not multiplied by the distance from the world origin, so coarser steps keep the 0.01 px bound), bit 4
(cubic prediction 3 k[r-1] - 3 k[r-2] + k[r-3], which smooth trajectories leave near zero) and bit 5 (the
timestamps as one exponent and predicted varints, for timestamps that are all exactly k * 2^-e).
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from ..cameras import Trajectory
from ..errors import CameraError, FormatError, MalformedSectionError
from .header import CameraLayout
from .layout import BytesLike

__all__ = ["CAMERA_MODES", "COMPACT_PRECISIONS", "REPROJECTION_TOLERANCE_PX", "pack_compact_cameras",
           "unpack_compact_cameras", "compact_camera_bytes", "reprojection_change", "quaternion_to_rotation",
           "rotation_to_quaternion", "canonical_float32_quaternions", "centre_translation", "fixed_exponents"]

CAMERA_MODES = ("compact", "exact", "legacy")  # what save() offers: see writer.dumps
COMPACT_PRECISIONS = (4, 8)
FIXED_POINT = 0  # P = 0 (format 1.6, required flag bit 6): fixed-point values, predicted, varint residuals
MAX_EXPONENT = 52  # a fixed-point value is k * 2^-e, |k| <= 2^53 (exact in binary64)
CONSTANT_INTRINSICS, STATIC_POSE, QUATERNION_POSES = 1 << 0, 1 << 1, 1 << 2
KNOWN_LAYOUT_FLAGS = CONSTANT_INTRINSICS | STATIC_POSE  # and QUATERNION_POSES in compact containers (1.3)
# fixed-point records only (format 1.6, FORMAT.md I.5.4); in P = 4 / 8 records bits 3..7 stay reserved
CENTRE_POSES, CUBIC_PREDICTION, FIXED_TIMESTAMPS = 1 << 3, 1 << 4, 1 << 5
FIXED_LAYOUT_FLAGS = (KNOWN_LAYOUT_FLAGS | QUATERNION_POSES | CENTRE_POSES | CUBIC_PREDICTION
                      | FIXED_TIMESTAMPS)
INTRINSIC_VALUES, POSE_VALUES, QUATERNION_POSE_VALUES = 5, 12, 7
REPROJECTION_TOLERANCE_PX = 0.01  # float32 is used only when no probe point moves more than this
PROBE_DEPTHS_M = (0.1, 1.0, 10.0, 100.0)  # the reference writer's probe points (FORMAT.md I.5.1)
PROBE_GRID = 5

_UINT: dict[int, np.dtype[Any]] = {4: np.dtype("<u4"), 8: np.dtype("<u8")}
_FLOAT: dict[int, np.dtype[Any]] = {4: np.dtype("<f4"), 8: np.dtype("<f8")}


def _intrinsic_records(K: np.ndarray) -> np.ndarray:
    return np.stack([K[:, 0, 0], K[:, 0, 1], K[:, 0, 2], K[:, 1, 1], K[:, 1, 2]], axis=1)


def _pack_block(records: np.ndarray, precision: int) -> bytes:
    values = np.ascontiguousarray(records, dtype=_FLOAT[precision])
    u = values.view(_UINT[precision])
    e = u.copy()
    e[1:] = u[1:] - u[:-1]  # unsigned arithmetic wraps mod 2^(8P)
    planes = e.reshape(-1).view(np.uint8).reshape(-1, precision).T
    return np.ascontiguousarray(planes).tobytes()


def _unpack_block(raw: bytes, records: int, values: int, precision: int) -> np.ndarray:
    planes = np.frombuffer(raw, dtype=np.uint8).reshape(precision, records * values)
    e = np.ascontiguousarray(planes.T).reshape(-1).view(_UINT[precision]).reshape(records, values)
    u: np.ndarray = np.cumsum(e, axis=0, dtype=_UINT[precision])  # wraps mod 2^(8P), inverting the difference
    with np.errstate(invalid="ignore"):  # a signalling NaN widens quietly; the camera checks refuse any NaN
        out: np.ndarray = u.view(_FLOAT[precision]).astype(np.float64)
    return out


def _flags(traj: Trajectory) -> int:
    flags = 0
    if (traj.K == traj.K[:1]).all():  # the values are finite (a Trajectory checks), so == is array equality
        flags |= CONSTANT_INTRINSICS
    if (traj.w2c == traj.w2c[:1]).all():
        flags |= STATIC_POSE
    return flags


def _pose_values(flags: int) -> int:
    return QUATERNION_POSE_VALUES if flags & QUATERNION_POSES else POSE_VALUES


def compact_camera_bytes(T: int, precision: int, flags: int, distortion_terms: int, has_timestamps: bool) -> int:
    """The raw length of a compact cameras section."""
    n_k = 1 if flags & CONSTANT_INTRINSICS else T
    n_p = 1 if flags & STATIC_POSE else T
    return 2 + precision * (INTRINSIC_VALUES * n_k + _pose_values(flags) * n_p) + 8 * (
        distortion_terms + (T if has_timestamps else 0))


_native_rotations: Callable[[np.ndarray, np.ndarray], bool | None] | None
_native_quaternions: Callable[[np.ndarray, bool, np.ndarray], bool | None] | None
try:  # the compiled formulas (vt4dcodec.format._rans_native; absent: numpy's, the same bits)
    from . import _rans_native as _compiled
    _native_rotations = _compiled.quaternions_to_rotations
    _native_quaternions = _compiled.rotations_to_quaternions
    _native_valid: Callable[[np.ndarray, np.ndarray, Any], bool] | None = _compiled.cameras_valid
except ImportError:  # pragma: no cover - a build without the extension
    _native_rotations = _native_quaternions = _native_valid = None


def quaternion_to_rotation(q: np.ndarray) -> np.ndarray:
    """(n, 4) quaternions (w, x, y, z), float64, any non-zero norm -> (n, 3, 3) rotations, by FORMAT.md I.5.2's
    formula, operation for operation (every step is one IEEE 754 binary64 operation, so readers agree)."""
    if _native_rotations is not None and len(q):
        R = np.empty((len(q), 3, 3))
        if _native_rotations(np.ascontiguousarray(q, dtype=np.float64), R):  # the same formula in C
            return R
    w, x, y, z = (np.ascontiguousarray(q[:, i], dtype=np.float64) for i in range(4))
    with np.errstate(all="ignore"):  # a zero or overflowing norm gives inf/NaN, rejected by the caller's checks
        s = 2.0 / (((w * w + x * x) + y * y) + z * z)
        R = np.empty((len(q), 3, 3))
        R[:, 0, 0] = 1.0 - s * (y * y + z * z)
        R[:, 0, 1] = s * (x * y - w * z)
        R[:, 0, 2] = s * (x * z + w * y)
        R[:, 1, 0] = s * (x * y + w * z)
        R[:, 1, 1] = 1.0 - s * (x * x + z * z)
        R[:, 1, 2] = s * (y * z - w * x)
        R[:, 2, 0] = s * (x * z - w * y)
        R[:, 2, 1] = s * (y * z + w * x)
        R[:, 2, 2] = 1.0 - s * (x * x + y * y)
    return R


def rotation_to_quaternion(R: np.ndarray, *, continuous: bool = True) -> np.ndarray:
    """(n, 3, 3) rotations -> (n, 4) unit quaternions (w, x, y, z) (informative: any writer method will do).
    Shepperd's method, from the largest of w, x, y, z (the first of the trace, R00, R11, R22 that is largest),
    normalised by the square root of ((w^2 + x^2) + y^2) + z^2 summed in that order.  ``continuous``: each sign
    is chosen so consecutive quaternions are close (q and -q are the same rotation: a negative dot product with
    the one before flips it), which keeps the predicted differences small; else each is signed on its own (a
    negative w flips it).  Vectorised: every value is the same binary64 operations for every rotation."""
    m = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    if _native_quaternions is not None and len(m):
        q_out = np.empty((len(m), 4))
        if _native_quaternions(np.ascontiguousarray(m), continuous, q_out):  # the same operations in C
            return q_out
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = (m[:, i, j] for i in range(3) for j in range(3))
    trace = (m00 + m11) + m22
    k = np.argmax(np.stack([trace, m00, m11, m22], axis=1), axis=1)
    with np.errstate(all="ignore"):  # every branch is computed for every rotation; only the chosen one is kept
        w = 0.5 * np.sqrt(np.maximum(1.0 + trace, 0.0))
        x = 0.5 * np.sqrt(np.maximum(((1.0 + m00) - m11) - m22, 0.0))
        y = 0.5 * np.sqrt(np.maximum(((1.0 - m00) + m11) - m22, 0.0))
        z = 0.5 * np.sqrt(np.maximum(((1.0 - m00) - m11) + m22, 0.0))
        branches = np.stack([
            np.stack([w, (m21 - m12) / (4 * w), (m02 - m20) / (4 * w), (m10 - m01) / (4 * w)], axis=1),
            np.stack([(m21 - m12) / (4 * x), x, (m01 + m10) / (4 * x), (m02 + m20) / (4 * x)], axis=1),
            np.stack([(m02 - m20) / (4 * y), (m01 + m10) / (4 * y), y, (m12 + m21) / (4 * y)], axis=1),
            np.stack([(m10 - m01) / (4 * z), (m02 + m20) / (4 * z), (m12 + m21) / (4 * z), z], axis=1)])
        q = branches[k, np.arange(len(m))]
        norm = np.sqrt(((q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1]) + q[:, 2] * q[:, 2]) + q[:, 3] * q[:, 3])
        v = q / norm[:, None]
    flip = v[:, 0] < 0  # against (1, 0, 0, 0): the first record, and every record when not continuous
    if continuous and len(v) > 1:
        dots = (((v[1:, 0] * v[:-1, 0] + v[1:, 1] * v[:-1, 1]) + v[1:, 2] * v[:-1, 2]) + v[1:, 3] * v[:-1, 3]).tolist()
        for i, dot in enumerate(dots, start=1):  # flipped when its dot with the (signed) record before is negative
            flip[i] = (-dot if flip[i - 1] else dot) < 0
    out: np.ndarray = np.where(flip[:, None], -v, v)
    return out


# the 81 float32 neighbours (each component -1, 0 or +1 ulp) of a quaternion, nearest first, in a fixed order
_NEIGHBOURS = np.array(sorted(itertools.product((-1, 0, 1), repeat=4), key=lambda k: (sum(map(abs, k)), k)),
                       dtype=np.int32)


def _float32(q: np.ndarray) -> np.ndarray:
    return np.asarray(q, dtype=np.float32).astype(np.float64) + 0.0  # + 0.0: never -0.0


def _exact_float32_quaternions(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each rotation, the first float32 quaternion near its own that rebuilds it exactly (FORMAT.md I.5.2
    formula), and whether there was one: (quaternions (n, 4), found (n,))."""
    centre = _float32(rotation_to_quaternion(R, continuous=False))
    found = np.all(quaternion_to_rotation(centre) == R, axis=(1, 2))
    q = centre.copy()
    miss = np.flatnonzero(~found)
    if len(miss):
        bits = centre[miss].astype(np.float32).view(np.int32)
        candidates = _float32((bits[:, None, :] + _NEIGHBOURS[None]).view(np.float32))  # (m, 81, 4)
        rebuilt = quaternion_to_rotation(candidates.reshape(-1, 4)).reshape(len(miss), len(_NEIGHBOURS), 3, 3)
        hit = np.all(rebuilt == R[miss][:, None], axis=(2, 3))
        first = np.argmax(hit, axis=1)
        ok = hit[np.arange(len(miss)), first]
        q[miss[ok]] = candidates[ok, first[ok]]
        found[miss[ok]] = True
    return q, found


def canonical_float32_quaternions(R: np.ndarray) -> np.ndarray | None:
    """float32 quaternions (as float64 values) for the rotations ``R``, chosen so that the writer finds the
    same ones again from the rotations they decode to: loading a file and saving it again gives the same
    bytes, and resaving never drifts.  A rotation some nearby float32 quaternion rebuilds exactly (one read
    from a 1.3 file) keeps that quaternion; any other is rounded to float32 and then replaced by the first
    quaternion that rebuilds the rounded one's rotation exactly.  Signs follow from frame to frame.  None in
    the (unseen so far) case where no such quaternion is found: the writer then keeps matrices."""
    R = np.asarray(R, dtype=np.float64)
    q, found = _exact_float32_quaternions(R)
    if not found.all():
        rounded = quaternion_to_rotation(_float32(rotation_to_quaternion(R[~found], continuous=False)))
        q_rounded, found_rounded = _exact_float32_quaternions(rounded)
        if not found_rounded.all():
            return None
        q[~found] = q_rounded
    flip = _follow_signs(q)  # q and -q rebuild the same rotation: keep consecutive records close
    q[flip] = -q[flip] + 0.0
    return q


def _follow_signs(q: np.ndarray) -> np.ndarray:
    """Which quaternions to negate so that each one's dot product with the (possibly negated) one before it is
    not negative: record i is negated when ``s * (q[i] . q[i-1]) < 0``, ``s`` = -1 if record i - 1 was negated
    (the rule of the one-at-a-time loop ``if q[i] @ q[i-1] < 0: q[i] = -q[i]``, whose bits the writer keeps).
    Between dot products that are 0 (which reset the chain) the negations follow the parity of the negative
    dot products; dot products within 1e-9 of 0, whose sign could hang on the summation order, are summed
    as that loop sums them."""
    n = len(q)
    flip = np.zeros(n, dtype=bool)
    if n < 2:
        return flip
    dots = np.einsum("ij,ij->i", q[1:], q[:-1])
    near = np.flatnonzero(np.abs(dots) < 1e-9)
    for i in near.tolist():
        dots[i] = float(q[i + 1] @ q[i])
    negative = np.concatenate([[0], np.cumsum(dots < 0)])  # negative dot products up to each record
    reset = np.concatenate([[True], ~(dots < 0) & ~(dots > 0)])  # a 0 (or NaN) dot: that record is not negated
    since = np.maximum.accumulate(np.where(reset, np.arange(n), 0))
    flip[:] = (negative - negative[since]) % 2 == 1
    return flip


def _encode(traj: Trajectory, precision: int, quaternions: np.ndarray | None = None) -> bytes:
    """The payload; ``quaternions`` (one per pose record kept) stores the poses as quaternion + t."""
    flags = _flags(traj) | (QUATERNION_POSES if quaternions is not None else 0)
    K = traj.K[:1] if flags & CONSTANT_INTRINSICS else traj.K
    w2c = traj.w2c[:1] if flags & STATIC_POSE else traj.w2c
    if quaternions is not None:
        poses = np.concatenate([quaternions, w2c[:, :3, 3]], axis=1)
    else:
        poses = w2c[:, :3, :].reshape(len(w2c), POSE_VALUES)
    parts = [bytes([precision, flags]), _pack_block(_intrinsic_records(K), precision), _pack_block(poses, precision)]
    for extra in (traj.distortion, traj.timestamps):
        if extra is not None:
            parts.append(np.ascontiguousarray(extra, dtype="<f8").tobytes())
    return b"".join(parts)


def _zigzag(v: int) -> int:
    return 2 * v if v >= 0 else -2 * v - 1


def _varint(v: int) -> bytes:
    out = bytearray()
    while v >= 0x80:
        out.append((v & 0x7F) | 0x80)
        v >>= 7
    out.append(v)
    return bytes(out)


def _predicted(k: list[list[int]], r: int, j: int, cubic: bool = False) -> int:
    """The prediction of value j of record r from the records before it: 0, the previous value, the linear
    extrapolation 2 k[r-1] - k[r-2], or with ``cubic`` (layout flag bit 4) from r = 3 on the quadratic one
    3 k[r-1] - 3 k[r-2] + k[r-3] (FORMAT.md I.5.4)."""
    if r == 0:
        return 0
    if r == 1:
        return k[0][j]
    if r == 2 or not cubic:
        return 2 * k[r - 1][j] - k[r - 2][j]
    return 3 * (k[r - 1][j] - k[r - 2][j]) + k[r - 3][j]


def _fixed_block(k: list[list[int]], cubic: bool = False) -> bytes:
    """Fixed-point integers, each predicted from the records before it, residuals zigzag LEB128, row-major."""
    return b"".join(_varint(_zigzag(v - _predicted(k, r, j, cubic)))
                    for r, row in enumerate(k) for j, v in enumerate(row))


def _read_fixed_ints(raw: bytes, pos: int, records: int, values: int,
                     cubic: bool = False) -> tuple[list[list[int]], int]:
    """Inverse of :func:`_fixed_block`: the integers of ``records`` records of ``values`` values from ``pos``,
    and the position after them; MalformedSectionError for a varint that runs past the payload, is longer than
    10 bytes or ends in a zero group, or a value beyond 2^53."""
    k: list[list[int]] = []
    for r in range(records):
        row: list[int] = []
        for j in range(values):
            value = shift = 0
            while True:
                if pos >= len(raw):
                    raise MalformedSectionError("compact cameras: a fixed-point varint runs past the section")
                byte = raw[pos]
                pos += 1
                value |= (byte & 0x7F) << shift
                shift += 7
                if byte < 0x80:
                    break
                if shift >= 70:
                    raise MalformedSectionError("compact cameras: a fixed-point varint is longer than 10 bytes")
            if byte == 0 and shift > 7:
                raise MalformedSectionError("compact cameras: a fixed-point varint ends in a zero group")
            row.append(_predicted(k + [row], r, j, cubic) + (value >> 1 if not value & 1 else -(value >> 1) - 1))
            if abs(row[-1]) > 1 << 53:
                raise MalformedSectionError("compact cameras: a fixed-point value exceeds 2^53")
        k.append(row)
    return k, pos


def _read_fixed_block(raw: bytes, pos: int, records: int, exponents: list[int],
                      cubic: bool = False) -> tuple[np.ndarray, int]:
    """:func:`_read_fixed_ints` and the scaling k * 2^-e of each value by the exponent of its column."""
    k, pos = _read_fixed_ints(raw, pos, records, len(exponents), cubic)
    values = np.array([[v * 2.0 ** -e for v, e in zip(row, exponents)] for row in k], dtype=np.float64)
    return values.reshape(records, len(exponents)), pos


def centre_translation(R: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations and (n, 3) camera centres -> (n, 3) translations t = -R c, by FORMAT.md I.5.4's
    formula, operation for operation: t_i = 0 - ((R_i0 c_0 + R_i1 c_1) + R_i2 c_2), every product, sum and
    difference one binary64 operation (numpy's elementwise operations never fuse), so every reader gets the
    same bits (0 - x is -x, except that a zero translation comes out +0, never -0)."""
    R, c = np.asarray(R, dtype=np.float64), np.asarray(c, dtype=np.float64)
    with np.errstate(all="ignore"):  # a NaN rotation (zero quaternion) is rejected by the caller's checks
        out: np.ndarray = 0.0 - ((R[:, :, 0] * c[:, 0:1] + R[:, :, 1] * c[:, 1:2]) + R[:, :, 2] * c[:, 2:3])
    return out


def fixed_exponents(traj: Trajectory, *, centre: bool = False) -> tuple[int, int, int]:
    """The reference writer's exponents (e_K, e_R, e_t) for a trajectory: steps small enough that rounding
    moves no probe point (depths down to 0.1 m) by more than a few thousandths of a pixel, from the image size
    and the largest focal length (in powers of two, so a decoded trajectory gives the same exponents).
    ``centre``: the poses store camera centres (layout flag bit 3), whose rotation error is not multiplied by
    the camera's distance from the world origin, so the quaternion and position steps are 16 and 4 times
    coarser."""
    side = max(traj.width, traj.height)
    f = float(np.abs(traj.K[:, :2, :2]).max())
    log_f = max(0, int(np.floor(np.log2(max(f, 1.0)))) + 1)  # f < 2^log_f
    log_side = int(np.ceil(np.log2(side)))
    if centre:
        # K: a half step 2^-(e_K + 1) moves the principal point by 2^-(log_side + 3) px (0.002 px at 64 px) and an
        # edge pixel by (W / 2) / f times that through the focal length
        e_k = log_side + 2
        e_r = log_f + 9   # quaternion: the rotation error, times f < 2^log_f px, about 0.002-0.004 px
        e_t = log_f + 11  # centre: step / 2 at 0.1 m, times f: < 0.0025 px
    else:  # the fallback keeps its finer steps: its rotation error is already near the bound
        e_k = log_side + 9
        e_r = log_f + 13  # quaternion: the rotation error, times f and |c| / 0.1 m, stays near 0.002 px
        e_t = log_f + 13  # translation: step / 2 at 0.1 m, times f
    return min(e_k, MAX_EXPONENT), min(e_r, MAX_EXPONENT), min(e_t, MAX_EXPONENT)


def _grid_quaternions(q: np.ndarray, e: int) -> list[list[int]]:
    """Integer quaternions k (k * 2^-e ~ q) that are fixed points of normalise-and-round, so that the rotation
    they decode to gives the same integers again (a saved file saves to the same bytes).  Their signs (q and -q
    are one rotation) follow from the integers alone: each record's dot product with the one before it is
    positive, and where there is none (the first record) or it is 0, the first non-zero component is positive
    -- so a rotation of half a turn (w = 0), whose float quaternion's sign hangs on rounding, is stored the
    same way again from the rotation it decodes to."""
    out: list[list[int]] = []
    for row in q:
        k = [int(round(float(v) * 2.0 ** e)) for v in row]
        for _ in range(8):
            norm = float(np.sqrt(sum(float(v) ** 2 for v in k))) * 2.0 ** -e
            nxt = [int(round(v / norm)) for v in k]
            if nxt == k:
                break
            k = nxt
        dot = sum(a * b for a, b in zip(k, out[-1])) if out else 0
        if dot < 0 or (dot == 0 and next((v for v in k if v), 0) < 0):
            k = [-v for v in k]
        out.append(k)
    return out


def _dyadic(values: np.ndarray) -> tuple[int, list[int]] | None:
    """(e, k) with every value exactly k * 2^-e, e the smallest such exponent (at most 52) and |k| <= 2^53; None
    when the values are not all of that form (timestamps of a 30 fps clock, say)."""
    if np.any(np.signbit(values) & (values == 0)):
        return None  # -0.0 would read back as +0.0
    ratios = [float(v).as_integer_ratio() for v in values]  # finite floats: the denominator is a power of two
    e = max((den.bit_length() - 1 for _, den in ratios), default=0)
    if e > MAX_EXPONENT:
        return None
    k = [num << (e - (den.bit_length() - 1)) for num, den in ratios]
    return (e, k) if all(abs(v) <= 1 << 53 for v in k) else None


def _encode_fixed(traj: Trajectory, *, centre: bool = False, cubic: bool | None = None,
                  fixed_timestamps: bool = True) -> bytes | None:
    """The P = 0 payload (FORMAT.md I.5.4): quaternion poses, with ``centre`` camera centres in place of
    translations (layout flag bit 3), exponents from :func:`fixed_exponents`; cubic prediction (bit 4) when it
    makes the payload shorter, and the timestamps in fixed point (bit 5) when they are all exactly k * 2^-e and
    that is shorter.  Both choices depend on the stored integers only, so a decoded trajectory makes them
    again.  None when a value is beyond 2^53 steps.  (``cubic`` True / False and ``fixed_timestamps=False``
    force those choices, for measurements.)"""
    flags = _flags(traj) | QUATERNION_POSES | (CENTRE_POSES if centre else 0)
    K = traj.K[:1] if flags & CONSTANT_INTRINSICS else traj.K
    w2c = traj.w2c[:1] if flags & STATIC_POSE else traj.w2c
    e_k, e_r, e_t = fixed_exponents(traj, centre=centre)
    q = _grid_quaternions(rotation_to_quaternion(w2c[:, :3, :3]), e_r)
    position = w2c[:, :3, 3]
    if centre:  # c = -R^-1 t (the exact inverse, as the probe points are lifted)
        with np.errstate(all="ignore"):
            position = -np.linalg.solve(w2c[:, :3, :3], position[:, :, None])[:, :, 0]
        if not np.isfinite(position).all():
            return None
    k_int = [[int(round(float(v) * 2.0 ** e_k)) for v in row] for row in _intrinsic_records(K)]
    poses = [qr + [int(round(float(v) * 2.0 ** e_t)) for v in p] for qr, p in zip(q, position)]
    if max(abs(v) for row in k_int + poses for v in row) > 1 << 53:
        return None
    stamps = _dyadic(traj.timestamps) if traj.timestamps is not None and fixed_timestamps else None
    best = None
    for cubic in (False, True) if cubic is None else (cubic,):
        parts = [_fixed_block(k_int, cubic), _fixed_block(poses, cubic)]
        if traj.distortion is not None:
            parts.append(np.ascontiguousarray(traj.distortion, dtype="<f8").tobytes())
        bits = flags | (CUBIC_PREDICTION if cubic else 0)
        if traj.timestamps is not None:
            as_floats = np.ascontiguousarray(traj.timestamps, dtype="<f8").tobytes()
            as_fixed = None if stamps is None else bytes([stamps[0]]) + _fixed_block([[v] for v in stamps[1]], cubic)
            if as_fixed is not None and len(as_fixed) < len(as_floats):
                parts.append(as_fixed)
                bits |= FIXED_TIMESTAMPS
            else:
                parts.append(as_floats)
        raw = b"".join([bytes([FIXED_POINT, bits, e_k, e_r, e_t]), *parts])
        if best is None or len(raw) < len(best):  # a tie keeps the linear prediction
            best = raw
    return best


@functools.lru_cache(maxsize=64)
def _probe_pixels(width: int, height: int) -> np.ndarray:
    """(3, P) homogeneous probe pixels of the 5 x 5 grid over a ``width`` x ``height`` image (read-only)."""
    u, v = np.meshgrid(np.linspace(-0.5, width - 0.5, PROBE_GRID), np.linspace(-0.5, height - 0.5, PROBE_GRID))
    pix = np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    pix.setflags(write=False)
    return pix


def _inverse_rotations(R: np.ndarray) -> np.ndarray:
    """(n, 3, 3) -> their inverses, the adjugate over the determinant (exact to rounding; not ``R^T``)."""
    a, b, c, d, e, f, g, h, i = (R[:, j, k] for j in range(3) for k in range(3))
    with np.errstate(all="ignore"):  # a singular matrix gives inf/NaN, which the caller's finiteness test refuses
        cof = np.stack([e * i - f * h, c * h - b * i, b * f - c * e,
                        f * g - d * i, a * i - c * g, c * d - a * f,
                        d * h - e * g, b * g - a * h, a * e - b * d], axis=1).reshape(-1, 3, 3)
        det = a * cof[:, 0, 0] + b * cof[:, 1, 0] + c * cof[:, 2, 0]
        out: np.ndarray = cof / det[:, None, None]
    return out


def reprojection_change(a: Trajectory, b: Trajectory) -> float:
    """The largest pixel distance between where camera ``a`` and camera ``b`` (same frame) put the same
    world point, over the reference writer's probe points: a 5 x 5 grid over each frame's image
    (corner pixels' outer edges included) lifted through ``a`` (its inverse, to rounding) to depths 0.1, 1,
    10 and 100 m.  Distortion is ignored (the compact encoding stores it unchanged).  Vectorised over frames
    and closed-form (the pinhole ``K`` inverts by substitution, a rotation by its adjugate): a handful of
    array operations whatever the frame count, since every write runs this test."""
    T = a.num_frames
    pix = _probe_pixels(a.width, a.height)
    depths = np.asarray(PROBE_DEPTHS_M)
    K = a.K
    with np.errstate(all="ignore"):  # valid cameras have fx, fy > 0; anything else ends as inf, refused below
        y = (pix[1][None] - K[:, 1, 2:3]) / K[:, 1, 1:2]                   # (T, P), z = 1
        x = (pix[0][None] - K[:, 0, 2:3] - K[:, 0, 1:2] * y) / K[:, 0, 0:1]
        rays = np.stack([x, y, np.ones_like(x)], axis=1)                   # (T, 3, P)
        cam_a = (rays[:, :, None, :] * depths[None, None, :, None]).reshape(T, 3, -1)  # (T, 3, Z P)
        world = _inverse_rotations(a.w2c[:, :3, :3]) @ (cam_a - a.w2c[:, :3, 3:])  # R^-1 (x - t): a float32
        # rotation is orthonormal only to ~1e-7, and R^T would move the points of a camera against itself
        proj = b.K @ (b.w2c[:, :3, :3] @ world + b.w2c[:, :3, 3:])
        uv = proj[:, :2] / proj[:, 2:]
        d = np.abs(uv - np.tile(pix[:2], len(depths))[None])
    worst = float(d.max())
    return worst if np.isfinite(worst) else float("inf")


def pack_compact_cameras(traj: Trajectory, mode: str = "compact", *, quaternions: bool = False,
                         fixed: bool = False) -> bytes:
    """The compact cameras payload of ``traj``.  ``mode`` "exact": float64 matrices (the trajectory reads
    back bit for bit); "compact": the first of fixed-point records with camera centres, fixed-point records with
    translations (both only with ``fixed``, format 1.6, and ``quaternions``), float32 quaternion poses (only
    with ``quaternions``, which a compact container allows), float32 matrices and float64 matrices whose
    decoded trajectory is valid and moves no probe point more than 0.01 px (:func:`reprojection_change`), and
    for which this same choice made on the decoded trajectory gives the same payload again -- so loading a
    file and saving it again writes the same bytes; float64 matrices when no other candidate qualifies."""
    if mode not in ("compact", "exact"):
        raise FormatError(f"compact camera mode must be 'compact' or 'exact', got {mode!r}")
    if mode == "compact":
        for raw, back in _within_tolerance(traj, quaternions, fixed):
            if _chosen_again(raw, back, quaternions, fixed):
                return raw
    return _encode(traj, 8)


def _self_change_is_noise(traj: Trajectory) -> bool:
    """Whether the probe test of ``traj`` against itself can only measure rounding: its probe points (depths up
    to 100 m, rays up to the image's edge) and translations are small enough that binary64 moves them by far
    less than 1e-5 px (about (f (|t| + 100) + 100 side) x 1e-15 / 0.1 m), so the test would pass."""
    f = float(np.abs(traj.K[:, :2, :2]).max())
    t = float(np.abs(traj.w2c[:, :3, 3]).max())
    return f * (t + 100.0) + 100.0 * max(traj.width, traj.height) < 1e9


def _chosen_again(raw: bytes, back: Trajectory, quaternions: bool, fixed: bool) -> bool:
    """Whether the writer, given ``back`` (what ``raw`` decodes to), chooses ``raw`` again.  A float32
    quaternion payload is the first candidate the writer tries for any trajectory outside format 1.6's fixed
    point; when ``back``'s own canonical quaternions encode to ``raw`` it is chosen again (it decodes to
    ``back`` itself, and the tolerance test of a camera against itself measures only rounding where
    :func:`_self_change_is_noise`), without a second tolerance test.  Otherwise the whole choice is made again
    on ``back``."""
    if quaternions and not fixed and raw[0] == 4 and raw[1] & QUATERNION_POSES and _self_change_is_noise(back):
        w2c = back.w2c[:1] if _flags(back) & STATIC_POSE else back.w2c
        q = canonical_float32_quaternions(w2c[:, :3, :3])
        if q is not None and _encode(back, 4, q) == raw:
            return True
    return next(_within_tolerance(back, quaternions, fixed), (None, None))[0] == raw


def _within_tolerance(traj: Trajectory, quaternions: bool, fixed: bool = False) -> Iterator[tuple[bytes, Trajectory]]:
    """(payload, decoded trajectory) of each lossy candidate, in the writer's order (with ``fixed`` and
    ``quaternions`` fixed point, camera centres then translations; float32 quaternion poses when
    ``quaternions``; float32 matrices), whose decoded trajectory is valid and within the probe tolerance."""
    layout = (traj.num_frames, traj.width, traj.height, 0 if traj.distortion is None else len(traj.distortion),
              traj.timestamps is not None)
    if fixed and quaternions:  # format 1.6 (I.5.4)
        for centre in (True, False):
            raw = _encode_fixed(traj, centre=centre)
            if raw is None:
                continue
            try:
                back = _decode(raw, *layout, quaternions=True, fixed=True)
            except MalformedSectionError:
                continue
            if reprojection_change(traj, back) <= REPROJECTION_TOLERANCE_PX:
                yield raw, back
    candidates: list[np.ndarray | None] = [None]
    if quaternions:
        w2c = traj.w2c[:1] if _flags(traj) & STATIC_POSE else traj.w2c
        q = canonical_float32_quaternions(w2c[:, :3, :3])
        candidates = [q, None] if q is not None else [None]
    for quat in candidates:
        raw = _encode(traj, 4, quat)
        try:
            back = _decode(raw, *layout, quaternions=quat is not None)
        except MalformedSectionError:
            continue  # float32 breaks a convention (a value beyond its range, a rotation at the tolerance)
        if reprojection_change(traj, back) <= REPROJECTION_TOLERANCE_PX:
            yield raw, back


def _decode(raw: BytesLike, T: int, width: int, height: int, distortion_terms: int, has_timestamps: bool, *,
            quaternions: bool = False, fixed: bool = False) -> Trajectory:
    raw = bytes(raw)
    if len(raw) < 2:
        raise MalformedSectionError(f"compact cameras section is {len(raw)} bytes; it needs at least 2")
    precision, flags = raw[0], raw[1]
    if precision == FIXED_POINT and fixed:
        return _decode_fixed(raw, T, width, height, distortion_terms, has_timestamps)
    if precision not in COMPACT_PRECISIONS:
        raise MalformedSectionError(f"compact cameras: precision {precision} is not 4 (float32) or 8 (float64)")
    if flags & ~(KNOWN_LAYOUT_FLAGS | (QUATERNION_POSES if quaternions else 0)):
        raise MalformedSectionError(f"compact cameras: layout flags 0x{flags:02x} set undefined bits"
                                    + ("" if quaternions else " (bit 2, quaternion poses, needs a compact container)"))
    need = compact_camera_bytes(T, precision, flags, distortion_terms, has_timestamps)
    if len(raw) != need:
        raise MalformedSectionError(f"compact cameras section is {len(raw)} bytes; its header and layout "
                                    f"byte need {need}")
    n_k = 1 if flags & CONSTANT_INTRINSICS else T
    n_p = 1 if flags & STATIC_POSE else T
    pos = 2
    kv = _unpack_block(raw[pos:pos + precision * INTRINSIC_VALUES * n_k], n_k, INTRINSIC_VALUES, precision)
    pos += precision * INTRINSIC_VALUES * n_k
    m = _pose_values(flags)
    pv = _unpack_block(raw[pos:pos + precision * m * n_p], n_p, m, precision)
    pos += precision * m * n_p
    tail = np.frombuffer(raw[pos:], dtype="<f8").astype(np.float64)
    return _assemble(kv, pv, flags, T, width, height, tail, distortion_terms, has_timestamps)


def _decode_fixed(raw: bytes, T: int, width: int, height: int, distortion_terms: int,
                  has_timestamps: bool) -> Trajectory:
    """A P = 0 payload (format 1.6, required flag bit 6, FORMAT.md I.5.4)."""
    flags = raw[1]
    if not flags & QUATERNION_POSES or flags & ~FIXED_LAYOUT_FLAGS:
        raise MalformedSectionError(f"compact cameras: fixed-point layout flags 0x{flags:02x} must set bit 2 "
                                    f"(quaternion poses) and no undefined bit (6, 7)")
    if flags & FIXED_TIMESTAMPS and not has_timestamps:
        raise MalformedSectionError("compact cameras: layout flag bit 5 (fixed-point timestamps) in a record "
                                    "without timestamps")
    if len(raw) < 5:
        raise MalformedSectionError("compact cameras: a fixed-point section is shorter than its 3 exponents")
    e_k, e_r, e_t = raw[2], raw[3], raw[4]
    if max(e_k, e_r, e_t) > MAX_EXPONENT:
        raise MalformedSectionError(f"compact cameras: a fixed-point exponent is above {MAX_EXPONENT}")
    n_k = 1 if flags & CONSTANT_INTRINSICS else T
    n_p = 1 if flags & STATIC_POSE else T
    cubic = bool(flags & CUBIC_PREDICTION)
    kv, pos = _read_fixed_block(raw, 5, n_k, [e_k] * 5, cubic)
    pv, pos = _read_fixed_block(raw, pos, n_p, [e_r] * 4 + [e_t] * 3, cubic)
    if flags & FIXED_TIMESTAMPS:
        at = pos + 8 * distortion_terms  # u8 e_s after the distortion, then T varints
        if len(raw) <= at:
            raise MalformedSectionError("compact cameras: the section ends before the timestamp exponent")
        if raw[at] > MAX_EXPONENT:
            raise MalformedSectionError(f"compact cameras: the timestamp exponent is above {MAX_EXPONENT}")
        stamps, end = _read_fixed_block(raw, at + 1, T, [raw[at]], cubic)
        if end != len(raw):
            raise MalformedSectionError(f"compact cameras: {len(raw) - end} bytes follow the fixed-point "
                                        f"timestamps")
        tail = np.concatenate([np.frombuffer(raw[pos:at], dtype="<f8").astype(np.float64), stamps[:, 0]])
    else:
        tail_len = 8 * (distortion_terms + (T if has_timestamps else 0))
        if len(raw) - pos != tail_len:
            raise MalformedSectionError(f"compact cameras: {len(raw) - pos} bytes follow the fixed-point records; "
                                        f"the distortion and timestamps need {tail_len}")
        tail = np.frombuffer(raw[pos:], dtype="<f8").astype(np.float64)
    return _assemble(kv, pv, flags, T, width, height, tail, distortion_terms, has_timestamps)


def _assemble(kv: np.ndarray, pv: np.ndarray, flags: int, T: int, width: int, height: int, tail: np.ndarray,
              distortion_terms: int, has_timestamps: bool) -> Trajectory:
    """The trajectory of decoded intrinsics and pose records (one each, or one per frame); with layout flag
    bit 3 (fixed-point records only) the last three pose values are the camera centre."""
    n_k, n_p = len(kv), len(pv)
    K = np.zeros((n_k, 3, 3))
    K[:, 0, 0], K[:, 0, 1], K[:, 0, 2], K[:, 1, 1], K[:, 1, 2] = kv.T
    K[:, 2, 2] = 1.0
    w2c = np.zeros((n_p, 4, 4))
    if flags & QUATERNION_POSES:
        w2c[:, :3, :3] = quaternion_to_rotation(pv[:, :4])
        w2c[:, :3, 3] = centre_translation(w2c[:, :3, :3], pv[:, 4:]) if flags & CENTRE_POSES else pv[:, 4:]
    else:
        w2c[:, :3, :] = pv.reshape(n_p, 3, 4)
    w2c[:, 3, 3] = 1.0
    K, w2c = np.repeat(K, T // n_k, axis=0), np.repeat(w2c, T // n_p, axis=0)
    stamps = tail[distortion_terms:] if has_timestamps else None
    if _native_valid is not None and not distortion_terms and _native_valid(K, w2c, b"" if stamps is None else stamps):
        return Trajectory._checked_elsewhere(K, w2c, width, height, stamps)  # plainly valid: checked in C
    try:
        return Trajectory(K=K, w2c=w2c, width=width, height=height,
                          distortion=tail[:distortion_terms] if distortion_terms else None, timestamps=stamps)
    except CameraError as exc:
        raise MalformedSectionError(f"cameras section breaks the camera conventions: {exc}") from None


def unpack_compact_cameras(raw: BytesLike, layout: CameraLayout, *, quaternions: bool = False,
                           fixed: bool = False) -> Trajectory:
    """Rebuild the trajectory from a compact cameras payload; any problem is a MalformedSectionError.
    ``quaternions``: the file is a compact container (format 1.3), where layout flag bit 2 is defined;
    ``fixed``: the file sets required flag bit 6 (format 1.6), where precision 0 (fixed point) is defined."""
    return _decode(raw, layout.num_frames, layout.width, layout.height, layout.distortion_terms,
                   layout.has_timestamps, quaternions=quaternions, fixed=fixed)
