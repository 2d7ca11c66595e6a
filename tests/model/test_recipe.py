"""The stage-2 recipe pieces: query scale, x0 prediction, pre-activations, token health, pair sampling,
cached latents and the stage-1 photo crops."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from vt4dcodec.errors import ModelError
from vt4dcodec.model import VideoTok4D, get_config
from vt4dcodec.model.bottleneck import saturation_penalty
from vt4dcodec.model.configs import ModelConfig
from vt4dcodec.model.layers import patchify
from vt4dcodec.model.diagnostics import effective_rank, saturation, slot_spread, swap_drop_db, token_health
from vt4dcodec.model.train.data import MixedFrames, PairDataset, PhotoCrops, axis_angles_deg
from vt4dcodec.model.train.tokenizer import draw_tau

from network_fixtures import random_batch

SMALL = dict(frames=4, image_size=32, width=32, heads=2, ae_width=8, spatial_layers=1, static_query_layers=1,
             track_layers=1, renderer_layers=1, n_static=8, n_dynamic=4, token_dim=8, n_tracks=8)


def small_model(seed: int = 0, **overrides) -> VideoTok4D:
    torch.manual_seed(seed)
    return VideoTok4D(get_config("tiny", **{**SMALL, **overrides})).eval()


def test_fresh_query_slots_differ():
    """Unit-scale queries: a fresh encoder gives every slot its own vector (std-0.02 queries gave 0.03)."""
    model = small_model()
    z_s, z_d = model.encode(random_batch(model.config, B=3))
    assert slot_spread(z_s) > 0.3 and slot_spread(z_d) > 0.3


def test_old_configs_keep_their_hash_and_x0_changes_it():
    shipped = Path(__file__).resolve().parents[2] / "model" / "weights" / "vt4d-tiny" / "config.json"
    meta = json.loads(shipped.read_text())
    if "prediction" not in meta["config"]:  # a config written before the field existed
        assert ModelConfig.from_dict(meta["config"]).sha256() == meta["config_sha256"]
    velocity = get_config("tiny", prediction="velocity")
    assert velocity.sha256() == get_config("tiny").sha256()
    assert get_config("tiny", prediction="x0").sha256() != velocity.sha256()
    with pytest.raises(ModelError):
        get_config("tiny", prediction="epsilon")


def test_x0_prediction_one_step_render_is_the_network_output():
    model = small_model(prediction="x0")
    for p in model.renderer.out.parameters():  # make the zero-initialised head say something
        torch.nn.init.normal_(p, std=0.5)
    batch = random_batch(model.config, B=2)
    z_s, z_d = model.encode(batch)
    latents = model.render_latents(z_s, z_d, batch.K, batch.w2c, steps=1, seed=3)
    cfg = model.config
    # every item of the batch starts from the same seeded noise (a view renders the same alone or in a batch)
    noise = torch.randn((1, cfg.frames, cfg.latent_channels, cfg.latent_size, cfg.latent_size),
                        generator=torch.Generator().manual_seed(3)).expand(2, -1, -1, -1, -1)
    direct = model.renderer(noise, z_s, z_d, model.rays(batch.K, batch.w2c), torch.ones(2))
    assert torch.allclose(latents, direct, atol=1e-5)


def test_x0_loss_at_tau_one_is_the_one_step_error_and_trains_the_encoder():
    model = small_model(prediction="x0").train()
    model.freeze_autoencoder()
    batch = random_batch(model.config, B=2)
    opt = torch.optim.SGD(model.tokenizer_parameters(), lr=0.05)
    for _ in range(3):  # zero-initialised gates and output (DiT) open the token path by step 3
        opt.zero_grad()
        loss, logs = model.rectified_flow_loss(batch, batch.frames, batch.K, batch.w2c, tau=torch.ones(2),
                                               saturation_weight=0.1)
        loss.backward()
        opt.step()
    assert logs["tau"] == 1.0 and np.isfinite(logs["flow"]) and logs["x0"] == pytest.approx(logs["flow"], rel=1e-4)
    grads = [p.grad for p in (model.spatial_branch.queries, model.temporal_branch.queries)]
    assert all(g is not None and g.abs().sum() > 0 for g in grads)
    for key in ("static_spread", "dynamic_spread", "static_saturation", "dynamic_rank"):
        assert key in logs
    with pytest.raises(ModelError):
        model.rectified_flow_loss(batch, batch.frames, batch.K, batch.w2c, tau=torch.full((2,), 1.5))


def test_cached_latents_give_the_same_loss_as_frames():
    model = small_model(prediction="x0")
    batch = random_batch(model.config, B=2)
    gen = lambda: torch.Generator().manual_seed(5)  # noqa: E731
    ref, _ = model.rectified_flow_loss(batch, batch.frames, batch.K, batch.w2c, gen())
    batch.latents = model.latents(batch.frames)
    cached, _ = model.rectified_flow_loss(batch, batch.frames, batch.K, batch.w2c, gen(),
                                          target_latents=batch.latents)
    assert torch.allclose(ref, cached)
    batch.latents = batch.latents[:, :1]
    with pytest.raises(ModelError):
        model.encode(batch)


def test_encode_is_tanh_of_the_preactivations():
    model = small_model()
    batch = random_batch(model.config, B=2)
    a_s, a_d = model.encode_preactivations(batch)
    z_s, z_d = model.encode(batch)
    assert torch.allclose(z_s, torch.tanh(a_s)) and torch.allclose(z_d, torch.tanh(a_d))


def test_saturation_penalty_is_zero_inside_the_knee():
    assert float(saturation_penalty(torch.tensor([0.0, 1.9, -1.99]))) == 0.0
    assert float(saturation_penalty(torch.tensor([3.0, -4.0]))) == pytest.approx((1 + 4) / 2)


@settings(max_examples=30, deadline=None)
@given(st.integers(2, 6), st.integers(2, 9), st.integers(1, 5), st.integers(0, 2**31 - 1))
def test_health_statistics(B, N, d, seed):
    g = torch.Generator().manual_seed(seed)
    same = torch.rand(B, 1, d, generator=g).expand(B, N, d) * 2 - 1
    assert slot_spread(same) == pytest.approx(0.0, abs=1e-6)   # every slot the same vector
    # slots spread by construction (uniform noise alone can put two slots close: B=N=2, d=1, seed 252759)
    distinct = torch.linspace(-0.9, 0.9, N)[None, :, None] + 0.1 * (torch.rand(B, N, d, generator=g) * 2 - 1)
    assert slot_spread(distinct) > 0.2
    identical_scenes = distinct[:1].expand(B, N, d)
    assert effective_rank(identical_scenes) == 0.0
    assert 1.0 <= effective_rank(distinct) <= B
    assert saturation(torch.full((B, N, d), 0.99)) == 1.0 and saturation(distinct * 0.9) == 0.0
    health = token_health(distinct, same)
    assert health["dynamic_spread"] == pytest.approx(0.0, abs=1e-6) and health["static_spread"] > 0.2


class _FakeModel:
    """Renders the first token value as a flat grey video: own tokens match, swapped ones do not."""

    def render(self, z_s, z_d, K, w2c, steps=1, seed=0, source=None):
        return z_s[:, :1, :1, None, None].expand(-1, 2, 3, 4, 4).clamp(0, 1)


def test_swap_drop_measures_how_much_the_tokens_matter():
    z_s = torch.tensor([0.2, 0.8]).view(2, 1, 1).expand(2, 3, 2).clone()
    truth = z_s[:, :1, :1, None, None].expand(-1, 2, 3, 4, 4)
    out = swap_drop_db(_FakeModel(), z_s, z_s, None, None, truth)
    assert out["psnr_own_db"] == pytest.approx(100.0) and out["swap_drop_db"] > 50


@pytest.fixture(scope="module")
def pool(tmp_path_factory):
    from vt4dcodec.model.train.data import ScenePool

    cfg = get_config("tiny", **SMALL)
    return ScenePool.for_config(cfg, tmp_path_factory.mktemp("cache"), cameras=4)


def test_pair_sampling_reconstruction_share_and_neighbours(pool):
    every = PairDataset(pool, [0])
    assert len(every) == 12 and all(a != b for a, b in every.pairs)
    recon = PairDataset(pool, [0], recon_share=1.0)
    assert len(recon) == 4
    torch.manual_seed(0)
    for i in range(4):
        source, target_frames, _, _ = recon[i]
        assert np.array_equal(source.frames, target_frames)  # the target is the encoded camera
    near = PairDataset(pool, [0], neighbour_sigma_deg=1e-3)  # only the closest camera has any weight
    angles = axis_angles_deg(pool.scene(0)["w2c"])
    np.fill_diagonal(angles, np.inf)
    scene = pool.scene(0)
    for src in range(4):
        _, target_frames, _, _ = near[src]
        assert np.array_equal(target_frames, scene["frames"][int(np.argmin(angles[src]))])
    with pytest.raises(ValueError):
        PairDataset(pool, [0], recon_share=1.5)


def test_axis_angles_are_symmetric_degrees():
    w2c = np.tile(np.eye(4), (3, 2, 1, 1))
    w2c[1, :, :3, :3] = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]  # camera 1 looks along world x
    angles = axis_angles_deg(w2c)
    assert np.allclose(angles, angles.T) and angles[0, 1] == pytest.approx(90.0) and angles[0, 2] == 0.0


def test_draw_tau_shares():
    torch.manual_seed(0)
    assert bool((draw_tau(64, 1.0) == 1.0).all())
    tau = draw_tau(2000, 0.0)
    assert 0.0 <= float(tau.min()) and float(tau.max()) < 1.0 and abs(float(tau.mean()) - 0.5) < 0.05


def test_photo_crops_are_deterministic_train_split_images(pool):
    crops = PhotoCrops(32, count=5, seed=1)
    a, b = crops[3], PhotoCrops(32, count=5, seed=1)[3]
    assert a.shape == (3, 32, 32) and torch.equal(a, b) and 0.0 <= float(a.min()) and float(a.max()) <= 1.0
    assert not torch.equal(crops[0], crops[1])
    assert all(n not in crops.names for n in ("rocket", "coins", "gravel", "clock", "retina"))  # test photos
    from vt4dcodec.model.train.data import FrameDataset

    frames = FrameDataset(pool, [0])
    mixed = MixedFrames(frames, photo_share=0.5)
    assert len(mixed) == 2 * len(frames) and mixed[len(frames)].shape == frames[0].shape


def test_per_item_static_drop_matches_whole_batch_drops():
    model = small_model()
    for p in model.renderer.parameters():  # open the zero-initialised gates so tokens matter
        if p.abs().sum() == 0:
            torch.nn.init.normal_(p, std=0.1)
    batch = random_batch(model.config, B=2)
    z_s, z_d = model.encode(batch)
    cfg = model.config
    y = torch.randn(2, cfg.frames, cfg.latent_channels, cfg.latent_size, cfg.latent_size)
    rays, tau = model.rays(batch.K, batch.w2c), torch.full((2,), 0.5)
    mixed = model.renderer(y, z_s, z_d, rays, tau, drop_static=torch.tensor([True, False]))
    dropped = model.renderer(y, z_s, z_d, rays, tau, drop_static=True)
    kept = model.renderer(y, z_s, z_d, rays, tau)
    assert torch.allclose(mixed[0], dropped[0], atol=1e-6) and torch.allclose(mixed[1], kept[1], atol=1e-6)
    assert not torch.allclose(dropped[0], kept[0])


def test_render_patch_size_keeps_old_hashes_and_shapes_the_renderer_only():
    base = get_config("tiny", **SMALL)
    assert get_config("tiny", **SMALL, render_patch_size=0).sha256() == base.sha256()
    assert "render_patch_size" not in base.canonical_json()
    fine = get_config("tiny", **SMALL, render_patch_size=1)
    assert fine.sha256() != base.sha256() and fine.renderer_patch == 1 and base.renderer_patch == base.patch_size
    model = VideoTok4D(fine).eval()
    assert model.renderer.pos_space.shape[0] == fine.latent_size ** 2
    assert model.spatial_branch.pos_space.shape[0] == fine.patches_per_side ** 2
    batch = random_batch(fine, B=2)
    z_s, z_d = model.encode(batch)
    frames = model.render(z_s, z_d, batch.K, batch.w2c, steps=1)
    assert frames.shape == batch.frames.shape
    for bad in (-1, 3, True, 2.0):  # 3 does not divide the 8-pixel latent
        with pytest.raises(ModelError):
            get_config("tiny", **SMALL, render_patch_size=bad)


def test_masked_attention_adds_the_bias_and_keeps_invalid_keys_out():
    from vt4dcodec.model.layers import masked_attention

    g = torch.Generator().manual_seed(0)
    q, k, v = (torch.randn(2, 3, 5, 4, generator=g) for _ in range(3))
    bias = torch.randn(3, 5, 6 - 1, generator=g)
    bias = torch.cat([bias, torch.zeros(3, 5, 1)], dim=-1)
    k, v = torch.cat([k, k[:, :, :1]], dim=2), torch.cat([v, v[:, :, :1]], dim=2)
    valid = torch.tensor([[True] * 5 + [False], [False] * 6])
    out = masked_attention(q, k, v, valid, bias)
    logits = q @ k.transpose(-1, -2) / 2.0 + bias[None]
    logits = logits.masked_fill(~valid[:, None, None, :], float("-inf"))
    want = logits[:1].softmax(-1) @ v[:1]
    torch.testing.assert_close(out[:1], want, atol=1e-5, rtol=1e-5)
    assert torch.equal(out[1], torch.zeros_like(out[1]))  # no valid key: exactly zero, no NaN
    torch.testing.assert_close(masked_attention(q, k, v, None, bias),
                               (q @ k.transpose(-1, -2) / 2.0 + bias[None]).softmax(-1) @ v, atol=1e-5, rtol=1e-5)


def test_locality_prior_anchors_static_queries_and_renderer_tokens():
    base = get_config("tiny", **SMALL)
    assert get_config("tiny", **SMALL, locality_sigma=0.0).sha256() == base.sha256()
    assert VideoTok4D(base).spatial_branch.query_bias is None and VideoTok4D(base).renderer.token_bias is None
    cfg = get_config("tiny", **SMALL, locality_sigma=1.0)
    assert cfg.sha256() != base.sha256()
    model = VideoTok4D(cfg).eval()
    P = cfg.patches_per_side ** 2
    qb = model.spatial_branch.query_bias.detach()
    assert qb.shape == (cfg.heads, cfg.n_static, P)
    # the first half of the heads prefer the anchor cell (i mod P); the rest read anywhere
    for i in range(cfg.n_static):
        assert int(qb[0, i].argmax()) == i % P and float(qb[0, i].max()) == 0.0
    assert torch.equal(qb[cfg.heads // 2:], torch.zeros_like(qb[cfg.heads // 2:]))
    tb = model.renderer.token_bias.detach()
    assert tb.shape == (cfg.heads, P, cfg.n_static + cfg.n_dynamic)
    assert torch.equal(tb[:, :, cfg.n_static:], torch.zeros_like(tb[:, :, cfg.n_static:]))  # Z_d unanchored
    assert int(tb[0, 3, :cfg.n_static].argmax()) % P == 3
    batch = random_batch(cfg, B=2)
    z_s, z_d = model.encode(batch)
    assert model.render(z_s, z_d, batch.K, batch.w2c, steps=1).shape == batch.frames.shape
    unified = VideoTok4D(get_config("tiny", **SMALL, locality_sigma=1.0, unified_tokens=True))
    assert unified.renderer.token_bias[0, :, -1].abs().sum() > 0  # every unified token is anchored
    with pytest.raises(ModelError):
        get_config("tiny", **SMALL, locality_sigma=-1.0)


def test_query_from_grid_starts_as_the_model_without_it_and_reads_the_anchor_cell():
    base = get_config("tiny", **SMALL, locality_sigma=1.0)
    cfg = get_config("tiny", **SMALL, locality_sigma=1.0, query_from_grid=True)
    assert get_config("tiny", **SMALL, locality_sigma=1.0, query_from_grid=False).sha256() == base.sha256()
    assert cfg.sha256() != base.sha256()
    torch.manual_seed(0)
    old = VideoTok4D(base).eval()
    new = VideoTok4D(cfg).eval()
    missing, unexpected = new.load_state_dict(old.state_dict(), strict=False)
    assert sorted(missing) == ["spatial_branch.query_content.bias", "spatial_branch.query_content.weight"]
    assert not unexpected
    batch = random_batch(cfg, B=2)
    with torch.no_grad():  # the map starts at zero: a warm start begins exactly where the old model was
        for a, b in zip(old.encode(batch), new.encode(batch)):
            torch.testing.assert_close(a, b)
    # once the map is non-zero, query i starts from W * (its anchor cell's feature averaged over frames)
    P = cfg.patches_per_side ** 2
    branch = new.spatial_branch
    assert branch.anchor.tolist() == [i % P for i in range(cfg.n_static)]
    with torch.no_grad():
        branch.query_content.weight.normal_(std=0.5)
        branch.query_blocks = torch.nn.ModuleList()  # no cross-attention: the start state is the output
        h = cfg.latent_size
        latents, rays = torch.randn(2, cfg.frames, cfg.latent_channels, h, h), torch.randn(2, cfg.frames, 6, h, h)
        q = branch(latents, rays)
        x = branch.embed(patchify(torch.cat([latents, rays], dim=2), cfg.patch_size))
        x = x + branch.pos_space[None, None] + branch.pos_time[None, :, None]
        for block in branch.blocks:
            x = block(x)
        want = branch.queries[None] + branch.query_content(x.mean(1)[:, torch.arange(cfg.n_static) % P])
        torch.testing.assert_close(q, want)
    with pytest.raises(ModelError, match="locality_sigma"):
        get_config("tiny", **SMALL, query_from_grid=True)
    with pytest.raises(ModelError, match="query_from_grid"):
        get_config("tiny", **SMALL, locality_sigma=1.0, query_from_grid=1)


def test_projected_anchors_equal_the_grid_prior_at_the_source_and_follow_the_target_pose():
    base = get_config("tiny", **SMALL, locality_sigma=0.5)
    cfg = get_config("tiny", **SMALL, locality_sigma=0.5, project_anchors=True)
    assert get_config("tiny", **SMALL, locality_sigma=0.5, project_anchors=False).sha256() == base.sha256()
    assert cfg.sha256() != base.sha256()
    torch.manual_seed(0)
    old, new = VideoTok4D(base).eval(), VideoTok4D(cfg).eval()
    missing, unexpected = new.load_state_dict(old.state_dict(), strict=False)
    assert sorted(missing) == ["renderer.depth_head.bias", "renderer.depth_head.weight"]
    assert unexpected == ["renderer.token_bias"]
    assert new.needs_source and not old.needs_source
    batch = random_batch(cfg, B=2)
    K, w2c = batch.K[:, :1].expand_as(batch.K).clone(), batch.w2c[:, :1].expand_as(batch.w2c).clone()  # static
    z_s, z_d = new.encode(batch)
    r = new.renderer
    # at the source camera every anchor lands on its own cell, whatever its depth: the grid prior
    bias = r.projected_bias(z_s, z_d, K, w2c, K[:, 0], w2c[:, 0])
    T, P, n = cfg.frames, cfg.renderer_patches_per_side ** 2, cfg.n_static + cfg.n_dynamic
    assert bias.shape == (2, cfg.heads, T * P, n)
    grid = old.renderer.token_bias.detach().repeat(1, T, 1)
    torch.testing.assert_close(bias[0], grid.clamp_min(-1.0e4), atol=1e-3, rtol=1e-4)
    h = cfg.latent_size
    y, tau = torch.randn(2, T, cfg.latent_channels, h, h), torch.full((2,), 0.7)
    with torch.no_grad():  # so a warm start renders its source view exactly as before
        v_old = old.velocity(y, z_s, z_d, old.rays(K, w2c), tau)
        v_new = new.velocity(y, z_s, z_d, new.rays(K, w2c), tau, cameras=new.render_cameras(K, w2c, (K, w2c)))
    torch.testing.assert_close(v_old, v_new, atol=1e-4, rtol=1e-4)
    # a target camera moved 0.5 m along its own x axis sees every anchor shifted left by f * 0.5 / depth
    moved = w2c.clone()
    moved[..., 0, 3] -= 0.5
    depth = r.anchor_depths(z_s, z_d, w2c[:, 0])  # (B, Na): the world origin's depth at initialisation
    assert torch.allclose(depth, w2c[:, 0, 2, 3, None].expand_as(depth))
    shifted = r.projected_bias(z_s, z_d, K, moved, K[:, 0], w2c[:, 0])
    assert not torch.allclose(shifted, bias)
    f, cell_px = float(K[0, 0, 0, 0]), cfg.image_size / cfg.patches_per_side
    shift_cells = f * 0.5 / float(depth[0, 0].detach()) / cell_px
    side = cfg.renderer_patches_per_side
    # token anchored at cell (row 1, col side-1) now peaks about shift_cells columns to the left
    token = 1 * side + side - 1
    peak = int(shifted[0, 0, :P, token].argmax())
    assert abs((side - 1 - peak % side) - shift_cells) <= 0.5 + 1e-6 and peak // side == 1
    # tokens that end up behind the target camera get the floor logit
    behind = w2c.clone()
    behind[..., :3, :3] = -behind[..., :3, :3]
    behind[..., :3, 3] = -behind[..., :3, 3]
    far = r.projected_bias(z_s, z_d, K, behind, K[:, 0], w2c[:, 0])
    assert float(far[:, 0, :, :cfg.n_static].max()) == -1.0e4
    assert torch.equal(far[:, cfg.heads // 2:], torch.zeros_like(far[:, cfg.heads // 2:]))
    # rendering needs the source trajectory, and says so
    with pytest.raises(ModelError, match="source"):
        new.render(z_s, z_d, K, w2c, steps=1)
    assert new.render(z_s, z_d, K, w2c, steps=1, source=batch.source).shape == batch.frames.shape
    loss, _ = new.rectified_flow_loss(batch, batch.frames, K, w2c)
    loss.backward()
    assert new.renderer.depth_head.weight.grad is not None
    with pytest.raises(ModelError, match="locality_sigma"):
        get_config("tiny", **SMALL, project_anchors=True)
