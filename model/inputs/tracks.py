"""Flow-propagated point tracks for Track-Aware Dynamic Attention (paper Sec. 3.2, Eq. 5).

Seeds are sampled from the latent-resolution motion masks M_t and carried across frames by the
optical flow, ``p_i^{t+1} = p_i^t + F_t(p_i^t)`` (Eq. 5), forward *and* backward from the seed frame.
A track becomes invalid in a direction when it leaves the frame or fails the forward-backward
consistency check, and stays invalid in that direction from then on.

Coordinates.  Track positions are in *track units* (normally latent pixels), pixel centres at
integers; flows are in *image pixels*.  With ``scale = s`` image pixels per track unit, a track point
``p`` sits at image pixel ``(p + 0.5) * s - 0.5`` (the centres of an s x s block average to the latent
cell centre), and a flow vector ``f`` (px) moves it by ``f / s`` track units.

Numpy only; no torch, no OpenCV.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vt4dcodec.errors import Vt4dError

__all__ = [
    "Tracks",
    "TrackInputError",
    "sample_seeds",
    "propagate_tracks",
    "bilinear_sample",
    "PADDING_SEED_FRAME",
    "DEFAULT_FB_TOLERANCE",
]

PADDING_SEED_FRAME = -1  # seed_frame of a padding track: invalid at every frame
DEFAULT_FB_TOLERANCE = 1.0  # px (image pixels); see propagate_tracks
FB_RELATIVE = 0.05  # extra tolerance per px^2 of motion (Sundaram et al. 2010 style), see propagate_tracks


class TrackInputError(Vt4dError, ValueError):
    """Seeds, masks or flows given to the track code have the wrong shape, dtype or values."""


@dataclass
class Tracks:
    """N point tracks over T frames.

    Attributes:
        xy: (N, T, 2) float32 positions (u, v) in track units (latent pixels), pixel centres at
            integers.  Where a track is invalid the position repeats the nearest valid position in
            that direction (or the seed for padding tracks is 0, 0), so it is always finite and
            inside the frame; consumers must still honour ``valid``.
        valid: (N, T) bool, True where the track is valid.
        seed_frame: (N,) int64 frame the track was seeded in; ``PADDING_SEED_FRAME`` (-1) for padding.
    """

    xy: np.ndarray
    valid: np.ndarray
    seed_frame: np.ndarray

    def __post_init__(self) -> None:
        N = self.seed_frame.shape[0]
        if self.xy.ndim != 3 or self.xy.shape[0] != N or self.xy.shape[2] != 2:
            raise TrackInputError("Tracks.xy must be (N, T, 2)")
        if self.valid.shape != self.xy.shape[:2]:
            raise TrackInputError("Tracks.valid must be (N, T)")

    @property
    def num_tracks(self) -> int:
        return int(self.xy.shape[0])

    @property
    def num_frames(self) -> int:
        return int(self.xy.shape[1])


def sample_seeds(
    mask: np.ndarray, num_tracks: int, *, rng: np.random.Generator, min_weight: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Sample ``num_tracks`` track seeds from latent-resolution motion masks.

    Every latent cell (t, y, x) with ``mask > min_weight`` is a candidate, drawn with probability
    proportional to its mask value (the fraction of moving pixels in the cell).  Cells are drawn
    without replacement while there are enough of them; if there are fewer candidates than tracks,
    every candidate is taken and the rest are drawn again with replacement.  Each seed gets a uniform
    sub-cell jitter in [-0.5, 0.5) so repeated cells give distinct tracks.

    Args:
        mask: (T, h, w) float in [0, 1] (or bool), latent-resolution motion masks.
        num_tracks: N >= 0, the fixed number of seeds returned.
        rng: the random generator (seeded by the caller for determinism).
        min_weight: cells with mask <= this are never seeded.

    Returns:
        frames: (N,) int64 seed frame per track; ``PADDING_SEED_FRAME`` (-1) for every row when the
            mask has no candidate cell (padding tracks, invalid everywhere).
        xy: (N, 2) float32 seed positions (u, v) in latent pixels (0, 0 for padding rows).
    """
    mask = np.asarray(mask)
    if mask.ndim != 3 or min(mask.shape) < 1:
        raise TrackInputError(f"mask must be a non-empty (T, h, w) array, got shape {mask.shape}")
    if isinstance(num_tracks, bool) or not isinstance(num_tracks, (int, np.integer)) or num_tracks < 0:
        raise TrackInputError(f"num_tracks must be a non-negative integer, got {num_tracks!r}")
    weights = np.nan_to_num(mask.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0).reshape(-1)
    candidates = np.flatnonzero(weights > min_weight)
    frames = np.full((num_tracks,), PADDING_SEED_FRAME, dtype=np.int64)
    xy = np.zeros((num_tracks, 2), dtype=np.float32)
    if num_tracks == 0 or candidates.size == 0:
        return frames, xy
    p = weights[candidates] / weights[candidates].sum()
    if candidates.size >= num_tracks:
        picked = rng.choice(candidates, size=num_tracks, replace=False, p=p)
    else:
        extra = rng.choice(candidates, size=num_tracks - candidates.size, replace=True, p=p)
        picked = np.concatenate([candidates, extra])
    t, y, x = np.unravel_index(picked, mask.shape)
    jitter = rng.uniform(-0.5, 0.5, size=(num_tracks, 2))
    h, w = mask.shape[1:]
    frames[:] = t
    xy[:, 0] = np.clip(x + jitter[:, 0], -0.5, w - 0.5)
    xy[:, 1] = np.clip(y + jitter[:, 1], -0.5, h - 0.5)
    return frames, xy


