"""Room scenes that look like real multi-camera captures (numpy only).

The ``"room"`` style of :class:`~.generator.SynthConfig`: one or two articulated people (see
:mod:`.figures`) walking or gesturing (one may wave a board) in a small room with photographic walls
and floor, furniture along the walls, posters and bright panels on them, an indoor light with hard shadows and a dim ambient term;
cameras like real rigs: webcams on stands 0.7-1.8 m from the people, wide-angle, at head height
around the room, and (with ``camera_motion``) some of them handheld, drifting and shaking a little.
Each camera's video then goes through a sensor: lens blur, exposure and response curve, white balance, muted colour,
vignetting and per-frame noise (:func:`apply_sensor`), so the frames carry the look of webcam
footage rather than of a clean ray tracer.  Geometry, depth, flow and masks stay exact (the sensor
only filters colours, and its blur is under a pixel).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..cameras import Trajectory, look_at
from .assets import PHOTO_TEXTURES, PROCEDURAL_KINDS, hsv_rgb
from .figures import BOARD_HALF, FIGURE_PARTS, Figure, PartMotion, sample_figure
from .motion import MotionLaw, rotation_about
from .render import SceneLayout, SceneObject
from .rig import arc_azimuths

__all__ = ["sample_room", "sample_room_rig", "sample_sensor", "apply_sensor", "RoomLook", "ROOM", "CLOSEUP"]

_Z_UP = np.array([0.0, 0.0, 1.0])

Range = tuple[float, float]


@dataclass(frozen=True)
class RoomLook:
    """The ranges a room scene is drawn from (:data:`ROOM` for ``style="room"``, :data:`CLOSEUP` for
    ``style="closeup"``): camera distance from the people's ground point, height, field of view (degrees), aim
    height and spread (m); the shares of gesturing first people holding a board, of gesturing (not walking)
    people and of scenes with a second person; clothing values; furniture and wall-card counts (inclusive) and
    their texture kinds; the sensor's exposure gain, gamma and noise sigma; the ambient light."""

    radius: Range = (0.7, 1.8)
    eye_z: Range = (1.1, 1.9)
    fov: Range = (55.0, 85.0)
    target_z: Range = (0.9, 1.5)
    aim: float = 0.25
    board: float = 0.5
    gesture: float = 0.6
    people_two: float = 0.35
    shirt_value: Range = (0.12, 0.75)
    trousers_value: Range = (0.08, 0.45)
    furniture: tuple[int, int] = (3, 7)
    cards: tuple[int, int] = (2, 4)
    posters: tuple[str, ...] = ("photo",)
    furniture_kinds: tuple[str, ...] = ("photo", "noise", "gradient", "stripes")
    gain: Range = (0.75, 1.25)
    gamma: Range = (1.0, 1.4)
    ambient: Range = (0.2, 0.4)
    noise: Range = (0.004, 0.015)


ROOM = RoomLook()
# What the "room" style's frames lacked against real desk and calibration recordings (docs/synth.md, "How far
# from real footage"): one person filling a third of the frame (webcams 0.65-1.1 m away at 40-65
# degrees, aimed at chest and head), more often holding a board, darker clothes, a cluttered room (more
# furniture, posters and boards with hard-edged textures), and a sensor that clips bright panels and crushes
# shadows (the contrast of a small sensor in indoor light) with less noise (webcam compression smooths it).
CLOSEUP = RoomLook(radius=(0.65, 1.1), eye_z=(1.1, 1.7), fov=(40.0, 65.0), target_z=(1.1, 1.6), aim=0.12,
                   board=0.65, gesture=0.85, people_two=0.15, shirt_value=(0.03, 0.35), trousers_value=(0.04, 0.35),
                   furniture=(5, 9), cards=(4, 8), posters=("photo", "checker", "stripes"),
                   furniture_kinds=("photo", "stripes", "checker", "noise"), gain=(1.3, 2.2), gamma=(1.2, 1.6),
                   noise=(0.002, 0.008))
_SKIN_PARTS = ("head",)
_LEG_PARTS = ("thigh_l", "thigh_r", "shin_l", "shin_r")


def _textures_by_kind(names: list[str]) -> dict[str, list[int]]:
    """Indices of ``names`` (a split's pool) by kind: "photo" or a procedural kind."""
    out: dict[str, list[int]] = {"photo": []}
    for i, name in enumerate(names):
        if name in PHOTO_TEXTURES:
            out["photo"].append(i)
        else:
            out.setdefault(PROCEDURAL_KINDS[int(name.split("_")[1]) % len(PROCEDURAL_KINDS)], []).append(i)
    return out


