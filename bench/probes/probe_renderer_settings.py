#!/usr/bin/env python
"""The same trained weights under renderer settings that add no weights, on the evaluation's target sets.

    python bench/probes/probe_renderer_settings.py RUN_OR_MODEL --set view_gate_deg=20,40,70 [--scenes 8]
        [--first-seed 0] [--sets source,near,far,multi-enc,multi-held] [--threads 1] [--out FILE.json]

For each value of the field given by ``--set`` (``view_gate_deg``, ``frame_gate_deg``, ``spread_views``,
``pixel_splat``, ``patch_gate_deg``, ``dynamic_gate_deg``, ``dynamic_gate_copies``: config fields that change how the renderer places
or weighs the tokens, not its weights) and for the model as it is, the model is re-configured with the same
weights (``model.train.ship.reconfigure``), saved to a temporary directory and evaluated by ``python -m
vt4dcodec.eval`` (held-out 10-camera scenes, int8 tokens, the model's decode steps, ``--methods ours``). Mean
PSNR dB / SSIM per target set and setting. Prints one JSON line and writes it to ``--out``. To choose a
setting without looking at the 50 evaluation scenes (test seeds 0-49), probe other test seeds:
``--first-seed 100``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from vt4dcodec.eval.command import main as evaluate
from vt4dcodec.eval.command import resolve_model
from vt4dcodec.model.train.common import parse_overrides
from vt4dcodec.model.train.ship import reconfigure
from vt4dcodec.model.weights_io import save_pretrained


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", help="a training run directory, a shipped id or a model directory")
    parser.add_argument("--set", required=True, metavar="FIELD=V1,V2,...", help="one config field and its values")
    parser.add_argument("--scenes", type=int, default=8)
    parser.add_argument("--first-seed", type=int, default=0, help="first held-out scene seed")
    parser.add_argument("--sets", default="source,near,far,multi-enc,multi-held")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    field, _, values = args.set.partition("=")
    if not values:
        raise SystemExit("--set: give FIELD=V1,V2,...")
    model = resolve_model(args.model)
    settings = {"as is": model}
    for value in values.split(","):
        settings[f"{field}={value}"] = reconfigure(model, parse_overrides([f"{field}={value}"]))
    result: dict = {"model": args.model, "scenes": args.scenes, "first_seed": args.first_seed, "settings": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for name, net in settings.items():
            directory = Path(tmp) / f"m{len(result['settings'])}"
            save_pretrained(net, directory, model_id="probe", model_version="0.0.0",
                            decode_steps=getattr(model, "decode_steps", 1))
            out = Path(tmp) / "eval.json"
            evaluate(["--model", str(directory), "--scenes", str(args.scenes), "--first-seed", str(args.first_seed),
                      "--views", "3", "--sets", args.sets,
                      "--methods", "ours", "--threads", str(args.threads), "--no-progress", "--out", str(out)])
            by_set = json.loads(out.read_text())["summary_by_set"]
            result["settings"][name] = {s: [round(v["ours"]["psnr"]["mean"], 3), round(v["ours"]["ssim"]["mean"], 3)]
                                        for s, v in by_set.items() if "ours" in v}
    print(json.dumps(result))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
