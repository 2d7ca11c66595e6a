"""Static-Dynamic Cross-Token Attention: static queries attend only to the static stream, dynamic
queries to both."""

from __future__ import annotations

import torch

from vt4dcodec.model.prior_blocks import CoDenoisingBlock, StaticDynamicAttention, static_dynamic_mask

from co4dgen_helpers import random_condition, small_prior


def test_mask_blocks_exactly_static_to_dynamic():
    mask = static_dynamic_mask(3, 2)
    assert mask.shape == (5, 5)
    assert not mask[:3, 3:].any()          # static queries never see dynamic keys
    assert mask[:3, :3].all()              # ... but all static keys
    assert mask[3:, :].all()               # dynamic queries see everything


def _streams(seed: int, B: int = 2, n_s: int = 6, n_d: int = 4, D: int = 16):
    g = torch.Generator().manual_seed(seed)
    return torch.randn((B, n_s, D), generator=g), torch.randn((B, n_d, D), generator=g)


def test_attention_static_outputs_ignore_dynamic_stream_dynamic_outputs_use_both():
    torch.manual_seed(0)
    attn = StaticDynamicAttention(16, 2)
    h_s, h_d = _streams(1)
    out_s, out_d = attn(h_s, h_d)
    out_s2, out_d2 = attn(h_s, h_d + 3.0 * torch.randn_like(h_d))  # perturb the dynamic stream
    assert torch.equal(out_s, out_s2)
    assert (out_d - out_d2).abs().max() > 1e-3
    out_s3, out_d3 = attn(h_s + 3.0 * torch.randn_like(h_s), h_d)  # perturb the static stream
    assert (out_s - out_s3).abs().max() > 1e-3
    assert (out_d - out_d3).abs().max() > 1e-3   # dynamic queries attend to static keys too


def test_attention_jacobian_static_wrt_dynamic_is_zero():
    torch.manual_seed(0)
    attn = StaticDynamicAttention(16, 2)
    h_s, h_d = _streams(2)
    h_d.requires_grad_(True)
    h_s.requires_grad_(True)
    out_s, out_d = attn(h_s, h_d)
    (grad_d,) = torch.autograd.grad(out_s.sum(), h_d, allow_unused=True, retain_graph=True)
    assert grad_d is None or torch.count_nonzero(grad_d) == 0
    (grad_s,) = torch.autograd.grad(out_d.square().sum(), h_s)
    assert torch.count_nonzero(grad_s) > 0


def test_block_and_whole_denoiser_keep_the_routing():
    """With every gate live (random weights), the static velocity of the whole denoiser does not depend
    on the dynamic input at all, while the dynamic velocity depends on the static one."""
    torch.manual_seed(0)
    block = CoDenoisingBlock(16, 2, 2.0)
    with torch.no_grad():
        for p in block.parameters():
            if not p.abs().gt(0).any():
                p.normal_(0, 0.2)
    h_s, h_d = _streams(3)
    cond, c = torch.randn(2, 5, 16), torch.randn(2, 16)
    a_s, a_d = block(h_s, h_d, cond, c)
    b_s, b_d = block(h_s, h_d * -2.0, cond, c)
    assert torch.equal(a_s, b_s) and (a_d - b_d).abs().max() > 1e-3

    prior = small_prior(scramble=True)
    h = prior.encode_condition(random_condition())
    tau = torch.tensor([0.3, 0.8])
    g = torch.Generator().manual_seed(5)
    x_s, x_d = torch.randn((2, 8, 8), generator=g), torch.randn((2, 4, 8), generator=g)
    v_s, v_d = prior.velocity(x_s, x_d, h, tau)
    v_s2, v_d2 = prior.velocity(x_s, torch.randn((2, 4, 8), generator=g), h, tau)
    assert torch.allclose(v_s, v_s2, atol=0, rtol=0)
    assert (v_d - v_d2).abs().max() > 1e-4
    v_s3, v_d3 = prior.velocity(torch.randn((2, 8, 8), generator=g), x_d, h, tau)
    assert (v_d - v_d3).abs().max() > 1e-4 and (v_s - v_s3).abs().max() > 1e-4


def test_condition_reaches_both_streams():
    prior = small_prior(scramble=True)
    x_s, x_d, tau = torch.randn(2, 8, 8), torch.randn(2, 4, 8), torch.tensor([0.5, 0.5])
    h1 = prior.encode_condition(random_condition(seed=1))
    h2 = prior.encode_condition(random_condition(seed=2))
    v1, v2 = prior.velocity(x_s, x_d, h1, tau), prior.velocity(x_s, x_d, h2, tau)
    assert (v1[0] - v2[0]).abs().max() > 1e-4 and (v1[1] - v2[1]).abs().max() > 1e-4
