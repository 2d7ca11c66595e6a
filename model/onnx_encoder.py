"""The encoder E(V_s, P_s) exported to ONNX, run on onnxruntime: encoding without torch.

A model directory may hold ``encoder.onnx`` next to its weights (written by ``model.onnx_export`` when a
model ships): the graph of ``VideoTok4D.encode`` for one source camera -- inputs the :func:`stack_inputs`
arrays of one clip (B = 1), outputs the bounded tokens Z_s (1, N_s, d) and Z_d (1, N_d, d) float32 -- and
``encoder-v{V}.onnx`` the same for one scene of V synchronized cameras (inputs of V clips, B = V). A model with
render feedback (``config.feedback_width``) splits the encoder in three, so the renderer's graph is stored once:
the encoder graphs output its first pass Z_s^0 and Z_d^0 (``z_s0``, ``z_d0``: the tokens of the same weights
without feedback, which a prior trained on them is conditioned on) and what the feedback reads
(:data:`FEEDBACK_STATE`); ``renderer.onnx`` renders Z^0 at the encoded cameras (the decoder's steps, seed 0, the
latents ``y_next``), and ``feedback.onnx`` (:data:`FEEDBACK_INPUTS` -> :data:`FEEDBACK_OUTPUTS`, any V) adds the
feedback; a model of several passes (``config.feedback_passes``) renders again and runs ``feedback-p{k}.onnx``
for pass k = 2, 3, ... A feedback that also reads the render's gradient (``config.feedback_gradient``) renders
with ``render-gradient.onnx`` (``render-gradient-v{V}.onnx`` for V cameras) instead: the same render Y and the
gradient of sum (x - Y)^2 by the tokens (:data:`GRADIENT_INPUTS` -> :data:`GRADIENT_OUTPUTS`; one backward
pass through the renderer, traced to a graph of its own per camera count), and its feedback graphs take the
gradient too (:func:`feedback_inputs`). The renderer places splats with float64 geometry, so a render -- and
the tokens the feedback makes of it -- agree with torch's to float rounding.

The weights are float16 where the float32 value is exactly a float16 (the shipped weights are): external
tensors into ``model.safetensors`` (or, in older exports, stored in the graph), so the graph computes with the
very weights ``from_pretrained`` loads.  Its metadata ties it to them:

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
from typing import TYPE_CHECKING, Any

import numpy as np

from vt4dcodec.errors import ModelError, ModelNotFoundError
from vt4dcodec.format import ModelFingerprint

from .configs import ModelConfig
from .directories import checked_default_quality, meta_fingerprint, meta_networks, meta_token_sources, model_directory, read_model_meta
from .inputs.source_inputs import SourceInputs, stack_inputs
from .onnx_session import MAX_ONNX_BYTES, onnx_available, open_checked  # noqa: F401  (MAX_ONNX_BYTES: as before)

if TYPE_CHECKING:
    from .onnx_renderer import OnnxRenderer

__all__ = ["OnnxEncoder", "ONNX_FILE", "ONNX_FORMAT", "INPUT_NAMES", "OUTPUT_NAMES", "FIRST_PASS_NAMES", "output_names",
           "FEEDBACK_STATE", "FEEDBACK_INPUTS", "FEEDBACK_OUTPUTS", "FEEDBACK_FILE", "FEEDBACK_FORMAT", "feedback_file",
           "feedback_inputs", "GRADIENT_INPUTS", "GRADIENT_OUTPUTS", "GRADIENT_FORMAT", "gradient_file",
           "onnx_available",
           "has_onnx_encoder", "encoder_file"]

ONNX_FILE = "encoder.onnx"
ONNX_FORMAT = "vt4d-encoder-onnx/1"
INPUT_NAMES = ("frames", "K", "w2c", "motion_mask", "track_xy", "track_valid")
OUTPUT_NAMES = ("z_s", "z_d")
FIRST_PASS_NAMES = ("z_s0", "z_d0")  # a model with render feedback: the tokens before it
# a model with render feedback: what its encoder graphs give the feedback graph (VideoTok4D.feedback_reads):
# the first pass's pre-activations (1, N_s, d), (1, N_d, d), the source latents (V, T, C, h, w), the dynamic
# tokens' track reads (clip (N_d,) int64, at (N_d, T, q, 2), weight (N_d, T)), the anchored tokens' cameras
# (N_a,) int64 and frame groups (N_a, T)
FEEDBACK_STATE = ("a_s0", "a_d0", "x", "track_clip", "track_at", "track_weight", "token_cameras", "covers")
FEEDBACK_INPUTS = FEEDBACK_STATE + ("y0",)  # y0: Z^0 rendered at the encoded cameras (V, T, C, h, w) latents
FEEDBACK_OUTPUTS = ("z_s", "z_d", "a_s", "a_d")  # the tokens after the pass and their pre-activations
FEEDBACK_FILE = "feedback.onnx"
FEEDBACK_FORMAT = "vt4d-feedback-onnx/1"
# a feedback that reads the render's gradient (config.feedback_gradient): the graph of the render and its gradient
# takes the tokens so far (1, N_s, d), (1, N_d, d), the source latents x (V, T, C, h, w) and the encoded cameras
# K (V, T, 3, 3), w2c (V, T, 4, 4); it gives their render y0 (V, T, C, h, w) at the encoded cameras (the
# decoder's steps, seed-0 noise) and the gradient of sum (x - y0)^2 by the tokens, g_s (1, N_s, d), g_d (1, N_d, d)
GRADIENT_INPUTS = ("z_s", "z_d", "x", "K", "w2c")
GRADIENT_OUTPUTS = ("y0", "g_s", "g_d")
GRADIENT_FORMAT = "vt4d-render-gradient-onnx/1"


def output_names(config: ModelConfig) -> tuple[str, ...]:
    """The outputs of the encoder graph of a model with ``config``."""
    return FIRST_PASS_NAMES + FEEDBACK_STATE if config.feedback_width else OUTPUT_NAMES


def feedback_inputs(config: ModelConfig) -> tuple[str, ...]:
    """The inputs of the feedback graphs of a model with ``config``: with ``feedback_gradient`` the gradient too."""
    return FEEDBACK_INPUTS + GRADIENT_OUTPUTS[1:] if config.feedback_gradient else FEEDBACK_INPUTS


def gradient_file(views: int = 1) -> str:
    """The file name of the graph of the render and its gradient for scenes of ``views`` cameras."""
    return "render-gradient.onnx" if views == 1 else f"render-gradient-v{int(views)}.onnx"


def feedback_file(step: int = 1) -> str:
    """The file name of the graph of render feedback pass ``step`` (1, 2, ...)."""
    return FEEDBACK_FILE if step == 1 else f"feedback-p{int(step)}.onnx"


def encoder_file(views: int = 1) -> str:
    """The file name of the encoder graph for scenes of ``views`` cameras."""
    return ONNX_FILE if views == 1 else f"encoder-v{int(views)}.onnx"


def has_onnx_encoder(directory: str | os.PathLike[str], views: int = 1) -> bool:
    return (Path(directory) / encoder_file(views)).is_file()


def _check_views(path: Path, props: dict[str, str], views: int) -> None:
    """ModelError unless a graph's metadata says it takes ``views`` cameras per scene (``vt4d_views``)."""
    stored = props.get("vt4d_views", "")
    if stored != str(views):
        raise ModelError(f"{path}: vt4d_views must be {str(views)!r}, got {stored!r}")


