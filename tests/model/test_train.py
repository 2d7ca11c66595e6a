"""The training commands: both stages run, resume, log, plot and save; a 2-rank torchrun path."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from vt4dcodec.errors import ModelError
from vt4dcodec.model import from_pretrained
from vt4dcodec.model.train import autoencoder as stage1
from vt4dcodec.model.train import tokenizer as stage2
from vt4dcodec.model.train.common import lr_at, load_checkpoint, parse_overrides, save_checkpoint
from vt4dcodec.model.train.data import rank_seeds

# A miniature config (4 frames at 32x32) so a training step takes well under a second.
SMALL = ["frames=4", "image_size=32", "width=32", "heads=2", "ae_width=8", "spatial_layers=1",
         "static_query_layers=1", "track_layers=1", "renderer_layers=1", "n_static=8", "n_dynamic=4",
         "token_dim=8", "n_tracks=8"]


def common(scenes: int = 1) -> list[str]:
    return ["--scenes", str(scenes), "--cameras", "2", "--workers", "0", "--log-every", "1", "--no-progress",
            "--warmup", "2", "--set", *SMALL]


COMMON = common()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    torch.set_num_threads(1)
    assert stage1.main(["--out", str(root / "ae"), "--steps", "3", "--batch-size", "4", "--ckpt-every", "2",
                        "--cache", str(root / "cache"), *COMMON]) == 0
    return root


def test_stage1_writes_weights_log_plot_and_resumes(runs):
    ae = runs / "ae"
    for name in ("autoencoder.safetensors", "autoencoder.json", "log.jsonl", "loss.png", "checkpoint/state.json"):
        assert (ae / name).is_file(), name
    assert [json.loads(line)["step"] for line in (ae / "log.jsonl").read_text().splitlines()] == [1, 2, 3]
    assert json.loads((ae / "checkpoint/state.json").read_text())["step"] == 3
    # the same command with more steps continues from step 3 instead of starting over
    assert stage1.main(["--out", str(ae), "--steps", "5", "--batch-size", "4", "--cache", str(runs / "cache"),
                        *COMMON]) == 0
    assert [json.loads(line)["step"] for line in (ae / "log.jsonl").read_text().splitlines()] == [1, 2, 3, 4, 5]
    stats = json.loads((ae / "autoencoder.json").read_text())
    assert len(stats["latent_std"]) == 4 and all(s > 0 for s in stats["latent_std"])


def test_a_checkpoint_without_optimizer_state_resumes_with_a_rewarmed_rate(runs, tmp_path):
    """The committed form of a run (weights + state.json, no optimizer.pt) resumes on another machine:
    the weights are kept, Adam starts over and the learning rate ramps up again over --warmup steps."""
    out = tmp_path / "ae"
    args = ["--out", str(out), "--batch-size", "4", "--cache", str(runs / "cache"), "--lr", "1e-3", *COMMON]
    assert stage1.main([*args, "--steps", "2"]) == 0
    (out / "checkpoint" / "optimizer.pt").unlink()
    assert stage1.main([*args, "--steps", "4"]) == 0
    log = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2, 3, 4]
    assert log[2]["lr"] == pytest.approx(lr_at(2, 1e-3, 2, 4) / 2)  # warm-up 2: half the rate at the first step
    assert log[3]["lr"] == pytest.approx(lr_at(3, 1e-3, 2, 4))
    assert (out / "checkpoint" / "optimizer.pt").is_file()  # the next checkpoint is complete again


def test_stage2_trains_and_saves_a_loadable_model(runs):
    out = runs / "tok"
    assert stage2.main(["--autoencoder", str(runs / "ae/autoencoder.safetensors"), "--out", str(out),
                        "--steps", "3", "--batch-size", "2", "--samples", "2", "--cache", str(runs / "cache"),
                        "--bf16", *COMMON]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steps"] == 3 and len(summary["psnr_db"]) == 2
    assert (out / "samples.png").is_file() and (out / "loss.png").is_file()
    model = from_pretrained(out / "model")
    assert model.config.frames == 4 and model.config.n_static == 8
    # the frozen autoencoder is the stage-1 one
    from safetensors.torch import load_file

    ae_state = load_file(str(runs / "ae/autoencoder.safetensors"))
    assert all(torch.equal(model.autoencoder.state_dict()[k], v) for k, v in ae_state.items())


def test_decoder_only_keeps_the_latents_and_ship_swaps_in_only_that_decoder(runs, tmp_path):
    from safetensors.torch import load_file

    from vt4dcodec.model.train.ship import swap_decoder

    before = load_file(str(runs / "ae/autoencoder.safetensors"))
    out = tmp_path / "dec"
    assert stage1.main(["--out", str(out), "--steps", "2", "--batch-size", "4", "--cache", str(runs / "cache"),
                        "--init", str(runs / "ae/autoencoder.safetensors"), "--decoder-only", *COMMON]) == 0
    after = load_file(str(out / "autoencoder.safetensors"))
    kept = [k for k in before if not k.startswith("decoder.")]
    assert "latent_std" in kept and all(torch.equal(before[k], after[k]) for k in kept)
    assert any(not torch.equal(before[k], after[k]) for k in before if k.startswith("decoder."))
    with pytest.raises(SystemExit):  # nothing to keep without --init
        stage1.main(["--out", str(tmp_path / "x"), "--steps", "1", "--decoder-only", *COMMON])

    assert stage2.main(["--autoencoder", str(runs / "ae/autoencoder.safetensors"), "--out", str(tmp_path / "tok"),
                        "--steps", "1", "--batch-size", "2", "--cache", str(runs / "cache"), *COMMON]) == 0
    model = from_pretrained(tmp_path / "tok" / "model")
    swap_decoder(model, out / "autoencoder.safetensors")
    state = model.autoencoder.state_dict()
    assert all(torch.equal(state[k], after[k]) for k in after)
    # a decoder that belongs to another encoder would decode the tokens' latents wrongly: refused
    other = tmp_path / "other"
    assert stage1.main(["--out", str(other), "--steps", "1", "--batch-size", "4", "--cache", str(runs / "cache"),
                        "--init", str(runs / "ae/autoencoder.safetensors"), *COMMON]) == 0
    with pytest.raises(ModelError, match="encoder|latent"):
        swap_decoder(model, other / "autoencoder.safetensors")
    with pytest.raises(ModelError, match="cannot read"):
        swap_decoder(model, tmp_path / "missing.safetensors")


def test_stage2_refuses_a_mismatched_autoencoder(runs, tmp_path):
    with pytest.raises(ModelError):
        stage2.main(["--autoencoder", str(runs / "ae/autoencoder.safetensors"), "--out", str(tmp_path / "x"),
                     "--steps", "1", "--cache", str(runs / "cache"), *COMMON, "ae_width=16"])


def test_checkpoint_round_trip_restores_optimizer_without_pickle(tmp_path):
    model = torch.nn.Linear(3, 2)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
    model(torch.randn(4, 3)).sum().backward()
    opt.step()
    save_checkpoint(tmp_path, model, opt, 7, {"note": "x"})
    model2 = torch.nn.Linear(3, 2)
    opt2 = torch.optim.AdamW(model2.parameters(), lr=1e-3)
    state = load_checkpoint(tmp_path, model2, opt2)
    assert state["step"] == 7 and state["note"] == "x"
    assert torch.equal(model.weight, model2.weight)
    assert torch.equal(opt.state_dict()["state"][0]["exp_avg"], opt2.state_dict()["state"][0]["exp_avg"])
    (tmp_path / "state.json").unlink()
    assert load_checkpoint(tmp_path, model2, opt2) is None  # incomplete checkpoints are ignored


def test_helpers():
    assert parse_overrides(["a=1", "b=true", "c=x"]) == {"a": 1, "b": True, "c": "x"}
    with pytest.raises(ModelError):
        parse_overrides(["novalue"])
    assert lr_at(0, 1.0, 10, 100) == pytest.approx(0.1) and lr_at(100, 1.0, 10, 100) == pytest.approx(0.1)
    assert lr_at(10, 1.0, 10, 100) == pytest.approx(1.0)
    ranks = [rank_seeds(5, 7, r, 2) for r in range(2)]
    assert sorted(ranks[0] + ranks[1]) == list(range(5, 12)) and not set(ranks[0]) & set(ranks[1])


def _torchrun(args: list[str], timeout: float) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node=2", "--master_port=0",
           "--rdzv_backend=c10d", "--rdzv_endpoint=localhost:0", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)


@pytest.mark.slow
def test_two_ranks_with_torchrun(runs, tmp_path):
    out = tmp_path / "ddp"
    proc = _torchrun(["-m", "vt4dcodec.model.train.tokenizer", "--autoencoder",
                      str(runs / "ae/autoencoder.safetensors"), "--out", str(out), "--steps", "2",
                      "--batch-size", "1", "--samples", "1", "--cache", str(runs / "cache"),
                      *common(scenes=2)], timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads((out / "checkpoint/state.json").read_text())["step"] == 2
    assert from_pretrained(out / "model").config.frames == 4


def test_training_from_capture_directories_on_disk(runs, tmp_path):
    """--data: scenes written by the synth writer, read through MultiViewPairs, match the generated ones."""
    from vt4dcodec.synth import SynthConfig, write_dataset

    write_dataset(tmp_path / "captures", num_scenes=1, split="train", seed=0, workers=1,
                  config=SynthConfig(num_cameras=2, num_frames=4, height=32, width=32))
    out = tmp_path / "ae"
    assert stage1.main(["--out", str(out), "--steps", "1", "--batch-size", "4", "--data", str(tmp_path / "captures"),
                        "--cache", str(tmp_path / "cache"), *COMMON]) == 0
    disk = next((tmp_path / "cache").glob("scene-disk-*.npz"))
    generated = next((runs / "cache").glob("scene-train-000000-*.npz"))
    with np.load(disk) as a, np.load(generated) as b:
        assert np.array_equal(a["frames"], b["frames"])  # PNG frames are lossless
        assert np.allclose(a["w2c"], b["w2c"], atol=1e-5) and np.allclose(a["K"], b["K"], atol=1e-4)


def test_prepared_cache_is_keyed_by_the_mask_rule_version(tmp_path, monkeypatch):
    """Regression: prepared inputs were cached without the mask rule's version, so a changed
    isolate_motion silently reused masks from the old rule."""
    from vt4dcodec.model.train import data

    pool = data.ScenePool(tmp_path, cameras=2, frames=8, image_size=64, latent_size=16, n_tracks=8)
    before = pool.prepared_path(3)
    monkeypatch.setattr(data, "MASK_RULE_VERSION", data.MASK_RULE_VERSION + 1)
    assert pool.prepared_path(3) != before
    no_iso = data.ScenePool(tmp_path, 2, 8, 64, 16, 8, motion_isolation=False)
    assert no_iso.prepared_path(3).name.endswith("-noiso.npz")  # the mask rule is not used at all


def test_room_share_picks_a_fixed_share_of_seeds_and_keys_their_cache():
    from vt4dcodec.model.train import data

    pool = data.ScenePool(Path("/nonexistent"), 2, 4, 32, 8, 8, room_share=0.5)
    styles = [pool.style(seed) for seed in range(400)]
    assert 0.4 < styles.count("room") / 400 < 0.6
    assert styles == [data.ScenePool(Path("/x"), 3, 8, 64, 16, 8, room_share=0.5).style(s) for s in range(400)]
    grown = data.ScenePool(Path("/nonexistent"), 2, 4, 32, 8, 8, room_share=0.8)
    assert all(grown.style(s) == "room" for s in range(400) if styles[s] == "room")  # a larger share adds seeds
    assert {data.ScenePool(Path("/n"), 2, 4, 32, 8, 8).style(s) for s in range(50)} == {"objects"}
    room = next(s for s in range(400) if styles[s] == "room")
    objects = next(s for s in range(400) if styles[s] == "objects")
    assert pool._stem(room).startswith("room-train-") and pool._stem(objects).startswith("train-")
    with pytest.raises(ValueError, match="room-share"):
        data.ScenePool.for_config(None, Path("/n"), 2, room_share=1.5)  # checked before the config is read


def test_closeup_share_takes_objects_seeds_and_leaves_the_room_seeds():
    from vt4dcodec.model.train import data

    room = data.ScenePool(Path("/n"), 2, 4, 32, 8, 8, room_share=0.25)
    both = data.ScenePool(Path("/n"), 2, 4, 32, 8, 8, room_share=0.25, closeup_share=0.3)
    before, after = [room.style(s) for s in range(600)], [both.style(s) for s in range(600)]
    assert all(a == "room" for b, a in zip(before, after) if b == "room")  # room scenes stay room scenes
    assert all(b == "objects" for b, a in zip(before, after) if a == "closeup")
    assert 0.22 < after.count("closeup") / 600 < 0.38
    closeup = after.index("closeup")
    assert both._stem(closeup).startswith("closeup-train-")
    with pytest.raises(ValueError, match="closeup-share"):
        data.ScenePool.for_config(None, Path("/n"), 2, room_share=0.8, closeup_share=0.3)


def test_stage2_trains_on_room_scenes(runs, tmp_path):
    out = tmp_path / "tok-room"
    assert stage2.main(["--autoencoder", str(runs / "ae/autoencoder.safetensors"), "--out", str(out),
                        "--steps", "2", "--batch-size", "2", "--samples", "1", "--cache", str(tmp_path / "cache"),
                        "--room-share", "1", *common(2)]) == 0
    cached = sorted(p.name for p in (tmp_path / "cache").glob("scene-*.npz"))
    assert cached and all(name.startswith("scene-room-") for name in cached)


def test_stage2_continues_a_saved_model_with_init(runs, tmp_path):
    """--init: a saved model (weights and frozen autoencoder) is the start, no --autoencoder needed."""
    assert stage2.main(["--autoencoder", str(runs / "ae/autoencoder.safetensors"), "--out", str(tmp_path / "first"),
                        "--steps", "1", "--batch-size", "2", "--samples", "1", "--cache", str(runs / "cache"),
                        *COMMON]) == 0
    start = tmp_path / "first" / "model"
    out = tmp_path / "cont"
    assert stage2.main(["--init", str(start), "--out", str(out), "--steps", "1", "--batch-size", "2",
                        "--samples", "1", "--cache", str(runs / "cache"), "--lr", "0", "--warmup", "1",
                        *COMMON]) == 0
    before, after = from_pretrained(start), from_pretrained(out / "model")
    assert all(torch.equal(a, b) for a, b in zip(before.state_dict().values(), after.state_dict().values()))
    with pytest.raises(ModelError, match="config differs"):
        stage2.main(["--init", str(start), "--out", str(tmp_path / "x"), "--steps", "1",
                     "--cache", str(runs / "cache"), *COMMON, "renderer_layers=2"])
    with pytest.raises(SystemExit):  # neither --init nor --autoencoder
        stage2.main(["--out", str(tmp_path / "y"), "--steps", "1", "--cache", str(runs / "cache"), *COMMON])


def test_stage2_from_scratch_on_a_saved_models_autoencoder(runs, tmp_path):
    """--autoencoder-from: a fresh tokenizer on the frozen autoencoder of a saved model; one start flag only."""
    first = tmp_path / "first"
    assert stage2.main(["--autoencoder", str(runs / "ae/autoencoder.safetensors"), "--out", str(first),
                        "--steps", "1", "--batch-size", "2", "--samples", "1", "--cache", str(runs / "cache"),
                        *COMMON]) == 0
    out = tmp_path / "scratch"
    assert stage2.main(["--autoencoder-from", str(first / "model"), "--out", str(out), "--steps", "1",
                        "--batch-size", "2", "--samples", "1", "--cache", str(runs / "cache"), "--lr", "0",
                        "--warmup", "1", "--seed", "7", "--tau-one", "1", *COMMON, "unified_tokens=true"]) == 0
    saved, fresh = from_pretrained(first / "model"), from_pretrained(out / "model")
    assert fresh.config.unified_tokens and not saved.config.unified_tokens
    # a renderer trained at tau = 1 only is saved to decode in one step; one trained at all flow times keeps 8
    assert (fresh.decode_steps, saved.decode_steps) == (1, 8)
    a, b = saved.state_dict(), fresh.state_dict()
    assert all(torch.equal(a[k].float(), b[k].float()) for k in b if k.startswith("autoencoder."))
    assert not torch.equal(a["spatial_branch.queries"][:4], b["spatial_branch.queries"][:4])  # fresh weights
    with pytest.raises(ModelError, match="autoencoder does not fit"):
        stage2.main(["--autoencoder-from", str(first / "model"), "--out", str(tmp_path / "x"), "--steps", "1",
                     "--cache", str(runs / "cache"), *COMMON, "ae_width=4"])
    with pytest.raises(SystemExit):  # two starts
        stage2.main(["--init", str(first / "model"), "--autoencoder-from", str(first / "model"),
                     "--out", str(tmp_path / "y"), "--steps", "1", "--cache", str(runs / "cache"), *COMMON])


def test_stage2_init_partial_keeps_the_saved_decode_steps_and_samples_0_draws_none(runs, tmp_path):
    """Regressions: ``--samples 0`` crashed after training (an empty batch of sample pairs), and a partial warm
    start took the fresh model's 8 decode steps where the saved model decodes in 1 (render feedback renders
    the first tokens as the decoder does, in training too)."""
    first = tmp_path / "first"
    assert stage2.main(["--autoencoder", str(runs / "ae/autoencoder.safetensors"), "--out", str(first),
                        "--steps", "1", "--batch-size", "2", "--samples", "0", "--tau-one", "1",
                        "--cache", str(runs / "cache"), *COMMON]) == 0
    assert not (first / "samples.png").exists() and (first / "model").is_dir()
    assert "pairs" not in json.loads((first / "summary.json").read_text())
    saved = from_pretrained(first / "model")
    assert saved.decode_steps == 1
    partial = stage2.warm_start_model(saved.config.replace(render_patch_size=2), str(first / "model"), partial=True)
    assert partial.decode_steps == 1
    with pytest.raises(SystemExit):
        stage2.main(["--init", str(first / "model"), "--out", str(tmp_path / "x"), "--steps", "1",
                     "--samples", "-1", "--cache", str(runs / "cache"), *COMMON])


def test_stage2_init_partial_copies_what_fits_and_trains_multi_camera_batches(runs, tmp_path):
    """--init-partial: a renderer with smaller patches starts from a saved model's other tensors; with
    --multi-share 1 every batch encodes several cameras, and --pixel-weight adds the decoded-pixel loss."""
    first = tmp_path / "first"
    assert stage2.main(["--autoencoder", str(runs / "ae/autoencoder.safetensors"), "--out", str(first),
                        "--steps", "1", "--batch-size", "2", "--samples", "1", "--cache", str(runs / "cache"),
                        *COMMON]) == 0
    out = tmp_path / "p2"
    assert stage2.main(["--init", str(first / "model"), "--init-partial", "--out", str(out), "--steps", "1",
                        "--batch-size", "2", "--samples", "1", "--cache", str(runs / "cache"), "--lr", "0",
                        "--warmup", "1", "--recon-share", "0.5", "--multi-share", "1", "--multi-views", "2",
                        "--pixel-weight", "1", "--ssim-weight", "0.5", *COMMON, "render_patch_size=2"]) == 0
    before, after = from_pretrained(first / "model"), from_pretrained(out / "model")
    assert after.config.renderer_patch == 2 and before.config.renderer_patch == after.config.patch_size
    old, new = before.state_dict(), after.state_dict()
    fresh = {k for k in new if k not in old or old[k].shape != new[k].shape}
    assert fresh == {"renderer.embed.weight", "renderer.pos_space", "renderer.out.weight", "renderer.out.bias"}
    assert all(torch.equal(old[k], new[k]) for k in new if k not in fresh)
    log = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert log and "pixel_mse" in log[-1] and log[-1]["pixel_mse"] > 0 and 0 < log[-1]["ssim"] < 1
    with pytest.raises(SystemExit):  # multi-camera batches need sampled targets
        stage2.main(["--init", str(first / "model"), "--out", str(tmp_path / "m"), "--steps", "1",
                     "--cache", str(runs / "cache"), "--multi-share", "0.5", *COMMON])
    with pytest.raises(SystemExit):  # the cell loss trains the token splat: a model without it refuses
        stage2.main(["--init", str(first / "model"), "--out", str(tmp_path / "c"), "--steps", "1",
                     "--cache", str(runs / "cache"), "--cell-weight", "1", *COMMON])
    splat = tmp_path / "splat"
    assert stage2.main(["--init", str(first / "model"), "--init-partial", "--out", str(splat), "--steps", "1",
                        "--batch-size", "2", "--samples", "1", "--cache", str(runs / "cache"), "--cell-weight", "1",
                        *COMMON, "locality_sigma=0.35", "project_anchors=true", "prediction=x0",
                        "token_splat=true"]) == 0
    log = [json.loads(line) for line in (splat / "log.jsonl").read_text().splitlines()]
    assert log[-1]["cell_mse"] > 0 and from_pretrained(splat / "model").config.token_splat


def test_stage2_trains_the_dynamic_splat_from_a_run_directory_with_the_track_and_patch_losses(runs, tmp_path):
    """--init RUN (a training run's checkpoint directory, as under checkpoints/) with --init-partial grows
    the dynamic splat; --track-weight trains it from the synthetic depth, --patch-weight its content, and
    both are refused without it."""
    splat = ["prediction=x0", "locality_sigma=0.35", "project_anchors=true", "token_splat=true", "pixel_splat=true"]
    first = tmp_path / "first"
    assert stage2.main(["--autoencoder", str(runs / "ae/autoencoder.safetensors"), "--out", str(first),
                        "--steps", "1", "--batch-size", "2", "--samples", "1", "--cache", str(runs / "cache"),
                        *COMMON, *splat]) == 0
    for flag in ("--track-weight", "--patch-weight"):
        with pytest.raises(SystemExit):
            stage2.main(["--init", str(first), "--out", str(tmp_path / "x"), "--steps", "1", flag, "0.1",
                         "--cache", str(runs / "cache"), *COMMON, *splat])
    out = tmp_path / "dyn"
    assert stage2.main(["--init", str(first), "--init-partial", "--out", str(out), "--steps", "2", "--batch-size", "2",
                        "--samples", "1", "--cache", str(runs / "cache"), "--track-weight", "0.1",
                        "--patch-weight", "0.2", *COMMON, *splat, "dynamic_splat=2"]) == 0
    logs = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert logs[-1]["track_loss"] > 0 and logs[-1]["track_px"] > 0 and logs[-1]["patch_mse"] > 0
    model = from_pretrained(out / "model")
    assert model.config.dynamic_splat == 2 and float(model.renderer.dynamic_gate.detach()) != 0.0  # the gate trained


def test_lr_scale_puts_the_named_parameters_in_their_own_group_and_the_loop_scales_their_rate():
    from vt4dcodec.model import VideoTok4D, get_config
    from vt4dcodec.model.train.tokenizer import parameter_groups

    net = VideoTok4D(get_config("tiny", frames=4, image_size=32, width=32, heads=2, ae_width=8, n_static=8,
                                n_dynamic=4, token_dim=8, n_tracks=8))
    net.freeze_autoencoder()
    groups = parameter_groups(net, "renderer.out=10, temporal_branch.queries=2")
    assert [g["lr_scale"] for g in groups] == [1.0, 2.0, 10.0]
    assert groups[2]["params"] == [net.renderer.out.weight, net.renderer.out.bias]
    assert sum(len(g["params"]) for g in groups) == len(net.tokenizer_parameters())
    assert len(parameter_groups(net, "")) == 1
    for bad in ("renderer.out", "renderer.out=0", "=3", "renderer.out=x", "autoencoder.=2"):
        with pytest.raises(ModelError, match="--lr-scale"):
            parameter_groups(net, bad)


def test_train_only_freezes_every_other_parameter_and_gradients_still_reach_the_trained_ones():
    from vt4dcodec.model import VideoTok4D, get_config
    from vt4dcodec.model.train.tokenizer import parameter_groups

    net = VideoTok4D(get_config("tiny", frames=4, image_size=32, width=32, heads=2, ae_width=8, n_static=8,
                                n_dynamic=4, token_dim=8, n_tracks=8, entropy_levels=2))
    net.freeze_autoencoder()
    groups = parameter_groups(net, "entropy.=20", "entropy.")
    trained = [p for g in groups for p in g["params"]]
    assert [g["lr_scale"] for g in groups] == [20.0]
    assert {id(p) for p in trained} == {id(net.entropy.logits), id(net.entropy.log_step)}
    assert all(p.requires_grad == (id(p) in {id(q) for q in trained}) for p in net.tokenizer_parameters())
    for bad in ("renderer.nothing", "autoencoder."):
        with pytest.raises(ModelError, match="--train-only"):
            parameter_groups(net, "", bad)


def test_slim_checkpoint_keeps_what_changed_and_restores_only_on_its_base(tmp_path):
    """slim_checkpoint: a run that changed part of a saved model is committed as the changed tensors plus the
    base's name and digest; it restores to the same weights, and onto other weights it is refused."""
    from vt4dcodec.model import VideoTok4D, get_config, save_pretrained
    from vt4dcodec.model.train.common import load_checkpoint, save_checkpoint, slim_checkpoint

    cfg = get_config("tiny", frames=4, image_size=32, width=32, heads=2, ae_width=8, n_static=8, n_dynamic=4,
                     token_dim=8, n_tracks=8, entropy_levels=2)
    torch.manual_seed(0)
    base = VideoTok4D(cfg)
    save_pretrained(base, tmp_path / "base", model_id="t", model_version="0")
    run = VideoTok4D(cfg)
    run.load_state_dict(from_pretrained(tmp_path / "base").state_dict())
    with torch.no_grad():
        run.entropy.log_step.add_(0.25)
    opt = torch.optim.SGD([run.entropy.log_step], lr=0.1)
    save_checkpoint(tmp_path / "run" / "checkpoint", run, opt, 7, {"config": cfg.to_dict()})
    kept, taken = slim_checkpoint(tmp_path / "run", str(tmp_path / "base"), tmp_path / "slim")
    assert kept >= 1 and taken > 50
    restored = VideoTok4D(cfg)
    assert load_checkpoint(tmp_path / "slim" / "checkpoint", restored, None)["step"] == 7
    for key, value in run.state_dict().items():
        assert torch.equal(restored.state_dict()[key], value), key
    torch.manual_seed(1)
    save_pretrained(VideoTok4D(cfg), tmp_path / "base", model_id="t", model_version="0")  # other weights
    with pytest.raises(ModelError, match="not the ones the run started from"):
        load_checkpoint(tmp_path / "slim" / "checkpoint", VideoTok4D(cfg), None)


def test_time_budget_stops_checkpoints_and_a_rerun_continues_to_steps(runs, tmp_path):
    """``--time-budget`` (a lent accelerator's fixed wall clock): the loop stops at the first step past
    the budget with a complete checkpoint and a saved model, and the same command without it resumes."""
    out = tmp_path / "tok"
    args = ["--autoencoder", str(runs / "ae/autoencoder.safetensors"), "--out", str(out), "--steps", "4",
            "--batch-size", "2", "--samples", "1", "--cache", str(runs / "cache"), *COMMON]
    assert stage2.main([*args, "--time-budget", "0", "--device", "auto"]) == 0
    assert json.loads((out / "checkpoint/state.json").read_text())["step"] == 1
    assert json.loads((out / "summary.json").read_text())["steps"] == 1
    assert from_pretrained(out / "model").config.n_static == 8
    assert stage2.main(args) == 0
    assert [json.loads(line)["step"] for line in (out / "log.jsonl").read_text().splitlines()] == [1, 2, 3, 4]


def test_stop_at_checkpoints_that_step_and_a_rerun_continues_on_the_same_schedule(runs, tmp_path):
    """``--stop-at STEP`` (to switch a flag mid-run, as the Table 5 ablations do at step 600): the loop stops
    after that step with a complete checkpoint and model, the learning rate follows --steps' schedule, and
    the command without it (or with a step already passed) resumes to --steps."""
    out = tmp_path / "tok"
    args = ["--autoencoder", str(runs / "ae/autoencoder.safetensors"), "--out", str(out), "--steps", "4",
            "--batch-size", "2", "--samples", "1", "--cache", str(runs / "cache"), *COMMON]
    assert stage2.main([*args, "--stop-at", "2"]) == 0
    assert json.loads((out / "checkpoint/state.json").read_text())["step"] == 2
    assert from_pretrained(out / "model").config.n_static == 8
    assert stage2.main([*args, "--stop-at", "2"]) == 0  # already there: nothing more is trained
    assert json.loads((out / "checkpoint/state.json").read_text())["step"] == 2
    assert stage2.main(args) == 0
    records = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records] == [1, 2, 3, 4]
    reference = tmp_path / "ref"
    assert stage2.main([a if a != str(out) else str(reference) for a in args]) == 0
    expected = [json.loads(line)["lr"] for line in (reference / "log.jsonl").read_text().splitlines()]
    assert [r["lr"] for r in records] == pytest.approx(expected)
    with pytest.raises(ModelError, match="--stop-at"):
        stage2.main([*args, "--stop-at", "0"])


