"""The model card is generated from a run's own records, so it cannot drift from what was trained."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from vt4dcodec.errors import ModelError
from vt4dcodec.model import VideoTok4D, get_config
from vt4dcodec.model.train.ship import model_card, reconfigure

FINGERPRINT = {"config_sha256": "c" * 64, "weights_sha256": "w" * 64, "static_shape": [64, 32],
               "dynamic_shape": [32, 32]}


def _run(tmp_path, name, **args):
    run = tmp_path / name
    (run / "checkpoint").mkdir(parents=True)
    base = {"batch_size": 8, "lr": 5e-4, "warmup": 100, "bf16": False, "scenes": 512, "scene_seed": 0,
            "cameras": 10, "recon_share": 0.5, "neighbour_sigma": 45.0, "tau_one": 1.0}
    (run / "checkpoint" / "state.json").write_text(json.dumps({"args": {**base, **args},
                                                               "config": {"prediction": "x0"}}))
    # two segments: the second resumed (elapsed restarts), so wall time adds both
    logs = [{"step": 50, "elapsed_s": 30.0, "loss": 1.0}, {"step": 100, "elapsed_s": 60.0, "loss": 0.8},
            {"step": 150, "elapsed_s": 20.0, "loss": 0.7}]
    (run / "log.jsonl").write_text("".join(json.dumps(r) + "\n" for r in logs))
    return run


def test_card_states_the_render_psnr_only_of_a_run_that_rendered_samples(tmp_path):
    """Regression: a run trained with --samples 0 (summary.json without pairs) put "render PSNR on 0 training
    pairs: nan dB (None Euler steps)" on the shipped card."""
    ae, run = _run(tmp_path, "ae"), _run(tmp_path, "tok")
    (run / "summary.json").write_text(json.dumps({"steps": 150}))
    assert "render PSNR" not in model_card("vt4d-tiny", "9.9.9", run, ae, FINGERPRINT, "")
    (run / "summary.json").write_text(json.dumps({"pairs": [{}, {}], "mean_psnr_db": 21.5, "render_steps": 1}))
    assert "render PSNR on 2 training pairs: 21.50 dB (1 Euler steps)" in model_card(
        "vt4d-tiny", "9.9.9", run, ae, FINGERPRINT, "")


def test_card_states_steps_wall_time_recipe_and_warm_start(tmp_path):
    ae = _run(tmp_path, "ae")
    fresh = model_card("vt4d-tiny", "9.9.9", _run(tmp_path, "tok"), ae, FINGERPRINT, "## Notes\nhand-written")
    assert "# vt4d-tiny 9.9.9" in fresh and "150 steps" in fresh and "1.000 -> 0.700" in fresh
    assert "2 min wall" in fresh or "1 min wall" in fresh  # 60 s + 20 s
    assert "with probability 0.5" in fresh and "exp(-angle / 45.0 deg)" in fresh and "## Notes" in fresh
    assert "warm start" not in fresh
    warm = model_card("vt4d-tiny", "9.9.9", _run(tmp_path, "tok2", init="vt4d-tiny", init_partial=True), ae,
                      FINGERPRINT, "")
    assert "warm start: the weights of vt4d-tiny" in warm and "start fresh" in warm


SMALL = dict(frames=4, image_size=32, width=32, heads=2, ae_width=8, spatial_layers=1, static_query_layers=1,
             track_layers=1, renderer_layers=1, n_static=32, n_dynamic=4, token_dim=8, n_tracks=8, patch_size=2,
             locality_sigma=0.35, project_anchors=True, prediction="x0", anchor_views=True)


def test_set_at_ship_time_keeps_the_weights_refuses_fields_that_need_new_ones_and_is_on_the_card(tmp_path):
    torch.manual_seed(0)
    model = VideoTok4D(get_config("tiny", **SMALL)).eval()
    spread = reconfigure(model, {"spread_views": True})
    assert spread.config.spread_views and not model.config.spread_views
    for name, value in model.state_dict().items():
        assert torch.equal(spread.state_dict()[name], value)
    with pytest.raises(ModelError, match="do not fit"):
        reconfigure(model, {"token_splat": True})  # adds the splat map
    with pytest.raises(ModelError, match="unknown"):
        reconfigure(model, {"no_such_field": 1})
    card = model_card("vt4d-tiny", "9.9.9", _run(tmp_path, "tok"), _run(tmp_path, "ae"), FINGERPRINT, "",
                      shipped_set={"spread_views": True})
    assert "set at ship time, no weights added (trained without them): spread_views=True" in card
    assert "spread_views=True" in card.split("- config: ")[1].splitlines()[0]


