"""The token splat (config ``token_splat``): anchored static tokens reach the clean-latent estimate directly."""

from __future__ import annotations

import pytest
import torch

from vt4dcodec.errors import ModelError
from vt4dcodec.model import VideoTok4D, get_config
from vt4dcodec.model.renderer import SPLAT_FLOOR

from network_fixtures import random_batch

SMALL = dict(frames=4, image_size=32, width=32, heads=2, ae_width=8, spatial_layers=1, static_query_layers=1,
             track_layers=1, renderer_layers=1, n_static=16, n_dynamic=4, token_dim=8, n_tracks=8, patch_size=2)  # one token per cell
SPLAT = dict(locality_sigma=0.35, query_from_grid=True, project_anchors=True, prediction="x0")


def small_model(seed: int = 0, **overrides) -> VideoTok4D:
    torch.manual_seed(seed)
    return VideoTok4D(get_config("tiny", **{**SMALL, **overrides})).eval()


def _velocity(model, batch, y, tau, **drop):
    z = model.encode(batch)
    return model.velocity(y, *z, model.rays(batch.K, batch.w2c), tau,
                          cameras=model.render_cameras(batch.K, batch.w2c, batch.source), **drop)


def test_config_hash_is_kept_while_off_and_the_switch_needs_projected_anchors_and_x0():
    base = get_config("tiny", **SMALL, **SPLAT)
    assert get_config("tiny", **SMALL, **SPLAT, token_splat=False).sha256() == base.sha256()
    assert get_config("tiny", **SMALL, **SPLAT, token_splat=True).sha256() != base.sha256()
    with pytest.raises(ModelError, match="token_splat"):
        get_config("tiny", **SMALL, **{**SPLAT, "prediction": "velocity"}, token_splat=True)
    with pytest.raises(ModelError, match="token_splat"):
        get_config("tiny", **SMALL, **{**SPLAT, "project_anchors": False}, token_splat=True)
    with pytest.raises(ModelError, match="token_splat"):
        get_config("tiny", **SMALL, **SPLAT, token_splat=1)


def test_a_warm_start_renders_exactly_as_the_model_without_it():
    base, splat = small_model(**SPLAT), small_model(**SPLAT, token_splat=True)
    missing, unexpected = splat.load_state_dict(base.state_dict(), strict=False)
    assert sorted(missing) == ["renderer.splat.bias", "renderer.splat.weight", "renderer.splat_in.bias",
                               "renderer.splat_in.weight"] and not unexpected
    with torch.no_grad():  # give the shared zero-initialised output layers some weight, as a trained model has
        for model in (base, splat):
            torch.manual_seed(1)
            for layer in (model.renderer.out, model.renderer.final_mod):
                layer.weight.normal_(std=0.1)
    cfg, h = base.config, base.config.latent_size
    batch = random_batch(cfg, B=2)
    y, tau = torch.randn(2, cfg.frames, cfg.latent_channels, h, h), torch.full((2,), 0.7)
    with torch.no_grad():
        torch.testing.assert_close(_velocity(splat, batch, y, tau), _velocity(base, batch, y, tau))


def test_at_the_source_camera_each_patch_reads_its_own_token_and_dropped_tokens_add_nothing():
    model = small_model(**SPLAT, token_splat=True)
    cfg, r = model.config, model.renderer
    batch = random_batch(cfg, B=2)
    # a static trajectory: every frame at the source camera's first pose
    K = batch.K[:, :1].expand(-1, cfg.frames, -1, -1).clone()
    w2c = batch.w2c[:, :1].expand(-1, cfg.frames, -1, -1).clone()
    with torch.no_grad():
        z_s, z_d = model.encode(batch)
        cams = model.render_cameras(K, w2c, (K, w2c))
        logit = r.projected_logit(z_s, z_d, *cams)  # (B, T, P, Na)
        r.splat.weight.normal_()
        content = r.splat(z_s)  # (B, N_s, C p p)
        splat = r.splat_latent(z_s, z_d, logit, None)
        g = torch.exp(logit)
        own = (g / (g.sum(-1, keepdim=True) + SPLAT_FLOOR)).diagonal(dim1=-2, dim2=-1)  # token j on patch j
        assert bool((own > 0.85).all())  # 1 / (1 + SPLAT_FLOOR + the neighbours' small share)
        torch.testing.assert_close(splat[:, 0], content, atol=0.2 * float(content.abs().max()), rtol=0)
        keep = torch.ones(2, cfg.n_static + cfg.n_dynamic, dtype=torch.bool)
        keep[:, :cfg.n_static] = False
        assert float(r.splat_latent(z_s, z_d, logit, keep).abs().max()) == 0.0
        # and the renderer adds it to its clean-latent estimate: v = (y - x0_hat) / tau
        h = cfg.latent_size
        y, tau = torch.randn(2, cfg.frames, cfg.latent_channels, h, h), torch.full((2,), 1.0)
        rays = model.rays(K, w2c)
        with_splat = model.velocity(y, z_s, z_d, rays, tau, cameras=cams)
        r.splat.weight.zero_()
        r.splat.bias.zero_()
        without = model.velocity(y, z_s, z_d, rays, tau, cameras=cams)
        assert float((with_splat - without).abs().max()) > 1e-3