def test_device_flag_refuses_cuda_where_there_is_none_and_names_the_flag(runs, tmp_path, capsys):
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    with pytest.raises(SystemExit):
        stage2.main(["--autoencoder", str(runs / "ae/autoencoder.safetensors"), "--out", str(tmp_path / "x"),
                     "--steps", "1", "--device", "cuda", *COMMON])
    assert "--device cuda" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        stage2.main(["--autoencoder", str(runs / "ae/autoencoder.safetensors"), "--out", str(tmp_path / "y"),
                     "--steps", "1", "--prefill-workers", "-1", *COMMON])


def test_to_device_moves_every_tensor_of_a_pair_batch_and_leaves_the_input_alone(runs):
    from vt4dcodec.model.train.common import to_device
    from vt4dcodec.model.train.data import PairDataset, ScenePool, collate_pairs

    pool = ScenePool(runs / "cache", cameras=2, frames=4, image_size=32, latent_size=8, n_tracks=8)
    batch = collate_pairs([PairDataset(pool, [0])[i] for i in range(2)])
    moved = to_device(batch, torch.device("meta"))
    tensors = [moved.target_frames, moved.K_tgt, moved.w2c_tgt, moved.source.frames, moved.source.K,
               moved.source.track_xy, moved.source.track_valid]
    assert all(t.device.type == "meta" for t in tensors)
    assert moved.source.views == batch.source.views and moved.target_frames.shape == batch.target_frames.shape
    assert batch.target_frames.device.type == "cpu" and batch.source.frames.device.type == "cpu"


