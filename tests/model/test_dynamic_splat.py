"""Dynamic splat (config ``dynamic_splat``): each dynamic token is tied to a track, decodes where that track
goes and splats a patch of latent content there in every target frame."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from vt4dcodec.errors import ModelError
from vt4dcodec.model import SourceBatch, VideoTok4D, get_config
from vt4dcodec.model.inputs.source_inputs import SourceInputs, stack_inputs
from vt4dcodec.model.layers import patchify
from vt4dcodec.model.renderer import DYNAMIC_GATE_SCALE, SPLAT_FLOOR
from vt4dcodec.model.temporal_branch import _stable_descending_order, select_tracks
from vt4dcodec.model.train.data import track_depths

from network_fixtures import orbit_cameras, random_batch

SMALL = dict(frames=4, image_size=32, width=32, heads=2, ae_width=8, spatial_layers=1, static_query_layers=1,
             track_layers=1, renderer_layers=1, n_static=32, n_dynamic=4, token_dim=8, n_tracks=8, patch_size=2,
             locality_sigma=0.35, query_from_grid=True, project_anchors=True, prediction="x0", anchor_views=True,
             token_splat=True, token_from_cell=True, frame_copies=True, frame_gate_deg=8.0, view_gate_deg=40.0,
             pixel_splat=True)
FOCAL, DEPTH = 0.9 * 32, 3.0


def camera(tx: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """K, w2c of a camera looking down +z at the origin DEPTH metres away, moved by -tx along x."""
    K = torch.tensor([[FOCAL, 0.0, 15.5], [0.0, FOCAL, 15.5], [0.0, 0.0, 1.0]])
    w2c = torch.eye(4)
    w2c[0, 3], w2c[2, 3] = tx, DEPTH
    return K, w2c


def test_config_hash_is_kept_while_off_and_values_are_checked():
    base = get_config("tiny", **SMALL)
    assert get_config("tiny", **SMALL, dynamic_splat=0).sha256() == base.sha256()
    assert get_config("tiny", **SMALL, dynamic_splat=3).sha256() != base.sha256()
    for bad in (-1, True, 2.0, "3", 9):  # latent size 8
        with pytest.raises(ModelError, match="dynamic_splat"):
            get_config("tiny", **SMALL, dynamic_splat=bad)
    with pytest.raises(ModelError, match="dynamic_splat needs pixel_splat"):
        get_config("tiny", **{**SMALL, "pixel_splat": False}, dynamic_splat=2)


@pytest.mark.parametrize("unified", [False, True])
def test_a_warm_start_encodes_and_renders_exactly_as_before(unified: bool):
    """Every new tensor starts where it changes nothing: the track queries' maps and the opacity gate are 0."""
    torch.manual_seed(0)
    cfg = get_config("tiny", **SMALL, unified_tokens=unified)
    old = VideoTok4D(cfg).eval()
    new = VideoTok4D(cfg.replace(dynamic_splat=3)).eval()
    missing = new.load_state_dict(old.state_dict(), strict=False).missing_keys
    assert missing and all(k.startswith(("renderer.dynamic_", "temporal_branch.track_query", "track_direct")) for k in missing)
    with torch.no_grad():  # content in the old splat maps, so the composite has something to cover
        for layer in (old.renderer.splat, new.renderer.splat):
            torch.manual_seed(3)
            layer.weight.normal_()
    batch = random_batch(cfg, B=2, n_tracks=8)
    with torch.no_grad():
        (zs0, zd0), (zs1, zd1) = old.encode(batch), new.encode(batch)
        assert torch.equal(zs0, zs1) and torch.equal(zd0, zd1)
        K, w2c = orbit_cameras(2, 4, 32, seed=5)
        a = old.render(zs0, zd0, K, w2c, steps=1, source=batch.source)
        b = new.render(zs0, zd0, K, w2c, steps=1, source=batch.source)
    assert torch.equal(a, b)