def test_the_cell_loss_asks_each_token_for_its_own_cameras_cell_averaged_over_the_frames():
    import dataclasses

    import torch.nn.functional as F

    from vt4dcodec.model.layers import patchify

    model = small_model(**SPLAT, token_splat=True, anchor_views=True)
    cfg, r = model.config, model.renderer
    batch = random_batch(cfg, B=4)
    pair = dataclasses.replace(batch, views=2)  # scenes (0, 1) and (2, 3)
    with torch.no_grad():
        r.splat.weight.normal_()
        z_s, _ = model.encode(pair)
        loss = model.cell_loss(pair, z_s)
        x = model.latents(pair.frames).mean(1, keepdim=True)
        cells = patchify(x, cfg.patch_size)[:, 0]  # (4, P, C p p)
        want = torch.stack([torch.stack([cells[2 * s + i % 2, i % cells.shape[1]] for i in range(cfg.n_static)])
                            for s in range(2)])
        torch.testing.assert_close(loss, F.mse_loss(r.splat(z_s), want))
        with pytest.raises(ModelError, match="token_splat"):
            small_model(**SPLAT).cell_loss(pair, z_s)
    # and it enters the training loss with its weight, logged
    loss0, logs0 = model.rectified_flow_loss(pair, batch.frames[::2], batch.K[::2], batch.w2c[::2],
                                             torch.Generator().manual_seed(0))
    loss1, logs1 = model.rectified_flow_loss(pair, batch.frames[::2], batch.K[::2], batch.w2c[::2],
                                             torch.Generator().manual_seed(0), cell_weight=2.0)
    assert logs0["cell_mse"] == 0.0 and logs1["cell_mse"] > 0
    torch.testing.assert_close(loss1 - loss0, torch.tensor(2.0 * logs1["cell_mse"]), atol=1e-4, rtol=1e-4)


def test_token_from_cell_starts_as_the_model_without_it_and_feeds_each_token_its_own_cameras_cell():
    import dataclasses

    base = small_model(**SPLAT, token_splat=True, anchor_views=True)
    direct = small_model(**SPLAT, token_splat=True, anchor_views=True, token_from_cell=True)
    assert sorted(direct.load_state_dict(base.state_dict(), strict=False).missing_keys) == [
        "cell_direct.bias", "cell_direct.weight"]
    cfg = base.config
    pair = dataclasses.replace(random_batch(cfg, B=4), views=2)
    with torch.no_grad():
        torch.testing.assert_close(direct.encode(pair)[0], base.encode(pair)[0])
        direct.cell_direct.weight.normal_()
        a_base, _ = base.encode_preactivations(pair)
        a_direct, _ = direct.encode_preactivations(pair)
        cells = direct.token_cells(direct.latents(pair.frames), 2)
        torch.testing.assert_close(a_direct - a_base, direct.cell_direct(cells), atol=1e-4, rtol=1e-4)
        # camera 1 of scene 0 changes: only the tokens anchored in it (odd i) see it through the direct path
        frames = pair.frames.clone()
        frames[1] = torch.rand_like(frames[1])
        moved = direct.token_cells(direct.latents(frames), 2) - cells
        assert bool((moved[0, 1::2].abs().amax(-1) > 1e-6).all()) and float(moved[0, 0::2].abs().max()) == 0.0
        assert float(moved[1].abs().max()) == 0.0
    with pytest.raises(ModelError, match="token_from_cell"):
        get_config("tiny", **SMALL, locality_sigma=0.35, token_from_cell=True)
    with pytest.raises(ModelError, match="token_from_cell"):
        get_config("tiny", **SMALL, **SPLAT, token_from_cell="yes")


def test_the_ssim_term_is_one_minus_the_evaluations_ssim_of_the_decoded_one_step_estimate():
    import kornia

    model = small_model(**SPLAT)
    cfg = model.config
    batch = random_batch(cfg, B=2)
    loss0, logs0 = model.rectified_flow_loss(batch, batch.frames, batch.K, batch.w2c, torch.Generator().manual_seed(0),
                                             tau=torch.ones(2))
    loss1, logs1 = model.rectified_flow_loss(batch, batch.frames, batch.K, batch.w2c, torch.Generator().manual_seed(0),
                                             tau=torch.ones(2), ssim_weight=0.5)
    assert logs0["ssim"] == 1.0 and 0.0 < logs1["ssim"] < 1.0
    torch.testing.assert_close(loss1 - loss0, torch.tensor(0.5 * (1.0 - logs1["ssim"])), atol=1e-4, rtol=1e-4)
    with torch.no_grad():  # the logged value is the evaluation's SSIM of the decoded x0 estimate at tau = 1
        z = model.encode(batch)
        h = cfg.latent_size
        x0 = model.renderer(torch.randn(2, cfg.frames, cfg.latent_channels, h, h), *z, model.rays(batch.K, batch.w2c),
                            torch.ones(2), cameras=model.render_cameras(batch.K, batch.w2c, batch.source))
        want = kornia.metrics.ssim(model.autoencoder.decode(x0).clamp(0, 1).flatten(0, 1),
                                   batch.frames.flatten(0, 1), 11).mean()
    assert abs(float(want) - logs1["ssim"]) < 0.05  # a different noise draw: close, not equal
