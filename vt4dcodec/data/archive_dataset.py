"""Torch datasets over archive shards: one dataset from a directory, glob or list of ``.vt4da`` files.

* :class:`ArchiveDataset` - map-style; index ``i`` is the i-th (shard, key) pair in shard order then
  key order.  Works with any sampler (``DistributedSampler`` for ranks).
* :class:`ArchiveIterableDataset` - streams the scenes, shuffled deterministically by
  ``(seed, epoch)`` (call :meth:`~ArchiveIterableDataset.set_epoch`), split first across
  ``torch.distributed`` ranks and then across DataLoader workers, so every scene is seen exactly
  once per epoch over all ranks and workers.

Both list the shards' keys once in the constructing process (reading only each shard's footer and
index) and open their own read handles lazily in each worker process: no file handle is ever
shared across ``fork``.  A sample is a dict::

    key              str, the scene key
    shard            str, the shard path or URL
    static_tokens    (N_s, d) tensor: float32 (dequantize=True) or the stored codes (uint8/float16)
    dynamic_tokens   (N_d, d) tensor, likewise
    K                (T, 3, 3) float32 intrinsics in pixels
    w2c              (T, 4, 4) float32 world-to-camera poses in metres
    metadata         dict: the scene's user metadata, encoding, frames, width, height,
                     fingerprint (dict), source_capture_id
"""

from __future__ import annotations

import glob
import os
from typing import Any, Iterator, Sequence

import numpy as np
import torch
from torch.utils.data import Dataset, IterableDataset, get_worker_info

from ..archive import ARCHIVE_EXTENSION, ArchiveReader, open_archive
from ..archive.source import is_url
from ..errors import ArchiveError

__all__ = ["ArchiveDataset", "ArchiveIterableDataset", "resolve_shards", "scene_sample"]


def resolve_shards(shards: Any, **storage_options: Any) -> list[str]:
    """Shard paths/URLs, sorted: a directory (its ``*.vt4da``), a glob, a path/URL, or a list of those."""
    if isinstance(shards, (list, tuple)):
        out: list[str] = []
        for s in shards:
            out.extend(resolve_shards(s, **storage_options))
        return out
    s = os.fspath(shards)
    if is_url(s):
        if glob.has_magic(s):
            import fsspec

            fs, _ = fsspec.core.url_to_fs(s, **storage_options)
            protocol = s.split("://", 1)[0]
            return sorted(p if "://" in p else f"{protocol}://{p.lstrip('/')}" for p in fs.glob(s))
        return [s]
    if os.path.isdir(s):
        found = sorted(glob.glob(os.path.join(s, "*" + ARCHIVE_EXTENSION)))
    elif glob.has_magic(s):
        found = sorted(glob.glob(s))
    else:
        found = [s]
    if not found:
        raise ArchiveError(f"no archive shards found at {s!r}")
    return found


def scene_sample(reader: ArchiveReader, key: str, *, dequantize: bool = True) -> dict[str, Any]:
    """Decode one scene of ``reader`` into the sample dict described in the module docstring."""
    f = reader.open_scene(key)
    cams = f.cameras
    static, dynamic = f.tokens(dequantize=dequantize)  # int<b>-rans: both sections in one decoding pass
    static, dynamic = np.array(static), np.array(dynamic)  # own, writable memory for torch
    prov = f.provenance
    return {
        "key": key,
        "shard": reader.name,
        "static_tokens": torch.from_numpy(static),
        "dynamic_tokens": torch.from_numpy(dynamic),
        "K": torch.from_numpy(np.asarray(cams.K, dtype=np.float32)),
        "w2c": torch.from_numpy(np.asarray(cams.w2c, dtype=np.float32)),
        "metadata": {
            "user": dict(f.metadata), "encoding": f.encoding, "frames": int(f.num_frames),
            "width": int(cams.width), "height": int(cams.height), "fingerprint": f.fingerprint.to_dict(),
            "source_capture_id": None if prov is None else prov.source_capture_id,
        },
    }


