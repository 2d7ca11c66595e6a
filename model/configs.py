"""Named model configurations (issue #5 item 6) and the ablation switches (item 7).

``get_config("paper")`` follows the paper's setting (32 frames at 256x256, N_s = 1024 static and
N_d = 512 dynamic tokens of width d = 64); ``get_config("tiny")`` is the same architecture at the
size this project's CPUs can train: 8 frames at 64x64, a 16x16x4 latent cut into 4x4 patches (16 grid
tokens per frame: half the training-step time of 2x2 patches on this CPU, same token budget),
N_s = 64, N_d = 32, d = 32,
i.e. 96 x 32 = 3,072 token floats for 8 x 64 x 64 x 3 = 98,304 pixel values (1/32).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from typing import Any

from vt4dcodec.errors import ModelError

__all__ = ["ModelConfig", "get_config", "CONFIG_NAMES", "PREDICTIONS"]

PREDICTIONS = ("velocity", "x0")
_UNSET = object()
# fields added after models were shipped -> the default that reproduces the earlier behaviour
_LATER_FIELDS: dict[str, Any] = {"prediction": "velocity", "render_patch_size": 0, "locality_sigma": 0.0,
                                 "query_from_grid": False}


@dataclass(frozen=True)
class ModelConfig:
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
    Ablations (same token budget):
        unified_tokens: one set of N_s + N_d tokens from the Spatial Branch, no Temporal Branch.
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

    def __post_init__(self) -> None:
        positive = ("frames", "image_size", "latent_channels", "ae_downsample", "ae_width", "patch_size",
                    "width", "heads", "n_static", "n_dynamic", "token_dim", "n_tracks", "renderer_layers",
                    "spatial_layers", "static_query_layers", "track_layers")
        for key in positive:
            value = getattr(self, key)
            if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
                raise ModelError(f"config {key} must be a positive integer, got {value!r}")
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
        if not isinstance(self.query_from_grid, bool):
            raise ModelError(f"config query_from_grid must be true or false, got {self.query_from_grid!r}")
        if self.query_from_grid and not self.locality_sigma > 0:
            raise ModelError("config query_from_grid needs locality_sigma > 0 (it reads each query's anchor cell)")
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
    def token_floats(self) -> int:
        return (self.n_static + self.n_dynamic) * self.token_dim

    # serialization ---------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def canonical_json(self) -> str:
        """Sorted keys, no whitespace: the bytes the fingerprint hashes. Fields added after models were
        shipped are left out while they hold their original default, so older configs keep their hash."""
        data = {k: v for k, v in self.to_dict().items() if _LATER_FIELDS.get(k, _UNSET) != v}
        return json.dumps(data, sort_keys=True, separators=(",", ":"))

    def sha256(self) -> str:
        return hashlib.sha256(self.canonical_json().encode("utf-8")).hexdigest()

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "ModelConfig":
        if not isinstance(data, dict):
            raise ModelError("a model config must be a JSON object")
        known = {f.name: f.type for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - set(known))
        if unknown:
            raise ModelError(f"unknown model config keys: {unknown}")
        try:
            return cls(**data)
        except TypeError as exc:
            raise ModelError(f"bad model config: {exc}") from None

    def replace(self, **overrides: Any) -> "ModelConfig":
        return ModelConfig.from_dict({**self.to_dict(), **overrides})


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
