"""Torch datasets over shards: exact once-per-epoch coverage across ranks x workers, determinism."""

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from vt4dcodec.archive import ArchiveWriter
from vt4dcodec.data.archive_dataset import ArchiveDataset, ArchiveIterableDataset, resolve_shards
from vt4dcodec.format import loads

from .helpers import scene_record

SHARDS, PER_SHARD = 3, 5


@pytest.fixture(scope="module")
def shard_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("shards")
    for s in range(SHARDS):
        with ArchiveWriter(d / f"part-{s:02d}.vt4da", durable=False) as w:
            for i in range(PER_SHARD):
                w.append(f"s{s}-scene{i}", scene_record(s * PER_SHARD + i))
    (d / "ignored.txt").write_text("not a shard")
    return d


def _keys(loader):
    return [sample["key"] for sample in loader]


def test_resolve_shards_dir_glob_list(shard_dir):
    by_dir = resolve_shards(shard_dir)
    assert len(by_dir) == SHARDS and by_dir == sorted(by_dir)
    assert resolve_shards(str(shard_dir / "part-0*.vt4da")) == by_dir
    assert resolve_shards([by_dir[0], by_dir[1]]) == by_dir[:2]


def test_map_style_sample_contents(shard_dir):
    ds = ArchiveDataset(shard_dir)
    assert len(ds) == SHARDS * PER_SHARD
    sample = ds[7]
    ref = loads(scene_record(7))
    assert sample["key"] == "s1-scene2"
    assert sample["static_tokens"].dtype == torch.float32 and tuple(sample["static_tokens"].shape) == (16, 8)
    np.testing.assert_array_equal(sample["static_tokens"].numpy(), ref.static_tokens)
    np.testing.assert_array_equal(sample["dynamic_tokens"].numpy(), ref.dynamic_tokens)
    assert tuple(sample["K"].shape) == (2, 3, 3) and tuple(sample["w2c"].shape) == (2, 4, 4)
    assert sample["metadata"]["user"] == {"seed": 7} and sample["metadata"]["frames"] == 2
    raw = ArchiveDataset(shard_dir, dequantize=False)[7]
    assert raw["static_tokens"].dtype == torch.uint8  # the stored int8 codes
    with pytest.raises(IndexError):
        ds[len(ds)]


def test_map_style_with_workers(shard_dir):
    ds = ArchiveDataset(shard_dir)
    loader = DataLoader(ds, batch_size=None, num_workers=2)
    assert sorted(_keys(loader)) == sorted(k for _, k in ds.keys)


def test_two_workers_two_ranks_see_every_scene_once_per_epoch(shard_dir):
    all_keys = sorted(k for _, k in ArchiveDataset(shard_dir).keys)
    orders = []
    for epoch in (0, 1):
        seen = []
        for rank in (0, 1):
            ds = ArchiveIterableDataset(shard_dir, shuffle=True, seed=3, rank=rank, world_size=2)
            ds.set_epoch(epoch)
            got = _keys(DataLoader(ds, batch_size=None, num_workers=2))
            seen.extend(got)
        assert sorted(seen) == all_keys  # each scene exactly once over 2 ranks x 2 workers
        full = ArchiveIterableDataset(shard_dir, seed=3, rank=0, world_size=1)
        full.set_epoch(epoch)
        orders.append(full.epoch_order().tolist())
    assert orders[0] != orders[1]  # a new shuffle each epoch...
    again = ArchiveIterableDataset(shard_dir, seed=3, rank=0, world_size=1)
    assert again.epoch_order().tolist() == orders[0]  # ...deterministic by (seed, epoch)