def test_prefill_scenes_builds_the_cache_in_worker_processes_once(tmp_path):
    from vt4dcodec.model.train.data import ScenePool, prefill_scenes

    pool = ScenePool(tmp_path, cameras=2, frames=4, image_size=32, latent_size=8, n_tracks=8)
    prefill_scenes(pool, [0, 1], workers=2)
    files = sorted(p.name for p in tmp_path.iterdir())
    assert len([f for f in files if f.startswith("scene-")]) == 2 and len([f for f in files if f.startswith("prep")]) == 2
    stamps = {p: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    prefill_scenes(pool, [0, 1], workers=1)  # cached: read back, not rebuilt
    assert {p: p.stat().st_mtime_ns for p in tmp_path.iterdir()} == stamps
    with pytest.raises(ValueError):
        prefill_scenes(pool, [0], workers=0)


def test_stored_tokens_are_the_values_a_file_stores_at_the_level():
    """--stored-levels trains the renderer on what the decoder reads: each scene's tokens at a level are the
    values a learned-rans payload of them decodes to (dead zones and frame-copy differences included)."""
    from vt4dcodec.format.learned import decode_learned_tokens, encode_learned_tokens
    from vt4dcodec.codec import model_tables
    from vt4dcodec.model.train.tokenizer import stored_tokens

    net = from_pretrained("vt4d-tiny")
    tables = model_tables(net)
    gen = torch.Generator().manual_seed(3)
    z_s = torch.tanh(torch.randn((2, *net.config.static_shape), generator=gen))
    z_d = torch.tanh(torch.randn((2, *net.config.dynamic_shape), generator=gen))
    for level, views in ((0, 1), (4, 3), (tables.steps.shape[0] - 1, 5)):
        s, d = stored_tokens(tables, level, z_s, z_d, views)
        for values, z, which in ((s, z_s, "static"), (d, z_d, "dynamic")):
            for item in range(2):
                payload = encode_learned_tokens(z[item].numpy(), tables, level, views, which)
                decoded, stored_level = decode_learned_tokens(payload, tables, *z.shape[1:], which, views)
                assert stored_level == level
                assert np.array_equal(values[item].detach().numpy(), decoded), (level, views, which)
    leaf = z_s.clone().requires_grad_(True)
    stored_tokens(tables, 0, leaf, z_d, 1)[0].sum().backward()  # straight through to the encoder's tokens
    assert torch.equal(leaf.grad, torch.ones_like(leaf))


def test_stored_levels_trains_the_renderer_alone_and_keeps_the_frozen_tables(tmp_path):
    """A renderer fine-tune on stored tokens (--config init --train-only renderer. --stored-levels): the encoder,
    autoencoder and entropy tables of the saved model come out bit for bit, only renderer tensors move, and the
    flags refuse what they cannot do."""
    from vt4dcodec.model import VideoTok4D, get_config, save_pretrained

    cfg = get_config("tiny", **parse_overrides(SMALL), entropy_levels=2)
    torch.manual_seed(0)
    base = VideoTok4D(cfg)
    base.freeze_autoencoder()
    base.update_entropy()
    save_pretrained(base, tmp_path / "base", model_id="t", model_version="0", storage_dtype="float16")
    args = ["--init", str(tmp_path / "base"), "--config", "init", "--train-only", "renderer.", "--steps", "2",
            "--batch-size", "2", "--cache", str(tmp_path / "cache"), "--samples", "1", "--scenes", "1",
            "--cameras", "2", "--workers", "0", "--log-every", "1", "--no-progress", "--warmup", "1",
            "--recon-share", "0.5"]
    assert stage2.main([*args, "--out", str(tmp_path / "run"), "--stored-levels", "1,3"]) == 0
    before = from_pretrained(tmp_path / "base").state_dict()
    after = from_pretrained(tmp_path / "run" / "model").state_dict()
    moved = {k for k in before if not torch.equal(before[k], after[k])}
    assert moved and all(k.startswith("renderer.") for k in moved), sorted(moved)[:5]
    # exported from its checkpoint (e.g. a slim one committed), the run keeps the base's tables too
    from vt4dcodec.model.train import export_run

    assert export_run.main(["--run", str(tmp_path / "run"), "--out", str(tmp_path / "exported"), "--id", "t",
                            "--version", "1"]) == 0
    exported = from_pretrained(tmp_path / "exported").state_dict()
    assert all(torch.equal(exported[k], after[k]) for k in after)
    levels = [json.loads(line)["level"] for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    assert len(levels) == 2 and set(levels) <= {0.0, 1.0}
    for bad in (["--stored-levels", "1"], ["--stored-levels", "0,0"], ["--stored-levels", "1,x"],
                ["--stored-levels", "1,1", "--rate-lambdas", "1,1"],
                ["--stored-levels", "1,1", "--repeat-feedback", "0.5"],  # not without --init-partial
                ["--stored-levels", "1,1", "--init-partial", "--repeat-feedback", "nan"]):
        with pytest.raises(SystemExit):
            stage2.main([*args, "--out", str(tmp_path / "bad"), *bad])
    unfrozen = VideoTok4D(cfg)
    save_pretrained(unfrozen, tmp_path / "unfrozen", model_id="t", model_version="0")
    with pytest.raises(SystemExit):
        stage2.main([*args[2:], "--init", str(tmp_path / "unfrozen"), "--out", str(tmp_path / "bad2"),
                     "--stored-levels", "1,1"])
