"""Depth without a sensor: classical plane-sweep stereo over neighbouring frames with known poses.

The paper estimates D_t with a monocular depth network (UniDepth); none can be downloaded here, and real
footage rarely ships depth.  A calibrated moving camera is a multi-view stereo rig over time, so depth
for frame r is found by sweeping fronto-parallel planes z = d (uniform in inverse depth between
``near`` and ``far``) through the reference camera:

1. For a neighbour n (frames r +- 1 .. r +- ``window``) with relative pose ``X_n = R X_r + t``, the
   plane z = d induces the homography ``H_d = K_n (R + t e_3^T / d) K_r^{-1}`` (ref px -> neighbour px);
   the neighbour is warped into the reference view with it (bilinear).
2. Photometric cost: truncated mean absolute RGB difference (intensities in [0, 1]), aggregated over a
   ``patch`` x ``patch`` box.  Per pixel and plane the neighbour costs are combined by averaging the
   best half of the neighbours that see the pixel (robust to occlusion and to the far side of a moving
   object); a pixel no neighbour sees gets the truncation cost.
3. Winner-take-all over planes, then a parabola through the best plane's cost and its two neighbours
   refines the inverse depth below the plane spacing.
4. Confidence = (mean cost over planes - best cost) / mean cost: flat cost curves (textureless areas,
   no baseline) score near 0.  Pixels under ``min_confidence`` are filled from the nearest confident
   pixel, then a 5 x 5 median filter removes isolated outliers.

Moving objects break the static-scene assumption across time, so their depth is unreliable (reported in
docs/motion.md).  A frame whose neighbours all have (near) zero baseline has no depth information at
all; camera-induced flow is then depth-independent, and the frame gets the geometric mean of ``near``
and ``far`` (or the median of the other frames' estimates).

Numpy + OpenCV; no torch.
"""

from __future__ import annotations

import cv2
import numpy as np

from vt4dcodec.errors import Vt4dError

__all__ = ["estimate_depth", "DepthInputError", "plane_homography"]

TRUNCATION = 0.2  # photometric cost cap (mean |RGB difference| in [0, 1] units)
MIN_BASELINE = 1e-6  # metres; neighbours closer than this carry no depth information


class DepthInputError(Vt4dError, ValueError):
    """Frames, cameras or depth range given to the depth estimator are invalid."""


def plane_homography(K_ref: np.ndarray, K_nbr: np.ndarray, R: np.ndarray, t: np.ndarray, depth: float, *,
                     K_ref_inv: np.ndarray | None = None) -> np.ndarray:
    """Homography (3, 3) mapping reference pixels to neighbour pixels for the plane z_ref = depth.

    ``R, t`` take reference-camera points to neighbour-camera points (``X_n = R X_r + t``), metres.
    ``K_ref_inv``: ``K_ref``'s inverse where the caller already has it (a sweep over many planes).
    """
    n = np.array([0.0, 0.0, 1.0])
    return K_nbr @ (R + np.outer(t, n) / depth) @ (np.linalg.inv(K_ref) if K_ref_inv is None else K_ref_inv)


def _check_inputs(frames: np.ndarray, K: np.ndarray, w2c: np.ndarray, near: float, far: float, num_planes: int) -> None:
    if not isinstance(frames, np.ndarray) or frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
        raise DepthInputError("frames must be a (T, H, W, 3) uint8 array")
    T, H, W = frames.shape[:3]
    if T < 1 or H < 2 or W < 2:
        raise DepthInputError(f"frames must hold at least one 2x2 frame, got {frames.shape}")
    if np.shape(K) != (T, 3, 3) or np.shape(w2c) != (T, 4, 4):
        raise DepthInputError(f"K must be ({T}, 3, 3) and w2c ({T}, 4, 4)")
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(w2c))):
        raise DepthInputError("K and w2c must be finite")
    if not (np.isfinite(near) and np.isfinite(far) and 0 < near < far):
        raise DepthInputError(f"need 0 < near < far (metres), got near={near!r}, far={far!r}")
    if isinstance(num_planes, bool) or not isinstance(num_planes, (int, np.integer)) or not 3 <= num_planes <= 1024:
        raise DepthInputError(f"num_planes must be an integer in [3, 1024], got {num_planes!r}")


def estimate_depth(
    frames: np.ndarray,
    K: np.ndarray,
    w2c: np.ndarray,
    *,
    near: float,
    far: float,
    num_planes: int = 48,
    window: int = 2,
    patch: int = 5,
    min_confidence: float = 0.15,
) -> np.ndarray:
    """Plane-sweep depth for every frame of a calibrated video (see the module docstring).

    Args:
        frames: (T, H, W, 3) uint8 RGB.
        K: (T, 3, 3) intrinsics in pixels of ``frames``.
        w2c: (T, 4, 4) world-to-camera poses, metres.
        near, far: depth search range in metres (z in the camera frame), 0 < near < far.
        num_planes: number of fronto-parallel planes, uniform in inverse depth.
        window: neighbours r-window .. r+window (excluding r) serve as the second views.
        patch: odd box size (pixels) of the cost aggregation.
        min_confidence: pixels below this confidence are filled from confident neighbours.

    Returns:
        (T, H, W) float32 depth in metres, within [near, far].
    """
    _check_inputs(frames, K, w2c, near, far, num_planes)
    if window < 1 or patch < 1 or patch % 2 == 0:
        raise DepthInputError("window must be >= 1 and patch an odd size >= 1")
    K = np.asarray(K, dtype=np.float64)
    w2c = np.asarray(w2c, dtype=np.float64)
    T, H, W = frames.shape[:3]
    inv_depths = np.linspace(1.0 / near, 1.0 / far, num_planes)
    images = frames.astype(np.float32) / 255.0
    out = np.zeros((T, H, W), dtype=np.float32)
    informative = np.zeros(T, dtype=bool)
    for r in range(T):
        nbrs = [n for n in range(max(0, r - window), min(T, r + window + 1)) if n != r]
        rel = [w2c[n] @ np.linalg.inv(w2c[r]) for n in nbrs]
        keep = [i for i, M in enumerate(rel) if np.linalg.norm(M[:3, 3]) > MIN_BASELINE]
        if not keep:
            continue
        cost = _cost_volume(images, K, r, [nbrs[i] for i in keep], [rel[i] for i in keep], inv_depths, patch)
        inv, conf = _winner_take_all(cost, inv_depths)
        ok = conf >= min_confidence
        if not np.any(ok):
            continue
        informative[r] = True
        out[r] = 1.0 / _fill_and_smooth(inv.astype(np.float32), ok)
    fallback = float(np.median(out[informative])) if np.any(informative) else float(np.sqrt(near * far))
    out[~informative] = fallback
    return np.clip(out, near, far).astype(np.float32)


