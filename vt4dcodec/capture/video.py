"""Read a window of frames from a video file with PyAV: seek, then decode only as far as the window.

Frame ``k`` of a video is the ``k``-th frame it presents (what decoding from the beginning and counting
gives).  To read frames ``[start, start + count)`` without decoding what comes before, the reader maps
presentation timestamps to frame numbers on the stream's frame-rate grid (``k = (pts - start_time) x
rate x time_base``), seeks to the keyframe at or before frame ``start`` and decodes forward, stopping
after the window: the cost is one group of pictures plus the window, whatever the video's length.
The grid is trusted only while every decoded frame lands on it (within a quarter frame) and the frames
follow one another without gaps; a video whose timestamps do not (variable frame rate, missing
timestamps, a seek that lands after the window) is read again by decoding from its first frame and
counting, which is exact for any file but costs the frames before the window.

Any container and codec the installed FFmpeg (through PyAV) decodes is accepted: H.264, H.265/HEVC,
VP8, VP9, AV1, MPEG-4 Part 2, Motion JPEG, ... in mp4, mov, mkv, webm or avi.  Problems are
:class:`~vt4dcodec.errors.CaptureError` naming the file and the fix.
"""

from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..errors import CaptureError

__all__ = ["read_video_window", "TRANSCODE_HINT"]

TRANSCODE_HINT = "transcode it to H.264 mp4 (ffmpeg -i IN -c:v libx264 -pix_fmt yuv420p OUT.mp4)"
_GRID_TOLERANCE = 0.25  # frames: how far a timestamp may sit from the frame-rate grid


class _OffGrid(Exception):
    """The timestamps do not follow the frame-rate grid: read by counting instead."""


def _grid(stream: Any) -> tuple[int, Fraction] | None:
    """(first pts, pts per frame) of ``stream``, or None when its timestamps cannot place frames."""
    rate = stream.average_rate or stream.guessed_rate
    if not rate or stream.time_base is None or stream.start_time is None:
        return None
    per_frame = 1 / (Fraction(rate) * Fraction(stream.time_base))
    return (int(stream.start_time), per_frame) if per_frame > 0 else None


def _frames_by_grid(container: Any, stream: Any, grid: tuple[int, Fraction], start: int) -> Iterator[tuple[int, Any]]:
    """(frame number, frame) from the keyframe at or before ``start`` on; _OffGrid when the grid fails."""
    origin, per_frame = grid
    if start > 0:
        container.seek(int(origin + start * per_frame), stream=stream, backward=True, any_frame=False)
    previous = None
    for frame in container.decode(stream):
        if frame.pts is None:
            raise _OffGrid
        position = (frame.pts - origin) / per_frame
        index = round(position)
        if abs(position - index) > _GRID_TOLERANCE:
            raise _OffGrid
        if previous is None and index > start:
            raise _OffGrid  # the seek landed after the window
        if previous is not None and index != previous + 1:
            raise _OffGrid  # a gap or a repeat: not a constant-rate stream
        previous = index
        yield index, frame


def _frames_by_count(container: Any, stream: Any) -> Iterator[tuple[int, Any]]:
    yield from enumerate(container.decode(stream))


def _read(path: Path, start: int, count: int, size: tuple[int, int], total: int | None, where: str,
          by_grid: bool) -> np.ndarray:
    import av

    width, height = size
    out = np.empty((count, height, width, 3), dtype=np.uint8)
    with av.open(str(path)) as container:
        if not container.streams.video:
            raise CaptureError(f"{where}: {path} holds no video stream")
        stream = container.streams.video[0]
        coded = (int(stream.codec_context.width), int(stream.codec_context.height))
        if coded != (width, height):
            raise CaptureError(f"{where}: {path} is {coded[0]}x{coded[1]}, manifest says {width}x{height}")
        if total is not None and stream.frames and stream.frames != total:
            raise CaptureError(f"{where}: {path} declares {stream.frames} frames but the manifest says {total}; trim "
                               "the video or fix num_frames")
        stream.thread_type = "AUTO"
        grid = _grid(stream) if by_grid else None
        if by_grid and grid is None:
            raise _OffGrid
        frames = _frames_by_count(container, stream) if grid is None else _frames_by_grid(container, stream, grid, start)
        got = 0
        seen = 0
        for index, frame in frames:
            seen = index + 1
            if index < start:
                continue
            if index >= start + count:
                if total is not None and start + count >= total:
                    raise CaptureError(f"{where}: {path} has more than the {total} frames the manifest says")
                break
            if (frame.width, frame.height) != (width, height):
                raise CaptureError(f"{where}: frame {index} of {path} is {frame.width}x{frame.height}, manifest "
                                   f"says {width}x{height}")
            out[index - start] = frame.to_ndarray(format="rgb24")
            got += 1
            if got == count and (total is None or start + count < total):
                break
        if got < count:
            raise CaptureError(f"{where}: {path} has {seen} frames but frames {start}..{start + count - 1} were asked "
                               f"for{'' if total is None else f' (the manifest says {total})'}")
    return out


def read_video_window(path: str | os.PathLike, start: int, count: int, *, width: int, height: int,
                      total: int | None = None, where: str = "video") -> np.ndarray:
    """Frames ``[start, start + count)`` of the first video stream of ``path`` as (count, height, width, 3)
    uint8 RGB, decoding from the keyframe before ``start`` and stopping after the window.

    ``total`` (the frame count the manifest states) is checked against the container's declared count
    where it has one, and, when the window reaches the end, against the frames actually there.
    """
    path = Path(path)
    if not path.is_file():
        raise CaptureError(f"{where}: missing video {path}")
    if start < 0 or count < 1:
        raise CaptureError(f"{where}: frames {start}..{start + count - 1} is not a window of {path}")
    import av

    try:
        try:
            return _read(path, start, count, (width, height), total, where, by_grid=True)
        except _OffGrid:
            return _read(path, start, count, (width, height), total, where, by_grid=False)
    except av.FFmpegError as exc:
        raise CaptureError(f"{where}: cannot decode {path} ({exc}); {TRANSCODE_HINT}") from None
