"""Export a model directory's networks to ONNX, for onnxruntime (``model.onnx_encoder``, ``model.onnx_renderer``).

    python -m vt4dcodec.model.onnx_export MODEL   # a shipped id or a model directory: every graph below

What it writes beside ``model.safetensors`` (:func:`export_model`; run when a model ships):

* ``encoder.onnx``: ``VideoTok4D.encode`` for one source camera, and ``encoder-v{V}.onnx`` for scenes of V
  synchronized cameras, V = 2 .. :data:`EXPORT_VIEWS` (the encoder's fusion of several cameras depends on V
  in Python: one graph per camera count, each a few hundred kilobytes);
* ``renderer.onnx``: one Euler step of the rectified-flow sampler plus the autoencoder's decoder, for any
  number of target views, frames and encoded cameras (``model.onnx_renderer`` runs the sampler loop);
* for a model with render feedback, ``feedback.onnx`` (and ``feedback-p{k}.onnx`` for pass k > 1): the feedback's
  update from the first pass and its render, for any number of encoded cameras; the encoder graphs of such a
  model stop at the first pass and output what the feedback reads, and ``model.onnx_encoder`` renders it
  with ``renderer.onnx``, so the renderer is stored once;
* for a feedback that reads the render's gradient (``config.feedback_gradient``), ``render-gradient.onnx`` and
  ``render-gradient-v{V}.onnx`` (V = 2 .. :data:`EXPORT_VIEWS`): the render at the encoded cameras and the
  gradient of the squared latent error by the tokens, which the encoder runs instead of the renderer (see
  below: traced otherwise, one graph per camera count);
* for a Co4DGen prior directory (:func:`export_prior`), ``prior-condition.onnx`` and ``prior-velocity.onnx``
  beside ``prior.safetensors`` (``model.onnx_prior`` runs its sampler).

Graphs are traced with torch's TorchScript-based exporter (opset 17) without constant folding, so their
weights are the model's own parameters, and every float32 weight whose values are exactly float16 (all
weights of a model stored in float16) is not copied into the graph: it is an ONNX external tensor that
points at its bytes in ``model.safetensors`` (float16) followed by a Cast. A graph thus holds structure and a
few small constants only, and computes with the very weights ``from_pretrained`` loads.  Tensors that are
not in the weights file stay in the graph (float16 where exact).

Three things of the torch networks have no ONNX form and are traced through equivalents here, each
checked by the parity test before a graph is written: ``torch.linalg.solve`` / ``inv`` of the 3 x 3
intrinsics (adjugate over determinant), the renderer's in-place key-mask and bias assignments (the same
values built by concatenation), and the renderer's per-camera-count index tables (token cameras, frame
copies, copy origins and resolutions, stored for 1 .. MAX_VIEWS cameras and gathered by the graph at the
count its source cameras have).  Before a graph replaces an old one, onnxruntime's output on example
inputs must match torch's within :data:`PARITY_TOLERANCE`.  Needs the ``onnx`` package (``train`` and
``test`` extras).

The render-gradient graphs are a backward pass, which that exporter cannot trace: ``torch.func`` differentiates
the decoder's render (:func:`_render_gradient`), ``make_fx`` traces forward and backward to aten operations
(attention on its math kernel; decompositions for the few operators without an ONNX form) and torch's dynamo
exporter writes the graph (it needs the ``onnxscript`` package, in the same extras). The trace fixes the shapes
and the camera count's index tables, hence one graph per camera count, each checked against torch's
render and gradient on captures it was not traced on (:data:`GRADIENT_TOLERANCE`); its weights are linked into
``model.safetensors`` as above.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import logging
import os
import struct
import sys
import warnings
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from vt4dcodec.errors import ModelError

from . import renderer as renderer_module
from .directories import WEIGHTS_FILE, model_directory, read_model_meta
from .entropy import MAX_VIEWS
from .inputs.source_inputs import SourceBatch
from .layers import dynamic_token_cameras, locality_heads
from .onnx_encoder import (FEEDBACK_FORMAT, FEEDBACK_OUTPUTS, GRADIENT_FORMAT, GRADIENT_INPUTS, GRADIENT_OUTPUTS,
                           INPUT_NAMES, ONNX_FORMAT, OnnxEncoder, encoder_file, feedback_file, feedback_inputs,
                           gradient_file, output_names)
from .onnx_session import module_available, open_checked
from .onnx_renderer import (RENDERER_FILE, RENDERER_FORMAT, RENDERER_INPUTS, RENDERER_OUTPUTS, OnnxRenderer)
from .videotok4d import VideoTok4D
from .weights_io import from_pretrained

__all__ = ["export_encoder", "export_feedback", "export_gradient", "export_renderer", "export_model", "export_prior",
           "example_inputs", "example_render_inputs", "PARITY_TOLERANCE", "GRADIENT_TOLERANCE", "EXPORT_VIEWS"]

PARITY_TOLERANCE = 1e-4  # max |difference| of tokens (or frames in [0, 1]) between onnxruntime and torch
# max |difference| of a render gradient relative to its largest |value| (vt4d-tiny gf1: 1.1e-6 measured)
GRADIENT_TOLERANCE = 1e-4
FOLD_LIMIT = 256  # the render-gradient graphs fold constants of at most this many elements (never a weight)
OPSET = 17
EXPORT_VIEWS = 10  # encoder graphs for scenes of 1 .. EXPORT_VIEWS cameras (a 10-camera rig; more: the torch runtime)


# --- example inputs --------------------------------------------------------------------------------
def _orbit(n: int, T: int, size: int, offset: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(K (n, T, 3, 3), w2c (n, T, 4, 4)): n cameras 3 m from the origin, each turning 0.3 rad over T frames."""
    K = torch.tensor([[size, 0.0, size / 2], [0.0, size, size / 2], [0.0, 0.0, 1.0]]).expand(n, T, 3, 3).contiguous()
    w2c = torch.eye(4).repeat(n, T, 1, 1)
    angle = torch.linspace(0.0, 0.3, T)[None] + offset + 0.4 * torch.arange(n)[:, None]
    w2c[..., 0, 0], w2c[..., 0, 2] = torch.cos(angle), torch.sin(angle)
    w2c[..., 2, 0], w2c[..., 2, 2] = -torch.sin(angle), torch.cos(angle)
    w2c[..., 2, 3] = 3.0
    return K, w2c


