"""The encoder E(V_s, P_s) exported to ONNX, run on onnxruntime: encoding without torch.

A model directory may hold ``encoder.onnx`` next to its weights (written by ``model.onnx_export`` when a
model ships): the graph of ``VideoTok4D.encode`` for one source camera -- inputs the :func:`stack_inputs`
arrays of one clip (B = 1), outputs the bounded tokens Z_s (1, N_s, d) and Z_d (1, N_d, d) float32 -- and
``encoder-v{V}.onnx`` the same for one scene of V synchronized cameras (inputs of V clips, B = V). A model with
render feedback (``config.feedback_width``) has two more outputs, its first pass Z_s^0 and Z_d^0 (``z_s0``,
``z_d0``: the tokens of the same weights without feedback, which a prior trained on them is conditioned on). The
weights are float16 where the float32 value is exactly a float16 (the shipped weights are): external tensors
into ``model.safetensors`` (or, in older exports, stored in the graph), so the graph computes with the very
weights ``from_pretrained`` loads.  Its metadata ties it to them:

* ``vt4d_format``: ``"vt4d-encoder-onnx/1"``;
* ``vt4d_weights_sha256`` / ``vt4d_config_sha256``: the hashes in ``config.json`` of the weights and config
  it was exported from (an encoder exported from other weights is refused, never used silently);
* ``vt4d_views``: the source cameras per scene the graph takes (``"1"`` for ``encoder.onnx``).

Tokens agree with the torch encoder's to float rounding (~1e-6; tested), and a scene encoded here stores
the same model fingerprint.  The point is memory: ``import torch`` alone is ~530 MB resident on Linux
(the CUDA libraries load even without a GPU); numpy, OpenCV, PyAV and onnxruntime together are ~120 MB.
Nothing here imports torch.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from vt4dcodec.errors import ModelError, ModelNotFoundError
from vt4dcodec.format import ModelFingerprint

from .configs import ModelConfig
from .directories import checked_default_quality, meta_fingerprint, meta_networks, meta_token_sources, model_directory, read_model_meta
from .inputs.source_inputs import SourceInputs, stack_inputs
from .onnx_session import MAX_ONNX_BYTES, onnx_available, open_checked  # noqa: F401  (MAX_ONNX_BYTES: as before)

__all__ = ["OnnxEncoder", "ONNX_FILE", "ONNX_FORMAT", "INPUT_NAMES", "OUTPUT_NAMES", "FIRST_PASS_NAMES", "output_names",
           "onnx_available",
           "has_onnx_encoder", "encoder_file"]

ONNX_FILE = "encoder.onnx"
ONNX_FORMAT = "vt4d-encoder-onnx/1"
INPUT_NAMES = ("frames", "K", "w2c", "motion_mask", "track_xy", "track_valid")
OUTPUT_NAMES = ("z_s", "z_d")
FIRST_PASS_NAMES = ("z_s0", "z_d0")  # a model with render feedback: the tokens before it


def output_names(config: ModelConfig) -> tuple[str, ...]:
    """The outputs of the encoder graph of a model with ``config``."""
    return OUTPUT_NAMES + (FIRST_PASS_NAMES if config.feedback_width else ())



def encoder_file(views: int = 1) -> str:
    """The file name of the encoder graph for scenes of ``views`` cameras."""
    return ONNX_FILE if views == 1 else f"encoder-v{int(views)}.onnx"


def has_onnx_encoder(directory: str | os.PathLike[str], views: int = 1) -> bool:
    return (Path(directory) / encoder_file(views)).is_file()


class OnnxEncoder:
    """A model directory's encoder graph for ``views`` cameras on an onnxruntime session.

    ``config`` is the directory's :class:`ModelConfig` (read from ``config.json``, as ``from_pretrained``
    reads it), ``views`` the cameras per scene the graph takes, ``device`` where it runs (``"cpu"``, ``"cuda"``).
    """

    def __init__(self, directory: Path, meta: dict[str, Any], session: Any, views: int, device: str = "cpu") -> None:
        self.directory, self.session, self.views, self.device = directory, session, views, device
        self.config: ModelConfig = meta["config"]
        self.model_id: str = meta["model_id"]
        self.model_version: str = meta["model_version"]
        self._fingerprint = meta_fingerprint(meta)
        self.network_digests = meta_networks(meta)
        self.token_sources = meta_token_sources(meta)
        # the quality level the codec stores tokens at when none is asked for, as from_pretrained reads it
        self.default_quality = checked_default_quality(meta.get("default_quality"), self.config.entropy_levels,
                                                       directory / "config.json")

    @classmethod
    def open(cls, model: str | os.PathLike[str], *, views: int = 1, threads: int | None = None,
             device: str = "cpu") -> "OnnxEncoder":
        """Open the encoder of a model (shipped id, directory, or name under $VT4D_MODEL_PATH) for scenes of
        ``views`` cameras, on ``device`` (``onnx_session.DEVICES``).

        Raises ModelNotFoundError when the directory has no graph for ``views`` cameras, ModelError when
        onnxruntime is missing, the file is not a valid graph, or its metadata does not match ``config.json``,
        DeviceError where ``device="cuda"`` finds no GPU."""
        directory = model_directory(model)
        meta = read_model_meta(directory)
        path = directory / encoder_file(views)
        if not path.is_file():
            raise ModelNotFoundError(f"{directory} has no {path.name}, the encoder for {views} camera(s) (export it "
                                     f"with `python -m vt4dcodec.model.onnx_export {directory}`, or encode with "
                                     "runtime='torch')")
        return cls.from_file(path, meta, views=views, threads=threads, device=device)

    @classmethod
    def from_file(cls, path: Path, meta: dict[str, Any], *, views: int = 1, threads: int | None = None,
                  device: str = "cpu") -> "OnnxEncoder":
        """Open the graph at ``path`` for the model whose parsed ``config.json`` is ``meta``
        (``directories.read_model_meta``); the checks of :meth:`open`."""
        directory = path.parent
        if not onnx_available():
            raise ModelError("encoding with runtime='onnx' needs onnxruntime (pip install onnxruntime), "
                             "or use runtime='torch'")
        session, where, props = open_checked(path, meta, fmt=ONNX_FORMAT, inputs=INPUT_NAMES,
                                             outputs=output_names(meta["config"]),
                                             what="encoder", device=device, threads=threads)
        stored = props.get("vt4d_views", "")
        if stored != str(views):
            raise ModelError(f"{path}: vt4d_views must be {str(views)!r}, got {stored!r}")
        return cls(directory, meta, session, views, where)

    def stored_fingerprint(self) -> ModelFingerprint:
        """The fingerprint a container stores for this model: the same as the torch model's."""
        return self._fingerprint

    def encode(self, clips: list[SourceInputs], feedback: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """One scene from ``views`` source clips (prepared as for the torch encoder) -> (Z_s (1, N_s, d),
        Z_d (1, N_d, d)) float32 in (-1, 1); ``feedback=False``: the first pass of a model with render feedback."""
        if len(clips) != self.views:
            raise ModelError(f"this ONNX encoder takes {self.views} source camera(s) per scene, got {len(clips)}; "
                             f"open the graph for {len(clips)} camera(s) (OnnxEncoder.open(model, views=...))")
        cfg = self.config
        arrays = stack_inputs(clips)
        T, H, h, N, V = cfg.frames, cfg.image_size, cfg.latent_size, cfg.n_tracks, self.views
        expected = {"frames": (V, T, 3, H, H), "K": (V, T, 3, 3), "w2c": (V, T, 4, 4), "motion_mask": (V, T, h, h),
                    "track_xy": (V, N, T, 2), "track_valid": (V, N, T)}
        for name, shape in expected.items():
            if arrays[name].shape != shape:
                raise ModelError(f"{name} must be {shape} for this model, got {arrays[name].shape}")
        names = FIRST_PASS_NAMES if not feedback and cfg.feedback_width else OUTPUT_NAMES
        z_s, z_d = self.session.run(list(names), {name: arrays[name] for name in INPUT_NAMES})
        return np.asarray(z_s, np.float32), np.asarray(z_d, np.float32)
