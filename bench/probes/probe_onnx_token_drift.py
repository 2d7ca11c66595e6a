"""Where do the onnxruntime encoder's tokens leave torch's, in a model with render feedback?

A built model directory (its exported graphs beside its weights: ``python -m vt4dcodec.model.train.ship`` or
``python -m vt4dcodec.model.onnx_export DIR``) encodes the parity test's capture (tests/codec/test_onnx_parity.py:
test scene 3, 10 cameras, 8 frames at 64 x 64) with ``--views`` cameras in both runtimes, and the difference is
followed pass by pass:

* the first pass's pre-activations A^0 (the encoder graph against ``VideoTok4D._first_preactivations``);
* each pass's look (the render-gradient graph's render Y and gradients g against torch's), fed the tokens each
  runtime has so far, and fed torch's exact tokens (the graph's own error);
* each pass's update, and the same feedback graph fed torch's inputs (its own rounding);
* the onnxruntime chain of passes started from torch's exact A^0 (what the passes add), and torch's chain
  started from onnxruntime's A^0 (what the passes amplify of the first pass's difference);
* that amplification again with a chosen pass's gradient MLPs or window MLPs switched off (``--off``), which
  says which read of which pass carries it.

``python bench/probes/probe_onnx_token_drift.py DIR --views 10 --out F.json``; the token tolerance is issue 51's 2e-6.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path

import numpy as np
import torch

from vt4dcodec import codec
from vt4dcodec.model.inputs.source_inputs import SourceBatch
from vt4dcodec.model.onnx_encoder import (FEEDBACK_OUTPUTS, FEEDBACK_STATE, FIRST_PASS_NAMES, GRADIENT_INPUTS,
                                          GRADIENT_OUTPUTS, INPUT_NAMES, OnnxEncoder, feedback_inputs)
from vt4dcodec.model.weights_io import from_pretrained
from vt4dcodec.synth import SynthConfig, generate_scene


def _diff(a: object, b: torch.Tensor) -> float:
    return float(np.abs(np.asarray(a, np.float64) - b.double().numpy()).max())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("model", help="a model directory with its exported graphs")
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--off", default="1:grad,1:window,0:grad",
                        help="comma-separated PASS:grad|window (0-based) to switch off for the amplification rows")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args(argv)
    torch.set_num_threads(2)
    capture = generate_scene(3, split="test", config=SynthConfig(num_cameras=10, num_frames=8, height=64,
                                                                 width=64)).capture
    names = capture.camera_names[:args.views]
    encoder = OnnxEncoder.open(args.model, views=args.views)
    if not encoder.config.feedback_width:
        sys.exit("this probe follows render feedback passes; the model has none")
    grabbed: dict[str, dict[str, np.ndarray]] = {}
    run_arrays = encoder.encode_arrays

    def grab(arrays: dict[str, np.ndarray], feedback: bool = True) -> tuple[np.ndarray, np.ndarray]:
        grabbed["arrays"] = arrays
        return run_arrays(arrays, feedback)

    encoder.encode_arrays = grab  # type: ignore[method-assign]
    got = codec.encode(capture, encoder, cameras=names, seed=1)
    net = from_pretrained(args.model).eval()
    want = codec.encode(capture, net, cameras=names, seed=1, runtime="torch")
    arrays = grabbed["arrays"]
    batch = SourceBatch(**{n: torch.from_numpy(np.ascontiguousarray(arrays[n])) for n in INPUT_NAMES},
                        views=args.views)
    report: dict[str, object] = {"model": str(args.model), "views": args.views,
                                 "tokens": {"z_s": float(np.abs(got.static_tokens - want.static_tokens).max()),
                                            "z_d": float(np.abs(got.dynamic_tokens - want.dynamic_tokens).max())}}
    cfg = encoder.config
    sessions, gradient_graph = encoder._feedback  # type: ignore[misc]
    if not cfg.feedback_gradient:
        sys.exit("this probe follows the render-gradient graph; the model's feedback reads no gradient")
    z_s, z_d, *state = encoder.session.run(list(FIRST_PASS_NAMES + FEEDBACK_STATE), {n: arrays[n] for n in INPUT_NAMES})
    onnx_first = (torch.from_numpy(state[0]), torch.from_numpy(state[1]))
    with torch.no_grad():
        a_s, a_d, x, chosen = net._first_preactivations(batch)
        torch_first = (a_s, a_d)
        report["first_pass"] = {"a_s": _diff(state[0], a_s), "a_d": _diff(state[1], a_d),
                                "max_abs_a_s": float(a_s.abs().max())}
        reads = net.feedback_reads(batch, chosen)
        passes = []
        for k, (module, session) in enumerate(zip(net.feedback_modules(), sessions)):
            y, (g_s, g_d) = net.feedback_look(module, batch, a_s, a_d, x)
            looked = gradient_graph.run(list(GRADIENT_OUTPUTS), dict(zip(GRADIENT_INPUTS, (
                z_s, z_d, state[2], arrays["K"], arrays["w2c"]))))
            exact = [t.numpy() for t in net._bound(a_s, a_d)]
            own = gradient_graph.run(list(GRADIENT_OUTPUTS), dict(zip(GRADIENT_INPUTS, (
                *exact, state[2], arrays["K"], arrays["w2c"]))))
            new_s, new_d = net.feedback_update(module, a_s, a_d, x, y, *reads, gradients=(g_s, g_d))
            out = session.run(list(FEEDBACK_OUTPUTS), dict(zip(feedback_inputs(cfg), (*state, *looked))))
            fed = list(state)
            fed[:2] = [a_s.numpy(), a_d.numpy()]
            alone = session.run(list(FEEDBACK_OUTPUTS), dict(zip(feedback_inputs(cfg), (
                *fed, y.numpy(), g_s.numpy(), g_d.numpy()))))
            passes.append({"pass": k + 1, "y": _diff(looked[0], y), "g_s": _diff(looked[1], g_s),
                           "g_d": _diff(looked[2], g_d), "max_abs_g_s": float(g_s.abs().max()),
                           "rms_g_s": float(g_s.square().mean().sqrt()),
                           "graph_own": {"y": _diff(own[0], y), "g_s": _diff(own[1], g_s), "g_d": _diff(own[2], g_d)},
                           "a_s_after": _diff(out[2], new_s), "a_d_after": _diff(out[3], new_d),
                           "update_own": {"a_s": _diff(alone[2], new_s), "a_d": _diff(alone[3], new_d)}})
            z_s, z_d, state[0], state[1] = out
            a_s, a_d = new_s, new_d
        report["passes"] = passes
        final = net._bound(a_s, a_d)

        def chain_from(model: object, first: tuple[torch.Tensor, torch.Tensor]) -> dict[str, float]:
            b_s, b_d = model._bound(*model._feedback(batch, x, *first, chosen))  # type: ignore[attr-defined]
            r_s, r_d = model._bound(*model._feedback(batch, x, *torch_first, chosen))  # type: ignore[attr-defined]
            return {"z_s": float((b_s - r_s).abs().max()), "z_d": float((b_d - r_d).abs().max())}

        report["torch_chain_from_onnx_first_pass"] = chain_from(net, onnx_first)
        for item in filter(None, args.off.split(",")):
            k, what = item.split(":")
            variant = copy.deepcopy(net)
            module = variant.feedback_modules()[int(k)]
            for mlp in ((module.static_grad, module.dynamic_grad) if what == "grad" else (module.static, module.dynamic)):
                mlp[2].weight.data.zero_()
                mlp[2].bias.data.zero_()
            report[f"torch_chain_from_onnx_first_pass_pass{int(k) + 1}_{what}_off"] = chain_from(variant, onnx_first)
    # the onnxruntime chain from torch's exact first pass
    z_s, z_d = (t.numpy() for t in net._bound(*torch_first))
    state[0], state[1] = (t.numpy() for t in torch_first)
    for session in sessions:
        looked = gradient_graph.run(list(GRADIENT_OUTPUTS), dict(zip(GRADIENT_INPUTS, (
            z_s, z_d, state[2], arrays["K"], arrays["w2c"]))))
        z_s, z_d, state[0], state[1] = session.run(list(FEEDBACK_OUTPUTS), dict(zip(feedback_inputs(cfg),
                                                                                  (*state, *looked))))
    report["onnx_chain_from_torch_first_pass"] = {"z_s": _diff(z_s, final[0]), "z_d": _diff(z_d, final[1])}
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        args.out.write_text(text + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
