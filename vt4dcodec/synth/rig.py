"""Synchronized camera rigs on smooth trajectories around the action (numpy only).

World frame: z up, metres, the action happens around the origin on the ground plane z = 0.
Cameras are spread along an arc around the origin (span 120-360 degrees), 3-5 m away, 0.8-2.8 m
high, with horizontal fields of view of 40-75 degrees (varied focal lengths), and each looks at a
point near the centre.  With ``camera_motion`` each camera slowly orbits, dollies and bobs, and its
look-at point drifts, all as smooth functions of time.  Poses use the OpenCV convention
(x right, y down, z forward), world-to-camera.
"""

from __future__ import annotations

import numpy as np

from ..cameras import Trajectory, look_at

__all__ = ["sample_rig", "arc_azimuths"]

_Z_UP = np.array([0.0, 0.0, 1.0])  # the world's up: image up is towards +z


def arc_azimuths(rng: np.random.Generator, n: int, *, min_span: float, jitter: float) -> np.ndarray:
    """Azimuths (n,) rad of ``n`` cameras spread evenly along an arc of ``min_span``..2 pi from a random start,
    each moved by up to ``jitter`` of the spacing; a full circle does not repeat its first camera."""
    span = rng.uniform(min_span, 2 * np.pi)
    start = rng.uniform(0, 2 * np.pi)
    step = span / (n if span > 1.9 * np.pi else max(n - 1, 1))
    return start + step * np.arange(n) + rng.uniform(-jitter, jitter, n) * step


def sample_rig(
    rng: np.random.Generator, *, num_cameras: int, times: np.ndarray, width: int, height: int,
    camera_motion: bool,
) -> dict[str, Trajectory]:
    """Draw ``num_cameras`` synchronized trajectories ``cam00``, ``cam01``, ... sampled at ``times`` (T,) s."""
    t = np.asarray(times, dtype=np.float64)[:, None]          # (T, 1)
    azim0 = arc_azimuths(rng, num_cameras, min_span=2 * np.pi / 3, jitter=0.25)
    radius0 = rng.uniform(3.0, 5.0, num_cameras)
    height0 = rng.uniform(0.8, 2.8, num_cameras)
    fov = np.deg2rad(rng.uniform(40.0, 75.0, num_cameras))
    target0 = np.stack([rng.uniform(-0.3, 0.3, num_cameras), rng.uniform(-0.3, 0.3, num_cameras),
                        rng.uniform(0.2, 0.7, num_cameras)], -1)
    if camera_motion:
        orbit_rate = rng.uniform(-0.25, 0.25, num_cameras)     # rad/s
        dolly_rate = rng.uniform(-0.5, 0.5, num_cameras)       # m/s
        bob_amp = rng.uniform(0.0, 0.25, num_cameras)          # m
        bob_freq = rng.uniform(0.2, 0.6, num_cameras)          # Hz
        target_vel = rng.uniform(-0.15, 0.15, (num_cameras, 3)) * np.array([1.0, 1.0, 0.3])
    else:
        orbit_rate = dolly_rate = bob_amp = bob_freq = np.zeros(num_cameras)
        target_vel = np.zeros((num_cameras, 3))
    cams: dict[str, Trajectory] = {}
    for i in range(num_cameras):
        az = azim0[i] + orbit_rate[i] * t[:, 0]
        rad = radius0[i] + dolly_rate[i] * t[:, 0]
        z = height0[i] + bob_amp[i] * np.sin(2 * np.pi * bob_freq[i] * t[:, 0])
        eye = np.stack([rad * np.cos(az), rad * np.sin(az), z], -1)
        target = target0[i][None] + target_vel[i][None] * t
        w2c = look_at(eye, target, _Z_UP)
        f = 0.5 * width / np.tan(0.5 * fov[i])
        K = np.array([[f, 0.0, 0.5 * (width - 1)], [0.0, f, 0.5 * (height - 1)], [0.0, 0.0, 1.0]])
        cams[f"cam{i:02d}"] = Trajectory(
            K=np.repeat(K[None], len(t), axis=0), w2c=w2c, width=width, height=height,
            timestamps=t[:, 0].copy(),
        )
    return cams
