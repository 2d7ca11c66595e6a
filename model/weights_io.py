"""Weights I/O and lookup of both models: the VideoTok4D tokenizer (``save_pretrained`` /
``from_pretrained``) and the Co4DGen prior (``save_prior`` / ``load_prior``).

Lookup (:func:`model_directory`, the same for both; it and the meta readers live in the torch-free
``directories`` and are re-exported here): a directory holding the model's meta file; else a
shipped id (a directory of ``model/weights/``); else a directory of that name under one of the
``os.pathsep``-separated roots in ``$VT4D_MODEL_PATH`` (user models and priors, found by the id a scene
or prior records); else ModelNotFoundError.

A tokenizer directory holds

* ``config.json``: ``{"format": "vt4d-model/1", "model_id", "model_version", "config": {...},
  "config_sha256", "weights_sha256", "decode_steps", "default_quality"}`` (``decode_steps``: the sampler
  steps the codec uses by default for this model, chosen by measurement; optional, 8 when absent; not
  hashed; ``default_quality``: for a model with quality levels, the level the codec stores tokens at when
  none is asked for, chosen by measurement, or null; absent for other models; not hashed; ``networks``: for
  a model with an entropy model, ``{"config_sha256", "weights_sha256"}`` of its networks alone
  (:func:`~.identity.network_digests`), checked on load: files of the model those networks came from decode
  with this one); ``reads``: optional, ``[{"model_version", "config_sha256", "weights_sha256"}, ...]``, the
  fingerprints of earlier models whose tokens this one reads exactly as they did -- the same config and every
  tensor outside ``renderer.*`` equal, checked by ``train.ship --reads`` -- so their files decode with it and
  a prior trained on their tokens stays bound to it (:func:`~.directories.same_networks`); not hashed;
* ``model.safetensors``: the full state dict, no pickle anywhere; floating tensors are stored as
  float32, or as float16 to halve shipped files (``storage_dtype="float16"``: the model is rounded to
  float16 values first, so what is saved, loaded and fingerprinted is the same model);
* optionally ``MODEL_CARD.md``;
* optionally ``encoder.onnx``: the encoder exported for onnxruntime (``onnx_export``, written when a model
  ships; ``onnx_encoder`` reads it and refuses one exported from other weights).

The fingerprint a container stores is SHA-256 over the canonical config JSON (sorted keys, no
whitespace) and SHA-256 over the weights in canonical order: for every tensor name in sorted order,
the UTF-8 name, its dtype and shape, then its little-endian bytes, taken from the model's own float32
state (independent of the storage dtype; ``identity.weights_sha256``). Loading recomputes the weights
hash and refuses files whose hash disagrees with config.json.  A prior directory holds ``prior.json``
(the same keys, format "co4dgen-prior/1", plus the fingerprint of its tokenizer), ``prior.safetensors``
and optionally ``MODEL_CARD.md``; a dense-baseline directory (Table 2's per-view video-diffusion model)
holds ``dense.json`` (format "dense-baseline/1", the same keys and the fingerprint of the tokenizer whose
autoencoder it shares) and ``dense.safetensors``.  Loading sets each model's identity (``model_id``, ``model_version``)
from its meta file.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from vt4dcodec.errors import ModelError
from vt4dcodec.format import ModelFingerprint

from .configs import DenseConfig, PriorConfig
from .dense_baseline import DenseViewDiffusion
from .directories import (CARD_FILE, CONFIG_FILE, DENSE_FORMAT, DENSE_META_FILE, DENSE_WEIGHTS_FILE, MODEL_FORMAT,
                          MODEL_PATH_ENV, PRIOR_FORMAT, PRIOR_META_FILE, PRIOR_WEIGHTS_FILE, SHIPPED_DIR, WEIGHTS_FILE,
                          checked_default_quality, meta_token_sources, model_directory, prior_sampler, read_model_meta,
                          read_weights_meta,
                          shipped_model_ids, shipped_prior_ids)
from .identity import network_digests, weights_sha256
from .prior import Co4DGen
from .videotok4d import DEFAULT_DECODE_STEPS, MAX_DECODE_STEPS, VideoTok4D

__all__ = [
    "save_pretrained", "from_pretrained", "save_prior", "load_prior", "shipped_model_ids", "shipped_prior_ids",
    "model_directory", "SHIPPED_DIR", "MODEL_PATH_ENV", "MODEL_FORMAT", "PRIOR_FORMAT", "write_weights_directory",
    "read_weights_meta", "storage_state", "widen_stored", "save_dense", "load_dense",
]

STORAGE_DTYPES = {"float32": torch.float32, "float16": torch.float16}


def storage_state(module: torch.nn.Module, storage_dtype: str = "float32"
                  ) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
    """(float32 state to fingerprint, tensors to store) for ``storage_dtype``.

    For "float16" the module's floating weights are first rounded to float16 values in place (they stay
    float32), so the stored file, the module and a reloaded module are the same weights.
    """
    if storage_dtype not in STORAGE_DTYPES:
        raise ModelError(f"storage_dtype must be one of {sorted(STORAGE_DTYPES)}, got {storage_dtype!r}")
    store = STORAGE_DTYPES[storage_dtype]
    if store != torch.float32:
        with torch.no_grad():
            for tensor in module.state_dict().values():
                if tensor.dtype == torch.float32:
                    tensor.copy_(tensor.to(store).to(torch.float32))
    state = {k: v.detach().to("cpu").contiguous().clone() for k, v in module.state_dict().items()}
    return state, {k: v.to(store) if v.dtype == torch.float32 else v for k, v in state.items()}


def widen_stored(state: dict[str, torch.Tensor], expected: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Stored float16 tensors widened to the module's float32; every other tensor unchanged."""
    return {k: v.to(torch.float32) if v.dtype == torch.float16 and k in expected
            and expected[k].dtype == torch.float32 else v for k, v in state.items()}