class _Shards:
    """Shard list + keys, and per-process lazily opened readers (never shared across fork)."""

    def __init__(self, shards: Any, storage_options: dict | None):
        self.storage_options = dict(storage_options or {})
        self.paths = resolve_shards(shards, **self.storage_options)
        self.items: list[tuple[int, str]] = []
        for i, path in enumerate(self.paths):
            with open_archive(path, **self.storage_options) as reader:
                self.items.extend((i, k) for k in reader.keys())
        self._readers: dict[int, ArchiveReader] = {}
        self._pid = os.getpid()

    def reader(self, shard: int) -> ArchiveReader:
        if self._pid != os.getpid():  # forked: drop the parent's handles without closing them
            self._readers, self._pid = {}, os.getpid()
        r = self._readers.get(shard)
        if r is None:
            r = self._readers[shard] = open_archive(self.paths[shard], **self.storage_options)
        return r

    def sample(self, i: int, dequantize: bool) -> dict[str, Any]:
        shard, key = self.items[i]
        return scene_sample(self.reader(shard), key, dequantize=dequantize)

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_readers"], state["_pid"] = {}, -1
        return state


class ArchiveDataset(Dataset):
    """Map-style dataset over archive shards (see the module docstring)."""

    def __init__(self, shards: Any, *, dequantize: bool = True, storage_options: dict | None = None):
        self._shards = _Shards(shards, storage_options)
        self.dequantize = dequantize

    @property
    def shards(self) -> list[str]:
        return list(self._shards.paths)

    @property
    def keys(self) -> list[tuple[str, str]]:
        """(shard, key) of every index, in dataset order."""
        return [(self._shards.paths[s], k) for s, k in self._shards.items]

    def __len__(self) -> int:
        return len(self._shards.items)

    def __getitem__(self, i: int) -> dict[str, Any]:
        if not -len(self) <= i < len(self):
            raise IndexError(f"index {i} out of range for {len(self)} scenes")
        return self._shards.sample(i % len(self), self.dequantize)


def _dist_rank_world() -> tuple[int, int]:
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return 0, 1


class ArchiveIterableDataset(IterableDataset):
    """Iterable dataset: deterministic (seed, epoch) shuffle, split across ranks then workers.

    ``rank``/``world_size`` default to ``torch.distributed``'s (0/1 when it is not initialised).
    Rank r takes positions r, r+W, r+2W... of the epoch's order; each DataLoader worker of that rank
    takes every num_workers-th of those.
    """

    def __init__(self, shards: Any, *, shuffle: bool = True, seed: int = 0, dequantize: bool = True,
                 rank: int | None = None, world_size: int | None = None, storage_options: dict | None = None):
        self._shards = _Shards(shards, storage_options)
        self.shuffle, self.seed, self.dequantize = shuffle, int(seed), dequantize
        self.epoch = 0
        if (rank is None) != (world_size is None):
            raise ArchiveError("pass both rank and world_size, or neither")
        if world_size is not None and not 0 <= rank < world_size:
            raise ArchiveError(f"rank {rank} outside 0..{world_size - 1}")
        self.rank, self.world_size = rank, world_size

    def set_epoch(self, epoch: int) -> None:
        """Select the shuffle of ``epoch`` (same seed and epoch -> same order on every rank)."""
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self._shards.items)

    def epoch_order(self) -> np.ndarray:
        """Dataset positions of this epoch, before the rank/worker split."""
        n = len(self._shards.items)
        if not self.shuffle:
            return np.arange(n)
        return np.random.default_rng([self.seed, self.epoch]).permutation(n)

    def positions(self) -> Sequence[int]:
        """The positions this rank and worker yield this epoch."""
        rank, world = (self.rank, self.world_size) if self.world_size is not None else _dist_rank_world()
        order = self.epoch_order()[rank::world]
        info = get_worker_info()
        if info is not None:
            order = order[info.id::info.num_workers]
        return order.tolist()

    def __iter__(self) -> Iterator[dict[str, Any]]:
        for i in self.positions():
            yield self._shards.sample(i, self.dequantize)
