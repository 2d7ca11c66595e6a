"""Writing rendered frames: mp4 (H.264 through PyAV), PNG sequences and .npz arrays."""

from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path

import numpy as np

from .errors import Vt4dError

__all__ = ["VIDEO_FORMATS", "MP4_CODEC", "MAX_UPSCALE", "DEFAULT_FPS", "CAPTURE_KEY", "scene_fps", "write_mp4",
           "read_mp4", "mp4_codec_name", "upscale",
           "side_by_side", "write_png_frames", "write_frames", "psnr"]

VIDEO_FORMATS = ("mp4", "png", "npz")
MP4_CODEC = "h264"   # what every mp4 the project writes holds (decoder name, as PyAV reports it)
MAX_UPSCALE = 16     # nearest-neighbour factor for viewing; 64x64 renders x4 -> 256x256
DEFAULT_FPS = 8.0    # videos of scenes that record no frame rate (the synthetic captures' rate)
CAPTURE_KEY = "capture"  # scene metadata {"capture": {"fps": F}}: the frame rate of the capture it was encoded from
_CRF = 16            # libx264 constant-rate factor: visually lossless for small renders, a few KB a clip


def _check(frames: np.ndarray) -> np.ndarray:
    frames = np.asarray(frames)
    if frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
        raise Vt4dError(f"frames must be (T, H, W, 3) uint8, got {frames.dtype} {frames.shape}")
    if frames.shape[0] == 0:
        raise Vt4dError("frames must hold at least one frame")
    return frames


def scene_fps(scene: object, default: float = DEFAULT_FPS) -> float:
    """The frame rate a scene's videos play at: the capture's, as ``vt4d encode`` records it in the metadata
    (``{"capture": {"fps": F}}``), else the one its cameras' timestamps give (median frame interval), else
    ``default``."""
    metadata = getattr(scene, "metadata", None) or {}
    recorded = metadata.get(CAPTURE_KEY) if isinstance(metadata, dict) else None
    fps = recorded.get("fps") if isinstance(recorded, dict) else None
    if isinstance(fps, (int, float)) and not isinstance(fps, bool) and np.isfinite(fps) and fps > 0:
        return float(fps)
    cameras = getattr(scene, "cameras", None)
    times = getattr(cameras, "timestamps", None)
    if times is not None and len(times) > 1:
        step = float(np.median(np.diff(np.asarray(times, np.float64))))
        if np.isfinite(step) and step > 0:
            return 1.0 / step
    return default


def upscale(frames: np.ndarray, factor: int) -> np.ndarray:
    """``frames`` (T, H, W, 3) enlarged ``factor`` times by pixel repetition (nearest neighbour): a 64x64
    render becomes readable on a screen without inventing detail.  ``factor`` 1 returns the frames."""
    if isinstance(factor, bool) or not isinstance(factor, (int, np.integer)) or not 1 <= factor <= MAX_UPSCALE:
        raise Vt4dError(f"upscale factor must be an integer in 1..{MAX_UPSCALE}, got {factor!r}")
    frames = _check(frames)
    if factor == 1:
        return frames
    return np.repeat(np.repeat(frames, factor, axis=1), factor, axis=2)


def side_by_side(*videos: np.ndarray, gap: int = 2) -> np.ndarray:
    """Videos of equal frame count and height placed left to right, ``gap`` white columns between them
    (the demo's ground truth | decoded video)."""
    if not videos:
        raise Vt4dError("side_by_side needs at least one video")
    videos = tuple(_check(v) for v in videos)
    if len({v.shape[:2] for v in videos}) != 1:
        raise Vt4dError(f"side_by_side needs equal frame counts and heights, got {[v.shape for v in videos]}")
    T, H = videos[0].shape[:2]
    spacer = np.full((T, H, gap, 3), 255, np.uint8)
    parts = [videos[0]]
    for v in videos[1:]:
        parts += [spacer, v]
    return np.concatenate(parts, axis=2)


def write_mp4(path: str | os.PathLike, frames: np.ndarray, fps: float = DEFAULT_FPS, *, scale: int = 1) -> Path:
    """Write RGB ``frames`` (T, H, W, 3) uint8 as an H.264 (High profile, yuv420p) ``.mp4`` through PyAV:
    plays in browsers, notebooks and common players.  ``scale`` > 1 enlarges the frames by pixel
    repetition first (for viewing small renders).  H.264 in yuv420p needs even sides: an odd width or
    height gets one more column or row repeating the last one (the decoded video is that much larger)."""
    try:
        import av
    except ImportError:
        raise Vt4dError('writing mp4 needs PyAV, in the codec extra: pip install -e ".[codec]" in a clone of '
                        'vt4dcodec (README, install)') from None
    frames = upscale(frames, scale)
    if not (np.isfinite(fps) and fps > 0):
        raise Vt4dError(f"fps must be a positive number, got {fps!r}")
    T, H, W, _ = frames.shape
    if H % 2 or W % 2:
        frames = np.pad(frames, ((0, 0), (0, H % 2), (0, W % 2), (0, 0)), mode="edge")
        T, H, W, _ = frames.shape
    path = Path(path)
    try:
        with av.open(str(path), mode="w", format="mp4", options={"movflags": "+faststart"}) as container:
            stream = container.add_stream("libx264", rate=Fraction(float(fps)).limit_denominator(1001))
            stream.width, stream.height, stream.pix_fmt = W, H, "yuv420p"
            stream.options = {"crf": str(_CRF), "preset": "medium", "profile": "high"}
            for frame in frames:
                container.mux(stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")))
            container.mux(stream.encode(None))
    except av.FFmpegError as exc:
        raise OSError(f"cannot write {path}: {exc}") from None
    return path


def mp4_codec_name(path: str | os.PathLike) -> str:
    """The codec of the first video stream of ``path`` as FFmpeg names it (``"h264"`` for ours)."""
    import av

    with av.open(str(path)) as container:
        return container.streams.video[0].codec_context.name


def read_mp4(path: str | os.PathLike) -> np.ndarray:
    """Every frame of the first video stream of ``path`` as (T, H, W, 3) uint8 RGB (PyAV)."""
    import av

    try:
        with av.open(str(path)) as container:
            frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    except av.FFmpegError as exc:
        raise Vt4dError(f"cannot read video {path}: {exc}") from None
    if not frames:
        raise Vt4dError(f"video {path} holds no frames")
    return np.stack(frames)


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


def write_frames(stem: str | os.PathLike, frames: np.ndarray, fmt: str, *, fps: float = DEFAULT_FPS,
                 extra: dict[str, np.ndarray] | None = None, scale: int = 1) -> Path:
    """Write ``frames`` as ``stem.mp4``, ``stem/`` (PNG frames) or ``stem.npz`` (key ``frames`` plus
    ``extra`` arrays such as the trajectory's K and w2c).  ``scale`` (nearest-neighbour upscaling for
    viewing) applies to mp4 only: PNG frames and arrays keep the rendered pixels, which the stored K
    describes."""
    if fmt not in VIDEO_FORMATS:
        raise Vt4dError(f"unknown output format {fmt!r}; choose one of {VIDEO_FORMATS}")
    if scale != 1 and fmt != "mp4":
        raise Vt4dError(f"upscaling is for mp4 videos only (format {fmt!r} keeps the rendered pixels)")
    stem = Path(stem)
    if fmt == "mp4":
        return write_mp4(stem.with_suffix(".mp4"), frames, fps, scale=scale)
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