def test_the_track_head_places_the_patch_at_its_track_and_moves_it_with_the_target_camera():
    torch.manual_seed(0)
    net = VideoTok4D(get_config("tiny", **SMALL, dynamic_splat=1)).eval()
    r, h = net.renderer, net.config.latent_size
    u, v = 2.0, 5.0  # latent pixels in the token's camera (centres at integers)
    with torch.no_grad():
        last = r.dynamic_path[2]
        last.weight.zero_()
        last.bias.copy_(torch.tensor([(u - (h - 1) / 2) / (h / 2), (v - (h - 1) / 2) / (h / 2), 0.0]).repeat(4))
    z_d = torch.zeros(1, 4, 8)
    uv, depth = r.dynamic_track(z_d, camera()[1][None])
    assert torch.allclose(uv[0, 0, 0], torch.tensor([u, v])) and torch.allclose(depth, torch.full_like(depth, DEPTH))
    K, w2c = camera()
    for tx, shift in ((0.0, 0.0), (0.5, FOCAL * 0.5 / DEPTH / 4)):  # latent px = image px / 4
        Kt, w2ct = camera(tx)
        ey, ex, f, _ = r.dynamic_placement(z_d, Kt.expand(1, 4, 3, 3), w2ct.expand(1, 4, 4, 4), K[None], w2c[None], None)
        assert int(ex[0, 0, 0, 0].argmax()) == round(u + shift) and int(ey[0, 0, 0, 0].argmax()) == round(v)
        assert torch.allclose(f, torch.ones_like(f))
    keep = torch.ones(1, 36, dtype=torch.bool)
    keep[:, 32:] = False  # Z_d dropped: no dynamic patch lands anywhere
    assert not r.dynamic_placement(z_d, K.expand(1, 4, 3, 3), w2c.expand(1, 4, 4, 4), K[None], w2c[None], keep)[2].any()


def test_the_composite_keeps_the_static_splat_until_the_gate_opens_and_then_covers_it():
    torch.manual_seed(0)
    net = VideoTok4D(get_config("tiny", **SMALL, dynamic_splat=1)).eval()
    r, C = net.renderer, net.config.latent_channels
    K, w2c = camera()
    z_d = torch.zeros(1, 4, 8)
    with torch.no_grad():
        placement = r.dynamic_placement(z_d, K.expand(1, 4, 3, 3), w2c.expand(1, 4, 4, 4), K[None], w2c[None], None)
    static = torch.randn(1, 4, 16, C * 4)
    with torch.no_grad():
        assert torch.equal(r.composite_dynamic(static, z_d, placement), static)
        r.dynamic_content.bias.copy_(torch.cat([torch.full((C,), 2.0), torch.tensor([20.0])]))  # opaque, value 2
        r.dynamic_gate.fill_(1.0 / DYNAMIC_GATE_SCALE)
        out = r.composite_dynamic(static, z_d, placement)
    ey, ex, f, _ = placement
    weight = torch.einsum("btnqh,btnqw->bthw", ey, ex)  # every token's patch lands on the same pixel here
    A = (weight / (weight + SPLAT_FLOOR))[:, :, None]
    grid = lambda x: x.reshape(1, 4, 4, 4, C, 2, 2).permute(0, 1, 4, 2, 5, 3, 6).reshape(1, 4, C, 8, 8)  # noqa: E731
    want = grid(static) * (1 - A) + 2.0 * A
    assert torch.allclose(out, patchify(want, 2), atol=1e-5)
    assert float(A.max()) > 0.9 and float(A.min()) < 1e-3  # covered at the track, untouched elsewhere


