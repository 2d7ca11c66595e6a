"""Render feedback (config ``feedback_width``): the encoder renders its first tokens at the encoded cameras and
reads the residual back around each token (model/feedback.py)."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from vt4dcodec.errors import ModelError
from vt4dcodec.model import VideoTok4D, get_config
from vt4dcodec.model.feedback import RenderFeedback

from network_fixtures import random_batch

SMALL = dict(frames=4, image_size=32, width=32, heads=2, ae_width=8, spatial_layers=1, static_query_layers=1,
             track_layers=1, renderer_layers=1, n_static=32, n_dynamic=4, token_dim=8, n_tracks=8, patch_size=2,
             locality_sigma=0.35, query_from_grid=True, project_anchors=True, prediction="x0", anchor_views=True,
             token_splat=True, token_from_cell=True, frame_copies=True, frame_gate_deg=8.0, view_gate_deg=40.0,
             pixel_splat=True, dynamic_splat=2, dynamic_from_patch=True)


def test_config_hash_is_kept_while_off_and_values_are_checked():
    base = get_config("tiny", **SMALL)
    assert get_config("tiny", **SMALL, feedback_width=0).sha256() == base.sha256()
    assert get_config("tiny", **SMALL, feedback_width=16).sha256() != base.sha256()
    for bad in (-1, True, 2.0, "16"):
        with pytest.raises(ModelError, match="feedback_width must be"):
            get_config("tiny", **SMALL, feedback_width=bad)
    assert get_config("tiny", **SMALL, feedback_width=16, feedback_passes=1).sha256() \
        == get_config("tiny", **SMALL, feedback_width=16).sha256()
    for bad in (0, 5, True, 2.0):
        with pytest.raises(ModelError, match="feedback_passes must be"):
            get_config("tiny", **SMALL, feedback_width=16, feedback_passes=bad)
    with pytest.raises(ModelError, match="feedback_passes > 1 needs feedback_width"):
        get_config("tiny", **SMALL, feedback_passes=2)
    levels = dict(SMALL, feedback_width=16, entropy_levels=3)
    assert get_config("tiny", **levels, feedback_quality=1).sha256() == get_config("tiny", **levels).sha256()
    for bad in (0, 4, True, 2.0):
        with pytest.raises(ModelError, match="feedback_quality must be a quality level 1 .. 3"):
            get_config("tiny", **levels, feedback_quality=bad)
    with pytest.raises(ModelError, match="feedback_quality > 1 needs feedback_width"):
        get_config("tiny", **dict(levels, feedback_width=0), feedback_quality=2)
    cfg = get_config("tiny", **levels, feedback_quality=2)
    assert [cfg.feeds_back(q) for q in (None, 1, 2, 3)] == [True, False, True, True]
    assert not get_config("tiny", **SMALL).feeds_back(None)
    assert cfg.without_feedback() == get_config("tiny", **dict(levels, feedback_width=0))
    assert get_config("tiny", **SMALL, feedback_width=16, feedback_window=3).sha256() \
        == get_config("tiny", **SMALL, feedback_width=16).sha256()
    for bad in (0, 2, 17, True, 3.0):
        with pytest.raises(ModelError, match="feedback_window must be an odd integer"):
            get_config("tiny", **SMALL, feedback_width=16, feedback_window=bad)
    with pytest.raises(ModelError, match="feedback_window other than 3 needs feedback_width"):
        get_config("tiny", **SMALL, feedback_window=5)
    assert get_config("tiny", **levels, feedback_window=5).without_feedback() == cfg.without_feedback()
    for missing in (dict(dynamic_splat=0, dynamic_from_patch=False),
                    dict(unified_tokens=True, dynamic_from_patch=False)):
        with pytest.raises(ModelError, match="feedback_width needs"):
            get_config("tiny", **{**SMALL, **missing}, feedback_width=16)


@pytest.mark.parametrize("views", [1, 2])
def test_a_warm_start_encodes_exactly_as_before(views: int):
    """The feedback's output layers start at zero: the model with feedback gives the same tokens."""
    torch.manual_seed(0)
    cfg = get_config("tiny", **SMALL)
    old = VideoTok4D(cfg).eval()
    new = VideoTok4D(cfg.replace(feedback_width=16)).eval()
    new.decode_steps = old.decode_steps = 1
    missing = new.load_state_dict(old.state_dict(), strict=False).missing_keys
    assert missing and all(k.startswith("feedback.") for k in missing)
    batch = dataclasses.replace(random_batch(cfg, B=2 * views, n_tracks=8), views=views)
    with torch.no_grad():
        a_old, a_new = old.encode_preactivations(batch), new.encode_preactivations(batch)
        assert torch.equal(a_old[0], a_new[0]) and torch.equal(a_old[1], a_new[1])
        for layer in (new.feedback.static[2], new.feedback.dynamic[2]):
            layer.weight.normal_()
        moved = new.encode_preactivations(batch)
    assert not torch.equal(moved[0], a_old[0]) and not torch.equal(moved[1], a_old[1])
    assert moved[0].shape == a_old[0].shape and moved[1].shape == a_old[1].shape


