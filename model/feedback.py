"""Render feedback: the encoder's second look, at what its first tokens render.

The encoder's tokens Z^0 = tanh(A^0) are rendered at the encoded cameras exactly as the decoder renders them
(its recorded steps, seed 0), and the residual R = X - Y^0 -- source latents minus rendered latents, in the frozen
autoencoder's latent space -- goes back to the tokens that drew it:

- each anchored static token reads R in a window of its cell and the cells around it (``feedback_window``
  cells a side, 3 by default, of its encoded camera): the time average, and its frame group's change from it (zero for the time-average copies);
- each dynamic token reads R along its track (the patch it splats, averaged over the track's valid frames).

A small MLP per token group maps [Z^0, its residual] to a change of pre-activation, zero at initialisation (a
model warm-started with feedback begins as the model without it):

    Z = tanh(A^0 + dA),   dA = MLP([Z^0, R around the token])

One learned step of what encoder refinement (:mod:`.refine`) does by gradient descent on the render error --
amortised iterative inference (Marino et al. 2018, "Iterative amortized inference") -- with one render and no
gradient at encode time. Y^0 carries no gradient (a stop-gradient, as the decoder's render is a fixed
function of the tokens); gradients reach the MLPs and, through Z^0 and the residual's X, the encoder.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from vt4dcodec.errors import ModelError

from .configs import ModelConfig
from .layers import frame_group_change, render_noise

__all__ = ["RenderFeedback", "gradient_features"]

GRADIENT_EPS = 1e-20  # RMS floor of a scene's render gradient (an exact render has none)


def gradient_features(z: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """z, g (S, N, d): tokens and the render error's gradient by them -> [z, g / RMS, log RMS] (S, N, 2 d + 1),
    the RMS over each scene's N d values: the direction at unit scale, and the scale apart."""
    rms = g.float().square().mean(dim=(1, 2), keepdim=True).add(GRADIENT_EPS).sqrt()
    return torch.cat([z.float(), g.float() / rms, rms.log().expand(*g.shape[:2], 1)], dim=-1)


def _mlp(inputs: int, width: int, outputs: int) -> nn.Sequential:
    mlp = nn.Sequential(nn.Linear(inputs, width), nn.GELU(), nn.Linear(width, outputs))
    nn.init.zeros_(mlp[2].weight)
    nn.init.zeros_(mlp[2].bias)
    return mlp


class RenderFeedback(nn.Module):
    """dA_s (S, N_anchored, d) and dA_d (S, N_d, d) from the first tokens and the render residual.

    Config: ``feedback_width`` (the MLPs' hidden width; 0 = no feedback), ``feedback_window`` (cells a side of a
    static token's window), with ``token_from_cell`` and
    ``dynamic_splat`` (the cells and tracks it reads through)."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        C, p, d = cfg.latent_channels, cfg.patch_size, cfg.token_dim
        self.patch_size = p
        self.window = cfg.feedback_window * p  # the token's cell and (feedback_window - 1) / 2 on each side, latent px
        cell = C * self.window ** 2
        self.static = _mlp(d + 2 * cell, cfg.feedback_width, d)
        self.dynamic = _mlp(d + C * cfg.dynamic_splat ** 2, cfg.feedback_width, d)
        self.static_grad: nn.Sequential | None = None
        self.dynamic_grad: nn.Sequential | None = None
        if cfg.feedback_gradient:  # [Z, its render gradient at unit RMS, log RMS] -> a further dA (zero at init)
            self.static_grad = _mlp(2 * d + 1, cfg.feedback_width, d)
            self.dynamic_grad = _mlp(2 * d + 1, cfg.feedback_width, d)
        # the decoder's starting noise at seed 0 (VideoTok4D.render_latents): a constant of the encoder's graph
        self.register_buffer("noise", render_noise(cfg.frames, C, cfg.latent_size, 0), persistent=False)

    def windows(self, residual: torch.Tensor) -> torch.Tensor:
        """residual (B, T, C, h, w) -> (B, T, P, C window^2): each encoder cell's window, zero outside the image."""
        B, T = residual.shape[:2]
        p = self.patch_size
        cols = F.unfold(residual.flatten(0, 1), self.window, padding=(self.window - p) // 2, stride=p)  # (B T, C w^2, P)
        return cols.transpose(1, 2).reshape(B, T, cols.shape[2], cols.shape[1])

    def forward(self, z_s: torch.Tensor, z_d: torch.Tensor, residual: torch.Tensor, track_residual: torch.Tensor,
                cameras: torch.Tensor, covers: torch.Tensor, gradients: tuple[torch.Tensor, torch.Tensor] | None = None
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """z_s (S, N_s, d), z_d (S, N_d, d): the first tokens; residual (B, T, C, h, w), B = S V clips
        scene-major; track_residual (S, N_d, q C): R along each dynamic token's track; cameras (N_a,): each
        anchored token's encoded camera; covers (N_a, T): the frames of its frame group (all zero for the
        time-average copies); gradients (``feedback_gradient`` only): the render's squared latent error
        differentiated by Z_s (S, N_s, d) and Z_d (S, N_d, d). Returns (dA_s (S, N_a, d), dA_d (S, N_d, d))."""
        f_s, f_d = self.features(z_s, z_d, residual, track_residual, cameras, covers)
        d_s, d_d = self.static(f_s), self.dynamic(f_d)
        if self.static_grad is not None and self.dynamic_grad is not None:
            if gradients is None:
                raise ModelError("a feedback_gradient model's feedback needs the render gradients")
            n_a = cameras.shape[0]
            d_s = d_s + self.static_grad(gradient_features(z_s[:, :n_a], gradients[0][:, :n_a]))
            d_d = d_d + self.dynamic_grad(gradient_features(z_d, gradients[1]))
        return d_s, d_d

    def features(self, z_s: torch.Tensor, z_d: torch.Tensor, residual: torch.Tensor, track_residual: torch.Tensor,
                 cameras: torch.Tensor, covers: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """What the MLPs read (arguments as :meth:`forward`): ([Z^0, window mean, window group change]
        (S, N_a, d + 2 C window^2), [Z^0_d, track residual] (S, N_d, d + q C))."""
        S, n_a = z_s.shape[0], cameras.shape[0]
        B, T = residual.shape[:2]
        cells = self.windows(residual.float())  # (B, T, P, F)
        P, Fw = cells.shape[2:]
        cells = cells.view(S, B // S, T, P, Fw).transpose(2, 3)  # (S, V, P, T, F)
        index = torch.arange(n_a, device=cells.device)
        mine = cells[:, cameras, index % P]  # (S, N_a, T, F)
        return (torch.cat([z_s[:, :n_a].float(), mine.mean(2), frame_group_change(mine, covers)], dim=-1),
                torch.cat([z_d.float(), track_residual.float()], dim=-1))
