"""Spread views (config ``spread_views``): with V encoded cameras sharing a factor with the P cells, each
camera's anchored tokens cover distinct cells."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from vt4dcodec.errors import ModelError
from vt4dcodec.model import VideoTok4D, get_config
from vt4dcodec.model.layers import token_cameras

from network_fixtures import random_batch

# 32 px, latent 8, patch 2: P = 16 cells; 80 static tokens = 5 per cell with one camera; 4 frames
SMALL = dict(frames=4, image_size=32, width=32, heads=2, ae_width=8, spatial_layers=1, static_query_layers=1,
             track_layers=1, renderer_layers=1, n_static=80, n_dynamic=4, token_dim=8, n_tracks=8, patch_size=2)
FULL = dict(locality_sigma=0.35, query_from_grid=True, project_anchors=True, prediction="x0", anchor_views=True,
            token_splat=True, token_from_cell=True, frame_copies=True)


def small_model(seed: int = 0, **overrides) -> VideoTok4D:
    torch.manual_seed(seed)
    return VideoTok4D(get_config("tiny", **{**SMALL, **FULL, **overrides})).eval()


def test_config_hash_is_kept_while_off_and_the_switch_needs_anchor_views():
    base = get_config("tiny", **SMALL, **FULL)
    assert get_config("tiny", **SMALL, **FULL, spread_views=False).sha256() == base.sha256()
    assert get_config("tiny", **SMALL, **FULL, spread_views=True).sha256() != base.sha256()
    with pytest.raises(ModelError, match="spread_views"):
        get_config("tiny", **SMALL, **{**FULL, "anchor_views": False}, spread_views=True)
    with pytest.raises(ModelError, match="spread_views"):
        get_config("tiny", **SMALL, **FULL, spread_views=1)


@given(blocks=st.integers(1, 8), views=st.integers(1, 12), cells=st.sampled_from([4, 16, 64, 49]))
def test_each_camera_gets_as_many_distinct_cells_as_it_can(blocks, views, cells):
    n = blocks * cells
    plain, spread = token_cameras(n, views, cells), token_cameras(n, views, cells, spread=True)
    index = torch.arange(n)
    assert torch.equal(plain, index % views)
    reach = cells // math.gcd(views, cells)  # distinct cells a camera reaches under i mod V
    assert torch.equal(spread, plain) == (math.gcd(views, cells) == 1 or -(-n // views) <= reach)
    if cells % views == 0:  # each camera: n / V tokens on min(n / V, P) distinct cells
        for v in range(views):
            mine = index[spread == v]
            assert len(mine) == n // views
            assert len(set((mine % cells).tolist())) == min(n // views, cells)


def test_four_cameras_of_320_tokens_on_64_cells_each_cover_every_cell():
    spread = token_cameras(320, 4, 64, spread=True)
    plain = token_cameras(320, 4, 64)
    cells = torch.arange(320) % 64
    for v in range(4):
        assert len(set(cells[spread == v].tolist())) == 64
        assert len(set(cells[plain == v].tolist())) == 16
        assert int((spread == v).sum()) == 80
    eight = token_cameras(320, 8, 64, spread=True)
    assert all(len(set(cells[eight == v].tolist())) == 40 for v in range(8))  # 40 tokens, 40 cells
    # ten cameras: i mod 10 already gives each camera 32 distinct cells, and shifting would cluster them
    # (vt4d-tiny 0.11.0, all ten cameras of 20 synthetic captures stored: 22.24 dB shifted, 23.1 before)
    assert torch.equal(token_cameras(320, 10, 64, spread=True), token_cameras(320, 10, 64))


def test_odd_camera_counts_render_exactly_as_without_it_and_even_ones_move_the_anchors():
    base, spread = small_model(), small_model(spread_views=True)
    spread.load_state_dict(base.state_dict())  # no new weights
    with torch.no_grad():
        for m in (base, spread):  # nonzero maps, so the tokens' cells matter
            torch.manual_seed(1)
            for lin in (m.cell_direct, m.renderer.splat, m.renderer.depth_head, m.spatial_branch.query_content):
                lin.weight.normal_(std=0.3)
    batch = random_batch(base.config, B=6)
    cfg, h = base.config, base.config.latent_size
    for views, same in ((1, True), (3, True), (2, False)):
        b = dataclasses.replace(batch, views=views)
        S = 6 // views
        y, tau = torch.randn(S, cfg.frames, cfg.latent_channels, h, h), torch.full((S,), 1.0)
        K, w2c = batch.K[::views], batch.w2c[::views]
        with torch.no_grad():
            out = []
            for m in (base, spread):
                z = m.encode(b)
                out.append(m.velocity(y, *z, m.rays(K, w2c), tau, cameras=m.render_cameras(K, w2c, b.source)))
        assert torch.allclose(out[0], out[1], atol=1e-5) == same, views
    r = spread.renderer  # two cameras, 16 cells: each camera's 40 tokens cover all 16 cells, and copies split them
    cams = r.token_cameras(2)
    for v in range(2):
        assert len(set((torch.arange(80)[cams == v] % 16).tolist())) == 16
    assert float(r.copy_frames(2).sum(1).gt(0).sum()) > 0
