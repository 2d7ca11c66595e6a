"""A prior conditioned on the tokenizer's own tokens of the video (``PriorConfig.cond_tokens``): Z^c = E(V_c, P_c)
projected and added to the denoiser's input tokens, trained from the token records, computed by ``generate``
with the prior's tokenizer, exported to ONNX with the condition tokens as graph inputs."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from co4dgen_helpers import SMALL_PRIOR, random_condition, small_prior
from vt4dcodec.errors import ModelError
from vt4dcodec.generate import conditioning_tokens, generate, load_prior_model
from vt4dcodec.model.configs import PriorConfig, get_prior_config
from vt4dcodec.model.onnx_export import export_prior
from vt4dcodec.model.onnx_prior import OnnxPrior
from vt4dcodec.model.prior import Co4DGen
from vt4dcodec.model.weights_io import load_prior, save_prior
from vt4dcodec.synth import SynthConfig, generate_scene


def token_prior(seed: int = 0, *, scramble: bool = True) -> Co4DGen:
    torch.manual_seed(seed)
    prior = Co4DGen(get_prior_config("co4dgen-tiny", **SMALL_PRIOR, cond_tokens=True))
    if scramble:  # the zero-initialised input projections and outputs live, so the tokens matter
        with torch.no_grad():
            for p in prior.parameters():
                if p.ndim >= 1 and not p.abs().gt(0).any():
                    p.normal_(0.0, 0.2)
    return prior.eval()


def with_tokens(cond, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    B = cond.batch_size
    cond.z_s = torch.rand((B, SMALL_PRIOR["n_static"], SMALL_PRIOR["token_dim"]), generator=g) * 1.8 - 0.9
    cond.z_d = torch.rand((B, SMALL_PRIOR["n_dynamic"], SMALL_PRIOR["token_dim"]), generator=g) * 1.8 - 0.9
    return cond


def test_config_field_keeps_older_hashes_and_is_checked():
    plain = get_prior_config("co4dgen-tiny")
    assert get_prior_config("co4dgen-tiny", cond_tokens=False).sha256() == plain.sha256()
    assert "cond_tokens" not in plain.to_dict() or plain.to_dict()["cond_tokens"] is False
    assert get_prior_config("co4dgen-tiny", cond_tokens=True).sha256() != plain.sha256()
    for bad in ("yes", 1, None):
        with pytest.raises(ModelError, match="cond_tokens"):
            PriorConfig.from_dict({**plain.to_dict(), "cond_tokens": bad})


def test_the_condition_tokens_steer_the_sample_and_are_required():
    prior = token_prior()
    cond = random_condition(B=1, seed=1)
    with pytest.raises(ModelError, match="z_s and z_d"):
        prior.sample(cond, steps=2, seed=0)
    a = prior.sample(with_tokens(cond, 0), steps=2, seed=0)
    b = prior.sample(with_tokens(cond, 0), steps=2, seed=0)
    c = prior.sample(with_tokens(cond, 1), steps=2, seed=0)
    assert all(torch.equal(x, y) for x, y in zip(a, b))
    assert (a[0] - c[0]).abs().max() > 1e-3 and (a[1] - c[1]).abs().max() > 1e-3
    wrong = with_tokens(random_condition(B=1, seed=1))
    wrong.z_s = wrong.z_s[:, :-1]
    with pytest.raises(ModelError):
        prior.sample(wrong, steps=1)
    nan = with_tokens(random_condition(B=1, seed=1))
    nan.z_d[0, 0, 0] = float("nan")
    with pytest.raises(ModelError, match="finite"):
        prior.sample(nan, steps=1)


def test_a_new_token_prior_starts_as_the_prior_it_is_initialised_from(tmp_path):
    from vt4dcodec.model.train.prior import initialise_from

    base = small_prior(scramble=True)
    save_prior(base, tmp_path / "base", model_id="base", model_version="0",
               tokenizer=_fingerprint())
    prior = token_prior(seed=5, scramble=False)
    copied = initialise_from(prior, tmp_path / "base")
    assert copied == sorted(base.state_dict()) and "cond_in_s.weight" not in copied
    cond = with_tokens(random_condition(B=2, seed=3))
    want = base.sample(cond, steps=2, seed=1)
    got = prior.sample(cond, steps=2, seed=1)  # zero input projections: the tokens do not change it yet
    assert all(torch.allclose(x, y, atol=1e-6) for x, y in zip(got, want))
    prior.train()
    loss, _ = prior.flow_matching_loss(cond.z_s, cond.z_d, cond, torch.Generator().manual_seed(0))
    loss.backward()
    assert prior.cond_in_s.weight.grad.abs().sum() > 0  # and they learn
    with pytest.raises(ModelError, match="do not fit"):
        initialise_from(Co4DGen(get_prior_config("co4dgen-tiny", **{**SMALL_PRIOR, "width": 16, "heads": 2})),
                        tmp_path / "base")
    with pytest.raises(ModelError, match="no prior.safetensors"):
        initialise_from(prior, tmp_path)


def _fingerprint():
    from vt4dcodec.format import ModelFingerprint

    return ModelFingerprint(model_id="tok-test", model_version="0", config_sha256="0" * 64, weights_sha256="0" * 64,
                            static_shape=(SMALL_PRIOR["n_static"], SMALL_PRIOR["token_dim"]),
                            dynamic_shape=(SMALL_PRIOR["n_dynamic"], SMALL_PRIOR["token_dim"]))


def test_onnx_graphs_take_the_condition_tokens(tmp_path):
    prior = token_prior(seed=2)
    directory = save_prior(prior, tmp_path / "p", model_id="tokens-test", model_version="0", tokenizer=_fingerprint())
    export_prior(load_prior(directory), directory)
    onnx = OnnxPrior.open(directory)
    cond = with_tokens(random_condition(B=1, seed=4), 2)
    arrays = [t.numpy() for t in (cond.frames, cond.K_c, cond.w2c_c, cond.K_a, cond.w2c_a)]
    with pytest.raises(ModelError, match="z_s and z_d"):
        onnx.sample(*arrays, steps=1)
    with pytest.raises(ModelError, match="z_s"):
        onnx.sample(*arrays, steps=1, z_s=cond.z_s.numpy()[:, :-1], z_d=cond.z_d.numpy())
    torch_prior = load_prior(directory)
    for steps, method in ((1, "euler"), (3, "heun")):
        got = onnx.sample(*arrays, steps=steps, seed=3, method=method, z_s=cond.z_s.numpy(), z_d=cond.z_d.numpy())
        want = torch_prior.sample(cond, steps=steps, seed=3, method=method)
        for a, b in zip(got, want):
            assert np.abs(a - b.numpy()).max() <= 2e-6


@pytest.fixture(scope="module")
def token_prior_run(tmp_path_factory, shards, trained_prior):
    """The training entry point with cond_tokens, started from the plain trained prior (--init)."""
    from vt4dcodec.model.train.prior import main

    out = tmp_path_factory.mktemp("token_prior_run")
    overrides = [f"{k}={v}" for k, v in SMALL_PRIOR.items() if k not in ("n_static", "n_dynamic", "token_dim",
                                                                      "frames", "image_size")]
    assert main(["--shards", str(shards), "--out", str(out), "--steps", "3", "--batch-size", "4", "--warmup", "1",
                 "--log-every", "1", "--no-progress", "--init", str(trained_prior / "prior"),
                 "--set", *overrides, "cond_tokens=true"]) == 0
    return out / "prior"


def test_training_reads_each_pair_with_the_conditioning_cameras_own_record(shards):
    from vt4dcodec.model.train.prior import PriorPairDataset, collate_prior

    data = PriorPairDataset(shards, anchors="all", condition_tokens=True)
    for index in range(len(data)):
        item = data[index]
        own = data.tokens[data.index[item["clip_key"]]]
        assert torch.equal(item["zc_s"], own["static_tokens"].float())
        assert torch.equal(item["zc_d"], own["dynamic_tokens"].float())
        if item["clip_key"] == item["anchor_key"]:
            assert torch.equal(item["zc_s"], item["z_s"])
    batch = collate_prior([data[0], data[1]])
    assert batch.cond.z_s.shape == batch.z_s.shape and batch.cond.z_d.shape == batch.z_d.shape
    repeated = PriorPairDataset(shards, anchors="all", source_repeats=3, condition_tokens=True)
    own = sum(1 for i, k in data.pairs if data.tokens.keys[i][1] == k)
    assert len(repeated) == len(data) + 2 * own and own == len(data.tokens)
    for bad in (0, 1.5):
        with pytest.raises(ModelError, match="source_repeats"):
            PriorPairDataset(shards, anchors="all", source_repeats=bad)
    with pytest.raises(ModelError, match="source_repeats"):
        PriorPairDataset(shards, anchors="distinct", source_repeats=2)


def test_relative_pose_is_the_identity_exactly_for_the_same_camera():
    from vt4dcodec.model.prior import RELATIVE_POSE_FEATURES, relative_pose

    cond = random_condition(B=2, T=4, seed=7)
    same = relative_pose(cond.w2c_c, cond.w2c_c)
    assert same.shape == (2, RELATIVE_POSE_FEATURES)
    assert torch.allclose(same[:, :12], torch.eye(3, 4).flatten().expand(2, -1), atol=1e-6)
    assert same[:, 12:].abs().max() < 1e-6
    moved = relative_pose(cond.w2c_a, cond.w2c_c)
    assert moved[:, 12:].abs().max() > 1e-2
    # a rigid camera (a rotation and a translation) and a point it sees: M maps c's coordinates to a's
    def rotated(angle: float, base: torch.Tensor) -> torch.Tensor:
        c, s = torch.cos(torch.tensor(angle)), torch.sin(torch.tensor(angle))
        out = base.clone()
        out[:3, :3] = torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        return out

    w2c_a, w2c_c = rotated(0.3, cond.w2c_a[0, 0]), rotated(-0.5, cond.w2c_c[0, 0])
    M = relative_pose(w2c_a[None, None], w2c_c[None, None])[0, :12].view(3, 4)
    p_world = torch.tensor([0.2, -0.1, 2.0, 1.0])
    p_c, p_a = w2c_c @ p_world, w2c_a @ p_world
    assert torch.allclose(M @ p_c, p_a[:3], atol=1e-5)


def test_generate_encodes_the_video_with_the_priors_tokenizer(token_prior_run, tokenizer_dir, monkeypatch):
    monkeypatch.setenv("VT4D_MODEL_PATH", str(tokenizer_dir.parent))
    capture = generate_scene(2, split="test", config=SynthConfig(num_cameras=2, num_frames=4, height=32,
                                                                 width=32)).capture
    cam = capture.camera_names[0]
    prior = load_prior_model(token_prior_run, runtime="torch")
    assert prior.config.cond_tokens
    scene = generate(capture.frames[cam], capture.cameras[cam], "source", model=prior, steps=2, seed=1)
    again = generate(capture.frames[cam], capture.cameras[cam], "source", model=prior, steps=2, seed=1,
                     tokenizer=tokenizer_dir)
    assert np.array_equal(scene.static_tokens, again.static_tokens)
    z_s, z_d = conditioning_tokens(prior, capture.frames[cam], capture.cameras[cam], tokenizer_dir)
    assert z_s.shape == (1, SMALL_PRIOR["n_static"], SMALL_PRIOR["token_dim"]) and z_d.dtype == np.float32
    with pytest.raises(ModelError):  # another tokenizer than the prior's
        from vt4dcodec.model import VideoTok4D, get_config, save_pretrained
        from co4dgen_helpers import SMALL_TOKENIZER

        torch.manual_seed(9)
        other = save_pretrained(VideoTok4D(get_config("tiny", **SMALL_TOKENIZER)), tokenizer_dir.parent / "tok-other",
                                model_id="tok-other", model_version="0")
        generate(capture.frames[cam], capture.cameras[cam], "source", model=prior, steps=1, tokenizer=other)


def test_cli_generate_and_the_onnx_runtime_with_a_token_prior(token_prior_run, tokenizer_dir, monkeypatch, tmp_path,
                                                              capsys):
    import json
    import shutil

    from vt4dcodec.capture.io import write_capture
    from vt4dcodec.cli import main as vt4d
    from vt4dcodec.format import load, save

    monkeypatch.setenv("VT4D_MODEL_PATH", str(tokenizer_dir.parent))
    capture = generate_scene(3, split="test", config=SynthConfig(num_cameras=2, num_frames=4, height=32,
                                                                 width=32)).capture
    write_capture(capture, tmp_path / "cap")
    prior_dir = tmp_path / "prior"
    shutil.copytree(token_prior_run, prior_dir)
    code = vt4d(["generate", str(tmp_path / "cap"), "--prior", str(prior_dir), "--views", "source", "--steps", "2",
                 "--render-steps", "1", "--format", "npz", "--json", "--runtime", "torch", "-o", str(tmp_path / "g")])
    assert code == 0, capsys.readouterr().err
    json.loads(capsys.readouterr().out)
    scene = load(tmp_path / "g" / "scene.vt4d")
    export_prior(load_prior(prior_dir), prior_dir)  # the torch-free path: graphs of the prior, the encoder's own
    cam = capture.camera_names[0]
    on_torch = generate(capture.frames[cam], capture.cameras[cam], "source", model=prior_dir, steps=2, seed=0,
                        runtime="torch")
    save(on_torch, tmp_path / "api.vt4d")  # the CLI is generate() (seed 0), stored in the same encoding
    assert np.array_equal(load(tmp_path / "api.vt4d").static_tokens, scene.static_tokens)
    z = conditioning_tokens(load_prior_model(prior_dir, runtime="torch"), *_fitted(capture, cam), runtime="torch")
    onnx = load_prior_model(prior_dir, runtime="onnx")
    assert isinstance(onnx, OnnxPrior)
    frames, traj = _fitted(capture, cam)
    pixels = frames.transpose(0, 3, 1, 2).astype(np.float32)[None] / np.float32(255.0)
    cams = [np.asarray(a, np.float32)[None] for a in (traj.K, traj.w2c, traj.K, traj.w2c)]
    got = onnx.sample(pixels, *cams, steps=2, seed=0, method="heun", z_s=z[0], z_d=z[1])
    want = load_prior_model(prior_dir, runtime="torch").sample(
        _torch_condition(pixels, cams, z), steps=2, seed=0, method="heun")
    for a, b in zip(got, want):
        assert np.abs(a - b.numpy()).max() <= 2e-6


def _fitted(capture, cam):
    from vt4dcodec.generate import fit_conditioning

    return fit_conditioning(capture.frames[cam], capture.cameras[cam], size=SMALL_PRIOR["image_size"],
                            frames=SMALL_PRIOR["frames"])


def _torch_condition(pixels, cams, z):
    from vt4dcodec.model.prior import PriorCondition

    t = [torch.from_numpy(a) for a in (pixels, *cams)]
    return PriorCondition(*t, z_s=torch.from_numpy(z[0]), z_d=torch.from_numpy(z[1]))


def test_the_sampler_computes_in_float64_and_follows_weight_changes(tmp_path):
    prior = small_prior(scramble=True)
    cond = random_condition(B=1, seed=2)
    net = prior.sampling_network()
    assert net.static_mean.dtype == torch.float64 and prior.sampling_network() is net
    assert all(not k.startswith("_sampling") for k in prior.state_dict())  # not part of the weights
    a = prior.sample(cond, steps=1, seed=0)
    assert a[0].dtype == torch.float32
    with torch.no_grad():
        prior.out_s.bias.add_(0.1)  # a training step or a load changes a tensor in place
    assert prior.sampling_network() is not net
    b = prior.sample(cond, steps=1, seed=0)
    assert not torch.equal(a[0], b[0])
    directory = save_prior(prior, tmp_path / "p", model_id="f64-test", model_version="0", tokenizer=_fingerprint())
    export_prior(load_prior(directory), directory)
    assert OnnxPrior.open(directory).dtype == np.float64
