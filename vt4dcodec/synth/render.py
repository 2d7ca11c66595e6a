"""Ray-cast rendering of a synthetic scene layout, with exact ground truth (numpy only).

Every pixel is one ray through the pixel centre (no supersampling): the RGB, depth, object id and
flow of a pixel all describe the SAME surface point, the first one the ray hits.

* RGB: trilinear mip-mapped texture lookup (mip level from the pixel footprint on the surface), times
  an object's tint, times Lambertian + ambient shading from one directional light; with the layout's
  ``shadows`` the objects cast hard shadows (a shadow ray towards the light per pixel).
* Depth: z of the hit point in the camera frame, metres (float32).
* Flow t -> t+1: the hit point X at frame t is moved by its surface's rigid motion (static for the
  ground and walls), X' = R(t+1) R(t)^T (X - p(t)) + p(t+1), and projected by the same camera at frame
  t+1; flow = (u', v') - (u, v) in pixels.  Exact up to float rounding.
* Flow validity: True where X' lands inside frame t+1, in front of the camera, and is visible there
  (the pixels around (u', v') with non-zero bilinear weight show the same surface, and their
  interpolated inverse depth equals 1 / z' within 1 %), i.e. the point is neither occluded nor out of view at t+1.

World frame: z up, metres; the ground is z = 0; four walls x = +-L, y = +-L close the room, so every
ray hits something and depth is finite everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..cameras import Trajectory
from .assets import TEXTURE_SIZE, TextureBank
from .motion import Motion
from .raycast import intersect_box, intersect_card, intersect_ellipsoid, intersect_plane_z, intersect_sphere

__all__ = ["SceneObject", "SceneLayout", "RenderedView", "render_layout", "FIRST_OBJECT_SURFACE", "SHAPES", "ALL_SHAPES"]

FIRST_OBJECT_SURFACE = 5      # surface ids: 0 ground, 1..4 walls (+x, -x, +y, -y), 5 + k object k
SHAPES = ("sphere", "box", "card")   # the rigid objects the default scenes draw from, in this order
ALL_SHAPES = SHAPES + ("ellipsoid",)
SHADOW_OFFSET = 1e-4          # metres a shadow ray starts off its surface, along the normal
VISIBILITY_TOLERANCE = 0.01   # relative inverse-depth tolerance of the flow visibility test
MIP_BIAS = 0.5                # levels added to the footprint level (slightly softer, less aliasing)


@dataclass(frozen=True)
class SceneObject:
    """A textured rigid object.

    Attributes:
        shape: "sphere" (size = (radius,)), "box" (size = half extents (3,)), "card" (size =
            (half width, half height), a two-sided quad in its local z = 0 plane), "ellipsoid" (size =
            radii along local x, y, z).
        size: metres, as above.
        texture: index into the split's :class:`TextureBank`.
        motion: its :class:`~.motion.Motion` (local -> world pose over time): a rigid object's
            :class:`~.motion.MotionLaw` or a figure part's :class:`~.figures.PartMotion`.
        tint: None: the texture's own colours; an RGB triple: the texture's luminance pattern in that
            colour, ``clip(tint * (0.5 + luminance), 0, 1)`` (clothing and skin from any texture).
    """

    shape: str
    size: tuple[float, ...]
    texture: int
    motion: Motion
    tint: tuple[float, float, float] | None = None

    @property
    def bounding_radius(self) -> float:
        """Radius (m) of a sphere about the object's origin that contains it."""
        extent = max(self.size) if self.shape == "ellipsoid" else float(np.linalg.norm(self.size))
        return extent * (1.0 + 1e-6) + 1e-9


@dataclass(frozen=True)
class SceneLayout:
    """Everything static about a scene plus its objects.

    Attributes:
        room_half: L, metres; walls at x = +-L and y = +-L.
        ground_texture, wall_textures (4,): texture indices; ``ground_tile``, ``wall_tile``: metres
            covered by one 128-texel tile.
        light_dir: (3,) unit vector towards the light (world); ``ambient`` in [0, 1].
        objects: the rigid objects (figure parts included); object k has id k + 1 in the output.
        shadows: whether the objects cast shadows (on everything, each other included).
        surface_tints: None, or for the ground and the four walls (in surface id order) each None or an
            RGB tint (as :attr:`SceneObject.tint`).
    """

    room_half: float
    ground_texture: int
    ground_tile: float
    wall_textures: tuple[int, int, int, int]
    wall_tile: float
    light_dir: np.ndarray
    ambient: float
    objects: tuple[SceneObject, ...] = field(default_factory=tuple)
    shadows: bool = False
    surface_tints: tuple | None = None


