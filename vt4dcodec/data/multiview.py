"""Training pairs from multi-camera scenes: (source video + cameras + depth, target video + cameras).

The codec encodes a SOURCE camera's video (with its depth and trajectory) and must render the same
event from a TARGET camera; :class:`MultiViewPairs` enumerates such pairs over many scenes.  Scenes
come from capture directories on disk (any capture, e.g. written by ``vt4d synth``) or are generated
on the fly from integer seeds with :func:`vt4dcodec.synth.generate_scene`.

Index order: scene-major, then source camera, then target camera (manifest order), so item ``i`` is
always the same pair (deterministic for an index).
"""

from __future__ import annotations

import json
import os
from collections import OrderedDict
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
import torch
from torch.utils.data import Dataset

from ..capture import io as capture_io
from ..capture.io import read_manifest
from ..errors import CaptureError
from ..synth import SynthConfig, generate_scene
from ..synth.assets import SynthError
from ..synth.dataset_writer import GT_NAME

__all__ = ["MultiViewPairs", "PAIRINGS", "camera_pairs", "find_capture_dirs"]

PAIRINGS = ("different", "same", "all")
MANIFEST = "capture.json"


def find_capture_dirs(root: str | os.PathLike) -> list[Path]:
    """Capture directories (holding ``capture.json``) directly inside ``root``, sorted by name;
    ``root`` itself if it is one."""
    root = Path(root)
    if (root / MANIFEST).is_file():
        return [root]
    if not root.is_dir():
        raise CaptureError(f"{root} is not a directory of captures")
    found = sorted(p for p in root.iterdir() if (p / MANIFEST).is_file())
    if not found:
        raise CaptureError(f"{root} holds no capture directories (subdirectories with {MANIFEST})")
    return found


def _camera_index(names: Sequence[str], which: str | int | None, what: str) -> list[int]:
    if which is None:
        return list(range(len(names)))
    if isinstance(which, (int, np.integer)) and not isinstance(which, bool):
        if not 0 <= which < len(names):
            raise CaptureError(f"{what} index {which} is out of range for {len(names)} cameras")
        return [int(which)]
    if which not in names:
        raise CaptureError(f"{what} {which!r} is not one of the cameras {list(names)}")
    return [list(names).index(which)]


def camera_pairs(names: Sequence[str], pairing: str, source_camera: str | int | None = None,
                 target_camera: str | int | None = None) -> list[tuple[int, int]]:
    """(source, target) camera index pairs of one scene.

    ``pairing``: "different" (every ordered pair of distinct cameras: novel-view training), "same"
    (source == target: reconstruction), "all" (both).  ``source_camera``/``target_camera`` (name or
    index) restrict the source/target side.
    """
    if pairing not in PAIRINGS:
        raise CaptureError(f"pairing must be one of {PAIRINGS}, got {pairing!r}")
    sources = _camera_index(names, source_camera, "source_camera")
    targets = _camera_index(names, target_camera, "target_camera")
    keep = {"different": lambda s, t: s != t, "same": lambda s, t: s == t, "all": lambda s, t: True}[pairing]
    return [(s, t) for s in sources for t in targets if keep(s, t)]


