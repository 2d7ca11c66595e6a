"""Pose-compensated motion isolation (paper Sec. 3.2, Eqs. 3-4), non-learned part.

Optical flow F_t comes from OpenCV DIS (the stand-in for RAFT, tuned for 64x64 frames), depth D_t from
the capture or from :func:`model.inputs.depth.estimate_depth`, and the flow the cameras alone would cause on a
static scene, F_pose (Eq. 3), as :func:`vt4dcodec.model.geometry.camera_flow` defines it.  The residual
``r_t(p) = || F_t(p) - F_pose_t(p) ||`` isolates independently moving content and
``M_t(p) = 1{ r_t(p) > tau_t }`` (Eq. 4).

What it takes to make Eq. 4 work on small, slow, synthetic objects (measured, docs/motion.md): objects
in the 64x64 synthetic scenes move 0.4-0.9 px per frame while DIS errs by 0.1-0.2 px on average and
0.3-0.6 px at its 95th percentile (much more inside textureless walls, where the aperture problem leaves
the flow undetermined).  A plain per-pixel threshold on adjacent-frame residuals therefore reaches only
IoU ~0.2-0.3 with the true object masks and marks up to 15 % of a static scene.  Classical steps fix
most of that (steps 1-4 work on the flow residual; 5-6 on the capture depth alone):

1. Longer baselines.  Besides the adjacent pairs (t, t+1) and (t, t-1) every frame is also compared with
   a partner ``LONG_GAP`` frames away (t + g, or t - g near the end).  Object displacement grows with the
   gap, DIS error hardly does, so residuals are divided by the gap (px per frame) and thresholded alike.
2. The tau_t rule, per frame pair, over the pair's *usable* pixels only:

       tau = max(TAU_MIN, median(r) + TAU_K * 1.4826 * MAD(r)),   TAU_MIN = 0.2 px/frame, TAU_K = 3.

   Most pixels are static, so median and MAD (x 1.4826 = a Gaussian sigma) measure the static error
   (DIS plus depth/pose error) without being pulled by the moving minority (breakdown point 50 %); 3
   sigma keeps ~0.1 % of a Gaussian error population.  The floor TAU_MIN (2x the mean DIS error on
   these frames) stops tau collapsing onto flow noise in very clean pairs.
3. Photometric confirmation.  A pixel is evidence of motion only if the camera-only hypothesis is also
   *photometrically* worse: ``e_pose - e_flow > PHOTO_MARGIN`` with ``e`` the 3x3 box-averaged mean
   absolute RGB difference (intensities in [0, 1]) between frame t and the partner frame warped back by
   F_pose or by the DIS flow.  Where the flow is undetermined (textureless regions) both warps match
   equally and the residual, however large, is ignored.
4. Segment voting.  Uniform object interiors carry no flow evidence of their own; the frame is split
   into segments by Felzenszwalb's graph segmentation on colour and inverse depth, and a segment joins
   the mask when at least ``VOTE_FRACTION`` of its pixels are evidence, filling in only within
   ``VOTE_REACH`` px of evidence (a segment can straddle an object edge).  The result is cleaned by a
   3x3 opening (drops isolated pixels) and closing (fills pinholes).
5. Pose consistency over the whole clip (capture depth only).  Every frame t is warped to every other
   frame s of the clip by F_pose alone (no flow: with exact depth this is exact for static content, and
   over 3-7 frames a moving object has moved several px, far above DIS noise).  A pixel *breaks free
   space* in a pair when the partner sees, all around the landing point (its 2x2 pixel block), something
   more than FREE_SPACE_RATIO farther than the point should be: a static point cannot be seen through, so
   the point has moved away (a nearer partner depth is only an occlusion and says nothing).  Mixed depth
   pixels (anti-aliased or flying pixels on a depth edge, MIXED_DEPTH_RATIO) are not tested.  The same
   warps, over pairs at least PHOTO_GAP frames apart where the pixel is visible, count colour matches:
   mean |RGB| of frame t outside the 3x3 min/max envelope of the warped partner <= PHOTO_TOLERANCE.
6. Evidence = any free-space violation, or DIS evidence (steps 1-3) unless the pixel is on a depth edge
   (DEPTH_EDGE_RATIO) where the pose warp explains its colour in >= VETO_MATCH_SHARE of at least two
   long-gap pairs and no pair breaks free space.  DIS smooths the flow across depth edges, so the flow
   residual of a static edge is large exactly where the pose warp shows nothing moved.  With plane-sweep
   depth (static-scene assumption: wrong on moving objects by construction) steps 5-6 are skipped.

Steps 5-6 run before the segment voting of step 4, which fills the object interiors from this evidence.

A pixel is *usable* in a pair when F_pose is valid (known depth, in front of the partner camera), it
lands inside the partner frame, and it is not occluded there (its predicted depth exceeds the partner's
depth at the landing point by more than OCCLUSION_RATIO): the flow of occluded or out-of-view points is
undefined, so they are left out of the statistics and give no evidence.  Every frame, the last
included, gets a mask from the pairs it has (the last frame: backward and long-gap pairs).

``mask_latent`` is the fraction of masked pixels in each latent cell (cv2.INTER_AREA), in [0, 1].
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import cv2
import numpy as np

from vt4dcodec.errors import Vt4dError
from .depth import estimate_depth

MIN_DEPTH = 1e-6  # metres: points at or behind this z are not in front of the camera (model.geometry's)

__all__ = [
    "MotionIsolation",
    "MotionInputError",
    "dis_flow",
    "estimate_flows",
    "isolate_motion",
    "residual_threshold",
    "mask_to_latent",
    "long_gap_partners",
    "all_pairs",
    "depth_edges",
    "TAU_MIN",
    "TAU_K",
    "LONG_GAP",
    "FREE_SPACE_RATIO",
    "DEFAULT_DEPTH_RANGE",
]

MASK_RULE_VERSION = 2  # bump whenever isolate_motion's output changes: caches of prepared inputs are keyed by it
TAU_MIN = 0.2  # px per frame, floor of the per-pair threshold (2x the mean DIS error at 64x64)
TAU_K = 3.0  # robust sigmas above the static median
MAD_TO_SIGMA = 1.4826
LONG_GAP = 3  # frames between a frame and its long-baseline partner
PHOTO_MARGIN = 0.01  # mean |RGB| difference in [0, 1] by which F_pose must explain the pixel worse
VOTE_FRACTION = 0.35  # fraction of evidence pixels that makes a segment move
VOTE_REACH = 2  # px: a voted segment fills in at most this far (Chebyshev) from evidence pixels
SEGMENT_SIGMA, SEGMENT_K, SEGMENT_MIN_SIZE = 0.5, 200.0, 8  # Felzenszwalb parameters (RGB in 0..255)
INV_DEPTH_WEIGHT = 500.0  # inverse-depth channel scale for segmentation (1/m -> "intensity" units)
OCCLUSION_RATIO = 0.05  # predicted depth > (1 + this) * depth at the landing point => occluded
POSE_MAX_GAP = 7  # step 5 warps every frame to every other frame at most this many frames away
FREE_SPACE_RATIO = 0.02  # partner depth > (1 + this) * predicted depth around the landing point => seen through
MIXED_DEPTH_RATIO = 0.1  # a pixel this much farther than its nearest and nearer than its farthest 3x3 neighbour
PHOTO_GAP = 3  # step 5 compares colours only over pairs at least this many frames apart
PHOTO_TOLERANCE = 0.05  # mean |RGB| outside the 3x3 envelope of the pose-warped partner still counted a match
DEPTH_EDGE_RATIO = 0.03  # |log depth| jump to a 4-neighbour that marks a depth edge
VETO_MATCH_SHARE = 0.8  # on a depth edge, DIS evidence is dropped if the pose warp matches this share of pairs
DEFAULT_DEPTH_RANGE = (0.3, 30.0)  # metres, plane-sweep range when the capture has no depth
MIN_SIZE = 8  # px, smallest frame side DIS is run on

_local = threading.local()


class MotionInputError(Vt4dError, ValueError):
    """Frames, cameras, depth or flows given to motion isolation are invalid."""


@dataclass
class MotionIsolation:
    """Everything pose-compensated motion isolation computed for one clip of T frames (H x W pixels).

    Attributes:
        flow_fwd: (T-1, H, W, 2) float32 DIS flow t -> t+1 (px), F_t.
        flow_bwd: (T-1, H, W, 2) float32 DIS flow t+1 -> t (px), lives on frame t+1.
        camera_flow: (T-1, H, W, 2) float32 F_pose_t of the forward pairs (Eq. 3), px; 0 where not usable.
        usable: (T-1, H, W) bool, forward-pair pixels whose residual is defined (module docstring).
        residual: (T-1, H, W) float32 r_t = ||F_t - F_pose_t|| (px) of the forward pairs, 0 where not usable.
        tau: (T-1,) float32 thresholds of the forward pairs (px).
        evidence: (T, H, W) bool per-pixel motion evidence of every frame (steps 1-3), before voting.
        mask: (T, H, W) bool motion mask M_t at pixel resolution (after voting and cleaning).
        mask_latent: (T, h, w) float32 fraction of masked pixels per latent cell.
        depth: (T, H, W) float32 depth used (metres).
        depth_source: "capture" or "estimated".
    """

    flow_fwd: np.ndarray
    flow_bwd: np.ndarray
    camera_flow: np.ndarray
    usable: np.ndarray
    residual: np.ndarray
    tau: np.ndarray
    evidence: np.ndarray
    mask: np.ndarray
    mask_latent: np.ndarray
    depth: np.ndarray
    depth_source: str


def _dis() -> cv2.DISOpticalFlow:
    """One DIS instance per thread (DataLoader workers and threads never share OpenCV state)."""
    inst = getattr(_local, "dis", None)
    if inst is None:
        inst = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        inst.setFinestScale(0)  # full resolution: 64x64 frames have no detail to spare
        inst.setPatchSize(4)
        inst.setPatchStride(2)
        inst.setGradientDescentIterations(12)  # measured: same end-point error as 25 at 64x64, faster
        inst.setVariationalRefinementIterations(2)
        _local.dis = inst
    return inst


def _check_frames(frames: np.ndarray, *, min_frames: int = 1) -> None:
    if not isinstance(frames, np.ndarray) or frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
        raise MotionInputError("frames must be a (T, H, W, 3) uint8 array")
    T, H, W = frames.shape[:3]
    if T < min_frames:
        raise MotionInputError(f"need at least {min_frames} frame(s), got {T}")
    if H < MIN_SIZE or W < MIN_SIZE:
        raise MotionInputError(f"frames must be at least {MIN_SIZE}x{MIN_SIZE} pixels, got {W}x{H}")


def dis_flow(frame_a: np.ndarray, frame_b: np.ndarray) -> np.ndarray:
    """Dense optical flow from ``frame_a`` to ``frame_b`` by OpenCV DIS (finest scale 0, patch 4, stride 2).

    Args:
        frame_a, frame_b: (H, W, 3) uint8 RGB frames of the same size, H, W >= 8.
    Returns:
        (H, W, 2) float32 flow (du, dv) in pixels: pixel p of ``frame_a`` appears at p + flow[p] in ``frame_b``.
    """
    for f in (frame_a, frame_b):
        if not isinstance(f, np.ndarray) or f.dtype != np.uint8 or f.ndim != 3 or f.shape[-1] != 3:
            raise MotionInputError("frames must be (H, W, 3) uint8 arrays")
    if frame_a.shape != frame_b.shape:
        raise MotionInputError(f"frame sizes differ: {frame_a.shape} vs {frame_b.shape}")
    _check_frames(frame_a[None])
    gray_a = cv2.cvtColor(np.ascontiguousarray(frame_a), cv2.COLOR_RGB2GRAY)
    gray_b = cv2.cvtColor(np.ascontiguousarray(frame_b), cv2.COLOR_RGB2GRAY)
    return _dis().calc(gray_a, gray_b, None).astype(np.float32, copy=False)


def estimate_flows(frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward (t -> t+1) and backward (t+1 -> t) DIS flows of a clip.

    Args:
        frames: (T, H, W, 3) uint8, T >= 1.
    Returns:
        ``(fwd, bwd)``, each (T-1, H, W, 2) float32 pixels; ``bwd[t]`` lives on frame t+1.
    """
    _check_frames(frames)
    T, H, W = frames.shape[:3]
    fwd = np.empty((T - 1, H, W, 2), np.float32)
    bwd = np.empty((T - 1, H, W, 2), np.float32)
    gray = [cv2.cvtColor(np.ascontiguousarray(f), cv2.COLOR_RGB2GRAY) for f in frames]
    dis = _dis()
    for t in range(T - 1):
        fwd[t] = dis.calc(gray[t], gray[t + 1], None)
        bwd[t] = dis.calc(gray[t + 1], gray[t], None)
    return fwd, bwd


