"""The configurations of both models: :class:`ModelConfig` (the VideoTok4D tokenizer, with its ablation
switches) and :class:`PriorConfig` (the Co4DGen prior), their named presets and shared validation.

Both are frozen dataclasses with the same serialization: ``to_dict`` / ``from_dict`` (unknown keys
refused), and ``sha256`` over the canonical JSON (sorted keys, no whitespace), the config hash a
model's fingerprint records.

``get_config("paper")`` follows the paper's setting (32 frames at 256x256, N_s = 1024 static and
N_d = 512 dynamic tokens of width d = 64); ``get_config("tiny")`` is the same architecture at the
size this project's CPUs can train: 8 frames at 64x64, a 16x16x4 latent cut into 4x4 patches (16 grid
tokens per frame: half the training-step time of 2x2 patches on this CPU, same token budget),
N_s = 64, N_d = 32, d = 32,
i.e. 96 x 32 = 3,072 token floats for 8 x 64 x 64 x 3 = 98,304 pixel values (1/32).
``get_prior_config("co4dgen-tiny")`` is the prior for vt4d-tiny's token state; ``"co4dgen-paper"`` the
paper-size one.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

from vt4dcodec.errors import ModelError

__all__ = [
    "ModelConfig", "get_config", "CONFIG_NAMES", "PREDICTIONS", "PriorConfig", "get_prior_config",
    "PRIOR_CONFIG_NAMES", "DenseConfig", "get_dense_config", "DENSE_CONFIG_NAMES",
]

PREDICTIONS = ("velocity", "x0")
_UNSET = object()
_C = TypeVar("_C", bound="_Config")


def _require_positive_ints(config: Any, keys: Any, label: str) -> None:
    """ModelError unless every field in ``keys`` is an int (not a bool) > 0; ``label`` names the config."""
    for key in keys:
        value = getattr(config, key)
        if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
            raise ModelError(f"{label} {key} must be a positive integer, got {value!r}")


def _require_bools(config: Any, keys: Any) -> None:
    """ModelError unless every model-config field in ``keys`` is true or false."""
    for key in keys:
        value = getattr(config, key)
        if not isinstance(value, bool):
            raise ModelError(f"config {key} must be true or false, got {value!r}")


def _require_degrees(config: Any, keys: Any) -> None:
    """ModelError unless every model-config field in ``keys`` is a number (not a bool) of degrees in [0, 180]."""
    for key in keys:
        value = getattr(config, key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= 180.0:
            raise ModelError(f"config {key} must be a number of degrees in [0, 180], got {value!r}")


class _Config:
    """Serialization shared by the frozen config dataclasses below.

    ``_KIND`` names the config in errors ("model", "prior"); ``_LATER_FIELDS`` maps fields added after
    models were shipped to the default that reproduces the earlier behaviour: while a field holds that
    default it is left out of the hashed JSON, so older configs keep their hash.
    """

    _KIND: ClassVar[str]
    _LATER_FIELDS: ClassVar[dict[str, Any]] = {}

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def canonical_json(self) -> str:
        """Sorted keys, no whitespace: the bytes the fingerprint hashes."""
        data = {k: v for k, v in self.to_dict().items() if self._LATER_FIELDS.get(k, _UNSET) != v}
        return json.dumps(data, sort_keys=True, separators=(",", ":"))

    def sha256(self) -> str:
        return hashlib.sha256(self.canonical_json().encode("utf-8")).hexdigest()

    @classmethod
    def from_dict(cls: type[_C], data: Any) -> _C:
        if not isinstance(data, dict):
            raise ModelError(f"a {cls._KIND} config must be a JSON object")
        unknown = sorted(set(data) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise ModelError(f"unknown {cls._KIND} config keys: {unknown}")
        try:
            return cls(**data)
        except TypeError as exc:
            raise ModelError(f"bad {cls._KIND} config: {exc}") from None

    def replace(self: _C, **overrides: Any) -> _C:
        return type(self).from_dict({**self.to_dict(), **overrides})


@dataclass(frozen=True)
class ModelConfig(_Config):
    """Every size and switch of a VideoTok4D model. Frozen; build variants with ``replace``.

    Sizes:
        frames (T), image_size (H = W, pixels), latent_channels (C), ae_downsample (H / h),
        ae_width (channels of the autoencoder's first stage), patch_size (latent pixels per token side),
        render_patch_size (latent pixels per renderer token side; 0 = patch_size: a smaller renderer
        patch gives the renderer more output tokens per frame for detail, the token budget is unchanged),
        width (transformer width D), heads, mlp_ratio.
    Layers:
        spatial_layers (factorized spatial+temporal blocks of the Spatial Branch), static_query_layers,
        dynamic_spatial_layers (mask-restricted spatial attention, Eq. 5), track_layers (Eq. 7 + query
        update), renderer_layers.
    Tokens:
        n_static (N_s), n_dynamic (N_d), token_dim (d), n_tracks (N, tracks fed to the Temporal Branch),
        token_noise (half-width of the uniform noise added to bounded tokens in training, in token units;
        1/254 matches int8 storage with scale 1/127).
    Renderer output:
        prediction: "velocity" -- the network outputs v (paper Eq. 2); "x0" -- it outputs the clean
        target latent X0_hat and v = (Y^tau - X0_hat) / tau. With "x0" a one-step render is the
        network's output itself, and training never has to learn to pass the input noise through.
    Token locality:
        locality_sigma: > 0 anchors the static tokens on the source image grid: static query i (and, in
        the renderer, static token i) gets a learned attention-logit bias initialised to a Gaussian
        of width ``locality_sigma`` encoder patches around anchor cell i mod P on half of the heads
        (the other heads read anywhere). Without it the static queries of vt4d-tiny 0.3.0 attend
        almost uniformly (84 of 128 grid keys effective) and carry only a scene's global colours.
        0 = no bias (earlier models).
        query_from_grid: with locality_sigma > 0, static query i starts from its learned embedding plus
        a linear map (zero at initialisation) of its anchor cell's feature averaged over the frames, so
        the token has a direct path to the content of its cell instead of only the cross-attention
        (vt4d-tiny 0.4.0's anchored tokens explain a third of their cell's latent variance linearly).
        project_anchors: with locality_sigma > 0, the renderer's locality bias follows the scene's
        geometry instead of the source image grid: anchored token i's cell centre is unprojected from
        the source camera (the first encoded camera, middle frame) at a depth the renderer reads from
        the token (the depth of the world origin times a learned factor in [e^-2, e^2], factor 1 at
        initialisation) and projected into every target frame; render patch j's bias is the Gaussian
        of its distance to that projection. At the source camera it equals the grid prior, so a
        model warm-started without it renders its source view unchanged; elsewhere tokens move with
        the target pose (vt4d-tiny 0.5.0's fixed grid bias made renders at other cameras a blurred
        copy of the source view: bench/probes/probe_pose_dependence.py). Rendering then needs the source
        trajectory.
        anchor_views: with project_anchors and V > 1 encoded cameras, anchored token i belongs to
        encoded camera i mod V: its query reads that camera's cell i (the locality bias and the grid
        feature of query_from_grid come from that camera only) and the renderer places it on that
        camera's cell ray. Without it every token is anchored in the first camera while its query
        averages all cameras' cells, so tokens describe camera 0's view with evidence from elsewhere,
        and an encoded camera that sees other parts of the scene is rendered as a novel view
        (vt4d-tiny 0.6.0: 5 encoded cameras 20.6 dB, the same as the 5 held out). With one camera
        both are the same model. Rendering then needs every encoded camera's trajectory.
        token_splat: with project_anchors and x0 prediction, each anchored static token also reaches the
        output directly: a linear map (zero at initialisation, so a warm start renders unchanged) of the
        token to one render patch of latent content, placed where the token projects in each target frame
        (the locality Gaussian's weights) and added to the renderer's estimate of the clean latent, which
        also enters the renderer as an input. A time-averaged cell latent -- what one 32-value token per
        2x2x8 cell can hold -- reconstructs the source view of held-out scenes at 26.0 dB where
        vt4d-tiny 0.7.0's attention-only renderer gives 24.0 (docs/training.md).
        token_from_cell: with project_anchors, each anchored static token's bottleneck pre-activation
        also gets a linear map (zero at initialisation) of its own cell's source latent averaged over the
        frames (C p p values of encoded camera i mod V), a direct path from the content a token should
        hold to the token, next to the query's attention.
        frame_copies: with token_from_cell and token_splat, anchored static tokens that share an anchor
        (the same encoded camera and cell; with one camera and n_static = k P each cell has k of them)
        split the clip's frames instead of repeating each other: copy 0 holds the cell's time-averaged
        content as before, copy r >= 1 of n covers frame group r - 1 of n - 1 equal groups (frame t of
        ``frames`` is in group floor(t (n - 1) / frames)). Copy r's pre-activation also gets a linear
        map (zero at initialisation) of its group's cell latent minus the time average, and the renderer
        splats a second linear map of its difference from copy 0 in the target frames of its group only,
        normalised over the copies landing on a patch in that frame (equal copies add nothing; a warm
        start from a model without it copies the cell and splat maps into the two new ones). Equal copies get equal
        gradients and stay equal (vt4d-tiny 0.9.0's 5 copies per cell, 0.005 apart against 2.26
        between cells); a time-averaged latent caps the source view at 26.0 dB / SSIM 0.76 where 4
        frame-group averages give 29.4 / 0.86 (bench/probes/probe_static_oracle.py).
        copy_blend: with frame_copies, the frame copies of an anchor blend over time instead of splitting it:
        copy r >= 1 of n is a knot at its frame group's centre c_r, and frame t takes the copies on either
        side with linear (hat) weights 1 - |t - c_r| / (frames / (n - 1)), t clamped to the first and last
        centres (weights sum to 1 in every frame, as the groups' did). The encoder's input for a copy is
        the same hat-weighted average of its cell minus the time average. On held-out scenes the frozen
        autoencoder's latent projected onto 4 hat functions reconstructs the source view at 30.44 dB
        against 29.99 for 4 frame-group averages (caliscope cam_0: 28.93 against 28.10;
        bench/probes/probe_temporal_basis.py). Trained from vt4d-tiny 2.1.0 (leg cb1) it renders the source
        view no better than the same steps without it (-0.04 dB; docs/training.md, "Blended frame copies").
        frame_gate_deg: with frame_copies, > 0 weighs each copy's frame splat in target frame t by
        exp(-a^2 / 2 s^2), a the angle at the token between the rays from its encoded camera and from
        the target camera, s this many degrees: a frame copy holds what its cell did as seen along the
        source trajectory, which a camera elsewhere sees differently (vt4d-tiny 0.10.0's frame splat gives
        the source view +2.1 dB and costs the near views 0.1 dB). 0 = no gate.
        spread_views: with anchor_views, when V encoded cameras share a factor g with the P cells and a
        camera has more tokens than the P / g cells i mod V lets it reach (320 tokens, P = 64: V = 2, 4,
        8), token i goes to camera (i + floor(i / P)) mod V instead of i mod V, so each camera's tokens
        cover distinct cells (4 cameras: 64 cells each instead of the same 16, repeated 5 times as frame
        copies); other V (1, 3, 5, 7, 10) are unchanged (layers.token_cameras). Cell i mod P
        and everything learned per token stay as they are, so a model trained without it renders odd V
        exactly as before.
        view_gate_deg: with project_anchors, > 0 lowers each anchored token's locality logit (attention bias
        and splat) in target frame t by (1 - cos a) / s^2 relative to the lowest of that frame, a the angle
        at the token between the rays from its encoded camera and from the target camera, s this many
        degrees: the splat has no depth order, so with several encoded cameras a token holding the far
        side of an object (seen from across the scene) lands on the near side's pixels; the gate lets the
        tokens seen from the target's direction win. Renderer only, no weights. 0 = off.
        pixel_splat: with token_splat, each of a token's p x p latent pixels is placed on its own (the
        sub-pixel's ray at the token's depth, projected into the target frame) with a Gaussian of
        ``locality_sigma`` latent pixels, instead of the whole patch snapping to the render-patch grid:
        a forward warp at latent-pixel precision. At the source camera it renders (nearly) as the patch
        splat, so a warm start keeps its source view; elsewhere the patch splat is off by up to half a
        cell (4 image pixels) and blends the tokens between two patches. Renderer only, no weights.
        patch_gate_deg: with pixel_splat, > 0 sends a share exp(-a^2 / 2 s^2) of each token's splat through
        the patch splat and the rest through the pixel splat, a the angle at the token between the rays
        from its encoded camera and from the target camera, s this many degrees: near its own camera's
        direction a token keeps the patch splat, which snaps small errors of its depth to its own cell
        (trained on the pixel splat alone, vt4d-tiny's source view lost 0.6 dB while its held-out cameras
        gained 0.15). Renderer only, no weights. 0 = off.
        dynamic_splat: with pixel_splat, > 0 gives every dynamic token (Z_d, or the unified ablation's last
        N_d tokens) a place in the scene that moves: dynamic token k belongs to encoded camera k mod V and
        to that camera's (k // V)-th most moving track (:func:`temporal_branch.select_tracks`, which the
        Temporal Branch's query k also reads); the renderer decodes from the token the track's per-frame
        position in its camera at the middle frame (u, v latent pixels and depth, supervised in training by
        the track and the source depth: ``VideoTok4D.track_loss``) and a ``dynamic_splat`` x
        ``dynamic_splat`` patch of latent content with an opacity per latent pixel, forward-warped into each
        target frame like the pixel splat and composited over the static splat (premultiplied, normalised
        per latent pixel). The opacity is scaled by a learned gate that starts at 0, so a warm start
        renders as before. 0 = off.
        dynamic_gate_deg: with dynamic_splat, > 0 scales each dynamic token's opacities in target frame t by
        1 - exp(-a^2 / 2 s^2), a the angle at its patch centre between the rays from its encoded camera and
        from the target camera, s this many degrees: the complement of ``frame_gate_deg``. Along its own
        camera's direction the frame copies show a moving object frame group by frame group, sharper than
        one patch carried along the track for the whole clip (vt4d-tiny-1.1-dyn's source view: 26.87 dB
        with its dynamic patches, 27.04 without Z_d); seen from elsewhere the patch is what moves the
        object. Renderer only, no weights. 0 = off.
        dynamic_gate_copies: with dynamic_gate_deg, the gate of a dynamic token's encoded camera is scaled by
        the share of that camera's cells whose frame copies split the clip (3 or more copies: a time
        average and at least two frame groups; :meth:`Renderer.copy_resolution`), so it leaves the
        camera's own view only to frame copies that show the motion. With one encoded camera (5 copies a
        cell) it is the plain gate; with 5 of 10 cameras encoded (320 tokens: one copy a cell, no frame
        copies) the gate is off and the camera's own dynamic patches draw its moving objects. Renderer
        only, no weights. False = the plain gate for every camera.
        dynamic_from_patch: with dynamic_splat (full model only), each dynamic token's bottleneck
        pre-activation also gets a zero-initialised linear map of the source latent around its track
        (its camera's latent at the track plus the patch offsets, averaged over the track's valid frames:
        ``VideoTok4D.patch_targets``), as token_from_cell gives each static token its cell: what the
        token's patch should show reaches it without the attention having to find it.
        entropy_levels: > 0 gives the model a learned entropy model (``model.entropy``) with that many
        quality levels: per-level quantizer steps, per-channel token densities trained with a rate term,
        frozen into integer rANS tables at ship time. 0: no entropy model (the fixed-point encodings only).
        entropy_context: with entropy_levels, each MEAN static token after the first is coded given the sign
        of the previous MEAN token's code in its channel (two more density classes, MEAN_AFTER_NEGATIVE and
        MEAN_AFTER_POSITIVE; FORMAT.md I.6.2, tables of 5 classes): neighbouring cells' tokens agree, which
        the factorized densities cannot use. False: one MEAN density per channel.
        entropy_partners: with entropy_context, each channel's partner channel (token_dim values, each -1 or an
        earlier channel): a MEAN value is also coded given the sign of its own token's code in the partner
        channel (six more classes, FORMAT.md I.6.2, tables of 11 classes). Channels that move together (one
        pair of channels correlates at 0.9 on q1 codes) cost a fraction once one of them is known. Chosen
        from token statistics (``python -m vt4dcodec.model.train.partner_context``). Empty: no partners.
        entropy_rounding: with entropy_levels, the writer's rounding offsets, 3 per level (coarsest first):
        MEAN, CHANGE and DYNAMIC values are stored as ``sign(x) floor(|x| + f)`` of ``x = token / step``
        (``vt4dcodec.format.learned.writer_codes``): f = 1/2 rounds to nearest, a smaller f is a dead zone
        that stores small values (a frame copy's small change) as 0. An encoder's choice, tuned on held-out
        scenes per level (docs/training.md); decoding does not use it. Empty: round to nearest everywhere.
        feedback_width: > 0 gives the encoder render feedback (:class:`.feedback.RenderFeedback`, MLPs of this
        hidden width): its first tokens are rendered at the encoded cameras as the decoder renders them, and
        each token's pre-activation gets a zero-initialised map of the residual (source latents minus
        rendered) around its cell or along its track. Encoder only: the decoder and the file format do not
        change. 0: no feedback.
        feedback_passes: with feedback_width, how many times the encoder renders its tokens and reads the residual
        back (each pass its own zero-initialised MLPs, so a model given a further pass starts as the model
        without it). 1: one pass.
        feedback_quality: with feedback_width and quality levels, the lowest level whose files store the tokens
        after render feedback; files of coarser levels store the first pass, where the feedback's extra bytes buy
        less than a finer level would (an encoder's choice, measured per level: docs/training.md). Encodings
        without a level store the feedback's tokens. 1: every level.
        feedback_window: with feedback_width, the side in encoder cells (odd) of the window of residual each
            anchored static token reads, centred on its cell. 3: its cell and one cell on each side.
        feedback_gradient: with feedback_width, each pass also reads the gradient of its render's squared latent
            error with respect to every token (the renderer's whole response to the token, where the residual
            window sees only its cell's surroundings): a second zero-initialised MLP per token group maps [Z, the
            gradient scaled to unit RMS per scene] to a further change of pre-activation. One backward pass
            through the renderer at encode time (torch); False: the residual window only.
        reference_frame: the world frame the encoder and renderer work in (vt4dcodec.reference.model_centre;
            the renderer measures token depths from its origin). "origin": the capture's own, unless its origin
            is less than 0.5 m in front of an encoded camera; "cameras": always the frame moved to the encoded
            cameras' reference point (their axes' meeting point, or 4 m ahead), in training and in the codec.
    Ablations (same token budget):
        unified_tokens: one set of N_s + N_d tokens from the Spatial Branch, no Temporal Branch. Every
            token is anchored, unless token_from_cell: then the first N_s are the anchored cell tokens (with
            their frame copies and splats, as in the full model) and the last N_d are free Spatial Branch
            queries in place of the Temporal Branch's Z_d (one bottleneck, one token type): the recipe of
            the full model without disentanglement.
        motion_isolation: False replaces the motion mask with ones.
        track_attention: False attends along fixed grid positions instead of tracks.
    """

    name: str = "tiny"
    frames: int = 8
    image_size: int = 64
    latent_channels: int = 4
    ae_downsample: int = 4
    ae_width: int = 16
    patch_size: int = 4
    width: int = 128
    heads: int = 4
    mlp_ratio: float = 2.0
    spatial_layers: int = 2
    static_query_layers: int = 2
    dynamic_spatial_layers: int = 1
    track_layers: int = 2
    renderer_layers: int = 4
    n_static: int = 64
    n_dynamic: int = 32
    token_dim: int = 32
    n_tracks: int = 64
    token_noise: float = 1.0 / 254.0
    unified_tokens: bool = False
    motion_isolation: bool = True
    track_attention: bool = True
    prediction: str = "velocity"
    render_patch_size: int = 0
    locality_sigma: float = 0.0
    query_from_grid: bool = False
    project_anchors: bool = False
    anchor_views: bool = False
    token_splat: bool = False
    token_from_cell: bool = False
    frame_copies: bool = False
    frame_gate_deg: float = 0.0
    copy_blend: bool = False
    spread_views: bool = False
    view_gate_deg: float = 0.0
    pixel_splat: bool = False
    patch_gate_deg: float = 0.0
    dynamic_splat: int = 0
    dynamic_gate_deg: float = 0.0
    dynamic_gate_copies: bool = False
    dynamic_from_patch: bool = False
    entropy_levels: int = 0
    entropy_context: bool = False
    entropy_rounding: tuple[float, ...] = ()
    entropy_partners: tuple[int, ...] = ()
    feedback_width: int = 0
    feedback_passes: int = 1
    feedback_quality: int = 1
    feedback_window: int = 3
    feedback_gradient: bool = False
    reference_frame: str = "origin"

    _KIND: ClassVar[str] = "model"
    _LATER_FIELDS: ClassVar[dict[str, Any]] = {"prediction": "velocity", "render_patch_size": 0, "locality_sigma": 0.0,
                                               "query_from_grid": False, "project_anchors": False,
                                               "anchor_views": False, "token_splat": False,
                                               "token_from_cell": False, "frame_copies": False,
                                               "frame_gate_deg": 0.0, "copy_blend": False, "spread_views": False,
                                               "view_gate_deg": 0.0, "pixel_splat": False,
                                               "patch_gate_deg": 0.0, "dynamic_splat": 0,
                                               "dynamic_gate_deg": 0.0, "dynamic_gate_copies": False,
                                               "dynamic_from_patch": False, "entropy_levels": 0,
                                               "entropy_context": False, "entropy_rounding": (),
                                               "entropy_partners": (), "feedback_width": 0,
                                               "feedback_passes": 1, "feedback_quality": 1, "feedback_window": 3,
                                               "feedback_gradient": False, "reference_frame": "origin"}

    def __post_init__(self) -> None:
        _require_positive_ints(self, ("frames", "image_size", "latent_channels", "ae_downsample", "ae_width",
                                      "patch_size", "width", "heads", "n_static", "n_dynamic", "token_dim",
                                      "n_tracks", "renderer_layers", "spatial_layers", "static_query_layers",
                                      "track_layers"), "config")
        if self.dynamic_spatial_layers < 0:
            raise ModelError("config dynamic_spatial_layers must be >= 0")
        if self.ae_downsample & (self.ae_downsample - 1):
            raise ModelError(f"ae_downsample must be a power of two, got {self.ae_downsample}")
        if self.image_size % (self.ae_downsample * self.patch_size):
            raise ModelError("image_size must be divisible by ae_downsample * patch_size")
        if isinstance(self.render_patch_size, bool) or not isinstance(self.render_patch_size, int) \
                or self.render_patch_size < 0:
            raise ModelError(f"config render_patch_size must be an integer >= 0, got {self.render_patch_size!r}")
        if self.image_size % (self.ae_downsample * self.renderer_patch):
            raise ModelError("image_size must be divisible by ae_downsample * render_patch_size")
        if self.width % self.heads:
            raise ModelError(f"width {self.width} is not divisible by heads {self.heads}")
        if self.prediction not in PREDICTIONS:
            raise ModelError(f"config prediction must be one of {PREDICTIONS}, got {self.prediction!r}")
        if isinstance(self.locality_sigma, bool) or not isinstance(self.locality_sigma, (int, float)) \
                or not 0.0 <= self.locality_sigma < 1e6:
            raise ModelError(f"config locality_sigma must be a number >= 0, got {self.locality_sigma!r}")
        _require_bools(self, ("query_from_grid", "project_anchors", "anchor_views", "token_splat", "token_from_cell",
                              "frame_copies", "copy_blend", "spread_views", "pixel_splat", "dynamic_gate_copies",
                              "dynamic_from_patch", "feedback_gradient"))
        _require_degrees(self, ("frame_gate_deg", "view_gate_deg", "patch_gate_deg", "dynamic_gate_deg"))
        if self.query_from_grid and not self.locality_sigma > 0:
            raise ModelError("config query_from_grid needs locality_sigma > 0 (it reads each query's anchor cell)")
        if self.project_anchors and not self.locality_sigma > 0:
            raise ModelError("config project_anchors needs locality_sigma > 0 (it moves the locality prior)")
        if self.anchor_views and not self.project_anchors:
            raise ModelError("config anchor_views needs project_anchors (it places tokens in their own camera)")
        if self.token_splat and not (self.project_anchors and self.prediction == "x0"):
            raise ModelError("config token_splat needs project_anchors and prediction x0 (it adds the tokens "
                             "where they project to the renderer's clean-latent estimate)")
        if self.token_from_cell and not self.project_anchors:
            raise ModelError("config token_from_cell needs project_anchors (it reads each anchored static token's "
                             "own cell)")
        if self.frame_copies and not (self.token_from_cell and self.token_splat):
            raise ModelError("config frame_copies needs token_from_cell and token_splat (it feeds each copy its "
                             "frame group's cell and splats it in those frames)")
        if self.copy_blend and not self.frame_copies:
            raise ModelError("config copy_blend needs frame_copies (it blends the frame copies over time)")
        if self.frame_gate_deg > 0 and not self.frame_copies:
            raise ModelError("config frame_gate_deg needs frame_copies (it weighs the frame copies' splat)")
        if self.spread_views and not self.anchor_views:
            raise ModelError("config spread_views needs anchor_views (it says which encoded camera holds each token)")
        if self.view_gate_deg > 0 and not self.project_anchors:
            raise ModelError("config view_gate_deg needs project_anchors (it weighs the anchors by where they are seen from)")
        if self.pixel_splat and not self.token_splat:
            raise ModelError("config pixel_splat needs token_splat (it places the splatted tokens' latent pixels)")
        if self.patch_gate_deg > 0 and not self.pixel_splat:
            raise ModelError("config patch_gate_deg needs pixel_splat (it shares each token between the two splats)")
        if isinstance(self.dynamic_splat, bool) or not isinstance(self.dynamic_splat, int) \
                or not 0 <= self.dynamic_splat <= self.image_size // self.ae_downsample:
            raise ModelError(f"config dynamic_splat must be an integer from 0 to the latent size, got {self.dynamic_splat!r}")
        if self.dynamic_splat > 0 and not self.pixel_splat:
            raise ModelError("config dynamic_splat needs pixel_splat (it warps the dynamic tokens' patches alike)")
        if self.dynamic_gate_copies and not self.dynamic_gate_deg > 0:
            raise ModelError("config dynamic_gate_copies needs dynamic_gate_deg > 0 (it scales that gate per camera)")
        if self.dynamic_gate_deg > 0 and not self.dynamic_splat:
            raise ModelError("config dynamic_gate_deg needs dynamic_splat > 0 (it scales the dynamic patches' opacity)")
        if self.dynamic_from_patch and not (self.dynamic_splat > 0 and not self.unified_tokens):
            raise ModelError("config dynamic_from_patch needs dynamic_splat > 0 and the full model (it reads each "
                             "dynamic token's track, which unified_tokens has not)")
        if isinstance(self.entropy_levels, bool) or not isinstance(self.entropy_levels, int) \
                or not 0 <= self.entropy_levels <= 16:
            raise ModelError(f"config entropy_levels must be an integer from 0 to 16, got {self.entropy_levels!r}")
        if not isinstance(self.entropy_context, bool) or (self.entropy_context and not self.entropy_levels):
            raise ModelError(f"config entropy_context must be a boolean, and true only with entropy_levels > 0, "
                             f"got {self.entropy_context!r}")
        rounding = self.entropy_rounding
        if not isinstance(rounding, (list, tuple)) or len(rounding) not in {0, 3 * self.entropy_levels} or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 <= v <= 0.5 for v in rounding):
            raise ModelError(f"config entropy_rounding must be empty or 3 x entropy_levels ({3 * self.entropy_levels}) "
                             f"numbers within [0, 0.5], got {rounding!r}")
        object.__setattr__(self, "entropy_rounding", tuple(float(v) for v in rounding))
        partners = self.entropy_partners
        if not isinstance(partners, (list, tuple)) or (partners and (
                not self.entropy_context or len(partners) != self.token_dim
                or not all(isinstance(v, int) and not isinstance(v, bool) and -1 <= v < c
                           for c, v in enumerate(partners)))):
            raise ModelError(f"config entropy_partners must be empty or, with entropy_context, token_dim "
                             f"({self.token_dim}) channels each -1 or below its own index, got {partners!r}")
        object.__setattr__(self, "entropy_partners", tuple(int(v) for v in partners))
        if isinstance(self.feedback_width, bool) or not isinstance(self.feedback_width, int) or self.feedback_width < 0:
            raise ModelError(f"config feedback_width must be an integer >= 0, got {self.feedback_width!r}")
        if self.feedback_width and not (self.token_from_cell and self.dynamic_splat > 0 and not self.unified_tokens):
            raise ModelError("config feedback_width needs token_from_cell, dynamic_splat > 0 and the full model (the "
                             "render residual reaches static tokens through their cells, dynamic ones along their tracks)")
        if isinstance(self.feedback_passes, bool) or not isinstance(self.feedback_passes, int) \
                or not 1 <= self.feedback_passes <= 4:
            raise ModelError(f"config feedback_passes must be an integer 1 .. 4, got {self.feedback_passes!r}")
        if self.feedback_passes > 1 and not self.feedback_width:
            raise ModelError("config feedback_passes > 1 needs feedback_width > 0 (the passes are render feedback)")
        if isinstance(self.feedback_quality, bool) or not isinstance(self.feedback_quality, int) \
                or not 1 <= self.feedback_quality <= max(1, self.entropy_levels):
            raise ModelError(f"config feedback_quality must be a quality level 1 .. {max(1, self.entropy_levels)}, "
                             f"got {self.feedback_quality!r}")
        if isinstance(self.feedback_window, bool) or not isinstance(self.feedback_window, int) \
                or not 1 <= self.feedback_window <= 15 or self.feedback_window % 2 == 0:
            raise ModelError(f"config feedback_window must be an odd integer 1 .. 15, got {self.feedback_window!r}")
        if self.reference_frame not in ("origin", "cameras"):
            raise ModelError(f"config reference_frame must be 'origin' or 'cameras', got {self.reference_frame!r}")
        if self.feedback_window != 3 and not self.feedback_width:
            raise ModelError("config feedback_window other than 3 needs feedback_width > 0 (it is the feedback's window)")
        if self.feedback_gradient and not self.feedback_width:
            raise ModelError("config feedback_gradient needs feedback_width > 0 (the gradient is read by render feedback)")
        if self.feedback_quality > 1 and not self.feedback_width:
            raise ModelError("config feedback_quality > 1 needs feedback_width > 0 (it says where the feedback is used)")
        if not (self.mlp_ratio > 0 and 0.0 <= self.token_noise < 1.0):
            raise ModelError("mlp_ratio must be > 0 and token_noise in [0, 1)")

    # derived sizes ---------------------------------------------------------------------------------
    @property
    def latent_size(self) -> int:
        """h = w, the latent map side in latent pixels."""
        return self.image_size // self.ae_downsample

    @property
    def patches_per_side(self) -> int:
        return self.latent_size // self.patch_size

    @property
    def renderer_patch(self) -> int:
        """Latent pixels per renderer token side (render_patch_size, or patch_size when it is 0)."""
        return self.render_patch_size or self.patch_size

    @property
    def renderer_patches_per_side(self) -> int:
        return self.latent_size // self.renderer_patch

    @property
    def static_shape(self) -> tuple[int, int]:
        return (self.n_static, self.token_dim)

    @property
    def dynamic_shape(self) -> tuple[int, int]:
        return (self.n_dynamic, self.token_dim)

    @property
    def n_anchored(self) -> int:
        """Tokens anchored on the encoder grid when locality_sigma > 0: the N_s static tokens; with
        unified_tokens all N_s + N_d, unless token_from_cell keeps the last N_d free."""
        if self.unified_tokens and not self.token_from_cell:
            return self.n_static + self.n_dynamic
        return self.n_static

    @property
    def token_floats(self) -> int:
        return (self.n_static + self.n_dynamic) * self.token_dim

    def networks(self) -> "ModelConfig":
        """This config with every entropy-model field (``entropy_*``) and the level the feedback starts at
        (``feedback_quality``, a choice among levels) at their defaults: the config of the networks alone, as they
        were before an entropy model was added to them (:func:`~.identity.network_digests`)."""
        defaults = {f.name: (f.default if f.default is not dataclasses.MISSING else f.default_factory())  # type: ignore[misc]
                    for f in dataclasses.fields(self) if f.name.startswith("entropy_") or f.name == "feedback_quality"}
        return dataclasses.replace(self, **defaults)

    def without_feedback(self) -> "ModelConfig":
        """This config with render feedback off (every ``feedback_*`` field at its default): the config of the
        encoder's first pass."""
        return dataclasses.replace(self, feedback_width=0, feedback_passes=1, feedback_quality=1, feedback_window=3,
                                   feedback_gradient=False)

    def feeds_back(self, quality: int | None) -> bool:
        """Whether a file of quality level ``quality`` (None: an encoding without levels) stores the tokens after
        render feedback (``feedback_quality``), rather than the first pass."""
        return bool(self.feedback_width) and (quality is None or quality >= self.feedback_quality)

    def update_bases_sha256s(self) -> tuple[str, ...]:
        """Config hashes of the earlier models an update of this config may read (``train.ship --reads``): itself
        with fewer render feedback passes or without the render's gradient, and without render feedback (each an
        encoder whose first pass, token quantizer and entropy tables this config keeps)."""
        hashes = [self.without_feedback().sha256()]
        if self.feedback_width:
            for passes in range(1, self.feedback_passes + 1):
                for gradient in dict.fromkeys((False, self.feedback_gradient)):
                    hashes.append(self.replace(feedback_passes=passes, feedback_gradient=gradient).sha256())
        return tuple(dict.fromkeys(hashes))

    def first_pass_sha256s(self) -> tuple[str, ...]:
        """Config hashes of a tokenizer whose tokens are this model's first pass: this config and its
        :meth:`networks` with render feedback off. () without feedback (the tokens are the first pass)."""
        if not self.feedback_width:
            return ()
        plain = self.without_feedback()
        return plain.sha256(), plain.networks().sha256()


