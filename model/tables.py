"""The frozen entropy tables of an installed tokenizer, read without torch.

``learned-rans`` files (FORMAT.md I.6.2) need the integer tables of the model that coded them. They ship in
the model's ``model.safetensors`` as the tensors ``entropy.steps``, ``entropy.freqs`` and ``entropy.origins`` (and
with partner channels ``entropy.partners``)
(``model.entropy.TokenEntropyModel.update``). :func:`entropy_tables` finds the model by a file's fingerprint
(shipped id or ``$VT4D_MODEL_PATH``), parses the safetensors with numpy, checks the weights against the
``weights_sha256`` the fingerprint names (so the tables are the model's, bit for bit), and returns them as
:class:`vt4dcodec.format.EntropyTables`. ``import vt4dcodec`` installs it as the format's table resolver.
"""

from __future__ import annotations

import hashlib
import json
import struct
from pathlib import Path
from typing import Any

import numpy as np

from vt4dcodec.errors import EntropyTablesError, ModelError
from vt4dcodec.format import EntropyTables, ModelFingerprint

from .directories import (WEIGHTS_FILE, meta_fingerprint, meta_token_sources, model_directory, read_model_meta,
                          same_token_layout)

__all__ = ["entropy_tables", "tables_from_directory", "read_safetensors", "rounding_offsets", "frozen_tables"]

# safetensors dtype -> (numpy dtype as stored, the model's dtype name in weights_sha256: floats widen to float32)
_DTYPES = {"F32": ("<f4", "float32"), "F16": ("<f2", "float32"), "I16": ("<i2", "int16"), "I32": ("<i4", "int32"),
           "I64": ("<i8", "int64"), "U8": ("u1", "uint8"), "BOOL": ("?", "bool")}
_MAX_HEADER = 16 << 20
_cache: dict[tuple[str, float, ModelFingerprint], EntropyTables | None] = {}


def read_safetensors(path: Path) -> dict[str, np.ndarray]:
    """Every tensor of a safetensors file as a numpy array in the model's dtype (float16 widened to float32,
    as the model holds it). ModelError for a damaged file."""
    data = path.read_bytes()
    if len(data) < 8:
        raise ModelError(f"{path} is not a safetensors file")
    (size,) = struct.unpack("<Q", data[:8])
    if size > min(_MAX_HEADER, len(data) - 8):
        raise ModelError(f"{path}: safetensors header of {size} bytes does not fit the file")
    try:
        header = json.loads(data[8:8 + size])
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelError(f"{path}: safetensors header is not JSON ({exc})") from None
    body = memoryview(data)[8 + size:]
    tensors = {}
    for name, spec in header.items():
        if name == "__metadata__":
            continue
        if not isinstance(spec, dict) or spec.get("dtype") not in _DTYPES:
            raise ModelError(f"{path}: tensor {name!r} has an unsupported dtype")
        stored, wide = _DTYPES[spec["dtype"]]
        begin, end = spec["data_offsets"]
        shape = tuple(int(v) for v in spec["shape"])
        count = int(np.prod(shape)) if shape else 1
        if not 0 <= begin <= end <= len(body) or end - begin != count * np.dtype(stored).itemsize:
            raise ModelError(f"{path}: tensor {name!r} does not fit its byte range")
        tensors[name] = np.frombuffer(body[begin:end], dtype=stored).reshape(shape).astype(wide)
    return tensors


def _weights_sha256(tensors: dict[str, np.ndarray]) -> str:
    """``model.identity.weights_sha256`` of the model's state, computed with numpy."""
    digest = hashlib.sha256()
    for name in sorted(tensors):
        t = tensors[name]  # (np.ascontiguousarray would make a 0-d tensor 1-d)
        digest.update(json.dumps([name, str(t.dtype), list(t.shape)], separators=(",", ":")).encode("utf-8"))
        digest.update(t.astype(t.dtype.newbyteorder("<")).tobytes())
    return digest.hexdigest()


