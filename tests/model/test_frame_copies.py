"""Frame copies (config ``frame_copies``): static tokens sharing an anchor split the clip's frames."""

from __future__ import annotations

import dataclasses

import pytest
import torch
import torch.nn.functional as F

from vt4dcodec.errors import ModelError
from vt4dcodec.model import VideoTok4D, get_config
from vt4dcodec.model.layers import patchify

from network_fixtures import random_batch

# 32 px, latent 8, patch 2: P = 16 cells; 80 static tokens = 5 per cell with one camera; 4 frames
SMALL = dict(frames=4, image_size=32, width=32, heads=2, ae_width=8, spatial_layers=1, static_query_layers=1,
             track_layers=1, renderer_layers=1, n_static=80, n_dynamic=4, token_dim=8, n_tracks=8, patch_size=2)
FULL = dict(locality_sigma=0.35, query_from_grid=True, project_anchors=True, prediction="x0", anchor_views=True,
            token_splat=True, token_from_cell=True)


def small_model(seed: int = 0, **overrides) -> VideoTok4D:
    torch.manual_seed(seed)
    return VideoTok4D(get_config("tiny", **{**SMALL, **FULL, **overrides})).eval()


def _render(model: VideoTok4D, batch, y, tau):
    z = model.encode(batch)
    return model.velocity(y, *z, model.rays(batch.K, batch.w2c), tau,
                          cameras=model.render_cameras(batch.K, batch.w2c, batch.source))


def test_config_hash_is_kept_while_off_and_the_switch_needs_the_cell_path_and_the_splat():
    base = get_config("tiny", **SMALL, **FULL)
    assert get_config("tiny", **SMALL, **FULL, frame_copies=False).sha256() == base.sha256()
    assert get_config("tiny", **SMALL, **FULL, frame_copies=True).sha256() != base.sha256()
    with pytest.raises(ModelError, match="frame_copies"):
        get_config("tiny", **SMALL, **{**FULL, "token_from_cell": False}, frame_copies=True)
    with pytest.raises(ModelError, match="frame_copies"):
        get_config("tiny", **SMALL, **{**FULL, "token_splat": False, "token_from_cell": False}, frame_copies=True)
    with pytest.raises(ModelError, match="frame_copies"):
        get_config("tiny", **SMALL, **FULL, frame_copies="yes")


def test_copies_of_an_anchor_split_the_frames_in_index_order():
    r = small_model(frame_copies=True).renderer
    one = r.copy_frames(1)  # 5 copies per cell: copy 0 none, copy k frame k - 1
    assert one.shape == (80, 4)
    assert float(one[:16].sum()) == 0.0
    for k in range(1, 5):
        assert torch.equal(one[16 * k:16 * (k + 1)], F.one_hot(torch.full((16,), k - 1), 4).float())
    # two cameras: token i sits in camera i mod 2, cell i mod 16 -- still 5 copies of 8 cells per camera
    assert torch.equal(r.copy_frames(2), one)
    # five cameras: every (camera, cell) has one token, so none is a copy
    assert float(r.copy_frames(5).sum()) == 0.0
    # three copies per anchor (n_static 48): copies 1 and 2 cover two frames each
    three = small_model(frame_copies=True, n_static=48).renderer.copy_frames(1)
    assert three[16:32].tolist() == [[1.0, 1.0, 0.0, 0.0]] * 16 and three[32:].tolist() == [[0.0, 0.0, 1.0, 1.0]] * 16
    assert float(small_model(frame_copies=False).renderer.copy_frames(1).sum()) == 0.0
    # each token's time-average copy: cell i mod 16's first token with one camera, itself with five
    assert r.copy_origin(1).tolist() == [i % 16 for i in range(80)]
    assert r.copy_origin(2).tolist() == [i % 16 for i in range(80)]
    assert r.copy_origin(5).tolist() == list(range(80))


def test_with_the_frame_maps_at_zero_it_encodes_and_renders_exactly_as_the_model_without_it():
    base, copies = small_model(), small_model(frame_copies=True)
    missing = copies.load_state_dict(base.state_dict(), strict=False).missing_keys
    assert sorted(missing) == ["cell_frames.bias", "cell_frames.weight", "renderer.splat_frames.bias",
                               "renderer.splat_frames.weight"]
    with torch.no_grad():  # (a fresh frame splat is random; it adds nothing only while copies are equal)
        copies.renderer.splat_frames.weight.zero_()
    with torch.no_grad():  # a trained model has non-zero direct paths and output layers
        for model in (base, copies):
            torch.manual_seed(1)
            for layer in (model.renderer.out, model.renderer.final_mod, model.renderer.splat, model.cell_direct):
                layer.weight.normal_(std=0.1)
    cfg, h = base.config, base.config.latent_size
    batch = random_batch(cfg, B=2)
    y, tau = torch.randn(2, cfg.frames, cfg.latent_channels, h, h), torch.full((2,), 0.7)
    with torch.no_grad():
        torch.testing.assert_close(copies.encode(batch)[0], base.encode(batch)[0])
        torch.testing.assert_close(_render(copies, batch, y, tau), _render(base, batch, y, tau))