def save_pretrained(model: VideoTok4D, directory: str | Path, *, model_id: str, model_version: str,
                    card: str | None = None, storage_dtype: str = "float32", decode_steps: int | None = None,
                    default_quality: int | None = None, reads: list[dict[str, str]] | None = None) -> Path:
    """Write config.json + model.safetensors (+ MODEL_CARD.md) into ``directory``; returns it.

    ``decode_steps`` (default: ``model.decode_steps``) is recorded as the codec's default sampler steps;
    ``default_quality`` (default: ``model.default_quality``) as the quality level the codec stores tokens at
    when none is asked for (recorded only for a model with an entropy model; None: no default level).

    ``storage_dtype="float16"`` rounds ``model``'s floating weights to float16 values in place (they stay
    float32 tensors) and stores them as float16, so the saved file, the loaded model and the
    fingerprint all describe the same weights.
    """
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    state, stored = storage_state(model, storage_dtype)
    digest = weights_sha256(state)
    steps = _checked_decode_steps(model.decode_steps if decode_steps is None else decode_steps, out)
    meta = {"format": MODEL_FORMAT, "model_id": str(model_id), "model_version": str(model_version),
            "config": model.config.to_dict(), "config_sha256": model.config.sha256(), "weights_sha256": digest,
            "decode_steps": steps}
    if model.config.entropy_levels:
        nets = network_digests(model, state)
        meta["networks"] = {"config_sha256": nets[0], "weights_sha256": nets[1]}
        meta["default_quality"] = checked_default_quality(
            model.default_quality if default_quality is None else default_quality, model.config.entropy_levels, out)
    elif default_quality is not None:
        raise ModelError(f"{out}: default_quality needs a model with quality levels (config entropy_levels > 0)")
    if reads:
        meta["reads"] = [dict(item) for item in reads]
        meta_token_sources(meta)  # well formed
    return write_weights_directory(out, stored, meta, weights_file=WEIGHTS_FILE, meta_file=CONFIG_FILE, card=card)


def _checked_decode_steps(value: Any, where: Path) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_DECODE_STEPS:
        raise ModelError(f"{where}: decode_steps must be an integer in [1, {MAX_DECODE_STEPS}], got {value!r}")
    return value


