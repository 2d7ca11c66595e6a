"""Source preprocessing: a calibrated clip -> :class:`model.inputs.source_inputs.SourceInputs`.

Runs the non-learned half of Track-Aware Dynamic Attention once per clip (in DataLoader workers during
training, once per encode at inference): DIS flow, pose-compensated motion isolation at latent
resolution (:mod:`model.inputs.motion`), track seeds sampled from the masks and propagated by the flow
(:mod:`model.inputs.tracks`).  When the capture carries no depth it is estimated by plane sweep
(:mod:`model.inputs.depth`).  Lens distortion, if the trajectory has any, is removed first (frames resampled
to the same pinhole ``K``), because every later step assumes a pinhole camera.
"""

from __future__ import annotations

import cv2
import numpy as np

from vt4dcodec.cameras import Trajectory

from .motion import DEFAULT_DEPTH_RANGE, MotionInputError, estimate_flows, isolate_motion
from .source_inputs import SourceInputs
from .tracks import propagate_tracks, sample_seeds

__all__ = ["prepare_source", "undistort_clip", "DEFAULT_NUM_TRACKS", "SEED_MIN_FRACTION"]

DEFAULT_NUM_TRACKS = 64
SEED_MIN_FRACTION = 0.25  # a latent cell is seeded only if at least this fraction of its pixels moves


def undistort_clip(
    frames: np.ndarray, trajectory: Trajectory, depth: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Resample frames (bilinear) and depth (nearest) to the ideal pinhole camera with the same ``K``.

    Returns the inputs unchanged when the trajectory has no (or all-zero) distortion.  Not the same
    resampling as ``vt4dcodec.capture.resample.FrameFitter`` (which the codec applies first, so its clips
    arrive here without distortion): here colour outside the source image repeats the edge pixel
    (BORDER_REPLICATE; FrameFitter writes black) and the size and ``K`` are kept (FrameFitter fuses the
    undistortion with its resize and centre crop, area-prefiltering when it shrinks).
    """
    dist = trajectory.distortion
    if dist is None or not np.any(dist):
        return frames, depth
    T, H, W = frames.shape[:3]
    out = np.empty_like(frames)
    out_depth = None if depth is None else np.empty_like(depth)
    for t in range(T):
        K = trajectory.K[t]
        mx, my = cv2.initUndistortRectifyMap(K, dist, None, K, (W, H), cv2.CV_32FC1)
        out[t] = cv2.remap(frames[t], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if depth is not None:
            out_depth[t] = cv2.remap(depth[t], mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out, out_depth


def prepare_source(
    frames: np.ndarray,
    trajectory: Trajectory,
    depth: np.ndarray | None,
    *,
    latent_hw: tuple[int, int] = (16, 16),
    num_tracks: int = DEFAULT_NUM_TRACKS,
    seed: int = 0,
    motion_isolation: bool = True,
    depth_range: tuple[float, float] = DEFAULT_DEPTH_RANGE,
) -> SourceInputs:
    """Everything the encoder needs about one source clip.

    Args:
        frames: (T, H, W, 3) uint8 RGB, H, W >= 8.
        trajectory: the clip's cameras (T poses; ``width`` x ``height`` must match the frames).
        depth: (T, H, W) float32 metric z-depth (<= 0 / non-finite = unknown) or None (estimated by
            plane sweep over ``depth_range`` metres).
        latent_hw: (h, w) latent grid of the frozen autoencoder.
        num_tracks: N, the fixed number of tracks (padding tracks are invalid everywhere).
        seed: seeds the track sampling; same inputs and seed give the same output.
        motion_isolation: False is the paper's "w/o Motion Isolation" ablation: the mask is all ones
            (no depth needed) and seeds come from the whole frame, but tracks still follow the flow.
        depth_range: (near, far) for the plane sweep when ``depth`` is None.

    Returns:
        :class:`SourceInputs` with ``motion_mask`` (T, h, w) in [0, 1] and tracks in latent pixels.
    """
    if not isinstance(trajectory, Trajectory):
        raise MotionInputError("trajectory must be a vt4dcodec.cameras.Trajectory")
    if not isinstance(frames, np.ndarray) or frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
        raise MotionInputError("frames must be a (T, H, W, 3) uint8 array")
    T, H, W = frames.shape[:3]
    if trajectory.num_frames != T or (trajectory.height, trajectory.width) != (H, W):
        raise MotionInputError(
            f"trajectory is {trajectory.num_frames} frames of {trajectory.width}x{trajectory.height}, "
            f"frames are {T} of {W}x{H}"
        )
    if isinstance(num_tracks, bool) or not isinstance(num_tracks, (int, np.integer)) or num_tracks < 0:
        raise MotionInputError(f"num_tracks must be a non-negative integer, got {num_tracks!r}")
    if depth is not None:
        depth = np.asarray(depth, dtype=np.float32)
        if depth.shape != (T, H, W):
            raise MotionInputError(f"depth must be ({T}, {H}, {W}), got {depth.shape}")
    frames, depth = undistort_clip(frames, trajectory, depth)
    h, w = latent_hw
    if motion_isolation:
        iso = isolate_motion(frames, trajectory.K, trajectory.w2c, depth, latent_hw=latent_hw, depth_range=depth_range)
        flow_fwd, flow_bwd, mask_latent = iso.flow_fwd, iso.flow_bwd, iso.mask_latent
    else:
        flow_fwd, flow_bwd = estimate_flows(frames)
        if not (isinstance(h, (int, np.integer)) and isinstance(w, (int, np.integer)) and 1 <= h <= H and 1 <= w <= W):
            raise MotionInputError(f"latent_hw must be positive integers no larger than the frame, got {latent_hw}")
        mask_latent = np.ones((T, h, w), np.float32)
    rng = np.random.default_rng(seed)
    seed_frames, seed_xy = sample_seeds(mask_latent, num_tracks, rng=rng, min_weight=SEED_MIN_FRACTION - 1e-6)
    tracks = propagate_tracks(seed_frames, seed_xy, flow_fwd, flow_bwd, scale=(W / w, H / h))
    return SourceInputs(
        frames=np.ascontiguousarray(frames),
        K=trajectory.K.astype(np.float32),
        w2c=trajectory.w2c.astype(np.float32),
        motion_mask=mask_latent.astype(np.float32),
        track_xy=tracks.xy,
        track_valid=tracks.valid,
    )
