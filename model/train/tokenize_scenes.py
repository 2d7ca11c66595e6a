"""Tokenize multi-camera synthetic scenes once with the frozen tokenizer, into archive shards for the
Co4DGen prior.

    python -m vt4dcodec.model.train.tokenize_scenes --tokenizer vt4d-tiny --out data/co4dgen \
        --split train --scenes 512 --cameras 4 --per-shard 128

Layout of ``--out`` (one pair of files per shard):

* ``<split>-NNNNN.vt4da``: an ordinary scene archive.  Record ``<split>-<seed:06d>/cam<a>`` is the
  ``.vt4d`` scene of camera a of that event: its tokens are the anchor state Z^a = E(V_a, P_a), its
  cameras P_a, its fingerprint the tokenizer's, and its metadata ``{"co4dgen": {"event", "camera",
  "num_cameras", "split", "seed"}}``.  Any tool of the storage library reads it.
* ``<split>-NNNNN.clips``: the sidecar with the conditioning material, written with the same archive
  machinery (so it gets the same commit/crash safety and index) but holding raw records: key
  ``<split>-<seed:06d>/cam<c>`` -> an ``.npz`` (no pickle) of ``frames`` (T, H, W, 3) uint8, ``K``
  (T, 3, 3) and ``w2c`` (T, 4, 4) float32 -- the camera's video V_c and cameras P_c.  Video does not
  belong in a token container (its metadata is bounded), so it lives beside it; a training pair is
  (token record of a, clip record of c != a of the same event).

Scenes and their preprocessing come from :class:`model.train.data.ScenePool` (the stage-2 cache is
reused when settings match).  Ranks of ``torchrun`` write disjoint shards.
"""

from __future__ import annotations

import argparse
import io
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vt4dcodec.archive import ArchiveWriter, open_archive
from vt4dcodec.cameras import Trajectory
from vt4dcodec.errors import ArchiveError, ModelError
from vt4dcodec.format import Provenance, Scene
from vt4dcodec.reference import model_centre

from ..inputs.source_inputs import SourceBatch
from ..weights_io import from_pretrained
from .data import ScenePool, rank_seeds

__all__ = ["CLIP_EXTENSION", "clip_path", "pack_clip", "unpack_clip", "ClipStore", "event_key", "record_key",
           "tokenize_event", "write_shards", "main", "MAX_CLIP_BYTES"]

CLIP_EXTENSION = ".clips"
MAX_CLIP_BYTES = 64 << 20  # a clip record larger than this is refused before it is parsed


def clip_path(shard: str | Path) -> str:
    """The sidecar of a token shard: ``x/train-00000.vt4da`` -> ``x/train-00000.clips``."""
    s = str(shard)
    return (s[: -len(".vt4da")] if s.endswith(".vt4da") else s) + CLIP_EXTENSION


def event_key(split: str, seed: int) -> str:
    return f"{split}-{seed:06d}"


def record_key(event: str, camera: int) -> str:
    return f"{event}/cam{camera}"


def pack_clip(frames: np.ndarray, K: np.ndarray, w2c: np.ndarray) -> bytes:
    """One camera's clip as compressed ``.npz`` bytes (frames uint8 (T,H,W,3), K (T,3,3), w2c (T,4,4))."""
    buf = io.BytesIO()
    np.savez_compressed(buf, frames=np.ascontiguousarray(frames, dtype=np.uint8),
                        K=np.asarray(K, dtype=np.float32), w2c=np.asarray(w2c, dtype=np.float32))
    return buf.getvalue()


def unpack_clip(data: bytes) -> dict[str, np.ndarray]:
    """Inverse of :func:`pack_clip`, validated (no pickle; shapes and dtypes checked)."""
    if len(data) > MAX_CLIP_BYTES:
        raise ArchiveError(f"clip record of {len(data)} bytes exceeds {MAX_CLIP_BYTES}")
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            if set(npz.files) != {"frames", "K", "w2c"}:
                raise ArchiveError(f"clip record holds {sorted(npz.files)}, expected frames, K, w2c")
            out = {k: npz[k] for k in npz.files}
    except (ValueError, OSError, EOFError) as exc:
        raise ArchiveError(f"clip record is not a valid npz: {exc}") from None
    f = out["frames"]
    if f.dtype != np.uint8 or f.ndim != 4 or f.shape[-1] != 3 or f.shape[0] < 1 \
            or out["K"].shape != (f.shape[0], 3, 3) or out["w2c"].shape != (f.shape[0], 4, 4):
        raise ArchiveError("clip record must hold frames (T,H,W,3) uint8, K (T,3,3), w2c (T,4,4)")
    if not (np.isfinite(out["K"]).all() and np.isfinite(out["w2c"]).all()):
        raise ArchiveError("clip record cameras hold non-finite values")
    return out