def write_weights_directory(out: Path, tensors: dict[str, torch.Tensor], meta: dict[str, Any], *,
                            weights_file: str, meta_file: str, card: str | None) -> Path:
    """Write ``tensors`` (safetensors, tagged with ``meta``'s format and weights hash), ``meta`` (sorted
    JSON) and an optional model card into ``out``: the layout shared by tokenizers and priors."""
    save_file(tensors, str(out / weights_file),
              metadata={"format": meta["format"], "weights_sha256": meta["weights_sha256"]})
    (out / meta_file).write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    if card is not None:
        (out / CARD_FILE).write_text(card, encoding="utf-8")
    return out


def from_pretrained(name_or_path: str | Path, *, device: str | torch.device = "cpu") -> VideoTok4D:
    """Load a shipped model id (e.g. "vt4d-tiny") or a model directory; autoencoder frozen, eval mode.

    Raises ModelNotFoundError for an unknown id/path, ModelError for damaged or inconsistent files.
    """
    directory = model_directory(name_or_path)
    meta = read_model_meta(directory)
    try:
        state = load_file(str(directory / WEIGHTS_FILE), device="cpu")
    except (SafetensorError, ValueError, RuntimeError) as exc:
        raise ModelError(f"{directory / WEIGHTS_FILE} is not a valid safetensors file: {exc}") from None
    model = VideoTok4D(meta["config"])
    expected = model.state_dict()
    if set(state) != set(expected):
        missing, extra = sorted(set(expected) - set(state)), sorted(set(state) - set(expected))
        raise ModelError(f"weights do not fit the config: missing {missing[:5]}, unexpected {extra[:5]}")
    # float16 storage is widened to the model's float32; any other dtype difference is an error
    state = widen_stored(state, expected)
    bad = [k for k in state if state[k].shape != expected[k].shape or state[k].dtype != expected[k].dtype]
    if bad:
        raise ModelError(f"weights do not fit the config: wrong shape/dtype for {bad[:5]}")
    if weights_sha256(state) != meta["weights_sha256"]:
        raise ModelError(f"{directory / WEIGHTS_FILE}: weights do not match weights_sha256 in {CONFIG_FILE}")
    model.load_state_dict(state, strict=True)
    model.freeze_autoencoder()
    model.set_identity(meta["model_id"], meta["model_version"])
    model.network_digests = (network_digests(model, state) if model.config.entropy_levels
                             else (meta["config_sha256"], meta["weights_sha256"]))  # verified just above
    recorded = meta.get("networks")
    if recorded is not None and (not isinstance(recorded, dict) or (recorded.get("config_sha256"),
                                                                    recorded.get("weights_sha256")) != model.network_digests):
        raise ModelError(f"{directory / CONFIG_FILE}: 'networks' does not match the networks in {WEIGHTS_FILE}")
    model.token_sources = meta_token_sources(meta)
    model.decode_steps = _checked_decode_steps(meta.get("decode_steps", DEFAULT_DECODE_STEPS), directory / CONFIG_FILE)
    model.default_quality = checked_default_quality(meta.get("default_quality"), model.config.entropy_levels,
                                                    directory / CONFIG_FILE)
    return model.to(device).eval()