def _cost_volume(
    images: np.ndarray, K: np.ndarray, r: int, nbrs: list[int], rel: list[np.ndarray],
    inv_depths: np.ndarray, patch: int,
) -> np.ndarray:
    """(D, H, W) aggregated photometric cost of reference frame r against its neighbours."""
    H, W = images.shape[1:3]
    D = len(inv_depths)
    ref_c = [np.ascontiguousarray(images[r][..., c]) for c in range(3)]
    K_ref_inv = np.linalg.inv(K[r])
    per_nbr = np.empty((len(nbrs), D, H, W), dtype=np.float32)
    seen = np.empty_like(per_nbr, dtype=bool)
    warped = np.empty((D, H, W, 4), dtype=np.float32)
    for j, (n, M) in enumerate(zip(nbrs, rel)):
        src = np.concatenate([images[n], np.ones((H, W, 1), np.float32)], axis=2)
        for d, inv in enumerate(inv_depths):
            Hmat = plane_homography(K[r], K[n], M[:3, :3], M[:3, 3], 1.0 / inv, K_ref_inv=K_ref_inv)
            cv2.warpPerspective(src, Hmat, (W, H), dst=warped[d], flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0, 0))
        # mean |RGB difference| over the channels, summed in the order numpy's mean sums three values
        diff = np.abs(warped[..., 0] - ref_c[0])
        diff += np.abs(warped[..., 1] - ref_c[1])
        diff += np.abs(warped[..., 2] - ref_c[2])
        diff /= np.float32(3.0)
        np.minimum(diff, TRUNCATION, out=diff)
        inside = warped[..., 3] > 0.999
        diff[~inside] = TRUNCATION
        for d in range(D):
            cv2.boxFilter(diff[d], -1, (patch, patch), dst=per_nbr[j, d], borderType=cv2.BORDER_REFLECT)
        seen[j] = inside
    if len(nbrs) == 1:
        return per_nbr[0]
    # average the best half of the neighbours that see the pixel (occlusion-robust)
    best = max(1, len(nbrs) // 2)
    # the `best` smallest costs per pixel and plane in ascending order (what sorting the neighbour axis gives;
    # an insertion through elementwise min/max, far faster than np.sort along this short outer axis)
    top = np.full((best, D, H, W), np.inf, dtype=np.float32)
    for j in range(len(nbrs)):
        value = np.where(seen[j], per_nbr[j], np.float32(np.inf))
        for i in range(best):
            low = np.minimum(top[i], value)
            np.maximum(top[i], value, out=value)
            top[i] = low
    count = np.isfinite(top).sum(axis=0)
    total = np.where(np.isfinite(top), top, 0.0).sum(axis=0)
    return np.where(count > 0, total / np.maximum(count, 1), TRUNCATION).astype(np.float32)


def _winner_take_all(cost: np.ndarray, inv_depths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Best inverse depth per pixel with parabolic sub-plane refinement, plus a confidence in [0, 1]."""
    D = cost.shape[0]
    best = np.argmin(cost, axis=0)
    c0 = np.take_along_axis(cost, best[None], 0)[0]
    lo = np.take_along_axis(cost, np.clip(best - 1, 0, D - 1)[None], 0)[0]
    hi = np.take_along_axis(cost, np.clip(best + 1, 0, D - 1)[None], 0)[0]
    curvature = lo - 2 * c0 + hi
    interior = (best > 0) & (best < D - 1) & (curvature > 1e-9)
    offset = np.where(interior, 0.5 * (lo - hi) / np.where(interior, curvature, 1.0), 0.0)
    offset = np.clip(offset, -0.5, 0.5)
    step = inv_depths[1] - inv_depths[0]
    inv = inv_depths[best] + offset * step
    mean = cost.mean(axis=0)
    conf = np.where(mean > 1e-9, (mean - c0) / np.maximum(mean, 1e-9), 0.0)
    return inv, conf


def _fill_and_smooth(inv: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Fill low-confidence pixels from the nearest confident pixel, then 5x5 median filter."""
    if not np.all(ok):
        src = np.where(ok, 0, 1).astype(np.uint8)  # zeros are the confident pixels
        _, labels = cv2.distanceTransformWithLabels(src, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
        ys, xs = np.nonzero(ok)
        lut_val = np.zeros(labels.max() + 1, dtype=np.float32)
        lut_val[labels[ys, xs]] = inv[ys, xs]
        inv = lut_val[labels]
    return cv2.medianBlur(inv, 5)
