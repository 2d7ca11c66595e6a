"""A prior's recorded sampler setting (prior.json ``extra.sampler``) and classifier-free guidance through
generate(), the ONNX prior and ``vt4d generate``."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from co4dgen_helpers import SMALL_PRIOR
from vt4dcodec.cli import main as vt4d
from vt4dcodec.errors import ModelError
from vt4dcodec.format import ModelFingerprint
from vt4dcodec.generate import generate
from vt4dcodec.model.configs import get_prior_config
from vt4dcodec.model.directories import (DEFAULT_SAMPLER, PRIOR_META_FILE, PRIOR_WEIGHTS_FILE, SamplerSetting,
                                         parse_sampler, read_prior_meta)
from vt4dcodec.model.onnx_export import export_prior
from vt4dcodec.model.onnx_prior import OnnxPrior, read_safetensor
from vt4dcodec.model.prior import Co4DGen
from vt4dcodec.model.weights_io import load_prior, save_prior
from vt4dcodec.synth import SynthConfig, generate_scene


@pytest.fixture(scope="module")
def capture():
    return generate_scene(1, split="test", config=SynthConfig(num_cameras=2, num_frames=4, height=32, width=32)).capture


@pytest.fixture(scope="module")
def guided_dir(tmp_path_factory, tokenizer_dir):
    """A small prior with a null condition (random weights), saved with a recorded sampler and exported."""
    from vt4dcodec.model import from_pretrained

    torch.manual_seed(0)
    prior = Co4DGen(get_prior_config("co4dgen-tiny", **SMALL_PRIOR, cond_dropout=0.1))
    with torch.no_grad():
        for p in prior.parameters():
            if not p.abs().gt(0).any():
                p.normal_(0.0, 0.2)
    tok = from_pretrained(tokenizer_dir).stored_fingerprint()
    out = save_prior(prior, tmp_path_factory.mktemp("guided") / "prior", model_id="guided-test", model_version="0",
                     tokenizer=tok, extra={"sampler": {"method": "euler", "steps": 3, "guidance": 2.0,
                                                       "measured": "a test"}})
    export_prior(load_prior(out), out)
    return out


def test_sampler_settings_parse_and_refuse_bad_values():
    assert parse_sampler("heun:16") == SamplerSetting("heun", 16, 1.0) == DEFAULT_SAMPLER
    assert parse_sampler("euler:4:1.5") == ("euler", 4, 1.5) and str(parse_sampler("euler:4:1.5")) == "euler:4:1.5"
    for bad in ("heun", "rk4:3", "heun:0", "heun:x", "heun:4:x", "heun:4:-1", "heun:4:30", "heun:4:1:2"):
        with pytest.raises(ModelError):
            parse_sampler(bad)


def test_load_prior_reads_the_recorded_sampler_and_refuses_malformed_ones(guided_dir, tmp_path, trained_prior):
    assert load_prior(guided_dir).sampler == SamplerSetting("euler", 3, 2.0)
    assert load_prior(trained_prior / "prior").sampler == DEFAULT_SAMPLER  # records none
    import shutil

    meta = json.loads((guided_dir / PRIOR_META_FILE).read_text())
    for bad in ({"method": "rk4", "steps": 3}, {"method": "heun", "steps": 0}, {"method": "heun", "steps": 2,
                                                                                  "extra_key": 1}, [1, 2]):
        d = tmp_path / f"bad{len(list(tmp_path.iterdir()))}"
        shutil.copytree(guided_dir, d)
        (d / PRIOR_META_FILE).write_text(json.dumps({**meta, "extra": {"sampler": bad}}))
        with pytest.raises(ModelError, match="extra.sampler"):
            read_prior_meta(d)
    # guidance recorded for a prior that has no null condition
    d = tmp_path / "noguide"
    shutil.copytree(trained_prior / "prior", d)
    plain = json.loads((d / PRIOR_META_FILE).read_text())
    (d / PRIOR_META_FILE).write_text(json.dumps({**plain, "extra": {"sampler": {"method": "heun", "steps": 2,
                                                                                "guidance": 2.0}}}))
    with pytest.raises(ModelError, match="null"):
        load_prior(d)


def test_generate_uses_the_recorded_sampler_and_explicit_settings_override_it(guided_dir, capture):
    cam = capture.camera_names[0]
    video, traj = capture.frames[cam], capture.cameras[cam]
    default = generate(video, traj, seed=2, model=guided_dir, runtime="torch")
    explicit = generate(video, traj, seed=2, model=guided_dir, runtime="torch", steps=3, method="euler", guidance=2.0)
    info = default.metadata["co4dgen"]
    assert (info["method"], info["steps"], info["guidance"]) == ("euler", 3, 2.0)
    assert np.array_equal(default.static_tokens, explicit.static_tokens)
    plain = generate(video, traj, seed=2, model=guided_dir, runtime="torch", guidance=1.0)
    assert "guidance" not in plain.metadata["co4dgen"] and not np.array_equal(plain.static_tokens,
                                                                             default.static_tokens)


@pytest.mark.parametrize("guidance", [1.0, 2.0, 0.0])
def test_onnx_guided_samples_match_torch(guided_dir, capture, guidance):
    cam = capture.camera_names[0]
    video, traj = capture.frames[cam], capture.cameras[cam]
    got = generate(video, traj, "orbit:degrees=10", seed=5, model=guided_dir, runtime="onnx", steps=2,
                   method="heun", guidance=guidance)
    want = generate(video, traj, "orbit:degrees=10", seed=5, model=guided_dir, runtime="torch", steps=2,
                    method="heun", guidance=guidance)
    assert got.metadata == want.metadata
    assert np.abs(got.static_tokens - want.static_tokens).max() <= 1e-4
    assert np.abs(got.dynamic_tokens - want.dynamic_tokens).max() <= 1e-4


def test_onnx_prior_refuses_guidance_without_a_null_condition(trained_prior, tmp_path):
    import shutil

    d = tmp_path / "plain"
    shutil.copytree(trained_prior / "prior", d)
    export_prior(load_prior(d), d)
    onnx = OnnxPrior.open(d)
    T, H = onnx.config.frames, onnx.config.image_size
    K = np.tile(np.array([[30.0, 0, 15.5], [0, 30.0, 15.5], [0, 0, 1]], np.float32), (1, T, 1, 1))
    w2c = np.tile(np.eye(4, dtype=np.float32), (1, T, 1, 1))
    frames = np.zeros((1, T, 3, H, H), np.float32)
    with pytest.raises(ModelError, match="cond_dropout"):
        onnx.sample(frames, K, w2c, K, w2c, steps=1, guidance=2.0)
    assert onnx.sample(frames, K, w2c, K, w2c, steps=1)[0].shape[0] == 1


def test_read_safetensor_reads_one_tensor_and_refuses_damage(guided_dir, tmp_path):
    null = read_safetensor(guided_dir / PRIOR_WEIGHTS_FILE, "null_condition", (SMALL_PRIOR["width"],))
    assert np.allclose(null, load_prior(guided_dir).null_condition.detach().numpy(), atol=1e-3)
    with pytest.raises(ModelError, match="no tensor"):
        read_safetensor(guided_dir / PRIOR_WEIGHTS_FILE, "missing", (1,))
    with pytest.raises(ModelError, match="not a"):
        read_safetensor(guided_dir / PRIOR_WEIGHTS_FILE, "null_condition", (3,))
    data = (guided_dir / PRIOR_WEIGHTS_FILE).read_bytes()
    n = int.from_bytes(data[:8], "little")
    begin, end = json.loads(data[8:8 + n])["null_condition"]["data_offsets"]
    for name, blob in (("short", data[:5]), ("huge", (1 << 40).to_bytes(8, "little") + data[8:]),
                       ("notjson", (4).to_bytes(8, "little") + b"{{{{" + data[12:]),
                       ("cut", data[:8 + n + (begin + end) // 2])):
        (tmp_path / name).write_bytes(blob)
        with pytest.raises(ModelError):
            read_safetensor(tmp_path / name, "null_condition", (SMALL_PRIOR["width"],))


def test_cli_generate_takes_guidance_and_names_the_flag_on_errors(guided_dir, trained_prior, capture, tmp_path,
                                                                   tokenizer_dir, monkeypatch, capsys):
    from vt4dcodec.capture.io import write_capture

    monkeypatch.setenv("VT4D_MODEL_PATH", str(tokenizer_dir.parent))
    cap = tmp_path / "cap"
    write_capture(capture, cap)
    assert vt4d(["generate", str(cap), "--prior", str(guided_dir), "-o", str(tmp_path / "g"), "--render-steps", "1",
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["sampler"] == {"method": "euler", "steps": 3, "guidance": 2.0}
    assert vt4d(["generate", str(cap), "--prior", str(guided_dir), "-o", str(tmp_path / "g2"), "--render-steps", "1",
                 "--guidance", "1.5", "--steps", "2", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["sampler"] == {"method": "euler", "steps": 2, "guidance": 1.5}
    assert vt4d(["generate", str(cap), "--prior", str(trained_prior / "prior"), "-o", str(tmp_path / "g3"),
                 "--guidance", "2"]) != 0
    assert "--guidance" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        vt4d(["generate", str(cap), "-o", str(tmp_path / "g4"), "--guidance", "25"])
    assert "--guidance" in capsys.readouterr().err


def test_ship_prior_records_the_measured_sampler(guided_dir, tmp_path, tokenizer_dir):
    import shutil

    from vt4dcodec.model.train.ship_prior import ship_prior

    dest = tmp_path / "weights"
    shutil.copytree(tokenizer_dir, dest / "tok-test")
    fp = ModelFingerprint.from_dict(json.loads((guided_dir / PRIOR_META_FILE).read_text())["tokenizer"])
    assert fp.model_id == "tok-test"
    out = ship_prior(guided_dir, dest, sampler="heun:4:1.5", measured="bench x")
    assert load_prior(out).sampler == SamplerSetting("heun", 4, 1.5)
    assert json.loads((out / PRIOR_META_FILE).read_text())["extra"]["sampler"]["measured"] == "bench x"
    with pytest.raises(ModelError):
        ship_prior(guided_dir, dest, sampler="heun:zero")
