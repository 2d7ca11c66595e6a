"""Exact 2-D point tracks of a synthetic scene (numpy only).

The generator knows every surface point's motion, so the true track of any pixel is computed, not
estimated: a query pixel (u, v) of camera c at frame t0 is unprojected with the exact depth to its world
point X, moved by the rigid motion of the surface it lies on from t0 to t (object k:
X_t = R_k(t) R_k(t0)^T (X - p_k(t0)) + p_k(t); the room's ground and walls stand still), and projected
by camera c at frame t.  A static background point moves in the image only because the camera moves.

The track is visible at frame t where the point lands inside the image, in front of the camera and is
not hidden: the same test as the generator's flow validity (:func:`.render._visible`: the pixels around
the projection show the same surface and their interpolated inverse depth matches the point's within 1 %).
At t0 + 1 the tracks therefore equal the generator's exact optical flow, and visibility its ``flow_valid``
(tests/synth/test_tracks.py checks both).

    from vt4dcodec.synth import generate_scene, true_tracks
    scene = generate_scene(3, split="test")
    xy, visible = true_tracks(scene, "cam00", [[10, 20, 0], [31, 40, 5]])   # (2, T, 2), (2, T)

Pixel convention: integer coordinates are pixel centres, u along the width, v along the height (the
generator's and OpenCV's).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .assets import SynthError
from .generator import SceneSetup, SynthConfig, SynthScene, scene_setup
from .render import _WALLS, FIRST_OBJECT_SURFACE, _visible

__all__ = ["true_tracks", "surface_ids", "setup_of"]


def setup_of(scene: SynthScene) -> SceneSetup:
    """The :class:`SceneSetup` (cameras, layout, times) a generated scene was rendered from, rebuilt from
    its seed, split and recorded config (cheap: nothing is rendered)."""
    meta = scene.capture.metadata or {}
    if "config" not in meta:
        raise SynthError("the scene records no generator config (capture.metadata['config']); pass setup=")
    config = SynthConfig(**{**meta["config"], "num_objects": tuple(meta["config"]["num_objects"])})
    return scene_setup(scene.seed, split=scene.split, config=config)


def _unproject(depth: np.ndarray, K: np.ndarray, w2c: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """World points (..., 3) of pixels ``uv`` (..., 2) at camera-z ``depth`` (...) metres (K (3, 3), w2c (4, 4))."""
    ones = np.ones(uv.shape[:-1] + (1,))
    rays = np.concatenate([uv.astype(np.float64), ones], -1) @ np.linalg.inv(K).T   # z = 1
    xc = rays * depth[..., None].astype(np.float64)
    world: np.ndarray = (xc - w2c[:3, 3]) @ w2c[:3, :3]                            # R^T (xc - t)
    return world


def surface_ids(setup: SceneSetup, camera: str, depth: np.ndarray, object_ids: np.ndarray) -> np.ndarray:
    """The generator's surface id of every pixel of one camera's frames (T, H, W) int16.

    ``depth`` (T, H, W) metres and ``object_ids`` (T, H, W) (0 background, k object k) are the scene's.
    Objects keep id ``FIRST_OBJECT_SURFACE + k - 1``; a background pixel gets 0 (ground) or 1-4 (walls
    x = +L, x = -L, y = +L, y = -L), whichever plane its world point lies on.
    """
    traj = setup.cameras[camera]
    T, H, W = depth.shape
    v, u = np.meshgrid(np.arange(H, dtype=np.float64), np.arange(W, dtype=np.float64), indexing="ij")
    uv = np.stack([u, v], -1)
    out = np.empty((T, H, W), np.int16)
    L = setup.layout.room_half
    for t in range(T):
        X = _unproject(depth[t], traj.K[t], traj.w2c[t], uv)
        dist = [np.abs(X[..., 2])] + [np.abs(X[..., axis] - sign * L) for axis, sign in _WALLS]
        background = np.argmin(np.stack(dist), axis=0).astype(np.int16)
        oid = object_ids[t].astype(np.int16)
        out[t] = np.where(oid > 0, oid + (FIRST_OBJECT_SURFACE - 1), background)
    return out


def _check_queries(queries: np.ndarray | Sequence[Sequence[int]], T: int, H: int, W: int) -> np.ndarray:
    q = np.asarray(queries)
    if q.ndim != 2 or q.shape[1] != 3:
        raise SynthError(f"queries must be an (N, 3) array of (u, v, t0), got shape {q.shape}")
    if q.dtype.kind not in "iu":
        if q.dtype.kind != "f" or not np.all(np.isfinite(q)) or not np.all(q == np.round(q)):
            raise SynthError("queries must hold integer pixel coordinates and frame indices (u, v, t0)")
    q = q.astype(np.int64)
    bad = (q[:, 0] < 0) | (q[:, 0] >= W) | (q[:, 1] < 0) | (q[:, 1] >= H) | (q[:, 2] < 0) | (q[:, 2] >= T)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise SynthError(f"query {i} = (u, v, t0) {tuple(int(x) for x in q[i])} lies outside {W}x{H} pixels "
                         f"x {T} frames")
    return q


def true_tracks(scene: SynthScene, camera: str, queries: np.ndarray | Sequence[Sequence[int]], *,
                setup: SceneSetup | None = None, surfaces: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Exact image tracks of query pixels of one camera through every frame of that camera.

    Args:
        scene: a generated scene (:func:`.generate_scene`).
        camera: one of its cameras, e.g. ``"cam00"``.
        queries: (N, 3) integers (u, v, t0): pixel column, row and the frame where the point is picked.
        setup: the scene's :class:`SceneSetup`, if already at hand (default: rebuilt, :func:`setup_of`).
        surfaces: the camera's :func:`surface_ids`, if already at hand (several calls on one camera).
    Returns:
        xy: (N, T, 2) float64 pixel positions (u, v) of each query's surface point at every frame (exactly
            the query at t0; finite wherever the point is in front of the camera, NaN behind it).
        visible: (N, T) bool, inside the image and not occluded at that frame (True at t0).
    Raises:
        SynthError: unknown camera, queries not (N, 3) integers inside the clip.
    """
    if camera not in scene.capture.cameras:
        raise SynthError(f"camera {camera!r} is not in the scene (cameras: {sorted(scene.capture.cameras)})")
    if setup is None:
        setup = setup_of(scene)
    depth = np.asarray(scene.capture.depth[camera]) if scene.capture.depth else None
    if depth is None:
        raise SynthError("the scene holds no depth; true tracks need the generator's exact depth")
    ids = scene.object_ids[camera]
    T, H, W = depth.shape
    q = _check_queries(queries, T, H, W)
    if surfaces is None:
        surfaces = surface_ids(setup, camera, depth, ids)
    traj = setup.cameras[camera]
    N = len(q)
    u0, v0, t0 = q[:, 0], q[:, 1], q[:, 2]
    X = np.empty((N, 3))
    for t in np.unique(t0):
        sel = t0 == t
        X[sel] = _unproject(depth[t, v0[sel], u0[sel]], traj.K[t], traj.w2c[t],
                            np.stack([u0[sel], v0[sel]], -1))
    oid = ids[t0, v0, u0].astype(np.int64)                     # 0 background, k object k
    # world point of every query at every frame: objects carry theirs rigidly, the room stays
    Xt = np.repeat(X[None], T, axis=0)                           # (T, N, 3)
    for k, obj in enumerate(setup.layout.objects):
        sel = np.flatnonzero(oid == k + 1)
        if not len(sel):
            continue
        R, p = obj.motion.pose(setup.times)                      # (T, 3, 3), (T, 3)
        local = np.einsum("nji,nj->ni", R[t0[sel]], X[sel] - p[t0[sel]])   # R(t0)^T (X - p(t0))
        Xt[:, sel] = np.einsum("tij,nj->tni", R, local) + p[:, None]
    w2c = traj.w2c.astype(np.float64)
    xc = np.einsum("tij,tnj->tni", w2c[:, :3, :3], Xt) + w2c[:, None, :3, 3]
    z = xc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        proj = np.einsum("tij,tnj->tni", traj.K.astype(np.float64), xc)
        uv = proj[..., :2] / z[..., None]
    uv = np.where((z > 0)[..., None], uv, np.nan)
    surf = np.broadcast_to(surfaces[t0, v0, u0][None], (T, N))
    visible = _visible(uv, z, surf, depth.astype(np.float64), surfaces)          # (T, N)
    xy = np.ascontiguousarray(uv.transpose(1, 0, 2))
    rows = np.arange(N)
    xy[rows, t0] = np.stack([u0, v0], -1)
    vis = np.ascontiguousarray(visible.T)
    vis[rows, t0] = True
    return xy, vis
