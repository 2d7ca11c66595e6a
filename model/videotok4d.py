"""VideoTok4D: the tokenizer E = (E_s, E_d) and the renderer D_theta, around a frozen autoencoder.

    z_s, z_d = model.encode(batch)                       # Eq. 1, tokens (B, N_s, d), (B, N_d, d)
    frames = model.render(z_s, z_d, K_tgt, w2c_tgt, source=(K_src, w2c_src))  # Euler integration
    loss, logs = model.rectified_flow_loss(batch, target_frames, K_tgt, w2c_tgt)   # Eq. 2

Rendering takes tokens, never source frames, so one token state renders any number of target
trajectories without re-running the encoder. A model with ``config.project_anchors`` also needs the
source trajectories (the encoded cameras': ``source=(K, w2c)``), whose middle frames place the
anchored tokens in 3-D; ``model.needs_source`` says so. Sampling noise comes from a ``torch.Generator`` seeded
with ``seed``: the same tokens and seed give the same frames.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import kornia
import torch
import torch.nn.functional as F
from torch import nn

from vt4dcodec.errors import ModelError
from vt4dcodec.format import ModelFingerprint

from .autoencoder import LatentAutoencoder
from .bottleneck import TokenBottleneck, centred_slot_spread, saturation_penalty, slot_diversity_penalty
from .configs import ModelConfig
from .diagnostics import token_health
from .entropy import MAX_VIEWS, TokenEntropyModel
from .feedback import RenderFeedback
from .identity import ModelIdentity, fingerprint_fields
from .layers import dynamic_patch_offsets, frame_group_change, patchify, render_noise
from .rays import latent_rays
from .renderer import Renderer
from .inputs.source_inputs import SourceBatch
from .spatial_branch import SpatialBranch
from .temporal_branch import TemporalBranch, sample_at_tracks, select_tracks

__all__ = ["VideoTok4D", "MIN_TAU", "DEFAULT_DECODE_STEPS", "MAX_DECODE_STEPS"]

MIN_TAU = 1e-3  # x0 prediction: v = (Y^tau - X0_hat) / max(tau, MIN_TAU)
DEFAULT_DECODE_STEPS = 8  # for model directories that record no decode_steps (written before it existed)
MAX_DECODE_STEPS = 1000


class VideoTok4D(ModelIdentity, nn.Module):
    """The whole model for one :class:`ModelConfig`.

    Identity (:class:`~.identity.ModelIdentity`: ``model_id``, ``model_version``, ``training_step``),
    ``decode_steps``, the sampler steps that give this model's best fidelity, the codec's default, and
    ``default_quality``, the quality level the codec stores tokens at when none is asked for (None: no
    default level; models without an entropy model have none), are set by ``weights_io.from_pretrained``
    from the model directory; none is part of the config hash.
    """

    decode_steps: int = DEFAULT_DECODE_STEPS
    default_quality: int | None = None

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.config = cfg
        self.autoencoder = LatentAutoencoder(cfg)
        n_spatial_queries = cfg.n_static + (cfg.n_dynamic if cfg.unified_tokens else 0)
        self.spatial_branch = SpatialBranch(cfg, n_spatial_queries)
        self.static_bottleneck = TokenBottleneck(cfg.width, cfg.token_dim, cfg.token_noise)
        if cfg.unified_tokens:  # ablation: one token set, same budget, no Temporal Branch
            self.temporal_branch = None
            self.dynamic_bottleneck = None
        else:
            self.temporal_branch = TemporalBranch(cfg)
            self.dynamic_bottleneck = TokenBottleneck(cfg.width, cfg.token_dim, cfg.token_noise)
        self.renderer = Renderer(cfg)
        self.cell_direct: nn.Linear | None = None
        if cfg.token_from_cell:  # static pre-activation + W * its cell's time-averaged latent (zero at init)
            self.cell_direct = nn.Linear(cfg.latent_channels * cfg.patch_size ** 2, cfg.token_dim)
            nn.init.zeros_(self.cell_direct.weight)
            nn.init.zeros_(self.cell_direct.bias)
        self.cell_frames: nn.Linear | None = None
        if cfg.frame_copies:  # a frame copy's pre-activation + W * (its frame group's cell - time average)
            self.cell_frames = nn.Linear(cfg.latent_channels * cfg.patch_size ** 2, cfg.token_dim)
            nn.init.zeros_(self.cell_frames.weight)
            nn.init.zeros_(self.cell_frames.bias)
        self.entropy: TokenEntropyModel | None = None
        if cfg.entropy_levels:  # quality levels: quantizer steps and token densities (model.entropy)
            self.entropy = TokenEntropyModel(cfg.entropy_levels, cfg.n_static, cfg.token_dim,
                                             classes=(11 if cfg.entropy_partners else 5) if cfg.entropy_context else 3,
                                             partners=cfg.entropy_partners or None)
        self.track_direct: nn.Linear | None = None
        if cfg.dynamic_splat and not cfg.unified_tokens:  # Z_d pre-activation + W * its track's (u, v, valid) per frame
            self.track_direct = nn.Linear(3 * cfg.frames, cfg.token_dim)
            nn.init.zeros_(self.track_direct.weight)
            nn.init.zeros_(self.track_direct.bias)
        self.patch_direct: nn.Linear | None = None
        if cfg.dynamic_from_patch:  # Z_d pre-activation + W * the source latent around its track (zero at init)
            self.patch_direct = nn.Linear(cfg.latent_channels * cfg.dynamic_splat ** 2, cfg.token_dim)
            nn.init.zeros_(self.patch_direct.weight)
            nn.init.zeros_(self.patch_direct.bias)
        self.feedback: RenderFeedback | None = None
        self.feedback_later: nn.ModuleList | None = None
        if cfg.feedback_width:  # the encoder's second look at what its first tokens render (zero at init)
            self.feedback = RenderFeedback(cfg)
            if cfg.feedback_passes > 1:  # further looks, each at what the previous pass's tokens render
                self.feedback_later = nn.ModuleList(RenderFeedback(cfg) for _ in range(cfg.feedback_passes - 1))

    # ---------------------------------------------------------------------------------------------
    def freeze_autoencoder(self) -> None:
        """Stage 2: the autoencoder is fixed (no gradients, never updated)."""
        self.autoencoder.requires_grad_(False)
        self.autoencoder.eval()

    def tokenizer_parameters(self) -> list[nn.Parameter]:
        """Everything trained in stage 2 (encoder branches, bottlenecks, renderer)."""
        return [p for name, p in self.named_parameters() if not name.startswith("autoencoder.")]

    def _check_video(self, frames: torch.Tensor, what: str) -> None:
        cfg = self.config
        if frames.ndim != 5 or frames.shape[2] != 3 or frames.shape[3:] != (cfg.image_size, cfg.image_size):
            raise ModelError(f"{what} must be (B, T, 3, {cfg.image_size}, {cfg.image_size}), got {tuple(frames.shape)}")
        if not 1 <= frames.shape[1] <= cfg.frames:
            raise ModelError(f"{what} has {frames.shape[1]} frames; this model takes 1..{cfg.frames}")
        if not frames.is_meta and not torch.isfinite(frames).all():
            raise ModelError(f"{what} hold non-finite values")

    def _check_cameras(self, K: torch.Tensor, w2c: torch.Tensor, B: int, T: int, what: str) -> None:
        if K.shape != (B, T, 3, 3) or w2c.shape != (B, T, 4, 4):
            raise ModelError(f"{what}: K must be ({B}, {T}, 3, 3) and w2c ({B}, {T}, 4, 4), "
                             f"got {tuple(K.shape)} and {tuple(w2c.shape)}")
        if not K.is_meta and not (torch.isfinite(K).all() and torch.isfinite(w2c).all()):
            raise ModelError(f"{what}: cameras hold non-finite values")

    @property
    def needs_source(self) -> bool:
        """Whether rendering needs the source trajectory (``config.project_anchors``)."""
        return bool(self.config.project_anchors)

    def render_cameras(self, K_tgt: torch.Tensor, w2c_tgt: torch.Tensor,
                       source: tuple[torch.Tensor, torch.Tensor] | None
                       ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor] | None:
        """The renderer's camera input: (K_tgt, w2c_tgt, K_src (B, V, 3, 3), w2c_src (B, V, 4, 4)) with the
        encoded cameras at the middle frame of ``source`` = (K (B, T_s, 3, 3), w2c (B, T_s, 4, 4)) for one
        camera, or (K (B, V, T_s, 3, 3), w2c (B, V, T_s, 4, 4)) for V encoded cameras in encoding order;
        None for models that do not use it (then ``source`` is ignored)."""
        if not self.needs_source:
            return None
        if source is None:
            raise ModelError("this model places its tokens with the source cameras: pass source=(K, w2c), the "
                             "trajectories of the encoded cameras (a Scene's cameras and extra_cameras)")
        K_src, w2c_src = source
        B = K_tgt.shape[0]
        if K_src.ndim == 4:
            K_src, w2c_src = K_src[:, None], w2c_src[:, None]
        if K_src.ndim != 5 or K_src.shape[0] != B or w2c_src.shape[:3] != K_src.shape[:3]:
            raise ModelError(f"source cameras: K must be ({B}, T, 3, 3) or ({B}, V, T, 3, 3) and w2c alike, "
                             f"got {tuple(K_src.shape)} and {tuple(w2c_src.shape)}")
        V, T_s = K_src.shape[1:3]
        self._check_cameras(K_src.flatten(0, 1), w2c_src.flatten(0, 1), B * V, T_s, "source cameras")
        mid = T_s // 2
        device = K_tgt.device
        return K_tgt, w2c_tgt, K_src[:, :, mid].to(device), w2c_src[:, :, mid].to(device)

    def rays(self, K: torch.Tensor, w2c: torch.Tensor) -> torch.Tensor:
        """Plücker rays of cameras (B, T) at latent resolution: (B, T, 6, h, w), always float32."""
        with torch.autocast("cuda" if K.device.type == "cuda" else "cpu", enabled=False):
            return latent_rays(K, w2c, self.config.image_size, self.config.latent_size)

    def _checked_latents(self, latents: torch.Tensor, B: int, T: int) -> torch.Tensor:
        cfg = self.config
        shape = (B, T, cfg.latent_channels, cfg.latent_size, cfg.latent_size)
        if tuple(latents.shape) != shape:
            raise ModelError(f"latents must be {shape}, got {tuple(latents.shape)}")
        return latents.float()

    def latents(self, frames: torch.Tensor) -> torch.Tensor:
        """X_t of the frozen encoder: (B, T, 3, H, W) in [0, 1] -> (B, T, C, h, w)."""
        with torch.no_grad():
            return self.autoencoder.encode(frames).float()

    # Eq. 1 ---------------------------------------------------------------------------------------
    def encode(self, batch: SourceBatch, feedback: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
        """Source clips -> (Z_s (S, N_s, d), Z_d (S, N_d, d)) float32 in (-1, 1), one token set per scene:
        S = B / batch.views scenes (one camera per scene unless the batch says otherwise). ``feedback=False``:
        the first pass Z^0 of a model with render feedback (the tokens of the same weights without it)."""
        return self._bound(*self.encode_preactivations(batch, feedback))

    def encode_passes(self, batch: SourceBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(Z_s, Z_d, Z_s^0, Z_d^0): the tokens and the first pass (equal without render feedback), computed once."""
        a_s, a_d, x, chosen = self._first_preactivations(batch)
        first = self._bound(a_s, a_d)
        if self.feedback is None:
            return (*first, *first)
        return (*self._bound(*self._feedback(batch, x, a_s, a_d, chosen)), *first)

    def _bound(self, a_s: torch.Tensor, a_d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Pre-activations -> tokens (the unified ablation bounds both groups with its one bottleneck)."""
        return self.static_bottleneck.bound(a_s), (self.dynamic_bottleneck or self.static_bottleneck).bound(a_d)

    def encode_preactivations(self, batch: SourceBatch, feedback: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
        """The bottleneck pre-activations (Z = tanh(A)): (A_s (S, N_s, d), A_d (S, N_d, d)) float32; with
        ``feedback=False`` those of the first pass (before render feedback)."""
        a_s, a_d, x, chosen = self._first_preactivations(batch)
        if feedback and self.feedback is not None:
            a_s, a_d = self._feedback(batch, x, a_s, a_d, chosen)
        return a_s, a_d

    def _first_preactivations(self, batch: SourceBatch
                              ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """(A_s^0, A_d^0, the source latents x (B, T, C, h, w), the chosen tracks or None): the encoder before
        render feedback."""
        cfg = self.config
        self._check_video(batch.frames, "source frames")
        B, T = batch.frames.shape[:2]
        V = batch.views
        if isinstance(V, bool) or not isinstance(V, int) or V < 1 or B % V:
            raise ModelError(f"a batch of {B} clips does not split into scenes of {V!r} views")
        self._check_cameras(batch.K, batch.w2c, B, T, "source cameras")
        h = cfg.latent_size
        if batch.motion_mask.shape != (B, T, h, h):
            raise ModelError(f"motion_mask must be ({B}, {T}, {h}, {h}), got {tuple(batch.motion_mask.shape)}")
        if batch.track_xy.ndim != 4 or batch.track_xy.shape[0] != B or batch.track_xy.shape[2:] != (T, 2) \
                or batch.track_valid.shape != batch.track_xy.shape[:3]:
            raise ModelError("track_xy must be (B, N, T, 2) and track_valid (B, N, T)")
        x = self.latents(batch.frames) if batch.latents is None else self._checked_latents(batch.latents, B, T)
        rays = self.rays(batch.K, batch.w2c)
        static_states = self.spatial_branch(x, rays, views=V)
        chosen = None
        if self.temporal_branch is None:  # unified ablation: Z_d is the Spatial Branch's last N_d queries
            a = self.static_bottleneck.preactivation(static_states)
            a_s, a_d = a[:, :cfg.n_static], a[:, cfg.n_static:]
        else:
            chosen = self.chosen_tracks(batch) if self.track_direct is not None else None  # dynamic_splat: once
            dynamic_states = self.temporal_branch(x, rays, batch.motion_mask, batch.track_xy, batch.track_valid,
                                                  views=V, chosen=chosen)
            a_s = self.static_bottleneck.preactivation(static_states)
            a_d = self.dynamic_bottleneck.preactivation(dynamic_states)
            if self.track_direct is not None:
                descriptors = self.track_descriptors(batch, chosen)
                a_d = a_d + self.track_direct(descriptors.to(self.track_direct.weight.dtype)).float()
            if self.patch_direct is not None:
                patches = self._track_patches(batch, x, chosen)[0].flatten(2)  # (S, N_d, q C)
                a_d = a_d + self.patch_direct(patches.to(self.patch_direct.weight.dtype)).float()
        if self.cell_direct is not None:
            cells = self.token_cells(x, V)  # (S, N_s, C p p)
            a_s = a_s + self.cell_direct(cells.to(self.cell_direct.weight.dtype)).float()
        if self.cell_frames is not None:
            covers = self.renderer.copy_frames(V)[:, :T]  # (N_s, T): copies covering none of the T frames get nothing
            change = self.token_frame_cells(x, V)  # zero for the time-average copies
            a_s = a_s + self.cell_frames(change.to(self.cell_frames.weight.dtype)).float() \
                * (covers.sum(1) > 0)[None, :, None]
        return a_s, a_d, x, chosen

    def feedback_modules(self) -> list[RenderFeedback]:
        """The render feedback passes in order (``config.feedback_passes``; empty without render feedback)."""
        return [] if self.feedback is None else [self.feedback, *(self.feedback_later or ())]

    def _feedback(self, batch: SourceBatch, x: torch.Tensor, a_s: torch.Tensor, a_d: torch.Tensor,
                  chosen: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        """A + dA of :class:`RenderFeedback`, once per pass (``config.feedback_passes``): the tokens so far
        rendered at the encoded cameras (:meth:`feedback_render`), the residual x - Y read back around each token."""
        reads = self.feedback_reads(batch, chosen)  # where the residual is read: the same for every pass
        for module in self.feedback_modules():
            y0, gradients = self.feedback_look(module, batch, a_s, a_d, x)
            a_s, a_d = self.feedback_update(module, a_s, a_d, x, y0, *reads, gradients=gradients)
        return a_s, a_d

    def feedback_look(self, module: RenderFeedback, batch: SourceBatch, a_s: torch.Tensor, a_d: torch.Tensor,
                      x: torch.Tensor) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor] | None]:
        """What a feedback pass reads of the tokens so far: their render Y (:meth:`feedback_render`) and, with
        ``feedback_gradient``, the render error's gradients (:meth:`feedback_render_gradients`; else None)."""
        if not self.config.feedback_gradient:
            return self.feedback_render(module, batch, a_s, a_d), None
        y0, g_s, g_d = self.feedback_render_gradients(module, batch, a_s, a_d, x)
        return y0, (g_s, g_d)

    def feedback_render(self, module: RenderFeedback, batch: SourceBatch, a_s: torch.Tensor,
                        a_d: torch.Tensor) -> torch.Tensor:
        """The tokens of pre-activations A rendered at the encoded cameras as the decoder renders them (its steps,
        the pass's seed-0 noise, no gradient): Y (B, T, C, h, w), each clip at its own trajectory."""
        z_s, z_d = self._bound(a_s, a_d)
        return self._render_encoded(module, batch, z_s.detach(), z_d.detach(), self.render_latents)

    def feedback_render_gradients(self, module: RenderFeedback, batch: SourceBatch, a_s: torch.Tensor,
                                  a_d: torch.Tensor, x: torch.Tensor
                                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """:meth:`feedback_render`'s Y with the gradient of the squared latent error sum (x - Y)^2 by the tokens:
        (Y (B, T, C, h, w), dL/dZ_s (S, N_s, d), dL/dZ_d (S, N_d, d)), all without a graph (a stop-gradient, as
        Y's). One backward pass through the renderer, whatever the caller's grad mode."""
        z_s, z_d = self._bound(a_s, a_d)
        with torch.enable_grad():
            zs, zd = z_s.detach().requires_grad_(True), z_d.detach().requires_grad_(True)
            error, y = self.feedback_render_error(module, batch, zs, zd, x.detach().float())
            g_s, g_d = torch.autograd.grad(error, [zs, zd])
        return y.detach(), g_s, g_d

    def feedback_render_error(self, module: RenderFeedback, batch: SourceBatch, z_s: torch.Tensor, z_d: torch.Tensor,
                              x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The squared latent error sum (x - Y)^2 of the tokens Z rendered at the encoded cameras (the decoder's
        render, differentiable: :meth:`render_latents` without its no-grad) and Y: what
        :meth:`feedback_render_gradients` differentiates (and ``onnx_export`` traces)."""
        render = functools.partial(type(self).render_latents.__wrapped__, self)
        y = self._render_encoded(module, batch, z_s, z_d, render)
        return (x - y).square().sum(), y

    def _render_encoded(self, module: RenderFeedback, batch: SourceBatch, z_s: torch.Tensor, z_d: torch.Tensor,
                        render: Callable[..., torch.Tensor]) -> torch.Tensor:
        """Each scene's tokens (S, N, d) rendered by ``render`` (:meth:`render_latents` or its undecorated
        function) at its clips' own trajectories, placed by the scene's encoded cameras, from the pass's noise."""
        V = batch.views
        K_src, w2c_src = batch.source
        if V > 1:  # every clip renders with its scene's encoded cameras
            K_src, w2c_src = K_src.repeat_interleave(V, 0), w2c_src.repeat_interleave(V, 0)
        return render(z_s.repeat_interleave(V, 0), z_d.repeat_interleave(V, 0), batch.K, batch.w2c,
                      source=(K_src, w2c_src), noise=module.noise[:, :batch.frames.shape[1]])

    def feedback_reads(self, batch: SourceBatch, chosen: torch.Tensor | None = None) -> tuple[torch.Tensor, ...]:
        """Where render feedback reads the residual, fixed by the batch before any render: each dynamic token's
        track as (clip (S N_d,) long, at (S N_d, T, q, 2) latent px, weight (S N_d, T)) (:meth:`_track_sampling`),
        and each anchored token's encoded camera (N_a,) long and frame group (N_a, T) (:class:`RenderFeedback`)."""
        r, V, T = self.renderer, batch.views, batch.frames.shape[1]
        device = batch.frames.device
        return (*self._track_sampling(batch, chosen), r.token_cameras(V).to(device), r.copy_frames(V)[:, :T].to(device))

    def feedback_update(self, module: RenderFeedback, a_s: torch.Tensor, a_d: torch.Tensor, x: torch.Tensor,
                        y0: torch.Tensor, clip: torch.Tensor, at: torch.Tensor, weight: torch.Tensor,
                        cameras: torch.Tensor, covers: torch.Tensor,
                        gradients: tuple[torch.Tensor, torch.Tensor] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """One feedback pass from its render: pre-activations A (S, N_s, d), (S, N_d, d), source latents x and
        their render Y (B, T, C, h, w) at the encoded cameras, the reads of :meth:`feedback_reads` -> A + dA;
        gradients: the render error's by the tokens (:meth:`feedback_render_gradients`, ``feedback_gradient``)."""
        z_s, z_d = self._bound(a_s, a_d)
        residual = x.float() - y0
        track = self._sample_tracks(residual, clip, at, weight, a_d.shape[0], a_d.shape[1])[0].flatten(2)
        d_s, d_d = module(z_s, z_d, residual, track, cameras, covers, gradients)  # track: (S, N_d, q C)
        n = d_s.shape[1]
        return torch.cat([a_s[:, :n] + d_s, a_s[:, n:]], dim=1), a_d + d_d

    def _check_tokens(self, z_s: torch.Tensor, z_d: torch.Tensor) -> None:
        cfg = self.config
        if z_s.ndim != 3 or z_s.shape[1:] != cfg.static_shape or z_d.ndim != 3 or z_d.shape[1:] != cfg.dynamic_shape \
                or z_s.shape[0] != z_d.shape[0]:
            raise ModelError(f"tokens must be (B, {cfg.n_static}, {cfg.token_dim}) and (B, {cfg.n_dynamic}, "
                             f"{cfg.token_dim}), got {tuple(z_s.shape)} and {tuple(z_d.shape)}")

    # sampling ------------------------------------------------------------------------------------
    @torch.no_grad()
    def render_latents(self, z_s: torch.Tensor, z_d: torch.Tensor, K_tgt: torch.Tensor, w2c_tgt: torch.Tensor,
                       *, steps: int | None = None, seed: int = 0, drop_static: bool = False,
                       drop_dynamic: bool = False,
                       source: tuple[torch.Tensor, torch.Tensor] | None = None,
                       noise: torch.Tensor | None = None) -> torch.Tensor:
        """Euler integration of dY/dtau = v from tau = 1 (seeded noise) to tau = 0, in ``steps`` steps
        (None: ``self.decode_steps``, the model's recorded best-fidelity setting).  Every item of the batch
        starts from the same noise (``seed``), so an item's render does not depend on its batch.

        K_tgt: (B, T, 3, 3) px of the H x W image; w2c_tgt: (B, T, 4, 4); source: the source trajectory
        (:meth:`render_cameras`; needed when ``needs_source``); noise: the starting noise (1, T, C, h, w) in place
        of ``seed``'s (a traced graph cannot hold a generator). Returns Y^0 (B, T, C, h, w).
        """
        self._check_tokens(z_s, z_d)
        steps = self.decode_steps if steps is None else steps
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ModelError(f"steps must be a positive integer, got {steps!r}")
        cfg = self.config
        B = z_s.shape[0]
        T = K_tgt.shape[1] if K_tgt.ndim == 4 else -1
        self._check_cameras(K_tgt, w2c_tgt, B, T, "target cameras")
        if not 1 <= T <= cfg.frames:
            raise ModelError(f"target trajectory has {T} frames; this model renders 1..{cfg.frames}")
        device = z_s.device
        h = cfg.latent_size
        if noise is None:
            noise = render_noise(T, cfg.latent_channels, h, seed)
        # every item starts from the same seeded noise: a view renders the same alone or in a batch
        y = noise.expand(B, -1, -1, -1, -1)
        y = y.contiguous().to(device)
        K_tgt, w2c_tgt = K_tgt.to(device), w2c_tgt.to(device)
        rays = self.rays(K_tgt, w2c_tgt)
        cameras = self.render_cameras(K_tgt, w2c_tgt, source)
        z_s, z_d = z_s.float(), z_d.float()
        for i in range(steps):
            tau = torch.full((B,), 1.0 - i / steps, device=device)
            v = self.velocity(y, z_s, z_d, rays, tau, cameras=cameras, drop_static=drop_static,
                              drop_dynamic=drop_dynamic)
            y = y - v / steps
        return y

    def velocity(self, y_tau: torch.Tensor, z_s: torch.Tensor, z_d: torch.Tensor, rays: torch.Tensor,
                 tau: torch.Tensor, cameras: tuple[torch.Tensor, ...] | None = None, **drop: bool) -> torch.Tensor:
        """v(Y^tau, Z_s, Z_d, P_tgt, tau) (B, T, C, h, w) float32, whatever the renderer predicts
        (``config.prediction``); rays are those of P_tgt at latent resolution, tau (B,) in (0, 1];
        cameras: :meth:`render_cameras` (None for models without projected anchors)."""
        if self.needs_source and cameras is None:
            raise ModelError("this model places its tokens with the source camera: pass cameras=render_cameras(...)")
        out = self.renderer(y_tau, z_s, z_d, rays, tau, cameras=cameras, **drop).float()
        if self.config.prediction == "velocity":
            return out
        t = tau.float().clamp_min(MIN_TAU).view(-1, 1, 1, 1, 1)
        return (y_tau.float() - out) / t

    @torch.no_grad()
    def render(self, z_s: torch.Tensor, z_d: torch.Tensor, K_tgt: torch.Tensor, w2c_tgt: torch.Tensor,
               **kwargs: Any) -> torch.Tensor:
        """Tokens + target trajectory -> frames (B, T, 3, H, W) in [0, 1] (kwargs as render_latents)."""
        latents = self.render_latents(z_s, z_d, K_tgt, w2c_tgt, **kwargs)
        # one item at a time: a batch's activations in one piece (tens of MB) are mapped afresh and faulted in
        # on every call, which made a batch of views decode ~1.5x slower per view on CPU; the same numbers
        frames = torch.cat([self.autoencoder.decode(item) for item in latents.split(1)])
        return frames.float().clamp_(0.0, 1.0)

    # Eq. 2 ---------------------------------------------------------------------------------------
    def rectified_flow_loss(self, batch: SourceBatch, target_frames: torch.Tensor, K_tgt: torch.Tensor,
                            w2c_tgt: torch.Tensor, generator: torch.Generator | None = None, *,
                            target_latents: torch.Tensor | None = None, tau: torch.Tensor | None = None,
                            drop_static: torch.Tensor | None = None, x0_weight: float = 0.0,
                            saturation_weight: float = 0.0, pixel_weight: float = 0.0, cell_weight: float = 0.0,
                            ssim_weight: float = 0.0, diversity_weight: float = 0.0, track_weight: float = 0.0,
                            patch_weight: float = 0.0, rate_level: int | None = None,
                            rate_lambda: float = 0.0, rate_quantized: bool = False,
                            stored: Callable[[torch.Tensor, torch.Tensor, int], tuple[torch.Tensor, torch.Tensor]]
                            | None = None) -> tuple[torch.Tensor, dict[str, float]]:
        """L_tok = E || (Y^1 - Y^0) - v_theta(Y^tau, Z_s, Z_d, P_tgt, tau) ||^2 (Eq. 2), plus optional terms.

        target_frames: (B, T, 3, H, W) in [0, 1]; K_tgt (B, T, 3, 3); w2c_tgt (B, T, 4, 4).
        tau: (B,) flow times in [0, 1]; default tau ~ U(0, 1) from ``generator`` (CPU), which also draws
        Y^1. At tau = 1 the one-step estimate Y^1 - v is what a 1-step render decodes, and the flow
        loss there is exactly its regression error.
        target_latents: optional (B, T, C, h, w) latents of ``target_frames`` (e.g. from a cache).
        drop_static: optional (B,) bool: items rendered without Z_s (token masking as in Table 4), so
        the renderer must read what Z_d carries and Z_d must carry it.
        x0_weight: weight of || Y^tau - tau v - Y^0 ||^2, the error of the one-step estimate of Y^0 at
        every tau (equal to the flow loss at tau = 1, tau^2 times it elsewhere). With
        ``config.prediction == "x0"`` that error is the loss (weight 1) and this is ignored.
        saturation_weight: weight of :func:`saturation_penalty` on the bottleneck pre-activations.
        pixel_weight: weight of the pixel MSE of the one-step estimate decoded by the frozen autoencoder,
        || D_ae(X0_hat) - target_frames ||^2 (gradients pass through the frozen decoder): the latent
        loss weighs every normalised channel alike, the pixel loss weighs them by what they do to the
        image -- what PSNR measures.
        cell_weight: weight of :meth:`cell_loss` (``config.token_splat`` only): each anchored static
        token, read by the splat's linear map alone, must give its own source cell's time-averaged latent.
        ssim_weight: weight of 1 - SSIM (kornia's, 11x11 Gaussian window, as the evaluation) of the one-step
        estimate decoded by the frozen autoencoder against ``target_frames``: the structure the latent
        MSE leaves blurred.
        diversity_weight: weight of :func:`slot_diversity_penalty` on the noise-free dynamic tokens
        tanh(a_d) of the batch's scenes: Z_d's slots must carry different scene-dependent content
        (trained from scratch next to the anchored static tokens, they drift onto one vector).
        track_weight: weight of :meth:`track_loss` (``config.dynamic_splat``; needs ``batch.track_depth``):
        each dynamic token must say where its track goes.
        patch_weight: weight of :meth:`patch_loss` (``config.dynamic_splat``): each dynamic token's patch
        content must be the source latent around its track.
        rate_level: with ``config.entropy_levels``, the quality level whose quantization the tokens get in
        place of the int8-sized noise (:meth:`TokenEntropyModel.noisy`), and ``rate_lambda`` the weight of
        its rate in bits per source pixel (bits / (views x frames x H x W)): the loss D + lambda R.
        rate_quantized: the renderer reads the level's stored token values (straight-through rounding)
        instead of the noisy ones; the rate still comes from the noise.
        stored: without ``rate_level``, a map (Z_s (S, N_s, d), Z_d (S, N_d, d), views) -> the token values a
        file stores for them (e.g. a frozen entropy model's writer codes at one level, no gradient to the
        encoder): the renderer is trained on exactly what it decodes.
        Returns the scalar loss and float logs (losses, tau, token health of the batch).
        """
        self._check_video(target_frames, "target frames")
        B, T = target_frames.shape[:2]
        self._check_cameras(K_tgt, w2c_tgt, B, T, "target cameras")
        if batch.batch_size != B * batch.views:
            raise ModelError(f"{B} targets need {B} source scenes; the batch holds {batch.batch_size} clips "
                             f"of {batch.views} view(s) each")
        if (cell_weight > 0 or patch_weight > 0) and batch.latents is None:  # encoder and losses: same latents
            batch = dataclasses.replace(batch, latents=self.latents(batch.frames))
        a_s, a_d = self.encode_preactivations(batch)
        bits = None
        if rate_level is not None:
            if self.entropy is None:
                raise ModelError("rate_level needs a model with an entropy model (config entropy_levels > 0)")
            z_s, z_d, bits = self.entropy.noisy(torch.tanh(a_s), torch.tanh(a_d), rate_level,
                                                self.static_origins(batch.views), quantized=rate_quantized)
        else:
            z_s, z_d = self._bound(a_s, a_d)
            if stored is not None:
                z_s, z_d = stored(z_s, z_d, batch.views)
        y0 = self.latents(target_frames) if target_latents is None else self._checked_latents(target_latents, B, T)
        y1 = torch.randn(y0.shape, generator=generator).to(y0.device)
        if tau is None:
            tau = torch.rand((B,), generator=generator)
        tau = tau.to(y0.device, torch.float32)
        if tau.shape != (B,) or not bool(((tau >= 0) & (tau <= 1)).all()):
            raise ModelError(f"tau must be ({B},) in [0, 1]")
        t = tau.view(B, 1, 1, 1, 1)
        y_tau = (1.0 - t) * y0 + t * y1
        drop = {} if drop_static is None else {"drop_static": drop_static.to(y0.device)}
        cameras = self.render_cameras(K_tgt, w2c_tgt, batch.source)
        out = self.renderer(y_tau, z_s, z_d, self.rays(K_tgt, w2c_tgt), tau, cameras=cameras, **drop).float()
        sat = saturation_penalty(torch.cat([a_s, a_d], dim=1))
        if self.config.prediction == "velocity":
            v, x0_hat = out, y_tau - t * out
            flow = F.mse_loss(v, y1 - y0)
            x0_err = F.mse_loss(x0_hat, y0)
            loss = flow + x0_weight * x0_err + saturation_weight * sat
        else:  # x0 prediction: the flow loss is tau^2-weighted x0 error; train on the x0 error itself
            x0_hat = out
            x0_err = F.mse_loss(x0_hat, y0)
            flow = (((y_tau - x0_hat) / t.clamp_min(MIN_TAU) - (y1 - y0)) ** 2).mean().detach()
            loss = x0_err + saturation_weight * sat
        if diversity_weight > 0:
            loss = loss + diversity_weight * slot_diversity_penalty(torch.tanh(a_d))
        track, track_px = torch.zeros(()), torch.zeros(())
        if track_weight > 0:
            track, track_px = self.track_loss(batch, z_d)
            loss = loss + track_weight * track
        patch = torch.zeros(())
        if patch_weight > 0:
            patch = self.patch_loss(batch, z_d)
            loss = loss + patch_weight * patch
        cell = torch.zeros(())
        if cell_weight > 0:
            cell = self.cell_loss(batch, z_s)
            loss = loss + cell_weight * cell
        bpp = torch.zeros(())
        if bits is not None:
            bpp = (bits / (batch.views * T * self.config.image_size ** 2)).mean()
            loss = loss + rate_lambda * bpp
        pixel, ssim = torch.zeros(()), torch.ones(())
        if pixel_weight > 0 or ssim_weight > 0:
            decoded = self.autoencoder.decode(x0_hat).float()
            if pixel_weight > 0:
                pixel = F.mse_loss(decoded, target_frames.float())
                loss = loss + pixel_weight * pixel
            if ssim_weight > 0:
                ssim = kornia.metrics.ssim(decoded.clamp(0.0, 1.0).flatten(0, 1),
                                           target_frames.float().flatten(0, 1), 11).mean()
                loss = loss + ssim_weight * (1.0 - ssim)
        logs = {"loss": float(loss.detach()), "flow": float(flow.detach()), "x0": float(x0_err.detach()),
                "pixel_mse": float(pixel.detach()), "cell_mse": float(cell.detach()),
                "track_loss": float(track.detach()), "track_px": float(track_px.detach()),
                "patch_mse": float(patch.detach()),
                **({} if bits is None else {"bpp": float(bpp.detach()), "token_bytes": float(bits.detach().mean()) / 8,
                                            "level": float(rate_level)}),
                "ssim": float(ssim.detach()),
                "saturation_penalty": float(sat.detach()), "tau": float(tau.mean()),
                "dynamic_centred_spread": float(centred_slot_spread(z_d.detach())),
                "z_s_abs": float(z_s.detach().abs().mean()), "z_d_abs": float(z_d.detach().abs().mean()),
                **token_health(z_s, z_d)}
        return loss, logs

    def static_origins(self, views: int) -> torch.Tensor:
        """(N_s,) long: the anchor origin of each static token when ``views`` cameras are encoded: the
        time-average token of its anchor for a frame copy (``Renderer.copy_origin``), itself otherwise
        (every token of a model without frame copies). The entropy model codes a copy given its origin."""
        index = torch.arange(self.config.n_static, device=self.static_bottleneck.proj.weight.device)
        if not self.config.frame_copies:
            return index
        origin = index.clone()
        origin[:self.renderer.n_anchored] = self.renderer.copy_origin(views).long()
        return origin

    @torch.no_grad()
    def update_entropy(self) -> None:
        """Freeze the entropy model's tables (:meth:`TokenEntropyModel.update`) with the static origins for
        1 .. MAX_VIEWS encoded cameras; a no-op without an entropy model. Run before a model ships."""
        if self.entropy is not None:
            self.entropy.update(torch.stack([self.static_origins(v) for v in range(1, MAX_VIEWS + 1)]).cpu())

    def chosen_tracks(self, batch: SourceBatch) -> torch.Tensor:
        """(S, N_d) the track of each dynamic token (:func:`select_tracks`; a mask of ones without
        ``config.motion_isolation``, as the Temporal Branch)."""
        mask = batch.motion_mask if self.config.motion_isolation else torch.ones_like(batch.motion_mask)
        return select_tracks(mask, batch.track_xy, batch.track_valid, self.config.n_dynamic, batch.views)

    def _chosen_clip_track(self, batch: SourceBatch, chosen: torch.Tensor | None = None
                           ) -> tuple[torch.Tensor, torch.Tensor]:
        """(clip, track), each (S N_d,) long: the batch item and track index of every dynamic token's track
        (``chosen`` (S, N_d), default :meth:`chosen_tracks`), scene-major then token order."""
        N = batch.track_valid.shape[1]
        if chosen is None:
            chosen = self.chosen_tracks(batch)  # (S, N_d) into each scene's V N tracks
        scenes = torch.arange(chosen.shape[0], device=chosen.device)[:, None]
        return (scenes * batch.views + chosen // N).flatten(), (chosen % N).flatten()

    def track_descriptors(self, batch: SourceBatch, chosen: torch.Tensor | None = None) -> torch.Tensor:
        """(S, N_d, 3 frames): each dynamic token's track (:meth:`chosen_tracks`) as (u, v) scaled to [-1, 1]
        and its validity per frame, zero at invalid frames and beyond the clip's T frames: the input of the
        direct map ``track_direct`` (zero at initialisation) into Z_d's pre-activation, so a token can hold
        where its track is without the attention having to find it. ``chosen``: that selection, if made."""
        cfg = self.config
        T, S, h = batch.track_valid.shape[2], batch.num_scenes, cfg.latent_size
        clip, track = self._chosen_clip_track(batch, chosen)
        valid = batch.track_valid[clip, track].float()[..., None]  # (S N_d, T, 1)
        uv = (batch.track_xy[clip, track].float() * (2.0 / max(h - 1, 1)) - 1.0) * valid
        desc = torch.cat([uv, valid], dim=-1)  # (S N_d, T, 3)
        desc = F.pad(desc, (0, 0, 0, cfg.frames - T))
        return desc.reshape(S, cfg.n_dynamic, 3 * cfg.frames)

    def track_targets(self, batch: SourceBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """What :meth:`Renderer.dynamic_track` should say for ``batch``'s tokens: each dynamic token's track
        (:func:`select_tracks`) unprojected at ``batch.track_depth`` with its camera at each frame and seen
        from that camera at the middle frame: (uv (S, N_d, T, 2) latent pixels, depth (S, N_d, T) metres,
        valid (S, N_d, T) bool: the track valid there, its depth known and in front of the camera)."""
        cfg = self.config
        if batch.track_depth is None:
            raise ModelError("the track loss needs the source tracks' depth (SourceBatch.track_depth)")
        T, S, ds = batch.track_valid.shape[2], batch.num_scenes, cfg.ae_downsample
        clip, track = self._chosen_clip_track(batch)
        xy = batch.track_xy[clip, track].float()  # (S N_d, T, 2)
        depth = batch.track_depth[clip, track].float()
        valid = batch.track_valid[clip, track].bool() & (depth > 0)
        K, w2c = batch.K[clip, :T].float(), batch.w2c[clip, :T].float()  # (S N_d, T, ...)
        pix = torch.cat([(xy + 0.5) * ds - 0.5, torch.ones_like(xy[..., :1])], dim=-1)
        x_cam = torch.einsum("ntij,ntj->nti", torch.linalg.inv(K), pix) * depth[..., None]
        R, t = w2c[..., :3, :3], w2c[..., :3, 3]
        x_world = torch.einsum("ntji,ntj->nti", R, x_cam - t)
        mid = T // 2
        x_mid = torch.einsum("nij,ntj->nti", R[:, mid], x_world) + t[:, mid, None]
        proj = torch.einsum("nij,ntj->nti", K[:, mid], x_mid)
        z = proj[..., 2]
        uv = (proj[..., :2] / z.clamp_min(1e-3)[..., None] + 0.5) / ds - 0.5
        valid = valid & (z > 1e-3)
        n_d = cfg.n_dynamic
        return uv.view(S, n_d, T, 2), z.view(S, n_d, T), valid.view(S, n_d, T)

    def track_loss(self, batch: SourceBatch, z_d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(loss, mean latent-pixel error) of :meth:`Renderer.dynamic_track` against :meth:`track_targets`:
        smooth-L1 of the (u, v) error in latent pixels plus smooth-L1 of 8 ln(depth ratio) (a 12 % depth
        error weighs as one latent pixel), averaged over the valid track frames. z_d (S, N_d, d)."""
        uv_t, depth_t, valid = self.track_targets(batch)
        T = uv_t.shape[2]
        w2c = batch.source[1]
        w2c_mid = (w2c[:, None] if w2c.ndim == 4 else w2c)[:, :, T // 2]
        uv, depth = self.renderer.dynamic_track(z_d, w2c_mid)
        uv, depth = uv[:, :, :T], depth[:, :, :T]
        weight = valid.float()
        count = weight.sum().clamp_min(1.0)
        uv_err = F.smooth_l1_loss(uv, uv_t, reduction="none", beta=1.0).sum(-1)
        depth_err = F.smooth_l1_loss(8.0 * torch.log(depth / depth_t.clamp_min(1e-3)), torch.zeros_like(depth),
                                     reduction="none", beta=1.0)
        loss = ((uv_err + depth_err) * weight).sum() / count
        px = ((uv - uv_t).norm(dim=-1) * weight).sum().detach() / count
        return loss, px

    def patch_targets(self, batch: SourceBatch) -> tuple[torch.Tensor, torch.Tensor]:
        """What each dynamic token's splat patch should hold (``config.dynamic_splat``): its encoded camera's
        source latent sampled bilinearly at the token's track (:meth:`chosen_tracks`) plus the patch offsets
        (row-major, as :meth:`Renderer.dynamic_placement`), averaged over the track's valid frames:
        (target (S, N_d, q, C), valid (S, N_d) bool: the track is valid at some frame), q = dynamic_splat^2."""
        B, T = batch.frames.shape[:2]
        x = self.latents(batch.frames) if batch.latents is None else self._checked_latents(batch.latents, B, T)
        return self._track_patches(batch, x)

    def _track_patches(self, batch: SourceBatch, x: torch.Tensor, chosen: torch.Tensor | None = None
                       ) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`patch_targets` from the source latents x (B, T, C, h, w) and the tracks ``chosen``."""
        clip, at, weight = self._track_sampling(batch, chosen)
        return self._sample_tracks(x, clip, at, weight, batch.num_scenes, self.config.n_dynamic)

    def _track_sampling(self, batch: SourceBatch, chosen: torch.Tensor | None = None
                        ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(clip (S N_d,) long, at (S N_d, T, q, 2), weight (S N_d, T)): each dynamic token's batch item, the
        latent pixels of its splat patch along its track (``chosen``) and the track's validity per frame."""
        cfg = self.config
        clip, track = self._chosen_clip_track(batch, chosen)
        xy = batch.track_xy[clip, track].float()  # (S N_d, T, 2) latent px, centres at integers
        weight = batch.track_valid[clip, track].float()  # (S N_d, T)
        at = (xy[:, :, None] + dynamic_patch_offsets(cfg.dynamic_splat, xy)).clamp(0.0, cfg.latent_size - 1)
        return clip, at, weight

    @staticmethod
    def _sample_tracks(x: torch.Tensor, clip: torch.Tensor, at: torch.Tensor, weight: torch.Tensor, S: int,
                       n_d: int) -> tuple[torch.Tensor, torch.Tensor]:
        """x (B, T, C, h, w) averaged over each track's valid frames at :meth:`_track_sampling`'s patch pixels:
        ((S, N_d, q, C), valid (S, N_d))."""
        sample = sample_at_tracks(x[clip].float(), at.transpose(1, 2)).transpose(1, 2)  # (S N_d, T, q, C)
        count = weight.sum(1)
        target = (sample * weight[..., None, None]).sum(1) / count.clamp_min(1.0)[:, None, None]
        return target.view(S, n_d, -1, x.shape[2]), (count > 0).view(S, n_d)

    def patch_loss(self, batch: SourceBatch, z_d: torch.Tensor) -> torch.Tensor:
        """|| patch content - :meth:`patch_targets` ||^2 over the dynamic tokens with a valid track: the
        renderer's linear content map (``dynamic_content``, its colour channels, not the opacity) must give
        the moving thing its track follows, so a patch placed on the track renders it and opening the
        opacity pays from the start. z_d: (S, N_d, d) of ``batch``."""
        r = self.renderer
        if r.dynamic_path is None:
            raise ModelError("the patch loss needs config.dynamic_splat")
        target, valid = self.patch_targets(batch)
        S, n_d, q, C = target.shape
        content = r.dynamic_content(z_d.to(r.dynamic_content.weight.dtype)).float().view(S, n_d, C + 1, q)
        err = ((content[:, :, :C].transpose(2, 3) - target) ** 2).mean((2, 3))
        weight = valid.float()
        return (err * weight).sum() / weight.sum().clamp_min(1.0)

    def cell_loss(self, batch: SourceBatch, z_s: torch.Tensor) -> torch.Tensor:
        """|| splat(z_i) - cell content ||^2 over the anchored static tokens: token i's cell is encoder cell
        i mod P of its encoded camera (:meth:`Renderer.token_cameras`), its content the source latent
        averaged over the frames (C p p values). Pushes each token to hold its cell in a form the
        renderer's direct path reads linearly. z_s: (S, N_s, d) of ``batch`` (S scenes)."""
        cfg, r = self.config, self.renderer
        if r.splat is None or cfg.renderer_patch != cfg.patch_size:
            raise ModelError("the cell loss needs config.token_splat with render_patch_size equal to patch_size")
        B, T = batch.frames.shape[:2]
        x = self.latents(batch.frames) if batch.latents is None else self._checked_latents(batch.latents, B, T)
        target = self.token_cells(x, batch.views)
        n = r.n_anchored
        loss = F.mse_loss(r.splat(z_s[:, :n].to(r.splat.weight.dtype)).float(), target.float())
        if r.splat_frames is None:
            return loss
        copies = r.copy_frames(batch.views).sum(1) > 0  # frame copies: their map gives their group's change
        if not bool(copies.any()):  # e.g. 5 cameras of 320 tokens: one per anchor
            return loss
        change = self.token_frame_cells(x, batch.views)[:, copies]
        difference = r.frame_difference(z_s, batch.views)[:, copies].to(r.splat_frames.weight.dtype)
        return loss + F.mse_loss(r.splat_frames(difference).float(), change.float())

    def token_cells(self, latents: torch.Tensor, views: int) -> torch.Tensor:
        """The time-averaged source latent inside each anchored static token's cell: (S, N_anchored, C p p)
        from latents (B, T, C, h, w) of S = B / views scenes; token i's cell is encoder cell i mod P of
        encoded camera :meth:`Renderer.token_cameras` (i mod V with ``config.anchor_views``, else 0)."""
        cfg, r = self.config, self.renderer
        B = latents.shape[0]
        cells = patchify(latents.float().mean(1, keepdim=True), cfg.patch_size)[:, 0]  # (B, P, C p p)
        cells = cells.view(B // views, views, cells.shape[1], cells.shape[2])
        index = torch.arange(r.n_anchored, device=cells.device)
        return cells[:, r.token_cameras(views), index % cells.shape[2]]

    def token_frame_cells(self, latents: torch.Tensor, views: int) -> torch.Tensor:
        """Each anchored static token's cell (as :meth:`token_cells`) averaged over the frames of its frame
        group (:meth:`Renderer.copy_frames`) minus the time average: (S, N_anchored, C p p), zero for a
        token that covers no frame (the time-average copies, and groups beyond the clip's T frames)."""
        cfg, r = self.config, self.renderer
        B, T = latents.shape[:2]
        P = cfg.patches_per_side ** 2
        cells = patchify(latents.float(), cfg.patch_size)  # (B, T, P, C p p)
        cells = cells.view(B // views, views, T, P, cells.shape[-1]).transpose(2, 3)  # (S, V, P, T, C p p)
        index = torch.arange(r.n_anchored, device=cells.device)
        mine = cells[:, r.token_cameras(views), index % P]  # (S, N_a, T, C p p)
        return frame_group_change(mine, r.copy_frames(views)[:, :T].to(cells.device))

    def forward(self, batch: SourceBatch, target_frames: torch.Tensor, K_tgt: torch.Tensor, w2c_tgt: torch.Tensor,
                generator: torch.Generator | None = None, **loss_options: Any) -> tuple[torch.Tensor, dict[str, float]]:
        """The training objective (so DistributedDataParallel can wrap the model): see rectified_flow_loss."""
        return self.rectified_flow_loss(batch, target_frames, K_tgt, w2c_tgt, generator, **loss_options)

    def fingerprint(self, model_id: str, model_version: str) -> ModelFingerprint:
        """The :class:`vt4dcodec.format.ModelFingerprint` a container stores for these weights."""
        return ModelFingerprint(**fingerprint_fields(self, model_id, model_version))

    def stored_fingerprint(self) -> ModelFingerprint:
        """The fingerprint a container stores for this model under its own identity ("unnamed", "0" for a
        model that was never saved or loaded), computed once per identity and kept."""
        if self._stored_fingerprint is None:
            self._stored_fingerprint = self.fingerprint(self.model_id or "unnamed", self.model_version or "0")
        return self._stored_fingerprint