def test_the_dynamic_gate_leaves_the_encoded_camera_to_the_frame_copies_and_covers_from_elsewhere():
    """dynamic_gate_deg: opacity x (1 - exp(-a^2 / 2 s^2)): zero along the encoded camera's own rays (the
    source view keeps the static splat's frame copies), nearly the ungated opacity 14 degrees away."""
    torch.manual_seed(0)
    plain = VideoTok4D(get_config("tiny", **SMALL, dynamic_splat=1)).eval()
    gated = VideoTok4D(get_config("tiny", **SMALL, dynamic_splat=1, dynamic_gate_deg=8.0)).eval()
    gated.load_state_dict(plain.state_dict())
    C = plain.config.latent_channels
    K, w2c = camera()
    z_d = torch.zeros(1, 4, 8)
    static = torch.randn(1, 4, 16, C * 4)
    with torch.no_grad():
        for net in (plain, gated):
            net.renderer.dynamic_content.bias.copy_(torch.cat([torch.full((C,), 2.0), torch.tensor([20.0])]))
            net.renderer.dynamic_gate.fill_(1.0 / DYNAMIC_GATE_SCALE)
        changes = {}
        for tx in (0.0, 0.75):  # 0.75 m at 3 m: 14 degrees at the origin, gate 1 - exp(-1.5) = 0.78
            Kt, w2ct = camera(tx)
            for name, net in (("plain", plain), ("gated", gated)):
                r = net.renderer
                placement = r.dynamic_placement(z_d, Kt.expand(1, 4, 3, 3), w2ct.expand(1, 4, 4, 4), K[None],
                                                w2c[None], None)
                changes[name, tx] = float((r.composite_dynamic(static, z_d, placement) - static).abs().max())
    assert changes["plain", 0.0] > 1.0 and changes["plain", 0.75] > 1.0  # the opaque patch covers ungated
    assert changes["gated", 0.0] < 1e-3
    assert changes["gated", 0.75] > 0.5 * changes["plain", 0.75]


def test_dynamic_gate_keeps_the_hash_while_off_and_needs_the_dynamic_splat():
    base = get_config("tiny", **SMALL, dynamic_splat=2)
    assert base.replace(dynamic_gate_deg=0.0).sha256() == base.sha256()
    assert base.replace(dynamic_gate_deg=8.0).sha256() != base.sha256()
    for bad in (-1.0, 181.0, True, "8"):
        with pytest.raises(ModelError, match="dynamic_gate_deg"):
            base.replace(dynamic_gate_deg=bad)
    with pytest.raises(ModelError, match="dynamic_gate_deg needs dynamic_splat"):
        get_config("tiny", **SMALL, dynamic_gate_deg=8.0)


def test_copy_resolution_is_the_share_of_a_cameras_cells_whose_frame_copies_split_the_clip():
    r = VideoTok4D(get_config("tiny", **{**SMALL, "n_static": 48}, dynamic_splat=1)).renderer  # 16 cells
    assert r.copy_resolution(1).tolist() == [1.0]  # 3 tokens a cell: a time average and 2 frame groups
    assert r.copy_resolution(3).tolist() == [0.0, 0.0, 0.0]  # 48 = 3 x 16: one token a (camera, cell)
    assert r.copy_resolution(5).tolist() == [0.0] * 5
    assert VideoTok4D(get_config("tiny", **SMALL, dynamic_splat=1)).renderer.copy_resolution(1).tolist() == [0.0]