@pytest.mark.parametrize("window", [3, 5])
def test_each_static_token_reads_the_residual_in_its_window_only(window: int):
    """Token i of camera c reads cell (i mod P)'s window (``feedback_window`` cells a side) of camera c's residual:
    a change outside it leaves the token's update unchanged, one inside changes it."""
    cfg = get_config("tiny", **SMALL, feedback_width=16, feedback_window=window)
    reach = window // 2  # cells on each side
    net = VideoTok4D(cfg).eval()
    torch.manual_seed(1)
    for layer in (net.feedback.static[2], net.feedback.dynamic[2]):
        torch.nn.init.normal_(layer.weight)
    views, T, C, h = 2, cfg.frames, cfg.latent_channels, cfg.latent_size
    z_s, z_d = torch.rand(1, cfg.n_static, cfg.token_dim), torch.rand(1, cfg.n_dynamic, cfg.token_dim)
    residual = torch.randn(views, T, C, h, h)
    track = torch.randn(1, cfg.n_dynamic, C * cfg.dynamic_splat ** 2)
    cameras, covers = net.renderer.token_cameras(views), net.renderer.copy_frames(views)[:, :T]
    fb: RenderFeedback = net.feedback
    with torch.no_grad():
        base, _ = fb(z_s, z_d, residual, track, cameras, covers)
        per_side = h // cfg.patch_size
        token = next(i for i in range(cfg.n_static)  # camera 1, a cell of the first row
                     if int(cameras[i]) == 1 and (i % per_side ** 2) // per_side == 0)
        far = residual.clone()
        far[1, :, :, (reach + 1) * cfg.patch_size:, :] += 5.0  # camera 1, rows below the window
        far[0] += 5.0  # all of camera 0
        changed, _ = fb(z_s, z_d, far, track, cameras, covers)
        assert torch.equal(changed[0, token], base[0, token])
        near = residual.clone()
        col = (token % per_side) * cfg.patch_size
        near[1, :, :, (reach + 1) * cfg.patch_size - 1, col] += 5.0  # the window's last latent row
        changed, _ = fb(z_s, z_d, near, track, cameras, covers)
        assert not torch.equal(changed[0, token], base[0, token])


def test_training_reaches_the_feedback_through_the_stored_tokens():
    """The tokenizer loss trains the feedback (gradients reach both MLPs) while the rendered Y^0 carries none."""
    cfg = get_config("tiny", **SMALL, feedback_width=16)
    torch.manual_seed(2)
    net = VideoTok4D(cfg)
    net.decode_steps = 1
    for layer in (net.feedback.static[2], net.feedback.dynamic[2], net.renderer.dynamic_content):
        torch.nn.init.normal_(layer.weight, std=0.01)  # dynamic_content: zero in a fresh model, no path to Z_d
    batch = random_batch(cfg, B=2, n_tracks=8)
    frames = torch.rand(2, cfg.frames, 3, cfg.image_size, cfg.image_size)
    loss, _ = net.rectified_flow_loss(batch, frames, batch.K, batch.w2c, tau=torch.ones(2), patch_weight=1.0)
    loss.backward()
    for mlp in (net.feedback.static, net.feedback.dynamic):
        assert all(p.grad is not None and float(p.grad.abs().sum()) > 0 for p in mlp.parameters())


def test_a_further_pass_starts_as_the_model_without_it_and_reads_what_the_previous_pass_renders():
    """feedback_passes=2 warm-started from one pass: the same tokens until the second pass's zero-initialised
    output layers move; the first pass (encode(feedback=False)) never changes, and gradients reach the new pass."""
    torch.manual_seed(0)
    cfg = get_config("tiny", **SMALL, feedback_width=16)
    one = VideoTok4D(cfg).eval()
    for layer in (one.feedback.static[2], one.feedback.dynamic[2]):
        torch.nn.init.normal_(layer.weight, std=0.1)
    two = VideoTok4D(cfg.replace(feedback_passes=2)).eval()
    one.decode_steps = two.decode_steps = 1
    missing = two.load_state_dict(one.state_dict(), strict=False).missing_keys
    assert missing and all(k.startswith("feedback_later.0.") for k in missing)
    batch = dataclasses.replace(random_batch(cfg, B=2, n_tracks=8), views=2)
    with torch.no_grad():
        assert all(torch.equal(a, b) for a, b in zip(one.encode(batch), two.encode(batch)))
        for layer in (two.feedback_later[0].static[2], two.feedback_later[0].dynamic[2]):
            layer.weight.normal_(std=0.1)
        moved = two.encode(batch)
        assert all(not torch.equal(a, b) for a, b in zip(moved, one.encode(batch)))
        assert all(torch.equal(a, b) for a, b in zip(two.encode(batch, feedback=False),
                                                      one.encode(batch, feedback=False)))
    two.requires_grad_(False)
    two.feedback_later.requires_grad_(True)
    sum(z.square().sum() for z in two.encode(batch)).backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in two.feedback_later.parameters())


