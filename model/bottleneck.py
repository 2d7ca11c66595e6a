"""The token bottleneck (issue #5 item 5): encoder width D -> bounded tokens of width d.

Tokens are ``tanh`` of a linear projection, so every value lies in (-1, 1); int8 storage with scale
1/127 then has a rounding error of at most 1/254. In training, uniform noise of that half-width
(``cfg.token_noise``) is added, so the renderer learns to ignore exactly the error int8 introduces.
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["TokenBottleneck"]


class TokenBottleneck(nn.Module):
    def __init__(self, width: int, token_dim: int, noise: float) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(width)
        self.proj = nn.Linear(width, token_dim)
        self.noise = noise

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        """h: (B, N, D) query states -> tokens (B, N, d) float32 in (-1, 1) (+ noise in training)."""
        z = torch.tanh(self.proj(self.norm(h)).float())
        if self.training and self.noise > 0:
            z = z + (torch.rand_like(z) * 2.0 - 1.0) * self.noise
        return z
