"""Capture cameras as render targets: ``"camera:NAME"`` and full-length capture trajectories.

A scene encoded from a capture records its clip in ``metadata["vt4d"]`` (``clip_start``, ``clip_frames``)
and the capture in its provenance (``source_capture_id``).  :func:`camera_target` takes capture camera
NAME's trajectory for exactly the scene's frames; :func:`cut_to_clip` cuts any capture-length trajectory
to the scene's window.  The renderer draws ideal pinhole images, so a calibrated camera's distortion
terms are dropped (the render is that camera's undistorted view, the one the encoder saw).
"""

from __future__ import annotations

import os
from dataclasses import replace
from typing import Any

from ..cameras import Trajectory
from ..errors import TrajectoryError
from .capture import Capture
from .io import CAMERA_NAME, read_manifest

__all__ = ["CAMERA_PREFIX", "is_camera_spec", "check_camera_spec", "clip_window", "cut_to_clip", "camera_target"]

CAMERA_PREFIX = "camera:"


def is_camera_spec(spec: Any) -> bool:
    return isinstance(spec, str) and spec.startswith(CAMERA_PREFIX)


def check_camera_spec(spec: str) -> str:
    """The camera name of ``"camera:NAME"``; TrajectoryError when NAME is not a capture camera name."""
    name = spec[len(CAMERA_PREFIX):]
    if not CAMERA_NAME.match(name):
        raise TrajectoryError(f"{spec!r}: write camera:NAME with the name of a capture camera "
                              "(vt4d capture-info CAPTURE lists them)")
    return name


def clip_window(metadata: dict[str, Any] | None) -> tuple[int, int] | None:
    """(clip_start, clip_frames) recorded in a scene's ``metadata["vt4d"]``, or None (e.g. generated scenes)."""
    info = (metadata or {}).get("vt4d")
    if not isinstance(info, dict):
        return None
    start, frames = info.get("clip_start"), info.get("clip_frames")
    if isinstance(start, int) and isinstance(frames, int) and start >= 0 and frames >= 1:
        return start, frames
    return None


def cut_to_clip(traj: Trajectory, metadata: dict[str, Any] | None, max_frames: int) -> Trajectory:
    """``traj`` itself when it fits the scene's ``max_frames``; a capture-length trajectory is cut to the
    scene's clip window.  TrajectoryError, naming the fix, when neither works."""
    if traj.num_frames <= max_frames:
        return traj
    window = clip_window(metadata)
    if window is None:
        raise TrajectoryError(f"trajectory has {traj.num_frames} frames; a scene covers {max_frames} frames and "
                              f"records no clip window to cut it to: pass the {max_frames} frames it shows "
                              f"(trajectory[start:start + {max_frames}])")
    start, frames = window
    if start + frames > traj.num_frames:
        raise TrajectoryError(f"trajectory has {traj.num_frames} frames but the scene's clip is frames {start}.."
                              f"{start + frames - 1}: pass the capture camera the scene was encoded from")
    return traj[start:start + min(frames, max_frames)]


def camera_target(spec: str, capture: "Capture | str | os.PathLike | None", metadata: dict[str, Any] | None,
                  source_capture_id: str | None, max_frames: int) -> Trajectory:
    """Capture camera ``"camera:NAME"``'s trajectory over the scene's frames, as a pinhole camera.

    ``capture`` is a :class:`Capture` or a capture directory (only its manifest is read)."""
    name = check_camera_spec(spec)
    if capture is None:
        raise TrajectoryError(f"{spec!r} needs the capture the scene was encoded from"
                              f"{f' ({source_capture_id!r})' if source_capture_id else ''}: pass capture=DIR")
    if isinstance(capture, Capture):
        cameras, capture_id = capture.cameras, capture.capture_id
    else:
        manifest = read_manifest(capture)
        cameras, capture_id = {e.name: e.trajectory for e in manifest.cameras}, manifest.capture_id
    if source_capture_id is not None and capture_id != source_capture_id:
        raise TrajectoryError(f"the scene was encoded from capture {source_capture_id!r} but capture {capture_id!r} "
                              "was given: pass the capture it was encoded from")
    if name not in cameras:
        raise TrajectoryError(f"{spec!r}: capture {capture_id!r} has no camera {name!r}; it has {sorted(cameras)}")
    traj = cameras[name]
    if clip_window(metadata) is None and traj.num_frames > max_frames:
        raise TrajectoryError(f"{spec!r}: the scene records no clip (clip_start, clip_frames) to take camera "
                              f"{name!r}'s frames from; pass a trajectory of {max_frames} frames instead")
    traj = cut_to_clip(traj, metadata, max_frames)
    return replace(traj, distortion=None) if traj.distortion is not None else traj