def _pick(rng: np.random.Generator, pools: dict[str, list[int]], *kinds: str) -> int:
    pool = [i for k in kinds for i in pools.get(k, [])]
    return int(pool[int(rng.integers(len(pool)))])


def _muted(rng: np.random.Generator, value: tuple[float, float], saturation: tuple[float, float]) -> tuple[float, float, float]:
    """A clothing colour: a random hue at the given value and saturation ranges."""
    hue = rng.random()
    v, s = rng.uniform(*value), rng.uniform(*saturation)
    r, g, b = hsv_rgb(np.array([hue]), np.array([s]), np.array([v]))[0]
    return (float(r), float(g), float(b))


def _skin(rng: np.random.Generator) -> tuple[float, float, float]:
    r = rng.uniform(0.45, 0.9)
    return (float(r), float(r * rng.uniform(0.7, 0.82)), float(r * rng.uniform(0.55, 0.7)))


def sample_room_rig(
    rng: np.random.Generator, *, num_cameras: int, times: np.ndarray, width: int, height: int,
    focus: np.ndarray, camera_motion: bool, look: RoomLook = ROOM,
) -> dict[str, Trajectory]:
    """``num_cameras`` synchronized cameras ``cam00``, ... around ``focus`` (2,), the people's ground point."""
    t = np.asarray(times, dtype=np.float64)[:, None]
    azim = arc_azimuths(rng, num_cameras, min_span=np.deg2rad(200), jitter=0.3)
    radius = rng.uniform(*look.radius, num_cameras)
    eye_z = rng.uniform(*look.eye_z, num_cameras)
    fov = np.deg2rad(rng.uniform(*look.fov, num_cameras))
    aim = look.aim
    target = np.stack([focus[0] + rng.uniform(-aim, aim, num_cameras), focus[1] + rng.uniform(-aim, aim, num_cameras),
                       rng.uniform(*look.target_z, num_cameras)], -1)
    handheld = (rng.random(num_cameras) < 0.35) & camera_motion
    cams: dict[str, Trajectory] = {}
    for i in range(num_cameras):
        eye = np.array([focus[0] + radius[i] * np.cos(azim[i]), focus[1] + radius[i] * np.sin(azim[i]), eye_z[i]])
        eye_t = np.repeat(eye[None], len(t), axis=0)
        tgt_t = np.repeat(target[i][None], len(t), axis=0)
        # drawn for every camera (so a rig's other cameras do not depend on which are handheld)
        drift = rng.uniform(-0.12, 0.12, 3) * np.array([1.0, 1.0, 0.3])
        amp, freq, phase = rng.uniform(0.01, 0.06, (2, 3)), rng.uniform(0.3, 1.2, (2, 3)), rng.uniform(0, 2 * np.pi, (2, 3))
        if handheld[i]:
            shake = amp[None] * np.sin(2 * np.pi * freq[None] * t[:, :, None] + phase[None])   # (T, 2, 3)
            eye_t = eye_t + drift[None] * t + shake[:, 0]
            tgt_t = tgt_t + 1.5 * shake[:, 1]
        f = 0.5 * width / np.tan(0.5 * fov[i])
        K = np.array([[f, 0.0, 0.5 * (width - 1)], [0.0, f, 0.5 * (height - 1)], [0.0, 0.0, 1.0]])
        cams[f"cam{i:02d}"] = Trajectory(K=np.repeat(K[None], len(t), axis=0), w2c=look_at(eye_t, tgt_t, _Z_UP),
                                         width=width, height=height, timestamps=t[:, 0].copy())
    return cams


def _figure_objects(rng: np.random.Generator, figure: Figure, index: int, pools: dict[str, list[int]],
                    look: RoomLook = ROOM) -> list[SceneObject]:
    shirt = (_pick(rng, pools, "photo", "noise", "stripes", "checker", "dots"), _muted(rng, look.shirt_value, (0.0, 0.55)))
    trousers = (_pick(rng, pools, "noise", "gradient", "stripes", "photo"), _muted(rng, look.trousers_value, (0.0, 0.4)))
    skin = (_pick(rng, pools, "gradient", "noise"), _skin(rng))
    bare_arms = rng.random() < 0.4
    objects = []
    for part in FIGURE_PARTS:
        radii = tuple(float(figure.scale * r) for r in FIGURE_PARTS[part][2])
        if part in _SKIN_PARTS or (bare_arms and part.startswith("forearm")):
            tex, tint = skin
        elif part in _LEG_PARTS:
            tex, tint = trousers
        else:
            tex, tint = shirt
        objects.append(SceneObject("ellipsoid", radii, tex, PartMotion(figure, part, index), tint))
    if figure.board:
        board_tint = (float(rng.uniform(0.8, 1.0)),) * 3
        size = (float(figure.scale * BOARD_HALF[0]), float(figure.scale * BOARD_HALF[1]))
        objects.append(SceneObject("card", size, _pick(rng, pools, "checker"), PartMotion(figure, "board", index),
                                   board_tint))
    return objects


