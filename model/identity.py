"""Who a model is: the identity both networks declare (id, version, training step) and the weights hash
that a fingerprint records.

A fingerprint (:class:`vt4dcodec.format.ModelFingerprint`) names a tokenizer by id and version and pins
it by two hashes: SHA-256 over its config's canonical JSON (``ModelConfig.sha256``) and
:func:`weights_sha256` over its weights in canonical order, computed from the model's own float32
state, whatever dtype its file stores.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

import torch

__all__ = ["ModelIdentity", "weights_sha256", "fingerprint_fields", "network_digests"]


def weights_sha256(state: dict[str, torch.Tensor]) -> str:
    """SHA-256 over tensors in sorted-name order: name, dtype, shape, then little-endian bytes."""
    digest = hashlib.sha256()
    for name in sorted(state):
        tensor = state[name].detach().to("cpu").contiguous()
        header = json.dumps([name, str(tensor.dtype).removeprefix("torch."), list(tensor.shape)],
                            separators=(",", ":"))
        digest.update(header.encode("utf-8"))
        digest.update(tensor.view(-1).view(torch.uint8).numpy().tobytes() if tensor.numel() else b"")
    return digest.hexdigest()


def fingerprint_fields(model: torch.nn.Module, model_id: str, model_version: str) -> dict[str, Any]:
    """The keyword arguments of ``vt4dcodec.format.ModelFingerprint`` for a tokenizer ``model``."""
    cfg = model.config
    return dict(model_id=str(model_id), model_version=str(model_version), config_sha256=cfg.sha256(),
                weights_sha256=weights_sha256(model.state_dict()), static_shape=tuple(cfg.static_shape),
                dynamic_shape=tuple(cfg.dynamic_shape), token_dtype="float32")


def network_digests(model: torch.nn.Module, state: dict[str, torch.Tensor] | None = None) -> tuple[str, str]:
    """(config_sha256, weights_sha256) of ``model``'s networks alone: its config with every entropy-model field
    (``entropy_*``) at its default and its weights (``state``, default the model's) without the entropy model's
    tensors (``entropy.*``). These are the fingerprint fields the same networks had before an entropy model was
    added to them, so a file that model wrote holds tokens these networks read exactly the same way."""
    weights = {k: v for k, v in (model.state_dict() if state is None else state).items()
               if not k.startswith("entropy.")}
    return model.config.networks().sha256(), weights_sha256(weights)


class ModelIdentity:
    """The identity attributes of a model class (a mixin of VideoTok4D and Co4DGen), never part of its
    config hash.

    ``model_id`` / ``model_version``: as recorded in the directory it was loaded from (``weights_io``),
    None for a model that was never saved and loaded; ``training_step``: the step of the training
    checkpoint it was loaded from, None otherwise.  Set them with :meth:`set_identity`, which also
    forgets a fingerprint computed under the old identity.
    """

    model_id: str | None = None
    model_version: str | None = None
    training_step: int | None = None
    network_digests: tuple[str, str] | None = None  # (config, weights) SHA-256 of the networks alone, when loaded
    token_sources: tuple[tuple[str, str], ...] = ()  # (config, weights) of earlier models whose tokens it reads
    _stored_fingerprint: Any = None  # the fingerprint computed for the current identity, if any

    def set_identity(self, model_id: str | None, model_version: str | None, *,
                     training_step: int | None = None) -> None:
        self.model_id, self.model_version, self.training_step = model_id, model_version, training_step
        self._stored_fingerprint = None