def example_inputs(net: VideoTok4D, seed: int = 0, views: int = 1) -> tuple[torch.Tensor, ...]:
    """Inputs of one scene of ``views`` clips of the model's shapes: random frames, orbiting cameras 3 m from
    the origin, a random motion mask (20 % of the cells) and random tracks (70 % valid)."""
    cfg = net.config
    g = torch.Generator().manual_seed(seed)
    T, H, h, N = cfg.frames, cfg.image_size, cfg.latent_size, cfg.n_tracks
    K, w2c = _orbit(views, T, H, 0.0)
    return (torch.rand(views, T, 3, H, H, generator=g), K, w2c,
            (torch.rand(views, T, h, h, generator=g) < 0.2).float(),
            torch.rand(views, N, T, 2, generator=g) * (h - 1),
            torch.rand(views, N, T, generator=g) < 0.7)


def example_render_inputs(net: VideoTok4D, *, views: int = 2, frames: int | None = None, cameras: int = 3,
                          seed: int = 0) -> dict[str, torch.Tensor]:
    """Renderer inputs: random tokens in (-1, 1) for ``views`` target views of ``frames`` frames (default the
    clip) along orbits, ``cameras`` encoded cameras (their middle frames), one step from tau = 1."""
    cfg = net.config
    g = torch.Generator().manual_seed(seed)
    T = cfg.frames if frames is None else frames
    K_tgt, w2c_tgt = _orbit(views, T, cfg.image_size, 0.05)
    K_src, w2c_src = (t[:, 0][None].expand(views, *t.shape[:1], *t.shape[2:]).contiguous()
                      for t in _orbit(cameras, 1, cfg.image_size, -0.1))
    noise = torch.randn(1, T, cfg.latent_channels, cfg.latent_size, cfg.latent_size, generator=g)
    return {"y": noise.expand(views, -1, -1, -1, -1).contiguous(), "tau": torch.ones(views), "steps": torch.tensor(1.0),
            "z_s": torch.rand(views, cfg.n_static, cfg.token_dim, generator=g) * 2 - 1,
            "z_d": torch.rand(views, cfg.n_dynamic, cfg.token_dim, generator=g) * 2 - 1,
            "K_tgt": K_tgt, "w2c_tgt": w2c_tgt, "K_src": K_src, "w2c_src": w2c_src,
            "drop_static": torch.zeros(views, dtype=torch.bool), "drop_dynamic": torch.zeros(views, dtype=torch.bool)}


# --- traceable equivalents ---------------------------------------------------------------------------
def _inverse3(K: torch.Tensor) -> torch.Tensor:
    """Inverse of (..., 3, 3) matrices by adjugate over determinant (ONNX has no matrix inverse)."""
    a, b, c = K[..., 0, 0], K[..., 0, 1], K[..., 0, 2]
    d, e, f = K[..., 1, 0], K[..., 1, 1], K[..., 1, 2]
    g, h, i = K[..., 2, 0], K[..., 2, 1], K[..., 2, 2]
    co = [e * i - f * h, f * g - d * i, d * h - e * g]  # cofactors of the first row
    adj = torch.stack([torch.stack([co[0], c * h - b * i, b * f - c * e], -1),
                       torch.stack([co[1], a * i - c * g, c * d - a * f], -1),
                       torch.stack([co[2], b * g - a * h, a * e - b * d], -1)], -2)
    det = a * co[0] + b * co[1] + c * co[2]
    return adj / det[..., None, None]


@contextlib.contextmanager
def _traceable_linalg() -> Iterator[None]:
    """torch.linalg.solve / inv of 3 x 3 systems as :func:`_inverse3` while a graph is traced."""
    solve, inv = torch.linalg.solve, torch.linalg.inv
    torch.linalg.solve = lambda A, B: _inverse3(A) @ B  # type: ignore[assignment]
    torch.linalg.inv = _inverse3  # type: ignore[assignment]
    try:
        yield
    finally:
        torch.linalg.solve, torch.linalg.inv = solve, inv  # type: ignore[assignment]


# --- weights: external tensors into model.safetensors -------------------------------------------------
def _safetensors_index(path: Path) -> dict[tuple[tuple[int, ...], bytes], tuple[int, int]]:
    """(shape, SHA-256 of the bytes) -> (offset, length) in the file of every float16 tensor of a safetensors
    file (read without the safetensors package: an 8-byte header length, a JSON header, the data)."""
    data = path.read_bytes()
    (length,) = struct.unpack("<Q", data[:8])
    header = json.loads(data[8:8 + length])
    base, index = 8 + length, {}
    for name, entry in header.items():
        if name == "__metadata__" or entry.get("dtype") != "F16":
            continue
        start, stop = (base + int(x) for x in entry["data_offsets"])
        index[(tuple(entry["shape"]), hashlib.sha256(data[start:stop]).digest())] = (start, stop - start)
    return index


def _link_weights(model: Any, weights: Path) -> int:
    """Rewrite the float32 (or float64) initializers of an ``onnx.ModelProto`` whose values are exactly float16 as
    float16 + Cast: an external tensor into ``weights`` (a safetensors file beside the graph) where that file holds the
    same values, else stored in the graph. Returns the number linked to the file."""
    import onnx
    from onnx import helper, numpy_helper

    index = _safetensors_index(weights)
    graph, casts, kept, linked = model.graph, [], [], 0
    for init in graph.initializer:
        value = numpy_helper.to_array(init)
        if value.dtype not in (np.float32, np.float64) or value.size < 16 or \
                not np.array_equal(value.astype(np.float16).astype(value.dtype), value):
            kept.append(init)
            continue
        half = value.astype(np.float16)
        found = index.get((tuple(half.shape), hashlib.sha256(half.tobytes()).digest()))
        if found is None:
            tensor = numpy_helper.from_array(half, init.name + "__f16")
        else:
            tensor = onnx.TensorProto(name=init.name + "__f16", data_type=onnx.TensorProto.FLOAT16,
                                      dims=list(half.shape), data_location=onnx.TensorProto.EXTERNAL)
            for key, text in (("location", weights.name), ("offset", str(found[0])), ("length", str(found[1]))):
                entry = tensor.external_data.add()
                entry.key, entry.value = key, text
            linked += 1
        kept.append(tensor)
        to = onnx.TensorProto.DOUBLE if value.dtype == np.float64 else onnx.TensorProto.FLOAT
        casts.append(helper.make_node("Cast", [tensor.name], [init.name], to=to, name=init.name + "__cast"))
    del graph.initializer[:]
    graph.initializer.extend(kept)
    nodes = casts + list(graph.node)
    del graph.node[:]
    graph.node.extend(nodes)
    return linked