def residual_threshold(residual: np.ndarray, usable: np.ndarray) -> float:
    """tau = max(TAU_MIN, median + TAU_K * 1.4826 * MAD) of the usable residuals (px/frame); module docstring."""
    r = residual[usable]
    if r.size == 0:
        return float(TAU_MIN)
    med = float(np.median(r))
    mad = float(np.median(np.abs(r - med)))
    return max(TAU_MIN, med + TAU_K * MAD_TO_SIGMA * mad)


def mask_to_latent(mask: np.ndarray, latent_hw: tuple[int, int]) -> np.ndarray:
    """(T, H, W) bool -> (T, h, w) float32 fraction of masked pixels per latent cell (area resampling)."""
    h, w = latent_hw
    out = np.empty((mask.shape[0], h, w), np.float32)
    for t, m in enumerate(mask):
        out[t] = cv2.resize(m.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    return np.clip(out, 0.0, 1.0)


@dataclass
class _Pairs:
    """Residual analysis of P frame pairs src[i] -> dst[i] (arrays (P, H, W[, 2]))."""

    src: np.ndarray
    dst: np.ndarray
    camera_flow: np.ndarray
    usable: np.ndarray
    residual: np.ndarray  # px (not divided by the gap)
    tau: np.ndarray  # (P,) px per frame
    evidence: np.ndarray


def _grid(H: int, W: int) -> tuple[np.ndarray, np.ndarray]:
    return tuple(np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32)))