_PAPER = dict(
    name="paper", frames=32, image_size=256, latent_channels=16, ae_downsample=8, ae_width=64,
    patch_size=2, width=768, heads=12, mlp_ratio=4.0, spatial_layers=12, static_query_layers=4,
    dynamic_spatial_layers=2, track_layers=6, renderer_layers=16, n_static=1024, n_dynamic=512,
    token_dim=64, n_tracks=1024,
)
_CONFIGS: dict[str, dict[str, Any]] = {"tiny": {}, "paper": _PAPER}
CONFIG_NAMES = tuple(_CONFIGS)


def get_config(name: str, /, **overrides: Any) -> ModelConfig:
    """The named configuration ("tiny" or "paper") with optional field overrides (e.g. ablations)."""
    if name not in _CONFIGS:
        raise ModelError(f"unknown model config {name!r}; choose one of {list(CONFIG_NAMES)}")
    return ModelConfig.from_dict({**ModelConfig().to_dict(), **_CONFIGS[name], **overrides})


@dataclass(frozen=True)
class PriorConfig(_Config):
    """Sizes of a Co4DGen prior.

    Token state (must equal the tokenizer's): n_static (N_s), n_dynamic (N_d), token_dim (d).
    Conditioning clip: frames (T), image_size (H = W pixels), cond_patch (pixels per video-token side),
    anchor_grid (anchor-ray tokens per frame side), cond_layers (self-attention blocks of E_cond).
    Denoiser: width (D), heads, mlp_ratio, layers (co-denoising blocks G^l).
    cond_dropout: the share of training samples whose condition is replaced by a learned null condition,
    so the prior also learns the unconditional velocity and can sample with classifier-free guidance
    (0: no null condition; the field's default leaves older configs' hashes unchanged).
    cond_tokens: whether E_cond also takes the tokenizer's own tokens of the conditioning video,
    Z^c = E(V_c, P_c), projected and added to the denoiser's input tokens at their positions (the way
    image-conditioned latent diffusion concatenates the conditioning image's latent); False for older configs.
    """

    name: str = "co4dgen-tiny"
    n_static: int = 64
    n_dynamic: int = 32
    token_dim: int = 32
    frames: int = 8
    image_size: int = 64
    cond_patch: int = 16
    anchor_grid: int = 4
    cond_layers: int = 2
    width: int = 128
    heads: int = 4
    mlp_ratio: float = 2.0
    layers: int = 4
    cond_dropout: float = 0.0
    cond_tokens: bool = False

    _KIND: ClassVar[str] = "prior"
    _LATER_FIELDS: ClassVar[dict[str, Any]] = {"cond_dropout": 0.0, "cond_tokens": False}

    def __post_init__(self) -> None:
        _require_positive_ints(self, [f.name for f in dataclasses.fields(self)
                                      if f.name not in ("name", "mlp_ratio", "cond_dropout", "cond_tokens")], "prior config")
        if not isinstance(self.cond_tokens, bool):
            raise ModelError(f"prior cond_tokens must be true or false, got {self.cond_tokens!r}")
        if isinstance(self.cond_dropout, bool) or not isinstance(self.cond_dropout, (int, float)) \
                or not 0.0 <= self.cond_dropout < 1.0:
            raise ModelError(f"prior cond_dropout must lie in [0, 1), got {self.cond_dropout!r}")
        if not isinstance(self.name, str) or not self.name:
            raise ModelError("prior config name must be a non-empty string")
        if self.width % self.heads or self.image_size % self.cond_patch:
            raise ModelError("prior width must divide by heads and image_size by cond_patch")
        if not (isinstance(self.mlp_ratio, (int, float)) and self.mlp_ratio > 0):
            raise ModelError("prior mlp_ratio must be > 0")

    @classmethod
    def for_tokenizer(cls, tokenizer: ModelConfig, name: str = "co4dgen-tiny", **overrides: Any) -> "PriorConfig":
        """The named prior config with the token and clip sizes of ``tokenizer``."""
        base = get_prior_config(name).to_dict()
        base.update(n_static=tokenizer.n_static, n_dynamic=tokenizer.n_dynamic, token_dim=tokenizer.token_dim,
                    frames=tokenizer.frames, image_size=tokenizer.image_size, **overrides)
        return cls.from_dict(base)

    def fits_tokenizer(self, tokenizer: ModelConfig) -> bool:
        return (self.n_static, self.n_dynamic, self.token_dim, self.frames, self.image_size) == (
            tokenizer.n_static, tokenizer.n_dynamic, tokenizer.token_dim, tokenizer.frames, tokenizer.image_size)


