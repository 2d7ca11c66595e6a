"""The slot-diversity hinge on Z_d (``--dynamic-diversity``): it counts only what differs across slots *and*
depends on the scene, it is zero on healthy tokens, and its gradient spreads collapsed slots apart."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from vt4dcodec.model import VideoTok4D, get_config
from vt4dcodec.model.bottleneck import DIVERSITY_TARGET, centred_slot_spread, slot_diversity_penalty
from vt4dcodec.model.diagnostics import slot_spread

from network_fixtures import random_batch
from test_unified_recipe import RECIPE


def test_fixed_per_slot_offsets_count_in_the_health_spread_but_not_in_the_centred_one():
    g = torch.Generator().manual_seed(0)
    offsets = torch.randn(1, 16, 8, generator=g)
    per_scene = torch.randn(6, 1, 8, generator=g)  # one vector per scene, the same in every slot
    z = offsets + per_scene
    assert slot_spread(z) > 0.5  # the health statistic sees the offsets
    assert float(centred_slot_spread(z)) < 1e-5  # ... which carry nothing about the scene
    assert float(slot_diversity_penalty(z)) == pytest.approx(DIVERSITY_TARGET, abs=1e-5)


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 8), st.integers(2, 40), st.integers(1, 16), st.integers(0, 2**31 - 1))
def test_independent_slots_are_healthy_and_the_penalty_is_bounded(scenes: int, slots: int, d: int, seed: int):
    z = torch.randn(scenes, slots, d, generator=torch.Generator().manual_seed(seed))
    penalty = float(slot_diversity_penalty(z))
    assert 0.0 <= penalty <= DIVERSITY_TARGET
    assert float(centred_slot_spread(z[:1])) == 0.0  # one scene: nothing to centre against
    if scenes * slots * d >= 256:
        assert penalty == 0.0  # independent slots spread ~sqrt(1 - 1/S) of the overall std


def test_the_gradient_pulls_collapsed_slots_apart():
    g = torch.Generator().manual_seed(1)
    base = torch.randn(8, 1, 16, generator=g)
    z = (base + 0.01 * torch.randn(8, 12, 16, generator=g)).requires_grad_(True)
    before = float(centred_slot_spread(z.detach()))
    slot_diversity_penalty(z).backward()
    with torch.no_grad():
        after = float(centred_slot_spread(z - 0.5 * z.grad))
    assert after > before


def test_the_training_loss_adds_the_weighted_hinge_on_the_dynamic_tokens():
    torch.manual_seed(0)
    net = VideoTok4D(get_config("tiny", **RECIPE)).train()
    batch = random_batch(net.config, B=4, seed=3)
    target = torch.rand(4, net.config.frames, 3, net.config.image_size, net.config.image_size)
    tau = torch.ones(4)

    def loss(weight: float) -> tuple[torch.Tensor, dict[str, float]]:
        torch.manual_seed(5)  # same token noise and flow noise in both calls
        return net.rectified_flow_loss(batch, target, batch.K, batch.w2c, torch.Generator().manual_seed(2),
                                       tau=tau, diversity_weight=weight)

    plain, logs = loss(0.0)
    weighted, _ = loss(2.0)
    with torch.no_grad():
        _, a_d = net.encode_preactivations(batch)
    expected = 2.0 * float(slot_diversity_penalty(torch.tanh(a_d)))
    assert float(weighted - plain) == pytest.approx(expected, rel=1e-4, abs=1e-6)
    assert 0.0 <= logs["dynamic_centred_spread"] <= 2.0
