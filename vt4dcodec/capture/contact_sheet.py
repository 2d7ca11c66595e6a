"""Contact sheets: one PNG showing a capture as a grid, cameras down, frames across (numpy + OpenCV).

From a capture directory, :func:`read_sheet_frames` decodes only the frames a sheet shows.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import CaptureError
from .capture import Capture
from .io import read_capture, read_manifest

__all__ = ["contact_sheet", "write_contact_sheet", "read_sheet_frames"]

LABEL_WIDTH = 72  # pixels left of each row for the camera name
HEADER_HEIGHT = 16  # pixels above the grid for frame numbers
GAP = 2


def _frame_indices(total: int, max_frames: int) -> np.ndarray:
    if max_frames < 1:
        raise CaptureError(f"a contact sheet needs at least one frame column, got {max_frames}")
    if total <= max_frames:
        return np.arange(total)
    return np.unique(np.round(np.linspace(0, total - 1, max_frames)).astype(int))


def read_sheet_frames(directory: "str | os.PathLike", max_frames: int = 8) -> tuple[Capture, list[int]]:
    """The ``max_frames`` evenly spaced frames a sheet of the capture directory shows, every camera, read
    one frame at a time (videos seeked): (a capture of just those frames, their frame numbers)."""
    manifest = read_manifest(directory)
    numbers = [int(i) for i in _frame_indices(manifest.num_frames, max_frames)]
    parts = [read_capture(manifest, start=i, num_frames=1) for i in numbers]
    first = parts[0]
    return Capture(cameras={n: t[np.zeros(len(numbers), int)] for n, t in first.cameras.items()},
                   frames={n: np.concatenate([p.frames[n] for p in parts]) for n in first.cameras},
                   fps=first.fps, capture_id=first.capture_id, metadata=first.metadata), numbers


def contact_sheet(capture: Capture, *, max_frames: int = 8, thumb_height: int = 96,
                  frame_numbers: "list[int] | None" = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB grid: one row per camera (labelled), ``max_frames`` evenly spaced frames.

    Thumbnails keep each camera's aspect ratio at ``thumb_height`` pixels high; the column headers are
    frame indices, or ``frame_numbers`` (one per frame of ``capture``, which is then shown whole: the
    frames :func:`read_sheet_frames` read).
    """
    import cv2

    if thumb_height < 8:
        raise CaptureError(f"thumb_height must be at least 8 pixels, got {thumb_height}")
    if frame_numbers is not None and len(frame_numbers) != capture.num_frames:
        raise CaptureError(f"{len(frame_numbers)} frame numbers for a capture of {capture.num_frames} frames")
    idx = np.arange(capture.num_frames) if frame_numbers is not None else _frame_indices(capture.num_frames,
                                                                                         max_frames)
    labels = frame_numbers if frame_numbers is not None else [int(f) for f in idx]
    thumb_w = {
        n: max(1, int(round(t.width * thumb_height / t.height))) for n, t in capture.cameras.items()
    }
    col_w = max(thumb_w.values())
    width = LABEL_WIDTH + len(idx) * (col_w + GAP)
    height = HEADER_HEIGHT + len(capture.cameras) * (thumb_height + GAP)
    sheet = np.full((height, width, 3), 255, dtype=np.uint8)
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.4
    for j, label in enumerate(labels):
        x = LABEL_WIDTH + j * (col_w + GAP)
        cv2.putText(sheet, f"t={label}", (x + 2, HEADER_HEIGHT - 4), font, scale, (0, 0, 0), 1, cv2.LINE_AA)
    for r, (name, video) in enumerate(capture.frames.items()):
        y = HEADER_HEIGHT + r * (thumb_height + GAP)
        cv2.putText(sheet, name[:10], (3, y + thumb_height // 2 + 4), font, scale, (0, 0, 0), 1, cv2.LINE_AA)
        for j, f in enumerate(idx):
            x = LABEL_WIDTH + j * (col_w + GAP)
            interp = cv2.INTER_AREA if thumb_height < video.shape[1] else cv2.INTER_NEAREST
            thumb = cv2.resize(video[f], (thumb_w[name], thumb_height), interpolation=interp)
            sheet[y:y + thumb_height, x:x + thumb_w[name]] = thumb
    return sheet


def write_contact_sheet(capture: Capture, path: str | os.PathLike, *, max_frames: int = 8,
                        thumb_height: int = 96, frame_numbers: "list[int] | None" = None) -> tuple[int, int]:
    """Write :func:`contact_sheet` as a PNG; returns its (width, height)."""
    import cv2

    sheet = contact_sheet(capture, max_frames=max_frames, thumb_height=thumb_height, frame_numbers=frame_numbers)
    path = Path(path)
    if not cv2.imwrite(str(path), np.ascontiguousarray(sheet[..., ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 9]):
        raise OSError(f"could not write PNG {path}")
    return sheet.shape[1], sheet.shape[0]
