"""The unified-token ablation on the full recipe (``unified_tokens`` with ``token_from_cell``): the anchored
cell tokens of the full model, and N_d free Spatial Branch queries in place of the Temporal Branch."""

from __future__ import annotations

import dataclasses

import torch

from vt4dcodec.model import VideoTok4D, get_config

from network_fixtures import random_batch

RECIPE = dict(frames=4, image_size=32, width=32, heads=2, ae_width=8, spatial_layers=1, static_query_layers=1,
              track_layers=1, renderer_layers=1, n_static=32, n_dynamic=4, token_dim=8, n_tracks=8, patch_size=2,
              locality_sigma=0.35, query_from_grid=True, project_anchors=True, prediction="x0", anchor_views=True,
              token_splat=True, token_from_cell=True, frame_copies=True, frame_gate_deg=8.0, spread_views=True,
              view_gate_deg=40.0, pixel_splat=True, patch_gate_deg=5.0)


def build(**changes: object) -> VideoTok4D:
    torch.manual_seed(0)
    return VideoTok4D(get_config("tiny", **{**RECIPE, **changes})).eval()


def test_anchored_tokens_per_variant():
    assert get_config("tiny", **RECIPE).n_anchored == 32
    assert get_config("tiny", **RECIPE, unified_tokens=True).n_anchored == 32  # Z_d stays free
    plain = get_config("tiny", unified_tokens=True)  # the older unified ablation anchors every token
    assert plain.n_anchored == plain.n_static + plain.n_dynamic


def test_unified_full_recipe_keeps_the_budget_and_has_no_temporal_branch():
    full, unified = build(), build(unified_tokens=True)
    assert unified.temporal_branch is None and unified.dynamic_bottleneck is None
    assert unified.config.token_floats == full.config.token_floats
    assert unified.renderer.n_anchored == full.renderer.n_anchored == 32
    assert unified.spatial_branch.queries.shape[0] == 36 and unified.spatial_branch.n_anchored == 32
    # the cell paths of the full model are there, on the anchored tokens only
    assert unified.cell_direct is not None and unified.cell_frames is not None
    batch = dataclasses.replace(random_batch(unified.config, B=4), views=2)
    z_s, z_d = unified.encode(batch)
    assert z_s.shape == (2, 32, 8) and z_d.shape == (2, 4, 8)
    assert z_s.abs().max() < 1 and z_d.abs().max() < 1
    K_src, w2c_src = batch.K.view(2, 2, 4, 3, 3), batch.w2c.view(2, 2, 4, 4, 4)
    frames = unified.render(z_s, z_d, batch.K[:2], batch.w2c[:2], steps=1, source=(K_src, w2c_src))
    assert frames.shape == (2, 4, 3, 32, 32) and torch.isfinite(frames).all()


def test_cell_maps_reach_the_static_tokens_and_not_the_free_ones():
    net = build(unified_tokens=True)
    batch = dataclasses.replace(random_batch(net.config, B=2), views=2)
    with torch.no_grad():
        a_s0, a_d0 = net.encode_preactivations(batch)
        net.cell_direct.weight.normal_()
        net.cell_frames.weight.normal_()
        a_s1, a_d1 = net.encode_preactivations(batch)
    assert (a_s1 - a_s0).abs().amax(-1).min() > 0  # every static token reads its own cell
    assert torch.equal(a_d0, a_d1)


def test_free_queries_read_the_whole_grid_without_a_bias():
    net = build(unified_tokens=True)
    branch = net.spatial_branch
    assert branch.query_bias.shape[1] == 32  # one locality bias per anchored query
    seen = {}

    def grab(module, args, kwargs):
        seen["bias"] = kwargs["bias"]

    handle = branch.query_blocks[0].register_forward_pre_hook(grab, with_kwargs=True)
    try:
        with torch.no_grad():
            net.encode(dataclasses.replace(random_batch(net.config, B=2), views=2))
    finally:
        handle.remove()
    bias = seen["bias"]  # (heads, n_queries, V T P)
    assert bias.shape == (2, 36, 2 * 4 * 16)
    assert torch.equal(bias[:, 32:], torch.zeros_like(bias[:, 32:]))
    assert bias[:, :32].abs().sum() > 0