def test_each_copy_reads_its_frame_groups_change_and_is_splatted_in_those_frames_only():
    model = small_model(frame_copies=True)
    cfg, r = model.config, model.renderer
    batch = random_batch(cfg, B=2)
    with torch.no_grad():
        x = model.latents(batch.frames)  # (2, T, C, h, w)
        cells = patchify(x.float(), cfg.patch_size)  # (2, T, P, C p p)
        change = model.token_frame_cells(x, 1)  # (2, 80, C p p)
        assert float(change[:, :16].abs().max()) == 0.0
        for k in range(1, 5):  # copy k: frame k - 1 minus the time average, cell i mod 16
            torch.testing.assert_close(change[:, 16 * k:16 * (k + 1)], cells[:, k - 1] - cells.mean(1))
        # the encoder's new path adds W * change to the copies only
        a0, _ = model.encode_preactivations(batch)
        model.cell_frames.weight.normal_()
        model.cell_frames.bias.normal_()
        a1, _ = model.encode_preactivations(batch)
        torch.testing.assert_close(a1[:, :16], a0[:, :16])
        torch.testing.assert_close(a1[:, 16:] - a0[:, 16:], model.cell_frames(change[:, 16:]), atol=1e-4, rtol=1e-4)
        # the copies of a cell now differ (equal queries, biases and slots in a grown set cannot do that)
        z_s, z_d = model.encode(batch)
        assert float((z_s[:, 16:32] - z_s[:, 32:48]).abs().max()) > 1e-3
        # renderer: only the copy covering frame t reaches frame t through splat_frames
        K = batch.K[:, :1].expand(-1, cfg.frames, -1, -1).clone()
        w2c = batch.w2c[:, :1].expand(-1, cfg.frames, -1, -1).clone()
        cams = model.render_cameras(K, w2c, (K, w2c))
        logit = r.projected_logit(z_s, z_d, *cams)
        frame_map = torch.randn_like(r.splat_frames.weight)

        def extra(z: torch.Tensor) -> torch.Tensor:  # what splat_frames adds, per target frame
            r.splat_frames.weight.zero_()
            without = r.splat_latent(z, z_d, logit, None)
            r.splat_frames.weight.copy_(frame_map)
            return r.splat_latent(z, z_d, logit, None) - without

        before = extra(z_s)
        assert float(before.abs().max()) > 1e-3
        other = z_s.clone()
        other[:, 48:64] = torch.rand_like(other[:, 48:64]) * 2 - 1  # the copies covering frame 2 change
        after = extra(other)
        for t in range(cfg.frames):
            if t == 2:
                assert float((after[:, t] - before[:, t]).abs().max()) > 1e-3
            else:
                torch.testing.assert_close(after[:, t], before[:, t])


def test_the_cell_loss_also_asks_each_copy_for_its_frame_groups_change():
    model = small_model(frame_copies=True)
    cfg, r = model.config, model.renderer
    batch = random_batch(cfg, B=2)
    with torch.no_grad():
        r.splat.weight.normal_()
        r.splat_frames.weight.normal_()
        z_s, _ = model.encode(batch)
        x = model.latents(batch.frames)
        difference = z_s[:, 16:] - z_s[:, :16].repeat(1, 4, 1)  # each copy minus its cell's copy 0
        want = F.mse_loss(r.splat(z_s), model.token_cells(x, 1)) \
            + F.mse_loss(r.splat_frames(difference), model.token_frame_cells(x, 1)[:, 16:])
        torch.testing.assert_close(model.cell_loss(batch, z_s), want)
    # and a two-camera batch runs end to end through training's loss
    pair = dataclasses.replace(random_batch(cfg, B=4), views=2)
    loss, logs = model.rectified_flow_loss(pair, pair.frames[::2], pair.K[::2], pair.w2c[::2],
                                           torch.Generator().manual_seed(0), cell_weight=1.0)
    assert torch.isfinite(loss) and logs["cell_mse"] > 0
    loss.backward()
    assert model.cell_frames.weight.grad is not None and float(model.cell_frames.weight.grad.abs().sum()) > 0
    assert float(r.splat_frames.weight.grad.abs().sum()) > 0
    # five cameras: no token is a copy, and the loss is the time-average term alone (not NaN)
    five = dataclasses.replace(random_batch(cfg, B=5), views=5)
    with torch.no_grad():
        z5, _ = model.encode(five)
        alone = F.mse_loss(r.splat(z5), model.token_cells(model.latents(five.frames), 5))
        torch.testing.assert_close(model.cell_loss(five, z5), alone)


