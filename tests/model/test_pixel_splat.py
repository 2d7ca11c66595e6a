"""Pixel splat (config ``pixel_splat``): the token splat as a forward warp at latent-pixel precision."""

from __future__ import annotations

import pytest
import torch

from vt4dcodec.errors import ModelError
from vt4dcodec.model import VideoTok4D, get_config
from vt4dcodec.model.layers import patchify
from vt4dcodec.model.renderer import SPLAT_FLOOR

SMALL = dict(frames=4, image_size=32, width=32, heads=2, ae_width=8, spatial_layers=1, static_query_layers=1,
             track_layers=1, renderer_layers=1, n_static=32, n_dynamic=4, token_dim=8, n_tracks=8, patch_size=2,
             locality_sigma=0.35, query_from_grid=True, project_anchors=True, prediction="x0", anchor_views=True,
             token_splat=True, token_from_cell=True, frame_copies=True, frame_gate_deg=8.0, view_gate_deg=40.0)
FOCAL = 0.9 * 32  # px
DEPTH = 3.0  # metres: the world origin's depth in the source camera, the anchors' depth at initialisation


def camera(tx: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """K (3, 3) and w2c (4, 4) of a camera looking down +z at the origin DEPTH metres away, moved by -tx along x
    (the scene moves right by FOCAL tx / DEPTH px)."""
    K = torch.tensor([[FOCAL, 0.0, 15.5], [0.0, FOCAL, 15.5], [0.0, 0.0, 1.0]])
    w2c = torch.eye(4)
    w2c[0, 3], w2c[2, 3] = tx, DEPTH
    return K, w2c


def model(pixel_splat: bool, **overrides) -> VideoTok4D:
    torch.manual_seed(0)
    net = VideoTok4D(get_config("tiny", **SMALL, pixel_splat=pixel_splat, **overrides)).eval()
    with torch.no_grad():  # the splat maps start at zero; give them content
        for layer in (net.renderer.splat, net.renderer.splat_frames):
            layer.weight.normal_()
            layer.bias.normal_()
    return net


def tokens() -> tuple[torch.Tensor, torch.Tensor]:
    torch.manual_seed(1)
    return torch.rand(2, 32, 8) * 2 - 1, torch.rand(2, 4, 8) * 2 - 1


def render_splat(net: VideoTok4D, tx: float, keep: torch.Tensor | None = None) -> torch.Tensor:
    """The splat (B, T, C, h, w) at a target camera moved by tx, one encoded camera at tx = 0."""
    r = net.renderer
    z_s, z_d = tokens()
    K, w2c = camera()
    Kt, w2ct = camera(tx)
    K_src, w2c_src = K.expand(2, 3, 3), w2c.expand(2, 4, 4)
    K_tgt, w2c_tgt = Kt.expand(2, 4, 3, 3), w2ct.expand(2, 4, 4, 4)
    with torch.no_grad():
        if net.config.pixel_splat:
            splat = r.splat_pixels(z_s, z_d, r.pixel_placement(z_s, z_d, K_tgt, w2c_tgt, K_src, w2c_src), keep)
        else:
            splat = r.splat_latent(z_s, z_d, r.projected_logit(z_s, z_d, K_tgt, w2c_tgt, K_src, w2c_src), keep)
    C = net.config.latent_channels
    return splat.reshape(2, 4, 4, 4, C, 2, 2).permute(0, 1, 4, 2, 5, 3, 6).reshape(2, 4, C, 8, 8)


def test_config_hash_is_kept_while_off_and_values_are_checked():
    base = get_config("tiny", **SMALL)
    assert get_config("tiny", **SMALL, pixel_splat=False).sha256() == base.sha256()
    assert get_config("tiny", **SMALL, pixel_splat=True).sha256() != base.sha256()
    for bad in (1, "true", None):
        with pytest.raises(ModelError, match="pixel_splat"):
            get_config("tiny", **SMALL, pixel_splat=bad)
    with pytest.raises(ModelError, match="pixel_splat"):
        get_config("tiny", **{**SMALL, "token_splat": False, "frame_copies": False, "frame_gate_deg": 0.0},
                   pixel_splat=True)


def test_no_new_weights():
    assert model(False).state_dict().keys() == model(True).state_dict().keys()


def test_at_the_source_camera_each_latent_pixel_lands_on_its_own_place():
    net = model(True)
    r = net.renderer
    z_s, z_d = tokens()
    K, w2c = camera()
    ey, ex, f = r.pixel_placement(z_s, z_d, K.expand(2, 4, 3, 3), w2c.expand(2, 4, 4, 4), K.expand(2, 3, 3),
                                  w2c.expand(2, 4, 4))
    rows, cols = ey.argmax(-1)[0, 0], ex.argmax(-1)[0, 0]  # (Na, q)
    cells = r.anchor_cells  # (Na, 2) (row, col) centres in encoder patches of 2 latent pixels
    q_row, q_col = torch.tensor([0, 0, 1, 1]), torch.tensor([0, 1, 0, 1])  # row-major, as layers.patchify
    assert torch.equal(rows, (cells[:, :1] - 0.5).long() * 2 + q_row)
    assert torch.equal(cols, (cells[:, 1:] - 0.5).long() * 2 + q_col)
    assert torch.allclose(ey.amax(-1), torch.ones(()), atol=1e-5) and torch.all(f == 1.0)
    # there it renders as the patch splat up to the neighbours' small share (exp(-1 / 2 sigma^2) = 0.017 each)
    pixel, patch = render_splat(net, 0.0), render_splat(model(False), 0.0)
    assert (pixel - patch).abs().max() < 0.25 * pixel.abs().max()


def test_half_a_patch_of_camera_motion_moves_the_render_by_one_latent_pixel():
    """A sideways move that shifts the scene by one latent pixel (4 image px, half a render patch): the pixel
    splat renders the source splat shifted by one latent pixel; the patch splat cannot place it there."""
    tx = 4.0 * DEPTH / FOCAL
    for pixel, tolerance in ((True, 1e-3), (False, None)):
        net = model(pixel)
        moved, still = render_splat(net, tx), render_splat(net, 0.0)
        error = (moved[..., 1:-1, 2:-1] - still[..., 1:-1, 1:-2]).abs().max() / still.abs().max()
        if tolerance is not None:
            assert error < tolerance
        else:
            assert error > 0.1


@pytest.mark.parametrize("blend", [{}, {"copy_blend": True}], ids=["groups", "blend"])
def test_equals_the_dense_weighted_sum(blend):
    """The separable computation is the normalised sum over every token's pixels written out densely (the frame
    copies' change normalised over the copies' weights in frame t, hats with copy_blend)."""
    net = model(True, **blend)
    r, cfg = net.renderer, net.config
    z_s, z_d = tokens()
    views = 2
    Ks = torch.stack([camera()[0], camera(0.3)[0]])[None].expand(2, -1, -1, -1)
    w2cs = torch.stack([camera()[1], camera(0.3)[1]])[None].expand(2, -1, -1, -1)
    Kt, w2ct = camera(0.17)
    K_tgt, w2c_tgt = Kt.expand(2, 4, 3, 3), w2ct.expand(2, 4, 4, 4)
    keep = torch.ones(2, 36, dtype=torch.bool)
    keep[1, :32] = False  # item 1 drops its static tokens
    torch.manual_seed(2)
    gate, view_term = torch.rand(2, 4, 32), torch.rand(2, 4, 32)
    with torch.no_grad():
        placement = r.pixel_placement(z_s, z_d, K_tgt, w2c_tgt, Ks, w2cs, view_term)
        fast = r.splat_pixels(z_s, z_d, placement, keep, views, gate)
        ey, ex, f = placement
        g = f[..., None, None] * ey[..., :, None] * ex[..., None, :] * keep[:, None, :32, None, None, None]
        content = r.splat(z_s[:, :32]).reshape(2, 32, cfg.latent_channels, 4).transpose(2, 3)
        out = torch.einsum("btnqyx,bnqc->btcyx", g / (g.sum((2, 3), keepdim=True) + SPLAT_FLOOR), content)
        g = g * r.copy_frames(views).T[None, :, :, None, None, None]
        w = g / (g.sum((2, 3), keepdim=True) + SPLAT_FLOOR) * gate[:, :, :, None, None, None]
        change = r.splat_frames(r.frame_difference(z_s, views)).reshape(2, 32, cfg.latent_channels, 4).transpose(2, 3)
        out = out + torch.einsum("btnqyx,bnqc->btcyx", w, change)
    assert torch.allclose(fast, patchify(out, 2), atol=1e-5)
    assert fast[1].abs().max() == 0.0  # nothing to splat where the static tokens are dropped


def test_forward_and_gradients_are_finite_with_a_camera_behind_the_scene():
    net = model(True).train()
    z_s, z_d = tokens()
    z_s.requires_grad_(True)
    K, w2c = camera()
    behind = w2c.clone()
    behind[2, 3] = -1.0  # the world origin behind the target camera
    y = torch.randn(2, 4, net.config.latent_channels, 8, 8)
    rays = torch.zeros(2, 4, 6, 8, 8)
    out = net.renderer(y, z_s, z_d, rays, torch.full((2,), 0.5),
                       cameras=(K.expand(2, 4, 3, 3), behind.expand(2, 4, 4, 4),
                                K.expand(2, 3, 3), w2c.expand(2, 4, 4)))
    out.sum().backward()
    assert torch.isfinite(out).all() and torch.isfinite(z_s.grad).all()


def test_patch_gate_config_is_checked():
    base = get_config("tiny", **SMALL, pixel_splat=True)
    assert get_config("tiny", **SMALL, pixel_splat=True, patch_gate_deg=0.0).sha256() == base.sha256()
    for bad in (-1.0, 181.0, True, "5"):
        with pytest.raises(ModelError, match="patch_gate_deg"):
            get_config("tiny", **SMALL, pixel_splat=True, patch_gate_deg=bad)
    with pytest.raises(ModelError, match="patch_gate_deg"):
        get_config("tiny", **SMALL, patch_gate_deg=5.0)


def test_patch_gate_keeps_the_patch_splat_at_the_source_camera_and_the_pixel_splat_far_from_it():
    """The renderer's output with patch_gate_deg: at the encoded camera every token is seen along its own ray
    (share 1), so the render equals the patch splat model's; seen from 60 degrees away (share ~e^-72) it
    equals the pixel splat model's."""
    torch.manual_seed(0)
    nets = {}
    for name, extra in (("patch", {}), ("pixel", {"pixel_splat": True}),
                        ("gated", {"pixel_splat": True, "patch_gate_deg": 5.0})):
        nets[name] = VideoTok4D(get_config("tiny", **SMALL, **extra)).eval()
    nets["patch"].renderer.splat.weight.data.normal_()
    for net in nets.values():
        net.load_state_dict(nets["patch"].state_dict())  # no new weights
    z_s, z_d = tokens()
    K, w2c = camera()
    turned = torch.eye(4)  # 60 degrees around the y axis through the origin, same distance
    c, s = 0.5, 3 ** 0.5 / 2
    turned[:3, :3] = torch.tensor([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
    turned[2, 3] = DEPTH
    y = torch.randn(2, 4, nets["patch"].config.latent_channels, 8, 8)
    rays = torch.zeros(2, 4, 6, 8, 8)

    def render(name: str, w2c_tgt: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            return nets[name].renderer(y, z_s, z_d, rays, torch.ones(2), cameras=(
                K.expand(2, 4, 3, 3), w2c_tgt.expand(2, 4, 4, 4), K.expand(2, 3, 3), w2c.expand(2, 4, 4)))

    assert torch.allclose(render("gated", w2c), render("patch", w2c), atol=1e-5)
    assert torch.allclose(render("gated", turned), render("pixel", turned), atol=1e-5)
    assert not torch.allclose(render("patch", turned), render("pixel", turned), atol=1e-3)