def test_gradient_feedback_config_is_checked_and_kept_out_of_the_first_pass():
    cfg = get_config("tiny", **SMALL, feedback_width=16)
    assert get_config("tiny", **SMALL, feedback_width=16, feedback_gradient=False).sha256() == cfg.sha256()
    grad = get_config("tiny", **SMALL, feedback_width=16, feedback_gradient=True)
    assert grad.sha256() != cfg.sha256() and grad.without_feedback() == cfg.without_feedback()
    with pytest.raises(ModelError, match="feedback_gradient needs feedback_width"):
        get_config("tiny", **SMALL, feedback_gradient=True)
    with pytest.raises(ModelError, match="feedback_gradient"):
        get_config("tiny", **SMALL, feedback_width=16, feedback_gradient=1)


def test_render_gradients_are_the_render_errors_derivative():
    """feedback_render_gradients: Y equals feedback_render's, and the gradient is d/dZ sum (x - Y)^2 (a central
    difference along a random direction agrees), also when called under no_grad as the codec encodes. Like
    refinement's, it is the renderer's training gradient: exact but for the time-average copies."""
    cfg = get_config("tiny", **SMALL, feedback_width=16, feedback_gradient=True)
    torch.manual_seed(3)
    net = VideoTok4D(cfg).eval()
    net.decode_steps = 1
    batch = random_batch(cfg, B=2, n_tracks=8)
    a_s = torch.randn(2, cfg.n_static, cfg.token_dim)
    a_d = torch.randn(2, cfg.n_dynamic, cfg.token_dim)
    x = torch.randn(2, cfg.frames, cfg.latent_channels, cfg.latent_size, cfg.latent_size)
    fb = net.feedback
    with torch.no_grad():
        y, g_s, g_d = net.feedback_render_gradients(fb, batch, a_s, a_d, x)
        assert torch.allclose(y, net.feedback_render(fb, batch, a_s, a_d), atol=1e-6)
        z_s, z_d = net._bound(a_s, a_d)
        u_s, u_d = torch.randn_like(z_s), torch.randn_like(z_d)
        # the frame splat holds each time-average copy fixed under the copies' differences (a training gradient by
        # design, renderer.frame_difference): the derivative is exact along every other token
        u_s[:, net.renderer.copy_origin(1).unique()] = 0.0
        eps = 3e-3

        def err(sign: float) -> float:
            r = net.render_latents.__wrapped__(net, z_s + sign * eps * u_s, z_d + sign * eps * u_d, batch.K, batch.w2c,
                                               source=batch.source, noise=fb.noise[:, :cfg.frames])
            return float((x - r).double().square().sum())
        numeric = (err(1.0) - err(-1.0)) / (2 * eps)
    analytic = float((g_s * u_s).sum() + (g_d * u_d).sum())
    assert abs(numeric - analytic) <= 1e-2 * max(1.0, abs(numeric))
    assert not g_s.requires_grad and not y.requires_grad


