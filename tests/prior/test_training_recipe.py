"""The prior's training recipe: the weight average, pairs anchored at the conditioning camera, and the
validation curve (sample quality between the flat-image floor and the encode's ceiling)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from torch import nn

from co4dgen_helpers import CAMERAS, EVENTS, SMALL_PRIOR
from vt4dcodec.errors import ModelError
from vt4dcodec.model import from_pretrained
from vt4dcodec.model.train.common import WeightAverage, load_checkpoint, save_checkpoint
from vt4dcodec.model.train.prior import PriorPairDataset, SampleValidation, main
from vt4dcodec.model.weights_io import load_prior


def _net(seed: int) -> nn.Module:
    torch.manual_seed(seed)
    net = nn.Sequential(nn.Linear(3, 4), nn.BatchNorm1d(4))
    return net


def test_weight_average_follows_its_formula_and_writes_into_a_model():
    net = _net(0)
    avg = WeightAverage(net, 0.9)
    start = {k: v.clone() for k, v in net.state_dict().items()}
    expected = {k: v.float().clone() for k, v in start.items() if v.is_floating_point()}
    for n in range(5):
        with torch.no_grad():
            for p in net.parameters():
                p.add_(1.0)
        avg.update(net)
        d = min(0.9, (1 + n) / (10 + n))
        for k, v in net.state_dict().items():
            if v.is_floating_point():
                expected[k] = d * expected[k] + (1 - d) * v.float()
    for k, v in expected.items():
        torch.testing.assert_close(avg.shadow[k], v)
    assert int(avg.shadow["1.num_batches_tracked"]) == int(net.state_dict()["1.num_batches_tracked"])
    other = _net(1)
    avg.copy_to(other)
    for k, v in expected.items():
        torch.testing.assert_close(other.state_dict()[k], v)
    # the average is not the last weights (they moved by +5): the test can fail
    assert not torch.allclose(other.state_dict()["0.weight"], net.state_dict()["0.weight"])


@pytest.mark.parametrize("decay", [0.0, 1.0, -0.5, 1.5])
def test_weight_average_refuses_a_decay_outside_the_open_unit_interval(decay):
    with pytest.raises(ModelError):
        WeightAverage(_net(0), decay)


def test_weight_average_is_checkpointed_and_restored(tmp_path):
    net = _net(0)
    opt = torch.optim.SGD(net.parameters(), lr=0.1)
    avg = WeightAverage(net, 0.99)
    for _ in range(3):
        with torch.no_grad():
            net[0].weight.mul_(0.5)
        avg.update(net)
    save_checkpoint(tmp_path / "ckpt", net, opt, 3, {"note": 1}, avg)
    net2 = _net(5)
    avg2 = WeightAverage(net2, 0.99)
    state = load_checkpoint(tmp_path / "ckpt", net2, torch.optim.SGD(net2.parameters(), lr=0.1), avg2)
    assert state["step"] == 3 and state["ema_updates"] == 3 and avg2.updates == 3
    for k in avg.shadow:
        assert torch.equal(avg.shadow[k], avg2.shadow[k])
    # a checkpoint written without an average starts one from its weights (and not a live view of them)
    (tmp_path / "ckpt" / "ema.safetensors").unlink()
    avg3 = WeightAverage(_net(7), 0.99)
    net3 = _net(7)
    load_checkpoint(tmp_path / "ckpt", net3, None, avg3)
    assert torch.equal(avg3.shadow["0.weight"], net.state_dict()["0.weight"]) and avg3.updates == 0
    with torch.no_grad():
        net3[0].weight.add_(1.0)
    assert torch.equal(avg3.shadow["0.weight"], net.state_dict()["0.weight"])


def test_pairs_anchored_at_every_camera_include_the_conditioning_camera_itself(shards):
    distinct = PriorPairDataset(shards, anchors="distinct")
    everyone = PriorPairDataset(shards, anchors="all")
    assert len(everyone) == EVENTS * CAMERAS * CAMERAS == len(distinct) + EVENTS * CAMERAS
    pairs = {(everyone.tokens.keys[i][1], clip) for i, clip in everyone.pairs}
    assert {(a, c) for a, c in pairs if a == c} == {(f"train-{s:06d}/cam{c}",) * 2 for s in range(EVENTS)
                                                  for c in range(CAMERAS)}
    item = everyone[everyone.pairs.index(next(p for p in everyone.pairs if everyone.tokens.keys[p[0]][1] == p[1]))]
    assert np.array_equal(item["K_a"].numpy(), item["K_c"]) and item["anchor_key"] == item["clip_key"]
    with pytest.raises(ModelError):
        PriorPairDataset(shards, anchors="some")


class _Oracle:
    """A stand-in prior that returns a fixed token state: the encode of camera 0 (the ceiling)."""

    def __init__(self, validation: SampleValidation, index: list[int]) -> None:
        self.validation, self.index = validation, index

    def eval(self) -> "_Oracle":
        return self

    def sample(self, cond, *, steps, seed, method="heun"):
        cams = self.validation.events[self.index[0]]
        self.index[0] += 1
        return cams[0]["z_s"][None], cams[0]["z_d"][None]


def test_validation_scores_the_encode_as_the_whole_gap_and_a_flat_sample_below_it(shards, tokenizer_dir):
    tok = from_pretrained(tokenizer_dir)
    validation = SampleValidation(shards, tok, events=EVENTS, steps=2)
    assert len(validation.events) == EVENTS and all(len(c) == CAMERAS for c in validation.events)
    flat = validation.reference["floor"]
    assert np.isfinite(flat["psnr"]) and 0 < flat["ssim"] < 1
    # a random tokenizer renders worse than a flat image (the gap is undefined: nan, not a number that
    # looks like progress); give it a floor below it, the negative of the truth, to check the arithmetic
    assert np.isnan(validation(_Oracle(validation, [0]))["gap_closed"]) or \
        validation.reference["ceiling"]["psnr"] > flat["psnr"]
    validation.floor = [255 - t for t in validation.truth]
    validation.reference["floor"] = validation._score(validation.floor)
    got = validation(_Oracle(validation, [0]))
    assert got["gap_closed"] == pytest.approx(1.0) and got["val_psnr"] == pytest.approx(got["ceiling_psnr"], abs=1e-3)
    assert got["val_own_ssim"] == pytest.approx(got["ceiling_own_ssim"], abs=1e-4)
    assert got["floor_psnr"] < got["ceiling_psnr"]


def test_validation_refuses_events_tokenized_by_another_tokenizer(shards, tokenizer_dir, tmp_path):
    from vt4dcodec.model import VideoTok4D, save_pretrained

    other = save_pretrained(VideoTok4D(from_pretrained(tokenizer_dir).config), tmp_path / "other",
                            model_id="tok-other", model_version="0")
    with pytest.raises(ModelError, match="not tokenized"):
        SampleValidation(shards, from_pretrained(other), events=1)


def test_training_validates_on_a_schedule_saves_the_average_and_resumes(shards, tokenizer_dir, tmp_path):
    out = tmp_path / "run"
    overrides = [f"{k}={v}" for k, v in SMALL_PRIOR.items() if k not in ("n_static", "n_dynamic", "token_dim",
                                                                      "frames", "image_size")]
    common = ["--shards", str(shards), "--out", str(out), "--batch-size", "4", "--warmup", "2", "--log-every", "2",
              "--ckpt-every", "2", "--no-progress", "--val-shards", str(shards), "--val-events", "1",
              "--val-every", "2", "--val-sampler", "heun:2", "--tokenizer", str(tokenizer_dir), "--ema-decay", "0.9",
              "--set", *overrides]
    assert main(["--steps", "4", *common]) == 0
    records = [json.loads(line) for line in (out / "val.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records] == [2, 4]
    assert all(np.isfinite(r["val_psnr"]) and np.isfinite(r["ceiling_psnr"]) for r in records)
    assert (out / "val.png").stat().st_size > 1000
    assert main(["--steps", "6", *common]) == 0  # resumed: the curve continues, no step twice
    assert [json.loads(line)["step"] for line in (out / "val.jsonl").read_text().splitlines()] == [2, 4, 6]
    from safetensors.torch import load_file

    ema = load_file(str(out / "checkpoint" / "ema.safetensors"))
    last = load_file(str(out / "checkpoint" / "model.safetensors"))
    saved = load_prior(out / "prior").state_dict()
    name = "blocks.0.mlp_s.fc1.weight" if "blocks.0.mlp_s.fc1.weight" in ema else next(
        k for k, v in ema.items() if v.ndim == 2 and not torch.equal(v, last[k]))
    assert torch.allclose(saved[name].float(), ema[name], atol=1e-6)  # the saved prior is the average
    assert not torch.allclose(ema[name], last[name])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["anchors"] == "all" and summary["ema_decay"] == 0.9


# --- classifier-free guidance --------------------------------------------------------------------------------------

def _guided_prior(cond_dropout: float = 0.2, seed: int = 0):
    from co4dgen_helpers import small_prior

    from vt4dcodec.model.configs import get_prior_config
    from vt4dcodec.model.prior import Co4DGen

    torch.manual_seed(seed)
    base = small_prior(seed, scramble=True)
    prior = Co4DGen(get_prior_config("co4dgen-tiny", **SMALL_PRIOR, cond_dropout=cond_dropout))
    prior.load_state_dict({**base.state_dict(), "null_condition": torch.randn(prior.config.width) * 0.5})
    return prior.eval()


@pytest.mark.parametrize("bad", [-0.1, 1.0, 2, True, "0.1"])
def test_cond_dropout_must_be_a_share_below_one(bad):
    from vt4dcodec.model.configs import get_prior_config

    with pytest.raises(ModelError, match="cond_dropout"):
        get_prior_config("co4dgen-tiny", cond_dropout=bad)


def test_cond_dropout_at_its_default_keeps_the_config_hash_and_adds_no_weights():
    from vt4dcodec.model.configs import get_prior_config
    from vt4dcodec.model.prior import Co4DGen

    plain, guided = get_prior_config("co4dgen-tiny"), get_prior_config("co4dgen-tiny", cond_dropout=0.1)
    assert "cond_dropout" not in plain.canonical_json() and plain.sha256() != guided.sha256()
    assert "null_condition" not in Co4DGen(plain).state_dict() and "null_condition" in Co4DGen(guided).state_dict()


def test_guidance_one_is_the_plain_sample_and_other_values_follow_the_null_condition():
    from co4dgen_helpers import random_condition

    prior = _guided_prior()
    cond = random_condition(B=2, seed=3)
    plain = prior.sample(cond, steps=3, seed=1)
    one = prior.sample(cond, steps=3, seed=1, guidance=1.0)
    assert all(torch.equal(a, b) for a, b in zip(plain, one))
    two = prior.sample(cond, steps=3, seed=1, guidance=2.0)
    assert not torch.allclose(two[0], plain[0])
    # guidance 0 is the unconditional sample: the condition no longer matters
    other = random_condition(B=2, seed=9)
    u1, u2 = prior.sample(cond, steps=3, seed=1, guidance=0.0), prior.sample(other, steps=3, seed=1, guidance=0.0)
    assert torch.allclose(u1[0], u2[0], atol=1e-5) and torch.allclose(u1[1], u2[1], atol=1e-5)
    assert not torch.allclose(plain[0], prior.sample(other, steps=3, seed=1)[0])


def test_guidance_is_refused_without_a_null_condition_and_outside_its_range():
    from co4dgen_helpers import random_condition, small_prior

    cond = random_condition(B=1)
    with pytest.raises(ModelError, match="cond_dropout"):
        small_prior().sample(cond, steps=1, guidance=2.0)
    for bad in (-1.0, 25.0, True, "2"):
        with pytest.raises(ModelError, match="guidance"):
            _guided_prior().sample(cond, steps=1, guidance=bad)


def test_training_drops_the_condition_for_its_share_of_samples_and_evaluation_never():
    from co4dgen_helpers import random_condition

    prior = _guided_prior(cond_dropout=0.999).train()
    z_s, z_d = torch.randn(2, 8, 8) * 0.3, torch.randn(2, 4, 8) * 0.3
    a, b = random_condition(B=2, seed=1), random_condition(B=2, seed=2)
    la, _ = prior.flow_matching_loss(z_s, z_d, a, torch.Generator().manual_seed(0))
    lb, _ = prior.flow_matching_loss(z_s, z_d, b, torch.Generator().manual_seed(0))
    assert torch.allclose(la, lb)  # every condition was replaced by the null one
    prior.eval()
    la, _ = prior.flow_matching_loss(z_s, z_d, a, torch.Generator().manual_seed(0))
    lb, _ = prior.flow_matching_loss(z_s, z_d, b, torch.Generator().manual_seed(0))
    assert not torch.allclose(la, lb)
