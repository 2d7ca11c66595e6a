"""The encoder E(V_s, P_s) exported to ONNX, run on onnxruntime: encoding one camera without torch.

A model directory may hold ``encoder.onnx`` next to its weights (written by ``model.onnx_export`` when a
model ships): the graph of ``VideoTok4D.encode`` for one source camera -- inputs the :func:`stack_inputs`
arrays of one clip (B = 1), outputs the bounded tokens Z_s (1, N_s, d) and Z_d (1, N_d, d) float32 -- with
its weights, stored as float16 where the float32 value is exactly a float16 (the shipped weights are), so
the graph computes with the very weights ``from_pretrained`` loads.  Its metadata ties it to them:

* ``vt4d_format``: ``"vt4d-encoder-onnx/1"``;
* ``vt4d_weights_sha256`` / ``vt4d_config_sha256``: the hashes in ``config.json`` of the weights and config
  it was exported from (an encoder exported from other weights is refused, never used silently);
* ``vt4d_views``: ``"1"``, the source cameras per scene the graph takes.

Tokens agree with the torch encoder's to float rounding (~1e-6; tested), and a scene encoded here stores
the same model fingerprint.  The point is memory: ``import torch`` alone is ~530 MB resident on Linux
(the CUDA libraries load even without a GPU); numpy, OpenCV, PyAV and onnxruntime together are ~120 MB.
Nothing here imports torch.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import Any

import numpy as np

from vt4dcodec.errors import ModelError, ModelNotFoundError
from vt4dcodec.format import ModelFingerprint

from .configs import ModelConfig
from .directories import CONFIG_FILE, meta_fingerprint, model_directory, read_model_meta
from .inputs.source_inputs import SourceInputs, stack_inputs

__all__ = ["OnnxEncoder", "ONNX_FILE", "ONNX_FORMAT", "INPUT_NAMES", "OUTPUT_NAMES", "onnx_available",
           "has_onnx_encoder"]

ONNX_FILE = "encoder.onnx"
ONNX_FORMAT = "vt4d-encoder-onnx/1"
INPUT_NAMES = ("frames", "K", "w2c", "motion_mask", "track_xy", "track_valid")
OUTPUT_NAMES = ("z_s", "z_d")
MAX_ONNX_BYTES = 1 << 28  # 256 MiB: far above any encoder this project ships


def onnx_available() -> bool:
    """Whether onnxruntime is installed (``pip install "vt4dcodec[codec]"`` installs it)."""
    try:
        return importlib.util.find_spec("onnxruntime") is not None
    except (ImportError, ValueError):  # a finder that refuses it: not importable here
        return False


def has_onnx_encoder(directory: str | os.PathLike[str]) -> bool:
    return (Path(directory) / ONNX_FILE).is_file()


class OnnxEncoder:
    """A model directory's ``encoder.onnx`` on an onnxruntime CPU session.

    ``config`` is the directory's :class:`ModelConfig` (read from ``config.json``, as ``from_pretrained``
    reads it), ``views`` the cameras per scene the graph takes (1).
    """

    def __init__(self, directory: Path, meta: dict[str, Any], session: Any, views: int) -> None:
        self.directory, self.session, self.views = directory, session, views
        self.config: ModelConfig = meta["config"]
        self.model_id: str = meta["model_id"]
        self.model_version: str = meta["model_version"]
        self._fingerprint = meta_fingerprint(meta)

    @classmethod
    def open(cls, model: str | os.PathLike[str], *, threads: int | None = None) -> "OnnxEncoder":
        """Open the encoder of a model (shipped id, directory, or name under $VT4D_MODEL_PATH).

        Raises ModelNotFoundError when the directory has no ``encoder.onnx``, ModelError when onnxruntime
        is missing, the file is not a valid graph, or its metadata does not match ``config.json``."""
        directory = model_directory(model)
        meta = read_model_meta(directory)
        path = directory / ONNX_FILE
        if not path.is_file():
            raise ModelNotFoundError(f"{directory} has no {ONNX_FILE} (export it with `python -m "
                                     f"vt4dcodec.model.onnx_export {directory}`, or encode with runtime='torch')")
        return cls.from_file(path, meta, threads=threads)

    @classmethod
    def from_file(cls, path: Path, meta: dict[str, Any], *, threads: int | None = None) -> "OnnxEncoder":
        """Open the graph at ``path`` for the model whose parsed ``config.json`` is ``meta``
        (``directories.read_model_meta``); the checks of :meth:`open`."""
        directory = path.parent
        if path.stat().st_size > MAX_ONNX_BYTES:
            raise ModelError(f"{path} is larger than {MAX_ONNX_BYTES} bytes")
        if not onnx_available():
            raise ModelError("encoding with runtime='onnx' needs onnxruntime (pip install onnxruntime), "
                             "or use runtime='torch'")
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.log_severity_level = 3  # errors only: no warnings about unused initializers on stderr
        if threads is not None:
            options.intra_op_num_threads = int(threads)
        try:
            session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own (pybind) exception types
            raise ModelError(f"{path} is not a valid ONNX encoder: {exc}") from None
        props = session.get_modelmeta().custom_metadata_map
        if props.get("vt4d_format") != ONNX_FORMAT:
            raise ModelError(f"{path}: metadata vt4d_format must be {ONNX_FORMAT!r}")
        for key in ("weights_sha256", "config_sha256"):
            if props.get(f"vt4d_{key}") != meta[key]:
                raise ModelError(f"{path} was exported from other weights than {directory / CONFIG_FILE} "
                                 f"describes ({key} differs): export it again")
        views = props.get("vt4d_views", "")
        if views != "1":
            raise ModelError(f"{path}: vt4d_views must be '1', got {views!r}")
        if tuple(i.name for i in session.get_inputs()) != INPUT_NAMES or \
                tuple(o.name for o in session.get_outputs()) != OUTPUT_NAMES:
            raise ModelError(f"{path}: inputs must be {INPUT_NAMES} and outputs {OUTPUT_NAMES}")
        return cls(directory, meta, session, int(views))

    def stored_fingerprint(self) -> ModelFingerprint:
        """The fingerprint a container stores for this model: the same as the torch model's."""
        return self._fingerprint

    def encode(self, clips: list[SourceInputs]) -> tuple[np.ndarray, np.ndarray]:
        """One scene from ``views`` source clips (prepared as for the torch encoder) -> (Z_s (1, N_s, d),
        Z_d (1, N_d, d)) float32 in (-1, 1)."""
        if len(clips) != self.views:
            raise ModelError(f"the ONNX encoder takes {self.views} source camera(s) per scene, got {len(clips)}; "
                             f"encode several cameras with runtime='torch'")
        cfg = self.config
        arrays = stack_inputs(clips)
        T, H, h, N = cfg.frames, cfg.image_size, cfg.latent_size, cfg.n_tracks
        expected = {"frames": (1, T, 3, H, H), "K": (1, T, 3, 3), "w2c": (1, T, 4, 4), "motion_mask": (1, T, h, h),
                    "track_xy": (1, N, T, 2), "track_valid": (1, N, T)}
        for name, shape in expected.items():
            if arrays[name].shape != shape:
                raise ModelError(f"{name} must be {shape} for this model, got {arrays[name].shape}")
        z_s, z_d = self.session.run(list(OUTPUT_NAMES), {name: arrays[name] for name in INPUT_NAMES})
        return np.asarray(z_s, np.float32), np.asarray(z_d, np.float32)