def test_without_an_autoencoder_run_the_card_carries_the_predecessors_stage_1_record(tmp_path):
    from vt4dcodec.model.train.ship import inherited_stage1_lines
    from vt4dcodec.model.weights_io import save_pretrained
    torch.manual_seed(0)
    model = VideoTok4D(get_config("tiny", **SMALL)).eval()
    shipped = save_pretrained(model, tmp_path / "weights" / "vt4d-tiny", model_id="vt4d-tiny", model_version="1.2.3",
                              storage_dtype="float16")
    (shipped / "MODEL_CARD.md").write_text("# vt4d-tiny 1.2.3\n- stage 1 autoencoder: 3000 steps, 26 min wall\n"
                                           "- decoder fine-tuned alone afterwards: 4000 steps\n- other\n")
    lines = inherited_stage1_lines(model, shipped)
    assert lines == ["- stage 1 autoencoder: 3000 steps, 26 min wall (kept from vt4d-tiny 1.2.3)",
                     "- decoder fine-tuned alone afterwards: 4000 steps (kept from vt4d-tiny 1.2.3)"]
    card = model_card("vt4d-tiny", "9.9.9", _run(tmp_path, "tok"), None, FINGERPRINT, "", stage1_lines=lines)
    assert lines[0] in card and lines[1] in card
    (shipped / "MODEL_CARD.md").write_text(card)  # shipped again from that card: the record names 1.2.3 once
    assert inherited_stage1_lines(model, shipped) == lines
    other = VideoTok4D(get_config("tiny", **SMALL)).eval()  # fresh random autoencoder: not the shipped one
    with pytest.raises(ModelError, match="not the one shipped"):
        inherited_stage1_lines(other, shipped)
    with pytest.raises(ModelError, match="no --autoencoder-run"):
        inherited_stage1_lines(model, tmp_path / "nowhere")


def test_ship_writes_float16_weights_and_a_matching_encoder_onnx_replacing_a_stale_one(tmp_path):
    from test_unified_recipe import RECIPE

    from vt4dcodec.model import save_pretrained
    from vt4dcodec.model.onnx_encoder import ONNX_FILE, OnnxEncoder
    from vt4dcodec.model.train.ship import main

    run = _run(tmp_path, "run")
    torch.manual_seed(0)
    net = VideoTok4D(get_config("tiny", **RECIPE))
    save_pretrained(net, run / "model", model_id="t", model_version="0")
    dest = tmp_path / "weights"  # a predecessor on the same frozen autoencoder, with an encoder of its weights
    save_pretrained(net, dest / "t", model_id="t", model_version="1.0.0", storage_dtype="float16")
    (dest / "t" / "MODEL_CARD.md").write_text("- stage 1 autoencoder: runs/ae (test)\n")
    (dest / "t" / ONNX_FILE).write_bytes(b"an encoder of older weights")
    assert main(["--run", str(run), "--id", "t", "--version", "2.0.0", "--dest", str(dest), "--decode-steps", "1"]) == 0
    encoder = OnnxEncoder.open(dest / "t")
    assert encoder.model_version == "2.0.0" and encoder.stored_fingerprint().model_id == "t"
    assert "2.0.0" in (dest / "t" / "MODEL_CARD.md").read_text()


