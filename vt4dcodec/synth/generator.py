"""Synthetic multi-camera dynamic scenes, deterministic from (seed, split, config) (numpy only).

Three styles.  ``"objects"`` (the default): a textured room (ground + four walls, photo or procedural
textures of the split's pool), 2-4 textured rigid objects (spheres, boxes, cards) with linear,
circular, bouncing or spinning motion near the centre, and K synchronized cameras 3-5 m around them
(see :mod:`.rig`).  ``"room"``: scenes that look like real captures: articulated people walking or
gesturing in a small furnished room with shadows, webcam-like rigs close to them and a sensor model
(see :mod:`.room`); ``"closeup"``: the room style framed as desk and calibration recordings are, one
person filling a third of the frame in a cluttered room through a contrastier sensor
(:data:`.room.CLOSEUP`).  All render RGB, metric depth, exact optical flow t -> t+1, dynamic masks and
object ids (see :mod:`.render`).
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass, field

import numpy as np

from ..capture import Capture
from ..cameras import Trajectory
from .assets import SynthError, check_split, texture_bank, texture_names
from .motion import MOTION_KINDS, sample_motion
from .render import FIRST_OBJECT_SURFACE, SHAPES, SceneLayout, SceneObject, render_layout
from .rig import sample_rig
from .room import CLOSEUP, ROOM, RoomLook, apply_sensor, sample_room, sample_sensor

__all__ = ["STYLES", "SynthConfig", "SynthScene", "SceneSetup", "generate_scene", "scene_setup", "scene_id"]

STYLES = ("objects", "room", "closeup")

MAX_SCENE_PIXELS = 64 * 2**20   # cameras x frames x height x width
MAX_CAMERAS = 256
MAX_FRAMES = 1024


@dataclass(frozen=True)
class SynthConfig:
    """What to generate.

    Attributes:
        num_cameras: synchronized cameras per scene.
        num_frames: frames per camera (T >= 2 so there is flow).
        height, width: image size in pixels.
        num_objects: inclusive (min, max) number of rigid objects (style "objects"; the "room" style
            draws its own: one or two people, a board, 3-7 pieces of furniture, 2-4 wall cards).
        static: True -> the objects (people) stand still (nothing moves; flow is camera-induced only).
        camera_motion: False -> every camera is fixed.
        fps: frame rate; motion speeds are in metres/second, so fps sets the per-frame motion.
        style: "objects" (rigid shapes in a large room), "room" (people in a furnished room, webcam
            rigs and a sensor model; :mod:`.room`) or "closeup" (the room style with the cameras near one
            person, clutter and a contrastier sensor; :data:`.room.CLOSEUP`).
    """

    num_cameras: int = 10
    num_frames: int = 8
    height: int = 64
    width: int = 64
    num_objects: tuple[int, int] = (2, 4)
    static: bool = False
    camera_motion: bool = True
    fps: float = 8.0
    style: str = "objects"

    def __post_init__(self) -> None:
        for name, lo, hi in (("num_cameras", 1, MAX_CAMERAS), ("num_frames", 2, MAX_FRAMES),
                             ("height", 2, 4096), ("width", 2, 4096)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
                raise SynthError(f"SynthConfig.{name} must be an integer in [{lo}, {hi}], got {v!r}")
        lo_hi = tuple(self.num_objects)
        if len(lo_hi) != 2 or not all(isinstance(x, (int, np.integer)) for x in lo_hi) or not (
                0 <= lo_hi[0] <= lo_hi[1] <= 16):
            raise SynthError(f"SynthConfig.num_objects must be (min, max) with 0 <= min <= max <= 16, got {self.num_objects!r}")
        object.__setattr__(self, "num_objects", (int(lo_hi[0]), int(lo_hi[1])))
        if not (isinstance(self.fps, (int, float)) and np.isfinite(self.fps) and 0 < self.fps <= 1000):
            raise SynthError(f"SynthConfig.fps must be a positive number of frames per second, got {self.fps!r}")
        if self.style not in STYLES:
            raise SynthError(f"SynthConfig.style must be one of {STYLES}, got {self.style!r}")

    def to_dict(self) -> dict:
        """The fields as plain values; ``style`` only when it is not the default, so every "objects"
        scene keeps the random draws (and pixels) it had before styles existed."""
        d = asdict(self)
        d["num_objects"] = list(self.num_objects)
        if self.style == "objects":
            del d["style"]
        return d


@dataclass
class SynthScene:
    """A generated scene: the capture plus per-camera ground truth.

    Attributes:
        capture: the :class:`Capture`, with depth (float32 metres, z in the camera frame).
        flow: camera -> (T-1, H, W, 2) float32 optical flow t -> t+1 in pixels (du, dv), exact.
        flow_valid: camera -> (T-1, H, W) bool, the point is inside and visible (not occluded) at t+1.
        dynamic_mask: camera -> (T, H, W) bool, the pixel shows a moving object.
        object_ids: camera -> (T, H, W) int16, 0 static background, k the k-th object (1-based).
        objects: one description per object (shape, size m, texture name, motion kind and params).
        textures: the names of every texture the scene uses.
        seed, split: what it was generated from.
    """

    capture: Capture
    flow: dict[str, np.ndarray]
    flow_valid: dict[str, np.ndarray]
    dynamic_mask: dict[str, np.ndarray]
    object_ids: dict[str, np.ndarray]
    objects: list[dict] = field(default_factory=list)
    textures: list[str] = field(default_factory=list)
    seed: int = 0
    split: str = "train"


def scene_id(seed: int, split: str) -> str:
    """The capture id of a generated scene, e.g. ``synth-train-000042``."""
    return f"synth-{split}-{seed:06d}"


def _rng(seed: int, split: str, config: SynthConfig, stream: int = 0) -> np.random.Generator:
    """The scene's random stream: 0 draws the setup (cameras, layout), 1 the room style's sensors."""
    digest = hashlib.sha256(repr((split, sorted(config.to_dict().items()))).encode()).digest()
    return np.random.default_rng([int(seed), int.from_bytes(digest[:8], "little")] + ([stream] if stream else []))


def _sample_object(rng: np.random.Generator, texture: int, kind: str) -> SceneObject:
    shape = SHAPES[int(rng.integers(len(SHAPES)))]
    angle = rng.uniform(0, 2 * np.pi)
    dist = rng.uniform(0.0, 1.3)
    start = np.array([dist * np.cos(angle), dist * np.sin(angle)])
    tumbling = kind == "spinning" and shape != "card" and rng.random() < 0.5
    if shape == "sphere":
        size = (float(rng.uniform(0.25, 0.6)),)
        rest, upright = size[0], False
    elif shape == "box":
        size = tuple(float(x) for x in rng.uniform(0.2, 0.55, 3))
        rest, upright = (float(np.linalg.norm(size)) if tumbling else size[2]), not tumbling
    else:
        size = (float(rng.uniform(0.3, 0.7)), float(rng.uniform(0.25, 0.6)))
        rest, upright = size[1] + 0.02, True
    motion = sample_motion(rng, kind, start=start, rest_height=rest, upright=upright)
    if shape == "card":
        # stand the card up: its local plane z = 0 becomes vertical (local y -> world z)
        stand = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
        motion = type(motion)(motion.kind, motion.p0, motion.R0 @ stand, motion.params)
    return SceneObject(shape=shape, size=size, texture=texture, motion=motion)


def _sample_layout(rng: np.random.Generator, config: SynthConfig, num_textures: int,
                   min_room: float) -> SceneLayout:
    textures = rng.permutation(num_textures)
    n_obj = int(rng.integers(config.num_objects[0], config.num_objects[1] + 1))
    objects = []
    for k in range(n_obj):
        kind = "static" if config.static else MOTION_KINDS[int(rng.integers(len(MOTION_KINDS)))]
        objects.append(_sample_object(rng, int(textures[5 + k % (num_textures - 5)]), kind))
    el = rng.uniform(np.deg2rad(35), np.deg2rad(75))
    az = rng.uniform(0, 2 * np.pi)
    return SceneLayout(
        room_half=float(max(rng.uniform(7.0, 10.0), min_room)),
        ground_texture=int(textures[0]), ground_tile=float(rng.uniform(1.0, 3.0)),
        wall_textures=tuple(int(x) for x in textures[1:5]), wall_tile=float(rng.uniform(2.0, 4.0)),
        light_dir=np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]),
        ambient=float(rng.uniform(0.45, 0.65)), objects=tuple(objects),
    )


@dataclass(frozen=True)
class SceneSetup:
    """Everything a scene is rendered from: its frame times, cameras and layout (objects and their motion).

    Attributes:
        times: (T,) float64 seconds of the frames.
        cameras: name -> :class:`Trajectory` (K, w2c per frame; OpenCV convention, world-to-camera).
        layout: the room, the light and the rigid objects with their :class:`~.motion.MotionLaw`;
            object k (0-based) has id k + 1 in :attr:`SynthScene.object_ids`.
    """

    times: np.ndarray
    cameras: dict[str, Trajectory]
    layout: SceneLayout


_ROOM_LOOKS: dict[str, RoomLook] = {"room": ROOM, "closeup": CLOSEUP}  # the styles drawn by sample_room


def _check_request(seed: int, split: str, config: SynthConfig) -> None:
    check_split(split)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SynthError(f"seed must be a non-negative integer, got {seed!r}")
    if config.num_cameras * config.num_frames * config.height * config.width > MAX_SCENE_PIXELS:
        raise SynthError("SynthConfig asks for more than 64 Mpixel per scene; use fewer/smaller views")


def scene_setup(seed: int, *, split: str = "train", config: SynthConfig = SynthConfig()) -> SceneSetup:
    """The cameras and layout of scene ``seed`` of ``split``, exactly those :func:`generate_scene` renders,
    without rendering (milliseconds): the ground truth of any point's motion (see :mod:`.tracks`)."""
    _check_request(seed, split, config)
    rng = _rng(int(seed), split, config)
    times = np.arange(config.num_frames) / float(config.fps)
    look = _ROOM_LOOKS.get(config.style)
    if look is not None:
        cameras, layout = sample_room(rng, texture_names=texture_names(split), num_cameras=config.num_cameras,
                                      times=times, width=config.width, height=config.height, static=config.static,
                                      camera_motion=config.camera_motion, look=look)
        return SceneSetup(times=times, cameras=cameras, layout=layout)
    cameras = sample_rig(rng, num_cameras=config.num_cameras, times=times, width=config.width,
                         height=config.height, camera_motion=config.camera_motion)
    farthest = max(float(np.abs(c.centers[:, :2]).max()) for c in cameras.values())
    layout = _sample_layout(rng, config, len(texture_names(split)), farthest + 1.0)
    return SceneSetup(times=times, cameras=cameras, layout=layout)


