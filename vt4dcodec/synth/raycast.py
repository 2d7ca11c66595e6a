"""Vectorized ray-primitive intersection (numpy only).

Every function takes ray origins ``o`` (N, 3) and unit directions ``d`` (N, 3) expressed in the
primitive's own frame and returns ``s`` (N,) float64, the distance along the ray to the first hit in
front of the origin (``np.inf`` on a miss), plus the outward unit normal (N, 3) at the hit in that
frame (undefined where missed).  Rays are one-sided: a ray starting inside a closed primitive misses.
"""

from __future__ import annotations

import numpy as np

__all__ = ["EPS", "intersect_plane_z", "intersect_sphere", "intersect_ellipsoid", "intersect_box", "intersect_card"]

EPS = 1e-6


def intersect_plane_z(o: np.ndarray, d: np.ndarray, z0: float = 0.0) -> np.ndarray:
    """Distance to the plane z = ``z0`` (both sides), ``inf`` for parallel rays or hits behind."""
    dz = d[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (z0 - o[:, 2]) / dz
    return np.where((np.abs(dz) > EPS) & (s > EPS), s, np.inf)


def intersect_sphere(o: np.ndarray, d: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Sphere of ``radius`` at the origin: (s, normal)."""
    b = o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1] + o[:, 2] * d[:, 2]
    c = o[:, 0] * o[:, 0] + o[:, 1] * o[:, 1] + o[:, 2] * o[:, 2] - radius * radius
    disc = b * b - c
    root = np.sqrt(np.maximum(disc, 0.0))
    s = -b - root
    s = np.where((disc >= 0) & (c > 0) & (s > EPS), s, np.inf)
    hit = o + np.where(np.isfinite(s), s, 0.0)[:, None] * d
    return s, hit / radius


def intersect_ellipsoid(o: np.ndarray, d: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned ellipsoid (x/a)^2 + (y/b)^2 + (z/c)^2 = 1 at the origin, ``radii`` = (a, b, c): (s, normal).

    Solved as the unit sphere in coordinates scaled by 1 / radii; the scaling is linear, so the ray
    parameter (the distance along the unit world direction) is the same in both frames."""
    r = np.asarray(radii, dtype=np.float64)
    os_, ds = o / r[None], d / r[None]
    a = np.sum(ds * ds, axis=1)
    b = np.sum(os_ * ds, axis=1)
    c = np.sum(os_ * os_, axis=1) - 1.0
    disc = b * b - a * c
    s = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
    s = np.where((disc >= 0) & (c > 0) & (s > EPS), s, np.inf)
    hit = o + np.where(np.isfinite(s), s, 0.0)[:, None] * d
    normal = hit / (r * r)[None]
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    return s, normal


def intersect_box(o: np.ndarray, d: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box [-half, half] (slab method): (s, normal of the entered face)."""
    half = np.asarray(half, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inv = 1.0 / d
        t1 = (-half[None] - o) * inv
        t2 = (half[None] - o) * inv
    tnear = np.minimum(t1, t2)
    tfar = np.maximum(t1, t2)
    # Rays parallel to a slab: inside it -> the whole line (-inf, inf), outside -> empty (inf, -inf).
    par = np.abs(d) < 1e-12
    inside = np.abs(o) <= half[None]
    tnear = np.where(par, np.where(inside, -np.inf, np.inf), tnear)
    tfar = np.where(par, np.where(inside, np.inf, -np.inf), tfar)
    axis = np.argmax(tnear, axis=1)
    s_in = tnear[np.arange(len(o)), axis]
    s_out = tfar.min(axis=1)
    s = np.where((s_in <= s_out) & (s_in > EPS), s_in, np.inf)
    normal = np.zeros_like(o)
    sign = -np.sign(d[np.arange(len(o)), axis])
    normal[np.arange(len(o)), axis] = np.where(sign == 0, 1.0, sign)
    return s, normal


def intersect_card(o: np.ndarray, d: np.ndarray, half_w: float, half_h: float) -> tuple[np.ndarray, np.ndarray]:
    """Two-sided rectangle |x| <= half_w, |y| <= half_h in the plane z = 0: (s, normal facing the ray)."""
    s = intersect_plane_z(o, d)
    hit = o + np.where(np.isfinite(s), s, 0.0)[:, None] * d
    s = np.where((np.abs(hit[:, 0]) <= half_w) & (np.abs(hit[:, 1]) <= half_h), s, np.inf)
    normal = np.zeros_like(o)
    normal[:, 2] = np.where(d[:, 2] > 0, -1.0, 1.0)
    return s, normal
