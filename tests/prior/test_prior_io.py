"""Prior weights I/O: safetensors + prior.json, hash verification, the tokenizer binding."""

from __future__ import annotations

import json
import os

import pytest
import torch

from co4dgen_helpers import random_condition, small_prior
from vt4dcodec.errors import ModelError, ModelMismatchError, ModelNotFoundError
from vt4dcodec.format import ModelFingerprint
from vt4dcodec.model.prior import check_tokenizer
from vt4dcodec.model.weights_io import load_prior, save_prior

FP = ModelFingerprint(model_id="tok", model_version="1", config_sha256="a" * 64, weights_sha256="b" * 64,
                      static_shape=(8, 8), dynamic_shape=(4, 8))


def test_save_load_round_trip_gives_identical_samples(tmp_path):
    prior = small_prior(scramble=True)
    prior.set_token_statistics(torch.rand(3, 8, 8) - 0.5, torch.rand(3, 4, 8) - 0.5)
    save_prior(prior, tmp_path / "p", model_id="p-test", model_version="2", tokenizer=FP, card="# card\n")
    loaded = load_prior(tmp_path / "p")
    assert (loaded.model_id, loaded.model_version) == ("p-test", "2")
    assert loaded.tokenizer_fingerprint == FP and loaded.config == prior.config
    cond = random_condition()
    a, b = prior.sample(cond, steps=2, seed=4), loaded.sample(cond, steps=2, seed=4)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    assert (tmp_path / "p" / "MODEL_CARD.md").read_text() == "# card\n"


def test_damaged_or_foreign_prior_files_are_refused(tmp_path):
    prior = small_prior()
    d = save_prior(prior, tmp_path / "p", model_id="p", model_version="1", tokenizer=FP)
    meta = json.loads((d / "prior.json").read_text())
    with pytest.raises(ModelNotFoundError):
        load_prior(tmp_path / "missing")
    with pytest.raises(ModelNotFoundError):
        load_prior("no-such-prior")
    # flipped weight byte -> hash mismatch
    raw = bytearray((d / "prior.safetensors").read_bytes())
    raw[-3] ^= 0x40
    (d / "prior.safetensors").write_bytes(bytes(raw))
    with pytest.raises(ModelError):
        load_prior(d)
    save_prior(prior, d, model_id="p", model_version="1", tokenizer=FP)
    for bad in ({**meta, "format": "vt4d-model/1"}, {**meta, "config_sha256": "0" * 64},
                {**meta, "tokenizer": {"model_id": "x"}}, {**meta, "config": {**meta["config"], "width": 64}}):
        (d / "prior.json").write_text(json.dumps(bad))
        with pytest.raises(ModelError):
            load_prior(d)
    (d / "prior.json").write_text("{not json")
    with pytest.raises(ModelError):
        load_prior(d)


def test_prior_found_by_id_through_model_path(tmp_path, monkeypatch):
    """$VT4D_MODEL_PATH finds priors by directory name, as it finds tokenizers (the one lookup of weights_io)."""
    from vt4dcodec.generate import load_prior_model

    save_prior(small_prior(), tmp_path / "models" / "p-user", model_id="p-user", model_version="3", tokenizer=FP)
    with pytest.raises(ModelNotFoundError, match="VT4D_MODEL_PATH"):
        load_prior("p-user")
    monkeypatch.setenv("VT4D_MODEL_PATH", str(tmp_path / "elsewhere") + os.pathsep + str(tmp_path / "models"))
    assert load_prior("p-user").model_version == "3"
    assert load_prior_model("p-user").model_id == "p-user"


