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


def test_every_encoded_camera_is_stored_and_places_the_tokens_of_an_anchor_views_model(tmp_path, synth_scene,
                                                                                     small_config):
    import dataclasses

    import torch

    from vt4dcodec.model import VideoTok4D, save_pretrained

    cfg = dataclasses.replace(small_config, locality_sigma=0.5, query_from_grid=True, project_anchors=True,
                              anchor_views=True)
    torch.manual_seed(0)
    net = VideoTok4D(cfg).eval()
    with torch.no_grad():  # tokens with depths other than the reference, so placement matters, and an
        net.renderer.depth_head.weight.normal_(std=0.5)  # output layer that is not zero (the fresh one is)
        net.renderer.out.weight.normal_(std=0.2)
    model_dir = save_pretrained(net, tmp_path / "anchored", model_id="anchored", model_version="0.0")
    cap = synth_scene.capture
    scene = codec.encode(cap, model=model_dir, cameras=["cam01", "cam00", "cam02"], seed=0)
    back = load(dumps(scene))
    assert len(back.extra_cameras) == 2
    for name, traj in zip(["cam00", "cam02"], back.extra_cameras):
        np.testing.assert_allclose(traj.w2c, cap.cameras[name].w2c, atol=1e-4)
    decoder = codec.SceneDecoder.open(dumps(scene), model=model_dir)
    K, w2c = decoder.source_cameras()
    assert K.shape == (1, 3, 8, 3, 3) and w2c.shape == (1, 3, 8, 4, 4)
    # an encoded camera renders from the file alone, as it renders from the capture (the stored camera is
    # within 0.01 px of it: an odd pixel may round the other way)
    from_file = decoder.render("camera:cam02", steps=1)
    assert np.abs(from_file.astype(int) - decoder.render("camera:cam02", steps=1, capture=cap)).max() <= 1
    # the extra cameras place the tokens: the same tokens placed with the first camera only render otherwise
    first_only = codec.SceneDecoder(scene=dataclasses.replace(back, extra_cameras=()), model=decoder.model)
    assert np.abs(first_only.render("camera:cam02", steps=1, capture=cap).astype(int) - from_file).max() > 0
    with pytest.raises(Vt4dError, match="capture"):
        decoder.render("camera:cam03", steps=1)  # not encoded: the capture is needed
