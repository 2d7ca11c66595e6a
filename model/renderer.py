"""Renderer D_theta (paper Sec. 3.1, Eq. 2): the rectified-flow velocity network
v_theta(Y^tau, Z_s, Z_d, P_tgt, tau) over target-video latents.

Target latents Y^tau (B, T, C, h, w) are patchified together with the Plücker rays of P_tgt, pass
through tau-modulated (AdaLN) blocks of spatial, temporal and token cross-attention, and are
unpatchified into a velocity of the same shape. Token masking (the ablation of Table 4): a dropped group
(Z_s or Z_d) is removed from the keys of every cross-attention.

Token locality (``config.locality_sigma``): half of the heads of every token cross-attention get a
Gaussian logit bias that ties render patch j to the static tokens anchored near it. Without
``config.project_anchors`` the bias is a learned (heads, P, N) table on the source image grid, the same
at every target pose; with it the anchors are placed in 3-D (the source camera's cell ray at a depth read
from the token) and projected into each target frame, so the bias moves with the target camera. With
``config.anchor_views`` and V encoded cameras, token i's cell ray is that of encoded camera i mod V
(``config.spread_views``: :func:`layers.token_cameras`).

Token splat (``config.token_splat``, x0 prediction with projected anchors): besides the attention, each
anchored static token reaches the output directly. A linear map (zero at initialisation) turns the token
into one render patch of latent content; it is placed at the token's projection in every target frame
with the locality Gaussian's weights, normalised over the tokens that land on a patch plus a floor
(``SPLAT_FLOOR``) so that a patch no token covers gets nothing, and added to the network's estimate of
the clean latent X0; the network also sees the splat as an input, so it predicts the correction.

Frame copies (``config.frame_copies``): anchored tokens sharing an anchor (camera and cell) split the clip's
frames (:meth:`Renderer.copy_frames`); a second linear map of each copy's difference from its anchor's
time-average copy (:meth:`Renderer.copy_origin`) is splatted only in the target frames of its group,
normalised over the copies covering that frame. Equal copies add nothing, so a warm start renders as before.

View gate (``config.view_gate_deg``): each anchored token's locality logit (attention bias and splat alike)
loses (1 - cos a) / s^2, a the angle at the token between the rays from its encoded camera and from the
target, relative to the best-aligned token of that target frame: with several encoded cameras, a token
described from the other side of the scene yields to those seen from nearly the target's direction.

Pixel splat (``config.pixel_splat``): the splat works on latent pixels instead of render patches. Each of a
token's p x p latent pixels sits on its own ray of the encoded camera at the token's depth, is projected
into the target frame, and spreads over the latent grid with a Gaussian of ``locality_sigma`` latent
pixels (view gate and dropped tokens as above), normalised per latent pixel over all tokens' pixels plus
the floor: a forward warp of the tokens' content at latent-pixel precision. With ``config.patch_gate_deg`` a
share exp(-a^2 / 2 s^2) of each token (a as for the view gate) goes through the patch splat instead: tokens
seen from near their own camera's direction keep the patch splat's snapping to their cell.

Dynamic splat (``config.dynamic_splat`` = s): each dynamic token k (encoded camera k mod V) decodes its
track's position in every frame (:meth:`Renderer.dynamic_track`: latent pixel (u, v) in its camera at the
middle frame and a depth) and an s x s patch of latent content with an opacity per latent pixel
(:meth:`Renderer.composite_dynamic`). The patch's latent pixels are unprojected at that depth and
forward-warped into target frame t with the pixel splat's Gaussian (view gate as above, relative among
the dynamic tokens), then composited over the static splat: out = S (1 - A) + sum w alpha c / (sum w +
SPLAT_FLOOR), A = sum w alpha / (sum w + SPLAT_FLOOR). Opacities are scaled by a learned gate that starts
at 0, so a warm start renders as before, and with ``config.dynamic_gate_deg`` s by 1 - exp(-a^2 / 2 s^2) in
each target frame (a the angle at the patch centre between its encoded camera's ray and the target's): along
its own camera's direction a token leaves the moving object to the frame copies (with
``config.dynamic_gate_copies`` only as far as that camera's frame copies resolve time).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from .configs import ModelConfig
from .layers import (AdaLNBlock, dynamic_patch_offsets, dynamic_token_cameras, grid_positions, locality_heads,
                     locality_prior, patchify, timestep_embedding, token_cameras, unpatchify)

__all__ = ["Renderer", "MAX_DEPTH_LOG_FACTOR", "MIN_ANCHOR_DEPTH", "SPLAT_FLOOR", "DYNAMIC_GATE_SCALE"]

MAX_DEPTH_LOG_FACTOR = 2.0  # a token's depth is d_ref * exp(f), f in (-2, 2): 0.14x .. 7.4x the reference
MIN_ANCHOR_DEPTH = 0.1  # metres; the reference depth (of the world origin) is clamped to at least this
FAR_LOGIT = -1.0e4  # bias of an anchor behind the target camera, and the floor of every Gaussian logit
DYNAMIC_GATE_SCALE = 100.0  # dynamic splat: opacity gate = this x a parameter starting at 0 (Adam moves it ~lr a step)
SPLAT_FLOOR = 0.1  # token splat: weight of "nothing" in each patch's normalisation (a lone token on its cell: 0.91)
EXP_MIN = -87.0  # below this float32 exp is denormal or 0, and torch's CPU exp falls back to a ~15x slower path
# Camera geometry -- anchor and track points, their projections into the target, the Gaussian distances and the
# angles of the view gates -- runs in float64 and is rounded to float32 at the exponent: a float32 projection
# puts a splat ~1e-5 latent pixels off, and the sigma-0.35 Gaussians turn that into ~1e-5 of the render, more
# than the network's own rounding (the encoder's render feedback reads it). Costs no measurable time (ten views,
# one thread: 0.44-0.46 s with it, 0.45 s without).
GEOMETRY_DTYPE = torch.float64


def _exp(x: torch.Tensor) -> torch.Tensor:
    """exp(x) for Gaussian weights and gates: 0 where x < EXP_MIN (exp would give at most 1.7e-38 there), so
    the far tails (distances of many sigma, FAR_LOGIT) stay on the vectorised path; a render changes by
    less than 1e-30 and batched renders run several times faster on CPU."""
    return torch.where(x < EXP_MIN, 0.0, torch.exp(x.clamp_min(EXP_MIN)))


def _splat_sum(rows: torch.Tensor, values: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
    """The separable splat's sum (B, T, K, h, w) = sum over n of rows[b, t, n, y] values[b, t, n, k] cols[b, t, n, x]
    (rows (B, T, N, h), values (B, T or 1, N, K), cols (B, T, N, w)). One batch item at a time: its (T, N, h K)
    products are a few MB, where a batch's in one piece are tens of MB that the allocator maps afresh and the
    CPU faults in on every call (a batch of views rendered slower per view than views alone)."""
    out = []
    for r, v, c in zip(rows, values, cols):  # (T, N, h), (T | 1, N, K), (T, N, w)
        T, N, h = r.shape
        products = (r[..., None] * v[:, :, None]).reshape(T, N, h * v.shape[-1])
        out.append((products.transpose(1, 2) @ c).view(T, h, v.shape[-1], -1).transpose(1, 2))
    return torch.stack(out)


class Renderer(nn.Module):
    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        p, D, C = cfg.renderer_patch, cfg.width, cfg.latent_channels
        self.cfg = cfg
        self.embed = nn.Linear((C + 6) * p * p, D)
        self.pos_space = nn.Parameter(torch.randn(cfg.renderer_patches_per_side ** 2, D) * 0.02)
        self.pos_time = nn.Parameter(torch.randn(cfg.frames, D) * 0.02)
        self.tau_mlp = nn.Sequential(nn.Linear(D, D), nn.SiLU(), nn.Linear(D, D))
        self.token_in = nn.Linear(cfg.token_dim, D)
        n_tokens = cfg.n_static + cfg.n_dynamic
        self.token_slot = nn.Parameter(torch.randn(n_tokens, D) * 0.02)  # queries keep their slot order
        self.token_type = nn.Parameter(torch.randn(2, D) * 0.02)  # static, dynamic
        self.blocks = nn.ModuleList(AdaLNBlock(D, cfg.heads, cfg.mlp_ratio) for _ in range(cfg.renderer_layers))
        self.final_norm = nn.LayerNorm(D, elementwise_affine=False)
        self.final_mod = nn.Linear(D, 2 * D)
        self.out = nn.Linear(D, C * p * p)
        self.token_bias = None
        self.depth_head: nn.Linear | None = None
        self.n_anchored = 0
        if cfg.locality_sigma > 0:  # render patch j prefers the static tokens anchored near it (configs)
            cells = grid_positions(cfg.patches_per_side)  # encoder grid, in encoder patches
            self.n_anchored = cfg.n_anchored
            anchors = cells[torch.arange(self.n_anchored) % cells.shape[0]]
            patches = grid_positions(cfg.renderer_patches_per_side, cfg.renderer_patch / cfg.patch_size)
            if cfg.project_anchors:  # anchors (row, col) in encoder patches; patch centres likewise
                self.register_buffer("anchor_cells", anchors, persistent=False)
                self.register_buffer("patch_cells", patches, persistent=False)
                self.depth_head = nn.Linear(cfg.token_dim, 1)  # log depth factor; zero: the reference depth
                nn.init.zeros_(self.depth_head.weight)
                nn.init.zeros_(self.depth_head.bias)
            else:
                prior = torch.zeros(cfg.heads, patches.shape[0], n_tokens)
                prior[:, :, :self.n_anchored] = locality_prior(patches, anchors, cfg.heads, cfg.locality_sigma)
                self.token_bias = nn.Parameter(prior)
        self.splat: nn.Linear | None = None
        if cfg.token_splat:  # token -> one render patch of latent content, placed where the token projects
            self.splat = nn.Linear(cfg.token_dim, C * p * p)
            self.splat_in = nn.Linear(C * p * p, D)
            for layer in (self.splat, self.splat_in):
                nn.init.zeros_(layer.weight)
                nn.init.zeros_(layer.bias)
        self.splat_frames: nn.Linear | None = None
        if cfg.frame_copies:  # a frame copy's difference from its time-average copy -> its frame group's change
            self.splat_frames = nn.Linear(cfg.token_dim, C * p * p)  # random weight: equal copies add nothing,
            nn.init.zeros_(self.splat_frames.bias)  # and the encoder's zero map still gets a gradient
        self.dynamic_path: nn.Sequential | None = None
        if cfg.dynamic_splat:  # dynamic token -> per frame (u, v, log depth factor); -> patch content + opacity
            self.dynamic_path = nn.Sequential(nn.Linear(cfg.token_dim, D), nn.SiLU(), nn.Linear(D, cfg.frames * 3))
            self.dynamic_content = nn.Linear(cfg.token_dim, (C + 1) * cfg.dynamic_splat ** 2)
            nn.init.zeros_(self.dynamic_content.weight)
            nn.init.zeros_(self.dynamic_content.bias)
            self.dynamic_gate = nn.Parameter(torch.zeros(()))
        for layer in (self.final_mod, self.out):
            nn.init.zeros_(layer.weight)
            nn.init.zeros_(layer.bias)

    def dynamic_track(self, z_d: torch.Tensor, w2c_src: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Where each dynamic token's track is (``config.dynamic_splat``): (uv (B, N_d, frames, 2) latent pixels
        (u, v, centres at integers) in the token's encoded camera (k mod V) at the middle frame, depth (B, N_d,
        frames) metres along its z axis: the depth of the world origin there (at least MIN_ANCHOR_DEPTH) times
        exp(f), f in (-MAX_DEPTH_LOG_FACTOR, MAX_DEPTH_LOG_FACTOR)). w2c_src: (B, 4, 4) or (B, V, 4, 4)."""
        if self.dynamic_path is None:
            raise RuntimeError("dynamic_track needs config.dynamic_splat")
        cfg = self.cfg
        if w2c_src.ndim == 3:
            w2c_src = w2c_src[:, None]
        B, n_d = z_d.shape[:2]
        out = self.dynamic_path(z_d.to(self.dynamic_content.weight.dtype)).float().view(B, n_d, cfg.frames, 3)
        h = cfg.latent_size
        uv = (h - 1) / 2 + (h / 2) * out[..., :2]
        cam = dynamic_token_cameras(n_d, w2c_src.shape[1], z_d.device)
        reference = w2c_src[:, cam, 2, 3].float().clamp_min(MIN_ANCHOR_DEPTH)  # (B, N_d)
        return uv, reference[..., None] * torch.exp(MAX_DEPTH_LOG_FACTOR * torch.tanh(out[..., 2]))

    def dynamic_placement(self, z_d: torch.Tensor, K_tgt: torch.Tensor, w2c_tgt: torch.Tensor, K_src: torch.Tensor,
                          w2c_src: torch.Tensor, keep: torch.Tensor | None
                          ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Where the dynamic splat puts latent pixel q of dynamic token k in target frame t, as
        :meth:`pixel_placement` does for the anchored tokens: (ey (B, T, N_d, q, h), ex (B, T, N_d, q, w),
        f (B, T, N_d, q), off_axis (B, T, N_d)), q = dynamic_splat^2 row-major; f is 0 behind the camera or for
        a dropped token (``keep`` (B, N_s + N_d)), else exp(-view term) relative among the dynamic tokens of
        that frame (``config.view_gate_deg``); off_axis is 1 - cos a, a the angle at the patch centre between
        the rays from the token's encoded camera and from target frame t's camera (``config.view_gate_deg``,
        ``config.dynamic_gate_deg``). Cameras as :meth:`projected_logit`."""
        cfg = self.cfg
        if K_src.ndim == 3:
            K_src, w2c_src = K_src[:, None], w2c_src[:, None]
        n_d, T, ds = z_d.shape[1], K_tgt.shape[1], cfg.ae_downsample
        uv, depth = self.dynamic_track(z_d, w2c_src)
        uv, depth = uv[:, :, :T].to(GEOMETRY_DTYPE), depth[:, :, :T].to(GEOMETRY_DTYPE)
        offsets = dynamic_patch_offsets(cfg.dynamic_splat, uv)  # (q, 2) latent px, row-major
        pix = (uv[:, :, :, None] + offsets + 0.5) * ds - 0.5  # (B, N_d, T, q, 2) image px
        pix = torch.cat([pix, torch.ones_like(pix[..., :1])], dim=-1)
        cam = dynamic_token_cameras(n_d, K_src.shape[1], z_d.device)
        K_tok, w2c_tok = K_src[:, cam].to(GEOMETRY_DTYPE), w2c_src[:, cam].to(GEOMETRY_DTYPE)  # (B, N_d, 3, 3), (4, 4)
        rays = torch.einsum("bnij,bntqj->bntqi", torch.linalg.inv(K_tok), pix)  # z = 1
        R, t = w2c_tok[..., :3, :3], w2c_tok[..., :3, 3]
        x_world = torch.einsum("bnji,bntqj->bntqi", R, rays * depth[..., None, None] - t[:, :, None, None])
        Rt, tt = w2c_tgt[..., :3, :3].to(GEOMETRY_DTYPE), w2c_tgt[..., :3, 3].to(GEOMETRY_DTYPE)
        x_tgt = torch.einsum("btij,bntqj->btnqi", Rt, x_world) + tt[:, :, None, None]  # (B, T, N_d, q, 3)
        proj = torch.einsum("btij,btnqj->btnqi", K_tgt.to(GEOMETRY_DTYPE), x_tgt)
        z = proj[..., 2]
        at = (proj[..., :2] / z.clamp_min(1e-3)[..., None] + 0.5) / ds
        centres = torch.arange(cfg.latent_size, dtype=at.dtype, device=at.device) + 0.5
        scale = 2.0 * cfg.locality_sigma ** 2
        ex = _exp((-(centres - at[..., 0:1]) ** 2 / scale).float())
        ey = _exp((-(centres - at[..., 1:2]) ** 2 / scale).float())
        f = (z > 1e-3).to(ex.dtype)
        point = x_world.mean(3)  # (B, N_d, T, 3) the patch centre
        origin = -torch.einsum("bnji,bnj->bni", R, t)  # (B, N_d, 3) encoded camera centres
        target = -torch.einsum("btji,btj->bti", Rt, tt)  # (B, T, 3)
        from_source = F.normalize(point - origin[:, :, None], dim=-1).transpose(1, 2)  # (B, T, N_d, 3)
        from_target = F.normalize(point.transpose(1, 2) - target[:, :, None], dim=-1)
        off_axis = 1.0 - (from_source * from_target).sum(-1)  # (B, T, N_d)
        if cfg.view_gate_deg > 0:
            term = off_axis / math.radians(cfg.view_gate_deg) ** 2
            f = f * _exp((-(term - term.amin(-1, keepdim=True))).float())[..., None]
        if keep is not None:
            f = f * keep[:, None, keep.shape[1] - n_d:, None].to(f.dtype)
        return ey, ex, f, off_axis

    def dynamic_opacity_scale(self) -> torch.Tensor:
        """The dynamic splat's opacity gate, () float: ``DYNAMIC_GATE_SCALE`` x the parameter, clamped to
        [0, 1] so every alpha is a convex blend weight. The clamp is straight-through: its gradient is the
        unclamped one, so a gate that a step pushed past a bound can come back (a plain clamp would freeze
        it there), and values inside [0, 1] are unchanged (warm starts keep their renders)."""
        raw = DYNAMIC_GATE_SCALE * self.dynamic_gate.float()
        return raw + (raw.clamp(0.0, 1.0) - raw).detach()

    def composite_dynamic(self, splat: torch.Tensor, z_d: torch.Tensor,
                          placement: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor],
                          views: int = 1) -> torch.Tensor:
        """The static splat (B, T, P, C p p) with the dynamic tokens' patches composited over it
        (placement from :meth:`dynamic_placement`): S (1 - A) + sum w alpha c / (sum w + SPLAT_FLOOR) per latent
        pixel, A = sum w alpha / (sum w + SPLAT_FLOOR), alpha = gate sigmoid(o) per patch pixel (gate from
        :meth:`dynamic_opacity_scale`), times 1 - exp(-a^2 / 2 s^2) per target frame with
        ``config.dynamic_gate_deg`` s (a from the placement's off_axis), that gate scaled per encoded camera
        (of ``views``) by :meth:`copy_resolution` with ``config.dynamic_gate_copies``. Same shape."""
        cfg = self.cfg
        ey, ex, f, off_axis = placement
        B, T, n_d, q, h = ey.shape
        w, C, p = ex.shape[-1], cfg.latent_channels, cfg.renderer_patch
        content = self.dynamic_content(z_d.to(self.dynamic_content.weight.dtype)).float().view(B, n_d, C + 1, q)
        alpha = self.dynamic_opacity_scale() * torch.sigmoid(content[:, :, C])  # (B, N_d, q), in [0, 1]
        colour = content[:, :, :C].transpose(2, 3)[:, None]  # (B, 1, N_d, q, C)
        alpha = alpha[:, None]  # (B, 1, N_d, q): the same in every target frame
        if cfg.dynamic_gate_deg > 0:  # (B, T, N_d, q): along its own camera's ray the frame copies take over
            gate = self._gate_from(off_axis, cfg.dynamic_gate_deg)
            if cfg.dynamic_gate_copies:  # ... where they resolve time
                gate = gate * self.copy_resolution(views)[dynamic_token_cameras(n_d, views, gate.device)]
            alpha = alpha * (1.0 - gate)[..., None]
        frames = alpha.shape[1]
        values = torch.cat([colour * alpha[..., None], alpha[..., None], torch.ones_like(alpha[..., None])],
                           dim=-1).reshape(B, frames, n_d * q, C + 2)
        rows = (f[..., None] * ey).reshape(B, T, n_d * q, h)
        acc = _splat_sum(rows, values, ex.reshape(B, T, n_d * q, w))  # (B, T, C + 2, h, w)
        norm = acc[:, :, C + 1:] + SPLAT_FLOOR
        static = unpatchify(splat.float(), p, C, h, w)
        out = static * (1.0 - acc[:, :, C:C + 1] / norm) + acc[:, :, :C] / norm
        return patchify(out, p).to(splat.dtype)

    def embed_tokens(self, z_s: torch.Tensor, z_d: torch.Tensor, drop_static: bool | torch.Tensor,
                     drop_dynamic: bool | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """[Z_s; Z_d] (B, N_s+N_d, d) -> (B, N_s+N_d, D) and their key validity (None = all kept).

        A drop flag is a bool for the whole batch or a (B,) bool tensor, one per item."""
        B, n_s, n_d = z_s.shape[0], z_s.shape[1], z_d.shape[1]
        tokens = self.token_in(torch.cat([z_s, z_d], dim=1).to(self.token_in.weight.dtype)) + self.token_slot[None]
        types = torch.zeros(n_s + n_d, dtype=torch.long, device=z_s.device)
        if not self.cfg.unified_tokens:
            types[n_s:] = 1
        tokens = tokens + self.token_type[types][None]
        if not any(isinstance(flag, torch.Tensor) or flag for flag in (drop_static, drop_dynamic)):
            return tokens, None
        drops = [torch.as_tensor(flag, dtype=torch.bool, device=z_s.device).expand(B)
                 for flag in (drop_static, drop_dynamic)]
        keep = torch.ones(B, n_s + n_d, dtype=torch.bool, device=z_s.device)
        keep[:, :n_s] &= ~drops[0][:, None]
        keep[:, n_s:] &= ~drops[1][:, None]
        return tokens, keep

    def token_cameras(self, views: int) -> torch.Tensor:
        """(N_anchored,) index of the encoded camera each anchored token sits in: with
        ``config.anchor_views`` :func:`layers.token_cameras` (i mod V, spread with ``config.spread_views``),
        else 0 (every token in the first camera)."""
        device = self.anchor_cells.device
        if not self.cfg.anchor_views:
            return torch.zeros(self.n_anchored, dtype=torch.long, device=device)
        return token_cameras(self.n_anchored, views, self.cfg.patches_per_side ** 2, self.cfg.spread_views, device)

    def copy_frames(self, views: int) -> torch.Tensor:
        """(N_anchored, frames) float: 1 where anchored token n is a frame copy (``config.frame_copies``)
        covering clip frame t, else 0. Tokens with the same encoded camera (:meth:`token_cameras`) and
        cell (n mod P) are copies in index order; copy r >= 1 of n covers the frames t with
        floor(t (n - 1) / frames) = r - 1, copy 0 (the time average) none. All zero without frame_copies.
        With ``config.copy_blend`` copy r's hat weight in frame t instead (0 to 1, summing to 1 over an
        anchor's copies in every frame)."""
        cfg = self.cfg
        frames = cfg.frames
        if not cfg.frame_copies:
            return torch.zeros(self.n_anchored, frames, device=self.anchor_cells.device)
        index, same = self._same_anchor(views)
        rank = (same & (index[None, :] < index[:, None])).sum(1)  # earlier tokens on the same anchor
        groups = same.sum(1) - 1  # n - 1 frame groups per anchor
        t = torch.arange(frames, device=index.device)
        copy = rank[:, None] >= 1
        if cfg.copy_blend:  # hat weights around each group's centre, frames clamped to the first and last centres
            span = frames / groups.clamp_min(1).float()[:, None]  # (Na, 1) frames per group
            centre = (rank[:, None] - 0.5) * span - 0.5
            at = torch.minimum(torch.maximum(t[None, :].float(), 0.5 * span - 0.5), frames - 0.5 * span - 0.5)
            return (copy * (1.0 - (at - centre).abs() / span).clamp_min(0.0)).float()
        group_of_frame = t[None, :] * groups[:, None] // frames  # (Na, frames)
        return (copy & (group_of_frame == rank[:, None] - 1)).float()

    def copy_resolution(self, views: int) -> torch.Tensor:
        """(views,) float in [0, 1]: per encoded camera, the share of its anchored cells whose frame copies
        (:meth:`copy_frames`) split the clip into two or more frame groups (3 or more tokens on the anchor),
        i.e. show what the cell did over time; 0 for a camera without anchored tokens."""
        cams = self.token_cameras(views)
        if not self.cfg.frame_copies:
            return torch.zeros(views, device=cams.device)
        index, same = self._same_anchor(views)
        first = self.copy_origin(views) == index  # one token per anchor
        resolved = (same.sum(1) >= 3) & first
        cells = torch.zeros(views, device=cams.device).index_add_(0, cams, first.float())
        hits = torch.zeros(views, device=cams.device).index_add_(0, cams, resolved.float())
        return hits / cells.clamp_min(1.0)

    def copy_origin(self, views: int) -> torch.Tensor:
        """(N_anchored,) index of the time-average copy (the first token) of each anchored token's anchor
        (same encoded camera and cell; :meth:`copy_frames`): the token itself for a time-average copy."""
        return self._same_anchor(views)[1].int().argmax(1)  # the first token with the same anchor

    def _same_anchor(self, views: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(index (N_anchored,), same (N_anchored, N_anchored) bool): whether two anchored tokens share an
        anchor, the same encoded camera (:meth:`token_cameras`) and cell (index mod P)."""
        P = self.cfg.patches_per_side ** 2
        index = torch.arange(self.n_anchored, device=self.anchor_cells.device)
        key = self.token_cameras(views) * P + index % P
        return index, key[:, None] == key[None, :]

    def frame_difference(self, z_s: torch.Tensor, views: int) -> torch.Tensor:
        """(B, N_anchored, d): each anchored static token minus its anchor's time-average copy (held fixed:
        the frame term trains the copies, not the time average), the input of the frame splat."""
        z = z_s[:, :self.n_anchored]
        return z - z[:, self.copy_origin(views)].detach()

    def anchor_depths(self, z_s: torch.Tensor, z_d: torch.Tensor, w2c_src: torch.Tensor) -> torch.Tensor:
        """Depth (B, N_anchored) in metres of each anchored token along its source cell's ray: the depth of
        the world origin in the token's source camera (w2c_src (B, 4, 4), or (B, N_anchored, 4, 4) one per
        token; at least MIN_ANCHOR_DEPTH) times exp(f(token)), f bounded to (-MAX_DEPTH_LOG_FACTOR,
        MAX_DEPTH_LOG_FACTOR)."""
        if self.depth_head is None:
            raise RuntimeError("anchor_depths needs config.project_anchors")
        tokens = torch.cat([z_s, z_d], dim=1)[:, :self.n_anchored].to(self.depth_head.weight.dtype)
        log_factor = MAX_DEPTH_LOG_FACTOR * torch.tanh(self.depth_head(tokens)[..., 0].float())
        reference = w2c_src[..., 2, 3].float().clamp_min(MIN_ANCHOR_DEPTH)
        if reference.ndim == 1:
            reference = reference[:, None]
        return reference * torch.exp(log_factor)

    def projected_bias(self, z_s: torch.Tensor, z_d: torch.Tensor, K_tgt: torch.Tensor, w2c_tgt: torch.Tensor,
                       K_src: torch.Tensor, w2c_src: torch.Tensor) -> torch.Tensor:
        """The geometric locality bias (B, heads, T P, N) of ``config.project_anchors`` (arguments as
        :meth:`projected_logit`): its Gaussian logits on the locality heads, zero elsewhere."""
        return self._bias_from_logit(self.projected_logit(z_s, z_d, K_tgt, w2c_tgt, K_src, w2c_src))

    def _bias_from_logit(self, logit: torch.Tensor) -> torch.Tensor:
        cfg = self.cfg
        B, T, P, _ = logit.shape
        bias = logit.new_zeros(B, cfg.heads, T * P, cfg.n_static + cfg.n_dynamic)
        bias[:, :locality_heads(cfg.heads), :, :self.n_anchored] = logit.reshape(B, 1, T * P, self.n_anchored)
        return bias

    def anchor_points(self, z_s: torch.Tensor, z_d: torch.Tensor, K_src: torch.Tensor, w2c_src: torch.Tensor,
                      offsets: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """World positions (B, N_anchored, 3) of the anchored tokens (each on its cell's ray of its encoded
        camera at :meth:`anchor_depths`) and the centres (B, N_anchored, 3) of those cameras, metres.
        K_src, w2c_src as :meth:`projected_logit`. With ``offsets`` (q, 2) (u, v image pixels from the cell
        centre) the positions are (B, N_anchored, q, 3): those pixels' rays at the token's depth."""
        cfg = self.cfg
        if K_src.ndim == 3:
            K_src, w2c_src = K_src[:, None], w2c_src[:, None]
        B = K_src.shape[0]
        cam = self.token_cameras(K_src.shape[1])
        K_tok, w2c_tok = K_src[:, cam].to(GEOMETRY_DTYPE), w2c_src[:, cam].to(GEOMETRY_DTYPE)  # (B, Na, 3, 3), (4, 4)
        cell_px = cfg.image_size / cfg.patches_per_side  # image pixels per encoder patch
        # anchor centres in pixel coordinates (u = col, v = row; pixel centres at integers), q per token
        uv = (self.anchor_cells.flip(-1).to(GEOMETRY_DTYPE) * cell_px - 0.5)[:, None]  # (Na, 1, 2)
        if offsets is not None:
            uv = uv + offsets.to(uv)[None]  # (Na, q, 2)
        pix = torch.cat([uv, torch.ones_like(uv[..., :1])], dim=-1)  # (Na, q, 3)
        depth = self.anchor_depths(z_s, z_d, w2c_tok).to(GEOMETRY_DTYPE)  # (B, Na)
        rays = torch.linalg.solve(K_tok[:, :, None], pix.expand(B, -1, -1, -1)[..., None])[..., 0]  # z = 1
        x_cam = rays * depth[..., None, None]  # (B, Na, q, 3)
        R, t = w2c_tok[..., :3, :3], w2c_tok[..., :3, 3]
        x_world = torch.einsum("bnji,bnqj->bnqi", R, x_cam - t[:, :, None])  # R^T (x - t)
        return x_world if offsets is not None else x_world[:, :, 0], -torch.einsum("bnji,bnj->bni", R, t)

    def pixel_offsets(self) -> torch.Tensor:
        """(p p, 2) (u, v) image-pixel offsets of a render patch's latent pixels from its centre, row-major
        (the order of :func:`layers.patchify`)."""
        p, f = self.cfg.renderer_patch, self.cfg.ae_downsample
        step = (torch.arange(p, dtype=torch.float32, device=self.anchor_cells.device) - (p - 1) / 2) * f
        rows, cols = torch.meshgrid(step, step, indexing="ij")
        return torch.stack([cols, rows], dim=-1).reshape(-1, 2)

    def pixel_placement(self, z_s: torch.Tensor, z_d: torch.Tensor, K_tgt: torch.Tensor, w2c_tgt: torch.Tensor,
                        K_src: torch.Tensor, w2c_src: torch.Tensor,
                        view_term: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Where ``config.pixel_splat`` puts latent pixel q of anchored token n (:meth:`pixel_offsets`) in
        target frame t, as the separable factors of its Gaussian weight over the h x w latent grid, sigma
        ``locality_sigma`` latent pixels: (ey (B, T, Na, q, h), ex (B, T, Na, q, w), f (B, T, Na, q)),
        weight(y, x) = f ey[y] ex[x]; f is 0 behind the camera and exp(-``view_term``) (B, T, Na), the view
        gate's logit penalty, elsewhere. Cameras as :meth:`projected_logit`."""
        cfg = self.cfg
        x_world, _ = self.anchor_points(z_s, z_d, K_src, w2c_src, self.pixel_offsets())  # (B, Na, q, 3)
        Rt, tt = w2c_tgt[..., :3, :3].to(GEOMETRY_DTYPE), w2c_tgt[..., :3, 3].to(GEOMETRY_DTYPE)
        x_tgt = torch.einsum("btij,bnqj->btnqi", Rt, x_world) + tt[:, :, None, None]  # (B, T, Na, q, 3)
        proj = torch.einsum("btij,btnqj->btnqi", K_tgt.to(GEOMETRY_DTYPE), x_tgt)
        z = proj[..., 2]
        at = (proj[..., :2] / z.clamp_min(1e-3)[..., None] + 0.5) / cfg.ae_downsample  # latent px (x, y)
        centres = torch.arange(cfg.latent_size, dtype=at.dtype, device=at.device) + 0.5
        scale = 2.0 * cfg.locality_sigma ** 2
        ex = _exp((-(centres - at[..., 0:1]) ** 2 / scale).float())
        ey = _exp((-(centres - at[..., 1:2]) ** 2 / scale).float())
        f = (z > 1e-3).to(ex.dtype)
        if view_term is not None:
            f = f * _exp(-view_term.float())[..., None]
        return ey, ex, f

    def splat_pixels(self, z_s: torch.Tensor, z_d: torch.Tensor,
                     placement: tuple[torch.Tensor, torch.Tensor, torch.Tensor], keep: torch.Tensor | None,
                     views: int = 1, gate: torch.Tensor | None = None,
                     share: torch.Tensor | None = None) -> torch.Tensor:
        """:meth:`splat_latent` at latent-pixel precision (placement from :meth:`pixel_placement`): each latent
        pixel gets the weighted sum of the tokens' pixel contents, weights normalised over all tokens' pixels
        plus SPLAT_FLOOR, then scaled by ``share`` (B, T, N_anchored) if given; returns (B, T, P, C p p) like
        :meth:`splat_latent`."""
        assert self.splat is not None
        cfg = self.cfg
        ey, ex, f = placement
        B, T, Na, q, h = ey.shape
        p, C = cfg.renderer_patch, cfg.latent_channels
        tokens = torch.cat([z_s, z_d], dim=1)[:, :self.n_anchored].to(self.splat.weight.dtype)
        if keep is not None:
            f = f * keep[:, None, :self.n_anchored, None].to(f.dtype)
        rows = (f[..., None] * ey).reshape(B, T, Na * q, h)
        cols = ex.reshape(B, T, Na * q, -1)

        def splat(linear: nn.Linear, x: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:  # (B, T, C, h, w)
            content = linear(x).float().reshape(B, Na, C, q).transpose(2, 3).reshape(B, 1, Na * q, C)
            return _splat_sum(rows, content, cols)

        def total(rows: torch.Tensor) -> torch.Tensor:  # (B, T, 1, h, w): sum of weights + floor
            return (rows.transpose(2, 3) @ cols)[:, :, None] + SPLAT_FLOOR

        def per_pixel(x: torch.Tensor) -> torch.Tensor:  # (B | 1, T, Na) per token -> (B | 1, T, Na q, 1)
            return x.to(rows.dtype).repeat_interleave(q, dim=2)[..., None]

        def shared(r: torch.Tensor) -> torch.Tensor:
            return r if share is None else r * per_pixel(share)

        out = splat(self.splat, tokens, shared(rows)) / total(rows)
        if self.splat_frames is not None:
            rows = rows * per_pixel(self.copy_frames(views)[:, :T].T[None])  # the copies covering frame t
            norm = total(rows)
            if gate is not None:
                rows = rows * per_pixel(gate)
            change = self.frame_difference(z_s, views).to(self.splat_frames.weight.dtype)
            out = out + splat(self.splat_frames, change, shared(rows)) / norm
        return patchify(out, p)

    def frame_gate(self, z_s: torch.Tensor, z_d: torch.Tensor, K_tgt: torch.Tensor, w2c_tgt: torch.Tensor,
                   K_src: torch.Tensor, w2c_src: torch.Tensor) -> torch.Tensor:
        """(B, T, N_anchored) in (0, 1]: exp(-a^2 / 2 s^2) with a^2 = 2 (1 - cos), a the angle at anchored token n between the rays
        from its encoded camera and from target frame t's camera, s = ``config.frame_gate_deg``. A frame
        copy holds what its cell did as seen along the source trajectory; the gate keeps it where the
        target sees the token from (nearly) the same direction. Arguments as :meth:`projected_logit`."""
        off_axis = self._off_axis(*self.anchor_points(z_s, z_d, K_src, w2c_src), w2c_tgt)
        return self._gate_from(off_axis, self.cfg.frame_gate_deg)

    @staticmethod
    def _gate_from(off_axis: torch.Tensor, degrees: float) -> torch.Tensor:
        """exp(-a^2 / 2 s^2) from :meth:`_off_axis` (1 - cos a = a^2 / 2), s ``degrees``: :meth:`frame_gate`
        with ``config.frame_gate_deg``, the patch splat's share with ``config.patch_gate_deg``."""
        return _exp((-off_axis / math.radians(degrees) ** 2).float())

    @staticmethod
    def _off_axis(x_world: torch.Tensor, centre: torch.Tensor, w2c_tgt: torch.Tensor) -> torch.Tensor:
        """(B, T, N_anchored): 1 - cos a, a the angle at each anchor (x_world (B, Na, 3)) between the rays from
        its encoded camera's centre (B, Na, 3) and from target frame t's camera; 2 (1 - cos a) = a^2 + O(a^4)."""
        R, t = w2c_tgt[..., :3, :3].to(x_world.dtype), w2c_tgt[..., :3, 3].to(x_world.dtype)
        target = -torch.einsum("btji,btj->bti", R, t)  # (B, T, 3) target camera centres
        from_source = F.normalize(x_world - centre, dim=-1)  # (B, Na, 3)
        from_target = F.normalize(x_world[:, None] - target[:, :, None], dim=-1)  # (B, T, Na, 3)
        return 1.0 - (from_target * from_source[:, None]).sum(-1)

    def _placed_logit(self, x_world: torch.Tensor, off_axis: torch.Tensor | None, K_tgt: torch.Tensor,
                      w2c_tgt: torch.Tensor) -> torch.Tensor:
        """:meth:`projected_logit` of anchors at x_world (B, N_anchored, 3); ``off_axis`` (:meth:`_off_axis`) is
        needed with ``config.view_gate_deg``: the logit then loses (1 - cos a) / s^2 relative to the anchor seen
        from the most similar direction in that target frame (so one camera's tokens, all seen alike, keep
        their weight against the unanchored tokens)."""
        logit = self._logit_at(x_world, K_tgt, w2c_tgt)
        if self.cfg.view_gate_deg > 0:
            assert off_axis is not None
            logit = (logit - self._view_term(off_axis)[:, :, None]).clamp_min(FAR_LOGIT)
        return logit.float()

    def _view_term(self, off_axis: torch.Tensor) -> torch.Tensor:
        """(B, T, N_anchored) logit penalty of ``config.view_gate_deg`` from :meth:`_off_axis`: (1 - cos a) / s^2
        minus its lowest value in that target frame."""
        term = off_axis / math.radians(self.cfg.view_gate_deg) ** 2
        return term - term.amin(-1, keepdim=True)

    def projected_logit(self, z_s: torch.Tensor, z_d: torch.Tensor, K_tgt: torch.Tensor, w2c_tgt: torch.Tensor,
                        K_src: torch.Tensor, w2c_src: torch.Tensor) -> torch.Tensor:
        """Gaussian logit (B, T, P, N_anchored) of render patch p's distance to anchored token n's projection
        in target frame t (-d^2 / 2 sigma^2, floored at FAR_LOGIT; FAR_LOGIT behind the camera), plus the
        view penalty of ``config.view_gate_deg`` when it is on.

        K_tgt (B, T, 3, 3), w2c_tgt (B, T, 4, 4): the target trajectory, px of the model's image;
        K_src (B, 3, 3), w2c_src (B, 4, 4): the camera whose image grid anchors the tokens, or
        (B, V, 3, 3), (B, V, 4, 4): the V encoded cameras (:meth:`token_cameras` says whose grid
        anchors each token)."""
        x_world, centre = self.anchor_points(z_s, z_d, K_src, w2c_src)
        off_axis = self._off_axis(x_world, centre, w2c_tgt) if self.cfg.view_gate_deg > 0 else None
        return self._placed_logit(x_world, off_axis, K_tgt, w2c_tgt)

    def _logit_at(self, x_world: torch.Tensor, K_tgt: torch.Tensor, w2c_tgt: torch.Tensor) -> torch.Tensor:
        """:meth:`projected_logit` of anchors at world positions x_world (B, N_anchored, 3)."""
        cfg = self.cfg
        cell_px = cfg.image_size / cfg.patches_per_side  # image pixels per encoder patch
        Rt, tt = w2c_tgt[..., :3, :3].to(x_world.dtype), w2c_tgt[..., :3, 3].to(x_world.dtype)
        x_tgt = torch.einsum("btij,bnj->btni", Rt, x_world) + tt[:, :, None]  # (B, T, Na, 3)
        proj = torch.einsum("btij,btnj->btni", K_tgt.to(x_world.dtype), x_tgt)
        z = proj[..., 2]
        in_front = z > 1e-3
        cells = (proj[..., :2] / z.clamp_min(1e-3)[..., None] + 0.5) / cell_px  # (B, T, Na, 2) (col, row)
        d2 = ((self.patch_cells.flip(-1)[None, None, :, None] - cells[:, :, None]) ** 2).sum(-1)  # (B, T, P, Na)
        logit = (-d2 / (2.0 * cfg.locality_sigma ** 2)).clamp_min(FAR_LOGIT)
        return torch.where(in_front[:, :, None], logit, torch.full_like(logit, FAR_LOGIT))

    def splat_latent(self, z_s: torch.Tensor, z_d: torch.Tensor, logit: torch.Tensor,
                     keep: torch.Tensor | None, views: int = 1, gate: torch.Tensor | None = None,
                     share: torch.Tensor | None = None) -> torch.Tensor:
        """The token splat (B, T, P, C p p): each render patch's weighted sum of its anchored tokens'
        linear patch content; weights exp(logit) / (sum over tokens + SPLAT_FLOOR), dropped tokens
        (``keep`` False) weigh nothing. With ``config.frame_copies`` plus, in target frame t, the frame
        copies covering t (:meth:`copy_frames` for ``views`` encoded cameras): the frame map of their
        :meth:`frame_difference`, normalised alike over those copies. ``share`` (B, T, N_anchored) scales each
        token's normalised weight (``config.patch_gate_deg``)."""
        assert self.splat is not None
        tokens = torch.cat([z_s, z_d], dim=1)[:, :self.n_anchored].to(self.splat.weight.dtype)
        g = _exp(logit.float())  # (B, T, P, Na)
        if keep is not None:
            g = g * keep[:, None, None, :self.n_anchored].to(g.dtype)
        weights = g / (g.sum(-1, keepdim=True) + SPLAT_FLOOR)
        if share is not None:
            weights = weights * share[:, :, None].to(weights.dtype)
        splat = torch.einsum("btpn,bnc->btpc", weights.to(tokens.dtype), self.splat(tokens))
        if self.splat_frames is None:
            return splat
        covers = self.copy_frames(views)[:, :logit.shape[1]].T.to(g.dtype)  # (T, Na): copy n covers frame t
        g = g * covers[None, :, None, :]
        weights = g / (g.sum(-1, keepdim=True) + SPLAT_FLOOR)
        if gate is not None:
            weights = weights * gate[:, :, None].to(weights.dtype)
        if share is not None:
            weights = weights * share[:, :, None].to(weights.dtype)
        change = self.splat_frames(self.frame_difference(z_s, views).to(self.splat_frames.weight.dtype))
        return splat + torch.einsum("btpn,bnc->btpc", weights.to(tokens.dtype), change)

    def forward(self, y_tau: torch.Tensor, z_s: torch.Tensor, z_d: torch.Tensor, rays: torch.Tensor,
                tau: torch.Tensor, *, drop_static: bool | torch.Tensor = False,
                drop_dynamic: bool | torch.Tensor = False,
                cameras: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
        """y_tau: (B, T, C, h, w); z_s: (B, N_s, d); z_d: (B, N_d, d); rays: (B, T, 6, h, w) of P_tgt;
        tau: (B,) in [0, 1]; cameras: (K_tgt, w2c_tgt, K_src, w2c_src) as :meth:`projected_bias`,
        required with ``config.project_anchors`` and ignored otherwise. Returns (B, T, C, h, w)."""
        B, T, C, h, w = y_tau.shape
        p = self.cfg.renderer_patch
        x = self.embed(patchify(torch.cat([y_tau, rays.to(y_tau.dtype)], dim=2), p))
        x = x + self.pos_space[None, None] + self.pos_time[None, :T, None]
        cond = self.tau_mlp(timestep_embedding(tau, x.shape[-1]))
        tokens, keep = self.embed_tokens(z_s, z_d, drop_static, drop_dynamic)
        splat = None
        if self.depth_head is not None:
            if cameras is None:
                raise RuntimeError("a renderer with projected anchors needs the target and source cameras")
            K_tgt, w2c_tgt, K_src, w2c_src = cameras
            x_world, centre = self.anchor_points(z_s, z_d, K_src, w2c_src)
            gated = self.cfg.frame_gate_deg > 0 or self.cfg.view_gate_deg > 0 or self.cfg.patch_gate_deg > 0
            off_axis = self._off_axis(x_world, centre, w2c_tgt) if gated else None  # once for both gates
            logit = self._placed_logit(x_world, off_axis, K_tgt, w2c_tgt)
            bias = self._bias_from_logit(logit).to(x.dtype)
            if self.splat is not None:
                views = 1 if K_src.ndim == 3 else K_src.shape[1]
                gate = self._gate_from(off_axis, self.cfg.frame_gate_deg) \
                    if off_axis is not None and self.cfg.frame_gate_deg > 0 else None
                if self.cfg.pixel_splat:
                    view_term = self._view_term(off_axis) if self.cfg.view_gate_deg > 0 else None
                    placement = self.pixel_placement(z_s, z_d, K_tgt, w2c_tgt, K_src, w2c_src, view_term)
                    share = None
                    if self.cfg.patch_gate_deg > 0:  # near its own camera's direction a token keeps the patch splat
                        assert off_axis is not None
                        share = self._gate_from(off_axis, self.cfg.patch_gate_deg)
                    splat = self.splat_pixels(z_s, z_d, placement, keep, views, gate,
                                              None if share is None else 1.0 - share)
                    if share is not None:
                        splat = splat + self.splat_latent(z_s, z_d, logit, keep, views, gate, share)
                    splat = splat.to(x.dtype)  # (B, T, P, C p p)
                else:
                    splat = self.splat_latent(z_s, z_d, logit, keep, views, gate).to(x.dtype)
                if self.dynamic_path is not None:
                    placement = self.dynamic_placement(z_d, K_tgt, w2c_tgt, K_src, w2c_src, keep)
                    splat = self.composite_dynamic(splat, z_d, placement, views)
                x = x + self.splat_in(splat)
        else:
            bias = None if self.token_bias is None else self.token_bias.repeat(1, T, 1)  # rows t P + p
        for block in self.blocks:
            x = block(x, cond, tokens, keep, bias)
        shift, scale = self.final_mod(F.silu(cond)).view(B, 1, 1, 2, -1).unbind(dim=3)
        x = self.out(self.final_norm(x) * (1 + scale) + shift)
        if splat is not None:
            x = x + splat  # the x0 estimate: the splatted tokens plus the network's correction
        return unpatchify(x, p, C, h, w)