def test_a_prior_is_only_used_with_its_tokenizer(tmp_path):
    d = save_prior(small_prior(), tmp_path / "p", model_id="p", model_version="1", tokenizer=FP)
    prior = load_prior(d)
    check_tokenizer(prior, FP)
    other = ModelFingerprint(**{**FP.to_dict(), "weights_sha256": "c" * 64})
    with pytest.raises(ModelMismatchError, match="trained on tokens of tok@1"):
        check_tokenizer(prior, other)
    check_tokenizer(prior, other, force=True)  # same shapes: allowed when forced
    wrong_shape = ModelFingerprint(**{**FP.to_dict(), "static_shape": (9, 8)})
    with pytest.raises(ModelMismatchError):
        check_tokenizer(prior, wrong_shape, force=True)
    with pytest.raises(ModelMismatchError):
        check_tokenizer(small_prior(), FP)  # never loaded: no recorded tokenizer
    # a tokenizer whose networks are exactly the recorded one's (an entropy model added: other digests and
    # version) makes the same tokens: accepted when its network digests say so, refused when they do not
    grown = ModelFingerprint(**{**FP.to_dict(), "model_version": "2", "weights_sha256": "d" * 64,
                                "config_sha256": "e" * 64})
    check_tokenizer(prior, grown, networks=(FP.config_sha256, FP.weights_sha256))
    with pytest.raises(ModelMismatchError, match="trained on tokens"):
        check_tokenizer(prior, grown, networks=(FP.config_sha256, "f" * 64))
    with pytest.raises(ModelMismatchError, match="trained on tokens"):
        check_tokenizer(prior, ModelFingerprint(**{**grown.to_dict(), "model_id": "other"}),
                        networks=(FP.config_sha256, FP.weights_sha256))


def test_float16_storage_round_trips_the_same_prior(tmp_path):
    prior = small_prior(scramble=True)
    save_prior(prior, tmp_path / "full", model_id="p", model_version="1", tokenizer=FP)
    save_prior(prior, tmp_path / "half", model_id="p", model_version="1", tokenizer=FP, storage_dtype="float16")
    sizes = [(tmp_path / d / "prior.safetensors").stat().st_size for d in ("full", "half")]
    assert sizes[1] < 0.6 * sizes[0]
    loaded = load_prior(tmp_path / "half")
    cond = random_condition()
    a, b = prior.sample(cond, steps=2, seed=1), loaded.sample(cond, steps=2, seed=1)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])


def test_ship_prior_stores_float16_beside_its_tokenizer_and_refuses_another_tokenizer(tmp_path):
    from co4dgen_helpers import SMALL_TOKENIZER

    from vt4dcodec.model import VideoTok4D, get_config, save_pretrained
    from vt4dcodec.model.train.ship_prior import main, ship_prior

    torch.manual_seed(0)
    dest = tmp_path / "weights"
    save_pretrained(VideoTok4D(get_config("tiny", **SMALL_TOKENIZER)), dest / "tok", model_id="tok", model_version="3")
    tokenizer = codec_fingerprint(dest / "tok")
    prior = small_prior(scramble=True)
    run = save_prior(prior, tmp_path / "run" / "prior", model_id="p-ship", model_version="3", tokenizer=tokenizer,
                     card="# trained\n", extra={"steps": 5})
    out = ship_prior(run, dest)
    from vt4dcodec.model.train.ship_prior import ONNX_CARD_NOTE

    assert out == dest / "p-ship" and (out / "MODEL_CARD.md").read_text() == "# trained\n" + ONNX_CARD_NOTE
    shipped = load_prior(out)
    assert shipped.tokenizer_fingerprint == tokenizer
    assert json.loads((out / "prior.json").read_text())["extra"] == {"steps": 5}
    assert (out / "prior.safetensors").stat().st_size < 0.6 * (run / "prior.safetensors").stat().st_size
    for name, value in shipped.state_dict().items():  # the float16-rounded prior, nothing else changed
        assert torch.equal(value, prior.state_dict()[name].half().float()), name
    absent = ModelFingerprint.from_dict({**FP.to_dict(), "model_id": "absent"})
    other = save_prior(prior, tmp_path / "other", model_id="p-ship", model_version="3", tokenizer=absent)
    with pytest.raises(ModelError, match="not shipped"):
        ship_prior(other, dest)
    stale = save_prior(prior, tmp_path / "stale", model_id="p-ship", model_version="3",
                       tokenizer=ModelFingerprint.from_dict({**tokenizer.to_dict(), "weights_sha256": "c" * 64}))
    with pytest.raises(ModelError, match="train the prior on the shipped tokenizer"):
        ship_prior(stale, dest)
    assert main([str(stale), "--dest", str(dest)]) == 2


def codec_fingerprint(directory):
    from vt4dcodec.model.directories import meta_fingerprint, read_model_meta

    return meta_fingerprint(read_model_meta(directory))
