"""Sizes and helpers of the Co4DGen tests (fixtures are in conftest.py).  Everything is tiny (4 frames of 32x32, 8 + 4 tokens of width 8) so
the whole package of tests stays within its time budget; the architecture is the shipped one."""

from __future__ import annotations

import torch

from vt4dcodec.model.configs import get_prior_config
from vt4dcodec.model.prior import Co4DGen, PriorCondition

SMALL_TOKENIZER = dict(frames=4, image_size=32, width=32, heads=2, spatial_layers=1, static_query_layers=1,
                       track_layers=1, renderer_layers=1, n_static=8, n_dynamic=4, token_dim=8, n_tracks=8,
                       ae_width=8)
SMALL_PRIOR = dict(n_static=8, n_dynamic=4, token_dim=8, frames=4, image_size=32, cond_patch=8, anchor_grid=2,
                   cond_layers=1, width=32, heads=2, layers=2)
EVENTS, CAMERAS = 2, 3


def small_prior(seed: int = 0, *, scramble: bool = False) -> Co4DGen:
    """A small prior; ``scramble`` replaces the zero-initialised gates/outputs by random weights so every
    path of the network is live (a zero gate would make routing tests pass trivially)."""
    torch.manual_seed(seed)
    prior = Co4DGen(get_prior_config("co4dgen-tiny", **SMALL_PRIOR))
    if scramble:
        with torch.no_grad():
            for p in prior.parameters():
                if p.ndim >= 1 and not p.abs().gt(0).any():
                    p.normal_(0.0, 0.2)
    return prior.eval()


def random_condition(B: int = 2, T: int = 4, size: int = 32, seed: int = 0) -> PriorCondition:
    """Conditioning batch with plausible cameras: cameras looking down +z from a few offsets."""
    g = torch.Generator().manual_seed(seed)
    K = torch.tensor([[30.0, 0, (size - 1) / 2], [0, 30.0, (size - 1) / 2], [0, 0, 1]]).expand(B, T, 3, 3).clone()

    def poses() -> torch.Tensor:
        w2c = torch.eye(4).expand(B, T, 4, 4).clone()
        w2c[..., :3, 3] = torch.randn((B, T, 3), generator=g) * 0.3
        return w2c

    return PriorCondition(frames=torch.rand((B, T, 3, size, size), generator=g), K_c=K, w2c_c=poses(),
                          K_a=K.clone(), w2c_a=poses())


