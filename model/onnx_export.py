"""Export a model directory's encoder to ``encoder.onnx`` (read by ``model.onnx_encoder``).

    python -m vt4dcodec.model.onnx_export MODEL   # a shipped id or a model directory

The graph is ``VideoTok4D.encode`` for one source camera, traced with torch's TorchScript-based ONNX
exporter (opset 17) on example inputs of the model's shapes; every shape in it is static (the Temporal
Branch's masked spatial attention runs on the whole latent grid with keys restricted to the mask instead
of gathering the masked pixels, the same attention).  Float32 initializers whose values are exactly
float16 (all weights of a model stored in float16) are stored as float16 with a Cast, halving the file
without changing a value.  The export is checked before it is written: onnxruntime's tokens on the
example inputs must match torch's within 1e-4.  Needs the ``onnx`` package (the ``test`` extra has it).
"""

from __future__ import annotations

import argparse
import io
import os
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from vt4dcodec.errors import ModelError

from .directories import model_directory, read_model_meta
from .inputs.source_inputs import SourceBatch
from .onnx_encoder import INPUT_NAMES, ONNX_FILE, ONNX_FORMAT, OUTPUT_NAMES, OnnxEncoder
from .videotok4d import VideoTok4D
from .weights_io import from_pretrained

__all__ = ["export_encoder", "example_inputs", "PARITY_TOLERANCE"]

PARITY_TOLERANCE = 1e-4  # max |token difference| between onnxruntime and torch on the example inputs
OPSET = 17


class _Encode(nn.Module):
    """``VideoTok4D.encode`` of one camera per scene, taking the :class:`SourceBatch` fields as tensors."""

    def __init__(self, net: VideoTok4D) -> None:
        super().__init__()
        self.net = net

    def forward(self, frames: torch.Tensor, K: torch.Tensor, w2c: torch.Tensor, motion_mask: torch.Tensor,
                track_xy: torch.Tensor, track_valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.net.encode(SourceBatch(frames=frames, K=K, w2c=w2c, motion_mask=motion_mask,
                                           track_xy=track_xy, track_valid=track_valid))


def example_inputs(net: VideoTok4D, seed: int = 0) -> tuple[torch.Tensor, ...]:
    """Inputs of one clip of the model's shapes: random frames, an orbiting camera 3 m from the origin, a
    random motion mask (20 % of the cells) and random tracks (70 % valid)."""
    cfg = net.config
    g = torch.Generator().manual_seed(seed)
    T, H, h, N = cfg.frames, cfg.image_size, cfg.latent_size, cfg.n_tracks
    K = torch.tensor([[H, 0.0, H / 2], [0.0, H, H / 2], [0.0, 0.0, 1.0]]).expand(1, T, 3, 3).contiguous()
    w2c = torch.eye(4).repeat(1, T, 1, 1)
    angle = torch.linspace(0.0, 0.3, T)
    w2c[0, :, 0, 0], w2c[0, :, 0, 2] = torch.cos(angle), torch.sin(angle)
    w2c[0, :, 2, 0], w2c[0, :, 2, 2] = -torch.sin(angle), torch.cos(angle)
    w2c[0, :, 2, 3] = 3.0
    return (torch.rand(1, T, 3, H, H, generator=g), K, w2c,
            (torch.rand(1, T, h, h, generator=g) < 0.2).float(),
            torch.rand(1, N, T, 2, generator=g) * (h - 1),
            torch.rand(1, N, T, generator=g) < 0.7)


def _store_exact_float16(model: Any) -> int:
    """Rewrite the float32 initializers of an ``onnx.ModelProto`` whose values are all exactly float16 as
    float16 + Cast; returns the number rewritten."""
    import onnx
    from onnx import helper, numpy_helper

    graph, casts, kept, count = model.graph, [], [], 0
    for init in graph.initializer:
        value = numpy_helper.to_array(init)
        if value.dtype == np.float32 and value.size >= 16 and np.array_equal(value.astype(np.float16).astype(np.float32), value):
            half = numpy_helper.from_array(value.astype(np.float16), init.name + "__f16")
            kept.append(half)
            casts.append(helper.make_node("Cast", [half.name], [init.name], to=onnx.TensorProto.FLOAT,
                                          name=init.name + "__cast"))
            count += 1
        else:
            kept.append(init)
    del graph.initializer[:]
    graph.initializer.extend(kept)
    nodes = casts + list(graph.node)
    del graph.node[:]
    graph.node.extend(nodes)
    return count


def export_encoder(net: VideoTok4D, directory: str | os.PathLike[str]) -> Path:
    """Write ``encoder.onnx`` for ``net`` into its model ``directory`` (whose config.json describes ``net``'s
    weights) and return its path; ModelError when the directory does not describe ``net`` or when
    onnxruntime's tokens differ from torch's by more than :data:`PARITY_TOLERANCE`."""
    import onnx

    directory = Path(directory)
    meta = read_model_meta(directory)
    fingerprint = net.fingerprint(meta["model_id"], meta["model_version"])
    if (fingerprint.weights_sha256, fingerprint.config_sha256) != (meta["weights_sha256"], meta["config_sha256"]):
        raise ModelError(f"{directory} describes other weights than the model given")
    net = net.eval()
    wrapper = _Encode(net).eval()
    inputs = example_inputs(net)
    buffer = io.BytesIO()
    with torch.no_grad():
        reference = [t.numpy() for t in wrapper(*inputs)]
        with warnings.catch_warnings():  # the tracer's notes on shape constants: every shape here is static
            warnings.simplefilter("ignore")
            torch.onnx.export(wrapper, inputs, buffer, dynamo=False, opset_version=OPSET,
                              input_names=list(INPUT_NAMES), output_names=list(OUTPUT_NAMES))
    model = onnx.load_from_string(buffer.getvalue())
    _store_exact_float16(model)
    for key, value in (("vt4d_format", ONNX_FORMAT), ("vt4d_weights_sha256", meta["weights_sha256"]),
                       ("vt4d_config_sha256", meta["config_sha256"]), ("vt4d_views", "1"),
                       ("vt4d_model", f"{meta['model_id']} {meta['model_version']}")):
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.checker.check_model(model)
    target = directory / ONNX_FILE
    with tempfile.TemporaryDirectory(dir=directory) as tmp:  # check the file before it replaces any old one
        candidate = Path(tmp) / ONNX_FILE
        onnx.save(model, str(candidate))
        encoder = OnnxEncoder.from_file(candidate, meta)
        feed = {name: t.numpy() for name, t in zip(INPUT_NAMES, inputs)}
        got = encoder.session.run(list(OUTPUT_NAMES), feed)
        error = max(float(np.abs(a - b).max()) for a, b in zip(got, reference))
        if error > PARITY_TOLERANCE:
            raise ModelError(f"exported encoder differs from torch by {error:.2e} (> {PARITY_TOLERANCE})")
        os.replace(candidate, target)
    return target


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m vt4dcodec.model.onnx_export", description=__doc__.split("\n\n")[0])
    parser.add_argument("model", help="a shipped model id or a model directory")
    args = parser.parse_args(argv)
    try:
        directory = model_directory(args.model)
        path = export_encoder(from_pretrained(directory), directory)
    except ModelError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
