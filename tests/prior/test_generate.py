"""generate() and ``vt4d generate``: one sample from one video, saved as a generated .vt4d, many views."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from co4dgen_helpers import SMALL_TOKENIZER

from vt4dcodec.cli import main as vt4d
from vt4dcodec.cli.generate_commands import split_view_specs
from vt4dcodec.codec import DEFAULT_ENCODING, SceneDecoder
from vt4dcodec.errors import CaptureError, ModelMismatchError, TrajectoryError, Vt4dError
from vt4dcodec.format import load
from vt4dcodec.generate import generate
from vt4dcodec.model import VideoTok4D, from_pretrained, get_config, save_pretrained
from vt4dcodec.model.prior import check_tokenizer
from vt4dcodec.model.weights_io import load_prior
from vt4dcodec.synth import SynthConfig, generate_scene


@pytest.fixture(scope="module")
def capture():
    """A held-out (test split) scene at 48x48, 5 frames: generate() must fit it to the prior's 32x32 x 4."""
    return generate_scene(0, split="test", config=SynthConfig(num_cameras=2, num_frames=5, height=48, width=48)).capture


@pytest.fixture()
def model_path(monkeypatch, tokenizer_dir):
    monkeypatch.setenv("VT4D_MODEL_PATH", str(tokenizer_dir.parent))


def test_generate_returns_a_seeded_generated_scene_for_the_anchor(capture, trained_prior, model_path):
    cam = capture.camera_names[0]
    video, traj = capture.frames[cam], capture.cameras[cam]
    prior_dir = trained_prior / "prior"
    a = generate(video, traj, "orbit:degrees=20", seed=3, model=prior_dir, steps=3)
    b = generate(video, traj, "orbit:degrees=20", seed=3, model=prior_dir, steps=3)
    c = generate(video, traj, "orbit:degrees=20", seed=4, model=prior_dir, steps=3)
    assert np.array_equal(a.static_tokens, b.static_tokens) and np.array_equal(a.dynamic_tokens, b.dynamic_tokens)
    assert not np.array_equal(a.static_tokens, c.static_tokens)
    assert a.provenance.kind == "generated" and a.provenance.source_capture_id is None
    assert a.fingerprint.model_id == "tok-test" and a.metadata["co4dgen"]["seed"] == 3
    assert a.cameras.num_frames == 4 and (a.cameras.width, a.cameras.height) == (32, 32)
    other_anchor = generate(video, traj, "source", seed=3, model=prior_dir, steps=3)
    assert not np.array_equal(other_anchor.static_tokens, a.static_tokens)  # P_a conditions the sample
    decoder = SceneDecoder.open(a)  # found by the stored fingerprint through $VT4D_MODEL_PATH
    views = decoder.render_many(["source", "pan:degrees=10"], steps=1)
    assert [v.shape for v in views] == [(4, 32, 32, 3)] * 2


def test_generate_moves_a_world_origin_at_the_camera_like_encode(capture, trained_prior, model_path):
    """A conditioning camera with the world origin at its centre (vt4dcodec.reference): the sample is the one the
    same video gives in the frame moved to the reference point, stored with its cameras in the capture's frame and
    the point under metadata["vt4d"]["centre_mm"], which the decoder renders from."""
    import dataclasses

    from vt4dcodec.reference import CENTRE_KEY, move_origin

    cam = capture.camera_names[0]
    video, traj = capture.frames[cam], capture.cameras[cam]
    w0 = np.asarray(traj.w2c, np.float64)[0]
    at_camera = dataclasses.replace(traj, w2c=move_origin(traj.w2c, -w0[:3, :3].T @ w0[:3, 3]))
    prior_dir = trained_prior / "prior"
    moved = generate(video, at_camera, "orbit:degrees=20", seed=3, model=prior_dir, steps=3)
    centre = np.asarray(moved.metadata["vt4d"][CENTRE_KEY], np.float64) / 1000.0
    plain_traj = dataclasses.replace(at_camera, w2c=move_origin(at_camera.w2c, centre))
    plain = generate(video, plain_traj, "orbit:degrees=20", seed=3, model=prior_dir, steps=3)
    assert "vt4d" not in plain.metadata
    np.testing.assert_allclose(moved.static_tokens, plain.static_tokens, atol=1e-5)
    # stored in the conditioning capture's frame, rendered in the moved one
    np.testing.assert_allclose(moved.cameras.w2c[:, :3, :3], plain.cameras.w2c[:, :3, :3], atol=1e-9)
    assert not np.allclose(moved.cameras.w2c[:, :3, 3], plain.cameras.w2c[:, :3, 3])
    a = SceneDecoder.open(moved).render("source", steps=1)
    b = SceneDecoder.open(plain).render("source", steps=1)
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 2


