"""codec.encode(capture, cameras=...) and `vt4d encode --cameras`: several cameras -> one scene."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from vt4dcodec import codec
from vt4dcodec.errors import CaptureError, Vt4dError
from vt4dcodec.format import dumps, load


def test_encode_several_cameras_records_them_and_keeps_the_budget(synth_scene, model_dir, encoded):
    cap = synth_scene.capture
    scene = codec.encode(cap, model=model_dir, cameras=["cam01", "cam00"], seed=0)
    assert scene.static_tokens.shape == encoded.static_tokens.shape
    assert scene.dynamic_tokens.shape == encoded.dynamic_tokens.shape
    info = load(dumps(scene)).metadata["vt4d"]
    assert info["source_cameras"] == ["cam01", "cam00"] and info["source_camera"] == "cam01"
    np.testing.assert_allclose(scene.cameras.w2c, cap.cameras["cam01"].w2c, atol=1e-6)
    assert not np.allclose(scene.static_tokens, encoded.static_tokens)
    # "all" and a comma-separated string are the same request as the list
    every = codec.encode(cap, model=model_dir, cameras="all", seed=0)
    assert every.metadata["vt4d"]["source_cameras"] == cap.camera_names
    listed = codec.encode(cap, model=model_dir, cameras=",".join(cap.camera_names), seed=0)
    np.testing.assert_array_equal(every.static_tokens, listed.static_tokens)
    # one camera through cameras= is the single-camera encode
    one = codec.encode(cap, model=model_dir, cameras=["cam00"], seed=0)
    np.testing.assert_array_equal(one.static_tokens, encoded.static_tokens)
    assert "source_cameras" not in one.metadata["vt4d"]
    # a multi-camera scene renders encoded and held-out trajectories alike
    decoder = codec.SceneDecoder.open(dumps(scene), model=model_dir)
    frames = decoder.render_many(["source", cap.cameras["cam02"]], steps=1)
    assert all(f.shape == (8, 64, 64, 3) and f.dtype == np.uint8 for f in frames)


@pytest.mark.parametrize("kwargs, message", [
    ({"cameras": ["cam00", "cam00"]}, "twice"),
    ({"cameras": ["cam00", "cam07"]}, "no camera 'cam07'"),
    ({"cameras": []}, "at least one"),
    ({"cameras": "cam00", "camera": "cam01"}, "not both"),
])
def test_bad_camera_lists_are_capture_errors(synth_scene, model_dir, kwargs, message):
    with pytest.raises(CaptureError, match=message):
        codec.encode(synth_scene.capture, model=model_dir, **kwargs)
    assert issubclass(CaptureError, Vt4dError)


def test_cli_encode_cameras(tmp_path, synth_scene, model_dir):
    from vt4dcodec.capture.io import write_capture

    cap_dir = tmp_path / "cap"
    write_capture(synth_scene.capture, cap_dir)
    out = tmp_path / "multi.vt4d"
    run = subprocess.run([sys.executable, "-m", "vt4dcodec", "encode", str(cap_dir), "--cameras", "cam00,cam02",
                          "--model", str(model_dir), "-o", str(out), "--json", "--quiet"],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert load(out).metadata["vt4d"]["source_cameras"] == ["cam00", "cam02"]
    archive = tmp_path / "a.vt4da"
    run = subprocess.run([sys.executable, "-m", "vt4dcodec", "encode", str(cap_dir), "--cameras", "all",
                          "--model", str(model_dir), "--archive", str(archive), "--json", "--quiet"],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "synth-test-000007/all/000000" in json.dumps(json.loads(run.stdout))
    run = subprocess.run([sys.executable, "-m", "vt4dcodec", "encode", str(cap_dir), "--cameras", "cam02,cam01",
                          "--model", str(model_dir), "--archive", str(archive), "--json", "--quiet"],
                         capture_output=True, text=True)
    assert run.returncode == 0 and "synth-test-000007/cam02.cam01/000000" in run.stdout, run.stderr
    bad = subprocess.run([sys.executable, "-m", "vt4dcodec", "encode", str(cap_dir), "--cameras", "cam00,cam09",
                          "--model", str(model_dir), "-o", str(tmp_path / "x.vt4d")], capture_output=True, text=True)
    assert bad.returncode != 0 and "cam09" in bad.stderr and "Traceback" not in bad.stderr
