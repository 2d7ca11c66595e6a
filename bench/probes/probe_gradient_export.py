#!/usr/bin/env python
"""Can the render gradient that ``feedback_gradient`` reads run without torch? The gradient of a feedback
model's render error sum (x - Y)^2 by its tokens, d/dZ of the decoder's render at the encoded cameras, traced
to aten operations (``torch.func.grad`` under ``make_fx``, attention on its math kernel, decompositions for the
operators the ONNX exporters lack) and written by torch's dynamo ONNX exporter (needs the ``onnxscript``
package); then run on onnxruntime beside torch's autograd, on the example capture it was traced on and on
other captures (the trace bakes the camera count and any data-dependent branch, so fresh inputs check it).

    python bench/probes/probe_gradient_export.py [--model runs/gf1/model] [--views 1] [--out FILE.json]

Prints and writes the export time, the graph's size (weights inside), the largest gradient difference against
torch's relative to the gradient's largest value, and one-thread wall times of both.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from vt4dcodec import codec  # noqa: E402
from vt4dcodec.model import onnx_export  # noqa: E402
from vt4dcodec.model.videotok4d import SourceBatch  # noqa: E402

NAMES = ("z_s", "z_d", "K", "w2c", "K_src", "w2c_src", "x")


def case(net, views: int, seed: int) -> tuple[tuple[torch.Tensor, ...], tuple[torch.Tensor, torch.Tensor]]:
    """(The gradient's inputs for example capture ``seed``: first-pass tokens, cameras, source latents; and
    ``VideoTok4D.feedback_render_gradients``' gradients of the same, what the feedback reads)."""
    inputs = onnx_export.example_inputs(net, seed=seed, views=views)
    batch = SourceBatch(**dict(zip(onnx_export.INPUT_NAMES, inputs)), views=views)
    with torch.no_grad():
        a_s, a_d, x, _ = net._first_preactivations(batch)
        _, g_s, g_d = net.feedback_render_gradients(net.feedback, batch, a_s, a_d, x)
    z_s, z_d = net._bound(a_s, a_d)
    K_src, w2c_src = batch.source
    return (z_s.repeat_interleave(views, 0), z_d.repeat_interleave(views, 0), batch.K, batch.w2c,
            K_src.repeat_interleave(views, 0), w2c_src.repeat_interleave(views, 0), x.float()), (g_s, g_d)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default="runs/gf1/model")
    p.add_argument("--views", type=int, default=1)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args()
    import onnxruntime as ort
    import torch._decomp as decomp
    from torch.fx.experimental.proxy_tensor import make_fx
    from torch.nn.attention import SDPBackend, sdpa_kernel

    torch.set_num_threads(1)
    aten = torch.ops.aten
    net = codec.load_model(args.model).eval()
    for param in net.parameters():
        param.requires_grad_(False)
    noise = net.feedback.noise[:, :net.config.frames]

    render = type(net).render_latents.__wrapped__  # the decoder's integration, with gradients

    def error(zs, zd, K, w2c, K_src, w2c_src, x):
        return (x - render(net, zs, zd, K, w2c, source=(K_src, w2c_src), noise=noise)).square().sum()

    gradient = torch.func.grad(error, argnums=(0, 1))
    table = dict(decomp.core_aten_decompositions())
    table.update(decomp.get_decompositions([aten._softmax, aten._log_softmax]))
    table[aten.empty_permuted.default] = lambda size, physical_layout, dtype=None, layout=None, device=None, \
        pin_memory=None: torch.empty(size, dtype=dtype, device=device)
    example = case(net, args.views, 0)[0]
    start = time.perf_counter()
    check_cameras = net._check_cameras
    net._check_cameras = lambda *a, **k: None  # type: ignore[method-assign]  # value checks cannot be traced
    with onnx_export._traceable_linalg(), sdpa_kernel(SDPBackend.MATH):
        traced = make_fx(gradient, decomposition_table=table)(*example)
    net._check_cameras = check_cameras  # type: ignore[method-assign]

    class Graph(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.traced = traced

        def forward(self, *inputs):
            return tuple(self.traced(*inputs))

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "gradient.onnx")
        torch.onnx.export(Graph(), example, dynamo=True, input_names=list(NAMES),
                          output_names=["g_s", "g_d"]).save(path)
        export_s = time.perf_counter() - start
        size = os.path.getsize(path)
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        session = ort.InferenceSession(path, options)
        rows = []
        for seed in (0, 1, 2, 3):
            inputs, reference = case(net, args.views, seed)
            start = time.perf_counter()
            want = gradient(*inputs)
            torch_s = time.perf_counter() - start
            if args.views == 1:  # one camera: the scene's gradient is the clip's
                same = max(float((w - r).abs().max()) for w, r in zip(want, reference))
                assert same < 1e-4, f"the traced function is not feedback_render_gradients ({same:.2e})"
            feed = {n: t.detach().numpy() for n, t in zip(NAMES, inputs)}
            session.run(None, feed)  # warm
            start = time.perf_counter()
            got = session.run(None, feed)
            onnx_s = time.perf_counter() - start
            scale = max(float(w.abs().max()) for w in want)
            diff = max(float(np.abs(g - w.numpy()).max()) for g, w in zip(got, want))
            rows.append({"seed": seed, "max_abs_diff": diff, "gradient_max": scale, "relative": diff / scale,
                         "torch_s": round(torch_s, 3), "onnx_s": round(onnx_s, 3)})
            print(rows[-1])
    result = {"model": args.model, "views": args.views, "export_s": round(export_s, 1), "graph_bytes": size,
              "nodes": len(traced.graph.nodes), "cases": rows, "torch": torch.__version__, "onnxruntime": ort.__version__,
              "command": "python bench/probes/probe_gradient_export.py " + " ".join(sys.argv[1:])}
    print(json.dumps({k: v for k, v in result.items() if k != "cases"}))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
