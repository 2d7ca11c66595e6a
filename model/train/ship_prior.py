"""Ship a trained Co4DGen prior: a training run's prior directory -> ``model/weights/<id>/`` in float16.

    python -m vt4dcodec.model.train.ship_prior runs/co4dgen/prior [--dest model/weights] \
        [--sampler euler:4 --measured "bench/bench_prior.py ... -> results.json"]

The prior's id and version, the fingerprint of the tokenizer it was trained on, its extra records and its
model card are kept; its weights are rounded to float16 (half the file; what is saved, loaded and hashed is
the same prior) and the destination directory is replaced.  ``--sampler`` records the sampler setting
chosen for the prior by measurement (prior.json ``extra.sampler``, with ``--measured`` naming the
measurement), which ``vt4d generate`` then uses by default. The tokenizer it names must be shipped in
``--dest`` with that very fingerprint: a prior trained on another tokenizer's tokens is refused.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from vt4dcodec.errors import ModelError

from ..directories import (CARD_FILE, CONFIG_FILE, PRIOR_META_FILE, SHIPPED_DIR, checked_guidance, meta_fingerprint,
                           parse_sampler, read_model_meta)
from ..onnx_export import export_prior
from ..weights_io import load_prior, save_prior

__all__ = ["ship_prior"]


ONNX_CARD_NOTE = """* ONNX: `prior-condition.onnx` and `prior-velocity.onnx`, exported for onnxruntime from these weights
  (`python -m vt4dcodec.model.onnx_export co4dgen-tiny`; their weights are read from `prior.safetensors`):
  `vt4d generate` samples with them where torch is not installed. They compute in float64, as the torch
  sampler does, so both give the same tokens to float32 rounding.
"""


def ship_prior(source: str | Path, dest: str | Path = SHIPPED_DIR, *, sampler: str | None = None,
               measured: str | None = None) -> Path:
    """Store the prior directory ``source`` as ``dest/<its model_id>`` (float16); returns that directory.
    ``sampler`` ("heun:16", "euler:4:1.5") is recorded as the prior's default sampler setting, with
    ``measured`` (how it was chosen).  ModelError when the tokenizer it was trained on is not shipped in
    ``dest`` with the same fingerprint, or the setting is malformed or asks a prior without a null condition
    for guidance."""
    source, dest = Path(source), Path(dest)
    prior = load_prior(source)
    meta = json.loads((source / PRIOR_META_FILE).read_text(encoding="utf-8"))
    if sampler is not None:
        chosen = parse_sampler(sampler)
        checked_guidance(chosen.guidance, prior.config.cond_dropout)
        setting = chosen.to_dict() | ({"measured": str(measured)} if measured else {})
        meta["extra"] = {**(meta.get("extra") or {}), "sampler": setting}
    tokenizer = prior.tokenizer_fingerprint
    tokenizer_dir = dest / tokenizer.model_id
    if not (tokenizer_dir / CONFIG_FILE).is_file():
        raise ModelError(f"the prior was trained on {tokenizer.short()}, which is not shipped in {dest}")
    shipped = meta_fingerprint(read_model_meta(tokenizer_dir))
    if not shipped.matches(tokenizer):
        raise ModelError(f"the prior was trained on {tokenizer.short()}; {dest} ships {shipped.short()}: "
                         f"train the prior on the shipped tokenizer's tokens")
    card_path = source / CARD_FILE
    card = card_path.read_text(encoding="utf-8") if card_path.is_file() else None
    if card is not None and "prior-velocity.onnx" not in card:
        card = card.rstrip("\n") + "\n" + ONNX_CARD_NOTE
    if card is not None and sampler is not None:
        card = card.rstrip("\n") + f"\n* Sampler (`vt4d generate`'s default, chosen by measurement): {chosen}" + (
            f" ({measured})" if measured else "") + "\n"
    out = dest / prior.model_id
    if out.exists():
        shutil.rmtree(out)
    out = save_prior(prior, out, model_id=prior.model_id, model_version=prior.model_version, tokenizer=tokenizer,
                     card=card, extra=meta.get("extra"), storage_dtype="float16")
    export_prior(load_prior(out), out)  # the graphs the torch-free generate runs, from the stored float16 weights
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m vt4dcodec.model.train.ship_prior",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("prior", type=Path, help="the prior directory a training run wrote (<out>/prior)")
    parser.add_argument("--dest", type=Path, default=SHIPPED_DIR, help="directory of shipped models")
    parser.add_argument("--sampler", default=None, metavar="METHOD:STEPS[:GUIDANCE]",
                        help="record this sampler setting as the prior's default (chosen by measurement)")
    parser.add_argument("--measured", default=None, help="the measurement that chose --sampler (command, results file)")
    args = parser.parse_args(argv)
    try:
        out = ship_prior(args.prior, args.dest, sampler=args.sampler, measured=args.measured)
    except ModelError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    size = sum(p.stat().st_size for p in out.iterdir())
    print(f"shipped prior -> {out} ({size / 1e6:.1f} MB: {', '.join(sorted(p.name for p in out.iterdir()))})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
