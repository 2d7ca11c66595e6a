"""View gate (config ``view_gate_deg``): tokens seen from the target's direction win the locality logit."""

from __future__ import annotations

import math

import pytest
import torch

from vt4dcodec.errors import ModelError
from vt4dcodec.model import VideoTok4D, get_config

SMALL = dict(frames=4, image_size=32, width=32, heads=2, ae_width=8, spatial_layers=1, static_query_layers=1,
             track_layers=1, renderer_layers=1, n_static=32, n_dynamic=4, token_dim=8, n_tracks=8, patch_size=2,
             locality_sigma=0.35, query_from_grid=True, project_anchors=True, prediction="x0", anchor_views=True)


def look_at(angle_deg: float, radius: float = 3.0, size: int = 32) -> tuple[torch.Tensor, torch.Tensor]:
    """K (3, 3) px and w2c (4, 4) of a camera on a horizontal circle looking at the origin (y down)."""
    a = math.radians(angle_deg)
    centre = torch.tensor([radius * math.sin(a), 0.0, -radius * math.cos(a)])
    forward = -centre / centre.norm()
    down = torch.tensor([0.0, 1.0, 0.0])
    right = torch.linalg.cross(down, forward)
    R = torch.stack([right, down, forward])
    w2c = torch.eye(4)
    w2c[:3, :3], w2c[:3, 3] = R, -R @ centre
    K = torch.tensor([[0.9 * size, 0.0, (size - 1) / 2], [0.0, 0.9 * size, (size - 1) / 2], [0.0, 0.0, 1.0]])
    return K, w2c


def test_config_hash_is_kept_while_off_and_values_are_checked():
    base = get_config("tiny", **SMALL)
    assert get_config("tiny", **SMALL, view_gate_deg=0.0).sha256() == base.sha256()
    assert get_config("tiny", **SMALL, view_gate_deg=30.0).sha256() != base.sha256()
    for bad in (-1.0, 181.0, True, "30"):
        with pytest.raises(ModelError, match="view_gate_deg"):
            get_config("tiny", **SMALL, view_gate_deg=bad)
    with pytest.raises(ModelError, match="view_gate_deg"):
        get_config("tiny", **{**SMALL, "project_anchors": False, "anchor_views": False, "query_from_grid": False},
                   view_gate_deg=30.0)


def test_tokens_of_a_camera_across_the_scene_yield_to_those_of_the_target_camera():
    torch.manual_seed(0)
    plain = VideoTok4D(get_config("tiny", **SMALL)).eval()
    gated = VideoTok4D(get_config("tiny", **SMALL, view_gate_deg=30.0)).eval()
    gated.load_state_dict(plain.state_dict())  # no new weights
    cams = [look_at(0.0), look_at(150.0)]  # encoded cameras 0 and 1, nearly opposite
    K_src = torch.stack([k for k, _ in cams])[None]  # (1, 2, 3, 3)
    w2c_src = torch.stack([w for _, w in cams])[None]
    K_tgt, w2c_tgt = cams[0][0].expand(1, 4, 3, 3), cams[0][1].expand(1, 4, 4, 4)  # rendered at camera 0
    z_s, z_d = torch.rand(1, 32, 8) * 2 - 1, torch.rand(1, 4, 8) * 2 - 1
    with torch.no_grad():
        off = plain.renderer.projected_logit(z_s, z_d, K_tgt, w2c_tgt, K_src, w2c_src)
        on = gated.renderer.projected_logit(z_s, z_d, K_tgt, w2c_tgt, K_src, w2c_src)
    camera = plain.renderer.token_cameras(2)
    change = (on - off)[0, :, 0]  # (T, Na): the same for every render patch
    assert torch.allclose(on - off, change[None, :, None].expand_as(on), atol=1e-3)
    assert change[:, camera == 0].abs().max() < 1e-4  # seen exactly from the target's direction
    # across the scene: a near 150 deg at the origin, (1 - cos a) / s^2 = 1.87 / 0.27 = 6.8 there
    assert (change[:, camera == 1] < -3.0).all()
    # one encoded camera: every token is seen alike, so the penalty relative to the best is small
    with torch.no_grad():
        single = gated.renderer.projected_logit(z_s, z_d, K_tgt, w2c_tgt, K_src[:, 0], w2c_src[:, 0])
        free = plain.renderer.projected_logit(z_s, z_d, K_tgt, w2c_tgt, K_src[:, 0], w2c_src[:, 0])
    assert torch.allclose(single, free, atol=1e-4)