def bilinear_sample(field: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Sample an (H, W, C) field at (N, 2) pixel positions (u, v), pixel centres at integers.

    Positions are clamped to the image (border replication), so callers check bounds themselves.
    Returns (N, C) float32.
    """
    H, W = field.shape[:2]
    u = np.clip(xy[:, 0].astype(np.float64), 0.0, W - 1.0)
    v = np.clip(xy[:, 1].astype(np.float64), 0.0, H - 1.0)
    u0 = np.minimum(np.floor(u).astype(np.int64), max(W - 2, 0))
    v0 = np.minimum(np.floor(v).astype(np.int64), max(H - 2, 0))
    u1 = np.minimum(u0 + 1, W - 1)
    v1 = np.minimum(v0 + 1, H - 1)
    a = (u - u0)[:, None]
    b = (v - v0)[:, None]
    top = field[v0, u0] * (1 - a) + field[v0, u1] * a
    bottom = field[v1, u0] * (1 - a) + field[v1, u1] * a
    return (top * (1 - b) + bottom * b).astype(np.float32)


def _check_flows(flow_fwd: np.ndarray, flow_bwd: np.ndarray) -> None:
    for name, f in (("flow_fwd", flow_fwd), ("flow_bwd", flow_bwd)):
        if not isinstance(f, np.ndarray) or f.ndim != 4 or f.shape[-1] != 2 or min(f.shape[1:3]) < 1:
            raise TrackInputError(f"{name} must be a (T-1, H, W, 2) array")
    if flow_fwd.shape != flow_bwd.shape:
        raise TrackInputError(f"flow_fwd {flow_fwd.shape} and flow_bwd {flow_bwd.shape} differ in shape")


def propagate_tracks(
    seed_frames: np.ndarray,
    seed_xy: np.ndarray,
    flow_fwd: np.ndarray,
    flow_bwd: np.ndarray,
    *,
    scale: float | tuple[float, float] = 1.0,
    fb_tolerance: float = DEFAULT_FB_TOLERANCE,
    fb_relative: float = FB_RELATIVE,
) -> Tracks:
    """Carry seeds across all T frames with the flow, forward and backward (paper Eq. 5).

    Forward from the seed frame s: ``p^{t+1} = p^t + F_t(p^t) / scale`` with ``F_t = flow_fwd[t]``
    sampled bilinearly; backward: ``p^{t-1} = p^t + B_{t-1}(p^t) / scale`` with
    ``B_{t-1} = flow_bwd[t-1]`` (the t -> t-1 flow).  A step is rejected, and the track stays invalid
    in that direction for good, when

    * the new point leaves the image (outside [-0.5, W - 0.5] x [-0.5, H - 0.5] in image pixels), or
    * the forward-backward check fails: with ``f`` the flow used for the step and ``b`` the opposite
      flow sampled at the landing point, ``|f + b| > fb_tolerance + fb_relative * (|f|^2 + |b|^2)``
      (pixels).  Occluded points land on a surface that moves differently, so ``b`` does not undo
      ``f``; the relative term allows for the larger error of large motions.

    Args:
        seed_frames: (N,) int frame per seed, in [0, T) or ``PADDING_SEED_FRAME`` (-1) for padding.
        seed_xy: (N, 2) float seed positions (u, v) in track units.
        flow_fwd: (T-1, H, W, 2) float flow t -> t+1 in image pixels.
        flow_bwd: (T-1, H, W, 2) float flow t+1 -> t in image pixels (``flow_bwd[t]`` lives on frame t+1).
        scale: image pixels per track unit (H / h for latent-pixel tracks), > 0; a pair (sx, sy) = (W / w,
            H / h) when the two axes differ.
        fb_tolerance: absolute forward-backward tolerance in image pixels, >= 0.
        fb_relative: relative forward-backward tolerance per px^2, >= 0.

    Returns:
        :class:`Tracks` with N tracks over T = len(flow_fwd) + 1 frames.
    """
    flow_fwd = np.asarray(flow_fwd, dtype=np.float32)
    flow_bwd = np.asarray(flow_bwd, dtype=np.float32)
    _check_flows(flow_fwd, flow_bwd)
    seed_frames = np.asarray(seed_frames).reshape(-1)
    seed_xy = np.asarray(seed_xy, dtype=np.float64)
    N = seed_frames.shape[0]
    T = flow_fwd.shape[0] + 1
    H, W = flow_fwd.shape[1:3]
    if seed_xy.shape != (N, 2):
        raise TrackInputError(f"seed_xy must be ({N}, 2), got {seed_xy.shape}")
    if N and not np.issubdtype(seed_frames.dtype, np.integer):
        raise TrackInputError("seed_frames must be integers")
    seed_frames = seed_frames.astype(np.int64)
    padding = seed_frames == PADDING_SEED_FRAME
    if np.any((seed_frames < 0) & ~padding) or np.any(seed_frames >= T):
        raise TrackInputError(f"seed frames must lie in [0, {T}) or be {PADDING_SEED_FRAME} (padding)")
    if not np.all(np.isfinite(seed_xy)):
        raise TrackInputError("seed_xy holds non-finite values")
    try:
        scale_xy = np.broadcast_to(np.asarray(scale, dtype=np.float64), (2,)).copy()
    except (TypeError, ValueError) as exc:
        raise TrackInputError(f"scale must be a number or a pair (sx, sy), got {scale!r}") from exc
    if not (np.all(np.isfinite(scale_xy)) and np.all(scale_xy > 0)):
        raise TrackInputError(f"scale must be finite and positive, got {scale!r}")
    if not (np.isfinite(fb_tolerance) and fb_tolerance >= 0 and np.isfinite(fb_relative) and fb_relative >= 0):
        raise TrackInputError("fb_tolerance and fb_relative must be finite non-negative numbers")
    if not (np.all(np.isfinite(flow_fwd)) and np.all(np.isfinite(flow_bwd))):
        raise TrackInputError("flows hold non-finite values")

    to_px = lambda p: (p + 0.5) * scale_xy - 0.5  # noqa: E731  track units -> image pixels
    to_units = lambda q: (q + 0.5) / scale_xy - 0.5  # noqa: E731

    xy = np.zeros((N, T, 2), dtype=np.float64)
    valid = np.zeros((N, T), dtype=bool)
    seed_px = to_px(seed_xy)
    inside0 = _inside(seed_px, H, W)
    for direction in (+1, -1):
        pos = seed_px.copy()
        alive = np.zeros(N, dtype=bool)
        started = np.zeros(N, dtype=bool)
        frames = range(T) if direction > 0 else range(T - 1, -1, -1)
        for t in frames:
            start = (seed_frames == t) & ~padding
            pos[start] = seed_px[start]
            alive[start] = inside0[start]
            started |= start
            xy[started, t] = to_units(pos[started])
            valid[started, t] |= alive[started]
            nxt = t + direction
            if nxt < 0 or nxt >= T or not np.any(alive):
                continue
            step_flow, back_flow = (flow_fwd[t], flow_bwd[t]) if direction > 0 else (flow_bwd[t - 1], flow_fwd[t - 1])
            idx = np.flatnonzero(alive)
            f = bilinear_sample(step_flow, pos[idx]).astype(np.float64)
            moved = pos[idx] + f
            ok = _inside(moved, H, W)
            b = bilinear_sample(back_flow, moved).astype(np.float64)
            err = np.linalg.norm(f + b, axis=1)
            ok &= err <= fb_tolerance + fb_relative * ((f**2).sum(1) + (b**2).sum(1))
            pos[idx[ok]] = moved[ok]
            alive[idx[~ok]] = False
    # positions of padding rows stay (0, 0); clamp everything into the frame in track units
    xy[..., 0] = np.clip(xy[..., 0], -0.5, W / scale_xy[0] - 0.5)
    xy[..., 1] = np.clip(xy[..., 1], -0.5, H / scale_xy[1] - 0.5)
    xy[padding] = 0.0
    return Tracks(xy=xy.astype(np.float32), valid=valid, seed_frame=seed_frames)


def _inside(px: np.ndarray, H: int, W: int) -> np.ndarray:
    return (px[:, 0] >= -0.5) & (px[:, 0] <= W - 0.5) & (px[:, 1] >= -0.5) & (px[:, 1] <= H - 0.5)