def _compact_names(model: Any) -> None:
    """Short names for every node and every value but the graph's inputs and outputs (the tracer's names spell
    module paths and take half of a graph's bytes); what the graph computes is unchanged."""
    graph = model.graph
    keep = {v.name for v in graph.input} | {v.name for v in graph.output} | {""}
    names: dict[str, str] = {}

    def short(name: str) -> str:
        if name in keep:
            return name
        if name not in names:
            names[name] = format(len(names), "x")
        return names[name]

    for init in graph.initializer:
        init.name = short(init.name)
    for node in graph.node:
        node.name = ""
        node.input[:] = [short(n) for n in node.input]
        node.output[:] = [short(n) for n in node.output]


def _trace(module: nn.Module, inputs: tuple[torch.Tensor, ...], input_names: list[str], output_names: list[str],
           dynamic_axes: dict[str, dict[int, str]] | None = None) -> Any:
    import onnx

    buffer = io.BytesIO()
    with torch.no_grad(), warnings.catch_warnings(), _traceable_linalg():
        warnings.simplefilter("ignore")  # the tracer's notes on shape constants: checked by the parity test
        torch.onnx.export(module, inputs, buffer, dynamo=False, opset_version=OPSET, input_names=input_names,
                          output_names=output_names, dynamic_axes=dynamic_axes, do_constant_folding=False)
    model = onnx.load_from_string(buffer.getvalue())
    del model.graph.value_info[:]  # traced shapes: onnxruntime would bake the example's sizes into reshapes
    _fill_uniform_constants(model)
    return model


def _fill_uniform_constants(model: Any, min_elements: int = 1024) -> int:
    """Replace every Constant node of ``model`` whose tensor (of ``min_elements`` or more) holds one value by a
    ConstantOfShape of that value: the same tensor, built at load time instead of stored. A static-shape trace
    stores the zero masks and biases a render expands over its batch (14 MB for the ten-camera encoder with
    render feedback). Returns the number replaced."""
    from onnx import helper, numpy_helper

    nodes, replaced = [], 0
    for node in model.graph.node:
        value = next((a.t for a in node.attribute if a.name == "value"), None) if node.op_type == "Constant" else None
        array = None if value is None else numpy_helper.to_array(value)
        if array is None or array.size < min_elements or not (array == array.flat[0]).all():
            nodes.append(node)
            continue
        shape = f"{node.output[0]}__shape"
        nodes.append(helper.make_node("Constant", [], [shape], value=numpy_helper.from_array(
            np.asarray(array.shape, np.int64), shape)))
        nodes.append(helper.make_node("ConstantOfShape", [shape], list(node.output),
                                      value=numpy_helper.from_array(array.reshape(-1)[:1].copy())))
        replaced += 1
    del model.graph.node[:]
    model.graph.node.extend(nodes)
    return replaced


def _finish(model: Any, directory: Path, meta: dict[str, Any], fmt: str, name: str, extra: dict[str, str],
            check: Any, weights: str = WEIGHTS_FILE) -> Path:
    """Link the weights, stamp the metadata, check with ``check(path)`` and move into place as ``name``."""
    import onnx

    _link_weights(model, directory / weights)
    _compact_names(model)
    for key, value in (("vt4d_format", fmt), ("vt4d_weights_sha256", meta["weights_sha256"]),
                       ("vt4d_config_sha256", meta["config_sha256"]),
                       ("vt4d_model", f"{meta['model_id']} {meta['model_version']}"), *extra.items()):
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    target = directory / name
    candidate = directory / f".{name}.tmp-{os.getpid()}"  # beside the weights its external tensors point into
    try:
        candidate.write_bytes(model.SerializeToString())
        onnx.checker.check_model(str(candidate))  # by path: the external tensors are read beside it
        check(candidate)
        os.replace(candidate, target)
    finally:
        candidate.unlink(missing_ok=True)
    return target


def _checked_meta(net: VideoTok4D, directory: Path) -> dict[str, Any]:
    meta = read_model_meta(directory)
    fingerprint = net.fingerprint(meta["model_id"], meta["model_version"])
    if (fingerprint.weights_sha256, fingerprint.config_sha256) != (meta["weights_sha256"], meta["config_sha256"]):
        raise ModelError(f"{directory} describes other weights than the model given")
    return meta


def _check_views(views: int) -> None:
    if isinstance(views, bool) or not isinstance(views, int) or not 1 <= views <= MAX_VIEWS:
        raise ModelError(f"views must be 1 .. {MAX_VIEWS}, got {views!r}")


def _parity(got: list[np.ndarray], want: list[np.ndarray], what: str) -> None:
    error = max(float(np.abs(a - b).max()) for a, b in zip(got, want))
    if error > PARITY_TOLERANCE:
        raise ModelError(f"exported {what} differs from torch by {error:.2e} (> {PARITY_TOLERANCE})")


# --- the encoder -------------------------------------------------------------------------------------
class _Encode(nn.Module):
    """``VideoTok4D.encode`` of one scene of ``views`` cameras, taking the :class:`SourceBatch` fields as tensors."""

    def __init__(self, net: VideoTok4D, views: int) -> None:
        super().__init__()
        self.net, self.views = net, views

    def forward(self, frames: torch.Tensor, K: torch.Tensor, w2c: torch.Tensor, motion_mask: torch.Tensor,
                track_xy: torch.Tensor, track_valid: torch.Tensor) -> tuple[torch.Tensor, ...]:
        batch = SourceBatch(frames=frames, K=K, w2c=w2c, motion_mask=motion_mask, track_xy=track_xy,
                            track_valid=track_valid, views=self.views)
        net = self.net
        if net.feedback is None:
            return net.encode(batch)
        a_s, a_d, x, chosen = net._first_preactivations(batch)  # the first pass and what the feedback reads
        return (*net._bound(a_s, a_d), a_s, a_d, x.float(), *net.feedback_reads(batch, chosen))  # FEEDBACK_STATE