def test_gradient_feedback_starts_as_the_model_without_it_and_trains():
    """A model given feedback_gradient, warm-started from one without: the same tokens (the gradient MLPs' output
    layers are zero); once they move the tokens move, and the tokenizer loss reaches them."""
    torch.manual_seed(4)
    cfg = get_config("tiny", **SMALL, feedback_width=16)
    old = VideoTok4D(cfg).eval()
    for layer in (old.feedback.static[2], old.feedback.dynamic[2]):
        torch.nn.init.normal_(layer.weight, std=0.1)
    new = VideoTok4D(cfg.replace(feedback_gradient=True)).eval()
    old.decode_steps = new.decode_steps = 1
    missing = new.load_state_dict(old.state_dict(), strict=False).missing_keys
    assert missing and all(".static_grad." in k or ".dynamic_grad." in k for k in missing)
    batch = random_batch(cfg, B=2, n_tracks=8)
    with torch.no_grad():
        a_old, a_new = old.encode_preactivations(batch), new.encode_preactivations(batch)
    assert torch.equal(a_old[0], a_new[0]) and torch.equal(a_old[1], a_new[1])
    new.train()
    for layer in (new.feedback.static_grad[2], new.feedback.dynamic_grad[2], new.renderer.dynamic_content):
        torch.nn.init.normal_(layer.weight, std=0.01)
    frames = torch.rand(2, cfg.frames, 3, cfg.image_size, cfg.image_size)
    loss, _ = new.rectified_flow_loss(batch, frames, batch.K, batch.w2c, tau=torch.ones(2), patch_weight=1.0)
    loss.backward()
    for mlp in (new.feedback.static_grad, new.feedback.dynamic_grad):
        assert all(p.grad is not None and float(p.grad.abs().sum()) > 0 for p in mlp.parameters())
    with torch.no_grad():
        moved = new.eval().encode_preactivations(batch)
    assert not torch.equal(moved[0], a_old[0]) and not torch.equal(moved[1], a_old[1])


@pytest.mark.parametrize("scale", [0.0, 0.5, 1.0])
def test_an_added_pass_can_start_as_the_last_pass_taken_again_at_a_scale(scale: float):
    """--repeat-feedback: each pass added to a saved model starts as that model's last pass with its MLPs' output
    layers times ``scale`` (every MLP gives ``scale`` x the last pass's output); at scale 0 the tokens are the
    saved model's; passes added to a model of two copy its second; without a scale they start fresh."""
    from vt4dcodec.model.train.tokenizer import repeated_feedback

    torch.manual_seed(5)
    cfg = get_config("tiny", **SMALL, feedback_width=16, feedback_gradient=True)
    one = VideoTok4D(cfg).eval()
    for mlp in ("static", "dynamic", "static_grad", "dynamic_grad"):
        torch.nn.init.normal_(getattr(one.feedback, mlp)[2].weight, std=0.1)
    two_cfg = cfg.replace(feedback_passes=2)
    state = repeated_feedback(one.state_dict(), cfg, two_cfg, scale)
    two = VideoTok4D(two_cfg).eval()
    two.load_state_dict(state, strict=True)
    for mlp in ("static", "dynamic", "static_grad", "dynamic_grad"):
        first, added = getattr(one.feedback, mlp), getattr(two.feedback_later[0], mlp)
        x = torch.randn(5, first[0].in_features)
        torch.testing.assert_close(added(x), scale * first(x))
    one.decode_steps = two.decode_steps = 1
    batch = random_batch(cfg, B=1, n_tracks=8)
    with torch.no_grad():
        same = all(torch.equal(a, b) for a, b in zip(one.encode(batch), two.encode(batch)))
    assert same == (scale == 0.0)
    three = repeated_feedback(two.state_dict(), two_cfg, cfg.replace(feedback_passes=3), 0.25)
    for name, value in two.state_dict().items():
        if name.startswith("feedback_later.0."):
            copied = three[name.replace("feedback_later.0.", "feedback_later.1.")]
            torch.testing.assert_close(copied, value * 0.25 if ".2." in name else value)
    plain = one.state_dict()
    assert repeated_feedback(plain, cfg, two_cfg, None) is plain
    assert repeated_feedback(plain, cfg, cfg, 0.5) is plain