def test_dynamic_gate_copies_lifts_the_gate_for_cameras_without_frame_copies():
    """With 3 encoded cameras and one token a (camera, cell) nothing else shows the motion at a camera's own
    view, so its dynamic patches draw there; with one camera (3 copies a cell) the plain gate holds."""
    torch.manual_seed(0)
    extra = {**SMALL, "n_static": 48}
    plain = VideoTok4D(get_config("tiny", **extra, dynamic_splat=1, dynamic_gate_deg=8.0)).eval()
    lifted = VideoTok4D(get_config("tiny", **extra, dynamic_splat=1, dynamic_gate_deg=8.0,
                                   dynamic_gate_copies=True)).eval()
    lifted.load_state_dict(plain.state_dict())
    C = plain.config.latent_channels
    K, w2c = camera()
    z_d = torch.zeros(1, 4, 8)
    static = torch.randn(1, 4, 16, C * 4)
    changes = {}
    with torch.no_grad():
        for name, net in (("plain", plain), ("lifted", lifted)):
            r = net.renderer
            r.dynamic_content.bias.copy_(torch.cat([torch.full((C,), 2.0), torch.tensor([20.0])]))
            r.dynamic_gate.fill_(1.0 / DYNAMIC_GATE_SCALE)
            for views in (1, 3):
                placement = r.dynamic_placement(z_d, K.expand(1, 4, 3, 3), w2c.expand(1, 4, 4, 4),
                                                K.expand(1, views, 3, 3), w2c.expand(1, views, 4, 4), None)
                out = r.composite_dynamic(static, z_d, placement, views)
                changes[name, views] = float((out - static).abs().max())
    assert changes["plain", 1] < 1e-3 and changes["plain", 3] < 1e-3  # the plain gate: every camera's own view
    assert changes["lifted", 1] < 1e-3  # frame copies resolve time: gated
    assert changes["lifted", 3] > 1.0  # none: the opaque patch covers
    with pytest.raises(ModelError, match="dynamic_gate_copies needs dynamic_gate_deg"):
        get_config("tiny", **extra, dynamic_splat=1, dynamic_gate_copies=True)
    base = get_config("tiny", **extra, dynamic_splat=1, dynamic_gate_deg=8.0)
    assert base.replace(dynamic_gate_copies=False).sha256() == base.sha256()


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 3), st.integers(1, 70), st.integers(0, 2 ** 31 - 1), st.booleans())
def test_the_stable_order_is_a_stable_descending_sort(B: int, N: int, seed: int, ties: bool):
    """select_tracks' order (written without a sort, which ONNX export lacks) equals torch's stable sort."""
    g = torch.Generator().manual_seed(seed)
    score = torch.randint(0, 4, (B, N), generator=g).float() / 3 if ties else torch.rand(B, N, generator=g)
    assert torch.equal(_stable_descending_order(score), torch.sort(-score, dim=1, stable=True).indices)


def test_select_tracks_ties_token_k_to_camera_k_mod_v_and_its_most_moving_tracks():
    B, N, T, h = 4, 3, 2, 8  # 2 scenes of 2 cameras
    xy = torch.zeros(B, N, T, 2)
    xy[:, :, :, 0] = torch.tensor([1.0, 4.0, 6.0])[None, :, None]  # tracks at columns 1, 4, 6
    mask = torch.zeros(B, T, h, h)
    mask[0, :, :, 6] = 1.0  # scene 0, camera 0: track 2 moves
    mask[1, :, :, 4] = 1.0  # scene 0, camera 1: track 1
    valid = torch.ones(B, N, T, dtype=torch.bool)
    chosen = select_tracks(mask, xy, valid, 5, views=2)
    assert chosen.shape == (2, 5)
    # token k: camera k mod 2, rank k // 2; indices c N + i; ties keep the track order
    assert chosen[0].tolist() == [2, 3 + 1, 0, 3 + 0, 1]
    assert chosen[1].tolist() == [0, 3, 1, 4, 2]