class _Feedback(nn.Module):
    """``VideoTok4D.feedback_update`` of render feedback pass ``step`` (1, 2, ...) of one scene: inputs
    ``feedback_inputs(config)`` (the render's gradient last where the feedback reads it), outputs
    :data:`FEEDBACK_OUTPUTS` (the bounded tokens and their pre-activations)."""

    def __init__(self, net: VideoTok4D, step: int) -> None:
        super().__init__()
        self.net, self.module = net, net.feedback_modules()[step - 1]

    def forward(self, a_s: torch.Tensor, a_d: torch.Tensor, x: torch.Tensor, clip: torch.Tensor, at: torch.Tensor,
                weight: torch.Tensor, cameras: torch.Tensor, covers: torch.Tensor, y0: torch.Tensor,
                *gradients: torch.Tensor) -> tuple[torch.Tensor, ...]:
        a_s, a_d = self.net.feedback_update(self.module, a_s, a_d, x, y0, clip, at, weight, cameras, covers,
                                            gradients=(gradients[0], gradients[1]) if gradients else None)
        return (*self.net._bound(a_s, a_d), a_s, a_d)


def _feedback_case(net: VideoTok4D, step: int, views: int, seed: int
                   ) -> tuple[tuple[torch.Tensor, ...], list[np.ndarray]]:
    """(``feedback_inputs(config)`` of pass ``step`` on example inputs for ``views`` cameras, torch's outputs)."""
    inputs = example_inputs(net, seed=seed, views=views)
    batch = SourceBatch(**dict(zip(INPUT_NAMES, inputs)), views=views)
    with torch.no_grad():
        a_s, a_d, x, *reads = _Encode(net, views)(*inputs)[2:]
        for module in net.feedback_modules()[:step]:
            y, gradients = net.feedback_look(module, batch, a_s, a_d, x)
            case = (a_s, a_d, x, *reads, y, *(gradients or ()))
            a_s, a_d = net.feedback_update(module, a_s, a_d, x, y, *reads, gradients=gradients)
    return case, [t.numpy() for t in (*net._bound(a_s, a_d), a_s, a_d)]


def export_feedback(net: VideoTok4D, directory: str | os.PathLike[str], step: int = 1) -> Path:
    """Write the graph of render feedback pass ``step`` (``feedback.onnx``, ``feedback-p{step}.onnx``; any number
    of encoded cameras) for ``net`` into its model ``directory``; ModelError when ``net`` has no such pass, when the
    directory does not describe it, or when onnxruntime's differ from torch's by more than
    :data:`PARITY_TOLERANCE`."""
    passes = len(net.feedback_modules())
    if not 1 <= step <= passes:
        raise ModelError(f"this model has {passes} render feedback pass(es), not a pass {step}")
    directory = Path(directory)
    meta = _checked_meta(net, directory)
    wrapper = _Feedback(net.eval(), step).eval()
    inputs, _ = _feedback_case(net, step, 2, 0)
    names = feedback_inputs(net.config)
    model = _trace(wrapper, inputs, list(names), list(FEEDBACK_OUTPUTS), {"x": {0: "V"}, "y0": {0: "V"}})

    def check(path: Path) -> None:
        session, _, _ = open_checked(path, meta, fmt=FEEDBACK_FORMAT, inputs=names, outputs=FEEDBACK_OUTPUTS,
                                     what="render feedback")
        for views, seed in ((1, 1), (3, 2)):
            case, want = _feedback_case(net, step, views, seed)
            _parity(session.run(list(FEEDBACK_OUTPUTS), {n: t.numpy() for n, t in zip(names, case)}), want,
                    f"render feedback pass {step} ({views} camera(s))")

    return _finish(model, directory, meta, FEEDBACK_FORMAT, feedback_file(step), {}, check)