@dataclass
class RenderedView:
    """One camera's rendered video and ground truth (T frames of H x W pixels)."""

    rgb: np.ndarray          # (T, H, W, 3) uint8
    depth: np.ndarray        # (T, H, W) float32 metres, z in the camera frame
    surface: np.ndarray      # (T, H, W) int16 surface id (see FIRST_OBJECT_SURFACE)
    flow: np.ndarray         # (T-1, H, W, 2) float32 pixels (du, dv), t -> t+1
    flow_valid: np.ndarray   # (T-1, H, W) bool


def _camera_rays(cameras: list[Trajectory], t: int, pix: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays of all cameras at frame t through pixel centres ``pix`` (P, 3) homogeneous.

    Returns the camera centres (C, 3), unit world directions (C*P, 3) and the camera-z component of
    each unit direction (C*P,), which turns distance along the ray into depth.
    """
    Kinv = np.linalg.inv(np.stack([c.K[t] for c in cameras]))                  # (C, 3, 3)
    R = np.stack([c.w2c[t, :3, :3] for c in cameras])                           # (C, 3, 3)
    dc = pix[None] @ np.swapaxes(Kinv, 1, 2)                                    # (C, P, 3)
    dc /= np.linalg.norm(dc, axis=2, keepdims=True)
    d = dc @ R                                                                  # world = R^T dc
    centers = np.stack([c.centers[t] for c in cameras])
    return centers, d.reshape(-1, 3), dc[..., 2].reshape(-1)


def _rowdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of (N, 3) arrays (faster than einsum for 3 columns)."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _bounding_candidates(cam_origin: np.ndarray, d: np.ndarray, center: np.ndarray, radius: float) -> np.ndarray:
    """Indices of the rays that pass within ``radius`` of ``center`` (a cheap, conservative cull).

    ``cam_origin`` (C, 3) are the camera centres and ``d`` (C*P, 3) the rays of each camera in turn.
    """
    C = len(cam_origin)
    oc = cam_origin - center                                            # (C, 3)
    b = (d.reshape(C, -1, 3) @ oc[:, :, None])[..., 0]                  # (C, P) = d . (o - c)
    c = (np.sum(oc * oc, axis=1) - radius * radius)[:, None]            # (C, 1)
    return np.flatnonzero(((b * b - c >= 0) & ((b < 0) | (c < 0))).ravel())


def _object_intersect(obj: SceneObject, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if obj.shape == "sphere":
        return intersect_sphere(o, d, obj.size[0])
    if obj.shape == "box":
        return intersect_box(o, d, np.asarray(obj.size))
    if obj.shape == "ellipsoid":
        return intersect_ellipsoid(o, d, np.asarray(obj.size))
    return intersect_card(o, d, obj.size[0], obj.size[1])


def _object_uv(obj: SceneObject, xl: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Level-0 texel coordinates (u, v) and texel density (texels per metre) of local points (N, 3)."""
    n = TEXTURE_SIZE
    if obj.shape == "sphere":
        r = obj.size[0]
        lon = np.arctan2(xl[:, 1], xl[:, 0])
        lat = np.arccos(np.clip(xl[:, 2] / r, -1.0, 1.0))
        # one mirror period (2n texels) around the equator keeps the seam continuous
        return (lon / (2 * np.pi) + 0.5) * 2 * n, lat / np.pi * n, np.full(len(xl), n / (np.pi * r))
    if obj.shape == "ellipsoid":   # the sphere's mapping on the unit-sphere coordinates
        radii = np.asarray(obj.size)
        xs = xl / radii[None]
        lon = np.arctan2(xs[:, 1], xs[:, 0])
        lat = np.arccos(np.clip(xs[:, 2], -1.0, 1.0))
        return (lon / (2 * np.pi) + 0.5) * 2 * n, lat / np.pi * n, np.full(len(xl), n / (np.pi * float(radii.mean())))
    if obj.shape == "box":
        half = np.asarray(obj.size)
        dens = n / (2.0 * half.max())
        axis = np.argmax(np.abs(xl) / half[None], axis=1)
        a = (axis + 1) % 3
        b = (axis + 2) % 3
        rows = np.arange(len(xl))
        offset = 37.0 * axis       # each face shows a different part of the texture
        return xl[rows, a] * dens + offset, xl[rows, b] * dens + offset, np.full(len(xl), dens)
    hw, hh = obj.size
    u = (xl[:, 0] / hw + 1.0) * 0.5 * n
    v = (1.0 - (xl[:, 1] / hh + 1.0) * 0.5) * n
    return u, v, np.full(len(xl), n / (hw + hh))


def _object_normal(obj: SceneObject, xl: np.ndarray, dl: np.ndarray) -> np.ndarray:
    if obj.shape == "sphere":
        return xl / obj.size[0]
    if obj.shape == "ellipsoid":
        nrm = xl / np.square(np.asarray(obj.size))[None]
        return nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    if obj.shape == "box":
        half = np.asarray(obj.size)
        axis = np.argmax(np.abs(xl) / half[None], axis=1)
        nrm = np.zeros_like(xl)
        nrm[np.arange(len(xl)), axis] = np.sign(xl[np.arange(len(xl)), axis])
        return nrm
    nrm = np.zeros_like(xl)
    nrm[:, 2] = np.where(dl[:, 2] > 0, -1.0, 1.0)
    return nrm


# static surfaces 0..4: (texture coordinate axis for u, sign of the inward normal axis)
_WALLS = ((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0))   # wall w is the plane x_axis = sign * L


def _render_frame(
    layout: SceneLayout, bank: TextureBank, cam_origin: np.ndarray, d: np.ndarray, focal: np.ndarray,
    poses: list, poses_next: list | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Shade the rays of one frame, ``d`` (N = C*P, 3) from the C camera centres ``cam_origin`` (C, 3).

    Returns RGB (N, 3) float32, distance (N,), surface id (N,) int16, and each hit point moved to the
    next frame's pose (N, 3) (equal to the hit for static surfaces)."""
    origin = np.repeat(cam_origin, len(d) // len(cam_origin), axis=0)
    N = len(d)
    L = layout.room_half
    s_best = intersect_plane_z(origin, d, 0.0)
    surf = np.zeros(N, dtype=np.int16)
    for wall, (axis, sign) in enumerate(_WALLS):
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (sign * L - origin[:, axis]) / d[:, axis]
        better = (s > 0) & (s < s_best)
        s_best = np.where(better, s, s_best)
        surf[better] = 1 + wall
    for k, obj in enumerate(layout.objects):
        R, p = poses[k]
        cand = _bounding_candidates(cam_origin, d, p, obj.bounding_radius)
        if not len(cand):
            continue
        s, _ = _object_intersect(obj, (origin[cand] - p) @ R, d[cand] @ R)
        better = s < s_best[cand]
        hit = cand[better]
        s_best[hit] = s[better]
        surf[hit] = FIRST_OBJECT_SURFACE + k
    X = origin + s_best[:, None] * d
    # Static surfaces by table lookup: ground uv = (x, y); walls uv = (the other horizontal axis, -z).
    n_surf = FIRST_OBJECT_SURFACE + len(layout.objects)
    tex_table = np.zeros(n_surf, dtype=np.int32)
    dens_table = np.zeros(n_surf)
    normal_table = np.zeros((n_surf, 3))
    u_axis = np.zeros(n_surf, dtype=np.int64)
    u_off = np.zeros(n_surf)
    tex_table[0], dens_table[0], normal_table[0, 2] = layout.ground_texture, TEXTURE_SIZE / layout.ground_tile, 1.0
    for wall, (axis, sign) in enumerate(_WALLS):
        tex_table[1 + wall], dens_table[1 + wall] = layout.wall_textures[wall], TEXTURE_SIZE / layout.wall_tile
        normal_table[1 + wall, axis] = -sign
        u_axis[1 + wall], u_off[1 + wall] = 1 - axis, 3.1 * wall
    tex = tex_table[surf]
    dens = dens_table[surf]
    normal = normal_table[surf]
    is_ground = surf == 0
    u = (np.take_along_axis(X, u_axis[surf][:, None], axis=1)[:, 0] + u_off[surf]) * dens
    v = np.where(is_ground, X[:, 1], -X[:, 2]) * dens
    tint = np.zeros((N, 3), dtype=np.float32)
    tinted = np.zeros(N, dtype=bool)
    for sid, colour in enumerate(layout.surface_tints or ()):
        if colour is not None:
            sel = surf == sid
            tint[sel], tinted[sel] = colour, True
    X_next = X.copy()
    for k, obj in enumerate(layout.objects):
        sel = np.flatnonzero(surf == FIRST_OBJECT_SURFACE + k)
        if not len(sel):
            continue
        R, p = poses[k]
        xl = (X[sel] - p) @ R
        u[sel], v[sel], dens[sel] = _object_uv(obj, xl)
        tex[sel] = obj.texture
        if obj.tint is not None:
            tint[sel], tinted[sel] = obj.tint, True
        normal[sel] = _object_normal(obj, xl, d[sel] @ R) @ R.T
        if poses_next is not None:
            Rn, pn = poses_next[k]
            X_next[sel] = xl @ Rn.T + pn
    cos = np.abs(_rowdot(normal, d))
    footprint = s_best / focal / np.sqrt(np.maximum(cos, 0.05))   # metres per pixel on the surface
    level = np.log2(np.maximum(footprint * dens, 1e-6)) + MIP_BIAS
    albedo = bank.sample(tex, u, v, level)
    if tinted.any():
        luma = albedo[tinted] @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
        albedo[tinted] = np.clip(tint[tinted] * (0.5 + luma)[:, None], 0.0, 1.0)
    direct = np.maximum(normal @ layout.light_dir, 0.0)
    if layout.shadows:
        direct *= ~_shadowed(layout, poses, X, normal, direct > 0)
    shade = layout.ambient + (1.0 - layout.ambient) * direct
    rgb = np.clip(albedo * shade[:, None].astype(np.float32), 0.0, 1.0)
    return rgb, s_best, surf, X_next


def _shadowed(layout: SceneLayout, poses: list, X: np.ndarray, normal: np.ndarray, lit: np.ndarray) -> np.ndarray:
    """(N,) bool: the surface points ``X`` (N, 3) whose ray towards the (directional) light hits an object.
    Only points facing the light (``lit``) are tested; the room is convex, so only objects cast shadows."""
    out = np.zeros(len(X), dtype=bool)
    idx = np.flatnonzero(lit)
    if not len(idx) or not layout.objects:
        return out
    L = np.asarray(layout.light_dir, dtype=np.float64)
    o = X[idx] + SHADOW_OFFSET * normal[idx]
    for k, obj in enumerate(layout.objects):
        R, p = poses[k]
        rad = obj.bounding_radius
        oc = p[None] - o
        along = oc @ L
        cand = np.flatnonzero((along > -rad) & (np.sum(oc * oc, axis=1) - along * along <= rad * rad))
        if not len(cand):
            continue
        s, _ = _object_intersect(obj, (o[cand] - p) @ R, np.broadcast_to(L @ R, (len(cand), 3)))
        out[idx[cand[np.isfinite(s)]]] = True
    return out


def _project(w2c: np.ndarray, K: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points X (C, P, 3) with per-camera w2c (C, 4, 4), K (C, 3, 3): uv (C, P, 2), z (C, P)."""
    xc = X @ np.swapaxes(w2c[:, :3, :3], 1, 2) + w2c[:, None, :3, 3]
    z = xc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (xc @ np.swapaxes(K, 1, 2))[..., :2] / z[..., None]
    return uv, z


def _visible(uv: np.ndarray, z: np.ndarray, surf: np.ndarray, depth_next: np.ndarray,
             surf_next: np.ndarray) -> np.ndarray:
    """Whether points at pixel coords ``uv`` (C, P, 2) with depth ``z`` (C, P) on surfaces ``surf``
    (C, P) are seen in the next frames ``depth_next``/``surf_next`` (C, H, W); returns (C, P) bool."""
    C, H, W = depth_next.shape
    ok = (z > 0) & np.all(np.isfinite(uv), axis=-1)
    eps = 1e-6   # pixels; keeps border points with zero flow (up to rounding) inside
    ok &= (uv[..., 0] >= -eps) & (uv[..., 0] <= W - 1 + eps) & (uv[..., 1] >= -eps) & (uv[..., 1] <= H - 1 + eps)
    uvc = np.where(ok[..., None], np.clip(uv, 0.0, [W - 1, H - 1]), 0.0)
    x0 = np.minimum(np.floor(uvc[..., 0]).astype(np.int64), W - 2)
    y0 = np.minimum(np.floor(uvc[..., 1]).astype(np.int64), H - 2)
    fx = uvc[..., 0] - x0
    fy = uvc[..., 1] - y0
    base = np.arange(C)[:, None] * (H * W) + y0 * W + x0
    inv = (1.0 / depth_next).reshape(-1)
    surf_flat = surf_next.reshape(-1)
    interp = np.zeros(z.shape)
    for off, w in ((0, (1 - fx) * (1 - fy)), (1, fx * (1 - fy)), (W, (1 - fx) * fy), (W + 1, fx * fy)):
        ok &= (surf_flat[base + off] == surf) | (w < 1e-9)   # neighbours with zero weight do not count
        interp += w * inv[base + off]
    with np.errstate(divide="ignore", invalid="ignore"):
        ok &= np.abs(interp * z - 1.0) <= VISIBILITY_TOLERANCE
    return ok


def render_layout(
    layout: SceneLayout, cameras: dict[str, Trajectory], times: np.ndarray, bank: TextureBank,
) -> dict[str, RenderedView]:
    """Render every camera of ``cameras`` at every time of ``times`` (T,) seconds."""
    names = list(cameras)
    cams = [cameras[n] for n in names]
    C, T = len(cams), len(times)
    H, W = cams[0].height, cams[0].width
    P = H * W
    poses_all = [obj.motion.pose(times) for obj in layout.objects]
    v, u = np.meshgrid(np.arange(H, dtype=np.float64), np.arange(W, dtype=np.float64), indexing="ij")
    pix = np.stack([u.ravel(), v.ravel(), np.ones(P)], -1)
    rgb = np.empty((T, C, P, 3), dtype=np.float32)
    depth = np.empty((T, C, P))
    surface = np.empty((T, C, P), dtype=np.int16)
    moved = []
    for t in range(T):
        centers, d, zdir = _camera_rays(cams, t, pix)
        focal = np.repeat([np.sqrt(c.K[t, 0, 0] * c.K[t, 1, 1]) for c in cams], P)
        poses = [(R[t], p[t]) for R, p in poses_all]
        poses_next = [(R[t + 1], p[t + 1]) for R, p in poses_all] if t + 1 < T else None
        col, dist, surf, X_next = _render_frame(layout, bank, centers, d, focal, poses, poses_next)
        rgb[t], depth[t], surface[t] = col.reshape(C, P, 3), (dist * zdir).reshape(C, P), surf.reshape(C, P)
        moved.append(X_next.reshape(C, P, 3))
    flow = np.zeros((max(T - 1, 0), C, P, 2), dtype=np.float32)
    valid = np.zeros((max(T - 1, 0), C, P), dtype=bool)
    for t in range(T - 1):
        w2c = np.stack([c.w2c[t + 1] for c in cams])
        K = np.stack([c.K[t + 1] for c in cams])
        uv, z = _project(w2c, K, moved[t])
        flow[t] = np.nan_to_num(uv - pix[None, :, :2])
        valid[t] = _visible(uv, z, surface[t], depth[t + 1].reshape(C, H, W), surface[t + 1].reshape(C, H, W))
    rgb8 = np.round(rgb * 255.0).astype(np.uint8)
    out: dict[str, RenderedView] = {}
    for c, name in enumerate(names):
        out[name] = RenderedView(
            rgb=rgb8[:, c].reshape(T, H, W, 3), depth=depth[:, c].reshape(T, H, W).astype(np.float32),
            surface=surface[:, c].reshape(T, H, W), flow=flow[:, c].reshape(-1, H, W, 2),
            flow_valid=valid[:, c].reshape(-1, H, W),
        )
    return out