def test_a_warm_start_from_a_model_without_it_starts_the_frame_maps_from_the_cell_and_splat_maps():
    from vt4dcodec.model.train.tokenizer import frame_copy_maps

    base = small_model()
    with torch.no_grad():
        for layer in (base.renderer.splat, base.cell_direct):
            layer.weight.normal_(std=0.1)
            layer.bias.normal_(std=0.1)
    old, new = base.config, base.config.replace(frame_copies=True)
    state = frame_copy_maps(base.state_dict(), old, new)
    model = VideoTok4D(new).eval()
    model.load_state_dict(state, strict=True)
    torch.testing.assert_close(model.cell_frames.weight, base.cell_direct.weight)
    torch.testing.assert_close(model.renderer.splat_frames.weight, base.renderer.splat.weight)
    assert float(model.cell_frames.bias.detach().abs().max()) == 0.0
    assert float(model.renderer.splat_frames.bias.detach().abs().max()) == 0.0
    # each copy now holds its frame group: copies of a cell differ where the clip changes
    with torch.no_grad():
        z_s, _ = model.encode(random_batch(new, B=1))
    assert float((z_s[0, 16:32] - z_s[0, :16]).abs().max()) > 1e-3
    # nothing to do when the saved model has them already, or the new one does not
    saved = model.state_dict()
    assert frame_copy_maps(saved, new, new) is saved
    assert frame_copy_maps(base.state_dict(), old, old) is not state
    plain = base.state_dict()
    assert frame_copy_maps(plain, old, old) is plain


def test_a_fresh_model_starts_off_the_saddle_of_two_zero_maps():
    model = small_model(frame_copies=True).train()
    cfg = model.config
    with torch.no_grad():
        assert float(model.cell_frames.weight.abs().max()) == 0.0
        assert float(model.renderer.splat_frames.weight.abs().max()) > 0
    batch = random_batch(cfg, B=2)
    loss, _ = model.rectified_flow_loss(batch, batch.frames, batch.K, batch.w2c, torch.Generator().manual_seed(0),
                                        cell_weight=1.0)
    loss.backward()
    assert float(model.cell_frames.weight.grad.abs().sum()) > 0