def test_card_names_the_shipped_config_its_graphs_and_a_partial_run(tmp_path):
    """The config line is the shipped model's (levels added after the run show), the ONNX line lists the graphs
    written beside it, and a run that trained only some parameters says so."""
    card = model_card("vt4d-tiny", "9.9.9", _run(tmp_path, "tok", train_only="entropy."), _run(tmp_path, "ae"),
                      FINGERPRINT, "", config={"prediction": "x0", "entropy_levels": 9},
                      graphs=["renderer.onnx", "encoder-v10.onnx", "encoder.onnx", "encoder-v2.onnx"])
    assert "entropy_levels=9" in card
    assert "`encoder.onnx` ... `encoder-v10.onnx`: the encoders for scenes of 1 to 10 cameras" in card
    assert "`renderer.onnx`" in card and "trained only the parameters named 'entropy.'" in card
    plain = model_card("vt4d-tiny", "9.9.9", _run(tmp_path, "tok2"), _run(tmp_path, "ae2"), FINGERPRINT, "")
    assert "the encoder for one camera per scene" in plain and "trained only" not in plain


def test_reads_records_a_renderer_only_update_whose_predecessors_files_and_prior_stay_bound(tmp_path):
    """ship --reads: a model whose renderer alone changed records its predecessor's fingerprint (and the networks
    that one read); the predecessor's files then find their entropy tables in it, their fingerprint is accepted
    for decoding and by a prior trained on their tokens; anything but a renderer change is refused."""
    from types import SimpleNamespace

    from vt4dcodec.errors import EntropyTablesError, ModelMismatchError
    from vt4dcodec.model import from_pretrained, save_pretrained
    from vt4dcodec.model.directories import check_tokenizer, same_networks
    from vt4dcodec.model.tables import tables_from_directory
    from vt4dcodec.model.train.ship import token_sources_of

    torch.manual_seed(0)
    base = VideoTok4D(get_config("tiny", **SMALL, entropy_levels=2)).eval()
    base.freeze_autoencoder()
    base.update_entropy()
    save_pretrained(base, tmp_path / "base", model_id="t", model_version="1", storage_dtype="float16")
    old = from_pretrained(tmp_path / "base")
    old_fp = old.fingerprint("t", "1")
    new = from_pretrained(tmp_path / "base")
    with torch.no_grad():
        new.renderer.out.bias.add_(0.25)
    reads = token_sources_of(new, str(tmp_path / "base"))
    assert reads[0] == {"model_version": "1", "config_sha256": old_fp.config_sha256,
                        "weights_sha256": old_fp.weights_sha256}
    assert [(e["config_sha256"], e["weights_sha256"]) for e in reads[1:]] == [tuple(old.network_digests)]
    save_pretrained(new, tmp_path / "new", model_id="t", model_version="2", storage_dtype="float16", reads=reads)
    loaded = from_pretrained(tmp_path / "new")
    have = loaded.fingerprint("t", "2")
    assert not have.matches(old_fp) and loaded.token_sources == tuple((e["config_sha256"], e["weights_sha256"])
                                                                     for e in reads)
    assert same_networks(loaded.network_digests, have, old_fp, loaded.token_sources)
    assert not same_networks(loaded.network_digests, have, old_fp)  # without the record: a different model
    prior = SimpleNamespace(tokenizer_fingerprint=old_fp)
    check_tokenizer(prior, have, networks=loaded.network_digests, sources=loaded.token_sources)
    with pytest.raises(ModelMismatchError):
        check_tokenizer(prior, have, networks=loaded.network_digests)
    # the predecessor's learned-rans files read their tables from the update: the same arrays, under their fingerprint
    tables, own = tables_from_directory(tmp_path / "new", old_fp), tables_from_directory(tmp_path / "base", old_fp)
    assert tables.fingerprint == old_fp
    for name in ("steps", "freqs", "origins"):
        assert np.array_equal(getattr(tables, name), getattr(own, name))
    networks_fp = dataclasses.replace(old_fp, config_sha256=reads[1]["config_sha256"],
                                      weights_sha256=reads[1]["weights_sha256"])
    with pytest.raises(EntropyTablesError):  # read, but another config: not these tables
        tables_from_directory(tmp_path / "new", networks_fp)
    with pytest.raises(EntropyTablesError):
        tables_from_directory(tmp_path / "new", dataclasses.replace(old_fp, weights_sha256="0" * 64))
    # refused: an encoder tensor changed, or the config
    encoder = from_pretrained(tmp_path / "base")
    with torch.no_grad():
        encoder.static_bottleneck.proj.bias.add_(0.25)
    with pytest.raises(ModelError, match="outside renderer"):
        token_sources_of(encoder, str(tmp_path / "base"))
    with pytest.raises(ModelError, match="config"):
        token_sources_of(reconfigure(new, {"spread_views": True}), str(tmp_path / "base"))
    meta = json.loads((tmp_path / "new" / "config.json").read_text())
    meta["reads"] = [{"config_sha256": "x", "weights_sha256": "y"}]
    (tmp_path / "new" / "config.json").write_text(json.dumps(meta))
    with pytest.raises(ModelError, match="reads"):
        from_pretrained(tmp_path / "new")


