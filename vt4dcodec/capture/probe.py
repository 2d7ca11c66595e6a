"""Probe media without decoding them whole: size, frame count, codec, and whether the first frame decodes.

Videos are probed with PyAV: the container's stream gives the size and codec, the frame count is the
number of video packets (demuxed, not decoded), and only the first frame is decoded.  PNG sequences are
probed from each file's signature and IHDR chunk (the first 33 bytes), decoding only the first file.
:func:`check_capture` probes every medium of a capture directory against its manifest
(``vt4d capture-info --check``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import CaptureError
from .io import PNG_NAME, CaptureManifest, _safe_relpath, read_manifest

__all__ = ["MediaInfo", "probe_video", "probe_png", "probe_png_sequence", "check_capture", "VIDEO_SUFFIXES",
           "IMAGE_SUFFIXES"]

VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".webm", ".avi")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclass(frozen=True)
class MediaInfo:
    """What a probe found: size, frame count, codec (``"png"`` for PNG sequences), frame rate (None if
    unknown) and whether the first frame decoded."""

    path: str
    width: int
    height: int
    num_frames: int
    codec: str
    fps: float | None
    decodable: bool

    def as_dict(self) -> dict[str, Any]:
        return {"path": self.path, "width": self.width, "height": self.height, "num_frames": self.num_frames,
                "codec": self.codec, "fps": self.fps, "decodable": self.decodable}


def probe_video(path: str | os.PathLike) -> MediaInfo:
    """Size, codec and frame count of the first video stream of ``path``, decoding only its first frame."""
    import av

    path = Path(path)
    if not path.is_file():
        raise CaptureError(f"{path}: video not found")
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise CaptureError(f"{path}: holds no video stream")
            stream = container.streams.video[0]
            width, height = int(stream.codec_context.width), int(stream.codec_context.height)
            codec = stream.codec_context.name
            rate = stream.average_rate or stream.guessed_rate
            fps = float(rate) if rate else None
            count = sum(1 for p in container.demux(stream) if p.size > 0)
        with av.open(str(path)) as container:
            decodable = next(iter(container.decode(video=0)), None) is not None
    except av.FFmpegError as exc:
        raise CaptureError(f"{path}: not a video FFmpeg can read ({exc}); transcode it to H.264 mp4 "
                           "(ffmpeg -i IN -c:v libx264 -pix_fmt yuv420p OUT.mp4)") from None
    return MediaInfo(str(path), width, height, count, codec, fps, decodable)


def probe_png(path: Path) -> tuple[int, int]:
    """(width, height) of a PNG from its IHDR chunk; CaptureError when it is not a PNG."""
    with path.open("rb") as fh:
        head = fh.read(24)
    if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        raise CaptureError(f"{path}: not a PNG file")
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def probe_png_sequence(folder: str | os.PathLike) -> MediaInfo:
    """A capture PNG folder (``000000.png``...): its frame count and common size from the PNG headers,
    decoding only the first file.  Gaps, stray files and size changes are CaptureErrors."""
    import cv2

    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureError(f"{folder}: PNG folder not found")
    present = sorted(p.name for p in folder.glob("*.png"))
    expected = [PNG_NAME.format(i) for i in range(len(present))]
    if not present or present != expected:
        raise CaptureError(f"{folder}: holds {len(present)} PNGs, not the files 000000.png ... numbered from 0 "
                           "without gaps")
    sizes = {probe_png(folder / name) for name in present}
    if len(sizes) != 1:
        raise CaptureError(f"{folder}: PNGs of different sizes {sorted(sizes)}")
    width, height = sizes.pop()
    decodable = cv2.imread(str(folder / present[0]), cv2.IMREAD_COLOR) is not None
    return MediaInfo(str(folder), width, height, len(present), "png", None, decodable)


def check_capture(directory: str | os.PathLike | CaptureManifest) -> list[dict[str, Any]]:
    """Probe every camera's media against the manifest.  Returns one dict per camera: ``name``, ``probe``
    (a :meth:`MediaInfo.as_dict`, or None when it could not be probed) and ``problems`` (messages that
    name the camera, the file and the fix; empty when the medium matches)."""
    manifest = directory if isinstance(directory, CaptureManifest) else read_manifest(directory)
    out = []
    for entry in manifest.cameras:
        where = f"camera {entry.name!r}"
        problems: list[str] = []
        info = None
        try:
            path = _safe_relpath(manifest.directory, entry.media_path, where)
            info = probe_png_sequence(path) if entry.media_type == "png" else probe_video(path)
        except CaptureError as exc:
            problems.append(f"{where}: {exc}")
        if info is not None:
            t = entry.trajectory
            if (info.width, info.height) != (t.width, t.height):
                problems.append(f"{where}: {entry.media_path} is {info.width}x{info.height} but the manifest says "
                                f"{t.width}x{t.height}; fix width/height (and K, which refers to that size) in "
                                "capture.json")
            if info.num_frames != manifest.num_frames:
                problems.append(f"{where}: {entry.media_path} has {info.num_frames} frames but num_frames is "
                                f"{manifest.num_frames}; trim the media or fix num_frames")
            if not info.decodable:
                problems.append(f"{where}: the first frame of {entry.media_path} does not decode; re-encode it "
                                "(H.264 mp4 or PNG)")
        out.append({"name": entry.name, "probe": None if info is None else info.as_dict(), "problems": problems})
    return out