def _manifest_camera_names(path: Path) -> list[str]:
    """Camera names listed in a capture manifest, without the full (slower) validated read.

    Only used to count pairs; the scene is read and validated with ``read_manifest`` when an item
    of it is first loaded."""
    try:
        with open(path / MANIFEST, "rb") as fh:
            doc = json.load(fh)
        names = [str(cam["name"]) for cam in doc["cameras"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise CaptureError(f"{path / MANIFEST}: cannot list its cameras ({exc})") from None
    if not names:
        raise CaptureError(f"{path / MANIFEST} lists no cameras")
    return names


class _DiskScene:
    """A capture directory read one camera at a time (only the cameras a pair needs)."""

    def __init__(self, path: Path):
        self.manifest = read_manifest(path)
        self.path = path
        self.names = [e.name for e in self.manifest.cameras]
        self.scene_id = self.manifest.capture_id

    def camera(self, name: str, *, depth: bool, mask: bool) -> dict[str, Any]:
        entry = self.manifest.camera(name)
        out: dict[str, Any] = {"frames": capture_io.read_camera_frames(self.manifest, name),
                               "K": entry.trajectory.K, "w2c": entry.trajectory.w2c}
        if depth and entry.depth_type is not None:
            # TODO(capture owner): a public read_camera_depth(manifest, name); this is its private twin.
            out["depth"] = capture_io.read_camera_depth(self.manifest, entry)
        if mask and (self.path / GT_NAME).is_file():
            try:
                with np.load(self.path / GT_NAME, allow_pickle=False) as z:
                    names = [str(n) for n in z["camera_names"]]
                    masks = z["dynamic_mask"]
            except (ValueError, OSError, KeyError, EOFError) as exc:
                raise SynthError(f"{self.path / GT_NAME} is damaged: {exc}") from None
            if name in names and masks.shape[1:] == out["frames"].shape[:3]:
                out["dynamic_mask"] = masks[names.index(name)]
        return out


class _GeneratedScene:
    """A scene generated in memory from its seed."""

    def __init__(self, seed: int, split: str, config: SynthConfig):
        self.scene = generate_scene(seed, split=split, config=config)
        self.names = self.scene.capture.camera_names
        self.scene_id = self.scene.capture.capture_id

    def camera(self, name: str, *, depth: bool, mask: bool) -> dict[str, Any]:
        cap = self.scene.capture
        out = {"frames": cap.frames[name], "K": cap.cameras[name].K, "w2c": cap.cameras[name].w2c}
        if depth:
            out["depth"] = cap.depth[name]
        if mask:
            out["dynamic_mask"] = self.scene.dynamic_mask[name]
        return out


def _video_tensor(frames: np.ndarray) -> torch.Tensor:
    """(T, H, W, 3) uint8 -> (T, 3, H, W) float32 in [0, 1]."""
    # numpy, not torch ops: tiny torch kernels stall on the thread pool when the machine is busy
    video = np.ascontiguousarray(frames.transpose(0, 3, 1, 2), dtype=np.float32)
    video /= np.float32(255.0)
    return torch.from_numpy(video)


def _f32(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))


class MultiViewPairs(Dataset):
    """(source video, source cameras, source depth, target video, target cameras) pairs.

    Args:
        scenes: a directory of capture directories (or one capture directory), a list of capture
            directory paths, OR a ``range``/list of integer seeds generated on the fly with ``split``
            and ``config``.
        pairing: "different" | "same" | "all", see :func:`camera_pairs`.
        source_camera, target_camera: fix the source/target camera (name or index).
        split, config: for generated scenes only.
        cache_scenes: how many scenes to keep in memory per process (generated scenes cost ~0.3 s
            each; items of a scene are adjacent, so sequential access generates each scene once).

    Each item is a dict:
        source_frames (T, 3, H, W) float32 in [0, 1]; source_K (T, 3, 3) float32 pixels;
        source_w2c (T, 4, 4) float32 metres; source_depth (T, H, W) float32 metres (0 = unknown);
        target_frames, target_K, target_w2c likewise for the target camera; target_depth when known;
        source_dynamic_mask (T, H, W) bool when known (synthetic scenes);
        scene_id str; source_camera, target_camera names.
    """

    def __init__(self, scenes: Any, *, pairing: str = "different", source_camera: str | int | None = None,
                 target_camera: str | int | None = None, split: str = "train",
                 config: SynthConfig = SynthConfig(), cache_scenes: int = 2):
        self.pairing = pairing
        self.split = split
        self.config = config
        self.cache_scenes = max(int(cache_scenes), 1)
        self._cache: OrderedDict[int, Any] = OrderedDict()
        self._sources = self._resolve(scenes)
        self._pairs: list[list[tuple[int, int]]] = []
        self._names: list[list[str] | None] = [None] * len(self._sources)
        for j in range(len(self._sources)):
            names = self._camera_names(j)
            self._pairs.append(camera_pairs(names, pairing, source_camera, target_camera))
        self._offsets = np.cumsum([0] + [len(p) for p in self._pairs])

    # --- scene sources ---------------------------------------------------------------------------
    def _resolve(self, scenes: Any) -> list[Path | int]:
        if isinstance(scenes, (str, os.PathLike)):
            return list(find_capture_dirs(scenes))
        if isinstance(scenes, range):
            scenes = list(scenes)
        if not isinstance(scenes, Iterable):
            raise CaptureError("scenes must be a directory, a list of capture directories, or seeds")
        items = list(scenes)
        if not items:
            raise CaptureError("scenes is empty")
        if all(isinstance(s, (int, np.integer)) and not isinstance(s, bool) for s in items):
            for s in items:
                if s < 0:
                    raise CaptureError(f"scene seeds must be non-negative, got {s}")
            return [int(s) for s in items]
        if all(isinstance(s, (str, os.PathLike)) for s in items):
            paths = [Path(s) for s in items]
            for p in paths:
                if not (p / MANIFEST).is_file():
                    raise CaptureError(f"{p} is not a capture directory (no {MANIFEST})")
            return paths
        raise CaptureError("scenes must be all integer seeds or all capture directory paths")

    def _camera_names(self, j: int) -> list[str]:
        names = self._names[j]
        if names is None:
            src = self._sources[j]
            if isinstance(src, int):   # generate_scene names its cameras cam00, cam01, ...
                names = [f"cam{i:02d}" for i in range(self.config.num_cameras)]
            else:
                names = _manifest_camera_names(src)
            self._names[j] = names
        return names

    def _scene(self, j: int) -> Any:
        if j in self._cache:
            self._cache.move_to_end(j)
            return self._cache[j]
        src = self._sources[j]
        scene = _GeneratedScene(src, self.split, self.config) if isinstance(src, int) else _DiskScene(src)
        self._cache[j] = scene
        while len(self._cache) > self.cache_scenes:
            self._cache.popitem(last=False)
        return scene

    # --- Dataset ---------------------------------------------------------------------------------
    @property
    def num_scenes(self) -> int:
        return len(self._sources)

    def __len__(self) -> int:
        return int(self._offsets[-1])

    def locate(self, index: int) -> tuple[int, str, str]:
        """(scene number, source camera, target camera) of item ``index``."""
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
            raise TypeError(f"index must be an integer, got {type(index).__name__}")
        n = len(self)
        if index < 0:
            index += n
        if not 0 <= index < n:
            raise IndexError(f"index {index} out of range for {n} pairs")
        j = int(np.searchsorted(self._offsets, index, side="right") - 1)
        s, t = self._pairs[j][index - int(self._offsets[j])]
        names = self._camera_names(j)
        return j, names[s], names[t]

    def __getitem__(self, index: int) -> dict[str, Any]:
        j, src_name, tgt_name = self.locate(index)
        scene = self._scene(j)
        if scene.names != self._camera_names(j):
            raise CaptureError(f"capture {self._sources[j]} changed while in use (its cameras differ)")
        src = scene.camera(src_name, depth=True, mask=True)
        tgt = src if tgt_name == src_name else scene.camera(tgt_name, depth=True, mask=False)
        T, H, W = src["frames"].shape[:3]
        item: dict[str, Any] = {
            "source_frames": _video_tensor(src["frames"]),
            "source_K": _f32(src["K"]),
            "source_w2c": _f32(src["w2c"]),
            "source_depth": _f32(src["depth"]) if "depth" in src else torch.zeros(T, H, W),
            "target_frames": _video_tensor(tgt["frames"]),
            "target_K": _f32(tgt["K"]),
            "target_w2c": _f32(tgt["w2c"]),
            "scene_id": scene.scene_id,
            "source_camera": src_name,
            "target_camera": tgt_name,
        }
        if "depth" in tgt:
            item["target_depth"] = _f32(tgt["depth"])
        if "dynamic_mask" in src:
            item["source_dynamic_mask"] = torch.from_numpy(np.ascontiguousarray(src["dynamic_mask"], dtype=bool))
        return item

