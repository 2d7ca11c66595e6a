"""Multi-camera encoding: several synchronized cameras of one event -> one token set."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from vt4dcodec.errors import ModelError
from vt4dcodec.model import VideoTok4D, get_config
from vt4dcodec.model.train.data import (PairDataset, ViewsBatchSampler, axis_angles_deg, collate_pairs,
                                         spread_cameras)

from network_fixtures import random_batch

SMALL = dict(frames=4, image_size=32, width=32, heads=2, ae_width=8, spatial_layers=1, static_query_layers=1,
             track_layers=1, renderer_layers=1, n_static=8, n_dynamic=4, token_dim=8, n_tracks=8)


def small_model(seed: int = 0, **overrides) -> VideoTok4D:
    torch.manual_seed(seed)
    return VideoTok4D(get_config("tiny", **{**SMALL, **overrides})).eval()


def _take(batch, index, views=1):
    return dataclasses.replace(batch, **{f.name: getattr(batch, f.name)[index] for f in dataclasses.fields(batch)
                                         if isinstance(getattr(batch, f.name), torch.Tensor)}, views=views)


def test_one_token_set_per_scene_and_a_repeated_camera_adds_nothing():
    model = small_model()
    batch = random_batch(model.config, B=4)
    with torch.no_grad():
        single = model.encode(batch)
        fused = model.encode(dataclasses.replace(batch, views=2))
        repeated = model.encode(_take(batch, [0, 0, 3, 3, 3], views=1))
        twice = model.encode(_take(batch, [0, 0, 3, 3], views=2))
    assert single[0].shape[0] == 4 and fused[0].shape[0] == 2 and fused[1].shape[0] == 2
    # attention over a camera's keys given twice is attention over them once
    for z_one, z_two in zip(single, twice):
        torch.testing.assert_close(z_two[0], z_one[0], atol=1e-5, rtol=0)
        torch.testing.assert_close(z_two[1], z_one[3], atol=1e-5, rtol=0)
    assert repeated[0].shape[0] == 5
    # a second, different camera changes the tokens
    assert (fused[0][0] - single[0][0]).abs().max() > 1e-3


def test_encoded_camera_order_within_a_scene_does_not_matter_much_but_scenes_stay_apart():
    model = small_model()
    batch = random_batch(model.config, B=4)
    with torch.no_grad():
        ab = model.encode(_take(batch, [0, 1, 2, 3], views=2))
        ba = model.encode(_take(batch, [1, 0, 3, 2], views=2))
        ac = model.encode(_take(batch, [0, 2, 1, 3], views=2))
    # the queries read the cameras as one set of keys: swapping cameras within a scene keeps the tokens
    torch.testing.assert_close(ab[0], ba[0], atol=1e-5, rtol=0)
    torch.testing.assert_close(ab[1], ba[1], atol=1e-5, rtol=0)
    assert (ab[0] - ac[0]).abs().max() > 1e-3


def test_bad_view_counts_are_refused():
    model = small_model()
    batch = random_batch(model.config, B=3)
    for views in (2, 0, True):
        with pytest.raises(ModelError):
            model.encode(dataclasses.replace(batch, views=views))
    with pytest.raises(ModelError):  # 2 scenes of 2 views, 3 targets
        model.rectified_flow_loss(dataclasses.replace(random_batch(model.config, B=4), views=2),
                                  torch.rand(3, 4, 3, 32, 32), batch.K, batch.w2c)


def test_multi_camera_loss_trains_every_encoded_camera_path():
    model = small_model(prediction="x0").train()
    for name, p in model.renderer.named_parameters():  # zero-initialised gates and head pass no gradient
        if "modulation" in name or "final_mod" in name or name.startswith("out."):
            torch.nn.init.normal_(p, std=0.1)
    batch = dataclasses.replace(random_batch(model.config, B=4), views=2)
    cfg = model.config
    latents = torch.randn(4, cfg.frames, cfg.latent_channels, cfg.latent_size, cfg.latent_size, requires_grad=True)
    batch.latents = latents
    batch.motion_mask = torch.ones_like(batch.motion_mask)
    target = random_batch(model.config, B=2, seed=5)
    loss, logs = model.rectified_flow_loss(batch, target.frames, target.K, target.w2c, tau=torch.ones(2))
    loss.backward()
    assert np.isfinite(logs["loss"])
    per_clip = latents.grad.abs().flatten(1).sum(dim=1)
    assert bool((per_clip > 0).all())  # every encoded camera of both scenes reaches the loss


@pytest.fixture(scope="module")
def pool(tmp_path_factory):
    from vt4dcodec.model.train.data import ScenePool

    return ScenePool.for_config(get_config("tiny", **SMALL), tmp_path_factory.mktemp("cache"), cameras=4)


def test_multi_camera_items_encode_distinct_cameras_and_target_held_out_ones(pool):
    held_out = PairDataset(pool, [0], recon_share=0.0, neighbour_sigma_deg=30.0)
    scene = pool.scene(0)
    torch.manual_seed(0)
    for i in range(4):
        sources, target, _, _ = held_out[(i, 3)]
        encoded = [int(np.flatnonzero([np.array_equal(s.frames, f) for f in scene["frames"]])[0]) for s in sources]
        assert len(set(encoded)) == 3 and encoded[0] == i
        assert not any(np.array_equal(target, scene["frames"][c]) for c in encoded)
    recon = PairDataset(pool, [0], recon_share=1.0)
    sources, target, _, _ = recon[(1, 2)]
    assert any(np.array_equal(target, s.frames) for s in sources)
    # every camera encoded: the target must be one of them
    sources, target, _, _ = held_out[(2, 4)]
    assert any(np.array_equal(target, s.frames) for s in sources)
    nearest = PairDataset(pool, [0], neighbour_sigma_deg=1e-3)
    angles = axis_angles_deg(scene["w2c"])
    torch.manual_seed(1)
    sources, target, _, _ = nearest[(0, 2)]
    encoded = [int(np.flatnonzero([np.array_equal(s.frames, f) for f in scene["frames"]])[0]) for s in sources]
    rest = [c for c in range(4) if c not in encoded]
    want = min(rest, key=lambda c: angles[encoded, c].min())
    assert np.array_equal(target, scene["frames"][want])


def ring_angles(n: int) -> np.ndarray:
    """Axis angles (degrees) of n cameras evenly spaced on a ring, all looking at its centre."""
    step = 360.0 / n
    diff = np.abs(np.arange(n)[:, None] - np.arange(n)[None]) * step
    return np.minimum(diff, 360.0 - diff)


def test_spread_cameras_picks_every_other_camera_of_a_ring():
    assert spread_cameras(ring_angles(10), 0, 5) == [0, 2, 4, 6, 8]
    assert spread_cameras(ring_angles(10), 3, 5) == [3, 1, 5, 7, 9]
    assert spread_cameras(ring_angles(10), 2, 2) == [2, 7]  # the opposite camera
    assert spread_cameras(ring_angles(8), 1, 4) == [1, 3, 5, 7]
    assert spread_cameras(ring_angles(4), 0, 4) == [0, 1, 2, 3]  # all of them, each once
    assert spread_cameras(ring_angles(10), 4, 1) == [4]


def test_spread_cameras_on_a_large_rig_falls_back_to_farthest_point():
    chosen = spread_cameras(ring_angles(40), 0, 8)  # C(39, 7) sets: too many to search
    assert chosen[0] == 0 and len(set(chosen)) == 8 and 20 in chosen  # the opposite camera comes second
    sub = ring_angles(40)[np.ix_(chosen, chosen)] + np.diag(np.full(8, np.inf))
    assert sub.min() >= 36.0  # no two chosen cameras closer than 4 ring steps


def test_spread_share_encodes_spread_cameras(pool):
    spread = PairDataset(pool, [0], recon_share=0.0, neighbour_sigma_deg=30.0, spread_share=1.0)
    scene = pool.scene(0)
    for i in range(4):
        sources, _, _, _ = spread[(i, 2)]
        encoded = [int(np.flatnonzero([np.array_equal(s.frames, f) for f in scene["frames"]])[0]) for s in sources]
        assert encoded == spread_cameras(axis_angles_deg(scene["w2c"]), i, 2)
        assert encoded[1] == int(np.argmax(axis_angles_deg(scene["w2c"])[i]))  # the farthest camera
    with pytest.raises(ValueError):
        PairDataset(pool, [0], recon_share=0.5, spread_share=1.5)


def test_views_batch_sampler_and_collate(pool):
    dataset = PairDataset(pool, [0, 1], recon_share=0.5)
    sampler = ViewsBatchSampler(len(dataset), 2, multi_share=0.5, multi_views=(2, 3),
                                generator=torch.Generator().manual_seed(0))
    batches = list(sampler)
    assert len(batches) == len(sampler) == 4
    assert sorted(i for b in batches for i, _ in b) == list(range(8))
    assert all(len({v for _, v in b}) == 1 for b in batches)
    assert {b[0][1] for b in batches} <= {1, 2, 3}
    many = [b[0][1] for _ in range(20) for b in ViewsBatchSampler(8, 2, multi_share=0.5, multi_views=(3,),
                                                                  generator=torch.Generator().manual_seed(_))]
    assert 1 in many and 3 in many
    batch = collate_pairs([dataset[(0, 3)], dataset[(5, 3)]])
    assert batch.source.views == 3 and batch.source.batch_size == 6 and batch.target_frames.shape[0] == 2
    with pytest.raises(ValueError):
        collate_pairs([dataset[(0, 3)], dataset[(5, 2)]])
    with pytest.raises(ValueError):
        ViewsBatchSampler(8, 2, multi_share=0.5, multi_views=(1,), generator=torch.Generator())
    with pytest.raises(ValueError):
        PairDataset(pool, [0])[(0, 2)]  # all ordered pairs: no sampled target for a multi-camera item


ANCHORED = dict(locality_sigma=0.5, query_from_grid=True, project_anchors=True)


def test_anchor_views_is_the_same_model_for_one_camera_and_anchors_each_token_in_its_own_camera():
    base, own = small_model(**ANCHORED), small_model(**ANCHORED, anchor_views=True)
    assert own.config.sha256() != base.config.sha256()
    assert small_model(**ANCHORED, anchor_views=False).config.sha256() == base.config.sha256()
    assert own.load_state_dict(base.state_dict()) is not None  # no new weights: a warm start is exact
    with torch.no_grad():
        own.spatial_branch.query_content.weight.normal_(std=0.5)
        base.spatial_branch.query_content.weight.copy_(own.spatial_branch.query_content.weight)
        own.renderer.depth_head.weight.normal_(std=0.5)
        base.renderer.depth_head.weight.copy_(own.renderer.depth_head.weight)
    batch = random_batch(own.config, B=4)
    cfg, h = own.config, own.config.latent_size
    y, tau = torch.randn(4, cfg.frames, cfg.latent_channels, h, h), torch.full((4,), 0.6)
    with torch.no_grad():  # one camera: identical tokens and velocities
        zb, zo = base.encode(batch), own.encode(batch)
        torch.testing.assert_close(zo[0], zb[0])
        vb = base.velocity(y, *zb, base.rays(batch.K, batch.w2c), tau,
                           cameras=base.render_cameras(batch.K, batch.w2c, batch.source))
        vo = own.velocity(y, *zo, own.rays(batch.K, batch.w2c), tau,
                          cameras=own.render_cameras(batch.K, batch.w2c, batch.source))
        torch.testing.assert_close(vo, vb, atol=1e-5, rtol=1e-5)
    # two cameras per scene: the source cameras of each scene, in encoding order
    pair = dataclasses.replace(batch, views=2)
    K_src, w2c_src = pair.source
    assert K_src.shape == (2, 2, cfg.frames, 3, 3) and torch.equal(w2c_src[1, 1], batch.w2c[3])
    r = own.renderer
    assert r.token_cameras(2).tolist() == [i % 2 for i in range(cfg.n_static)]
    assert base.renderer.token_cameras(2).tolist() == [0] * cfg.n_static
    with torch.no_grad():
        z = own.encode(pair)
        # rendered at encoded camera 1 (static trajectory), camera 1's tokens peak on their own cells
        K1 = batch.K[1::2, :1].expand(-1, cfg.frames, -1, -1).clone()
        w1 = batch.w2c[1::2, :1].expand(-1, cfg.frames, -1, -1).clone()
        cams = own.render_cameras(K1, w1, (K_src[:, :, :1].expand_as(K_src), w2c_src[:, :, :1].expand_as(w2c_src)))
        bias = r.projected_bias(*z, *cams)
        P = cfg.renderer_patches_per_side ** 2
        nearest = ((r.patch_cells[:, None] - r.anchor_cells[None]) ** 2).sum(-1).argmin(0)  # (Na,) patch
        peaks = bias[:, 0, :P, :cfg.n_static].argmax(1)  # (S, Na)
        assert torch.equal(peaks[:, 1::2], nearest[1::2].expand(2, -1))
        assert not torch.equal(peaks[:, 0::2], nearest[0::2].expand(2, -1))  # camera 0's tokens land elsewhere
        # the grid feature each query starts from comes from its own camera's cell only
        seen = []
        hook = own.spatial_branch.query_content.register_forward_hook(lambda m, a, out: seen.append(a[0]))
        assert pair.latents is None
        frames = pair.frames.clone()
        frames[1] = torch.rand_like(frames[1])  # scene 0, camera 1 only
        own.encode(pair)
        own.encode(dataclasses.replace(pair, frames=frames))
        hook.remove()
        before, after = seen
        moved = (after[0] - before[0]).abs().amax(-1) > 1e-6  # (n_queries,)
        assert moved[1::2].all() and not moved[0::2].any()
        assert torch.equal(after[1], before[1])  # scene 1 untouched
    with pytest.raises(ModelError, match="project_anchors"):
        get_config("tiny", **SMALL, locality_sigma=0.5, anchor_views=True)
    with pytest.raises(ModelError, match="anchor_views"):
        get_config("tiny", **SMALL, **ANCHORED, anchor_views=1)
    with pytest.raises(ModelError, match="source cameras"):
        own.render_cameras(K1, w1, (K_src[:, :, 0], w2c_src))