def test_track_targets_follow_the_track_into_the_middle_frame_camera_and_the_loss_trains_the_head():
    torch.manual_seed(0)
    cfg = get_config("tiny", **SMALL, dynamic_splat=2)
    net = VideoTok4D(cfg)
    batch = random_batch(cfg, B=2, n_tracks=8)
    depth = torch.full(batch.track_valid.shape, DEPTH)
    depth[0, 0, 1] = 0.0  # unknown depth: not supervised
    batch = SourceBatch(**{**batch.__dict__, "track_depth": depth})
    uv, z, valid = net.track_targets(batch)
    assert uv.shape == (2, 4, 4, 2) and z.shape == valid.shape == (2, 4, 4)
    chosen = select_tracks(batch.motion_mask, batch.track_xy, batch.track_valid, 4, 1)
    mid = 2
    for s in range(2):
        for k in range(4):
            i = int(chosen[s, k])
            assert torch.equal(valid[s, k], batch.track_valid[s, i] & (depth[s, i] > 0))
            if batch.track_valid[s, i, mid]:  # at the middle frame the target is the track itself
                assert torch.allclose(uv[s, k, mid], batch.track_xy[s, i, mid], atol=1e-3)
                assert abs(float(z[s, k, mid]) - DEPTH) < 1e-3
    with torch.no_grad():
        z_s, z_d = net.encode(batch)
    z_d = z_d.clone().requires_grad_(False)
    opt = torch.optim.Adam(net.renderer.dynamic_path.parameters(), lr=1e-2)
    first = float(net.track_loss(batch, z_d)[0])
    for _ in range(100):
        opt.zero_grad()
        loss, px = net.track_loss(batch, z_d)
        loss.backward()
        opt.step()
    assert float(loss) < 0.3 * first
    with pytest.raises(ModelError, match="track_depth"):
        net.track_targets(SourceBatch(**{**batch.__dict__, "track_depth": None}))


def test_the_training_loss_adds_the_weighted_track_loss_and_logs_it():
    torch.manual_seed(0)
    cfg = get_config("tiny", **SMALL, dynamic_splat=2)
    net = VideoTok4D(cfg)
    batch = random_batch(cfg, B=2, n_tracks=8)
    batch = SourceBatch(**{**batch.__dict__, "track_depth": torch.full(batch.track_valid.shape, DEPTH)})
    K, w2c = orbit_cameras(2, 4, 32, seed=1)
    frames = torch.rand(2, 4, 3, 32, 32)
    kwargs = dict(tau=torch.ones(2), generator=torch.Generator().manual_seed(0))
    plain, _ = net.rectified_flow_loss(batch, frames, K, w2c, **kwargs)
    kwargs["generator"] = torch.Generator().manual_seed(0)
    weighted, logs = net.rectified_flow_loss(batch, frames, K, w2c, track_weight=0.5, **kwargs)
    assert logs["track_loss"] > 0 and logs["track_px"] > 0
    assert abs(float(weighted - plain) - 0.5 * logs["track_loss"]) < 1e-4


def test_track_depths_samples_the_nearest_pixel_and_marks_the_unknown():
    depth = np.arange(2 * 8 * 8, dtype=np.float32).reshape(2, 8, 8) + 1.0
    xy = np.array([[[0.0, 0.0], [1.0, 2.0]], [[-5.0, 0.0], [3.0, 3.0]]], dtype=np.float32)  # (N 2, T 2, 2), 4 px
    valid = np.array([[True, True], [True, False]])
    got = track_depths(depth, xy, valid, latent_size=4)
    # latent (u, v) -> image pixel ((u + 0.5) 2 - 0.5) rounded: (0, 0) -> (0.5 -> 0 or 1), (1, 2) -> (2.5, 4.5)
    assert got[0, 0] == depth[0, round(0.5), round(0.5)]
    assert got[0, 1] == depth[1, round(4.5), round(2.5)]
    assert got[1, 0] == 0.0 and got[1, 1] == 0.0  # left the image; invalid


