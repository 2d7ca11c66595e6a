"""Co4DGen: a flow-matching prior over the VideoTok4D token space (paper Sec. 3.3).

    prior = Co4DGen(get_prior_config("co4dgen-tiny"))
    loss, logs = prior.flow_matching_loss(z_s, z_d, cond)            # Eq. 9, one training step
    z_s, z_d = prior.sample(cond, steps=16, seed=0, method="heun")  # one joint token state
    z_s, z_d = prior.sample(cond, guidance=2.0)                      # classifier-free guidance

Training pairs (c != a) of one event: the target is the anchor camera's joint token state
Z^a = [Z_s^a; Z_d^a] = E(V_a, P_a) (Eq. 8); the condition is (V_c, P_c, P_a) (:class:`PriorCondition`).
Tokens are standardised per stream and channel with statistics of the training set (buffers stored
with the weights) and perturbed on the linear path Z_tau = alpha_tau Z + sigma_tau eps with
alpha_tau = 1 - tau, sigma_tau = tau (rectified flow, the renderer's convention); the network predicts
the velocity v = eps - Z (Eq. 9).  Sampling integrates dZ/dtau = v from tau = 1 (seeded noise) to 0 with
Euler or Heun steps, un-standardises and clips to the tokenizer's open interval (-1, 1).

A prior configured with ``cond_dropout`` > 0 replaces that share of its training conditions by a learned
null condition (one vector in place of every condition token), so it also learns the unconditional
velocity; sampling with ``guidance`` w then follows v_uncond + w (v_cond - v_uncond) (classifier-free
guidance; w = 1 is the plain conditional sample).

Its configuration, :class:`~vt4dcodec.model.configs.PriorConfig`, sits in ``configs.py`` beside the
tokenizer's.  Weights: a prior directory holds ``prior.json`` (config, hashes and the fingerprint of the tokenizer the
prior was trained on), ``prior.safetensors`` and optionally ``MODEL_CARD.md``.  :func:`load_prior`
verifies the weights hash; :func:`check_tokenizer` refuses a tokenizer other than the recorded one.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from vt4dcodec.errors import ModelError
from vt4dcodec.format import ModelFingerprint

from .configs import PriorConfig
from .directories import DEFAULT_SAMPLER, SamplerSetting, checked_guidance
from .directories import check_tokenizer  # noqa: F401  (torch-free, where the ONNX prior needs it; kept importable here)
from .identity import ModelIdentity
from .layers import MLP
from .prior_blocks import CoDenoisingBlock, ConditionEncoder, flow_time_embedding

__all__ = ["PriorCondition", "Co4DGen", "check_tokenizer", "relative_pose", "SAMPLERS", "TOKEN_LIMIT",
           "RELATIVE_POSE_FEATURES", "SAMPLE_DTYPE"]

SAMPLERS = ("euler", "heun")
TOKEN_LIMIT = 1.0 - 1e-4  # sampled tokens are clipped to the tokenizer's bounded range (-1, 1)
RELATIVE_POSE_FEATURES = 24
SAMPLE_DTYPE = torch.float64  # what sample() computes in (the exported graphs too)


def relative_pose(w2c_a: torch.Tensor, w2c_c: torch.Tensor) -> torch.Tensor:
    """Where the anchor camera sits relative to the conditioning camera: M_t = w2c_a,t c2w_c,t per frame (the
    rigid inverse, no general solve), its top 3 x 4 block averaged over the frames, and the same block's
    largest |entry| deviation from the identity over the frames, 12 + 12 = 24 features; (B, T, 4, 4) x 2 ->
    (B, 24).  Zero deviation and the identity block exactly when the anchor is the conditioning camera."""
    R, t = w2c_c[..., :3, :3], w2c_c[..., :3, 3:]
    c2w = torch.cat([R.transpose(-1, -2), -R.transpose(-1, -2) @ t], dim=-1)                      # (B, T, 3, 4)
    M = w2c_a[..., :3, :3] @ c2w[..., :3]
    M = torch.cat([M, w2c_a[..., :3, :3] @ c2w[..., 3:] + w2c_a[..., :3, 3:]], dim=-1).flatten(2)  # (B, T, 12)
    eye = torch.eye(3, 4, dtype=M.dtype, device=M.device).flatten()
    return torch.cat([M.mean(dim=1), (M - eye).abs().amax(dim=1)], dim=-1)


@dataclass
class PriorCondition:
    """(V_c, P_c, P_a) for a batch.

    frames: (B, T, 3, H, W) float32 in [0, 1], the conditioning video V_c.
    K_c, w2c_c: (B, T, 3, 3) px and (B, T, 4, 4) metres, its cameras P_c.
    K_a, w2c_a: the anchor trajectory P_a whose token state is sampled.
    z_s, z_d: (B, N_s, d), (B, N_d, d) the tokenizer's tokens of the conditioning video, Z^c = E(V_c, P_c),
        for a prior configured with ``cond_tokens`` (None otherwise).
    """

    frames: torch.Tensor
    K_c: torch.Tensor
    w2c_c: torch.Tensor
    K_a: torch.Tensor
    w2c_a: torch.Tensor
    z_s: torch.Tensor | None = None
    z_d: torch.Tensor | None = None

    @property
    def batch_size(self) -> int:
        return int(self.frames.shape[0])

    def _map(self, fn: "Any") -> "PriorCondition":
        return PriorCondition(*(None if getattr(self, f.name) is None else fn(getattr(self, f.name))
                                for f in dataclasses.fields(self)))

    def to(self, device: torch.device | str) -> "PriorCondition":
        return self._map(lambda t: t.to(device))

    def validate(self, frames: range, image_size: int) -> None:
        """ModelError unless frames is (B, T, 3, image_size, image_size) with T in ``frames`` and every
        camera tensor is (B, T, 3, 3) / (B, T, 4, 4) and finite."""
        f = self.frames
        if f.ndim != 5 or f.shape[1] not in frames or f.shape[2:] != (3, image_size, image_size):
            raise ModelError(f"conditioning frames must be (B, {frames.start}..{frames.stop - 1}, 3, {image_size}, "
                             f"{image_size}), got {tuple(f.shape)}")
        B, T = f.shape[:2]
        for name, shape in (("K_c", (B, T, 3, 3)), ("w2c_c", (B, T, 4, 4)), ("K_a", (B, T, 3, 3)),
                            ("w2c_a", (B, T, 4, 4))):
            value = getattr(self, name)
            if tuple(value.shape) != shape:
                raise ModelError(f"condition {name} must be {shape}, got {tuple(value.shape)}")
            if not torch.isfinite(value).all():
                raise ModelError(f"condition {name} holds non-finite values")

    def repeat(self, n: int) -> "PriorCondition":
        """Each item repeated ``n`` times along the batch (for n independent samples)."""
        return self._map(lambda t: t.repeat_interleave(n, 0))


class Co4DGen(ModelIdentity, nn.Module):
    """v_omega(Z_tau, h, tau): the Co4DGen denoiser with its conditioning encoder.

    Identity (:class:`~.identity.ModelIdentity`) and ``tokenizer_fingerprint``, the fingerprint of the
    tokenizer whose tokens it models, are set by ``weights_io.load_prior`` from prior.json (None for a
    prior that was never saved and loaded).
    """

    tokenizer_fingerprint: ModelFingerprint | None = None
    sampler: SamplerSetting = DEFAULT_SAMPLER  # the setting prior.json records (set by load_prior)

    def __init__(self, cfg: PriorConfig) -> None:
        super().__init__()
        self.config = cfg
        D = cfg.width
        self.cond_encoder = ConditionEncoder(D, cfg.heads, cfg.mlp_ratio, cfg.cond_layers, cfg.frames,
                                             cfg.image_size, cfg.cond_patch, cfg.anchor_grid)
        self.in_s, self.in_d = nn.Linear(cfg.token_dim, D), nn.Linear(cfg.token_dim, D)
        self.pos_s = nn.Parameter(torch.randn(cfg.n_static, D) * 0.02)  # token identity (learned queries)
        self.pos_d = nn.Parameter(torch.randn(cfg.n_dynamic, D) * 0.02)
        self.time_mlp = MLP(D, 2.0)
        self.cond_pool = nn.Linear(D, D)
        self.blocks = nn.ModuleList(CoDenoisingBlock(D, cfg.heads, cfg.mlp_ratio) for _ in range(cfg.layers))
        self.out_norm_s = nn.LayerNorm(D, elementwise_affine=False)
        self.out_norm_d = nn.LayerNorm(D, elementwise_affine=False)
        self.out_mod = nn.Linear(D, 4 * D)
        self.out_s, self.out_d = nn.Linear(D, cfg.token_dim), nn.Linear(D, cfg.token_dim)
        for layer in (self.out_mod, self.out_s, self.out_d):
            nn.init.zeros_(layer.weight)
            nn.init.zeros_(layer.bias)
        # per-stream, per-channel token statistics of the training set (standardisation)
        if cfg.cond_dropout > 0:
            self.null_condition = nn.Parameter(torch.zeros(D))
        if cfg.cond_tokens:  # Z^c at the input and the relative pose P_a P_c^-1 in the modulation, both zero at
            # initialisation (a prior without them is the starting point)
            self.cond_in_s, self.cond_in_d = nn.Linear(cfg.token_dim, D), nn.Linear(cfg.token_dim, D)
            self.relative_pose = nn.Sequential(nn.Linear(RELATIVE_POSE_FEATURES, D), nn.SiLU(), nn.Linear(D, D))
            for layer in (self.cond_in_s, self.cond_in_d, self.relative_pose[2]):
                nn.init.zeros_(layer.weight)
                nn.init.zeros_(layer.bias)
        self.register_buffer("static_mean", torch.zeros(cfg.token_dim))
        self.register_buffer("static_std", torch.ones(cfg.token_dim))
        self.register_buffer("dynamic_mean", torch.zeros(cfg.token_dim))
        self.register_buffer("dynamic_std", torch.ones(cfg.token_dim))

    # ---------------------------------------------------------------------------------------------
    @torch.no_grad()
    def set_token_statistics(self, z_s: torch.Tensor, z_d: torch.Tensor, min_std: float = 1e-3) -> None:
        """Standardisation constants from training tokens z_s (M, N_s, d), z_d (M, N_d, d)."""
        self._check_tokens(z_s, z_d)
        self.static_mean.copy_(z_s.float().mean(dim=(0, 1)))
        self.static_std.copy_(z_s.float().std(dim=(0, 1)).clamp_min(min_std) if z_s.numel() > z_s.shape[-1]
                              else torch.ones_like(self.static_std))
        self.dynamic_mean.copy_(z_d.float().mean(dim=(0, 1)))
        self.dynamic_std.copy_(z_d.float().std(dim=(0, 1)).clamp_min(min_std) if z_d.numel() > z_d.shape[-1]
                               else torch.ones_like(self.dynamic_std))

    def normalize(self, z_s: torch.Tensor, z_d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return (z_s - self.static_mean) / self.static_std, (z_d - self.dynamic_mean) / self.dynamic_std

    def denormalize(self, x_s: torch.Tensor, x_d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return x_s * self.static_std + self.static_mean, x_d * self.dynamic_std + self.dynamic_mean

    def _check_tokens(self, z_s: torch.Tensor, z_d: torch.Tensor) -> None:
        cfg = self.config
        if z_s.ndim != 3 or z_s.shape[1:] != (cfg.n_static, cfg.token_dim) or z_d.ndim != 3 \
                or z_d.shape[1:] != (cfg.n_dynamic, cfg.token_dim) or z_s.shape[0] != z_d.shape[0]:
            raise ModelError(f"prior tokens must be (B, {cfg.n_static}, {cfg.token_dim}) and (B, {cfg.n_dynamic}, "
                             f"{cfg.token_dim}), got {tuple(z_s.shape)} and {tuple(z_d.shape)}")

    def _check_condition(self, cond: PriorCondition) -> None:
        if not isinstance(cond, PriorCondition):
            raise ModelError("the condition must be a PriorCondition")
        cond.validate(range(1, self.config.frames + 1), self.config.image_size)
        if self.config.cond_tokens:
            if cond.z_s is None or cond.z_d is None:
                raise ModelError("this prior is conditioned on the tokenizer's tokens of the conditioning video: the "
                                 "condition needs z_s and z_d (Z^c = E(V_c, P_c))")
            self._check_tokens(cond.z_s, cond.z_d)
            if cond.z_s.shape[0] != cond.batch_size or not (torch.isfinite(cond.z_s).all()
                                                            and torch.isfinite(cond.z_d).all()):
                raise ModelError("the condition tokens must be finite and one set per conditioning video")

    # ---------------------------------------------------------------------------------------------
    def encode_condition(self, cond: PriorCondition) -> torch.Tensor:
        """h = E_cond(V_c, P_c, P_a): (B, L, D)."""
        return self.condition_features(cond)[0]

    def condition_features(self, cond: PriorCondition
                           ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None]:
        """The checked condition as the denoiser takes it: h = E_cond(V_c, P_c, P_a) (B, L, D), and for a prior
        with ``cond_tokens`` :meth:`token_features` of its Z^c and cameras (None otherwise)."""
        self._check_condition(cond)
        dtype = self.static_mean.dtype  # float32, or float64 for the sampler's copy
        h = self.cond_encoder(cond.frames.to(dtype), cond.K_c.to(dtype), cond.w2c_c.to(dtype), cond.K_a.to(dtype),
                              cond.w2c_a.to(dtype))
        if not self.config.cond_tokens:
            return h, None
        return h, self.token_features(cond.z_s.to(dtype), cond.z_d.to(dtype),  # type: ignore[union-attr]
                                      cond.w2c_a.to(dtype), cond.w2c_c.to(dtype))

    def token_features(self, z_s: torch.Tensor, z_d: torch.Tensor, w2c_a: torch.Tensor, w2c_c: torch.Tensor
                       ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """A prior with ``cond_tokens``: the condition tokens Z^c (z_s, z_d) standardised and projected to the
        width, (B, N_s, D) and (B, N_d, D), added to the denoiser's input tokens, and the embedded relative pose
        of the anchor to the conditioning camera (:func:`relative_pose`), (B, D), added to the modulation (it
        tells the network whether and how far the anchor moved from the camera Z^c was encoded in).  Unchecked:
        :meth:`condition_features` checks a condition first (the exported graph calls this directly)."""
        zc_s, zc_d = self.normalize(z_s, z_d)
        return self.cond_in_s(zc_s), self.cond_in_d(zc_d), self.relative_pose(relative_pose(w2c_a, w2c_c))

    def velocity(self, x_s: torch.Tensor, x_d: torch.Tensor, h: torch.Tensor, tau: torch.Tensor,
                 tokens: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None
                 ) -> tuple[torch.Tensor, torch.Tensor]:
        """v_omega on standardised tokens x_s (B, N_s, d), x_d (B, N_d, d), tau (B,) -> (v_s, v_d);
        ``tokens``: :meth:`token_features` (a prior with ``cond_tokens``)."""
        c = flow_time_embedding(tau, self.config.width, self.time_mlp) + self.cond_pool(h.mean(dim=1))
        h_s = self.in_s(x_s) + self.pos_s
        h_d = self.in_d(x_d) + self.pos_d
        if tokens is not None:
            h_s, h_d, c = h_s + tokens[0], h_d + tokens[1], c + tokens[2]
        for block in self.blocks:
            h_s, h_d = block(h_s, h_d, h, c)
        shift_s, scale_s, shift_d, scale_d = self.out_mod(F.silu(c))[:, None].chunk(4, dim=-1)
        v_s = self.out_s(self.out_norm_s(h_s) * (1 + scale_s) + shift_s)
        v_d = self.out_d(self.out_norm_d(h_d) * (1 + scale_d) + shift_d)
        return v_s, v_d

    def flow_matching_loss(self, z_s: torch.Tensor, z_d: torch.Tensor, cond: PriorCondition,
                           generator: torch.Generator | None = None) -> tuple[torch.Tensor, dict[str, float]]:
        """L_Co4DGen = E_{tau, Z^a, eps} || v_omega(Z_tau^a, h, tau) - v_tau ||^2 (Eq. 9).

        z_s (B, N_s, d), z_d (B, N_d, d): the anchor tokens Z^a; ``generator`` (CPU) makes tau and eps
        reproducible.  Returns the scalar loss (mean over both streams' elements) and float logs.
        """
        self._check_tokens(z_s, z_d)
        if cond.batch_size != z_s.shape[0]:
            raise ModelError("tokens and condition have different batch sizes")
        B = z_s.shape[0]
        x_s, x_d = self.normalize(z_s.float(), z_d.float())
        eps_s = torch.randn(x_s.shape, generator=generator).to(x_s.device)
        eps_d = torch.randn(x_d.shape, generator=generator).to(x_d.device)
        tau = torch.rand((B,), generator=generator).to(x_s.device)
        t = tau.view(B, 1, 1)
        h, tokens = self.condition_features(cond)
        if self.config.cond_dropout > 0 and self.training:
            drop = (torch.rand((B,), generator=generator) < self.config.cond_dropout).to(h.device)
            h = torch.where(drop.view(B, 1, 1), self.null_condition.to(h.dtype).expand_as(h), h)
            if tokens is not None:  # the null condition has no tokens and no relative pose
                keep = (~drop).view(B, 1, 1).to(tokens[0].dtype)
                tokens = (tokens[0] * keep, tokens[1] * keep, tokens[2] * keep[:, 0])
        v_s, v_d = self.velocity((1 - t) * x_s + t * eps_s, (1 - t) * x_d + t * eps_d, h, tau, tokens)
        err_s = (v_s.float() - (eps_s - x_s)).pow(2)
        err_d = (v_d.float() - (eps_d - x_d)).pow(2)
        loss = torch.cat([err_s.flatten(1), err_d.flatten(1)], dim=1).mean()
        return loss, {"loss": float(loss.detach()), "loss_static": float(err_s.mean().detach()),
                      "loss_dynamic": float(err_d.mean().detach()), "tau": float(tau.mean())}

    def forward(self, z_s: torch.Tensor, z_d: torch.Tensor, cond: PriorCondition,
                generator: torch.Generator | None = None) -> tuple[torch.Tensor, dict[str, float]]:
        """The training objective (so DistributedDataParallel can wrap the prior)."""
        return self.flow_matching_loss(z_s, z_d, cond, generator)

    def guided_velocity(self, x_s: torch.Tensor, x_d: torch.Tensor, h: torch.Tensor, tau: torch.Tensor,
                        guidance: float, tokens: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None
                        ) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`velocity` with classifier-free guidance w: v_u + w (v_c - v_u), v_u the velocity under the
        null condition (no condition tokens; one batch of 2B); w = 1 is :meth:`velocity` itself."""
        if guidance == 1.0:
            return self.velocity(x_s, x_d, h, tau, tokens)
        B = x_s.shape[0]
        null = self.null_condition.to(h.dtype).expand_as(h)
        both = None if tokens is None else tuple(torch.cat([t, torch.zeros_like(t)]) for t in tokens)
        v_s, v_d = self.velocity(torch.cat([x_s, x_s]), torch.cat([x_d, x_d]), torch.cat([h, null]),
                                 torch.cat([tau, tau]), both)  # type: ignore[arg-type]
        return (v_s[B:] + guidance * (v_s[:B] - v_s[B:]), v_d[B:] + guidance * (v_d[:B] - v_d[B:]))

    @torch.no_grad()
    def sample(self, cond: PriorCondition, *, steps: int = 16, seed: int = 0, method: str = "heun",
               guidance: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
        """Draw one joint token state per condition: (Z_s (B, N_s, d), Z_d (B, N_d, d)) float32 in (-1, 1).

        Integrates dx/dtau = v from tau = 1 (noise from ``torch.Generator().manual_seed(seed)``) to 0 in
        ``steps`` uniform steps, Euler or Heun (2 network evaluations per step except the last), with
        classifier-free guidance ``guidance`` (1: none; other values need a prior trained with
        ``cond_dropout``).  Same condition, seed, steps, method and guidance -> the same tokens.  The network
        and the integration run in :data:`SAMPLE_DTYPE` (float64, :meth:`sampling_network`), so that the exported
        graphs (``model.onnx_prior``) reproduce the tokens to far below float32 rounding whatever order their
        kernels sum in; the tokens are rounded to float32 once, at the end.
        """
        if not isinstance(steps, int) or isinstance(steps, bool) or steps < 1:
            raise ModelError(f"steps must be a positive integer, got {steps!r}")
        if method not in SAMPLERS:
            raise ModelError(f"unknown sampler {method!r}; choose one of {SAMPLERS}")
        guidance = checked_guidance(guidance, self.config.cond_dropout)
        cfg = self.config
        net = self.sampling_network()
        h, tokens = net.condition_features(cond)
        B, device, dtype = h.shape[0], h.device, h.dtype
        generator = torch.Generator(device="cpu").manual_seed(int(seed))
        x_s = torch.randn((B, cfg.n_static, cfg.token_dim), generator=generator).to(device, dtype)
        x_d = torch.randn((B, cfg.n_dynamic, cfg.token_dim), generator=generator).to(device, dtype)
        for i in range(steps):
            t0, t1 = 1.0 - i / steps, 1.0 - (i + 1) / steps
            v_s, v_d = net.guided_velocity(x_s, x_d, h, torch.full((B,), t0, device=device, dtype=dtype), guidance,
                                           tokens)
            e_s, e_d = x_s + (t1 - t0) * v_s, x_d + (t1 - t0) * v_d
            if method == "heun" and t1 > 0:
                w_s, w_d = net.guided_velocity(e_s, e_d, h, torch.full((B,), t1, device=device, dtype=dtype),
                                               guidance, tokens)
                e_s = x_s + (t1 - t0) * 0.5 * (v_s + w_s)
                e_d = x_d + (t1 - t0) * 0.5 * (v_d + w_d)
            x_s, x_d = e_s, e_d
        z_s, z_d = net.denormalize(x_s, x_d)
        return (z_s.clamp(-TOKEN_LIMIT, TOKEN_LIMIT).float(), z_d.clamp(-TOKEN_LIMIT, TOKEN_LIMIT).float())

    def sampling_network(self) -> "Co4DGen":
        """This prior in :data:`SAMPLE_DTYPE` on its device: itself if it already is, else a copy, kept until
        one of its tensors changes (a training step, a load) and then made again."""
        if self.static_mean.dtype == SAMPLE_DTYPE:
            return self
        state = self.state_dict()
        key = tuple((t.data_ptr(), t._version) for t in state.values())
        cached = self.__dict__.get("_sampling_copy")  # not a registered submodule: not part of the state
        if cached is not None and cached[0] == key:
            return cached[1]
        net = Co4DGen(self.config)
        net.load_state_dict(state)
        net = net.to(device=self.static_mean.device, dtype=SAMPLE_DTYPE).eval()
        self.__dict__["_sampling_copy"] = (key, net)
        return net