FEEDBACK_READY = dict(SMALL, query_from_grid=True, token_splat=True, token_from_cell=True, frame_copies=True,
                      frame_gate_deg=8.0, view_gate_deg=40.0, pixel_splat=True, dynamic_splat=2,
                      dynamic_from_patch=True, entropy_levels=2)


def test_reads_records_render_feedback_added_to_the_encoder_and_a_prior_is_conditioned_on_its_first_pass(tmp_path):
    """ship --reads of a model that gave its predecessor's encoder render feedback: the predecessor's files find
    their entropy tables in it, and a prior trained on the predecessor's tokens is conditioned on the first pass,
    which is the predecessor's encode exactly (torch and ONNX), while the codec encodes with the feedback. A base
    that has feedback must keep it; a prior trained on the update's own tokens gets them with the feedback."""
    from types import SimpleNamespace

    from network_fixtures import orbit_cameras
    from vt4dcodec.cameras import Trajectory
    from vt4dcodec.generate import conditioning_tokens
    from vt4dcodec.model import from_pretrained, save_pretrained
    from vt4dcodec.model.onnx_export import export_model
    from vt4dcodec.model.tables import tables_from_directory
    from vt4dcodec.model.train.ship import token_sources_of

    torch.manual_seed(0)
    base = VideoTok4D(get_config("tiny", **FEEDBACK_READY)).eval()
    base.freeze_autoencoder()
    base.update_entropy()
    base.decode_steps = 1
    save_pretrained(base, tmp_path / "base", model_id="t", model_version="1", storage_dtype="float16")
    old = from_pretrained(tmp_path / "base")
    old_fp = old.fingerprint("t", "1")
    new = VideoTok4D(old.config.replace(feedback_width=16)).eval()
    new.load_state_dict(old.state_dict(), strict=False)
    new.decode_steps = 1
    for layer in (new.feedback.static[2], new.feedback.dynamic[2]):
        torch.nn.init.normal_(layer.weight, std=0.1)  # a feedback that moves the tokens
    reads = token_sources_of(new, str(tmp_path / "base"))
    assert reads[0]["config_sha256"] == old_fp.config_sha256 and reads[0]["weights_sha256"] == old_fp.weights_sha256
    save_pretrained(new, tmp_path / "new", model_id="t", model_version="2", storage_dtype="float16", reads=reads)
    for directory in (tmp_path / "base", tmp_path / "new"):
        export_model(from_pretrained(directory), directory, views=1)  # (a feedback encoder renders with the renderer)
    tables, own = tables_from_directory(tmp_path / "new", old_fp), tables_from_directory(tmp_path / "base", old_fp)
    assert tables.fingerprint == old_fp and all(np.array_equal(getattr(tables, n), getattr(own, n))
                                                for n in ("steps", "freqs", "origins"))

    cfg = old.config
    K, w2c = orbit_cameras(1, cfg.frames, cfg.image_size)
    cameras = Trajectory(K=K[0].numpy().astype(np.float64), w2c=w2c[0].numpy().astype(np.float64),
                         width=cfg.image_size, height=cfg.image_size)
    frames = np.random.default_rng(0).integers(0, 256, (cfg.frames, cfg.image_size, cfg.image_size, 3), np.uint8)
    trained_on_base = SimpleNamespace(tokenizer_fingerprint=old_fp)
    trained_on_networks = SimpleNamespace(tokenizer_fingerprint=dataclasses.replace(
        old_fp, config_sha256=old.network_digests[0], weights_sha256=old.network_digests[1]))
    for runtime in ("torch", "onnx"):
        want = conditioning_tokens(trained_on_base, frames, cameras, tmp_path / "base", runtime=runtime)
        for prior in (trained_on_base, trained_on_networks):
            got = conditioning_tokens(prior, frames, cameras, tmp_path / "new", runtime=runtime)
            assert all(np.abs(a - b).max() <= 2e-6 for a, b in zip(got, want))
        trained_on_new = SimpleNamespace(tokenizer_fingerprint=from_pretrained(tmp_path / "new").fingerprint("t", "2"))
        full = conditioning_tokens(trained_on_new, frames, cameras, tmp_path / "new", runtime=runtime)
        assert max(float(np.abs(a - b).max()) for a, b in zip(full, want)) > 1e-3  # the feedback is in the tokens

    # feedback_quality (set at ship time, no weights): files of coarser levels store the first pass -- the base's
    # tokens, so the same bytes -- and files from that level up the feedback's
    from vt4dcodec import codec
    from vt4dcodec.capture import Capture
    from vt4dcodec.format import dumps

    later = reconfigure(from_pretrained(tmp_path / "new"), {"feedback_quality": 2})
    later.decode_steps = 1
    save_pretrained(later, tmp_path / "later", model_id="t", model_version="3", storage_dtype="float16",
                    reads=token_sources_of(later, str(tmp_path / "base")))
    capture = Capture(cameras={"cam0": cameras}, frames={"cam0": frames}, fps=8.0, capture_id="c")
    for runtime in ("torch", "onnx"):
        if runtime == "onnx":
            export_model(from_pretrained(tmp_path / "later"), tmp_path / "later", views=1)
        coarse, fine = (codec.encode(capture, tmp_path / "later", quality=q, runtime=runtime) for q in (1, 2))
        first = [codec.encode(capture, tmp_path / d, quality=q, runtime=runtime) for d, q in (("base", 1), ("base", 2))]
        assert np.array_equal(coarse.static_tokens, first[0].static_tokens)
        assert np.array_equal(coarse.dynamic_tokens, first[0].dynamic_tokens)  # the same codes: only the fingerprint
        assert abs(len(dumps(coarse)) - len(dumps(first[0]))) <= 8  # differs (its compressed bytes by one or two)
        assert float(np.abs(fine.static_tokens - first[1].static_tokens).max()) > 1e-3

    # a base with render feedback is read only by models that keep it
    changed = from_pretrained(tmp_path / "new")
    with torch.no_grad():
        changed.feedback.static[2].bias.add_(0.25)
    with pytest.raises(ModelError, match="outside renderer"):
        token_sources_of(changed, str(tmp_path / "new"))
    with pytest.raises(ModelError, match="config"):  # no other config change
        token_sources_of(reconfigure(from_pretrained(tmp_path / "new"), {"spread_views": True}), str(tmp_path / "base"))
    # ... and may add to it: a further pass and the render's gradient (new tensors; the base's feedback kept)
    kept = from_pretrained(tmp_path / "new")
    grown = VideoTok4D(kept.config.replace(feedback_gradient=True, feedback_passes=2)).eval()
    assert set(grown.load_state_dict(kept.state_dict(), strict=False).missing_keys) == \
        {k for k in grown.state_dict() if k.startswith(("feedback_later.", "feedback.static_grad.", "feedback.dynamic_grad."))}
    new_fp = kept.fingerprint("t", "2")
    reads = token_sources_of(grown, str(tmp_path / "new"))
    assert reads[0]["weights_sha256"] == new_fp.weights_sha256
    save_pretrained(grown, tmp_path / "grown", model_id="t", model_version="4", storage_dtype="float16", reads=reads)
    for fp in (new_fp, old_fp):  # the files of the model it grew, and of that one's base, find their tables in it
        assert tables_from_directory(tmp_path / "grown", fp).fingerprint == fp
    with torch.no_grad():
        grown.feedback.dynamic[0].weight.mul_(1.5)
    with pytest.raises(ModelError, match="outside renderer"):
        token_sources_of(grown, str(tmp_path / "new"))
