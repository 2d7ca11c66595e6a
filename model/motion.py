"""Pose-compensated motion isolation (paper Sec. 3.2, Eqs. 3-4), non-learned part.

Optical flow F_t comes from OpenCV DIS (the stand-in for RAFT, tuned for 64x64 frames), depth D_t from
the capture or from :func:`model.depth.estimate_depth`, and the flow the cameras alone would cause on a
static scene, F_pose (Eq. 3), from :func:`vt4dcodec.geometry.camera_flow`.  The residual
``r_t(p) = || F_t(p) - F_pose_t(p) ||`` isolates independently moving content and
``M_t(p) = 1{ r_t(p) > tau_t }`` (Eq. 4).

What it takes to make Eq. 4 work on small, slow, synthetic objects (measured, docs/motion.md): objects
in the 64x64 synthetic scenes move 0.4-0.9 px per frame while DIS errs by 0.1-0.2 px on average and
0.3-0.6 px at its 95th percentile (much more inside textureless walls, where the aperture problem leaves
the flow undetermined).  A plain per-pixel threshold on adjacent-frame residuals therefore reaches only
IoU ~0.2-0.3 with the true object masks and marks up to 15 % of a static scene.  Three classical steps,
all on the same residual, fix most of that:

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
import torch

from vt4dcodec.errors import Vt4dError
from vt4dcodec.geometry import camera_flow, relative_pose, unproject

from .depth import estimate_depth

__all__ = [
    "MotionIsolation",
    "MotionInputError",
    "dis_flow",
    "estimate_flows",
    "isolate_motion",
    "residual_threshold",
    "mask_to_latent",
    "TAU_MIN",
    "TAU_K",
    "LONG_GAP",
    "DEFAULT_DEPTH_RANGE",
]

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


def _warp(image: np.ndarray, flow: np.ndarray, grid: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """``image`` sampled at p + flow(p) (bilinear, border replicated): the partner frame brought back to p."""
    return cv2.remap(image, grid[0] + flow[..., 0], grid[1] + flow[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def _analyse_pairs(
    rgb: np.ndarray, depth: np.ndarray, K: np.ndarray, w2c: np.ndarray,
    src: np.ndarray, dst: np.ndarray, flow: np.ndarray,
) -> _Pairs:
    """F_pose, usable pixels, residuals, per-pair tau and photometrically confirmed evidence.

    ``rgb`` (T, H, W, 3) float32 in [0, 1]; ``depth`` (T, H, W) metres (0 = unknown); ``flow`` (P, H, W, 2)
    DIS flow of each pair.
    """
    P = len(src)
    H, W = depth.shape[1:]
    D = torch.from_numpy(depth)
    Kt, Pt = torch.from_numpy(K.astype(np.float32)), torch.from_numpy(w2c.astype(np.float32))
    fpose_t, valid_t = camera_flow(D[src], Kt[src], Kt[dst], Pt[src], Pt[dst])
    # depth of each source point in the partner camera (z row of T_{src->dst}) for the occlusion test;
    # an einsum, as a batched 3x3 matmul per pixel is slow on CPU
    rel = relative_pose(Pt[src], Pt[dst])
    z_pred = (torch.einsum("phwc,pc->phw", unproject(D[src], Kt[src]), rel[:, 2, :3]) + rel[:, 2, 3, None, None]).numpy()
    fpose = fpose_t.numpy().astype(np.float32)
    valid = valid_t.numpy()
    grid = tuple(np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32)))
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
            by plane sweep over ``depth_range`` (see :mod:`model.depth`).
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
    pairs = _analyse_pairs(
        frames.astype(np.float32) / 255.0, depth, K, w2c, src, dst,
        np.concatenate([flow_fwd, flow_bwd, long_flow]).astype(np.float32),
    )
    evidence = np.zeros((T, H, W), dtype=bool)
    for i, s in enumerate(src):
        evidence[s] |= pairs.evidence[i]
    mask = np.stack([_clean(_vote(frames[t], depth[t], evidence[t])) for t in range(T)])
    n = T - 1
    return MotionIsolation(
        flow_fwd=flow_fwd, flow_bwd=flow_bwd, camera_flow=pairs.camera_flow[:n], usable=pairs.usable[:n],
        residual=pairs.residual[:n], tau=pairs.tau[:n], evidence=evidence, mask=mask,
        mask_latent=mask_to_latent(mask, (h, w)), depth=depth, depth_source=depth_source,
    )
