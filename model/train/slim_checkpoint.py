"""Commit a run that trained part of a saved model: its checkpoint without the tensors the base model holds.

    python -m vt4dcodec.model.train.slim_checkpoint --run runs/e1 --base vt4d-tiny \
        --out checkpoints/vt4d-tiny-2.0-e1

A run trained with ``train.tokenizer --train-only entropy.`` changes ~170 KB of a 17 MB checkpoint; the slim
copy keeps those tensors and names the base (``state.json`` ``"base"``: the model and a SHA-256 of the tensors
taken from it). ``train.tokenizer --out OUT`` resumes from it, and ``export_run --run OUT`` exports it, on any
machine whose base model has the same weights.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vt4dcodec.errors import ModelError

from .common import slim_checkpoint


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", type=Path, required=True, help="a training run directory (its latest checkpoint)")
    p.add_argument("--base", required=True, help="the saved model (id or directory) the run started from")
    p.add_argument("--out", type=Path, required=True, help="run directory to write (e.g. under checkpoints/)")
    args = p.parse_args(argv)
    try:
        kept, taken = slim_checkpoint(args.run, args.base, args.out)
    except (ModelError, OSError, ValueError, KeyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.out}: {kept} tensors kept, {taken} taken from {args.base}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
