"""The frozen latent autoencoder: it stands in for the paper's VA-VAE encoder and
VideoDCAE decoder, which cannot be downloaded here.

A per-frame convolutional autoencoder: RGB (3, H, W) in [0, 1] -> latent X_t (C, H/f, W/f) -> RGB.
It is trained first (stage 1, ``vt4dcodec.model.train.autoencoder``) and then frozen. Latents are
returned normalised per channel (buffers ``latent_mean`` / ``latent_std`` set from training data
after stage 1) so the rectified-flow renderer works on roughly unit-variance targets Y^0.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .configs import DenseConfig, ModelConfig

__all__ = ["LatentAutoencoder"]


def _norm(channels: int) -> nn.GroupNorm:
    return nn.GroupNorm(min(8, channels), channels)


def _channels_last(x: torch.Tensor) -> torch.Tensor:
    """The decoder's convolutions run in channels-last order (NHWC in memory): on the CPU oneDNN's convolutions of
    these few channels take about half the time they take on NCHW tensors (bench/bench_render_batch.py --stages);
    the frames are the same to float rounding (1e-6). The encoder stays NCHW: its latents feed the render
    feedback, whose tokens the exported graphs must match to 2e-6, and it gains little (a tenth)."""
    return x.contiguous(memory_format=torch.channels_last)


class ResBlock(nn.Module):
    def __init__(self, channels: int) -> None:
        super().__init__()
        self.body = nn.Sequential(
            _norm(channels), nn.SiLU(), nn.Conv2d(channels, channels, 3, padding=1),
            _norm(channels), nn.SiLU(), nn.Conv2d(channels, channels, 3, padding=1),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x)


class LatentAutoencoder(nn.Module):
    """Per-frame conv autoencoder with downsampling factor ``cfg.ae_downsample``."""

    def __init__(self, cfg: ModelConfig | DenseConfig) -> None:
        super().__init__()
        n_down = int(math.log2(cfg.ae_downsample))
        widths = [cfg.ae_width * min(2 ** i, 4) for i in range(n_down + 1)]
        enc: list[nn.Module] = [nn.Conv2d(3, widths[0], 3, padding=1)]
        for i in range(n_down):
            enc += [ResBlock(widths[i]), nn.Conv2d(widths[i], widths[i + 1], 3, stride=2, padding=1)]
        enc += [ResBlock(widths[-1]), _norm(widths[-1]), nn.SiLU(), nn.Conv2d(widths[-1], cfg.latent_channels, 3, padding=1)]
        self.encoder = nn.Sequential(*enc)
        dec: list[nn.Module] = [nn.Conv2d(cfg.latent_channels, widths[-1], 3, padding=1), ResBlock(widths[-1])]
        for i in reversed(range(n_down)):
            dec += [nn.Upsample(scale_factor=2, mode="nearest"), nn.Conv2d(widths[i + 1], widths[i], 3, padding=1),
                    ResBlock(widths[i])]
        dec += [_norm(widths[0]), nn.SiLU(), nn.Conv2d(widths[0], 3, 3, padding=1)]
        self.decoder = nn.Sequential(*dec)
        self.register_buffer("latent_mean", torch.zeros(cfg.latent_channels))
        self.register_buffer("latent_std", torch.ones(cfg.latent_channels))

    def encode_raw(self, images: torch.Tensor) -> torch.Tensor:
        """(N, 3, H, W) in [0, 1] -> un-normalised latents (N, C, h, w)."""
        return self.encoder(images * 2.0 - 1.0)

    def decode_raw(self, latents: torch.Tensor) -> torch.Tensor:
        """Un-normalised latents (N, C, h, w) -> RGB (N, 3, H, W) in [0, 1]."""
        return torch.sigmoid(self.decoder(_channels_last(latents))).contiguous()

    def encode(self, frames: torch.Tensor) -> torch.Tensor:
        """Video (B, T, 3, H, W) in [0, 1] -> normalised latents X (B, T, C, h, w)."""
        B, T = frames.shape[:2]
        z = self.encode_raw(frames.flatten(0, 1))
        z = (z - self.latent_mean[:, None, None]) / self.latent_std[:, None, None]
        return z.view(B, T, *z.shape[1:])

    def decode(self, latents: torch.Tensor) -> torch.Tensor:
        """Normalised latents (B, T, C, h, w) -> video (B, T, 3, H, W) in [0, 1]."""
        B, T = latents.shape[:2]
        z = latents.flatten(0, 1) * self.latent_std[:, None, None] + self.latent_mean[:, None, None]
        x = self.decode_raw(z)
        return x.view(B, T, *x.shape[1:])

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """Stage-1 reconstruction: (N, 3, H, W) in [0, 1] -> (N, 3, H, W) in [0, 1]."""
        return self.decode_raw(self.encode_raw(images))

    @torch.no_grad()
    def set_latent_statistics(self, images: torch.Tensor) -> None:
        """Set the per-channel normalisation from a sample of frames (N, 3, H, W) in [0, 1]."""
        z = self.encode_raw(images).transpose(0, 1).flatten(1)  # (C, N h w)
        self.latent_mean.copy_(z.mean(dim=1))
        self.latent_std.copy_(z.std(dim=1).clamp_min(1e-3))