# --- the render and its gradient ------------------------------------------------------------------------
def _render_gradient(net: VideoTok4D, views: int) -> Any:
    """``VideoTok4D.feedback_render_gradients`` of one scene of ``views`` cameras as a function of the
    :data:`GRADIENT_INPUTS` tensors -> (y0, g_s, g_d) (:data:`GRADIENT_OUTPUTS`), differentiated by ``torch.func``.
    Every feedback pass renders from the same seed-0 noise, so one graph serves them all (checked)."""
    first, *later = net.feedback_modules()
    if any(not torch.equal(module.noise, first.noise) for module in later):
        raise ModelError("the render feedback passes render from different noise: one render-gradient graph "
                         "cannot serve them")

    def error(z_s: torch.Tensor, z_d: torch.Tensor, x: torch.Tensor, K: torch.Tensor, w2c: torch.Tensor
              ) -> tuple[torch.Tensor, torch.Tensor]:
        # the render reads the cameras and the clip count and length only: x stands for the other fields
        batch = SourceBatch(frames=x, K=K, w2c=w2c, motion_mask=x, track_xy=x, track_valid=x, views=views)
        return net.feedback_render_error(first, batch, z_s, z_d, x)

    gradient = torch.func.grad_and_value(error, argnums=(0, 1), has_aux=True)

    def render_gradient(z_s: torch.Tensor, z_d: torch.Tensor, x: torch.Tensor, K: torch.Tensor, w2c: torch.Tensor
                        ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        (g_s, g_d), (_, y) = gradient(z_s, z_d, x, K, w2c)
        return y, g_s, g_d

    return render_gradient


def _gradient_case(net: VideoTok4D, views: int, seed: int) -> tuple[tuple[torch.Tensor, ...], list[np.ndarray]]:
    """(:data:`GRADIENT_INPUTS` of the first pass on example inputs for ``views`` cameras, torch's
    ``feedback_render_gradients`` of them)."""
    inputs = example_inputs(net, seed=seed, views=views)
    batch = SourceBatch(**dict(zip(INPUT_NAMES, inputs)), views=views)
    with torch.no_grad():
        a_s, a_d, x, _ = net._first_preactivations(batch)
        want = net.feedback_render_gradients(net.feedback_modules()[0], batch, a_s, a_d, x)
    return (*net._bound(a_s, a_d), x.float(), batch.K, batch.w2c), [t.numpy() for t in want]


@contextlib.contextmanager
def _differentiable_trace(net: VideoTok4D) -> Iterator[None]:
    """While a gradient is traced: frozen parameters (the gradient is by the tokens only), no camera value checks
    (a trace cannot branch on values; the inputs are the encoder's own), math attention and :func:`_traceable_linalg`."""
    from torch.nn.attention import SDPBackend, sdpa_kernel

    grads = [p.requires_grad for p in net.parameters()]
    for param in net.parameters():
        param.requires_grad_(False)
    net._check_cameras = lambda *args, **kwargs: None  # type: ignore[method-assign]
    try:
        with _traceable_linalg(), sdpa_kernel(SDPBackend.MATH):
            yield
    finally:
        del net._check_cameras
        for param, grad in zip(net.parameters(), grads):
            param.requires_grad_(grad)


def _trace_gradient(net: VideoTok4D, views: int, example: tuple[torch.Tensor, ...]) -> Any:
    """The render-gradient graph (an ``onnx.ModelProto``) of ``views`` cameras traced on ``example``."""
    import torch._decomp as decomp
    from torch.fx.experimental.proxy_tensor import make_fx

    aten = torch.ops.aten
    table = dict(decomp.core_aten_decompositions())
    table.update(decomp.get_decompositions([aten._softmax, aten._log_softmax]))

    def empty_permuted(size: Any, physical_layout: Any, dtype: Any = None, layout: Any = None, device: Any = None,
                       pin_memory: Any = None) -> torch.Tensor:  # no ONNX form; its values are never read
        return torch.empty(size, dtype=dtype, device=device)

    table[aten.empty_permuted.default] = empty_permuted
    function = _render_gradient(net, views)
    # the weights enter the trace as inputs: as constants, make_fx would run what is done to them (a linear layer's
    # transpose) at trace time and store the results, a copy of the weights that is not model.safetensors'
    weights = {name: param.detach() for name, param in net.named_parameters()}

    def with_weights(values: dict[str, torch.Tensor], *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        with torch.nn.utils.stateless._reparametrize_module(net, values):
            return function(*inputs)

    with _differentiable_trace(net):
        traced = make_fx(with_weights, decomposition_table=table)(weights, *example)

    class Graph(nn.Module):
        """The traced function with the weights as buffers: initializers of the exported graph."""

        def __init__(self) -> None:
            super().__init__()
            self.traced, self.names = traced, list(weights)
            for k, value in enumerate(weights.values()):
                self.register_buffer(f"w{k}", value)

        def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
            values = {name: getattr(self, f"w{k}") for k, name in enumerate(self.names)}
            return tuple(self.traced(values, *inputs))

    loggers = [logging.getLogger(name) for name in ("torch.onnx", "onnxscript", "onnx_ir")]
    levels = [logger.level for logger in loggers]
    try:  # the exporter's progress lines and its notes on torchvision operators this graph never uses
        for logger in loggers:
            logger.setLevel(logging.ERROR)
        with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
            warnings.simplefilter("ignore")
            program = torch.onnx.export(Graph(), example, dynamo=True, input_names=list(GRADIENT_INPUTS),
                                        output_names=list(GRADIENT_OUTPUTS), verbose=False, optimize=False)
    finally:
        for logger, level in zip(loggers, levels):
            logger.setLevel(level)
    import onnx
    import onnxscript.optimizer

    # optimised with the weights as graph inputs: as initializers, the optimiser would fold every transposed weight
    # into a new constant (a copy of the weights in each graph, 7 MB for vt4d-tiny, that _link_weights cannot find)
    model = program.model_proto
    weights_in = list(model.graph.initializer)
    del model.graph.initializer[:]
    inputs = list(model.graph.input)
    model.graph.input.extend(onnx.helper.make_tensor_value_info(w.name, w.data_type, list(w.dims)) for w in weights_in)
    model = onnxscript.optimizer.optimize(model, input_size_limit=FOLD_LIMIT, output_size_limit=FOLD_LIMIT)
    used = {name for node in model.graph.node for name in node.input}
    del model.graph.input[:]
    model.graph.input.extend(inputs)
    model.graph.initializer.extend(w for w in weights_in if w.name in used)
    del model.graph.value_info[:]  # renamed by _compact_names
    del model.graph.metadata_props[:]
    for node in model.graph.node:  # the exporter's notes on each node (stack traces, fx names): 80 % of the bytes
        del node.metadata_props[:]
        node.doc_string = ""
    _fill_uniform_constants(model)
    return model


def export_gradient(net: VideoTok4D, directory: str | os.PathLike[str], views: int = 1) -> Path:
    """Write the render-gradient graph for scenes of ``views`` cameras (``render-gradient.onnx`` for one) of a
    ``feedback_gradient`` model into its model ``directory``; ModelError for a model whose feedback reads no
    gradient, when the directory does not describe ``net``, or when onnxruntime's render differs from torch's by
    more than :data:`PARITY_TOLERANCE` or its gradient by more than :data:`GRADIENT_TOLERANCE` of its scale,
    on captures other than the traced one. Needs ``onnxscript`` (the dynamo exporter)."""
    if not net.config.feedback_gradient:
        raise ModelError("this model's render feedback reads no gradient (config feedback_gradient): it has no "
                         "render-gradient graph")
    _check_views(views)
    if not module_available("onnxscript"):
        raise ModelError("exporting a render-gradient graph needs onnxscript (pip install onnxscript; in the "
                         "'train' extra)")
    directory = Path(directory)
    meta = _checked_meta(net, directory)
    net = net.eval()
    model = _trace_gradient(net, views, _gradient_case(net, views, 0)[0])

    def check(path: Path) -> None:
        session, _, _ = open_checked(path, meta, fmt=GRADIENT_FORMAT, inputs=GRADIENT_INPUTS, outputs=GRADIENT_OUTPUTS,
                                     what="render gradient")
        for seed in (1, 2):
            case, want = _gradient_case(net, views, seed)
            got = session.run(list(GRADIENT_OUTPUTS), {n: t.numpy() for n, t in zip(GRADIENT_INPUTS, case)})
            _parity(got[:1], want[:1], f"render at the encoded cameras ({views} camera(s))")
            scale = max(float(np.abs(w).max()) for w in want[1:])
            error = max(float(np.abs(g - w).max()) for g, w in zip(got[1:], want[1:])) / max(scale, 1e-30)
            if error > GRADIENT_TOLERANCE:
                raise ModelError(f"exported render gradient ({views} camera(s)) differs from torch by {error:.2e} "
                                 f"of its scale (> {GRADIENT_TOLERANCE})")

    return _finish(model, directory, meta, GRADIENT_FORMAT, gradient_file(views), {"vt4d_views": str(views)}, check)


def export_encoder(net: VideoTok4D, directory: str | os.PathLike[str], views: int = 1) -> Path:
    """Write the encoder graph for scenes of ``views`` cameras (``encoder.onnx`` for one) into ``net``'s model
    ``directory`` (whose config.json describes ``net``'s weights) and return its path; ModelError when the
    directory does not describe ``net`` or when onnxruntime's tokens differ from torch's by more than
    :data:`PARITY_TOLERANCE`. A model with render feedback renders with the directory's ``renderer.onnx`` and
    feedback graphs, written first (:func:`export_model` does)."""
    _check_views(views)
    directory = Path(directory)
    meta = _checked_meta(net, directory)
    wrapper = _Encode(net.eval(), views).eval()
    inputs = example_inputs(net, views=views)
    with torch.no_grad():
        reference = [t.numpy() for t in wrapper(*inputs)]
    outputs = list(output_names(net.config))
    model = _trace(wrapper, inputs, list(INPUT_NAMES), outputs)

    def check(path: Path) -> None:
        encoder = OnnxEncoder.from_file(path, meta, views=views)
        arrays = {n: t.numpy() for n, t in zip(INPUT_NAMES, inputs)}
        _parity(encoder.session.run(outputs, arrays), reference, f"encoder ({views} camera(s))")
        if net.feedback is not None:  # and the tokens after the feedback, through the renderer's graph
            with torch.no_grad():
                want = net.encode(SourceBatch(**dict(zip(INPUT_NAMES, inputs)), views=views))
            _parity(list(encoder.encode_arrays(arrays)), [t.numpy() for t in want],
                    f"encoder with render feedback ({views} camera(s))")

    return _finish(model, directory, meta, ONNX_FORMAT, encoder_file(views), {"vt4d_views": str(views)}, check)


# --- the renderer ------------------------------------------------------------------------------------
def _splat_sum_batched(rows: torch.Tensor, values: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
    """``renderer._splat_sum`` for the whole batch at once (its per-item loop would trace the example's batch size):
    (B, T, K, h, w) = sum over n of rows[b, t, n, y] values[b, t, n, k] cols[b, t, n, x]."""
    B, T, N, h = rows.shape
    K = values.shape[-1]
    products = (rows[..., None] * values[:, :, :, None]).reshape(B, T, N, h * K)
    return (products.transpose(2, 3) @ cols).reshape(B, T, h, K, -1).transpose(2, 3)


class _RenderStep(nn.Module):
    """One Euler step of ``VideoTok4D.render_latents`` and the decoded frames of its result: inputs
    :data:`RENDERER_INPUTS`, outputs (y_next = y - v / steps, frames = decode(y_next) clamped to [0, 1]).

    The renderer's per-camera-count index tables (token cameras, frame copies, copy origins, copy resolution,
    dynamic token cameras) are buffers for 1 .. MAX_VIEWS encoded cameras, gathered at the count the source
    cameras input has; its in-place key mask and locality bias are built by concatenation (same values)."""

    def __init__(self, net: VideoTok4D) -> None:
        super().__init__()
        self.net = net
        r, cfg = net.renderer, net.config
        counts = range(1, MAX_VIEWS + 1)
        with torch.no_grad():
            anchored = r.n_anchored > 0 and cfg.project_anchors
            tables = {
                "token_cameras": [r.token_cameras(v) if anchored else torch.zeros(0, dtype=torch.long) for v in counts],
                "copy_frames": [r.copy_frames(v) if anchored else torch.zeros(0, cfg.frames) for v in counts],
                "copy_origin": [r.copy_origin(v) if anchored else torch.zeros(0, dtype=torch.long) for v in counts],
                "copy_resolution": [F.pad(r.copy_resolution(v), (0, MAX_VIEWS - v)) if anchored
                                    else torch.zeros(MAX_VIEWS) for v in counts],
                "dynamic_cameras": [dynamic_token_cameras(cfg.n_dynamic, v) for v in counts],
            }
        self.register_buffer("token_cameras", torch.stack(tables["token_cameras"]).to(torch.int16))
        copy_frames = torch.stack(tables["copy_frames"])  # 0/1, or hat weights with config.copy_blend
        self.register_buffer("copy_frames", copy_frames.float() if cfg.copy_blend else copy_frames.to(torch.uint8))
        self.register_buffer("copy_origin", torch.stack(tables["copy_origin"]).to(torch.int16))
        self.register_buffer("copy_resolution", torch.stack(tables["copy_resolution"]).float())
        self.register_buffer("dynamic_cameras", torch.stack(tables["dynamic_cameras"]).to(torch.int16))

    @contextlib.contextmanager
    def _tables(self, K_src: torch.Tensor) -> Iterator[None]:
        r = self.net.renderer
        at = (torch.ones_like(K_src[0, :, 0, 0]).sum() - 1).long()  # the camera count - 1, as a graph value
        token_cameras, copy_frames = self.token_cameras[at].long(), self.copy_frames[at].float()
        copy_origin, copy_resolution = self.copy_origin[at].long(), self.copy_resolution[at]
        dynamic = self.dynamic_cameras[at].long()
        cfg = r.cfg

        def embed_tokens(z_s: torch.Tensor, z_d: torch.Tensor, drop_static: torch.Tensor, drop_dynamic: torch.Tensor
                         ) -> tuple[torch.Tensor, torch.Tensor]:
            n_s, n_d = z_s.shape[1], z_d.shape[1]
            if not isinstance(drop_static, torch.Tensor):  # the encoder's render feedback: a flag for every item
                drop_static = (torch.ones_like if drop_static else torch.zeros_like)(z_s[:, 0, 0], dtype=torch.bool)
            if not isinstance(drop_dynamic, torch.Tensor):
                drop_dynamic = (torch.ones_like if drop_dynamic else torch.zeros_like)(z_d[:, 0, 0], dtype=torch.bool)
            tokens = r.token_in(torch.cat([z_s, z_d], dim=1).to(r.token_in.weight.dtype)) + r.token_slot[None]
            types = torch.cat([torch.zeros(n_s, dtype=torch.long),
                               torch.full((n_d,), 0 if cfg.unified_tokens else 1, dtype=torch.long)])
            keep = torch.cat([(~drop_static)[:, None].expand(-1, n_s), (~drop_dynamic)[:, None].expand(-1, n_d)], 1)
            return tokens + r.token_type[types][None], keep

        def bias_from_logit(logit: torch.Tensor) -> torch.Tensor:
            B, T, P, na = logit.shape
            heads, near = cfg.heads, locality_heads(cfg.heads)
            top = logit.reshape(B, 1, T * P, na).expand(-1, near, -1, -1)
            top = torch.cat([top, torch.zeros_like(top[..., :1]).expand(-1, -1, -1, cfg.n_static + cfg.n_dynamic - na)],
                            dim=-1)
            return torch.cat([top, torch.zeros_like(top[:, :1]).expand(-1, heads - near, -1, -1)], dim=1)

        patches = {"token_cameras": lambda views: token_cameras, "copy_frames": lambda views: copy_frames,
                   "copy_origin": lambda views: copy_origin, "copy_resolution": lambda views: copy_resolution,
                   "embed_tokens": embed_tokens, "_bias_from_logit": bias_from_logit}
        functions = {"dynamic_token_cameras": lambda n, views, device=None: dynamic}
        if hasattr(renderer_module, "_splat_sum"):  # a loop over the batch in torch (memory): one product here
            functions["_splat_sum"] = _splat_sum_batched
        saved = {name: getattr(renderer_module, name) for name in functions}
        for name, value in patches.items():
            setattr(r, name, value)
        for name, value in functions.items():
            setattr(renderer_module, name, value)
        try:
            yield
        finally:
            for name in patches:
                delattr(r, name)
            for name, value in saved.items():
                setattr(renderer_module, name, value)

    def forward(self, y: torch.Tensor, tau: torch.Tensor, steps: torch.Tensor, z_s: torch.Tensor, z_d: torch.Tensor,
                K_tgt: torch.Tensor, w2c_tgt: torch.Tensor, K_src: torch.Tensor, w2c_src: torch.Tensor,
                drop_static: torch.Tensor, drop_dynamic: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        net = self.net
        with self._tables(K_src):
            cameras = (K_tgt, w2c_tgt, K_src, w2c_src) if net.needs_source else None
            v = net.velocity(y, z_s, z_d, net.rays(K_tgt, w2c_tgt), tau, cameras=cameras, drop_static=drop_static,
                             drop_dynamic=drop_dynamic)
        y_next = y - v / steps
        return y_next, net.autoencoder.decode(y_next).float().clamp(0.0, 1.0)


def _torch_render(net: VideoTok4D, inputs: dict[str, torch.Tensor], steps: int, seed: int) -> np.ndarray:
    """``VideoTok4D.render`` of :func:`example_render_inputs` (cameras given as the encoded cameras' middle frames)."""
    source = (inputs["K_src"][:, :, None], inputs["w2c_src"][:, :, None])
    with torch.no_grad():
        return net.render(inputs["z_s"], inputs["z_d"], inputs["K_tgt"], inputs["w2c_tgt"], steps=steps, seed=seed,
                          source=source).numpy()


def export_renderer(net: VideoTok4D, directory: str | os.PathLike[str]) -> Path:
    """Write ``renderer.onnx`` for ``net`` into its model ``directory`` and return its path; ModelError when the
    directory does not describe ``net`` or when onnxruntime's frames (``OnnxRenderer.render``, seeded noise and
    the Euler loop included) differ from ``VideoTok4D.render``'s by more than :data:`PARITY_TOLERANCE`."""
    directory = Path(directory)
    meta = _checked_meta(net, directory)
    wrapper = _RenderStep(net.eval()).eval()
    inputs = example_render_inputs(net)
    dynamic = {"y": {0: "B", 1: "T"}, "tau": {0: "B"}, "z_s": {0: "B"}, "z_d": {0: "B"}, "K_tgt": {0: "B", 1: "T"},
               "w2c_tgt": {0: "B", 1: "T"}, "K_src": {0: "B", 1: "V"}, "w2c_src": {0: "B", 1: "V"},
               "drop_static": {0: "B"}, "drop_dynamic": {0: "B"}, "y_next": {0: "B", 1: "T"}, "frames": {0: "B", 1: "T"}}
    model = _trace(wrapper, tuple(inputs[n] for n in RENDERER_INPUTS), list(RENDERER_INPUTS), list(RENDERER_OUTPUTS),
                   dynamic)

    def check(path: Path) -> None:
        renderer = OnnxRenderer.from_file(path, meta)
        for views, frames, cameras, steps, seed in ((2, None, 3, 1, 0), (1, 3, 1, 2, 5)):
            case = example_render_inputs(net, views=views, frames=frames, cameras=cameras, seed=seed + 1)
            got = renderer.render(*(case[n].numpy() for n in ("z_s", "z_d", "K_tgt", "w2c_tgt", "K_src", "w2c_src")),
                                  steps=steps, seed=seed)
            _parity([got], [_torch_render(net, case, steps, seed)], "renderer")

    return _finish(model, directory, meta, RENDERER_FORMAT, RENDERER_FILE, {}, check)


# --- the prior ---------------------------------------------------------------------------------------
class _PriorCondition(nn.Module):
    """``Co4DGen.encode_condition`` and the token normalisation its sampler undoes (outputs CONDITION_OUTPUTS)."""

    def __init__(self, prior: Any) -> None:
        super().__init__()
        self.prior = prior

    def forward(self, frames: torch.Tensor, K_c: torch.Tensor, w2c_c: torch.Tensor, K_a: torch.Tensor,
                w2c_a: torch.Tensor, *tokens: torch.Tensor) -> tuple[torch.Tensor, ...]:
        p = self.prior
        h = p.cond_encoder(frames, K_c, w2c_c, K_a, w2c_a)
        out = (h, p.static_mean * 1.0, p.static_std * 1.0, p.dynamic_mean * 1.0, p.dynamic_std * 1.0)  # as outputs
        return out if not tokens else (*out, *p.token_features(tokens[0], tokens[1], w2c_a, w2c_c))


class _PriorVelocity(nn.Module):
    def __init__(self, prior: Any) -> None:
        super().__init__()
        self.prior = prior

    def forward(self, x_s: torch.Tensor, x_d: torch.Tensor, h: torch.Tensor, tau: torch.Tensor, *tokens: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        return self.prior.velocity(x_s, x_d, h, tau, (tokens[0], tokens[1], tokens[2]) if tokens else None)


def _prior_condition(prior: Any, seed: int) -> tuple[torch.Tensor, ...]:
    """An example condition: V_c, P_c, P_a, and Z^c (tokens in (-0.9, 0.9)) for a prior with ``cond_tokens``."""
    cfg = prior.config
    g = torch.Generator().manual_seed(seed)
    case = (torch.rand(1, cfg.frames, 3, cfg.image_size, cfg.image_size, generator=g),
            *_orbit(1, cfg.frames, cfg.image_size, 0.1 * seed), *_orbit(1, cfg.frames, cfg.image_size, -0.2))
    if not cfg.cond_tokens:
        return case
    return (*case, (torch.rand(1, cfg.n_static, cfg.token_dim, generator=g) - 0.5) * 1.8,
            (torch.rand(1, cfg.n_dynamic, cfg.token_dim, generator=g) - 0.5) * 1.8)


def export_prior(prior: Any, directory: str | os.PathLike[str]) -> list[Path]:
    """Write ``prior-condition.onnx`` and ``prior-velocity.onnx`` for the Co4DGen ``prior`` into its prior
    ``directory`` and return their paths; ModelError when the directory does not describe ``prior`` or when
    ``OnnxPrior.sample``'s tokens differ from ``Co4DGen.sample``'s by more than :data:`PARITY_TOLERANCE`."""
    from .configs import PriorConfig  # noqa: F401  (the prior's config type, read by read_prior_meta)
    from .directories import PRIOR_WEIGHTS_FILE, read_prior_meta
    from .identity import weights_sha256
    from .onnx_prior import PRIOR_CONDITION_FILE, PRIOR_ONNX_FORMAT, PRIOR_VELOCITY_FILE, OnnxPrior, graph_io
    from .prior import TOKEN_LIMIT, PriorCondition

    directory = Path(directory)
    meta = read_prior_meta(directory)
    if (weights_sha256(prior.state_dict()), prior.config.sha256()) != (meta["weights_sha256"], meta["config_sha256"]):
        raise ModelError(f"{directory} describes other weights than the prior given")
    prior = prior.eval()
    cfg = prior.config
    net = prior.sampling_network()  # the graphs compute in the sampler's float64, as Co4DGen.sample does
    dtype = net.static_mean.dtype
    condition = tuple(t.to(dtype) for t in _prior_condition(prior, 0))
    with torch.no_grad():
        outputs = _PriorCondition(net)(*condition)
        h = outputs[0]
    velocity_inputs = (torch.randn(1, cfg.n_static, cfg.token_dim, dtype=dtype),
                       torch.randn(1, cfg.n_dynamic, cfg.token_dim, dtype=dtype), h, torch.ones(1, dtype=dtype),
                       *outputs[5:])
    (cond_in, cond_out), (vel_in, vel_out) = graph_io(cfg)
    graphs = [(PRIOR_CONDITION_FILE, _PriorCondition(net), condition, cond_in, cond_out),
              (PRIOR_VELOCITY_FILE, _PriorVelocity(net), velocity_inputs, vel_in, vel_out)]
    extra = {"vt4d_token_limit": repr(TOKEN_LIMIT)}
    paths = [_finish(_trace(module.eval(), inputs, list(input_names), list(output_names)), directory, meta,
                     PRIOR_ONNX_FORMAT, name, extra, lambda path: None, weights=PRIOR_WEIGHTS_FILE)
             for name, module, inputs, input_names, output_names in graphs]
    try:  # the whole sampler, once both graphs are in place (OnnxPrior opens them there)
        exported = OnnxPrior.open(directory)
        for seed, steps, method in ((1, 2, "heun"), (2, 3, "euler")):
            case = _prior_condition(prior, seed)
            with torch.no_grad():
                want = prior.sample(PriorCondition(*case), steps=steps, seed=seed, method=method)
            tokens = dict(zip(("z_s", "z_d"), (t.numpy() for t in case[5:])))
            got = exported.sample(*(t.numpy() for t in case[:5]), steps=steps, seed=seed, method=method, **tokens)
            _parity(list(got), [t.numpy() for t in want], "prior")
    except BaseException:
        for path in paths:
            path.unlink(missing_ok=True)
        raise
    return paths


def export_model(net: VideoTok4D, directory: str | os.PathLike[str], *, views: int = EXPORT_VIEWS) -> list[Path]:
    """Every graph of :mod:`this module <vt4dcodec.model.onnx_export>`: the encoders for 1 .. ``views`` cameras,
    the renderer and, for a model with render feedback, ``feedback.onnx`` (and one graph per further pass) and, where
    the feedback reads the render's gradient, the render-gradient graphs for 1 .. ``views`` cameras; returns their
    paths. The encoders come last: their parity check runs the feedback through the graphs before them."""
    paths = [export_renderer(net, directory)]
    if net.config.feedback_gradient:
        paths += [export_gradient(net, directory, v) for v in range(1, views + 1)]
    paths += [export_feedback(net, directory, k) for k in range(1, len(net.feedback_modules()) + 1)]
    return paths + [export_encoder(net, directory, v) for v in range(1, views + 1)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m vt4dcodec.model.onnx_export", description=__doc__.split("\n\n")[0])
    parser.add_argument("model", help="a shipped model id or a model directory (a tokenizer's, or a prior's)")
    parser.add_argument("--views", type=int, default=EXPORT_VIEWS,
                        help=f"encoder (and render-gradient) graphs for scenes of 1 .. VIEWS cameras (default "
                             f"{EXPORT_VIEWS})")
    args = parser.parse_args(argv)
    try:
        from .directories import PRIOR_META_FILE, shipped_prior_ids

        if args.model in shipped_prior_ids() or (Path(args.model) / PRIOR_META_FILE).is_file():
            from .weights_io import load_prior

            directory = model_directory(args.model, PRIOR_META_FILE)
            paths = export_prior(load_prior(directory), directory)
        else:
            directory = model_directory(args.model)
            paths = export_model(from_pretrained(directory), directory, views=args.views)
    except ModelError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for path in paths:
        print(f"wrote {path} ({path.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