_PRIOR_CONFIGS: dict[str, dict[str, Any]] = {
    "co4dgen-tiny": {},
    "co4dgen-paper": dict(name="co4dgen-paper", n_static=1024, n_dynamic=512, token_dim=64, frames=32,
                          image_size=256, cond_patch=16, anchor_grid=8, cond_layers=4, width=768, heads=12,
                          mlp_ratio=4.0, layers=12),
}
PRIOR_CONFIG_NAMES = tuple(_PRIOR_CONFIGS)


def get_prior_config(name: str, /, **overrides: Any) -> PriorConfig:
    """"co4dgen-tiny" (for vt4d-tiny: 96 x 32 tokens, width 128, 4 blocks) or "co4dgen-paper"."""
    if name not in _PRIOR_CONFIGS:
        raise ModelError(f"unknown prior config {name!r}; choose one of {list(PRIOR_CONFIG_NAMES)}")
    return PriorConfig.from_dict({**PriorConfig().to_dict(), **_PRIOR_CONFIGS[name], **overrides})


@dataclass(frozen=True)
class DenseConfig(_Config):
    """Sizes of the dense per-view baseline (:class:`~.dense_baseline.DenseViewDiffusion`).

    Clip and latent space (must equal the tokenizer's whose frozen autoencoder it shares): frames (T),
    image_size (H = W pixels), latent_channels (C), ae_downsample (H / h), ae_width.
    Conditioning (the same encoder as Co4DGen's E_cond): cond_patch (pixels per video-token side),
    anchor_grid (target-ray tokens per frame side), cond_layers.
    Denoiser: patch_size (latent pixels per generated token side), width (D), heads, mlp_ratio, layers
    (factorised space-time DiT blocks).
    """

    name: str = "dense-tiny"
    frames: int = 8
    image_size: int = 64
    latent_channels: int = 8
    ae_downsample: int = 4
    ae_width: int = 16
    cond_patch: int = 16
    anchor_grid: int = 4
    cond_layers: int = 2
    patch_size: int = 2
    width: int = 164
    heads: int = 4
    mlp_ratio: float = 2.0
    layers: int = 6

    _KIND: ClassVar[str] = "dense"

    def __post_init__(self) -> None:
        _require_positive_ints(self, [f.name for f in dataclasses.fields(self) if f.name not in ("name", "mlp_ratio")],
                               "dense config")
        if not isinstance(self.name, str) or not self.name:
            raise ModelError("dense config name must be a non-empty string")
        if self.width % self.heads or self.image_size % self.cond_patch:
            raise ModelError("dense width must divide by heads and image_size by cond_patch")
        if self.image_size % self.ae_downsample or self.latent_size % self.patch_size:
            raise ModelError("dense image_size must divide by ae_downsample and the latent size by patch_size")
        if not (isinstance(self.mlp_ratio, (int, float)) and self.mlp_ratio > 0):
            raise ModelError("dense mlp_ratio must be > 0")

    @property
    def latent_size(self) -> int:
        """h = w of the latent map."""
        return self.image_size // self.ae_downsample

    @classmethod
    def for_tokenizer(cls, tokenizer: ModelConfig, name: str = "dense-tiny", **overrides: Any) -> "DenseConfig":
        """The named dense config with the clip and latent sizes of ``tokenizer``."""
        base = get_dense_config(name).to_dict()
        base.update(frames=tokenizer.frames, image_size=tokenizer.image_size, latent_channels=tokenizer.latent_channels,
                    ae_downsample=tokenizer.ae_downsample, ae_width=tokenizer.ae_width, **overrides)
        return cls.from_dict(base)


_DENSE_CONFIGS: dict[str, dict[str, Any]] = {
    "dense-tiny": {},
}
DENSE_CONFIG_NAMES = tuple(_DENSE_CONFIGS)


def get_dense_config(name: str, /, **overrides: Any) -> DenseConfig:
    """"dense-tiny": the dense per-view baseline matched in size to co4dgen-tiny + vt4d-tiny's renderer."""
    if name not in _DENSE_CONFIGS:
        raise ModelError(f"unknown dense config {name!r}; choose one of {list(DENSE_CONFIG_NAMES)}")
    return DenseConfig.from_dict({**DenseConfig().to_dict(), **_DENSE_CONFIGS[name], **overrides})
