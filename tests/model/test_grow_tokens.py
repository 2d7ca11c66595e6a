"""Growing the static token set on a warm start (``--init-partial`` with ``n_static`` = k x the saved one)."""

from __future__ import annotations

import torch

from vt4dcodec.model import VideoTok4D, get_config
from vt4dcodec.model.train.tokenizer import grown_static_tokens

from network_fixtures import random_batch
from test_token_splat import SMALL, SPLAT

FULL = dict(**SPLAT, anchor_views=True, token_splat=True, token_from_cell=True)


def _trained_like(cfg) -> VideoTok4D:
    torch.manual_seed(0)
    model = VideoTok4D(cfg).eval()
    with torch.no_grad():  # zero-initialised maps get weight, as in a trained model
        for layer in (model.renderer.splat, model.renderer.out, model.renderer.final_mod):
            layer.weight.normal_(std=0.1)
    return model


def test_one_camera_gives_each_token_k_times_and_every_per_token_tensor_is_repeated():
    small = get_config("tiny", **SMALL, **FULL)
    big = small.replace(n_static=3 * small.n_static)
    source = _trained_like(small)
    grown = VideoTok4D(big).eval()
    state = grown_static_tokens(source.state_dict(), small, big)
    grown.load_state_dict(state, strict=True)  # every tensor fits
    n = small.n_static
    torch.testing.assert_close(grown.renderer.token_slot[n:2 * n], source.renderer.token_slot[:n])
    torch.testing.assert_close(grown.renderer.token_slot[3 * n:], source.renderer.token_slot[n:])
    batch = random_batch(small, B=2)
    with torch.no_grad():
        z_s, z_d = source.encode(batch)
        g_s, g_d = grown.encode(batch)
    for copy in range(3):
        torch.testing.assert_close(g_s[:, copy * n:(copy + 1) * n], z_s, atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(g_d, z_d, atol=1e-5, rtol=1e-4)


def test_anything_but_a_whole_multiple_is_left_to_the_partial_copy():
    small = get_config("tiny", **SMALL, **FULL)
    state = _trained_like(small).state_dict()
    for n_static in (small.n_static, small.n_static + 4, small.n_static // 2):
        assert grown_static_tokens(state, small, small.replace(n_static=n_static)) is state
    unified = small.replace(unified_tokens=True, token_from_cell=False)
    assert grown_static_tokens(state, unified, unified.replace(n_static=2 * small.n_static)) is state
