"""The learned VideoTok4D networks: shapes (tiny and paper), gradients, track isolation, masks,
token masking, determinism, and the config contract."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from vt4dcodec.errors import ModelError
from vt4dcodec.model import SourceBatch, VideoTok4D, get_config
from vt4dcodec.model.layers import masked_attention, patchify, unpatchify
from vt4dcodec.model.rays import latent_rays
from vt4dcodec.model.temporal_branch import TrackAttention, fixed_grid_tracks, sample_at_tracks

from network_fixtures import orbit_cameras, random_batch

torch.set_num_threads(1)
TINY = get_config("tiny")


@pytest.fixture(scope="module")
def tiny_model() -> VideoTok4D:
    torch.manual_seed(0)
    model = VideoTok4D(TINY)
    model.freeze_autoencoder()
    return model.eval()


# --- configs --------------------------------------------------------------------------------------
def test_tiny_budget_and_paper_token_counts():
    video_values = TINY.frames * TINY.image_size ** 2 * 3
    assert TINY.n_static == 2 * TINY.n_dynamic
    assert video_values / 64 <= TINY.token_floats <= video_values / 16
    assert TINY.latent_size == 16 and TINY.latent_channels == 4
    paper = get_config("paper")
    assert (paper.frames, paper.image_size, paper.n_static, paper.n_dynamic, paper.token_dim) == (32, 256, 1024, 512, 64)
    assert paper.token_floats == 98_304


def test_config_round_trip_and_hash():
    cfg = get_config("tiny", unified_tokens=True)
    assert type(cfg).from_dict(cfg.to_dict()) == cfg
    assert cfg.sha256() == get_config("tiny", unified_tokens=True).sha256()
    assert cfg.sha256() != TINY.sha256()
    assert len(TINY.sha256()) == 64


@pytest.mark.parametrize("bad", [dict(width=130, heads=4), dict(n_static=0), dict(ae_downsample=3),
                                 dict(frames=True), dict(bogus=1), dict(image_size=66)])
def test_bad_configs_raise_model_error(bad):
    with pytest.raises(ModelError):
        get_config("tiny", **bad)
    with pytest.raises(ModelError):
        get_config("huge")


# --- shapes ---------------------------------------------------------------------------------------
def test_tiny_shapes_encode_render(tiny_model):
    batch = random_batch(TINY, B=2)
    z_s, z_d = tiny_model.encode(batch)
    assert z_s.shape == (2, 64, 32) and z_d.shape == (2, 32, 32)
    assert z_s.dtype == torch.float32 and z_s.abs().max() < 1 and z_d.abs().max() < 1
    lat = tiny_model.render_latents(z_s, z_d, batch.K[:, :5], batch.w2c[:, :5], steps=2)
    assert lat.shape == (2, 5, 4, 16, 16)
    frames = tiny_model.render(z_s, z_d, batch.K, batch.w2c, steps=2)
    assert frames.shape == (2, 8, 3, 64, 64) and 0 <= frames.min() and frames.max() <= 1


@pytest.mark.parametrize("ablation", [dict(unified_tokens=True), dict(motion_isolation=False),
                                      dict(track_attention=False)])
def test_ablations_keep_the_token_budget(ablation):
    torch.manual_seed(0)
    cfg = get_config("tiny", **ablation)
    model = VideoTok4D(cfg).eval()
    z_s, z_d = model.encode(random_batch(cfg, B=1))
    assert z_s.shape == (1, 64, 32) and z_d.shape == (1, 32, 32)
    if cfg.unified_tokens:
        assert model.temporal_branch is None


def test_paper_config_shapes_on_meta_device():
    cfg = get_config("paper")
    with torch.device("meta"):
        model = VideoTok4D(cfg)
        B, T, H, h, N = 1, cfg.frames, cfg.image_size, cfg.latent_size, cfg.n_tracks
        batch = SourceBatch(frames=torch.empty(B, T, 3, H, H), K=torch.empty(B, T, 3, 3), w2c=torch.empty(B, T, 4, 4),
                            motion_mask=torch.empty(B, T, h, h), track_xy=torch.empty(B, N, T, 2),
                            track_valid=torch.empty(B, N, T, dtype=torch.bool))
        z_s, z_d = model.encode(batch)
        v = model.renderer(torch.empty(B, T, cfg.latent_channels, h, h), z_s, z_d,
                           model.rays(batch.K, batch.w2c), torch.empty(B))
    assert z_s.shape == (1, 1024, 64) and z_d.shape == (1, 512, 64)
    assert v.shape == (1, 32, cfg.latent_channels, 32, 32)


def test_bad_inputs_raise_model_error(tiny_model):
    batch = random_batch(TINY, B=1)
    wrong = SourceBatch(**{**batch.__dict__, "frames": batch.frames[..., :32, :32]})
    with pytest.raises(ModelError):
        tiny_model.encode(wrong)
    with pytest.raises(ModelError):
        tiny_model.encode(SourceBatch(**{**batch.__dict__, "motion_mask": batch.motion_mask[..., :8]}))
    nan_frames = batch.frames.clone()
    nan_frames[0, 1, 2, 3, 4] = float("nan")
    with pytest.raises(ModelError):
        tiny_model.encode(SourceBatch(**{**batch.__dict__, "frames": nan_frames}))
    no_tracks = SourceBatch(**{**batch.__dict__, "track_xy": batch.track_xy[:, :0],
                               "track_valid": batch.track_valid[:, :0]})
    assert torch.isfinite(tiny_model.encode(no_tracks)[1]).all()  # zero tracks is legal (N = 0)
    z_s, z_d = tiny_model.encode(batch)
    with pytest.raises(ModelError):
        tiny_model.render(z_s[:, :10], z_d, batch.K, batch.w2c)
    nan_K = batch.K.clone()
    nan_K[0, 0, 0, 0] = float("nan")
    with pytest.raises(ModelError):
        tiny_model.render(z_s, z_d, nan_K, batch.w2c)
    with pytest.raises(ModelError):
        tiny_model.render(z_s, z_d, batch.K, batch.w2c, steps=0)


# --- gradients ------------------------------------------------------------------------------------
def test_every_parameter_gets_a_gradient():
    torch.manual_seed(0)
    model = VideoTok4D(TINY)
    model.freeze_autoencoder()
    batch = random_batch(TINY, B=2, mask_density=0.3)
    target = torch.rand(2, TINY.frames, 3, 64, 64)
    params = model.tokenizer_parameters()
    opt = torch.optim.SGD(params, lr=0.05)
    for _ in range(3):  # zero-initialised gates and output (DiT) open the token path by step 3
        opt.zero_grad()
        loss, logs = model.rectified_flow_loss(batch, target, batch.K, batch.w2c)
        loss.backward()
        opt.step()
    dead = [name for name, p in model.named_parameters()
            if not name.startswith("autoencoder.") and (p.grad is None or p.grad.abs().sum() == 0)]
    assert dead == []
    assert all(p.grad is None for p in model.autoencoder.parameters())  # frozen in stage 2
    # stage 1: the autoencoder's reconstruction loss reaches every autoencoder parameter
    ae = VideoTok4D(TINY).autoencoder
    images = torch.rand(2, 3, 64, 64)
    torch.nn.functional.mse_loss(ae.decode_raw(ae.encode_raw(images)), images).backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in ae.parameters())


# --- track-aware attention ------------------------------------------------------------------------
@settings(max_examples=20)
@given(n_tracks=st.integers(2, 6), frames=st.integers(1, 6), seed=st.integers(0, 10_000))
def test_track_attention_never_mixes_tracks(n_tracks, frames, seed):
    torch.manual_seed(seed)
    layer = TrackAttention(16, 2, 2.0)
    g = torch.randn(2, n_tracks, frames, 16, requires_grad=True)
    valid = torch.rand(2, n_tracks, frames) < 0.6
    valid[0, 0] = False  # one track invalid everywhere
    out = layer(g, valid)
    assert torch.isfinite(out).all()
    i = seed % n_tracks
    out[:, i].sum().backward()
    grad = g.grad.abs().sum(dim=(2, 3))  # (B, N)
    others = torch.ones(n_tracks, dtype=torch.bool)
    others[i] = False
    assert torch.all(grad[:, others] == 0), "track i's output depends on another track"
    # invalid frames of track i are neither read (masked keys) nor written (zero output)
    assert torch.all(out[~valid] == 0)
    read = g.grad[:, i].abs().sum(-1) > 0  # (B, T) frames of track i that influence its outputs
    assert not torch.any(read & ~valid[:, i])


def test_temporal_branch_ignores_latents_outside_the_mask(tiny_model):
    batch = random_batch(TINY, B=1, mask_density=0.25)
    latents = tiny_model.latents(batch.frames).requires_grad_(True)
    rays = tiny_model.rays(batch.K, batch.w2c)
    out = tiny_model.temporal_branch(latents, rays, batch.motion_mask, batch.track_xy, batch.track_valid)
    out.sum().backward()
    outside = (batch.motion_mask == 0)[:, :, None].expand_as(latents)
    assert torch.all(latents.grad[outside] == 0)
    assert latents.grad[~outside].abs().sum() > 0


def test_empty_masks_and_no_valid_tracks_stay_finite(tiny_model):
    batch = random_batch(TINY, B=1)
    batch.motion_mask.zero_()
    batch.track_valid.zero_()
    z_s, z_d = tiny_model.encode(batch)
    assert torch.isfinite(z_s).all() and torch.isfinite(z_d).all()


def test_sample_at_tracks_hits_pixel_centres():
    feats = torch.arange(2 * 3 * 5 * 7, dtype=torch.float32).view(1, 2, 3, 5, 7)  # (B,T,D,h,w)
    xy = torch.tensor([[[[0.0, 0.0], [6.0, 4.0]], [[3.0, 2.0], [2.5, 1.0]]]])  # (1, N=2, T=2, 2)
    g = sample_at_tracks(feats, xy)
    assert g.shape == (1, 2, 2, 3)
    assert torch.allclose(g[0, 0, 0], feats[0, 0, :, 0, 0])
    assert torch.allclose(g[0, 0, 1], feats[0, 1, :, 4, 6])
    assert torch.allclose(g[0, 1, 0], feats[0, 0, :, 2, 3])
    assert torch.allclose(g[0, 1, 1], 0.5 * (feats[0, 1, :, 1, 2] + feats[0, 1, :, 1, 3]))


def test_fixed_grid_tracks_are_stationary_and_valid():
    xy, valid = fixed_grid_tracks(2, 64, 8, 16, torch.device("cpu"))
    assert xy.shape == (2, 64, 8, 2) and valid.all()
    assert torch.equal(xy[:, :, :1].expand_as(xy), xy)
    assert xy.min() >= 0 and xy.max() <= 15 and len(torch.unique(xy[0, :, 0], dim=0)) == 64


def test_masked_attention_with_no_valid_keys_is_zero():
    q, k, v = (torch.randn(3, 2, 4, 8) for _ in range(3))
    valid = torch.tensor([[True, False, False, True, False], [False] * 5, [True] * 5])
    out = masked_attention(q, k[:, :, :1].expand(3, 2, 5, 8), v[:, :, :1].expand(3, 2, 5, 8), valid)
    assert torch.isfinite(out).all() and torch.all(out[1] == 0) and out[0].abs().sum() > 0


@settings(max_examples=30)
@given(p=st.sampled_from([1, 2, 4]), c=st.integers(1, 5), hp=st.integers(1, 4), wp=st.integers(1, 4))
def test_patchify_round_trip(p, c, hp, wp):
    x = torch.randn(2, 3, c, hp * p, wp * p)
    patches = patchify(x, p)
    assert patches.shape == (2, 3, hp * wp, c * p * p)
    assert torch.equal(unpatchify(patches, p, c, hp * p, wp * p), x)


# --- rendering ------------------------------------------------------------------------------------
def test_render_is_deterministic_per_seed_and_never_reencodes(tiny_model, monkeypatch):
    batch = random_batch(TINY, B=1)
    z_s, z_d = tiny_model.encode(batch)

    def forbidden(*args, **kwargs):
        raise AssertionError("render must not run the encoder")

    monkeypatch.setattr(tiny_model.spatial_branch, "forward", forbidden)
    monkeypatch.setattr(tiny_model.temporal_branch, "forward", forbidden)
    K2, w2c2 = orbit_cameras(1, TINY.frames, 64, seed=7)
    a = tiny_model.render(z_s, z_d, batch.K, batch.w2c, steps=3, seed=5)
    b = tiny_model.render(z_s, z_d, batch.K, batch.w2c, steps=3, seed=5)
    c = tiny_model.render(z_s, z_d, batch.K, batch.w2c, steps=3, seed=6)
    other_view = tiny_model.render(z_s, z_d, K2, w2c2, steps=3, seed=5)
    assert torch.equal(a, b)
    assert not torch.equal(a, c)
    assert other_view.shape == a.shape


def test_token_masking_changes_the_velocity(tiny_model):
    torch.manual_seed(1)
    renderer = tiny_model.renderer
    with torch.no_grad():  # untrained gates are zero: give them values so tokens matter
        for p in renderer.parameters():
            if p.abs().sum() == 0:
                p.normal_(0, 0.05)
    batch = random_batch(TINY, B=1)
    z_s, z_d = tiny_model.encode(batch)
    y = torch.randn(1, TINY.frames, 4, 16, 16)
    rays, tau = tiny_model.rays(batch.K, batch.w2c), torch.tensor([0.5])
    full = renderer(y, z_s, z_d, rays, tau)
    no_s = renderer(y, z_s, z_d, rays, tau, drop_static=True)
    no_d = renderer(y, z_s, z_d, rays, tau, drop_dynamic=True)
    neither = renderer(y, z_s, z_d, rays, tau, drop_static=True, drop_dynamic=True)
    assert not torch.allclose(full, no_s) and not torch.allclose(full, no_d)
    assert torch.isfinite(neither).all()
    # dropping Z_s makes the output independent of Z_s
    assert torch.allclose(no_s, renderer(y, torch.rand_like(z_s), z_d, rays, tau, drop_static=True), atol=1e-6)


def test_bottleneck_is_bounded_with_int8_sized_training_noise():
    from vt4dcodec.model.bottleneck import TokenBottleneck

    torch.manual_seed(0)
    neck = TokenBottleneck(16, 8, noise=1 / 254)
    h = torch.randn(4, 10, 16) * 100
    neck.eval()
    clean = neck(h)
    assert clean.abs().max() <= 1
    neck.train()
    noisy = neck(h)
    assert (noisy - clean).abs().max() <= 1 / 254 + 1e-6 and not torch.equal(noisy, clean)


def test_latent_rays_follow_the_pixel_centre_convention():
    K, w2c = orbit_cameras(1, 2, 64, seed=3)
    rays = latent_rays(K, w2c, 64, 16)
    assert rays.shape == (1, 2, 6, 16, 16)
    d = rays[:, :, :3]
    assert torch.allclose(d.norm(dim=2), torch.ones(1, 2, 16, 16), atol=1e-5)
    # the latent map's centre (7.5, 7.5) is the image centre (31.5, 31.5): the optical axis
    centre_dir = d[..., 7:9, 7:9].mean(dim=(-1, -2))
    axis = w2c[:, :, 2, :3]  # camera z axis in world coordinates
    assert torch.allclose(torch.nn.functional.normalize(centre_dir, dim=-1), axis, atol=1e-3)


def test_tracks_and_masks_reach_only_the_dynamic_tokens(tiny_model):
    batch = random_batch(TINY, B=1, mask_density=0.3)
    z_s, z_d = tiny_model.encode(batch)
    moved = SourceBatch(**{**batch.__dict__, "track_xy": batch.track_xy.flip(1)})
    z_s2, z_d2 = tiny_model.encode(moved)
    masked = SourceBatch(**{**batch.__dict__, "motion_mask": torch.ones_like(batch.motion_mask)})
    z_s3, z_d3 = tiny_model.encode(masked)
    assert torch.equal(z_s, z_s2) and torch.equal(z_s, z_s3)  # Z_s = E_s(X, P_s) only
    assert not torch.allclose(z_d, z_d2) and not torch.allclose(z_d, z_d3)
