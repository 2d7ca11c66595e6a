"""The in-memory capture: synchronized multi-camera video with calibration (numpy only).

A capture is what the codec compresses.  On disk it is a capture directory (FORMAT.md, "Captures");
``vt4dcodec.capture.io`` reads and writes it.  Here it is plain arrays that are validated once.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..cameras import Trajectory
from ..errors import CaptureError

__all__ = ["Capture"]


@dataclass
class Capture:
    """Synchronized videos of one event from several cameras.

    Attributes:
        cameras: camera name -> :class:`Trajectory` (one pose and K per frame), in camera order.
        frames: camera name -> (T, H, W, 3) uint8 RGB frames, H and W matching the trajectory.
        depth: optional camera name -> (T, H, W) float32 metric depth (z in the camera frame, metres;
            0 or non-finite where unknown).
        fps: frames per second of the synchronized clock.
        capture_id: a stable name for the capture (stored as provenance in encoded scenes).
        metadata: free-form JSON-like information about the capture.
    """

    cameras: dict[str, Trajectory]
    frames: dict[str, np.ndarray]
    depth: dict[str, np.ndarray] | None = None
    fps: float = 30.0
    capture_id: str = "capture"
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.cameras:
            raise CaptureError("a capture needs at least one camera")
        if set(self.frames) != set(self.cameras):
            raise CaptureError(
                f"frames are given for cameras {sorted(self.frames)} but calibration for {sorted(self.cameras)}"
            )
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise CaptureError(f"fps must be a positive number, got {self.fps!r}")
        counts = set()
        for name, traj in self.cameras.items():
            if not isinstance(traj, Trajectory):
                raise CaptureError(f"camera {name!r}: calibration must be a Trajectory")
            video = self.frames[name]
            if not isinstance(video, np.ndarray) or video.dtype != np.uint8 or video.ndim != 4 or video.shape[-1] != 3:
                raise CaptureError(f"camera {name!r}: frames must be a (T, H, W, 3) uint8 array")
            T, H, W, _ = video.shape
            if (H, W) != (traj.height, traj.width):
                raise CaptureError(
                    f"camera {name!r}: frames are {W}x{H} but its calibration is for {traj.width}x{traj.height}"
                )
            if T != traj.num_frames:
                raise CaptureError(f"camera {name!r}: {T} frames but {traj.num_frames} poses")
            counts.add(T)
            if self.depth is not None and name in self.depth:
                d = self.depth[name]
                if not isinstance(d, np.ndarray) or d.shape != (T, H, W):
                    raise CaptureError(f"camera {name!r}: depth must be a (T, H, W) array, one map per frame")
        if len(counts) != 1:
            raise CaptureError(f"cameras have different frame counts {sorted(counts)}; a capture is synchronized")
        if self.depth is not None:
            unknown = set(self.depth) - set(self.cameras)
            if unknown:
                raise CaptureError(f"depth given for unknown cameras {sorted(unknown)}")

    @property
    def camera_names(self) -> list[str]:
        return list(self.cameras)

    @property
    def num_frames(self) -> int:
        return next(iter(self.cameras.values())).num_frames

    def has_depth(self, camera: str) -> bool:
        return self.depth is not None and camera in self.depth