def test_generate_rejects_bad_inputs(capture, trained_prior):
    cam = capture.camera_names[0]
    video, traj = capture.frames[cam], capture.cameras[cam]
    prior_dir = trained_prior / "prior"
    with pytest.raises(CaptureError):
        generate(video[:3], traj, model=prior_dir)  # shorter than the prior's clip
    with pytest.raises(CaptureError):
        generate(video.astype(np.float32), traj, model=prior_dir)
    with pytest.raises(CaptureError):
        generate(video, traj, model=prior_dir, start=2)
    with pytest.raises(TrajectoryError):
        generate(video, "cam0", model=prior_dir)
    with pytest.raises(TrajectoryError):
        generate(video, traj, "spiral:turns=2", model=prior_dir)
    with pytest.raises(Vt4dError):
        generate(video, traj, model=prior_dir, steps=0)


def test_split_view_specs():
    assert split_view_specs(["source,orbit:degrees=30,distance=2,pan", "tilt:degrees=5"]) == [
        "source", "orbit:degrees=30,distance=2", "pan", "tilt:degrees=5"]
    assert split_view_specs([]) == []
    with pytest.raises(CaptureError):
        split_view_specs(["degrees=3,pan"])


def test_cli_generate_saves_one_sample_and_renders_every_view(capture, trained_prior, model_path, tmp_path, capsys):
    from vt4dcodec.capture.io import write_capture

    cap_dir = tmp_path / "cap"
    write_capture(capture, cap_dir)
    out = tmp_path / "gen"
    code = vt4d(["generate", str(cap_dir), "--prior", str(trained_prior / "prior"), "--anchor", "orbit:degrees=15",
                 "--views", "source,pan:degrees=10", "--views", "dolly_in", "--steps", "2", "--render-steps", "1",
                 "--format", "npz", "--seed", "5", "--json", "-o", str(out)])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert [v["view"] for v in result["views"]] == ["source", "pan:degrees=10", "dolly_in"]
    scene = load(out / "scene.vt4d")
    assert scene.provenance.kind == "generated" and scene.encoding == DEFAULT_ENCODING  # one default with encode
    assert scene.provenance.source_capture_id == capture.capture_id  # `vt4d info` names the capture
    for v in result["views"]:
        with np.load(v["path"], allow_pickle=False) as npz:
            assert npz["frames"].shape == (4, 32, 32, 3)
    # a bad view spec is invalid input (exit 1) and a missing capture an OS error (exit 3)
    assert vt4d(["generate", str(cap_dir), "--prior", str(trained_prior / "prior"), "--views", "spin", "--steps",
                 "1", "-o", str(out)]) == 1
    assert vt4d(["generate", str(tmp_path / "nope"), "--prior", str(trained_prior / "prior"), "-o", str(out)]) in (1, 3)


def test_cli_generate_refuses_a_tokenizer_the_prior_was_not_trained_on(capture, trained_prior, tmp_path):
    from vt4dcodec.capture.io import write_capture

    torch.manual_seed(99)
    other = save_pretrained(VideoTok4D(get_config("tiny", **SMALL_TOKENIZER)), tmp_path / "other",
                            model_id="tok-test", model_version="0")
    cap_dir = tmp_path / "cap"
    write_capture(capture, cap_dir)
    assert vt4d(["generate", str(cap_dir), "--prior", str(trained_prior / "prior"), "--model", str(other),
                 "--steps", "1", "-o", str(tmp_path / "g")]) == 1
    assert not (tmp_path / "g").exists()  # refused before sampling anything
    with pytest.raises(ModelMismatchError):
        check_tokenizer(load_prior(trained_prior / "prior"), from_pretrained(other).fingerprint("tok-test", "0"))
