"""Weights I/O: safetensors + config.json round trip, fingerprint, from_pretrained errors."""

from __future__ import annotations

import json
import os

import pytest
import torch

from vt4dcodec.errors import ModelError, ModelNotFoundError
from vt4dcodec.model import VideoTok4D, from_pretrained, get_config, save_pretrained
from vt4dcodec.model.identity import fingerprint_fields, weights_sha256
from vt4dcodec.model.weights_io import model_directory

from network_fixtures import random_batch

torch.set_num_threads(1)
CFG = get_config("tiny", width=64, heads=2, renderer_layers=1, spatial_layers=1, track_layers=1,
                 static_query_layers=1, ae_width=8)


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    torch.manual_seed(0)
    model = VideoTok4D(CFG)
    out = save_pretrained(model, tmp_path_factory.mktemp("m") / "vt4d-test", model_id="vt4d-test",
                          model_version="0.1", card="# test card\n")
    return model.eval(), out


def test_round_trip_gives_identical_tokens_and_frames(saved):
    model, path = saved
    assert sorted(p.name for p in path.iterdir()) == ["MODEL_CARD.md", "config.json", "model.safetensors"]
    loaded = from_pretrained(path)
    assert loaded.config == CFG and loaded.model_id == "vt4d-test"
    assert all(not p.requires_grad for p in loaded.autoencoder.parameters())
    batch = random_batch(CFG, B=1)
    za, zb = model.encode(batch), loaded.encode(batch)
    assert torch.equal(za[0], zb[0]) and torch.equal(za[1], zb[1])
    fa = model.render(*za, batch.K, batch.w2c, steps=2, seed=3)
    fb = loaded.render(*zb, batch.K, batch.w2c, steps=2, seed=3)
    assert torch.equal(fa, fb)


def test_fingerprint_hashes_config_and_weights(saved):
    model, path = saved
    fields = fingerprint_fields(model, "vt4d-test", "0.1")
    meta = json.loads((path / "config.json").read_text())
    assert fields["config_sha256"] == CFG.sha256() == meta["config_sha256"]
    assert fields["weights_sha256"] == meta["weights_sha256"]
    assert fields["static_shape"] == (64, 32) and fields["dynamic_shape"] == (32, 32)
    fp = model.fingerprint("vt4d-test", "0.1")
    assert fp.weights_sha256 == fields["weights_sha256"] and fp.static_shape == (64, 32)
    state = {k: v.clone() for k, v in model.state_dict().items()}
    state["renderer.out.bias"][0] += 1e-7  # one changed weight changes the hash
    assert weights_sha256(state) != fields["weights_sha256"]


def test_model_found_by_id_through_model_path(saved, tmp_path, monkeypatch):
    """$VT4D_MODEL_PATH: os.pathsep-separated roots whose subdirectories are found by their name."""
    _, path = saved
    with pytest.raises(ModelNotFoundError, match="VT4D_MODEL_PATH"):
        from_pretrained(path.name)
    monkeypatch.setenv("VT4D_MODEL_PATH", os.pathsep.join([str(tmp_path), str(path.parent)]))
    assert model_directory(path.name) == path and from_pretrained(path.name).model_id == "vt4d-test"


def test_unknown_ids_and_paths_raise_model_not_found(tmp_path):
    with pytest.raises(ModelNotFoundError):
        from_pretrained("vt4d-does-not-exist")
    with pytest.raises(ModelNotFoundError):
        from_pretrained(tmp_path / "missing")
    with pytest.raises(ModelNotFoundError):
        from_pretrained(tmp_path)  # a directory without model files


def _copy(path, tmp_path):
    out = tmp_path / "copy"
    out.mkdir()
    for name in ("config.json", "model.safetensors"):
        (out / name).write_bytes((path / name).read_bytes())
    return out


@pytest.mark.parametrize("damage", ["truncate", "flip", "json", "config", "shape", "format"])
def test_damaged_files_raise_model_error(saved, tmp_path, damage):
    _, path = saved
    out = _copy(path, tmp_path)
    weights, config = out / "model.safetensors", out / "config.json"
    meta = json.loads(config.read_text())
    if damage == "truncate":
        weights.write_bytes(weights.read_bytes()[:1000])
    elif damage == "flip":
        data = bytearray(weights.read_bytes())
        data[-5] ^= 0xFF
        weights.write_bytes(bytes(data))
    elif damage == "json":
        config.write_text("{not json")
    elif damage == "config":
        meta["config"]["width"] = 96  # hash no longer matches
        config.write_text(json.dumps(meta))
    elif damage == "shape":
        meta["config"]["width"] = 96
        meta["config_sha256"] = type(CFG).from_dict(meta["config"]).sha256()
        config.write_text(json.dumps(meta))  # consistent config, weights of the wrong shape
    elif damage == "format":
        meta["format"] = "something-else"
        config.write_text(json.dumps(meta))
    with pytest.raises(ModelError):
        from_pretrained(out)


def test_float16_storage_halves_the_file_and_loads_the_same_model(tmp_path):
    torch.manual_seed(1)
    model = VideoTok4D(CFG).eval()
    full = save_pretrained(model, tmp_path / "fp32", model_id="m", model_version="1")
    half = save_pretrained(model, tmp_path / "fp16", model_id="m", model_version="1", storage_dtype="float16")
    size = lambda d: (d / "model.safetensors").stat().st_size  # noqa: E731
    assert size(half) < 0.6 * size(full)
    loaded = from_pretrained(half)
    assert all(p.dtype == torch.float32 for p in loaded.parameters())
    # the in-memory model was rounded to float16 values, so it and the loaded one are identical
    assert weights_sha256(loaded.state_dict()) == weights_sha256(model.state_dict())
    assert loaded.fingerprint("m", "1").matches(model.fingerprint("m", "1"))
    batch = random_batch(CFG, B=1)
    assert torch.equal(model.encode(batch)[0], loaded.encode(batch)[0])
    with pytest.raises(ModelError, match="storage_dtype"):
        save_pretrained(model, tmp_path / "x", model_id="m", model_version="1", storage_dtype="int8")


def test_decode_steps_are_recorded_per_model_outside_the_hash(tmp_path):
    torch.manual_seed(0)
    model = VideoTok4D(CFG)
    one = from_pretrained(save_pretrained(model, tmp_path / "one", model_id="t", model_version="1", decode_steps=1))
    eight = from_pretrained(save_pretrained(model, tmp_path / "eight", model_id="t", model_version="1"))
    assert one.decode_steps == 1 and eight.decode_steps == 8
    meta = json.loads((tmp_path / "one" / "config.json").read_text())
    assert meta["decode_steps"] == 1 and one.fingerprint("t", "1") == eight.fingerprint("t", "1")
    batch = random_batch(CFG, B=1)
    z = one.encode(batch)
    assert torch.equal(one.render(*z, batch.K, batch.w2c, seed=2), eight.render(*z, batch.K, batch.w2c, steps=1, seed=2))
    del meta["decode_steps"]  # directories written before the field existed decode with 8 steps
    (tmp_path / "one" / "config.json").write_text(json.dumps(meta))
    assert from_pretrained(tmp_path / "one").decode_steps == 8
    for bad in (0, -1, 1.5, True, "8", 10**6):
        meta["decode_steps"] = bad
        (tmp_path / "one" / "config.json").write_text(json.dumps(meta))
        with pytest.raises(ModelError, match="decode_steps"):
            from_pretrained(tmp_path / "one")
    with pytest.raises(ModelError, match="decode_steps"):
        save_pretrained(model, tmp_path / "bad", model_id="t", model_version="1", decode_steps=0)
