"""The dense per-view baseline of the paper's Table 2: a conditional latent video-diffusion model
(DFoT-style) that generates one target view's latent video directly from the conditioning video and
the target trajectory, one sampling run per view.

    dense = DenseViewDiffusion(get_dense_config("dense-tiny"))
    loss, logs = dense.flow_matching_loss(y, cond)            # y: target latents (B, T, C, h, w)
    frames = dense.generate(cond, steps=16, seed=0)           # (B, T, 3, H, W) in [0, 1]

It is Co4DGen's counterpart without the token space: where Co4DGen samples one joint token state
(N_s + N_d tokens) once and the renderer draws every view from it, this model denoises the
T (h/p)^2 latent patches of each target view itself, so 9 views cost 9 sampling runs over the full
latent video.  To make the comparison about that difference only, it shares with the Co4DGen pipeline

* the conditioning: the same :class:`~.prior_blocks.ConditionEncoder` E_cond(V_c, P_c, P_tgt) (video
  patches with their Plücker rays, plus target-ray tokens), and the same :class:`~.prior.PriorCondition`
  input (with the target trajectory in the anchor's place);
* the latent space: the tokenizer's frozen autoencoder (a copy is held here, frozen, so the weights
  directory is self-contained); latents are the autoencoder's normalised X_t;
* the generative path: rectified flow Y_tau = (1 - tau) Y + tau eps, velocity v = eps - Y, Euler steps
  from tau = 1 (seeded noise) to 0 (the renderer's and the prior's convention);
* the backbone family: the renderer's factorised space-time DiT block (:class:`~.layers.AdaLNBlock`:
  spatial attention within a frame, temporal attention across frames, cross-attention to the
  conditioning tokens, MLP, adaLN-zero from tau and the pooled condition).

"Matched size": dense-tiny's trainable parameters (E_cond + denoiser) equal co4dgen-tiny's plus
vt4d-tiny's renderer's to within a few per cent (``trainable_parameters``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from vt4dcodec.errors import ModelError

from .autoencoder import LatentAutoencoder
from .configs import DenseConfig
from .identity import ModelIdentity
from .layers import MLP, AdaLNBlock, patchify, unpatchify
from .prior import PriorCondition
from .prior_blocks import ConditionEncoder, flow_time_embedding
from .rays import latent_rays

__all__ = ["DenseViewDiffusion", "DENSE_SAMPLERS"]

DENSE_SAMPLERS = ("euler", "heun")


class DenseViewDiffusion(ModelIdentity, nn.Module):
    """v_theta(Y_tau, h, P_tgt, tau): the dense baseline's denoiser over one view's latent video.

    Identity (:class:`~.identity.ModelIdentity`) and ``tokenizer_fingerprint`` (the tokenizer whose
    autoencoder defines the latent space) are set by ``weights_io.load_dense``.
    """

    tokenizer_fingerprint = None

    def __init__(self, cfg: DenseConfig | dict) -> None:
        super().__init__()
        if isinstance(cfg, dict):
            cfg = DenseConfig.from_dict(cfg)
        self.config = cfg
        D, p, C = cfg.width, cfg.patch_size, cfg.latent_channels
        self.autoencoder = LatentAutoencoder(cfg)
        self.autoencoder.requires_grad_(False)
        self.cond_encoder = ConditionEncoder(D, cfg.heads, cfg.mlp_ratio, cfg.cond_layers, cfg.frames,
                                             cfg.image_size, cfg.cond_patch, cfg.anchor_grid)
        self.patch_embed = nn.Linear(C * p * p, D)
        self.ray_embed = nn.Linear(6 * p * p, D)
        self.frame_embed = nn.Parameter(torch.randn(cfg.frames, D) * 0.02)
        self.pos_embed = nn.Parameter(torch.randn((cfg.latent_size // p) ** 2, D) * 0.02)
        self.time_mlp = MLP(D, 2.0)
        self.cond_pool = nn.Linear(D, D)
        self.blocks = nn.ModuleList(AdaLNBlock(D, cfg.heads, cfg.mlp_ratio) for _ in range(cfg.layers))
        self.out_norm = nn.LayerNorm(D, elementwise_affine=False)
        self.out_mod = nn.Linear(D, 2 * D)
        self.out = nn.Linear(D, C * p * p)
        for layer in (self.out_mod, self.out):
            nn.init.zeros_(layer.weight)
            nn.init.zeros_(layer.bias)

    def trainable_parameters(self) -> int:
        """Parameters outside the frozen autoencoder (E_cond + denoiser)."""
        return sum(p.numel() for name, p in self.named_parameters() if not name.startswith("autoencoder."))

    def train(self, mode: bool = True) -> "DenseViewDiffusion":
        super().train(mode)
        self.autoencoder.eval()  # frozen: GroupNorm has no running state, but keep it in eval mode anyway
        return self

    # ---------------------------------------------------------------------------------------------
    def _check_condition(self, cond: PriorCondition) -> None:
        if not isinstance(cond, PriorCondition):
            raise ModelError("the condition must be a PriorCondition (V_c, P_c and the target trajectory)")
        cond.validate(range(self.config.frames, self.config.frames + 1), self.config.image_size)

    def _check_latents(self, y: torch.Tensor, B: int) -> None:
        cfg = self.config
        shape = (B, cfg.frames, cfg.latent_channels, cfg.latent_size, cfg.latent_size)
        if tuple(y.shape) != shape:
            raise ModelError(f"target latents must be {shape}, got {tuple(y.shape)}")

    def encode_condition(self, cond: PriorCondition) -> tuple[torch.Tensor, torch.Tensor]:
        """(h (B, L, D) = E_cond(V_c, P_c, P_tgt), target rays per generated patch (B, T, P, 6 p^2))."""
        self._check_condition(cond)
        cfg = self.config
        h = self.cond_encoder(cond.frames.float(), cond.K_c.float(), cond.w2c_c.float(), cond.K_a.float(),
                              cond.w2c_a.float())
        with torch.autocast(cond.frames.device.type, enabled=False):
            rays = latent_rays(cond.K_a.float(), cond.w2c_a.float(), cfg.image_size, cfg.latent_size)
        return h, patchify(rays, cfg.patch_size)

    def velocity(self, y: torch.Tensor, h: torch.Tensor, rays: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
        """v_theta on latents y (B, T, C, h, w), conditioning h (B, L, D), rays (B, T, P, 6 p^2), tau (B,)."""
        cfg = self.config
        B, T = y.shape[:2]
        c = flow_time_embedding(tau, cfg.width, self.time_mlp) + self.cond_pool(h.mean(dim=1))
        x = self.patch_embed(patchify(y, cfg.patch_size)) + self.ray_embed(rays)
        x = x + self.pos_embed + self.frame_embed[:T, None]
        for block in self.blocks:
            x = block(x, c, h, None)
        shift, scale = self.out_mod(F.silu(c))[:, None, None].chunk(2, dim=-1)
        out = self.out(self.out_norm(x) * (1 + scale) + shift)
        return unpatchify(out, cfg.patch_size, cfg.latent_channels, cfg.latent_size, cfg.latent_size)

    def flow_matching_loss(self, y: torch.Tensor, cond: PriorCondition, generator: torch.Generator | None = None
                           ) -> tuple[torch.Tensor, dict[str, float]]:
        """E_{tau, Y, eps} || v_theta(Y_tau, h, P_tgt, tau) - (eps - Y) ||^2 on the target view's latents
        y (B, T, C, h, w) (the autoencoder's normalised X_t); ``generator`` (CPU) makes tau and eps
        reproducible.  Returns the scalar loss and float logs."""
        B = cond.batch_size
        self._check_latents(y, B)
        y = y.float()
        eps = torch.randn(y.shape, generator=generator).to(y.device)
        tau = torch.rand((B,), generator=generator).to(y.device)
        t = tau.view(B, 1, 1, 1, 1)
        h, rays = self.encode_condition(cond)
        v = self.velocity((1 - t) * y + t * eps, h, rays, tau)
        loss = (v.float() - (eps - y)).pow(2).mean()
        return loss, {"loss": float(loss.detach()), "tau": float(tau.mean())}

    def forward(self, y: torch.Tensor, cond: PriorCondition, generator: torch.Generator | None = None
                ) -> tuple[torch.Tensor, dict[str, float]]:
        """The training objective (so DistributedDataParallel can wrap the model)."""
        return self.flow_matching_loss(y, cond, generator)

    @torch.no_grad()
    def sample_latents(self, cond: PriorCondition, *, steps: int = 16, seed: int = 0, method: str = "euler"
                       ) -> torch.Tensor:
        """One target latent video per condition: (B, T, C, h, w), integrating dY/dtau = v from tau = 1
        (noise from ``torch.Generator().manual_seed(seed)``) to 0 in ``steps`` uniform Euler or Heun steps."""
        if not isinstance(steps, int) or isinstance(steps, bool) or steps < 1:
            raise ModelError(f"steps must be a positive integer, got {steps!r}")
        if method not in DENSE_SAMPLERS:
            raise ModelError(f"unknown sampler {method!r}; choose one of {DENSE_SAMPLERS}")
        cfg = self.config
        h, rays = self.encode_condition(cond)
        B, device = h.shape[0], h.device
        generator = torch.Generator(device="cpu").manual_seed(int(seed))
        y = torch.randn((B, cfg.frames, cfg.latent_channels, cfg.latent_size, cfg.latent_size),
                        generator=generator).to(device)
        for i in range(steps):
            t0, t1 = 1.0 - i / steps, 1.0 - (i + 1) / steps
            v = self.velocity(y, h, rays, torch.full((B,), t0, device=device)).float()
            e = y + (t1 - t0) * v
            if method == "heun" and t1 > 0:
                w = self.velocity(e, h, rays, torch.full((B,), t1, device=device)).float()
                e = y + (t1 - t0) * 0.5 * (v + w)
            y = e
        return y

    @torch.no_grad()
    def generate(self, cond: PriorCondition, *, steps: int = 16, seed: int = 0, method: str = "euler"
                 ) -> torch.Tensor:
        """The target view itself: (B, T, 3, H, W) in [0, 1], decoded by the frozen autoencoder."""
        return self.autoencoder.decode(self.sample_latents(cond, steps=steps, seed=seed, method=method)).clamp(0, 1)

    @torch.no_grad()
    def latents(self, frames: torch.Tensor) -> torch.Tensor:
        """Training targets: video (B, T, 3, H, W) in [0, 1] -> normalised latents (B, T, C, h, w)."""
        return self.autoencoder.encode(frames.float()).float()
