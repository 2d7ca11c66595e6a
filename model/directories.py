"""Where models live and what their meta files say: the torch-free half of ``weights_io``.

:func:`model_directory` finds a tokenizer or prior directory (a directory holding the meta file; else a
shipped id, a directory of ``model/weights/``; else a directory of that name under one of the
``os.pathsep``-separated roots in ``$VT4D_MODEL_PATH``); :func:`read_model_meta` parses and checks a
tokenizer's ``config.json``. The layout of both directories is described in ``weights_io``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from vt4dcodec.errors import ModelError, ModelMismatchError, ModelNotFoundError
from vt4dcodec.format import ModelFingerprint

from .configs import ModelConfig

__all__ = [
    "check_tokenizer", "read_prior_meta", "SamplerSetting", "DEFAULT_SAMPLER", "parse_sampler", "checked_guidance",
    "prior_sampler", "same_networks", "same_token_layout", "meta_networks", "meta_token_sources", "checked_default_quality",
    "model_directory", "read_model_meta", "meta_fingerprint", "read_weights_meta", "shipped_model_ids", "shipped_prior_ids",
    "SHIPPED_DIR", "MODEL_PATH_ENV", "MODEL_FORMAT", "PRIOR_FORMAT", "CONFIG_FILE", "WEIGHTS_FILE", "CARD_FILE",
    "PRIOR_META_FILE", "PRIOR_WEIGHTS_FILE", "MAX_CONFIG_BYTES", "DENSE_FORMAT", "DENSE_META_FILE",
    "DENSE_WEIGHTS_FILE",
]

MODEL_FORMAT, PRIOR_FORMAT = "vt4d-model/1", "co4dgen-prior/1"


class SamplerSetting(tuple):
    """(method, steps, guidance) of a prior's sampler: ``"euler"``/``"heun"``, steps >= 1, classifier-free
    guidance in [0, 20] (1: none).  A prior records the setting chosen for it by measurement in prior.json
    (``extra.sampler``); ``vt4d generate`` and :func:`vt4dcodec.generate.generate` use it by default."""

    __slots__ = ()

    def __new__(cls, method: str, steps: int, guidance: float = 1.0) -> "SamplerSetting":
        if method not in ("euler", "heun"):
            raise ModelError(f"sampler method must be euler or heun, got {method!r}")
        if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= 1000:
            raise ModelError(f"sampler steps must be an integer in 1..1000, got {steps!r}")
        return super().__new__(cls, (method, steps, checked_guidance(guidance)))

    method = property(lambda self: self[0])
    steps = property(lambda self: self[1])
    guidance = property(lambda self: self[2])

    def to_dict(self) -> dict[str, Any]:
        return {"method": self.method, "steps": self.steps, "guidance": self.guidance}

    def __str__(self) -> str:
        return f"{self.method}:{self.steps}" + ("" if self.guidance == 1.0 else f":{self.guidance:g}")


def checked_guidance(guidance: Any, cond_dropout: float | None = None) -> float:
    """``guidance`` as a float: a number in [0, 20]; other than 1 only for a prior whose ``cond_dropout`` > 0
    (one with a null condition; ``cond_dropout`` None: not checked).  ModelError otherwise."""
    if isinstance(guidance, bool) or not isinstance(guidance, (int, float)) or not 0.0 <= guidance <= 20.0:
        raise ModelError(f"guidance must be a number in [0, 20], got {guidance!r}")
    if guidance != 1.0 and cond_dropout is not None and cond_dropout <= 0:
        raise ModelError(f"classifier-free guidance {guidance:g} needs a prior trained with a null condition "
                         "(cond_dropout > 0); sample with guidance 1")
    return float(guidance)


DEFAULT_SAMPLER = SamplerSetting("heun", 16, 1.0)  # a prior that records none


def parse_sampler(text: str) -> SamplerSetting:
    """``"heun:16"`` or ``"euler:4:1.5"`` (METHOD:STEPS[:GUIDANCE]) -> a :class:`SamplerSetting`."""
    parts = str(text).strip().split(":")
    if len(parts) not in (2, 3) or not parts[1].isdigit():
        raise ModelError(f"a sampler setting is METHOD:STEPS[:GUIDANCE], e.g. heun:16 or euler:4:1.5; got {text!r}")
    try:
        guidance = float(parts[2]) if len(parts) == 3 else 1.0
    except ValueError:
        raise ModelError(f"sampler guidance must be a number, got {parts[2]!r}") from None
    return SamplerSetting(parts[0], int(parts[1]), guidance)
SHIPPED_DIR = Path(__file__).resolve().parent / "weights"
MODEL_PATH_ENV = "VT4D_MODEL_PATH"  # os.pathsep-separated directories holding user model and prior directories
CONFIG_FILE, WEIGHTS_FILE, CARD_FILE = "config.json", "model.safetensors", "MODEL_CARD.md"
PRIOR_META_FILE, PRIOR_WEIGHTS_FILE = "prior.json", "prior.safetensors"
DENSE_FORMAT, DENSE_META_FILE, DENSE_WEIGHTS_FILE = "dense-baseline/1", "dense.json", "dense.safetensors"
MAX_CONFIG_BYTES = 1 << 20


def _shipped_ids(meta_file: str) -> list[str]:
    return sorted(p.name for p in SHIPPED_DIR.iterdir() if (p / meta_file).is_file())


def shipped_model_ids() -> list[str]:
    """Ids of the tokenizers shipped inside the package (directories of model/weights/ with config.json)."""
    return _shipped_ids(CONFIG_FILE)


def shipped_prior_ids() -> list[str]:
    """Ids of the priors shipped inside the package (directories of model/weights/ with prior.json)."""
    return _shipped_ids(PRIOR_META_FILE)


def _user_directory(model_id: str, meta_file: str) -> Path | None:
    """The first directory named ``model_id`` and holding ``meta_file`` under a root of $VT4D_MODEL_PATH."""
    for root in filter(None, os.environ.get(MODEL_PATH_ENV, "").split(os.pathsep)):
        candidate = Path(root) / model_id
        if (candidate / meta_file).is_file():
            return candidate
    return None


def model_directory(name_or_path: str | os.PathLike[str], meta_file: str = CONFIG_FILE) -> Path:
    """The directory of a tokenizer (``meta_file`` config.json) or a prior (prior.json): a directory
    holding ``meta_file``; else a shipped id; else a directory of that name under $VT4D_MODEL_PATH; else
    any other directory (its reader then says what it lacks).  ModelNotFoundError otherwise."""
    path = Path(name_or_path)
    if (path / meta_file).is_file():
        return path
    shipped = _shipped_ids(meta_file)
    if isinstance(name_or_path, str) and name_or_path and "/" not in name_or_path and os.sep not in name_or_path:
        if name_or_path in shipped:
            return SHIPPED_DIR / name_or_path
        user = _user_directory(name_or_path, meta_file)
        if user is not None:
            return user
    if path.is_dir():
        return path
    what, hint = {PRIOR_META_FILE: ("prior", ""), DENSE_META_FILE: ("dense baseline", "")}.get(
        meta_file, ("model", "; pass model=<path to the model directory>"))
    raise ModelNotFoundError(f"no {what} {str(name_or_path)!r}: not a directory, not a shipped id (shipped: "
                             f"{shipped or 'none'}) and not a directory under ${MODEL_PATH_ENV}{hint}")


def read_weights_meta(directory: Path, *, meta_file: str, weights_file: str, fmt: str,
                      config_type: Any) -> dict[str, Any]:
    """Parse and validate a model directory's JSON meta (tokenizer ``config.json`` or prior ``prior.json``):
    bounded size, format tag, string identity fields, and a config whose canonical hash matches.
    ``meta["config"]`` is returned as a ``config_type`` instance."""
    path = directory / meta_file
    if not path.is_file() or not (directory / weights_file).is_file():
        raise ModelNotFoundError(f"{directory} lacks {meta_file} or {weights_file}")
    if path.stat().st_size > MAX_CONFIG_BYTES:
        raise ModelError(f"{path} is larger than {MAX_CONFIG_BYTES} bytes")
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelError(f"{path} is not valid JSON: {exc}") from None
    if not isinstance(meta, dict) or meta.get("format") != fmt:
        raise ModelError(f"{path}: format must be {fmt!r}")
    for key in ("model_id", "model_version", "weights_sha256", "config_sha256"):
        if not isinstance(meta.get(key), str):
            raise ModelError(f"{path}: {key} must be a string")
    config = config_type.from_dict(meta.get("config"))
    if config.sha256() != meta["config_sha256"]:
        raise ModelError(f"{path}: config_sha256 does not match the config")
    meta["config"] = config
    return meta


def read_model_meta(directory: Path) -> dict[str, Any]:
    """Parse and validate config.json of a model directory."""
    return read_weights_meta(directory, meta_file=CONFIG_FILE, weights_file=WEIGHTS_FILE, fmt=MODEL_FORMAT,
                             config_type=ModelConfig)


def read_prior_meta(directory: Path) -> dict[str, Any]:
    """Parse and validate prior.json of a prior directory; ``meta["tokenizer"]`` becomes the ModelFingerprint of
    the tokenizer it was trained on (ModelError where it is missing or malformed)."""
    from .configs import PriorConfig

    meta = read_weights_meta(directory, meta_file=PRIOR_META_FILE, weights_file=PRIOR_WEIGHTS_FILE, fmt=PRIOR_FORMAT,
                             config_type=PriorConfig)
    try:
        meta["tokenizer"] = ModelFingerprint.from_dict(meta.get("tokenizer"))
    except Exception as exc:  # the format's own validation errors
        raise ModelError(f"{directory / PRIOR_META_FILE}: bad tokenizer fingerprint: {exc}") from None
    meta["sampler"] = prior_sampler(meta, directory / PRIOR_META_FILE)
    return meta


def prior_sampler(meta: dict[str, Any], path: Any) -> SamplerSetting:
    """The sampler setting prior.json records (``extra.sampler``: method, steps, guidance), or
    :data:`DEFAULT_SAMPLER`; ModelError naming ``path`` when it is malformed or asks for guidance from a
    prior without a null condition."""
    extra = meta.get("extra")
    recorded = extra.get("sampler") if isinstance(extra, dict) else None
    if recorded is None:
        return DEFAULT_SAMPLER
    try:
        if not isinstance(recorded, dict) or set(recorded) - {"method", "steps", "guidance", "measured"}:
            raise ModelError("it must be a map of method, steps, guidance (and measured)")
        setting = SamplerSetting(recorded.get("method"), recorded.get("steps"), recorded.get("guidance", 1.0))
        checked_guidance(setting.guidance, getattr(meta.get("config"), "cond_dropout", 0.0))
    except ModelError as exc:
        raise ModelError(f"{path}: bad extra.sampler: {exc}") from None
    return setting


def meta_fingerprint(meta: dict[str, Any]) -> ModelFingerprint:
    """The fingerprint a container stores for the tokenizer whose parsed ``config.json`` is ``meta`` (as
    :func:`read_model_meta` returns it): the same as the loaded model's ``stored_fingerprint()``."""
    config = meta["config"]
    return ModelFingerprint(model_id=meta["model_id"], model_version=meta["model_version"],
                            config_sha256=meta["config_sha256"], weights_sha256=meta["weights_sha256"],
                            static_shape=tuple(config.static_shape), dynamic_shape=tuple(config.dynamic_shape),
                            token_dtype="float32")