def test_source_inputs_carry_an_optional_track_depth_into_the_batch():
    T, N = 2, 3
    clip = dict(frames=np.zeros((T, 8, 8, 3), np.uint8), K=np.zeros((T, 3, 3), np.float32),
                w2c=np.zeros((T, 4, 4), np.float32), motion_mask=np.zeros((T, 2, 2), np.float32),
                track_xy=np.zeros((N, T, 2), np.float32), track_valid=np.ones((N, T), bool))
    with pytest.raises(ValueError, match="track_depth"):
        SourceInputs(**clip, track_depth=np.zeros((N, T + 1), np.float32))
    plain, deep = SourceInputs(**clip), SourceInputs(**clip, track_depth=np.ones((N, T), np.float32))
    assert "track_depth" not in stack_inputs([plain, deep])  # only when every clip has it
    batch = SourceBatch.collate([deep, deep])
    assert batch.track_depth is not None and batch.track_depth.shape == (2, N, T)
    assert SourceBatch.collate([plain]).track_depth is None


def test_the_track_descriptor_gives_each_dynamic_token_its_own_tracks_positions():
    cfg = get_config("tiny", **SMALL, dynamic_splat=2)
    net = VideoTok4D(cfg).eval()
    batch = random_batch(cfg, B=2, n_tracks=8)
    desc = net.track_descriptors(batch).view(2, 4, 4, 3)
    chosen = net.chosen_tracks(batch)
    h = cfg.latent_size
    for s in range(2):
        for k in range(4):
            i = int(chosen[s, k])
            valid = batch.track_valid[s, i]
            assert torch.equal(desc[s, k, :, 2], valid.float())
            want = (batch.track_xy[s, i] * 2 / (h - 1) - 1) * valid[:, None]
            assert torch.allclose(desc[s, k, :, :2], want)
    with torch.no_grad():  # the direct map reaches Z_d once it is non-zero, and only Z_d
        z_s0, z_d0 = net.encode(batch)
        net.track_direct.weight.normal_()
        z_s1, z_d1 = net.encode(batch)
    assert torch.equal(z_s0, z_s1) and not torch.allclose(z_d0, z_d1)
    assert VideoTok4D(cfg.replace(unified_tokens=True)).track_direct is None  # the ablation has no tracks


def test_the_patch_target_is_the_source_latent_around_the_track_averaged_over_its_valid_frames():
    torch.manual_seed(0)
    cfg = get_config("tiny", **SMALL, dynamic_splat=2)
    net = VideoTok4D(cfg)
    batch = random_batch(cfg, B=2, n_tracks=8)
    h, T = cfg.latent_size, batch.frames.shape[1]
    latents = torch.randn(2, T, cfg.latent_channels, h, h)
    xy = torch.randint(1, h - 2, batch.track_xy.shape).float()  # on latent pixel centres: no interpolation
    valid = batch.track_valid.clone()
    valid[:, :, 0] = False
    batch = SourceBatch(**{**batch.__dict__, "latents": latents, "track_xy": xy, "track_valid": valid})
    target, ok = net.patch_targets(batch)
    assert target.shape == (batch.num_scenes, 4, 4, cfg.latent_channels)
    clip, track = net._chosen_clip_track(batch)
    side = torch.tensor([-0.5, 0.5])
    dv, du = torch.meshgrid(side, side, indexing="ij")
    offsets = torch.stack([du, dv], -1).reshape(-1, 2)  # row-major (q, 2), as the renderer places the patch
    for k in range(4):
        n, i = int(clip[k]), int(track[k])
        frames = [t for t in range(T) if valid[n, i, t]]
        assert bool(ok[0, k]) == bool(frames)
        if not frames:
            continue
        points = xy[n, i, frames][:, None] + offsets  # (F, q, 2) latent px
        sampled = torch.nn.functional.grid_sample(latents[n, frames], (points * 2.0 / (h - 1) - 1.0)[:, :, None],
                                                  align_corners=True)  # (F, C, q, 1)
        torch.testing.assert_close(target[0, k], sampled[..., 0].mean(0).T, atol=1e-5, rtol=1e-5)


