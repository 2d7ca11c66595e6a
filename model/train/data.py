"""Training data from the synthetic multi-camera generator, cached on disk.

Generating a scene (about 1 s per camera at 64x64) and preprocessing a source clip (DIS flow, motion
isolation, tracks: about 1.5 s) cost far more than a training step, so each scene is generated once,
each camera preprocessed once, and both are cached as ``.npz`` (no pickle) under ``cache``. Workers
fill the cache lazily; later epochs, resumed runs and other runs with the same settings reuse it.

Scenes come either from integer seeds (generated on the fly by :func:`vt4dcodec.synth.generate_scene`)
or, with ``captures``, from capture directories on disk (e.g. written by ``vt4d synth``), read through
:class:`vt4dcodec.data.multiview.MultiViewPairs`; then a "seed" is an index into ``captures``.

* :class:`FrameDataset` (stage 1): single frames of every camera.
* :class:`PairDataset` (stage 2): (source c, target a) camera pairs of one event -- every ordered
  pair a != c, or per source a sampled target (itself, or a camera that overlaps it): the source clip
  with its :class:`SourceInputs`, the target camera's frames and trajectory.
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset, Sampler
from tqdm import tqdm

from vt4dcodec.cameras import Trajectory
from vt4dcodec.data.multiview import MultiViewPairs
from vt4dcodec.errors import CaptureError
from vt4dcodec.reference import model_centre, move_origin
from vt4dcodec.synth import SynthConfig, generate_scene
from vt4dcodec.synth.assets import PHOTO_TEXTURES, photo_image

from ..configs import ModelConfig
from ..identity import weights_sha256
from ..inputs.motion import MASK_RULE_VERSION
from ..inputs.preprocess import prepare_source
from ..inputs.source_inputs import SourceBatch, SourceInputs

__all__ = ["ScenePool", "FrameDataset", "PhotoCrops", "MixedFrames", "PairDataset", "ViewsBatchSampler",
           "axis_angles_deg", "track_depths",
           "autoencoder_key", "precompute_latents", "prefill_scenes", "collate_pairs", "PairBatch", "rank_seeds"]


def rank_seeds(first: int, count: int, rank: int, world_size: int) -> list[int]:
    """The scene seeds of one process: disjoint across ranks, together ``first .. first+count-1``."""
    return list(range(first + rank, first + count, world_size))


def _save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
    with tmp.open("wb") as f:
        np.savez(f, **arrays)
    os.replace(tmp, path)


def _load_npz(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


@dataclass(frozen=True)
class ScenePool:
    """Where and how the synthetic training scenes are made (picklable for DataLoader workers)."""

    cache: Path
    cameras: int
    frames: int
    image_size: int
    latent_size: int
    n_tracks: int
    motion_isolation: bool = True
    split: str = "train"
    captures: tuple[Path, ...] = ()
    room_share: float = 0.0
    closeup_share: float = 0.0

    @classmethod
    def for_config(cls, cfg: ModelConfig, cache: Path, cameras: int, captures: tuple[Path, ...] = (),
                   room_share: float = 0.0, closeup_share: float = 0.0) -> "ScenePool":
        if not 0.0 <= room_share <= 1.0:
            raise ValueError(f"--room-share must be a share in [0, 1], got {room_share!r}")
        if not 0.0 <= closeup_share <= 1.0 - room_share:
            raise ValueError(f"--closeup-share must be a share in [0, 1 - room share], got {closeup_share!r}")
        return cls(Path(cache), cameras, cfg.frames, cfg.image_size, cfg.latent_size, cfg.n_tracks,
                   cfg.motion_isolation, captures=tuple(Path(p).resolve() for p in captures),
                   room_share=float(room_share), closeup_share=float(closeup_share))

    def style(self, seed: int) -> str:
        """The synthetic style of scene ``seed``: "room" for a fixed ``room_share`` of the seeds, "closeup" for
        the next ``closeup_share`` (by a hash of the seed, so a scene's style never depends on the pool's size or
        order, and a closeup share leaves the room scenes where they were), else "objects"."""
        u = int.from_bytes(hashlib.sha256(f"room-share:{seed}".encode()).digest()[:8], "little") / 2.0**64
        if u < self.room_share:
            return "room"
        return "closeup" if u < self.room_share + self.closeup_share else "objects"

    def _stem(self, seed: int) -> str:
        source = f"disk-{self.captures[seed].name}" if self.captures else f"{self.split}-{seed:06d}"
        style = "objects" if self.captures else self.style(seed)
        if style != "objects":
            source = f"{style}-{source}"
        return f"{source}-c{self.cameras}-t{self.frames}-s{self.image_size}"

    def scene(self, seed: int) -> dict[str, np.ndarray]:
        """frames (C,T,H,W,3) uint8, K (C,T,3,3) and w2c (C,T,4,4) float64, depth (C,T,H,W) float32."""
        return _cached_scene(self, seed)

    def prepared(self, seed: int) -> dict[str, np.ndarray]:
        """motion_mask (C,T,h,w), track_xy (C,N,T,2), track_valid (C,N,T) of every camera as source."""
        return _cached_prepared(self, seed)

    def source_inputs(self, seed: int, cameras: list[int], centre: np.ndarray | None = None) -> list[SourceInputs]:
        """The encoder inputs of each of ``cameras`` of scene ``seed`` as a source (float32 cameras), in the world
        frame whose origin is ``centre`` (None: the scene's own; vt4dcodec.reference.model_centre)."""
        scene, prep = self.scene(seed), self.prepared(seed)
        return [SourceInputs(frames=scene["frames"][c], K=scene["K"][c].astype(np.float32),
                             w2c=move_origin(scene["w2c"][c], centre).astype(np.float32),
                             motion_mask=prep["motion_mask"][c],
                             track_xy=prep["track_xy"][c], track_valid=prep["track_valid"][c],
                             track_depth=track_depths(scene["depth"][c], prep["track_xy"][c], prep["track_valid"][c],
                                                      self.latent_size)) for c in cameras]

    def build_scene(self, seed: int) -> dict[str, np.ndarray]:
        path = self.cache / f"scene-{self._stem(seed)}.npz"
        if path.is_file():
            return _load_npz(path)
        arrays = self._read_capture(self.captures[seed]) if self.captures else self._generate(seed)
        self.cache.mkdir(parents=True, exist_ok=True)
        _save_npz(path, arrays)
        return arrays

    def _generate(self, seed: int) -> dict[str, np.ndarray]:
        config = SynthConfig(num_cameras=self.cameras, num_frames=self.frames, height=self.image_size,
                             width=self.image_size, style=self.style(seed))
        capture = generate_scene(seed, split=self.split, config=config).capture
        names = sorted(capture.cameras)
        return {
            "frames": np.stack([capture.frames[n] for n in names]),
            "K": np.stack([capture.cameras[n].K for n in names]).astype(np.float64),
            "w2c": np.stack([capture.cameras[n].w2c for n in names]).astype(np.float64),
            "depth": np.stack([capture.depth[n] for n in names]).astype(np.float32),
        }

    def _read_capture(self, path: Path) -> dict[str, np.ndarray]:
        """The first ``cameras`` cameras and ``frames`` frames of a capture directory (depth 0 = unknown)."""
        views = MultiViewPairs([path], pairing="same")
        if len(views) < self.cameras:
            raise CaptureError(f"{path} has {len(views)} cameras; training asks for {self.cameras}")
        items = [views[c] for c in range(self.cameras)]
        T, _, H, W = items[0]["source_frames"].shape
        if T < self.frames or (H, W) != (self.image_size, self.image_size):
            raise CaptureError(f"{path}: {T} frames of {W}x{H}; the model needs >= {self.frames} frames of "
                               f"{self.image_size}x{self.image_size}")
        T = self.frames

        def stack(key: str) -> np.ndarray:
            return np.stack([it[key][:T].numpy() for it in items])

        frames = np.round(stack("source_frames") * 255.0).clip(0, 255).astype(np.uint8).transpose(0, 1, 3, 4, 2)
        return {"frames": np.ascontiguousarray(frames), "K": stack("source_K").astype(np.float64),
                "w2c": stack("source_w2c").astype(np.float64), "depth": stack("source_depth").astype(np.float32)}

    def latents_path(self, seed: int, key: str) -> Path:
        """Cache file of one scene's autoencoder latents (C, T, c, h, w) float32; ``key`` names the
        frozen autoencoder (:func:`autoencoder_key`), so latents of other weights are never mixed in."""
        return self.cache / f"lat-{self._stem(seed)}-{key}.npz"

    def latents(self, seed: int, key: str) -> np.ndarray:
        return _load_npz(self.latents_path(seed, key))["latents"]

    def prepared_path(self, seed: int) -> Path:
        """Cache file of one scene's prepared inputs; keyed by the mask rule's version, so masks made
        by an older ``isolate_motion`` are never mixed with new ones."""
        iso = f"iso{MASK_RULE_VERSION}" if self.motion_isolation else "noiso"
        return self.cache / f"prep-{self._stem(seed)}-l{self.latent_size}-n{self.n_tracks}-{iso}.npz"

    def build_prepared(self, seed: int) -> dict[str, np.ndarray]:
        path = self.prepared_path(seed)
        if path.is_file():
            return _load_npz(path)
        scene = self.scene(seed)
        masks, xys, valids = [], [], []
        for c in range(self.cameras):
            trajectory = Trajectory(K=scene["K"][c], w2c=scene["w2c"][c], width=self.image_size,
                                    height=self.image_size)
            depth = scene["depth"][c] if np.any(scene["depth"][c] > 0) else None  # None: plane-sweep estimate
            src = prepare_source(scene["frames"][c], trajectory, depth,
                                 latent_hw=(self.latent_size, self.latent_size), num_tracks=self.n_tracks,
                                 seed=seed * 1009 + c, motion_isolation=self.motion_isolation)
            masks.append(src.motion_mask)
            xys.append(src.track_xy)
            valids.append(src.track_valid)
        arrays = {"motion_mask": np.stack(masks), "track_xy": np.stack(xys), "track_valid": np.stack(valids)}
        _save_npz(path, arrays)
        return arrays


def track_depths(depth: np.ndarray, track_xy: np.ndarray, track_valid: np.ndarray, latent_size: int) -> np.ndarray:
    """(N, T) float32: the depth map (T, H, W, metres, 0 = unknown) at each track's position (N, T, 2, latent
    pixels (u, v), centres at integers), nearest image pixel; 0 where the track is invalid or leaves the image."""
    T, H, W = depth.shape
    scale = W / latent_size
    x = np.rint((track_xy[..., 0] + 0.5) * scale - 0.5).astype(np.int64)
    y = np.rint((track_xy[..., 1] + 0.5) * scale - 0.5).astype(np.int64)
    inside = track_valid & (x >= 0) & (x < W) & (y >= 0) & (y < H)
    t = np.broadcast_to(np.arange(T)[None], x.shape)
    out = depth[t, y.clip(0, H - 1), x.clip(0, W - 1)]
    return np.where(inside, out, 0.0).astype(np.float32)


def autoencoder_key(autoencoder: torch.nn.Module) -> str:
    """12 hex digits of the autoencoder's weights hash (the one model fingerprints use)."""
    return weights_sha256(autoencoder.state_dict())[:12]


@torch.no_grad()
def precompute_latents(pool: "ScenePool", seeds: list[int], autoencoder: torch.nn.Module,
                       progress: bool = False) -> str:
    """Encode every frame of every camera of ``seeds`` once with the frozen ``autoencoder`` and cache
    the latents (stage 2 then skips the encoder pass, about 40 % of a step). Returns the cache key."""
    key = autoencoder_key(autoencoder)
    autoencoder.eval()
    device = next(autoencoder.parameters()).device  # encoded where the autoencoder lives (CPU or accelerator)
    for seed in tqdm(seeds, desc="latents", disable=not progress):
        path = pool.latents_path(seed, key)
        if path.is_file():
            continue
        frames = torch.from_numpy(pool.scene(seed)["frames"]).permute(0, 1, 4, 2, 3).float().div_(255.0)
        latents = autoencoder.encode(frames.to(device)).float().cpu().numpy()  # (C, T, c, h, w), normalised
        _save_npz(path, {"latents": latents})
    return key


def _prefill_one(pool: "ScenePool", seed: int) -> int:
    pool.build_scene(seed)
    pool.build_prepared(seed)
    return seed


def prefill_scenes(pool: "ScenePool", seeds: list[int], workers: int, progress: bool = False) -> None:
    """Generate and preprocess every scene of ``seeds`` into the cache with ``workers`` processes (each
    scene is one task; cached ones are read back, not rebuilt). Training would fill the cache lazily in
    its one DataLoader worker; on a many-core machine (an accelerator's host) this fills it first, in
    parallel. Files are written atomically, so runs sharing a cache may prefill at the same time."""
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if workers == 1:
        for seed in tqdm(seeds, desc="scenes", disable=not progress):
            _prefill_one(pool, seed)
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    context = multiprocessing.get_context("spawn")  # no forked torch/OpenCV thread state in the workers
    with ProcessPoolExecutor(max_workers=workers, mp_context=context) as executor:
        done = executor.map(functools.partial(_prefill_one, pool), seeds, chunksize=1)
        for _ in tqdm(done, total=len(seeds), desc="scenes", disable=not progress):
            pass


@functools.lru_cache(maxsize=8)
def _cached_scene(pool: ScenePool, seed: int) -> dict[str, np.ndarray]:
    return pool.build_scene(seed)


@functools.lru_cache(maxsize=8)
def _cached_prepared(pool: ScenePool, seed: int) -> dict[str, np.ndarray]:
    return pool.build_prepared(seed)


class FrameDataset(Dataset):
    """Stage 1: every frame of every camera of the pool's scenes, as (3, H, W) float32 in [0, 1]."""

    def __init__(self, pool: ScenePool, seeds: list[int]) -> None:
        self.pool, self.seeds = pool, list(seeds)
        self.per_scene = pool.cameras * pool.frames

    def __len__(self) -> int:
        return len(self.seeds) * self.per_scene

    def __getitem__(self, index: int) -> torch.Tensor:
        scene = self.pool.scene(self.seeds[index // self.per_scene])
        c, t = divmod(index % self.per_scene, self.pool.frames)
        return torch.from_numpy(scene["frames"][c, t]).permute(2, 0, 1).float().div_(255.0)


class PhotoCrops(Dataset):
    """Random square crops of the training-split photos (full resolution), resized to ``size``.

    Natural-image statistics for stage 1, so the frozen autoencoder is not fitted to rendered
    textures only (real captures look like photos). Crop ``i`` is a deterministic function of ``i``
    and ``seed``: side 1/8 .. 1 of the photo's shorter side, random position, horizontal flip, area
    resampling. Only ``split="train"`` photos are used (the test photos stay unseen).
    """

    def __init__(self, size: int, count: int, seed: int = 0) -> None:
        self.size, self.count, self.seed = size, int(count), int(seed)
        self.names = sorted(n for n, split in PHOTO_TEXTURES.items() if split == "train")

    def __len__(self) -> int:
        return self.count

    def __getitem__(self, index: int) -> torch.Tensor:
        rng = np.random.default_rng([self.seed, int(index)])
        img = photo_image(self.names[int(rng.integers(len(self.names)))])
        H, W = img.shape[:2]
        side = int(round(min(H, W) * rng.uniform(0.125, 1.0)))
        side = max(self.size // 2, min(side, H, W))
        y0, x0 = int(rng.integers(H - side + 1)), int(rng.integers(W - side + 1))
        crop = np.ascontiguousarray(img[y0:y0 + side, x0:x0 + side])
        if rng.random() < 0.5:
            crop = crop[:, ::-1]
        interp = cv2.INTER_AREA if side >= self.size else cv2.INTER_CUBIC
        out = np.clip(cv2.resize(np.ascontiguousarray(crop), (self.size, self.size), interpolation=interp), 0, 1)
        return torch.from_numpy(out.reshape(self.size, self.size, 3)).permute(2, 0, 1).float()


class MixedFrames(Dataset):
    """Stage-1 data: rendered frames plus a share ``photo_share`` of :class:`PhotoCrops`."""

    def __init__(self, frames: FrameDataset, photo_share: float, seed: int = 0) -> None:
        if not 0.0 <= photo_share < 1.0:
            raise ValueError("photo_share must be in [0, 1)")
        self.frames = frames
        n_photos = int(round(len(frames) * photo_share / (1.0 - photo_share)))
        self.photos = PhotoCrops(frames.pool.image_size, n_photos, seed)

    def __len__(self) -> int:
        return len(self.frames) + len(self.photos)

    def __getitem__(self, index: int) -> torch.Tensor:
        n = len(self.frames)
        return self.frames[index] if index < n else self.photos[index - n]


@dataclass
class PairBatch:
    """A stage-2 batch: the source clips and the target cameras' videos and trajectories."""

    source: SourceBatch
    target_frames: torch.Tensor  # (B, T, 3, H, W) in [0, 1]
    K_tgt: torch.Tensor  # (B, T, 3, 3) px
    w2c_tgt: torch.Tensor  # (B, T, 4, 4)
    target_latents: torch.Tensor | None = None  # (B, T, C, h, w) when the dataset serves cached latents


def axis_angles_deg(w2c: np.ndarray) -> np.ndarray:
    """(C, T, 4, 4) world-to-camera -> (C, C) angles in degrees between the cameras' first-frame optical
    axes: a cheap proxy for how much two views overlap (0 = same direction)."""
    z = np.asarray(w2c, dtype=np.float64)[:, 0, 2, :3]
    z = z / np.linalg.norm(z, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip(z @ z.T, -1.0, 1.0)))


SPREAD_SEARCH_MAX = 20_000  # camera sets searched by spread_cameras before it falls back to greedy


def spread_cameras(angles: np.ndarray, first: int, views: int) -> list[int]:
    """``views`` cameras spread over a rig, ``first`` among them: of the sets holding ``first``, the one whose
    closest two optical axes (``angles`` (C, C) degrees, :func:`axis_angles_deg`) are farthest apart, ties
    to the larger sum of each camera's angle to its nearest other, then the first in index order. On a
    ring of evenly spaced cameras with ``views`` dividing C this is every (C / views)-th camera. Returned
    as ``first``, then the others in index order."""
    others = [c for c in range(angles.shape[0]) if c != first]
    if math.comb(len(others), views - 1) > SPREAD_SEARCH_MAX:  # large rigs: greedy farthest point
        chosen = [first]
        while len(chosen) < views:
            nearest = angles[:, chosen].min(axis=1)
            nearest[chosen] = -1.0
            chosen.append(int(np.argmax(nearest)))
        return [first, *sorted(chosen[1:])]
    best, best_key = None, None
    for rest in itertools.combinations(others, views - 1):
        cams = [first, *rest]
        sub = angles[np.ix_(cams, cams)] + np.diag(np.full(len(cams), np.inf))
        nearest = sub.min(axis=1)
        key = (round(float(nearest.min()), 6), round(float(nearest.sum()), 6))
        if best_key is None or key > best_key:
            best, best_key = cams, key
    assert best is not None
    return best


class PairDataset(Dataset):
    """Stage 2: (source camera, target camera) pairs of one event of the pool's scenes.

    Default (``recon_share=0``, ``neighbour_sigma_deg=None``): every ordered pair with target != source.
    Sampled: one item per (scene, source camera); the target is the source itself with probability
    ``recon_share`` (a reconstruction pair), else another camera drawn with weight
    exp(-angle / ``neighbour_sigma_deg``) by optical-axis angle, so targets lean toward views that
    overlap the source. Draws use torch's RNG (seeded per DataLoader worker).

    Multi-camera items: indexed with ``(index, V)`` (see :class:`ViewsBatchSampler`) an item encodes V
    cameras of the event -- the index's camera first, then V - 1 others drawn at random, or with
    probability ``spread_share`` spread over the rig (:func:`spread_cameras`, what a user who encodes a
    subset of a rig picks) -- and its target is one of them with probability ``recon_share``, else a
    camera that was not encoded, drawn with weight exp(-angle to the nearest encoded camera /
    ``neighbour_sigma_deg``).
    """

    def __init__(self, pool: ScenePool, seeds: list[int], *, recon_share: float = 0.0,
                 neighbour_sigma_deg: float | None = None, latent_key: str | None = None,
                 spread_share: float = 0.0, reference_frame: str = "origin") -> None:
        if pool.cameras < 2:
            raise ValueError("stage 2 needs at least 2 cameras per scene")
        if not 0.0 <= recon_share <= 1.0 or (neighbour_sigma_deg is not None and not neighbour_sigma_deg > 0):
            raise ValueError("recon_share must be in [0, 1] and neighbour_sigma_deg > 0")
        if not 0.0 <= spread_share <= 1.0:
            raise ValueError("spread_share must be in [0, 1]")
        self.spread_share = float(spread_share)
        self.reference_frame = reference_frame  # the model's config.reference_frame: the frame each item is in
        self.pool, self.seeds = pool, list(seeds)
        self.recon_share, self.sigma = float(recon_share), neighbour_sigma_deg
        self.latent_key = latent_key
        self.sampled = recon_share > 0 or neighbour_sigma_deg is not None
        if self.sampled:
            self.pairs = [(a, a) for a in range(pool.cameras)]  # target drawn in __getitem__
        else:
            self.pairs = [(a, b) for a in range(pool.cameras) for b in range(pool.cameras) if a != b]

    def __len__(self) -> int:
        return len(self.seeds) * len(self.pairs)

    def _draw_target(self, src: int, w2c: np.ndarray, encoded: list[int] | None = None) -> int:
        encoded = [src] if encoded is None else encoded
        others = ~np.isin(np.arange(self.pool.cameras), encoded)
        if torch.rand(()) < self.recon_share or not others.any():
            return encoded[int(torch.randint(len(encoded), ()))]
        if self.sigma is None:
            weights = others.astype(np.float64)
        else:  # exp(-angle / sigma), shifted by the nearest camera's angle so it never underflows to all 0
            angles = axis_angles_deg(w2c)[encoded].min(axis=0)
            weights = np.zeros(self.pool.cameras)
            weights[others] = np.exp(-(angles[others] - angles[others].min()) / self.sigma)
        return int(torch.multinomial(torch.from_numpy(weights / weights.sum()), 1))

    def __getitem__(self, index: int | tuple[int, int]) -> tuple:
        """(source inputs, target frames, target K, target w2c) and, with ``latent_key``, the source's
        and the target's cached latents. Indexed ``(index, V)`` with V > 1, the source inputs and
        source latents are lists of the V encoded cameras."""
        index, views = index if isinstance(index, tuple) else (index, 1)
        seed = self.seeds[index // len(self.pairs)]
        src, tgt = self.pairs[index % len(self.pairs)]
        scene = self.pool.scene(seed)
        encoded = [src]
        if views > 1:
            if not self.sampled:
                raise ValueError("multi-camera items need a sampled dataset (recon_share or neighbour_sigma_deg)")
            if self.spread_share > 0 and float(torch.rand(())) < self.spread_share:  # no draw when off: same stream
                encoded = spread_cameras(axis_angles_deg(scene["w2c"]), src, views)
            else:
                rest = [c for c in range(self.pool.cameras) if c != src]
                pick = torch.randperm(len(rest))[:views - 1].tolist()
                encoded += [rest[i] for i in pick]
        if self.sampled:
            tgt = self._draw_target(src, scene["w2c"], encoded)
        # the frame the codec would encode these cameras in (vt4dcodec.reference): sources and target alike
        centre = model_centre(self.reference_frame, scene["w2c"][encoded])
        sources = self.pool.source_inputs(seed, encoded, centre)
        item = (sources if views > 1 else sources[0], scene["frames"][tgt], scene["K"][tgt],
                move_origin(scene["w2c"][tgt], centre))
        if self.latent_key is None:
            return item
        latents = self.pool.latents(seed, self.latent_key)
        return item + ([latents[c] for c in encoded] if views > 1 else latents[src], latents[tgt])


class ViewsBatchSampler(Sampler):
    """Shuffled batches of :class:`PairDataset` indices whose items share their number of encoded cameras:
    a batch is single-camera (V = 1), or with probability ``multi_share`` multi-camera with V drawn
    uniformly from ``multi_views``. Yields lists of ``(index, V)``; every index once per pass."""

    def __init__(self, size: int, batch_size: int, generator: torch.Generator, *, multi_share: float,
                 multi_views: tuple[int, ...]) -> None:
        if not 0.0 <= multi_share <= 1.0 or any(v < 2 for v in multi_views) or (multi_share > 0 and not multi_views):
            raise ValueError("multi_share must be in [0, 1] and multi_views numbers >= 2")
        self.size, self.batch_size = size, batch_size
        self.multi_share, self.multi_views, self.generator = multi_share, tuple(multi_views), generator

    def __len__(self) -> int:
        return self.size // self.batch_size

    def __iter__(self):
        order = torch.randperm(self.size, generator=self.generator).tolist()
        for b in range(len(self)):
            views = 1
            if float(torch.rand((), generator=self.generator)) < self.multi_share:
                views = self.multi_views[int(torch.randint(len(self.multi_views), (), generator=self.generator))]
            yield [(i, views) for i in order[b * self.batch_size:(b + 1) * self.batch_size]]


def collate_pairs(items: list[tuple]) -> PairBatch:
    """Stack PairDataset items (all single-camera, or all with the same number of encoded cameras)."""
    def flat(value: Any) -> list:
        return value if isinstance(value, list) else [value]

    views = len(flat(items[0][0]))
    if any(len(flat(it[0])) != views for it in items):
        raise ValueError("a batch mixes items with different numbers of encoded cameras")
    target = torch.from_numpy(np.stack([it[1] for it in items])).permute(0, 1, 4, 2, 3).float().div_(255.0)
    source = SourceBatch.collate([s for it in items for s in flat(it[0])], views=views)
    target_latents = None
    if len(items[0]) > 4:
        source.latents = torch.from_numpy(np.stack([x for it in items for x in flat(it[4])])).float()
        target_latents = torch.from_numpy(np.stack([it[5] for it in items])).float()
    return PairBatch(source=source, target_frames=target,
                     K_tgt=torch.from_numpy(np.stack([it[2] for it in items])).float(),
                     w2c_tgt=torch.from_numpy(np.stack([it[3] for it in items])).float(),
                     target_latents=target_latents)