class ClipStore:
    """Read access to the sidecars of a list of token shards (opened lazily, per process)."""

    def __init__(self, shards: list[str]) -> None:
        self.paths = [clip_path(s) for s in shards]
        self.keys: dict[str, int] = {}
        for i, path in enumerate(self.paths):
            with open_archive(path) as reader:
                for key in reader.keys():
                    self.keys[key] = i
        self._readers: dict[int, Any] = {}
        self._pid = -1

    def __contains__(self, key: str) -> bool:
        return key in self.keys

    def load(self, key: str) -> dict[str, np.ndarray]:
        if key not in self.keys:
            raise ArchiveError(f"no conditioning clip {key!r} in {self.paths}")
        if self._pid != os.getpid():
            self._readers, self._pid = {}, os.getpid()
        i = self.keys[key]
        if i not in self._readers:
            self._readers[i] = open_archive(self.paths[i])
        return unpack_clip(self._readers[i].read_bytes(key))

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_readers": {}, "_pid": -1}


@torch.no_grad()
def tokenize_event(tokenizer: Any, pool: ScenePool, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(Z_s, Z_d) of every camera of one event, encoded as one batch by the frozen tokenizer, each camera in the
    world frame the codec would encode it in (vt4dcodec.reference.model_centre)."""
    w2c = pool.scene(seed)["w2c"]
    clips = [clip for c in range(pool.cameras)
             for clip in pool.source_inputs(seed, [c], model_centre(tokenizer.config.reference_frame, w2c[[c]]))]
    z_s, z_d = tokenizer.encode(SourceBatch.collate(clips))
    return [(z_s[c].numpy().astype(np.float32), z_d[c].numpy().astype(np.float32)) for c in range(pool.cameras)]


def write_shards(tokenizer: Any, pool: ScenePool, seeds: list[int], out: Path, *, per_shard: int,
                 encoding: str = "float16", shard_offset: int = 0, progress: bool = False) -> list[str]:
    """Tokenize ``seeds`` of ``pool`` into shards ``<out>/<split>-NNNNN.vt4da`` + sidecars; returns the
    token shard paths.  Shard numbers start at ``shard_offset`` (distinct per rank)."""
    if per_shard < 1:
        raise ModelError("per_shard must be >= 1")
    out.mkdir(parents=True, exist_ok=True)
    fingerprint = tokenizer.stored_fingerprint()
    size = pool.image_size
    paths = []
    for n, start in enumerate(range(0, len(seeds), per_shard)):
        path = out / f"{pool.split}-{shard_offset + n:05d}.vt4da"
        with ArchiveWriter(path, "w") as tokens, ArchiveWriter(clip_path(path), "w") as clips:
            for seed in seeds[start:start + per_shard]:
                event = event_key(pool.split, seed)
                scene = pool.scene(seed)
                for cam, (z_s, z_d) in enumerate(tokenize_event(tokenizer, pool, seed)):
                    traj = Trajectory(K=scene["K"][cam], w2c=scene["w2c"][cam], width=size, height=size)
                    meta = {"co4dgen": {"event": event, "camera": cam, "num_cameras": pool.cameras,
                                        "split": pool.split, "seed": int(seed)}}
                    record = Scene(static_tokens=z_s, dynamic_tokens=z_d, cameras=traj, fingerprint=fingerprint,
                                   metadata=meta, provenance=Provenance.now(event, "encoded"), encoding=encoding)
                    tokens.append(record_key(event, cam), record)
                    clips.append(record_key(event, cam), pack_clip(scene["frames"][cam], scene["K"][cam],
                                                                   scene["w2c"][cam]),
                                 validate=False, summary={"frames": int(scene["frames"].shape[1])})
                if progress:
                    print(f"  {event}: {pool.cameras} cameras", file=sys.stderr)
        paths.append(str(path))
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m vt4dcodec.model.train.tokenize_scenes", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tokenizer", required=True, help="shipped tokenizer id or model directory")
    parser.add_argument("--out", type=Path, required=True, help="directory for the shards")
    parser.add_argument("--split", choices=("train", "test"), default="train")
    parser.add_argument("--scenes", type=int, default=64)
    parser.add_argument("--scene-seed", type=int, default=0, help="first scene seed")
    parser.add_argument("--cameras", type=int, default=4)
    parser.add_argument("--per-shard", type=int, default=128, help="events per shard")
    parser.add_argument("--encoding", default="float16", help="token encoding of the records")
    parser.add_argument("--cache", type=Path, default=Path("runs/scene_cache"), help="ScenePool cache")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    rank, world = int(os.environ.get("RANK", "0")), int(os.environ.get("WORLD_SIZE", "1"))
    if args.cameras < 2:
        raise ModelError("Co4DGen pairs need at least 2 cameras per event")
    tokenizer = from_pretrained(args.tokenizer)
    pool = ScenePool.for_config(tokenizer.config, args.cache, args.cameras)
    if args.split != pool.split:
        pool = ScenePool(pool.cache, pool.cameras, pool.frames, pool.image_size, pool.latent_size, pool.n_tracks,
                         pool.motion_isolation, split=args.split)
    seeds = rank_seeds(args.scene_seed, args.scenes, rank, world)
    shards_before = rank * (-(-args.scenes // world) // args.per_shard + 1)
    t0 = time.perf_counter()
    paths = write_shards(tokenizer, pool, seeds, args.out, per_shard=args.per_shard, encoding=args.encoding,
                         shard_offset=shards_before, progress=not args.quiet)
    print(f"tokenized {len(seeds)} events x {args.cameras} cameras into {len(paths)} shard(s) in "
          f"{time.perf_counter() - t0:.1f} s: {', '.join(paths)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
