"""Small captures for the capture tests."""

import numpy as np

from vt4dcodec.cameras import Trajectory
from vt4dcodec.capture import Capture


def make_trajectory(T=3, width=32, height=24, *, moving=True, distortion=None, timestamps=True):
    K = np.array([[40.0, 0.0, (width - 1) / 2], [0.0, 41.0, (height - 1) / 2], [0.0, 0.0, 1.0]])
    w2c = np.stack([np.eye(4)] * T)
    if moving:
        w2c[:, 0, 3] = np.linspace(0.0, 0.3, T)
    ts = np.arange(T) / 10.0 if timestamps else None
    return Trajectory(K=np.stack([K] * T), w2c=w2c, width=width, height=height, distortion=distortion,
                      timestamps=ts)


def smooth_video(T, H, W, seed=0):
    """Smooth colour gradients that survive lossy video coding nearly unchanged."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:H, 0:W]
    frames = []
    for t in range(T):
        a, b, c = rng.uniform(0.5, 2.0, 3)
        img = np.stack([
            127 + 100 * np.sin(a * u / W * np.pi + t * 0.2),
            127 + 100 * np.cos(b * v / H * np.pi),
            127 + 100 * np.sin(c * (u + v) / (W + H) * np.pi),
        ], axis=-1)
        frames.append(img)
    return np.clip(np.rint(frames), 0, 255).astype(np.uint8)


def make_capture(T=3, width=32, height=24, *, cameras=("cam_a", "cam_b"), depth=True, seed=0, frames=None):
    rng = np.random.default_rng(seed)
    trajs = {n: make_trajectory(T, width, height) for n in cameras}
    if frames is None:
        frames = {n: rng.integers(0, 256, size=(T, height, width, 3), dtype=np.uint8) for n in cameras}
    d = {cameras[0]: rng.uniform(0.5, 20.0, size=(T, height, width)).astype(np.float32)} if depth else None
    return Capture(cameras=trajs, frames=frames, depth=d, fps=10.0, capture_id="test",
                   metadata={"note": "unit test"})


def write_video(path, frames, codec="libx264", *, container=None, rate=25, options=None, pts=None):
    """Write RGB ``frames`` as one video with PyAV (``pts``: explicit timestamps in milliseconds, for
    variable frame rates).  Returns the path."""
    from fractions import Fraction

    import av

    T, H, W, _ = frames.shape
    with av.open(str(path), "w", format=container) as out:
        stream = out.add_stream(codec, rate=rate)
        stream.width, stream.height = W, H
        stream.pix_fmt = "yuvj420p" if codec == "mjpeg" else "rgb24" if codec == "png" else "yuv420p"
        stream.options = dict(options or {})
        if pts is not None:
            stream.codec_context.time_base = Fraction(1, 1000)
        for i, frame in enumerate(frames):
            vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
            if pts is not None:
                vf.pts, vf.time_base = int(pts[i]), Fraction(1, 1000)
            out.mux(stream.encode(vf))
        out.mux(stream.encode(None))
    return path


def numbered_video(T, H=48, W=64):
    """Frames whose frame number can be read back after lossy coding: a grey level per frame."""
    levels = np.linspace(16, 239, T).round().astype(np.uint8)
    return np.broadcast_to(levels[:, None, None, None], (T, H, W, 3)).copy()


def video_capture(directory, videos, num_frames, width, height, fps=25.0):
    """A capture directory whose cameras' media are the given video files (name -> file in directory)."""
    from vt4dcodec.capture.io import CAPTURE_FORMAT, CAPTURE_VERSION, camera_json, read_manifest, write_manifest

    cams = [camera_json(name, make_trajectory(1, width, height, moving=False, timestamps=False),
                        {"type": "mp4", "path": file}, None) for name, file in videos.items()]
    write_manifest(directory, {"format": CAPTURE_FORMAT, "version": CAPTURE_VERSION, "fps": fps,
                               "num_frames": num_frames, "cameras": cams})
    return read_manifest(directory)
