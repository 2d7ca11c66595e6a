"""MultiViewPairs: pairing, determinism, disk vs generated scenes, collation, bad input."""

from __future__ import annotations

import pytest
import torch
from torch.utils.data import DataLoader

from vt4dcodec.errors import Vt4dError
from vt4dcodec.data.multiview import MultiViewPairs, camera_pairs
from vt4dcodec.synth import SynthConfig, generate_scene, write_dataset

CFG = SynthConfig(num_cameras=3, num_frames=4, height=24, width=24)


@pytest.fixture(scope="module")
def disk_scenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("mv")
    write_dataset(root, num_scenes=2, split="train", seed=10, config=CFG, workers=1)
    return root


@pytest.mark.parametrize("pairing, per_scene", [("different", 6), ("same", 3), ("all", 9)])
def test_pair_counts(pairing, per_scene):
    ds = MultiViewPairs(range(2), pairing=pairing, config=CFG)
    assert len(ds) == 2 * per_scene
    pairs = [ds.locate(i)[1:] for i in range(per_scene)]
    assert len(set(pairs)) == per_scene
    if pairing == "different":
        assert all(s != t for s, t in pairs)
    if pairing == "same":
        assert all(s == t for s, t in pairs)


def test_fixed_cameras():
    names = ["a", "b", "c"]
    assert camera_pairs(names, "different", source_camera="b") == [(1, 0), (1, 2)]
    assert camera_pairs(names, "all", source_camera=0, target_camera="c") == [(0, 2)]
    assert camera_pairs(names, "same", source_camera="a", target_camera="b") == []
    ds = MultiViewPairs([4], pairing="different", source_camera="cam02", config=CFG)
    assert [ds.locate(i)[1:] for i in range(len(ds))] == [("cam02", "cam00"), ("cam02", "cam01")]


def test_items_are_the_generated_scene_and_deterministic():
    ds = MultiViewPairs([7, 8], pairing="different", config=CFG)
    item = ds[3]                                # scene 7, source cam01, target cam02
    assert (item["scene_id"], item["source_camera"], item["target_camera"]) == ("synth-train-000007", "cam01", "cam02")
    sc = generate_scene(7, config=CFG)
    T, H, W = 4, 24, 24
    assert item["source_frames"].shape == (T, 3, H, W) and item["source_frames"].dtype == torch.float32
    assert 0.0 <= item["source_frames"].min() and item["source_frames"].max() <= 1.0
    assert torch.equal(item["source_frames"], torch.from_numpy(sc.capture.frames["cam01"]).permute(0, 3, 1, 2) / 255.0)
    assert torch.equal(item["target_frames"], torch.from_numpy(sc.capture.frames["cam02"]).permute(0, 3, 1, 2) / 255.0)
    assert torch.allclose(item["source_K"], torch.from_numpy(sc.capture.cameras["cam01"].K).float())
    assert torch.allclose(item["target_w2c"], torch.from_numpy(sc.capture.cameras["cam02"].w2c).float())
    assert torch.equal(item["source_depth"], torch.from_numpy(sc.capture.depth["cam01"]))
    assert torch.equal(item["source_dynamic_mask"], torch.from_numpy(sc.dynamic_mask["cam01"]))
    again = MultiViewPairs([7, 8], pairing="different", config=CFG)[3]
    for key, value in item.items():
        assert torch.equal(value, again[key]) if torch.is_tensor(value) else value == again[key]
    assert ds[-1]["scene_id"] == "synth-train-000008"


def test_disk_scenes_match_generated(disk_scenes):
    disk = MultiViewPairs(disk_scenes, pairing="all")
    gen = MultiViewPairs([10, 11], pairing="all", config=CFG)
    assert len(disk) == len(gen) == 18
    for i in (0, 5, 13):
        a, b = disk[i], gen[i]
        assert a["scene_id"] == b["scene_id"]
        assert torch.equal(a["source_frames"], b["source_frames"])
        assert torch.equal(a["target_frames"], b["target_frames"])
        assert torch.allclose(a["source_w2c"], b["source_w2c"], atol=1e-6)
        assert torch.allclose(a["source_depth"], b["source_depth"], atol=6e-4)   # 1 mm PNG depth
        assert torch.equal(a["source_dynamic_mask"], b["source_dynamic_mask"])
    paths = sorted(p for p in disk_scenes.iterdir())
    assert len(MultiViewPairs([paths[1]], pairing="same")) == 3
    assert len(MultiViewPairs(paths[0], pairing="same")) == 3          # one capture directory


def test_dataloader_collates(disk_scenes):
    loader = DataLoader(MultiViewPairs(disk_scenes), batch_size=4, shuffle=False)
    batch = next(iter(loader))
    assert batch["source_frames"].shape == (4, 4, 3, 24, 24)
    assert batch["target_K"].shape == (4, 4, 3, 3)
    assert len(batch["scene_id"]) == 4


@pytest.mark.parametrize("scenes, kwargs", [
    ([], {}), ([-1], {}), ([1, "x"], {}), (range(1), {"pairing": "cross"}),
    (range(1), {"source_camera": "cam99"}), (range(1), {"target_camera": 7}), (3.5, {}),
])
def test_bad_arguments(scenes, kwargs):
    with pytest.raises(Vt4dError):
        MultiViewPairs(scenes, config=CFG, **kwargs)


def test_bad_directory_and_index(tmp_path):
    with pytest.raises(Vt4dError):
        MultiViewPairs(tmp_path)
    for text in ("not json", '{"cameras": []}', '{"cameras": [{"nom": 1}]}', "[1, 2]"):
        (tmp_path / "broken").mkdir(exist_ok=True)
        (tmp_path / "broken" / "capture.json").write_text(text)
        with pytest.raises(Vt4dError):
            MultiViewPairs(tmp_path)
    (tmp_path / "broken" / "capture.json").unlink()
    with pytest.raises(Vt4dError):
        MultiViewPairs([tmp_path])
    ds = MultiViewPairs(range(1), pairing="same", config=CFG)
    with pytest.raises(IndexError):
        ds[3]
    with pytest.raises(TypeError):
        ds["0"]


def test_dataloader_worker_processes_give_the_same_items():
    ds = MultiViewPairs([3], pairing="same", config=CFG)
    serial = [ds[i] for i in range(len(ds))]
    loader = DataLoader(ds, batch_size=None, num_workers=1)
    for a, b in zip(serial, loader):
        assert torch.equal(a["source_frames"], b["source_frames"]) and a["target_camera"] == b["target_camera"]