def test_the_frame_gate_keeps_the_frame_splat_where_the_target_sees_a_token_as_its_camera_did():
    base = get_config("tiny", **SMALL, **FULL, frame_copies=True)
    assert base.replace(frame_gate_deg=0.0).sha256() == base.sha256() == base.replace(frame_gate_deg=0).sha256()
    assert base.replace(frame_gate_deg=10.0).sha256() != base.sha256()
    for bad in (-1.0, 181.0, True, "10"):
        with pytest.raises(ModelError, match="frame_gate_deg"):
            base.replace(frame_gate_deg=bad)
    with pytest.raises(ModelError, match="frame_gate_deg"):
        get_config("tiny", **SMALL, **FULL, frame_gate_deg=10.0)
    plain, gated = small_model(frame_copies=True), small_model(frame_copies=True, frame_gate_deg=10.0)
    gated.load_state_dict(plain.state_dict(), strict=True)  # the gate has no weights
    with torch.no_grad():
        for model in (plain, gated):
            model.cell_frames.weight.copy_(model.cell_direct.weight.normal_(std=0.3))
            model.renderer.splat.weight.normal_(std=0.3)
            model.renderer.splat_frames.weight.copy_(model.renderer.splat.weight)
            model.renderer.out.weight.normal_(std=0.1)
    gated.load_state_dict(plain.state_dict(), strict=True)
    cfg, h = plain.config, plain.config.latent_size
    batch = random_batch(cfg, B=2)
    y, tau = torch.randn(2, cfg.frames, cfg.latent_channels, h, h), torch.full((2,), 1.0)
    still = [a[:, cfg.frames // 2:cfg.frames // 2 + 1].expand_as(a).clone() for a in (batch.K, batch.w2c)]
    with torch.no_grad():
        z_s, z_d = plain.encode(batch)
        # at the source camera every token is seen from its own camera: gate 1, the same render
        cams = plain.render_cameras(*still, (batch.K, batch.w2c))
        gate = gated.renderer.frame_gate(z_s, z_d, *cams)
        torch.testing.assert_close(gate, torch.ones_like(gate))
        rays = plain.rays(*still)
        torch.testing.assert_close(gated.velocity(y, z_s, z_d, rays, tau, cameras=cams),
                                   plain.velocity(y, z_s, z_d, rays, tau, cameras=cams))
        # a camera a quarter turn around the scene sees the tokens from elsewhere: the frame splat is gone
        turn = torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
        moved = still[1].clone()
        moved[..., :3, :3] = moved[..., :3, :3] @ turn.T  # world rotated a quarter turn about y
        far = plain.render_cameras(still[0], moved, (batch.K, batch.w2c))
        assert float(gated.renderer.frame_gate(z_s, z_d, *far).max()) < 0.01
        logit = plain.renderer.projected_logit(z_s, z_d, *far)
        gated_splat = gated.renderer.splat_latent(z_s, z_d, logit, None, 1, gated.renderer.frame_gate(z_s, z_d, *far))
        plain.renderer.splat_frames.weight.zero_()
        plain.renderer.splat_frames.bias.zero_()
        torch.testing.assert_close(gated_splat, plain.renderer.splat_latent(z_s, z_d, logit, None), atol=2e-2, rtol=0)
    # and it trains: finite gradients where the target is the source camera itself (angle 0)
    gated.train()
    loss, _ = gated.rectified_flow_loss(batch, batch.frames, batch.K, batch.w2c, torch.Generator().manual_seed(0))
    loss.backward()
    assert all(torch.isfinite(p.grad).all() for p in gated.parameters() if p.grad is not None)


def test_a_short_clip_gives_the_copies_of_missing_frames_nothing():
    model = small_model(frame_copies=True)
    cfg = model.config
    with torch.no_grad():
        model.cell_frames.bias.normal_()
        model.cell_frames.weight.normal_()
    batch = random_batch(cfg, B=1)
    short = dataclasses.replace(batch, frames=batch.frames[:, :2], K=batch.K[:, :2], w2c=batch.w2c[:, :2],
                                motion_mask=batch.motion_mask[:, :2], track_xy=batch.track_xy[:, :, :2],
                                track_valid=batch.track_valid[:, :, :2])
    with torch.no_grad():
        a, _ = model.encode_preactivations(short)
        model.cell_frames.weight.zero_()
        model.cell_frames.bias.zero_()
        plain, _ = model.encode_preactivations(short)
    # frames 0 and 1 are covered by copies 1 and 2 (tokens 16-47); copies 3 and 4 cover frames 2 and 3
    assert float((a[:, 16:48] - plain[:, 16:48]).abs().max()) > 1e-3
    torch.testing.assert_close(a[:, 48:], plain[:, 48:])
    torch.testing.assert_close(a[:, :16], plain[:, :16])


def test_blended_copies_weigh_the_frames_by_hats_around_their_groups_centres():
    base = get_config("tiny", **SMALL, **FULL, frame_copies=True)
    assert get_config("tiny", **SMALL, **FULL, frame_copies=True, copy_blend=False).sha256() == base.sha256()
    assert get_config("tiny", **SMALL, **FULL, frame_copies=True, copy_blend=True).sha256() != base.sha256()
    with pytest.raises(ModelError, match="copy_blend needs frame_copies"):
        get_config("tiny", **SMALL, **FULL, copy_blend=True)
    # three copies per anchor (n_static 48): two groups of two frames, centres at frames 0.5 and 2.5
    three = small_model(frame_copies=True, copy_blend=True, n_static=48).renderer.copy_frames(1)
    assert float(three[:16].sum()) == 0.0  # the time-average copies weigh no frame
    assert three[16:32].tolist() == [[1.0, 0.75, 0.25, 0.0]] * 16
    assert three[32:].tolist() == [[0.0, 0.25, 0.75, 1.0]] * 16
    # one frame per group: the hats are the groups
    blended = small_model(frame_copies=True, copy_blend=True)
    assert torch.equal(blended.renderer.copy_frames(1), small_model(frame_copies=True).renderer.copy_frames(1))
    # every frame's weights over an anchor's copies sum to 1; five cameras: no copies, nothing blended
    eight = small_model(frame_copies=True, copy_blend=True, frames=8).renderer.copy_frames(1)
    assert torch.allclose(eight.view(5, 16, 8).sum(0)[0], torch.ones(8))
    assert float(blended.renderer.copy_frames(5).sum()) == 0.0


def test_blended_copies_read_their_hat_weighted_change():
    model = small_model(frame_copies=True, copy_blend=True, n_static=48)
    batch = random_batch(model.config, B=1)
    with torch.no_grad():
        x = model.latents(batch.frames)
        change = model.token_frame_cells(x, 1)  # (1, 48, C p p)
        cells = patchify(x.float(), 2)[0]  # (T, P, C p p)
        for copy, hat in ((1, [1.0, 0.75, 0.25, 0.0]), (2, [0.0, 0.25, 0.75, 1.0])):
            w = torch.tensor(hat) / sum(hat)
            expected = torch.einsum("tpc,t->pc", cells, w) - cells.mean(0)
            torch.testing.assert_close(change[0, 16 * copy:16 * (copy + 1)], expected, atol=1e-5, rtol=1e-5)
        assert float(change[0, :16].abs().max()) == 0.0
        assert torch.isfinite(model.encode(batch)[0]).all()