def checked_default_quality(value: Any, levels: int, where: Path) -> int | None:
    """``value`` when it is None or a quality level 1 .. ``levels``; else ModelError naming ``where``."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= levels:
        raise ModelError(f"{where}: default_quality must be a quality level 1 .. {levels} or null, got {value!r}")
    return value


def same_networks(networks: tuple[str, str] | None, have: Any, stored: Any,
                  sources: tuple[tuple[str, str], ...] = ()) -> bool:
    """True when fingerprint ``stored`` (of a file, or the tokenizer a prior was trained on) names a model whose
    tokens the model ``have`` (its fingerprint) reads exactly as that model did: same id, token shapes and dtype,
    and the stored config and weights digests either equal ``networks`` (``have``'s
    :func:`~.identity.network_digests`: the same networks, differing at most by an entropy model, which changes how
    tokens are stored, never what they mean) or are one of ``sources`` (``have``'s :func:`meta_token_sources`:
    earlier models with its first-pass encoder and entropy tables, whose renderer it replaced or whose encoder it
    gave render feedback)."""
    if have is None or stored is None:
        return False
    digests = (stored.config_sha256, stored.weights_sha256)
    return ((networks is not None and digests == tuple(networks)) or digests in sources) and same_token_layout(have, stored)


def same_token_layout(a: Any, b: Any) -> bool:
    """Whether fingerprints ``a`` and ``b`` name the same model id with the same token shapes and dtype."""
    return (a.model_id, a.static_shape, a.dynamic_shape, a.token_dtype) \
        == (b.model_id, b.static_shape, b.dynamic_shape, b.token_dtype)


def meta_networks(meta: dict[str, Any]) -> tuple[str, str] | None:
    """(config, weights) SHA-256 of a model's networks alone, from its parsed ``config.json``: its recorded
    ``networks`` (a model with an entropy model), or its own digests (a model without one); None when a model
    with an entropy model records none."""
    nets = meta.get("networks")
    if isinstance(nets, dict) and isinstance(nets.get("config_sha256"), str) and isinstance(nets.get("weights_sha256"), str):
        return nets["config_sha256"], nets["weights_sha256"]
    config = meta.get("config")
    if getattr(config, "entropy_levels", 0) == 0 and nets is None:
        return meta["config_sha256"], meta["weights_sha256"]
    return None


def meta_token_sources(meta: dict[str, Any]) -> tuple[tuple[str, str], ...]:
    """(config, weights) SHA-256 of the earlier models whose tokens a tokenizer reads as they did, from its parsed
    ``config.json``'s optional ``reads`` (``[{"model_version", "config_sha256", "weights_sha256"}, ...]``, written
    by ``train.ship --reads`` after checking that the model has that model's encoder and entropy tables); () when
    absent. ModelError for a malformed record."""
    reads = meta.get("reads", [])
    if not isinstance(reads, list) or len(reads) > 64:
        raise ModelError("config.json: 'reads' must be a list of at most 64 model fingerprints")
    out = []
    for item in reads:
        pair = (item.get("config_sha256"), item.get("weights_sha256")) if isinstance(item, dict) else (None, None)
        if not all(isinstance(v, str) and len(v) == 64 and all(c in "0123456789abcdef" for c in v) for v in pair):
            raise ModelError("config.json: each 'reads' entry needs config_sha256 and weights_sha256 (64 hex digits)")
        out.append((str(pair[0]), str(pair[1])))
    return tuple(out)


def check_tokenizer(prior: Any, tokenizer_fingerprint: Any, *, force: bool = False,
                    networks: tuple[str, str] | None = None, sources: tuple[tuple[str, str], ...] = ()) -> None:
    """Refuse (ModelMismatchError) a tokenizer other than the one the prior (a Co4DGen or an OnnxPrior, with its
    ``tokenizer_fingerprint``) was trained on. ``networks``: the tokenizer's
    :func:`~.identity.network_digests`; a tokenizer whose networks are exactly the recorded one's (an entropy
    model added, :func:`same_networks`) makes the same tokens and is accepted, and so is one whose ``sources``
    (:func:`meta_token_sources`) name the recorded tokenizer (a renderer replaced or render feedback added, the
    first-pass encoder kept: ``generate.conditioning_tokens`` then conditions on the first pass).

    With ``force`` only the token shapes must agree.
    """
    recorded = prior.tokenizer_fingerprint
    if recorded is None:
        raise ModelMismatchError("this prior records no tokenizer fingerprint (load it with load_prior)")
    if recorded.matches(tokenizer_fingerprint) or same_networks(networks, tokenizer_fingerprint, recorded, sources):
        return
    shapes_agree = (recorded.static_shape, recorded.dynamic_shape) == (
        tokenizer_fingerprint.static_shape, tokenizer_fingerprint.dynamic_shape)
    if force and shapes_agree:
        return
    raise ModelMismatchError(f"the prior was trained on tokens of {recorded.short()}, but the tokenizer given is "
                             f"{tokenizer_fingerprint.short()}" + ("" if shapes_agree else " (token shapes differ)"))

