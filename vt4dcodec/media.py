"""Writing rendered frames: mp4 (OpenCV's MPEG-4 writer), PNG sequences and .npz arrays."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .errors import Vt4dError

__all__ = ["VIDEO_FORMATS", "write_mp4", "write_png_frames", "write_frames", "psnr"]

VIDEO_FORMATS = ("mp4", "png", "npz")


def _check(frames: np.ndarray) -> np.ndarray:
    frames = np.asarray(frames)
    if frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
        raise Vt4dError(f"frames must be (T, H, W, 3) uint8, got {frames.dtype} {frames.shape}")
    return frames


def write_mp4(path: str | os.PathLike, frames: np.ndarray, fps: float = 8.0) -> Path:
    """Write RGB ``frames`` (T, H, W, 3) uint8 as an MPEG-4 Part 2 ``.mp4`` (plays in common players)."""
    import cv2

    frames = _check(frames)
    T, H, W, _ = frames.shape
    path = Path(path)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (W, H))
    if not writer.isOpened():
        raise OSError(f"OpenCV cannot write {path} (mp4v codec unavailable?)")
    try:
        for frame in frames:
            writer.write(np.ascontiguousarray(frame[..., ::-1]))
    finally:
        writer.release()
    return path


def write_png_frames(directory: str | os.PathLike, frames: np.ndarray) -> Path:
    """Write ``frames`` as ``directory/000000.png``, ``000001.png``... (lossless)."""
    import cv2

    frames = _check(frames)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    for i, frame in enumerate(frames):
        if not cv2.imwrite(str(directory / f"{i:06d}.png"), np.ascontiguousarray(frame[..., ::-1])):
            raise OSError(f"cannot write {directory / f'{i:06d}.png'}")
    return directory


def write_frames(stem: str | os.PathLike, frames: np.ndarray, fmt: str, *, fps: float = 8.0,
                 extra: dict[str, np.ndarray] | None = None) -> Path:
    """Write ``frames`` as ``stem.mp4``, ``stem/`` (PNG frames) or ``stem.npz`` (key ``frames`` plus
    ``extra`` arrays such as the trajectory's K and w2c)."""
    if fmt not in VIDEO_FORMATS:
        raise Vt4dError(f"unknown output format {fmt!r}; choose one of {VIDEO_FORMATS}")
    stem = Path(stem)
    if fmt == "mp4":
        return write_mp4(stem.with_suffix(".mp4"), frames, fps)
    if fmt == "png":
        return write_png_frames(stem, frames)
    out = stem.with_suffix(".npz")
    np.savez_compressed(out, frames=_check(frames), **(extra or {}))
    return out


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """PSNR in dB between uint8 images/videos of equal shape (peak 255), optionally over ``mask`` pixels."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise Vt4dError(f"PSNR needs equal shapes, got {a.shape} and {b.shape}")
    err = (a - b) ** 2
    if mask is not None:
        m = np.broadcast_to(np.asarray(mask, bool)[..., None], err.shape)
        if not m.any():
            return float("nan")
        mse = float(err[m].mean())
    else:
        mse = float(err.mean())
    return float("inf") if mse == 0 else 10.0 * np.log10(255.0**2 / mse)
