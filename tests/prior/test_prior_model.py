"""Co4DGen model: configs, condition checks, flow-matching loss, seeded samplers, standardisation."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from co4dgen_helpers import SMALL_PRIOR, random_condition, small_prior
from vt4dcodec.errors import ModelError
from vt4dcodec.model import get_config
from vt4dcodec.model.configs import PriorConfig, get_prior_config
from vt4dcodec.model.prior import Co4DGen


def test_tiny_config_fits_vt4d_tiny_and_paper_config_builds():
    tiny = get_prior_config("co4dgen-tiny")
    assert tiny.fits_tokenizer(get_config("tiny"))
    assert (tiny.n_static + tiny.n_dynamic, tiny.token_dim, tiny.width) == (96, 32, 128)
    paper = get_prior_config("co4dgen-paper")
    assert paper.fits_tokenizer(get_config("paper"))
    with torch.device("meta"):
        prior = Co4DGen(paper)
    assert sum(p.numel() for p in prior.parameters()) > 50_000_000
    assert PriorConfig.for_tokenizer(get_config("paper"), "co4dgen-tiny").n_static == 1024


@pytest.mark.parametrize("override", [dict(width=0), dict(heads=3), dict(cond_patch=5), dict(layers=True),
                                      dict(mlp_ratio=-1.0), dict(name="")])
def test_bad_configs_raise_model_error(override):
    with pytest.raises(ModelError):
        get_prior_config("co4dgen-tiny", **override)
    with pytest.raises(ModelError):
        get_prior_config("nope")
    with pytest.raises(ModelError):
        PriorConfig.from_dict({"bogus": 1})


def test_config_round_trips_through_dict():
    cfg = get_prior_config("co4dgen-tiny", **SMALL_PRIOR)
    assert PriorConfig.from_dict(cfg.to_dict()) == cfg and cfg.sha256() == PriorConfig.from_dict(cfg.to_dict()).sha256()


def test_bad_condition_and_tokens_raise_model_error():
    prior = small_prior()
    cond = random_condition()
    zs, zd = torch.zeros(2, 8, 8), torch.zeros(2, 4, 8)
    with pytest.raises(ModelError):
        prior.flow_matching_loss(zs[:, :7], zd, cond)
    with pytest.raises(ModelError):
        prior.flow_matching_loss(zs[:1], zd[:1], cond)
    bad = random_condition()
    bad.w2c_a = bad.w2c_a[:, :3]
    with pytest.raises(ModelError):
        prior.sample(bad, steps=1)
    bad = random_condition()
    bad.K_c[0, 0, 0, 0] = float("nan")
    with pytest.raises(ModelError):
        prior.sample(bad, steps=1)
    bad = random_condition(size=16)
    with pytest.raises(ModelError):
        prior.sample(bad, steps=1)
    for kwargs in (dict(steps=0), dict(steps=True), dict(method="rk4")):
        with pytest.raises(ModelError):
            prior.sample(cond, **kwargs)


def test_loss_is_finite_reproducible_and_trains():
    prior = small_prior()
    prior.train()
    cond = random_condition(B=4)
    g = torch.Generator().manual_seed(0)
    zs, zd = torch.rand((4, 8, 8), generator=g) * 1.6 - 0.8, torch.rand((4, 4, 8), generator=g) * 1.6 - 0.8
    prior.set_token_statistics(zs, zd)
    l1, logs = prior.flow_matching_loss(zs, zd, cond, torch.Generator().manual_seed(3))
    l2, _ = prior.flow_matching_loss(zs, zd, cond, torch.Generator().manual_seed(3))
    assert torch.isfinite(l1) and l1.item() == l2.item()
    assert set(logs) >= {"loss", "loss_static", "loss_dynamic", "tau"}
    opt = torch.optim.Adam(prior.parameters(), lr=3e-3)
    first = None
    for step in range(40):  # overfit one batch with a fixed (tau, eps) sequence
        loss, _ = prior(zs, zd, cond, torch.Generator().manual_seed(step % 4))
        opt.zero_grad()
        loss.backward()
        opt.step()
        first = loss.item() if first is None else first
    final = sum(prior(zs, zd, cond, torch.Generator().manual_seed(s))[0].item() for s in range(4)) / 4
    assert final < 0.7 * first


@pytest.mark.parametrize("method", ["euler", "heun"])
def test_sampling_is_seeded_and_bounded(method):
    prior = small_prior(scramble=True)
    cond = random_condition()
    a = prior.sample(cond, steps=3, seed=7, method=method)
    b = prior.sample(cond, steps=3, seed=7, method=method)
    c = prior.sample(cond, steps=3, seed=8, method=method)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    assert not torch.equal(a[0], c[0])
    assert a[0].shape == (2, 8, 8) and a[1].shape == (2, 4, 8)
    assert a[0].abs().max() < 1 and a[1].abs().max() < 1
    # batched samples equal their one-by-one counterparts only through the seed's noise: a batch item is
    # a function of (condition, its noise), so repeating the condition gives distinct samples
    rep = prior.sample(cond.repeat(2), steps=2, seed=1, method=method)
    assert not torch.equal(rep[0][0], rep[0][1])


def test_heun_and_euler_agree_for_a_constant_velocity_field():
    """Zero-initialised outputs make v = 0: both samplers return the standardised noise unchanged."""
    prior = small_prior()  # fresh: out layers are zero, so v == 0 exactly
    cond = random_condition()
    e = prior.sample(cond, steps=4, seed=2, method="euler")
    h = prior.sample(cond, steps=4, seed=2, method="heun")
    g = torch.Generator().manual_seed(2)
    noise_s = torch.randn((2, 8, 8), generator=g)
    assert torch.equal(e[0], h[0])
    assert torch.allclose(e[0], noise_s.clamp(-1 + 1e-4, 1 - 1e-4))


@given(st.floats(-0.9, 0.9), st.floats(0.01, 0.5), st.integers(0, 2**31 - 1))
def test_standardisation_round_trips(mean, std, seed):
    prior = small_prior()
    g = torch.Generator().manual_seed(seed)
    zs = (torch.randn((5, 8, 8), generator=g) * std + mean).clamp(-0.99, 0.99)
    zd = (torch.randn((5, 4, 8), generator=g) * std + mean).clamp(-0.99, 0.99)
    prior.set_token_statistics(zs, zd)
    xs, xd = prior.normalize(zs, zd)
    assert xs.mean(dim=(0, 1)).abs().max() < 1e-4
    rs, rd = prior.denormalize(xs, xd)
    assert torch.allclose(rs, zs, atol=1e-5) and torch.allclose(rd, zd, atol=1e-5)