class OnnxEncoder:
    """A model directory's encoder graph for ``views`` cameras on an onnxruntime session.

    ``config`` is the directory's :class:`ModelConfig` (read from ``config.json``, as ``from_pretrained``
    reads it), ``views`` the cameras per scene the graph takes, ``device`` where it runs (``"cpu"``, ``"cuda"``).
    """

    def __init__(self, directory: Path, meta: dict[str, Any], session: Any, views: int, device: str = "cpu",
                 feedback: "tuple[list[Any], OnnxRenderer | Any] | None" = None) -> None:
        self.directory, self.session, self.views, self.device = directory, session, views, device
        # a model with render feedback: (a session per feedback pass, what renders for it: the renderer, or the
        # session of the render-gradient graph where the feedback reads the gradient)
        self._feedback = feedback
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
        _check_views(path, props, views)
        feedback = None
        cfg = meta["config"]
        if cfg.feedback_width:  # its later looks render with the renderer's graph, or the render-gradient graph
            from .onnx_renderer import RENDERER_FILE, OnnxRenderer

            passes = [feedback_file(k) for k in range(1, cfg.feedback_passes + 1)]
            render = gradient_file(views) if cfg.feedback_gradient else RENDERER_FILE
            for name in (*passes, render):
                if not (directory / name).is_file():
                    raise ModelNotFoundError(f"{directory} has no {name}, which its encoder's render feedback needs "
                                             f"(export it with `python -m vt4dcodec.model.onnx_export {directory}`, "
                                             "or encode with runtime='torch')")
            sessions = [open_checked(directory / name, meta, fmt=FEEDBACK_FORMAT, inputs=feedback_inputs(cfg),
                                     outputs=FEEDBACK_OUTPUTS, what="render feedback", device=device,
                                     threads=threads)[0] for name in passes]
            if cfg.feedback_gradient:
                renderer, _, props = open_checked(directory / render, meta, fmt=GRADIENT_FORMAT, inputs=GRADIENT_INPUTS,
                                                  outputs=GRADIENT_OUTPUTS, what="render gradient", device=device,
                                                  threads=threads)
                _check_views(directory / render, props, views)
            else:
                renderer = OnnxRenderer.from_file(directory / RENDERER_FILE, meta, threads=threads, device=device)
            feedback = (sessions, renderer)
        return cls(directory, meta, session, views, where, feedback)

    def stored_fingerprint(self) -> ModelFingerprint:
        """The fingerprint a container stores for this model: the same as the torch model's."""
        return self._fingerprint

    def encode(self, clips: list[SourceInputs], feedback: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """One scene from ``views`` source clips (prepared as for the torch encoder) -> (Z_s (1, N_s, d),
        Z_d (1, N_d, d)) float32 in (-1, 1); ``feedback=False``: the first pass of a model with render feedback."""
        if len(clips) != self.views:
            raise ModelError(f"this ONNX encoder takes {self.views} source camera(s) per scene, got {len(clips)}; "
                             f"open the graph for {len(clips)} camera(s) (OnnxEncoder.open(model, views=...))")
        return self.encode_arrays(stack_inputs(clips), feedback)

    def encode_arrays(self, arrays: dict[str, np.ndarray], feedback: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`encode` of the :func:`stack_inputs` arrays of ``views`` clips (the graph's inputs)."""
        cfg = self.config
        T, H, h, N, V = cfg.frames, cfg.image_size, cfg.latent_size, cfg.n_tracks, self.views
        expected = {"frames": (V, T, 3, H, H), "K": (V, T, 3, 3), "w2c": (V, T, 4, 4), "motion_mask": (V, T, h, h),
                    "track_xy": (V, N, T, 2), "track_valid": (V, N, T)}
        for name, shape in expected.items():
            if arrays[name].shape != shape:
                raise ModelError(f"{name} must be {shape} for this model, got {arrays[name].shape}")
        feed = {name: arrays[name] for name in INPUT_NAMES}
        if not cfg.feedback_width:
            z_s, z_d = self.session.run(list(OUTPUT_NAMES), feed)
            return np.asarray(z_s, np.float32), np.asarray(z_d, np.float32)
        if not feedback:
            z_s, z_d = self.session.run(list(FIRST_PASS_NAMES), feed)
            return np.asarray(z_s, np.float32), np.asarray(z_d, np.float32)
        z_s, z_d, *state = self.session.run(list(FIRST_PASS_NAMES + FEEDBACK_STATE), feed)
        assert self._feedback is not None  # from_file opened it for a model with render feedback
        sessions, renderer = self._feedback
        mid = T // 2  # each clip renders at its own trajectory, its tokens placed by the V encoded cameras
        K_src = np.broadcast_to(arrays["K"][None, :, mid], (V, V, 3, 3))
        w2c_src = np.broadcast_to(arrays["w2c"][None, :, mid], (V, V, 4, 4))
        for session in sessions:  # each pass looks at what the tokens so far render
            if cfg.feedback_gradient:  # the render and its gradient by the tokens
                looked = renderer.run(list(GRADIENT_OUTPUTS), dict(zip(GRADIENT_INPUTS, (
                    z_s, z_d, state[2], arrays["K"], arrays["w2c"]))))
            else:
                looked = [renderer.render_latents(np.repeat(z_s, V, 0), np.repeat(z_d, V, 0), arrays["K"],
                                                  arrays["w2c"], K_src, w2c_src, seed=0)]
            z_s, z_d, a_s, a_d = session.run(list(FEEDBACK_OUTPUTS), dict(zip(feedback_inputs(cfg),
                                                                              (*state, *looked))))
            state[:2] = [a_s, a_d]
        return np.asarray(z_s, np.float32), np.asarray(z_d, np.float32)