def tables_from_directory(directory: Path, fingerprint: ModelFingerprint | None = None) -> EntropyTables:
    """The entropy tables of the model in ``directory`` (EntropyTablesError when it has none, or when its
    fingerprint is not ``fingerprint``)."""
    meta = read_model_meta(directory)
    own = meta_fingerprint(meta)
    if fingerprint is not None and own != fingerprint and reads_tables_of(meta, own, fingerprint):
        own = fingerprint  # an update of the file's model (renderer, render feedback): the same encoder and tables
    elif fingerprint is not None and own != fingerprint:
        raise EntropyTablesError(f"{directory} holds model {own.model_id} {own.model_version}, not the file's "
                                 f"{fingerprint.model_id} {fingerprint.model_version}")
    if not meta["config"].entropy_levels:
        raise EntropyTablesError(f"model {own.model_id} {own.model_version} has no entropy model (learned-rans "
                                 f"needs a model with quality levels)")
    tensors = read_safetensors(directory / WEIGHTS_FILE)
    if _weights_sha256(tensors) != meta["weights_sha256"]:
        raise EntropyTablesError(f"{directory / WEIGHTS_FILE}: weights do not match weights_sha256")
    if not (tensors["entropy.freqs"] > 0).any():
        raise EntropyTablesError(f"model {own.model_id} {own.model_version} was saved before its entropy tables "
                                 f"were frozen (VideoTok4D.update_entropy)")
    return EntropyTables(tensors["entropy.steps"], tensors["entropy.freqs"], tensors["entropy.origins"], own,
                         rounding_offsets(meta["config"]), tensors.get("entropy.partners"))


def reads_tables_of(meta: dict[str, Any], own: ModelFingerprint, fingerprint: ModelFingerprint) -> bool:
    """Whether the model of ``meta`` (fingerprint ``own``) holds the entropy tables of model ``fingerprint``: one of
    its ``reads`` (:func:`~.directories.meta_token_sources`) with its own id, token shapes and config, or its
    config without render feedback, or with fewer feedback passes or without the render's gradient -- an earlier
    model whose renderer it replaced or whose encoder's render feedback it added or grew (``train.ship --reads``
    checked every other tensor equal; ``ModelConfig.update_bases_sha256s``)."""
    configs = (own.config_sha256, *meta["config"].update_bases_sha256s())
    return ((fingerprint.config_sha256, fingerprint.weights_sha256) in meta_token_sources(meta)
            and fingerprint.config_sha256 in configs and same_token_layout(own, fingerprint))


def frozen_tables(model: Any, fingerprint: ModelFingerprint) -> EntropyTables | None:
    """The frozen entropy tables of a loaded VideoTok4D (None without an entropy model or before
    ``update_entropy``) under ``fingerprint``: what a learned-rans file of the model is read and written with."""
    entropy = getattr(model, "entropy", None)
    if entropy is None or not entropy.frozen:
        return None
    partners = getattr(entropy, "partners", None)
    return EntropyTables(entropy.steps.numpy(), entropy.freqs.numpy(), entropy.origins.numpy(), fingerprint,
                         rounding_offsets(model.config), None if partners is None else partners.numpy())


def rounding_offsets(config: Any) -> np.ndarray | None:
    """(levels, 3) the writer's rounding offsets of a model config (``entropy_rounding``), None where it has none."""
    values = getattr(config, "entropy_rounding", ())
    return np.asarray(values, np.float64).reshape(-1, 3) if values else None


def entropy_tables(fingerprint: ModelFingerprint) -> EntropyTables | None:
    """The tables of the installed model (shipped id, or a directory under $VT4D_MODEL_PATH named by the
    model id) whose fingerprint is ``fingerprint``; None when no such model is installed."""
    try:
        directory = model_directory(fingerprint.model_id)
        meta_path = directory / WEIGHTS_FILE
        key = (str(directory.resolve()), meta_path.stat().st_mtime, fingerprint)
    except (ModelError, OSError):
        return None
    if key not in _cache:
        try:
            _cache[key] = tables_from_directory(directory, fingerprint)
        except EntropyTablesError:
            _cache[key] = None
        except ModelError:
            return None
    return _cache[key]
