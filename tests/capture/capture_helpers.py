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