def test_the_patch_loss_trains_the_content_map_and_the_training_loss_adds_it():
    torch.manual_seed(0)
    cfg = get_config("tiny", **SMALL, dynamic_splat=2)
    net = VideoTok4D(cfg)
    batch = random_batch(cfg, B=2, n_tracks=8)
    with torch.no_grad():
        z_d = net.encode(batch)[1]
    opt = torch.optim.Adam(net.renderer.dynamic_content.parameters(), lr=3e-2)
    first = float(net.patch_loss(batch, z_d))
    assert first > 0
    for _ in range(500):
        opt.zero_grad()
        loss = net.patch_loss(batch, z_d)
        loss.backward()
        opt.step()
    assert float(loss) < 0.3 * first
    K, w2c = orbit_cameras(2, 4, 32, seed=1)
    frames = torch.rand(2, 4, 3, 32, 32)
    kwargs = dict(tau=torch.ones(2))
    plain, _ = net.rectified_flow_loss(batch, frames, K, w2c, generator=torch.Generator().manual_seed(0), **kwargs)
    weighted, logs = net.rectified_flow_loss(batch, frames, K, w2c, generator=torch.Generator().manual_seed(0),
                                             patch_weight=2.0, **kwargs)
    assert logs["patch_mse"] > 0
    assert abs(float(weighted - plain) - 2.0 * logs["patch_mse"]) < 1e-4
    with pytest.raises(ModelError, match="dynamic_splat"):
        VideoTok4D(get_config("tiny", **SMALL)).patch_loss(batch, z_d)


def test_dynamic_from_patch_is_checked_starts_at_zero_and_hands_each_token_the_latent_around_its_track():
    base = get_config("tiny", **SMALL, dynamic_splat=2)
    assert get_config("tiny", **SMALL, dynamic_splat=2, dynamic_from_patch=False).sha256() == base.sha256()
    for bad in (dict(dynamic_from_patch=True), dict(dynamic_splat=2, unified_tokens=True, dynamic_from_patch=True),
                dict(dynamic_splat=2, dynamic_from_patch=1)):
        with pytest.raises(ModelError, match="dynamic_from_patch"):
            get_config("tiny", **SMALL, **bad)
    torch.manual_seed(0)
    old = VideoTok4D(base).eval()
    new = VideoTok4D(base.replace(dynamic_from_patch=True)).eval()
    assert new.load_state_dict(old.state_dict(), strict=False).missing_keys == ["patch_direct.weight",
                                                                               "patch_direct.bias"]
    batch = random_batch(base, B=2, n_tracks=8)
    with torch.no_grad():
        a_old, a_new = old.encode_preactivations(batch), new.encode_preactivations(batch)
        assert torch.equal(a_old[0], a_new[0]) and torch.equal(a_old[1], a_new[1])  # warm start: unchanged
        new.patch_direct.weight.normal_()
        patches, _ = new.patch_targets(batch)
        a_s, a_d = new.encode_preactivations(batch)
    assert torch.equal(a_s, a_old[0])
    torch.testing.assert_close(a_d - a_old[1], patches.flatten(2) @ new.patch_direct.weight.T, atol=1e-5, rtol=1e-5)


def test_dynamic_opacity_gate_is_clamped_to_0_1_with_a_straight_through_gradient():
    # Regression: the gate was unbounded, so a trained run (the unified ablation) reached -0.09 and
    # composited negative opacities; alpha could also exceed 1.
    r = VideoTok4D(get_config("tiny", **SMALL, dynamic_splat=1)).renderer
    for raw, used in ((-0.09, 0.0), (0.63, 0.63), (1.7, 1.0)):
        with torch.no_grad():
            r.dynamic_gate.fill_(raw / DYNAMIC_GATE_SCALE)
        r.dynamic_gate.grad = None
        scale = r.dynamic_opacity_scale()
        assert abs(float(scale) - used) < 1e-6
        scale.backward()
        assert abs(float(r.dynamic_gate.grad) - DYNAMIC_GATE_SCALE) < 1e-3  # a bound does not freeze it
