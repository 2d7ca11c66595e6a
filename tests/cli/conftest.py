"""Fixtures of the command-line tests (helpers in cli_helpers.py): a torch-free scene file, a small random
model directory, a capture directory and a scene encoded from it by `vt4d encode`, and small captures for tests that stand in
for the codec (cli_helpers.StandInCodec)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from cli_helpers import make_scene, save_small_model, vt4d
from vt4dcodec import save


@pytest.fixture()
def scene_file(tmp_path) -> Path:
    """A small valid .vt4d file (no model needed to read it)."""
    path = tmp_path / "s.vt4d"
    save(make_scene(kind="encoded", capture="cap-1"), path)
    return path


@pytest.fixture(scope="session")
def small_model(tmp_path_factory) -> Path:
    return save_small_model(tmp_path_factory.mktemp("models"))


@pytest.fixture(scope="session")
def capture_dir(tmp_path_factory) -> Path:
    """A held-out synthetic capture (3 cameras, 8 frames of 64x64) as a capture directory."""
    from vt4dcodec.capture.io import write_capture
    from vt4dcodec.synth import SynthConfig, generate_scene

    path = tmp_path_factory.mktemp("captures") / "cap"
    write_capture(generate_scene(7, split="test", config=SynthConfig(num_cameras=3)).capture, path)
    return path


@pytest.fixture(scope="session")
def encoded_file(tmp_path_factory, small_model, capture_dir) -> Path:
    """capture_dir encoded by small_model through `vt4d encode`."""
    out = tmp_path_factory.mktemp("encoded") / "scene.vt4d"
    r = vt4d("encode", capture_dir, "--model", small_model, "-o", out, "-q")
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture(scope="session")
def small_captures(tmp_path_factory):
    """A folder of three small captures (one camera, 8 frames of 16x16), ids cap-a, cap-b and cap-c."""
    from vt4dcodec.capture.io import write_capture
    from vt4dcodec.synth import SynthConfig, generate_scene

    root = tmp_path_factory.mktemp("captures")
    write_capture(generate_scene(3, split="test", config=SynthConfig(num_cameras=1, height=16, width=16)).capture,
                  root / "cap-a")
    for name in ("cap-a", "cap-b", "cap-c"):
        if name != "cap-a":
            shutil.copytree(root / "cap-a", root / name)
        manifest = json.loads((root / name / "capture.json").read_text())
        (root / name / "capture.json").write_text(json.dumps({**manifest, "capture_id": name}))
    return root
