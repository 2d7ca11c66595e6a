"""The Co4DGen prior exported to ONNX, run on onnxruntime: generation without torch.

A prior directory may hold two graphs beside ``prior.safetensors`` (written by ``model.onnx_export``): the
condition encoder, ``prior-condition.onnx`` (V_c (1, T, 3, H, W), P_c, P_a -> h, plus the token normalisation
the sampler undoes), and the velocity, ``prior-velocity.onnx`` (standardised tokens x_s, x_d, h, tau -> v_s, v_d).
A prior with ``cond_tokens`` also feeds Z^c (``z_s``, ``z_d``) to the first and its outputs ``c_s``, ``c_d`` (Z^c
projected) and ``c_pose`` (the relative pose of the anchor, embedded) to the second (:func:`graph_io`).
Their weights are external tensors into ``prior.safetensors``; their metadata ties them to prior.json
(``vt4d_format`` ``"vt4d-prior-onnx/1"``, the weights and config hashes, the token clip ``vt4d_token_limit``).

:class:`OnnxPrior` runs ``Co4DGen.sample``'s Euler / Heun integration in numpy from the same seeded noise
(``onnx_renderer.TorchNormal``): the tokens agree with the torch prior's to float rounding (tested on every
shipped prior). Nothing here imports torch.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from vt4dcodec.errors import ModelError, ModelNotFoundError
from vt4dcodec.format import ModelFingerprint

from .configs import PriorConfig
from .directories import (PRIOR_META_FILE, PRIOR_WEIGHTS_FILE, SamplerSetting, checked_guidance, model_directory,
                          read_prior_meta)
from .onnx_renderer import TorchNormal
from .onnx_session import open_checked

__all__ = ["OnnxPrior", "read_safetensor", "PRIOR_CONDITION_FILE", "PRIOR_VELOCITY_FILE", "PRIOR_ONNX_FORMAT", "CONDITION_INPUTS",
           "CONDITION_OUTPUTS", "VELOCITY_INPUTS", "VELOCITY_OUTPUTS", "TOKEN_INPUTS", "TOKEN_OUTPUTS", "graph_io",
           "has_onnx_prior", "SAMPLERS"]

PRIOR_CONDITION_FILE, PRIOR_VELOCITY_FILE = "prior-condition.onnx", "prior-velocity.onnx"
PRIOR_ONNX_FORMAT = "vt4d-prior-onnx/1"
CONDITION_INPUTS = ("frames", "K_c", "w2c_c", "K_a", "w2c_a")
CONDITION_OUTPUTS = ("h", "static_mean", "static_std", "dynamic_mean", "dynamic_std")
VELOCITY_INPUTS = ("x_s", "x_d", "h", "tau")
VELOCITY_OUTPUTS = ("v_s", "v_d")
# a prior with cond_tokens: Z^c in; projected Z^c and the embedded relative pose of P_a to P_c out
TOKEN_INPUTS, TOKEN_OUTPUTS = ("z_s", "z_d"), ("c_s", "c_d", "c_pose")


def graph_io(config: PriorConfig) -> tuple[tuple[tuple[str, ...], tuple[str, ...]], tuple[tuple[str, ...], tuple[str, ...]]]:
    """(inputs, outputs) of the condition graph and of the velocity graph of a prior with ``config``: a prior
    with ``cond_tokens`` also feeds the condition tokens Z^c to the condition graph, which returns them
    projected (``c_s``, ``c_d``) with the embedded relative pose (``c_pose``) for the velocity graph."""
    if not config.cond_tokens:
        return (CONDITION_INPUTS, CONDITION_OUTPUTS), (VELOCITY_INPUTS, VELOCITY_OUTPUTS)
    return ((CONDITION_INPUTS + TOKEN_INPUTS, CONDITION_OUTPUTS + TOKEN_OUTPUTS),
            (VELOCITY_INPUTS + TOKEN_OUTPUTS, VELOCITY_OUTPUTS))
SAMPLERS = ("euler", "heun")  # as model.prior.SAMPLERS


def has_onnx_prior(directory: str | os.PathLike[str]) -> bool:
    return all((Path(directory) / name).is_file() for name in (PRIOR_CONDITION_FILE, PRIOR_VELOCITY_FILE))


class OnnxPrior:
    """A prior directory's two graphs on onnxruntime sessions; ``config``, ``model_id``, ``model_version`` and
    ``tokenizer_fingerprint`` as the torch prior's (from prior.json), ``device`` where it runs."""

    def __init__(self, directory: Path, meta: dict[str, Any], condition: Any, velocity: Any, token_limit: float,
                 device: str) -> None:
        self.directory, self.condition, self.velocity, self.device = directory, condition, velocity, device
        self.config: PriorConfig = meta["config"]
        self.model_id: str = meta["model_id"]
        self.model_version: str = meta["model_version"]
        self.tokenizer_fingerprint: ModelFingerprint = meta["tokenizer"]
        self.sampler: SamplerSetting = meta["sampler"]
        self.token_limit = token_limit
        self._null: np.ndarray | None = None

    @classmethod
    def open(cls, model: str | os.PathLike[str], *, threads: int | None = None, device: str = "cpu") -> "OnnxPrior":
        """Open the prior graphs of a prior (shipped id, directory, or name under $VT4D_MODEL_PATH) on ``device``.
        ModelNotFoundError without them; ModelError, DeviceError as ``OnnxRenderer.open``."""
        directory = model_directory(model, PRIOR_META_FILE)
        meta = read_prior_meta(directory)
        if not has_onnx_prior(directory):
            raise ModelNotFoundError(f"{directory} has no {PRIOR_CONDITION_FILE} and {PRIOR_VELOCITY_FILE} (export them "
                                     f"with `python -m vt4dcodec.model.onnx_export {directory}`, or sample with torch)")
        sessions, limit = [], None  # graphs of float64 (since co4dgen-tiny 1.2.0) or float32 tensors
        (cond_in, cond_out), (vel_in, vel_out) = graph_io(meta["config"])
        for name, inputs, outputs in ((PRIOR_CONDITION_FILE, cond_in, cond_out), (PRIOR_VELOCITY_FILE, vel_in, vel_out)):
            session, where, props = open_checked(directory / name, meta, fmt=PRIOR_ONNX_FORMAT, inputs=inputs,
                                                 outputs=outputs, what="prior", device=device, threads=threads)
            sessions.append(session)
            limit = props.get("vt4d_token_limit", limit)
        try:
            token_limit = float(limit)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            raise ModelError(f"{directory / PRIOR_VELOCITY_FILE}: metadata vt4d_token_limit must be a number") from None
        return cls(directory, meta, sessions[0], sessions[1], token_limit, where)

    @property
    def dtype(self) -> type:
        """The float type the graphs compute in (their inputs): np.float64, or np.float32 for older exports."""
        return np.float64 if self.condition.get_inputs()[0].type == "tensor(double)" else np.float32

    def null_condition(self) -> np.ndarray:
        """The learned null condition (D,) float32 of a prior trained with ``cond_dropout``, read from its
        weights file (the tensor the guided sampler puts in place of every condition token)."""
        if self._null is None:
            checked_guidance(2.0, self.config.cond_dropout)  # ModelError for a prior without one
            self._null = read_safetensor(self.directory / PRIOR_WEIGHTS_FILE, "null_condition", (self.config.width,))
        return self._null

    def sample(self, frames: np.ndarray, K_c: np.ndarray, w2c_c: np.ndarray, K_a: np.ndarray, w2c_a: np.ndarray, *,
               steps: int = 16, seed: int = 0, method: str = "heun", guidance: float = 1.0,
               z_s: np.ndarray | None = None, z_d: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``Co4DGen.sample`` of one condition: frames (1, T, 3, H, W) float32 in [0, 1], cameras (1, T, 3, 3) and
        (1, T, 4, 4) -> (Z_s (1, N_s, d), Z_d (1, N_d, d)) float32 in (-1, 1); ``guidance`` as there; ``z_s``,
        ``z_d`` the tokenizer's tokens of the video, (1, N_s, d) and (1, N_d, d), for a prior with ``cond_tokens``."""
        if not isinstance(steps, int) or isinstance(steps, bool) or steps < 1:
            raise ModelError(f"steps must be a positive integer, got {steps!r}")
        if method not in SAMPLERS:
            raise ModelError(f"unknown sampler {method!r}; choose one of {SAMPLERS}")
        guidance = checked_guidance(guidance, self.config.cond_dropout)
        null = self.null_condition() if guidance != 1.0 else None
        cfg = self.config
        dtype = self.dtype
        feed = {n: np.ascontiguousarray(a, dtype) for n, a in zip(CONDITION_INPUTS, (frames, K_c, w2c_c, K_a, w2c_a))}
        T, H = cfg.frames, cfg.image_size
        want = {"frames": (1, T, 3, H, H), "K_c": (1, T, 3, 3), "w2c_c": (1, T, 4, 4), "K_a": (1, T, 3, 3),
                "w2c_a": (1, T, 4, 4)}
        if cfg.cond_tokens:
            if z_s is None or z_d is None:
                raise ModelError("this prior is conditioned on the tokenizer's tokens of the conditioning video: pass "
                                 "z_s and z_d (Z^c = E(V_c, P_c))")
            feed.update(z_s=np.ascontiguousarray(z_s, dtype), z_d=np.ascontiguousarray(z_d, dtype))
            want.update(z_s=(1, cfg.n_static, cfg.token_dim), z_d=(1, cfg.n_dynamic, cfg.token_dim))
        for name, shape in want.items():
            if feed[name].shape != shape or not np.isfinite(feed[name]).all():
                raise ModelError(f"{name} must be a finite {shape} array, got {feed[name].shape}")
        (_, cond_out), _ = graph_io(cfg)
        h, s_mean, s_std, d_mean, d_std, *tokens = self.condition.run(list(cond_out), feed)
        token_feed = dict(zip(TOKEN_OUTPUTS, tokens))
        null_tokens = {k: np.zeros_like(v) for k, v in token_feed.items()}
        noise = TorchNormal(seed)
        x_s = noise.randn((1, cfg.n_static, cfg.token_dim)).astype(dtype)  # torch's float32 noise, as there
        x_d = noise.randn((1, cfg.n_dynamic, cfg.token_dim)).astype(dtype)

        h_null = None if null is None else np.ascontiguousarray(np.broadcast_to(null.astype(h.dtype), h.shape))

        def velocity(a: np.ndarray, b: np.ndarray, tau: float) -> tuple[np.ndarray, np.ndarray]:
            t = np.full(1, tau, dtype)
            v_s, v_d = self.velocity.run(list(VELOCITY_OUTPUTS), {"x_s": a, "x_d": b, "h": h, "tau": t, **token_feed})
            if h_null is None:
                return v_s, v_d
            u_s, u_d = self.velocity.run(list(VELOCITY_OUTPUTS), {"x_s": a, "x_d": b, "h": h_null, "tau": t,
                                                                  **null_tokens})
            g = dtype(guidance)
            return u_s + g * (v_s - u_s), u_d + g * (v_d - u_d)

        for i in range(steps):  # as Co4DGen.sample: Python-float step sizes, arithmetic in the graphs' type
            t0, t1 = 1.0 - i / steps, 1.0 - (i + 1) / steps
            v_s, v_d = velocity(x_s, x_d, t0)
            e_s, e_d = x_s + dtype(t1 - t0) * v_s, x_d + dtype(t1 - t0) * v_d
            if method == "heun" and t1 > 0:
                w_s, w_d = velocity(e_s, e_d, t1)
                e_s = x_s + dtype((t1 - t0) * 0.5) * (v_s + w_s)
                e_d = x_d + dtype((t1 - t0) * 0.5) * (v_d + w_d)
            x_s, x_d = e_s, e_d
        limit = dtype(self.token_limit)
        return (np.clip(x_s * s_std + s_mean, -limit, limit).astype(np.float32),
                np.clip(x_d * d_std + d_mean, -limit, limit).astype(np.float32))


_SAFETENSOR_DTYPES = {"F16": np.float16, "F32": np.float32, "BF16": None}


def read_safetensor(path: Path, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """One tensor of a safetensors file as float32, without torch: the 8-byte little-endian header length,
    the JSON header, then the named tensor's byte range.  ModelError when the file is not a safetensors
    file, lacks the tensor or holds it with another shape or a dtype other than F16 / F32."""
    import json

    try:
        with open(path, "rb") as f:
            head = f.read(8)
            if len(head) != 8:
                raise ValueError("shorter than its header length")
            n = int.from_bytes(head, "little")
            if not 2 <= n <= 16 << 20:
                raise ValueError(f"header length {n} out of range")
            header = json.loads(f.read(n).decode("utf-8"))
            entry = header.get(name) if isinstance(header, dict) else None
            if not isinstance(entry, dict):
                raise ValueError(f"no tensor {name!r}")
            dtype = _SAFETENSOR_DTYPES.get(entry.get("dtype"))
            begin, end = entry.get("data_offsets", (None, None))
            if dtype is None or list(entry.get("shape", ())) != list(shape) or not isinstance(begin, int) \
                    or not isinstance(end, int) or end - begin != int(np.prod(shape)) * np.dtype(dtype).itemsize:
                raise ValueError(f"tensor {name!r} is not a {shape} float16/float32 tensor")
            f.seek(8 + n + begin)
            data = f.read(end - begin)
            if len(data) != end - begin:
                raise ValueError(f"tensor {name!r} runs past the end of the file")
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise ModelError(f"{path}: {exc}") from None
    return np.frombuffer(data, dtype=dtype).reshape(shape).astype(np.float32)
