"""Scenes on disk: capture directories + ground truth round-trip; `vt4d synth`; resume; bad input."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from vt4dcodec.capture.io import read_capture
from vt4dcodec.cli import main
from vt4dcodec.synth import SynthConfig, SynthError, read_ground_truth, write_dataset
from vt4dcodec.synth.dataset_writer import FLOW_NAME, GT_NAME

from .helpers import SMALL, scene

TINY = SynthConfig(num_cameras=2, num_frames=3, height=24, width=24)


@settings(max_examples=3)
@given(seed=st.integers(0, 10**6), split=st.sampled_from(["train", "test"]))
def test_write_dataset_round_trips(seed, split):
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_dataset(tmp, num_scenes=2, split=split, seed=seed, config=SMALL, workers=1)
        assert [p.name for p in paths] == [f"{split}-{seed:06d}", f"{split}-{seed + 1:06d}"]
        for i, path in enumerate(paths):
            _check_round_trip(scene(seed + i, split), path)


def _check_round_trip(sc, path: Path) -> None:
    """The capture directory and ground truth on disk equal the in-memory scene."""
    cap = read_capture(path)
    gt = read_ground_truth(path)
    assert cap.capture_id == sc.capture.capture_id and cap.fps == sc.capture.fps
    assert cap.metadata["seed"] == sc.seed and cap.metadata["textures"] == sc.textures
    for name in sc.capture.camera_names:
        assert np.array_equal(cap.frames[name], sc.capture.frames[name])
        assert np.abs(cap.depth[name] - sc.capture.depth[name]).max() <= 0.0005 + 2e-5   # 1 mm PNG, float32 metres
        assert cap.cameras[name].equals(sc.capture.cameras[name], atol=1e-12)
        # float16 flow: relative error 2^-11
        assert np.allclose(gt["flow"][name], sc.flow[name], rtol=2**-10, atol=1e-3)
        assert np.array_equal(gt["flow_valid"][name], sc.flow_valid[name])
        assert np.array_equal(gt["object_ids"][name], sc.object_ids[name])
        assert np.array_equal(gt["dynamic_mask"][name], sc.dynamic_mask[name])


def test_parallel_workers_match_serial_and_resume_skips(tmp_path):
    a = write_dataset(tmp_path / "a", num_scenes=3, split="train", config=TINY, workers=1)
    b = write_dataset(tmp_path / "b", num_scenes=3, split="train", config=TINY, workers=2)
    for pa, pb in zip(a, b):
        assert (pa / FLOW_NAME).read_bytes() == (pb / FLOW_NAME).read_bytes()
        assert (pa / "cam01" / "rgb" / "000002.png").read_bytes() == (pb / "cam01" / "rgb" / "000002.png").read_bytes()
    stamp = (a[0] / "capture.json").stat().st_mtime_ns
    again = write_dataset(tmp_path / "a", num_scenes=3, split="train", config=TINY, workers=1)
    assert again == a and (a[0] / "capture.json").stat().st_mtime_ns == stamp


def test_cli_synth(tmp_path, capsys):
    rc = main(["synth", "-n", "2", "--split", "test", "-o", str(tmp_path), "--seed", "7", "--workers", "1",
               "--cameras", "2", "--frames", "3", "--size", "24"])
    assert rc == 0
    assert "2 test scenes" in capsys.readouterr().out  # -q would print nothing (tests/cli/test_output_options.py)
    cap = read_capture(tmp_path / "test-000008")
    assert cap.camera_names == ["cam00", "cam01"] and cap.num_frames == 3
    assert cap.frames["cam00"].shape == (3, 24, 24, 3)
    assert cap.metadata["split"] == "test"


def test_cli_synth_room_style_round_trips(tmp_path):
    assert main(["synth", "-n", "1", "--style", "room", "-o", str(tmp_path), "--seed", "3", "--workers", "1",
                 "--cameras", "2", "--frames", "3", "--size", "24", "-q"]) == 0
    cap = read_capture(tmp_path / "train-000003")
    assert cap.metadata["config"]["style"] == "room"
    room = scene(3, "train", SynthConfig(num_cameras=2, num_frames=3, height=24, width=24, style="room"))
    assert np.array_equal(cap.frames["cam01"], room.capture.frames["cam01"])
    gt = read_ground_truth(tmp_path / "train-000003")
    assert any(np.asarray(m).any() for m in gt["dynamic_mask"].values())
    with pytest.raises(SystemExit):
        main(["synth", "-n", "1", "--style", "studio", "-o", str(tmp_path)])


def test_cli_synth_bad_usage(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["synth", "-n", "0", "-o", str(tmp_path)])
    assert exc.value.code == 2
    with pytest.raises(SystemExit):
        main(["synth", "-n", "1", "--split", "val", "-o", str(tmp_path)])
    assert main(["synth", "-n", "1", "-o", str(tmp_path), "--min-objects", "3", "--max-objects", "1", "-q"]) == 1


@pytest.mark.parametrize("kwargs", [
    {"num_scenes": -1, "split": "train"}, {"num_scenes": 1, "split": "dev"},
    {"num_scenes": 1, "split": "train", "workers": 0}, {"num_scenes": 1, "split": "train", "seed": -3},
])
def test_write_dataset_rejects_bad_arguments(tmp_path, kwargs):
    with pytest.raises(SynthError):
        write_dataset(tmp_path, **kwargs)


def test_read_ground_truth_errors(tmp_path):
    with pytest.raises(SynthError):
        read_ground_truth(tmp_path)
    path = write_dataset(tmp_path, num_scenes=1, split="train", config=TINY, workers=1)[0]
    (path / GT_NAME).write_bytes(b"not a zip")
    with pytest.raises(SynthError):
        read_ground_truth(path)
    np.save(path / FLOW_NAME, np.zeros((5, 2)))
    path2 = write_dataset(tmp_path / "x", num_scenes=1, split="train", config=TINY, workers=1)[0]
    np.save(path2 / FLOW_NAME, np.zeros((5, 2)))
    with pytest.raises(SynthError):
        read_ground_truth(path2)