def _furniture(rng: np.random.Generator, room_half: float, pools: dict[str, list[int]], count: int,
               look: RoomLook = ROOM) -> list[SceneObject]:
    """Static boxes (desks, cabinets, shelves) standing against the walls, textured by one of ``look``'s kinds."""
    out = []
    for _ in range(count):
        wall = int(rng.integers(4))
        half = np.array([rng.uniform(0.25, 0.7), rng.uniform(0.18, 0.4), rng.uniform(0.2, 0.9)])
        along = rng.uniform(-room_half + half[0] + 0.05, room_half - half[0] - 0.05)
        off = room_half - half[1] - 0.02
        pos = [np.array([along, off]), np.array([along, -off]), np.array([off, along]), np.array([-off, along])][wall]
        R0 = rotation_about(_Z_UP, 0.0 if wall < 2 else np.pi / 2)   # local x along the wall, local y towards it
        motion = MotionLaw("static", np.array([pos[0], pos[1], half[2]]), R0, {})
        tint = _muted(rng, (0.2, 0.85), (0.0, 0.35)) if rng.random() < 0.6 else None
        out.append(SceneObject("box", tuple(float(h) for h in half), _pick(rng, pools, *look.furniture_kinds), motion,
                               tint))
    return out


def _wall_cards(rng: np.random.Generator, room_half: float, pools: dict[str, list[int]], count: int,
                look: RoomLook = ROOM) -> list[SceneObject]:
    """Static cards flat on the walls: posters (textured by one of ``look.posters``) and bright panels (windows,
    lamps, white boards)."""
    out = []
    for _ in range(count):
        wall = int(rng.integers(4))
        hw, hh = float(rng.uniform(0.25, 0.7)), float(rng.uniform(0.25, 0.6))
        along = rng.uniform(-room_half + hw + 0.05, room_half - hw - 0.05)
        off = room_half - 0.01
        pos = [np.array([along, off]), np.array([along, -off]), np.array([off, along]), np.array([-off, along])][wall]
        # card plane z = 0 -> the wall plane: local x along the wall, local y up
        along_axis = np.array([1.0, 0.0, 0.0]) if wall < 2 else np.array([0.0, 1.0, 0.0])
        R0 = np.stack([along_axis, _Z_UP, np.cross(along_axis, _Z_UP)], axis=1)
        motion = MotionLaw("static", np.array([pos[0], pos[1], rng.uniform(1.0, 1.9)]), R0, {})
        bright = rng.random() < 0.6
        tint = (float(rng.uniform(0.85, 1.0)),) * 3 if bright else None
        tex = _pick(rng, pools, "gradient", "noise") if bright else _pick(rng, pools, *look.posters)
        out.append(SceneObject("card", (hw, hh), tex, motion, tint))
    return out