# --- the Co4DGen prior -------------------------------------------------------------------------------------
def _save_bound(module: torch.nn.Module, directory: str | Path, *, fmt: str, meta_file: str, weights_file: str,
                model_id: str, model_version: str, tokenizer: Any, card: str | None, extra: dict[str, Any] | None,
                storage_dtype: str) -> Path:
    """A model bound to one tokenizer (the prior, the dense baseline): meta JSON + safetensors (+ card)."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    state, stored = storage_state(module, storage_dtype)
    digest = weights_sha256(state)
    meta = {"format": fmt, "model_id": str(model_id), "model_version": str(model_version),
            "config": module.config.to_dict(), "config_sha256": module.config.sha256(), "weights_sha256": digest,
            "tokenizer": tokenizer.to_dict(), **({"extra": extra} if extra else {})}
    return write_weights_directory(out, stored, meta, weights_file=weights_file, meta_file=meta_file, card=card)


def save_prior(prior: Co4DGen, directory: str | Path, *, model_id: str, model_version: str,
               tokenizer: Any, card: str | None = None, extra: dict[str, Any] | None = None,
               storage_dtype: str = "float32") -> Path:
    """Write prior.json + prior.safetensors (+ MODEL_CARD.md); ``tokenizer`` is the
    :class:`~vt4dcodec.format.ModelFingerprint` of the tokenizer whose tokens the prior models.
    ``storage_dtype="float16"`` halves the file (see :func:`storage_state`)."""
    return _save_bound(prior, directory, fmt=PRIOR_FORMAT, meta_file=PRIOR_META_FILE, weights_file=PRIOR_WEIGHTS_FILE,
                       model_id=model_id, model_version=model_version, tokenizer=tokenizer, card=card, extra=extra,
                       storage_dtype=storage_dtype)


def save_dense(dense: DenseViewDiffusion, directory: str | Path, *, model_id: str, model_version: str,
               tokenizer: Any, card: str | None = None, extra: dict[str, Any] | None = None,
               storage_dtype: str = "float32") -> Path:
    """Write dense.json + dense.safetensors (+ MODEL_CARD.md) of the dense per-view baseline; ``tokenizer``
    is the fingerprint of the tokenizer whose frozen autoencoder (the latent space) it holds."""
    return _save_bound(dense, directory, fmt=DENSE_FORMAT, meta_file=DENSE_META_FILE, weights_file=DENSE_WEIGHTS_FILE,
                       model_id=model_id, model_version=model_version, tokenizer=tokenizer, card=card, extra=extra,
                       storage_dtype=storage_dtype)


def _load_bound(name_or_path: str | Path, cls: Any, *, fmt: str, meta_file: str, weights_file: str,
                config_type: Any, device: str | torch.device) -> tuple[Any, dict[str, Any], Path]:
    directory = model_directory(name_or_path, meta_file)
    path = directory / meta_file
    meta = read_weights_meta(directory, meta_file=meta_file, weights_file=weights_file, fmt=fmt,
                             config_type=config_type)
    try:
        tokenizer = ModelFingerprint.from_dict(meta.get("tokenizer"))
    except ValueError as exc:
        raise ModelError(f"{path}: bad tokenizer fingerprint: {exc}") from None
    try:
        state = load_file(str(directory / weights_file), device="cpu")
    except (SafetensorError, ValueError, RuntimeError, OSError) as exc:
        raise ModelError(f"{directory / weights_file} is not a valid safetensors file: {exc}") from None
    module = cls(meta["config"])
    expected = module.state_dict()
    state = widen_stored(state, expected)
    if weights_sha256(state) != meta["weights_sha256"]:
        raise ModelError(f"{directory / weights_file}: weights do not match weights_sha256")
    if set(state) != set(expected) or any(state[k].shape != expected[k].shape or state[k].dtype != expected[k].dtype
                                          for k in state):
        raise ModelError(f"{directory}: weights do not fit the {config_type._KIND} config")
    module.load_state_dict(state, strict=True)
    module.set_identity(meta["model_id"], meta["model_version"])
    module.tokenizer_fingerprint = tokenizer
    module.requires_grad_(False)
    return module.to(device).eval(), meta, path


def load_prior(name_or_path: str | Path, *, device: str | torch.device = "cpu") -> Co4DGen:
    """A shipped prior id (e.g. "co4dgen-tiny") or a prior directory, verified, in eval mode.

    Its ``model_id``, ``model_version``, ``tokenizer_fingerprint`` and ``sampler`` (the sampler setting
    chosen for it, :class:`~.directories.SamplerSetting`) are those recorded in prior.json.
    """
    prior, meta, path = _load_bound(name_or_path, Co4DGen, fmt=PRIOR_FORMAT, meta_file=PRIOR_META_FILE,
                                    weights_file=PRIOR_WEIGHTS_FILE, config_type=PriorConfig, device=device)
    prior.sampler = prior_sampler(meta, path)
    return prior


def load_dense(name_or_path: str | Path, *, device: str | torch.device = "cpu") -> DenseViewDiffusion:
    """A dense-baseline directory (dense.json), verified, frozen, in eval mode; ``tokenizer_fingerprint`` is
    the tokenizer whose autoencoder it holds."""
    dense, _, _ = _load_bound(name_or_path, DenseViewDiffusion, fmt=DENSE_FORMAT, meta_file=DENSE_META_FILE,
                              weights_file=DENSE_WEIGHTS_FILE, config_type=DenseConfig, device=device)
    return dense