def _warp(image: np.ndarray, flow: np.ndarray, grid: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """``image`` sampled at p + flow(p) (bilinear, border replicated): the partner frame brought back to p."""
    return cv2.remap(image, grid[0] + flow[..., 0], grid[1] + flow[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def _pair_geometry(
    depth: np.ndarray, K: np.ndarray, w2c: np.ndarray, src: np.ndarray, dst: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """F_pose (P, H, W, 2) of pairs src[i] -> dst[i] (Eq. 3, as :func:`vt4dcodec.model.geometry.camera_flow`), its
    validity (P, H, W) and the depth z_pred (P, H, W) each source pixel would have in the partner camera
    if it were static (for the occlusion and free-space tests).  ``depth`` (T, H, W) metres, 0 = unknown.

    Each frame is unprojected once and moved by one batched matmul per pair (camera_flow would unproject
    the source frame again for every pair, ~4x slower for the 56 pairs of an 8-frame clip).
    """
    T, H, W = depth.shape
    known = depth > 0
    D = np.where(known, depth, np.float32(1.0)).astype(np.float32)
    Kf, P = K.astype(np.float32), w2c.astype(np.float32)
    v, u = np.meshgrid(np.arange(H, dtype=np.float32), np.arange(W, dtype=np.float32), indexing="ij")
    fx, fy, skew = Kf[:, 0, 0, None, None], Kf[:, 1, 1, None, None], Kf[:, 0, 1, None, None]
    y = (v[None] - Kf[:, 1, 2, None, None]) / fy  # unproject: normalised image coordinates times depth
    x = (u[None] - Kf[:, 0, 2, None, None] - skew * y) / fx
    points = np.stack([x * D, y * D, D], axis=-1).reshape(T, H * W, 3)
    inverse = np.zeros_like(P)  # inv(w2c) of rigid poses: [R^T, -R^T t]
    inverse[:, :3, :3] = P[:, :3, :3].transpose(0, 2, 1)
    inverse[:, :3, 3:] = -inverse[:, :3, :3] @ P[:, :3, 3:]
    inverse[:, 3, 3] = 1.0
    # K_dst @ [R | t] of T_{src->dst} = w2c_dst inv(w2c_src): one matmul gives (z u, z v, z) per pixel
    to_pixels = Kf[dst] @ (P[dst] @ inverse[src])[:, :3, :]
    uvz = (points[src] @ to_pixels[:, :, :3].transpose(0, 2, 1) + to_pixels[:, None, :, 3]).reshape(-1, H, W, 3)
    z = uvz[..., 2]
    valid = known[src] & (z > MIN_DEPTH)
    uv = uvz[..., :2] / np.where(valid, z, np.float32(1.0))[..., None]
    grid = np.stack([u, v], axis=-1)
    fpose = np.where(valid[..., None], uv - grid, np.float32(0.0))
    return fpose.astype(np.float32), valid, z.astype(np.float32)


def _analyse_pairs(
    rgb: np.ndarray, depth: np.ndarray, src: np.ndarray, dst: np.ndarray, flow: np.ndarray,
    geometry: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> _Pairs:
    """Usable pixels, residuals, per-pair tau and photometrically confirmed DIS evidence (steps 1-3).

    ``rgb`` (T, H, W, 3) float32 in [0, 1]; ``depth`` (T, H, W) metres (0 = unknown); ``flow`` (P, H, W, 2)
    DIS flow of each pair; ``geometry`` the pairs' :func:`_pair_geometry` (F_pose is copied, not modified).
    """
    P = len(src)
    H, W = depth.shape[1:]
    fpose, valid, z_pred = geometry
    fpose = fpose.copy()
    grid = _grid(H, W)
    usable = np.zeros((P, H, W), dtype=bool)
    evidence = np.zeros((P, H, W), dtype=bool)
    tau = np.zeros(P, np.float32)
    residual = np.linalg.norm(flow - fpose, axis=-1).astype(np.float32)
    for i, (s, d) in enumerate(zip(src, dst)):
        mx, my = grid[0] + fpose[i, ..., 0], grid[1] + fpose[i, ..., 1]
        inside = (mx >= -0.5) & (mx <= W - 0.5) & (my >= -0.5) & (my <= H - 0.5)
        depth_there = cv2.remap(depth[d], mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        visible = ~(z_pred[i] > (1.0 + OCCLUSION_RATIO) * depth_there)
        usable[i] = valid[i] & inside & visible
        per_frame = residual[i] / abs(int(d) - int(s))
        tau[i] = residual_threshold(per_frame, usable[i])
        e_pose = cv2.boxFilter(np.abs(_warp(rgb[d], fpose[i], grid) - rgb[s]).mean(-1), -1, (3, 3))
        e_flow = cv2.boxFilter(np.abs(_warp(rgb[d], flow[i], grid) - rgb[s]).mean(-1), -1, (3, 3))
        evidence[i] = usable[i] & (per_frame > tau[i]) & (e_pose - e_flow > PHOTO_MARGIN)
    residual[~usable] = 0.0
    fpose[~usable] = 0.0
    return _Pairs(src=src, dst=dst, camera_flow=fpose, usable=usable, residual=residual, tau=tau, evidence=evidence)


@dataclass
class _PoseConsistency:
    """Per-frame counts (T, H, W) over the all-pairs pose warps of step 5."""

    violations: np.ndarray  # pairs in which the pixel breaks free space (seen through in the partner)
    matches: np.ndarray  # long-gap pairs, pixel visible, colour explained by the pose warp
    visible: np.ndarray  # long-gap pairs in which the pixel is visible


def all_pairs(T: int, max_gap: int = POSE_MAX_GAP) -> tuple[np.ndarray, np.ndarray]:
    """(src, dst) of every ordered frame pair 1 <= |src - dst| <= max_gap, as int64 arrays."""
    t = np.arange(T)
    src, dst = np.meshgrid(t, t, indexing="ij")
    keep = (src != dst) & (np.abs(src - dst) <= max_gap)
    return src[keep].astype(np.int64), dst[keep].astype(np.int64)


def _pose_consistency(
    rgb: np.ndarray, depth: np.ndarray, src: np.ndarray, dst: np.ndarray,
    geometry: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> _PoseConsistency:
    """Step 5: warp every frame to every other frame by F_pose alone (capture depth, no flow) and count,
    per pixel of the source frame, free-space violations and long-gap colour matches."""
    T, H, W = depth.shape
    fpose, valid, z_pred = geometry
    grid = _grid(H, W)
    # min and max depth of each 2x2 block [y, y+1] x [x, x+1] (edge replicated): the partner depth around a
    # landing point (floor(x), floor(y)).  Nearest/bilinear sampling would mix the two sides of a depth edge.
    padded = np.pad(depth, ((0, 0), (0, 1), (0, 1)), mode="edge")
    blocks = np.stack([padded[:, :-1, :-1], padded[:, :-1, 1:], padded[:, 1:, :-1], padded[:, 1:, 1:]])
    low, high = blocks.min(0), blocks.max(0)
    out = _PoseConsistency(*(np.zeros((T, H, W), np.int16) for _ in range(3)))
    mx, my = grid[0] + fpose[..., 0], grid[1] + fpose[..., 1]
    inside = valid & (mx >= -0.5) & (mx <= W - 0.5) & (my >= -0.5) & (my <= H - 0.5)
    at = (dst[:, None, None], np.clip(np.floor(my), 0, H - 1).astype(np.intp),
          np.clip(np.floor(mx), 0, W - 1).astype(np.intp))
    # low > 0: all four known.  Mixed pixels (depth between a clearly nearer and a clearly farther
    # neighbour: anti-aliased or "flying" pixels on a depth edge) belong to no surface and are not tested.
    k3 = np.ones((3, 3), np.uint8)
    nearest = np.stack([cv2.erode(d, k3) for d in depth])
    farthest = np.stack([cv2.dilate(d, k3) for d in depth])
    mixed = (nearest * (1.0 + MIXED_DEPTH_RATIO) < depth) & (farthest > depth * (1.0 + MIXED_DEPTH_RATIO))
    violation = inside & ~mixed[src] & (low[at] > (1.0 + FREE_SPACE_RATIO) * z_pred)
    visible = inside & ~violation & (high[at] * (1.0 + OCCLUSION_RATIO) >= z_pred)
    for t in range(T):
        out.violations[t] = violation[src == t].sum(0)
    for i in np.flatnonzero(np.abs(src - dst) >= PHOTO_GAP):
        s, d = src[i], dst[i]
        warped = _warp(rgb[d], fpose[i], grid)
        # colour error against the 3x3 min/max envelope of the warped partner: sub-pixel misregistration
        # of edges (pose, depth sampling, resampling) costs nothing, a displacement of several px does
        err = np.maximum(np.maximum(rgb[s] - cv2.dilate(warped, k3), cv2.erode(warped, k3) - rgb[s]), 0.0).mean(-1)
        out.matches[s] += visible[i] & (err <= PHOTO_TOLERANCE)
        out.visible[s] += visible[i]
    return out


def depth_edges(depth: np.ndarray, ratio: float = DEPTH_EDGE_RATIO) -> np.ndarray:
    """(T, H, W) bool: pixels whose depth differs from a 4-neighbour's by more than ``ratio`` in log depth
    (both sides of the edge are marked; unknown depth never makes an edge)."""
    log_d = np.log(np.where(depth > 0, depth, 1.0))
    known = depth > 0
    edge = np.zeros(depth.shape, dtype=bool)
    for axis in (1, 2):
        n = depth.shape[axis] - 1
        a, b = (slice(None),) * axis + (slice(0, n),), (slice(None),) * axis + (slice(1, n + 1),)
        jump = (np.abs(log_d[b] - log_d[a]) > ratio) & known[a] & known[b]
        edge[a] |= jump
        edge[b] |= jump
    return edge


def _combine_evidence(dis_evidence: np.ndarray, pose: _PoseConsistency, edges: np.ndarray) -> np.ndarray:
    """Step 6, per pixel: any free-space violation, or DIS evidence (steps 1-3) unless it sits on a depth
    edge where the pose warp explains the colour in >= VETO_MATCH_SHARE of the (>= 2) long-gap pairs the
    pixel is visible in and no pair breaks free space."""
    explained = (pose.visible >= 2) & (pose.matches >= VETO_MATCH_SHARE * pose.visible) & (pose.violations == 0)
    return (pose.violations > 0) | (dis_evidence & ~(edges & explained))


_OPEN_CLOSE_KERNEL = np.ones((3, 3), np.uint8)


def _clean(mask: np.ndarray) -> np.ndarray:
    m = mask.astype(np.uint8)
    m = cv2.morphologyEx(m, cv2.MORPH_OPEN, _OPEN_CLOSE_KERNEL)
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, _OPEN_CLOSE_KERNEL)
    return m.astype(bool)


def _segmenter():
    inst = getattr(_local, "segmenter", None)
    if inst is None:
        inst = cv2.ximgproc.segmentation.createGraphSegmentation(SEGMENT_SIGMA, SEGMENT_K, SEGMENT_MIN_SIZE)
        _local.segmenter = inst
    return inst


def _vote(frame: np.ndarray, depth: np.ndarray, evidence: np.ndarray) -> np.ndarray:
    """Segments (colour + inverse depth) with >= VOTE_FRACTION evidence pixels, as an (H, W) bool mask."""
    if not evidence.any():
        return evidence.copy()
    inv = np.where(depth > 0, INV_DEPTH_WEIGHT / np.maximum(depth, 1e-6), 0.0).astype(np.float32)
    labels = _segmenter().processImage(np.concatenate([frame.astype(np.float32), inv[..., None]], axis=-1))
    n = int(labels.max()) + 1
    count = np.bincount(labels.ravel(), minlength=n)
    hits = np.bincount(labels.ravel(), weights=evidence.ravel().astype(np.float64), minlength=n)
    voted = (hits >= VOTE_FRACTION * np.maximum(count, 1))[labels]
    if VOTE_REACH > 0:  # a voted segment only fills in near its evidence (segments may straddle edges)
        size = 2 * VOTE_REACH + 1
        near = cv2.dilate(evidence.astype(np.uint8), np.ones((size, size), np.uint8)).astype(bool)
        voted &= near
    return voted


def _check_cameras_depth(frames: np.ndarray, K, w2c, depth) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    T, H, W = frames.shape[:3]
    K = np.asarray(K, dtype=np.float64)
    w2c = np.asarray(w2c, dtype=np.float64)
    if K.shape != (T, 3, 3) or w2c.shape != (T, 4, 4):
        raise MotionInputError(f"K must be ({T}, 3, 3) and w2c ({T}, 4, 4), got {K.shape} and {w2c.shape}")
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(w2c))):
        raise MotionInputError("K and w2c must be finite")
    if np.any(K[:, 0, 0] <= 0) or np.any(K[:, 1, 1] <= 0):
        raise MotionInputError("focal lengths must be positive")
    if depth is not None:
        depth = np.asarray(depth, dtype=np.float32)
        if depth.shape != (T, H, W):
            raise MotionInputError(f"depth must be ({T}, {H}, {W}), got {depth.shape}")
        depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
    return K, w2c, depth


def long_gap_partners(T: int, gap: int = LONG_GAP) -> np.ndarray:
    """(T,) partner frame of every frame for the long-baseline pairs: t + g, or t - g if past the end.

    ``g = min(gap, T - 1)``; frames with no partner at distance g on either side (short clips) get -1.
    """
    g = min(gap, T - 1)
    t = np.arange(T)
    partner = np.where(t + g < T, t + g, t - g)
    return np.where((g >= 2) & (partner >= 0), partner, -1)


def isolate_motion(
    frames: np.ndarray,
    K: np.ndarray,
    w2c: np.ndarray,
    depth: np.ndarray | None,
    *,
    latent_hw: tuple[int, int] = (16, 16),
    flows: tuple[np.ndarray, np.ndarray] | None = None,
    depth_range: tuple[float, float] = DEFAULT_DEPTH_RANGE,
) -> MotionIsolation:
    """Motion masks M_t of a calibrated clip (paper Eqs. 3-4; the full rule is in the module docstring).

    Args:
        frames: (T, H, W, 3) uint8 RGB, H, W >= 8.
        K: (T, 3, 3) intrinsics in pixels of ``frames`` (undistorted pinhole).
        w2c: (T, 4, 4) world-to-camera poses in metres.
        depth: (T, H, W) float32 z-depth in metres (<= 0 or non-finite = unknown), or None to estimate it
            by plane sweep over ``depth_range`` (see :mod:`model.inputs.depth`).
        latent_hw: (h, w) latent resolution of ``mask_latent``.
        flows: precomputed adjacent ``(fwd, bwd)`` as returned by :func:`estimate_flows` (skips that DIS
            work; the long-baseline flows are always computed here).
        depth_range: (near, far) metres searched when ``depth`` is None.
    Returns:
        :class:`MotionIsolation`.
    """
    _check_frames(frames)
    K, w2c, depth = _check_cameras_depth(frames, K, w2c, depth)
    T, H, W = frames.shape[:3]
    h, w = latent_hw
    if not (isinstance(h, (int, np.integer)) and isinstance(w, (int, np.integer)) and 1 <= h <= H and 1 <= w <= W):
        raise MotionInputError(f"latent_hw must be positive integers no larger than the frame, got {latent_hw}")
    if flows is None:
        flow_fwd, flow_bwd = estimate_flows(frames)
    else:
        flow_fwd, flow_bwd = (np.asarray(f, dtype=np.float32) for f in flows)
        if flow_fwd.shape != (T - 1, H, W, 2) or flow_bwd.shape != (T - 1, H, W, 2):
            raise MotionInputError(f"flows must both be ({T - 1}, {H}, {W}, 2)")
        if not (np.all(np.isfinite(flow_fwd)) and np.all(np.isfinite(flow_bwd))):
            raise MotionInputError("flows hold non-finite values")
    if depth is None:
        depth = estimate_depth(frames, K, w2c, near=depth_range[0], far=depth_range[1])
        depth_source = "estimated"
    else:
        depth_source = "capture"

    # every pair: forward t -> t+1, backward t+1 -> t, long baseline t -> partner(t)
    partner = long_gap_partners(T)
    has_long = np.flatnonzero(partner >= 0)
    gray = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]
    long_flow = np.stack([_dis().calc(gray[t], gray[partner[t]], None) for t in has_long]) if has_long.size else (
        np.zeros((0, H, W, 2), np.float32))
    src = np.concatenate([np.arange(T - 1), np.arange(1, T), has_long]).astype(np.int64)
    dst = np.concatenate([np.arange(1, T), np.arange(T - 1), partner[has_long]]).astype(np.int64)
    # F_pose once for every ordered pair; the DIS pairs above are a subset of them
    all_src, all_dst = all_pairs(T)
    geometry = _pair_geometry(depth, K, w2c, all_src, all_dst)
    index = {(int(a), int(b)): i for i, (a, b) in enumerate(zip(all_src, all_dst))}
    take = np.array([index[(int(a), int(b))] for a, b in zip(src, dst)], dtype=np.int64)
    rgb = frames.astype(np.float32) / 255.0
    pairs = _analyse_pairs(
        rgb, depth, src, dst, np.concatenate([flow_fwd, flow_bwd, long_flow]).astype(np.float32),
        tuple(g[take] for g in geometry),
    )
    dis_evidence = np.zeros((T, H, W), dtype=bool)
    for i, s in enumerate(src):
        dis_evidence[s] |= pairs.evidence[i]
    if depth_source == "capture":
        evidence = _combine_evidence(dis_evidence, _pose_consistency(rgb, depth, all_src, all_dst, geometry),
                                    depth_edges(depth))
    else:  # plane-sweep depth is wrong on moving objects by construction (static-scene assumption)
        evidence = dis_evidence
    mask = np.stack([_clean(_vote(frames[t], depth[t], evidence[t])) for t in range(T)])
    n = T - 1
    return MotionIsolation(
        flow_fwd=flow_fwd, flow_bwd=flow_bwd, camera_flow=pairs.camera_flow[:n], usable=pairs.usable[:n],
        residual=pairs.residual[:n], tau=pairs.tau[:n], evidence=evidence, mask=mask,
        mask_latent=mask_to_latent(mask, (h, w)), depth=depth, depth_source=depth_source,
    )