def sample_room(
    rng: np.random.Generator, *, texture_names: list[str], num_cameras: int, times: np.ndarray, width: int,
    height: int, static: bool, camera_motion: bool, look: RoomLook = ROOM,
) -> tuple[dict[str, Trajectory], SceneLayout]:
    """The cameras and layout of one room scene (people, board, furniture, light), drawn from ``look``'s ranges."""
    pools = _textures_by_kind(texture_names)
    focus = rng.uniform(-0.3, 0.3, 2)
    cameras = sample_room_rig(rng, num_cameras=num_cameras, times=times, width=width, height=height,
                              focus=focus, camera_motion=camera_motion, look=look)
    farthest = max(float(np.abs(c.centers[:, :2]).max()) for c in cameras.values())
    room_half = float(max(rng.uniform(2.6, 3.6), farthest + 1.0))
    people = 1 if rng.random() < 1.0 - look.people_two else 2
    objects: list[SceneObject] = []
    for k in range(people):
        action = "still" if static else ("walk", "gesture")[int(rng.random() < look.gesture)]
        if k == 0:
            where, heading = focus, rng.uniform(0, 2 * np.pi)
        else:
            ang = rng.uniform(0, 2 * np.pi)
            where = focus + rng.uniform(0.8, 1.1) * np.array([np.cos(ang), np.sin(ang)])
            heading = ang + np.pi + rng.uniform(-1.0, 1.0)   # roughly facing the first person
        board = action != "walk" and k == 0 and rng.random() < look.board
        figure = sample_figure(rng, action, position=where, heading=float(heading), board=board)
        objects += _figure_objects(rng, figure, k, pools, look)
    objects += _furniture(rng, room_half, pools, int(rng.integers(look.furniture[0], look.furniture[1] + 1)), look)
    objects += _wall_cards(rng, room_half, pools, int(rng.integers(look.cards[0], look.cards[1] + 1)), look)
    el = rng.uniform(np.deg2rad(45), np.deg2rad(80))
    az = rng.uniform(0, 2 * np.pi)
    layout = SceneLayout(
        room_half=room_half, ground_texture=_pick(rng, pools, "noise", "gradient", "photo", "checker"),
        ground_tile=float(rng.uniform(1.5, 3.0)),
        wall_textures=tuple(_pick(rng, pools, "photo", "photo", "photo", "noise", "gradient") for _ in range(4)),  # type: ignore[arg-type]
        wall_tile=float(rng.uniform(0.6, 2.0)),
        light_dir=np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]),
        ambient=float(rng.uniform(*look.ambient)), objects=tuple(objects), shadows=True,
        surface_tints=(_muted(rng, (0.3, 0.85), (0.05, 0.45)) if rng.random() < 0.7 else None,
                       *(_muted(rng, (0.35, 0.95), (0.0, 0.3)) if rng.random() < 0.5 else None for _ in range(4))),
    )
    return cameras, layout


def sample_sensor(rng: np.random.Generator, num_cameras: int, look: RoomLook = ROOM) -> list[dict]:
    """Per camera: blur sigma (px), exposure gain, gamma (> 1: the darker, contrastier response of a small
    sensor in indoor light), white-balance gains (3,), saturation, vignetting, noise sigma."""
    out = []
    for _ in range(num_cameras):
        wb = 1.0 + rng.uniform(-0.08, 0.08, 3)
        out.append(dict(blur=float(rng.uniform(0.2, 0.5)), gain=float(rng.uniform(*look.gain)),
                        gamma=float(rng.uniform(*look.gamma)),
                        white_balance=(wb / wb.mean()).tolist(), saturation=float(rng.uniform(0.5, 0.85)),
                        vignetting=float(rng.uniform(0.1, 0.4)), noise=float(rng.uniform(*look.noise)),
                        noise_seed=int(rng.integers(2**31))))
    return out


def _blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur of (T, H, W, 3) along H and W (radius 2, edges replicated)."""
    x = np.arange(-2, 3, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    k /= k.sum()
    pad = np.pad(img, ((0, 0), (2, 2), (0, 0), (0, 0)), mode="edge")
    img = sum(k[i] * pad[:, i:i + img.shape[1]] for i in range(5))
    pad = np.pad(img, ((0, 0), (0, 0), (2, 2), (0, 0)), mode="edge")
    return sum(k[i] * pad[:, :, i:i + img.shape[2]] for i in range(5))


def apply_sensor(rgb: np.ndarray, sensor: dict) -> np.ndarray:
    """One camera's (T, H, W, 3) uint8 video through the sensor ``sensor`` (one of :func:`sample_sensor`'s)."""
    T, H, W, _ = rgb.shape
    img = _blur(rgb.astype(np.float64) / 255.0, sensor["blur"])
    img = np.clip(img * sensor["gain"] * np.asarray(sensor["white_balance"])[None, None, None], 0.0, 1.0) ** sensor["gamma"]
    luma = img @ np.array([0.299, 0.587, 0.114])
    img = luma[..., None] + sensor["saturation"] * (img - luma[..., None])
    yy, xx = np.meshgrid(np.linspace(-1, 1, H), np.linspace(-1, 1, W), indexing="ij")
    img = img * (1.0 - sensor["vignetting"] * 0.5 * (xx ** 2 + yy ** 2))[None, :, :, None]
    noise = np.random.default_rng(sensor["noise_seed"]).standard_normal(img.shape)
    img = img + sensor["noise"] * noise
    return np.round(np.clip(img, 0.0, 1.0) * 255.0).astype(np.uint8)