def generate_scene(seed: int, *, split: str = "train", config: SynthConfig = SynthConfig()) -> SynthScene:
    """Generate scene ``seed`` of ``split`` ("train" or "test"); the same arguments give the same scene."""
    setup = scene_setup(seed, split=split, config=config)
    bank = texture_bank(split)
    times, cameras, layout = setup.times, setup.cameras, setup.layout
    views = render_layout(layout, cameras, times, bank)
    look = _ROOM_LOOKS.get(config.style)
    if look is not None:
        sensors = sample_sensor(_rng(int(seed), split, config, stream=1), len(views), look)
        for view, sensor in zip(views.values(), sensors):
            view.rgb = apply_sensor(view.rgb, sensor)
    moving = np.array([False] + [o.motion.moves for o in layout.objects])
    frames, depth, flow, valid, masks, ids = {}, {}, {}, {}, {}, {}
    for name, view in views.items():
        frames[name], depth[name], flow[name], valid[name] = view.rgb, view.depth, view.flow, view.flow_valid
        oid = np.maximum(view.surface.astype(np.int16) - (FIRST_OBJECT_SURFACE - 1), 0).astype(np.int16)
        ids[name] = oid
        masks[name] = moving[oid]
    used = [bank.names[i] for i in (layout.ground_texture, *layout.wall_textures)]
    objects = []
    for obj in layout.objects:
        used.append(bank.names[obj.texture])
        objects.append({"shape": obj.shape, "size_m": list(obj.size), "texture": bank.names[obj.texture],
                        "motion": obj.motion.kind, "motion_params": obj.motion.params})
    capture = Capture(
        cameras=cameras, frames=frames, depth=depth, fps=float(config.fps),
        capture_id=scene_id(int(seed), split),
        metadata={"generator": "vt4dcodec.synth", "seed": int(seed), "split": split,
                  "config": config.to_dict(), "objects": objects, "textures": sorted(set(used))},
    )
    return SynthScene(capture=capture, flow=flow, flow_valid=valid, dynamic_mask=masks, object_ids=ids,
                      objects=objects, textures=sorted(set(used)), seed=int(seed), split=split)
