"""Export a training run's latest checkpoint as a model directory the codec, the benchmarks and the
evaluation load (``--model DIR``), without shipping it: the entropy tables frozen (``update_entropy``; a
``--stored-levels`` run keeps the tables of the model it started from, which its renderer learned), the
renderer's decode steps of the run kept, and config fields that add no weights changed on the way -- the
writer's rounding offsets (``entropy_rounding``), for one.

    python -m vt4dcodec.model.train.export_run --run checkpoints/vt4d-tiny-2.0-rd8q --out runs/rd8q-dz-model \\
        --version 2.0.0-dev.q593dz --set 'entropy_rounding=[0.45,0.2,0.45, ...]'
"""

from __future__ import annotations

import argparse
from pathlib import Path

from vt4dcodec.errors import ModelError

from ..weights_io import save_pretrained
from .common import model_from_run, parse_overrides
from .ship import reconfigure


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m vt4dcodec.model.train.export_run", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, required=True, help="training run directory (holds checkpoint/)")
    parser.add_argument("--out", type=Path, required=True, help="model directory to write")
    parser.add_argument("--id", default="vt4d-tiny", help="model id recorded in the model")
    parser.add_argument("--version", required=True, help="model version recorded in the model")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="config fields to change that add no weights (JSON values), e.g. entropy_rounding=[...]")
    args = parser.parse_args(argv)
    try:
        overrides = parse_overrides(args.set)
        model, state = model_from_run(args.run)
        if overrides:
            model = reconfigure(model, overrides)
    except ModelError as exc:
        parser.error(f"--run / --set: {exc}")
    if not state.get("args", {}).get("stored_levels"):  # a --stored-levels run trained on its init's frozen tables
        model.update_entropy()
    out = save_pretrained(model, args.out, model_id=args.id, model_version=args.version)
    print(f"exported {args.run} (step {state.get('step')}) -> {out} (decode steps {model.decode_steps})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
