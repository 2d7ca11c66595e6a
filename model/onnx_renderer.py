"""The renderer D_theta and the autoencoder's decoder exported to ONNX, run on onnxruntime: decoding without torch.

A model directory may hold ``renderer.onnx`` next to its weights (written by ``model.onnx_export`` when a
model ships): one Euler step of ``VideoTok4D.render_latents`` followed by the autoencoder's decoder --
inputs :data:`RENDERER_INPUTS` (the latent Y^tau (B, T, C, h, w), tau (B,), the step count as a float, the
tokens, the target cameras (B, T, ...) and the encoded cameras' middle frames (B, V, ...), per-view token
drops), outputs Y^(tau - 1/steps) and its frames (B, T, 3, H, W) in [0, 1]. B, T and V are free. The
weights are external tensors into ``model.safetensors`` (``onnx_export``); the metadata ties the graph to
them as the encoder's does (``vt4d_format`` ``"vt4d-renderer-onnx/1"``, the weights and config hashes).

:class:`OnnxRenderer` runs the sampler: the start noise is torch's seeded ``torch.randn`` reproduced in
numpy (:func:`seeded_noise`: the CPU generator's Mersenne Twister and its Box-Muller transform), and the
Euler loop takes ``steps`` steps from tau = 1, as ``VideoTok4D.render`` does; frames agree with the torch
renderer's to float rounding (tested on every shipped model). Nothing here imports torch.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from vt4dcodec.errors import ModelError, ModelNotFoundError
from vt4dcodec.format import ModelFingerprint

from .configs import ModelConfig
from .directories import CONFIG_FILE, meta_fingerprint, meta_networks, meta_token_sources, model_directory, read_model_meta
from .onnx_session import open_checked

__all__ = ["OnnxRenderer", "RENDERER_FILE", "RENDERER_FORMAT", "RENDERER_INPUTS", "RENDERER_OUTPUTS",
           "has_onnx_renderer", "seeded_noise", "TorchNormal"]

RENDERER_FILE = "renderer.onnx"
RENDERER_FORMAT = "vt4d-renderer-onnx/1"
RENDERER_INPUTS = ("y", "tau", "steps", "z_s", "z_d", "K_tgt", "w2c_tgt", "K_src", "w2c_src", "drop_static",
                   "drop_dynamic")
RENDERER_OUTPUTS = ("y_next", "frames")
DEFAULT_DECODE_STEPS, MAX_DECODE_STEPS = 8, 1000  # as model.videotok4d (a directory that records no decode_steps)
MAX_VIEWS = 64  # encoded cameras of one token set (model.entropy.MAX_VIEWS; the graph holds tables for 1 .. 64)


def has_onnx_renderer(directory: str | os.PathLike[str]) -> bool:
    return (Path(directory) / RENDERER_FILE).is_file()


class TorchNormal:
    """``torch.randn(shape, generator=g)`` for successive shapes of one ``g = torch.Generator().manual_seed(seed)``, in
    numpy float32 (to the last bit of its log, cos and sin: ~1e-7): the generator is MT19937 seeded with the low
    32 bits of ``seed``; every value is a 24-bit uniform u = (word & 0xFFFFFF) / 2^24, and each block of 16
    becomes normal by Box-Muller, r = sqrt(-2 ln(1 - u_j)), theta = 2 pi u_(j+8); a count not a multiple of 16
    redraws 16 fresh uniforms for the last 16 values. For at least 16 values a draw (the codec's always are)."""

    def __init__(self, seed: int) -> None:
        self.generator = np.random.MT19937(0)
        self.generator._legacy_seeding(int(seed) & 0xFFFFFFFF)  # MT19937's own init_genrand, as torch's CPU generator

    def _uniform(self, count: int) -> np.ndarray:
        words = self.generator.random_raw(count).astype(np.uint32) & np.uint32(0xFFFFFF)
        return words.astype(np.float32) * np.float32(1.0 / (1 << 24))

    @staticmethod
    def _box_muller(u: np.ndarray) -> np.ndarray:  # (k, 16) -> (k, 16)
        radius = np.sqrt(np.float32(-2.0) * np.log(np.float32(1.0) - u[:, :8]))
        theta = np.float32(2.0 * np.pi) * u[:, 8:]
        return np.concatenate([radius * np.cos(theta), radius * np.sin(theta)], axis=1)

    def randn(self, shape: tuple[int, ...]) -> np.ndarray:
        n = int(np.prod(shape))
        if n < 16:
            raise ValueError("TorchNormal reproduces torch.randn for 16 values or more")
        data = self._uniform(n)
        full = n - n % 16
        data[:full] = self._box_muller(data[:full].reshape(-1, 16)).reshape(-1)
        if n % 16:
            data[n - 16:] = self._box_muller(self._uniform(16)[None])[0]
        return data.reshape(shape).astype(np.float32)


def seeded_noise(shape: tuple[int, ...], seed: int) -> np.ndarray:
    """``torch.randn(shape, generator=torch.Generator().manual_seed(seed))`` in numpy (:class:`TorchNormal`)."""
    return TorchNormal(seed).randn(shape)


class OnnxRenderer:
    """A model directory's ``renderer.onnx`` on an onnxruntime session: tokens + cameras -> frames.

    ``config``, ``decode_steps`` (the sampler steps of the model's best fidelity), ``model_id`` and
    ``model_version`` as the torch model's; ``device`` where it runs (``"cpu"``, ``"cuda"``)."""

    def __init__(self, directory: Path, meta: dict[str, Any], session: Any, device: str = "cpu") -> None:
        self.directory, self.session, self.device = directory, session, device
        self.config: ModelConfig = meta["config"]
        self.model_id: str = meta["model_id"]
        self.model_version: str = meta["model_version"]
        steps = meta.get("decode_steps", DEFAULT_DECODE_STEPS)
        if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= MAX_DECODE_STEPS:
            raise ModelError(f"{directory / CONFIG_FILE}: decode_steps must be an integer 1 .. {MAX_DECODE_STEPS}")
        self.decode_steps: int = steps
        self._fingerprint = meta_fingerprint(meta)
        self.network_digests = meta_networks(meta)
        self.token_sources = meta_token_sources(meta)

    @property
    def needs_source(self) -> bool:
        """Whether rendering needs the encoded cameras (``config.project_anchors``), as ``VideoTok4D.needs_source``."""
        return bool(self.config.project_anchors)

    @classmethod
    def open(cls, model: str | os.PathLike[str], *, threads: int | None = None, device: str = "cpu") -> "OnnxRenderer":
        """Open the renderer of a model (shipped id, directory, or name under $VT4D_MODEL_PATH) on ``device``.

        Raises ModelNotFoundError when the directory has no ``renderer.onnx``, ModelError when onnxruntime is
        missing, the file is not a valid graph, or its metadata does not match ``config.json``, DeviceError
        where ``device="cuda"`` finds no GPU."""
        directory = model_directory(model)
        meta = read_model_meta(directory)
        path = directory / RENDERER_FILE
        if not path.is_file():
            raise ModelNotFoundError(f"{directory} has no {RENDERER_FILE} (export it with `python -m "
                                     f"vt4dcodec.model.onnx_export {directory}`, or decode with runtime='torch')")
        return cls.from_file(path, meta, threads=threads, device=device)

    @classmethod
    def from_file(cls, path: Path, meta: dict[str, Any], *, threads: int | None = None,
                  device: str = "cpu") -> "OnnxRenderer":
        """Open the graph at ``path`` for the model whose parsed ``config.json`` is ``meta``; the checks of
        :meth:`open`."""
        session, where, _ = open_checked(path, meta, fmt=RENDERER_FORMAT, inputs=RENDERER_INPUTS,
                                         outputs=RENDERER_OUTPUTS, what="renderer", device=device, threads=threads)
        return cls(path.parent, meta, session, where)

    def stored_fingerprint(self) -> ModelFingerprint:
        """The fingerprint a container stores for this model: the same as the torch model's."""
        return self._fingerprint

    def render(self, z_s: np.ndarray, z_d: np.ndarray, K_tgt: np.ndarray, w2c_tgt: np.ndarray,
               K_src: np.ndarray | None = None, w2c_src: np.ndarray | None = None, *, steps: int | None = None,
               seed: int = 0, drop_static: bool = False, drop_dynamic: bool = False) -> np.ndarray:
        """Frames (B, T, 3, H, W) float32 in [0, 1], as ``VideoTok4D.render``: tokens z_s (B, N_s, d), z_d (B, N_d,
        d); target cameras K_tgt (B, T, 3, 3), w2c_tgt (B, T, 4, 4); the encoded cameras at their middle frame
        K_src (B, V, 3, 3), w2c_src (B, V, 4, 4) (needed when :attr:`needs_source`); ``steps`` Euler steps (None:
        :attr:`decode_steps`) from the same seeded noise for every view."""
        return self._sample(z_s, z_d, K_tgt, w2c_tgt, K_src, w2c_src, steps, seed, drop_static, drop_dynamic)[1]

    def render_latents(self, z_s: np.ndarray, z_d: np.ndarray, K_tgt: np.ndarray, w2c_tgt: np.ndarray,
                       K_src: np.ndarray | None = None, w2c_src: np.ndarray | None = None, *, steps: int | None = None,
                       seed: int = 0) -> np.ndarray:
        """The sampled latents Y^0 (B, T, C, h, w) float32 of :meth:`render` (``VideoTok4D.render_latents``)."""
        return self._sample(z_s, z_d, K_tgt, w2c_tgt, K_src, w2c_src, steps, seed, False, False)[0]

    def _sample(self, z_s: np.ndarray, z_d: np.ndarray, K_tgt: np.ndarray, w2c_tgt: np.ndarray,
                K_src: np.ndarray | None, w2c_src: np.ndarray | None, steps: int | None, seed: int,
                drop_static: bool, drop_dynamic: bool) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.config
        steps = self.decode_steps if steps is None else steps
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ModelError(f"steps must be a positive integer, got {steps!r}")
        z_s, z_d = np.ascontiguousarray(z_s, np.float32), np.ascontiguousarray(z_d, np.float32)
        if z_s.ndim != 3 or z_s.shape[1:] != tuple(cfg.static_shape) or z_d.ndim != 3 or \
                z_d.shape[1:] != tuple(cfg.dynamic_shape) or z_s.shape[0] != z_d.shape[0]:
            raise ModelError(f"tokens must be (B, {cfg.n_static}, {cfg.token_dim}) and (B, {cfg.n_dynamic}, "
                             f"{cfg.token_dim}), got {z_s.shape} and {z_d.shape}")
        B = z_s.shape[0]
        K_tgt, w2c_tgt = np.ascontiguousarray(K_tgt, np.float32), np.ascontiguousarray(w2c_tgt, np.float32)
        T = K_tgt.shape[1] if K_tgt.ndim == 4 else -1
        if K_tgt.shape != (B, T, 3, 3) or w2c_tgt.shape != (B, T, 4, 4) or not 1 <= T <= cfg.frames:
            raise ModelError(f"target cameras must be K ({B}, T, 3, 3) and w2c ({B}, T, 4, 4) with T in 1 .. "
                             f"{cfg.frames}, got {K_tgt.shape} and {w2c_tgt.shape}")
        if K_src is None or w2c_src is None:
            if self.needs_source:
                raise ModelError("this model places its tokens with the source cameras: pass K_src and w2c_src, the "
                                 "encoded cameras (a Scene's cameras and extra_cameras) at their middle frame")
            K_src, w2c_src = np.broadcast_to(np.eye(3, dtype=np.float32), (B, 1, 3, 3)), \
                np.broadcast_to(np.eye(4, dtype=np.float32), (B, 1, 4, 4))
        K_src, w2c_src = np.ascontiguousarray(K_src, np.float32), np.ascontiguousarray(w2c_src, np.float32)
        V = K_src.shape[1] if K_src.ndim == 4 else -1
        if K_src.shape != (B, V, 3, 3) or w2c_src.shape != (B, V, 4, 4) or not 1 <= V <= MAX_VIEWS:
            raise ModelError(f"source cameras must be K ({B}, V, 3, 3) and w2c ({B}, V, 4, 4) with V in 1 .. "
                             f"{MAX_VIEWS}, got {K_src.shape} and {w2c_src.shape}")
        for name, array in (("target", K_tgt), ("target", w2c_tgt), ("source", K_src), ("source", w2c_src)):
            if not np.isfinite(array).all():
                raise ModelError(f"{name} cameras hold non-finite values")
        h = cfg.latent_size
        y = np.ascontiguousarray(np.broadcast_to(seeded_noise((1, T, cfg.latent_channels, h, h), seed),
                                                 (B, T, cfg.latent_channels, h, h)))
        feed = {"z_s": z_s, "z_d": z_d, "K_tgt": K_tgt, "w2c_tgt": w2c_tgt, "K_src": K_src, "w2c_src": w2c_src,
                "steps": np.asarray(float(steps), np.float32),
                "drop_static": np.full(B, bool(drop_static)), "drop_dynamic": np.full(B, bool(drop_dynamic))}
        frames = None
        for i in range(steps):
            feed["y"] = y
            feed["tau"] = np.full(B, 1.0 - i / steps, np.float32)
            y, frames = self.session.run(list(RENDERER_OUTPUTS), feed)
        return np.asarray(y, np.float32), np.asarray(frames, np.float32)
