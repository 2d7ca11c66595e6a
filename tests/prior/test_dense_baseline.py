"""The dense per-view baseline of Table 2: its network, weights I/O, training entry point and bench."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
import torch

from co4dgen_helpers import SMALL_TOKENIZER, random_condition
from vt4dcodec.errors import ModelError, ModelNotFoundError
from vt4dcodec.model.configs import DenseConfig, ModelConfig, PriorConfig, get_config, get_dense_config
from vt4dcodec.model.dense_baseline import DenseViewDiffusion
from vt4dcodec.model.prior import Co4DGen, PriorCondition
from vt4dcodec.model.videotok4d import VideoTok4D
from vt4dcodec.model.weights_io import load_dense, save_dense

BENCH = Path(__file__).resolve().parents[2] / "bench" / "bench_table2.py"
SMALL_DENSE = dict(cond_patch=8, anchor_grid=2, cond_layers=1, width=32, heads=2, layers=1, patch_size=2)


def small_dense(seed: int = 0) -> DenseViewDiffusion:
    torch.manual_seed(seed)
    cfg = DenseConfig.for_tokenizer(get_config("tiny", **SMALL_TOKENIZER), **SMALL_DENSE)
    return DenseViewDiffusion(cfg).eval()


def _fingerprint():
    from vt4dcodec.format import ModelFingerprint

    return ModelFingerprint(model_id="tok", model_version="0", config_sha256="a" * 64, weights_sha256="b" * 64,
                            static_shape=(8, 8), dynamic_shape=(4, 8), token_dtype="float32")


def test_dense_tiny_is_matched_in_size_to_co4dgen_tiny_plus_the_renderer():
    """Table 2 compares models of matched size: the dense baseline's trainable parameters (E_cond + denoiser)
    against what Co4DGen runs to make views (the prior + the tokenizer's renderer), for the shipped sizes."""
    tokenizer = ModelConfig.from_dict(json.loads(
        (Path(__file__).resolve().parents[2] / "model" / "weights" / "vt4d-tiny" / "config.json").read_text())["config"])
    prior = Co4DGen(PriorConfig.for_tokenizer(tokenizer))
    renderer = VideoTok4D(tokenizer).renderer
    co4dgen = sum(p.numel() for p in prior.parameters()) + sum(p.numel() for p in renderer.parameters())
    dense = DenseViewDiffusion(DenseConfig.for_tokenizer(tokenizer)).trainable_parameters()
    assert abs(dense / co4dgen - 1.0) < 0.05, (dense, co4dgen)


def test_samples_are_seeded_shaped_and_in_range():
    dense = small_dense()
    cond = random_condition(B=2, T=4, size=32)
    a = dense.sample_latents(cond, steps=2, seed=3)
    b = dense.sample_latents(cond, steps=2, seed=3)
    c = dense.sample_latents(cond, steps=2, seed=4)
    assert a.shape == (2, 4, dense.config.latent_channels, 8, 8)
    assert torch.equal(a, b) and not torch.equal(a, c)
    frames = dense.generate(cond, steps=1, method="heun")
    assert frames.shape == (2, 4, 3, 32, 32) and frames.min() >= 0 and frames.max() <= 1


def test_the_target_trajectory_changes_the_sample():
    """With its output layer live, the denoiser must read the target cameras (else it cannot place a view)."""
    dense = small_dense()
    with torch.no_grad():
        for layer in (dense.out, dense.out_mod):
            layer.weight.normal_(0, 0.2)
    cond = random_condition(B=1, T=4, size=32)
    moved = PriorCondition(cond.frames, cond.K_c, cond.w2c_c, cond.K_a, cond.w2c_a.clone())
    moved.w2c_a[..., 0, 3] += 0.5
    assert not torch.allclose(dense.sample_latents(cond, steps=1), dense.sample_latents(moved, steps=1))


def test_bad_inputs_raise_model_error():
    dense = small_dense()
    cond = random_condition(B=1, T=4, size=32)
    with pytest.raises(ModelError, match="frames"):
        dense.sample_latents(PriorCondition(cond.frames[:, :3], cond.K_c, cond.w2c_c, cond.K_a, cond.w2c_a))
    bad = cond.w2c_a.clone()
    bad[0, 0, 0, 0] = float("nan")
    with pytest.raises(ModelError, match="non-finite"):
        dense.sample_latents(PriorCondition(cond.frames, cond.K_c, cond.w2c_c, cond.K_a, bad))
    with pytest.raises(ModelError, match="steps"):
        dense.sample_latents(cond, steps=0)
    with pytest.raises(ModelError, match="sampler"):
        dense.sample_latents(cond, method="ddim")
    with pytest.raises(ModelError, match="latents"):
        dense.flow_matching_loss(torch.zeros(1, 4, 2, 8, 8), cond)
    with pytest.raises(ModelError, match="PriorCondition"):
        dense.sample_latents(cond.frames)  # type: ignore[arg-type]
    with pytest.raises(ModelError):
        get_dense_config("dense-huge")
    with pytest.raises(ModelError):
        DenseConfig(image_size=60)


def test_training_steps_reduce_the_loss_on_a_fixed_batch():
    dense = small_dense().train()
    cond = random_condition(B=2, T=4, size=32)
    y = dense.latents(cond.frames)
    opt = torch.optim.AdamW([p for p in dense.parameters() if p.requires_grad], lr=3e-3)
    losses = []
    for step in range(40):
        loss, _ = dense.flow_matching_loss(y, cond, generator=torch.Generator().manual_seed(step % 4))
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert sum(losses[-4:]) < 0.8 * sum(losses[:4]), losses
    assert all(not p.requires_grad for p in dense.autoencoder.parameters())


def test_save_load_round_trip_and_damaged_files_are_refused(tmp_path):
    dense = small_dense()
    out = save_dense(dense, tmp_path / "d", model_id="dense-test", model_version="1", tokenizer=_fingerprint())
    loaded = load_dense(out)
    cond = random_condition(B=1, T=4, size=32)
    assert torch.equal(dense.sample_latents(cond, steps=2), loaded.sample_latents(cond, steps=2))
    assert loaded.model_id == "dense-test" and loaded.tokenizer_fingerprint.model_id == "tok"
    half = save_dense(dense, tmp_path / "h", model_id="dense-test", model_version="1", tokenizer=_fingerprint(),
                      storage_dtype="float16")
    assert torch.equal(dense.sample_latents(cond, steps=1), load_dense(half).sample_latents(cond, steps=1))
    weights = out / "dense.safetensors"
    data = bytearray(weights.read_bytes())
    data[-5] ^= 0xFF
    weights.write_bytes(bytes(data))
    with pytest.raises(ModelError, match="weights_sha256"):
        load_dense(out)
    meta = json.loads((half / "dense.json").read_text())
    meta["format"] = "co4dgen-prior/1"
    (half / "dense.json").write_text(json.dumps(meta))
    with pytest.raises(ModelError, match="format"):
        load_dense(half)
    with pytest.raises(ModelNotFoundError):
        load_dense(tmp_path / "missing")


@pytest.fixture(scope="module")
def trained_dense(tmp_path_factory, shards, tokenizer_dir) -> Path:
    from vt4dcodec.model.train.dense import main

    out = tmp_path_factory.mktemp("dense_run")
    overrides = [f"{k}={v}" for k, v in SMALL_DENSE.items()]
    assert main(["--shards", str(shards), "--out", str(out), "--tokenizer", str(tokenizer_dir), "--steps", "4",
                 "--batch-size", "4", "--warmup", "2", "--log-every", "2", "--ckpt-every", "2", "--no-progress",
                 "--set", *overrides]) == 0
    return out / "dense"


def test_training_binds_the_dense_model_to_the_tokenizers_autoencoder(trained_dense, tokenizer_dir):
    from vt4dcodec.model import from_pretrained

    dense, tokenizer = load_dense(trained_dense), from_pretrained(tokenizer_dir)
    assert dense.tokenizer_fingerprint.weights_sha256 == tokenizer.stored_fingerprint().weights_sha256
    for name, value in tokenizer.autoencoder.state_dict().items():
        assert torch.equal(dense.autoencoder.state_dict()[name], value), name
    assert "dense-tiny" in (trained_dense / "MODEL_CARD.md").read_text()


def test_training_refuses_shards_of_another_tokenizer(tmp_path, shards):
    from vt4dcodec.model import save_pretrained
    from vt4dcodec.model.train.dense import main

    torch.manual_seed(1)
    other = save_pretrained(VideoTok4D(get_config("tiny", **SMALL_TOKENIZER)), tmp_path / "other", model_id="other",
                            model_version="0")
    with pytest.raises(ModelError, match="another tokenizer"):
        main(["--shards", str(shards), "--out", str(tmp_path / "run"), "--tokenizer", str(other), "--steps", "1",
              "--no-progress"])


def test_bench_table2_reports_both_methods_paired_and_timed(shards, trained_prior, trained_dense, tokenizer_dir,
                                                           monkeypatch, tmp_path):
    monkeypatch.setenv("VT4D_MODEL_PATH", str(tokenizer_dir.parent))
    spec = importlib.util.spec_from_file_location("bench_table2", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    results, figure = tmp_path / "t2.json", tmp_path / "t2.png"
    assert bench.main(["--shards", str(shards), "--prior", str(trained_prior / "prior"), "--dense", str(trained_dense),
                       "--events", "2", "--prior-steps", "1,2", "--render-steps", "1", "--dense-steps", "1,2",
                       "--timing-events", "1", "--repeats", "1", "--results", str(results),
                       "--figure", str(figure)]) == 0
    out = json.loads(results.read_text())
    assert set(out["quality"]) == {"co4dgen@1", "co4dgen@2", "dense@1", "dense@2", "encoded_anchor"}
    assert out["headline"] == "co4dgen@1" and out["quality"]["co4dgen@1"]["psnr_db"]["n"] == 2 and out["views"] == 2  # the fixture's 3 cameras: 2 besides the conditioning one
    assert set(out["paired"]) == {"co4dgen@1 - dense@1", "co4dgen@1 - dense@2"}
    assert set(out["speedup"]) == {"co4dgen@2", "dense@1 batched", "dense@1 sequential", "dense@2 batched",
                                   "dense@2 sequential"}
    for metric in ("psnr_db", "ssim"):  # the fastest dense setting at least as good, if any, and the ratio to it
        match = out["equal_quality"][metric]
        better = [s for s in (1, 2) if out["quality"][f"dense@{s}"][metric]["mean"] >= out["quality"]["co4dgen@1"][metric]["mean"]]
        assert (match["dense"] is None) == (not better)
    assert all(v["wall_s"] > 0 for v in out["speedup"].values())
    assert out["table"]["dense"]["sequence_per_run"] == 4 * 16 and figure.stat().st_size > 1000


def test_training_exports_float16_when_asked(tmp_path, shards, tokenizer_dir):
    """``--storage-dtype float16`` (the committed dense-tiny 2.0.0) stores half-width tensors that load back as
    the float32 model they were rounded to."""
    import json as _json
    import struct

    from vt4dcodec.model.train.dense import main

    overrides = [f"{k}={v}" for k, v in SMALL_DENSE.items()]
    assert main(["--shards", str(shards), "--out", str(tmp_path), "--tokenizer", str(tokenizer_dir), "--steps", "2",
                 "--batch-size", "4", "--warmup", "1", "--log-every", "1", "--ckpt-every", "2", "--no-progress",
                 "--storage-dtype", "float16", "--set", *overrides]) == 0
    raw = (tmp_path / "dense" / "dense.safetensors").read_bytes()
    header = _json.loads(raw[8:8 + struct.unpack("<Q", raw[:8])[0]])
    dtypes = {v["dtype"] for k, v in header.items() if k != "__metadata__"}
    assert "F16" in dtypes and "F32" not in dtypes
    dense = load_dense(tmp_path / "dense")
    assert all(p.dtype == torch.float32 for p in dense.parameters())
