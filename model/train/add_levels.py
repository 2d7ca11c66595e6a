"""Give a trained rate-distortion tokenizer coarser quality levels or context-coded MEAN tokens, as the warm
start of a fine-tune.

    python -m vt4dcodec.model.train.add_levels --run checkpoints/vt4d-tiny-2.0-rd --out runs/rd-init \
        --ratios 2.0,1.4
    python -m vt4dcodec.model.train.add_levels --run checkpoints/vt4d-tiny-2.0-rd8g --out runs/ctx-init \
        --mean-context

``--mean-context`` turns on ``config.entropy_context``: the two new density classes (MEAN after a negative and
after a positive code) start as copies of the MEAN densities, so the model codes exactly as before until its
densities are fitted again (``train.tokenizer --calibrate-batches N``).

Reads the run's latest checkpoint (or ``--model DIR``, a saved model), and writes a saved model
(``config.json`` + ``model.safetensors``) whose entropy model has ``len(ratios)`` more levels in front of
the coarsest one: new level ``i`` starts with the old coarsest steps times ``ratios[i]`` (largest first, so
levels stay ordered coarsest first). Every other weight, the densities included, is copied; the frozen
tables are rebuilt (:meth:`VideoTok4D.update_entropy`). Train on from it with ``train.tokenizer --init OUT
--init-partial`` and one more ``--rate-lambdas`` value per added level. The densities serve any step
(``model.entropy``), so the new levels are usable before the fine-tune; the fine-tune adapts the encoder,
the renderer and the steps to them. ``--finer-ratios`` appends levels after the finest one instead (steps =
the finest times each ratio below 1): finer top levels for a model whose encoder and renderer are frozen, whose
fidelity then only depends on the step. ``--entropy-from`` gives a model another one's entropy model (same
networks config): the start of fitting an entropy model to frozen networks.

    python -m vt4dcodec.model.train.add_levels --model vt4d-tiny --entropy-from checkpoints/vt4d-tiny-2.0-rd8q \
        --out runs/e1-init
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import torch

from vt4dcodec.errors import ModelError

from ..entropy import MAX_STEP, MIN_STEP
from ..configs import ModelConfig
from ..videotok4d import VideoTok4D
from ..weights_io import from_pretrained, save_pretrained
from .common import model_from_run, model_from_run_or_saved


def add_levels(model: VideoTok4D, ratios: list[float],
               rounding: list[tuple[float, float, float]] | None = None) -> VideoTok4D:
    """A copy of ``model`` with ``len(ratios)`` coarser levels prepended (steps = the coarsest x ratio, largest
    first). ``rounding``: the writer's offsets (MEAN, CHANGE, DYNAMIC) of each new level in that order, for a
    model with ``entropy_rounding``; a ratio of exactly 1 (the coarsest steps again) needs it, and offsets below
    the coarsest level's in some class (a wider dead zone: fewer bytes at the same steps)."""
    if model.entropy is None:
        raise ModelError("the model has no entropy model (config entropy_levels = 0)")
    if not ratios or any(not (r >= 1.0) or not math.isfinite(r) for r in ratios):
        raise ModelError(f"ratios must be finite numbers of at least 1, got {ratios}")
    order = sorted(range(len(ratios)), key=lambda i: -ratios[i])
    old_rounding = model.config.entropy_rounding
    if rounding is not None and (len(rounding) != len(ratios) or not old_rounding
                                 or any(len(r) != 3 or not all(0.0 <= v <= 0.5 for v in r) for r in rounding)):
        raise ModelError("rounding needs one (MEAN, CHANGE, DYNAMIC) triple in [0, 1/2] per ratio, for a model "
                         "with rounding offsets (config entropy_rounding)")
    repeats = [i for i, r in enumerate(ratios) if r == 1.0]
    if repeats and (rounding is None or any(all(a >= b for a, b in zip(rounding[i], old_rounding[:3]))
                                            for i in repeats)):
        raise ModelError("a level at ratio 1 repeats the coarsest steps: give it a wider dead zone (rounding "
                         "offsets below the coarsest level's in some class)")
    state = _trained_state(model)
    old = state["entropy.log_step"]
    coarsest = old[:1].clamp(max=math.log(MAX_STEP))
    state["entropy.log_step"] = torch.cat([coarsest + math.log(ratios[i]) for i in order] + [old])
    new_rounding = old_rounding
    if old_rounding:
        first = tuple(old_rounding[:3])
        new_rounding = tuple(v for i in order for v in (rounding[i] if rounding is not None else first)) \
            + tuple(old_rounding)
    return _rebuilt(model, dataclasses.replace(model.config, entropy_levels=model.config.entropy_levels + len(ratios),
                                               entropy_rounding=new_rounding), state)


def add_finer_levels(model: VideoTok4D, ratios: list[float]) -> VideoTok4D:
    """A copy of ``model`` with ``len(ratios)`` finer levels appended (steps = the finest x ratio, each ratio in
    (0, 1), clamped at MIN_STEP); the writer rounds the new levels' values to nearest (rounding offsets 1/2)."""
    if model.entropy is None:
        raise ModelError("the model has no entropy model (config entropy_levels = 0)")
    if not ratios or any(not (0.0 < r < 1.0) for r in ratios):
        raise ModelError(f"finer ratios must lie strictly between 0 and 1, got {ratios}")
    state = _trained_state(model)
    old = state["entropy.log_step"]
    finest = old[-1:].clamp(min=math.log(MIN_STEP))
    new = [(finest + math.log(r)).clamp(min=math.log(MIN_STEP) + 1e-6) for r in sorted(ratios, reverse=True)]
    state["entropy.log_step"] = torch.cat([old] + new)
    rounding = model.config.entropy_rounding
    if rounding:
        rounding = tuple(rounding) + (0.5, 0.5, 0.5) * len(ratios)
    cfg = dataclasses.replace(model.config, entropy_levels=model.config.entropy_levels + len(ratios),
                              entropy_rounding=rounding)
    return _rebuilt(model, cfg, state)


# buffers that follow from the config and the other weights: the frozen tables (rebuilt by update_entropy) and
# the partner channels (config.entropy_partners, set when the model is built)
_FROZEN = ("entropy.steps", "entropy.freqs", "entropy.origins", "entropy.partners")


def _trained_state(model: VideoTok4D) -> dict[str, torch.Tensor]:
    """The model's weights without the frozen tables (rebuilt by update_entropy for the new config)."""
    return {k: v for k, v in model.state_dict().items() if k not in _FROZEN}


def _rebuilt(model: VideoTok4D, cfg: ModelConfig, state: dict[str, torch.Tensor]) -> VideoTok4D:
    """A model of ``cfg`` with ``state`` (every weight but the frozen tables), its tables frozen again."""
    out = VideoTok4D(cfg)
    missing, unexpected = out.load_state_dict(state, strict=False)
    if unexpected or set(missing) != {k for k in _FROZEN if k in out.state_dict()}:
        raise ModelError(f"the model does not fit its own config: missing {missing}, unexpected {unexpected}")
    out.decode_steps = model.decode_steps
    out.eval()
    out.update_entropy()
    return out


def with_entropy_of(model: VideoTok4D, donor: VideoTok4D) -> VideoTok4D:
    """A copy of ``model`` (every network weight kept) with ``donor``'s entropy model: its levels, context,
    partners and rounding offsets, steps and densities. The start of a fit of the entropy model alone to the
    frozen networks of ``model`` (``train.tokenizer --train-only entropy.``). The two configs must agree in
    everything else."""
    if donor.entropy is None:
        raise ModelError("the donor has no entropy model (config entropy_levels = 0)")
    fields = [f.name for f in dataclasses.fields(model.config) if f.name.startswith("entropy_")]
    cfg = dataclasses.replace(model.config, **{f: getattr(donor.config, f) for f in fields})
    if cfg != donor.config:
        raise ModelError("the donor's config differs from the model's outside the entropy model")
    state = {k: v for k, v in _trained_state(model).items() if not k.startswith("entropy.")}
    state.update({k: v for k, v in _trained_state(donor).items() if k.startswith("entropy.")})
    return _rebuilt(model, cfg, state)


def add_mean_context(model: VideoTok4D) -> VideoTok4D:
    """A copy of ``model`` whose entropy model codes MEAN tokens given the previous MEAN token's sign
    (``config.entropy_context``), its two new density classes copies of the MEAN densities."""
    if model.entropy is None:
        raise ModelError("the model has no entropy model (config entropy_levels = 0)")
    if model.config.entropy_context:
        raise ModelError("the model already codes MEAN tokens in context (config entropy_context = true)")
    state = _trained_state(model)
    logits = state["entropy.logits"]
    state["entropy.logits"] = torch.cat([logits, logits[:1], logits[:1]])  # MEAN_AFTER_NEGATIVE, _POSITIVE
    return _rebuilt(model, dataclasses.replace(model.config, entropy_context=True), state)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--run", type=Path, help="a training run directory (its latest checkpoint)")
    src.add_argument("--model", help="a saved model directory or shipped model id")
    p.add_argument("--out", type=Path, required=True, help="directory of the model to write")
    p.add_argument("--ratios", default=None, help="comma-separated step ratios (> 1) of the new levels")
    p.add_argument("--entropy-from", type=Path, default=None, metavar="RUN_OR_MODEL",
                   help="replace the entropy model by this run's (checkpoint) or saved model's, networks kept")
    p.add_argument("--finer-ratios", default=None,
                   help="comma-separated step ratios (between 0 and 1) of new levels appended after the finest")
    p.add_argument("--rounding", default=None, metavar="M/C/D,...",
                   help="with --ratios: the writer's rounding offsets of each new level (MEAN/CHANGE/DYNAMIC)")
    p.add_argument("--mean-context", action="store_true",
                   help="code MEAN tokens given the previous MEAN token's sign (config entropy_context)")
    p.add_argument("--id", default="vt4d-tiny", help="model id recorded in the written model")
    p.add_argument("--version", default="0.0.0-init", help="model version recorded in the written model")
    args = p.parse_args(argv)
    if args.ratios is None and args.finer_ratios is None and not args.mean_context and args.entropy_from is None:
        p.error("nothing to add: give --entropy-from, --ratios, --finer-ratios, --mean-context or several")
    try:
        ratios = [] if args.ratios is None else [float(v) for v in args.ratios.split(",")]
    except ValueError:
        p.error(f"--ratios takes comma-separated numbers, got {args.ratios!r}")
    try:
        rounding = None if args.rounding is None else [
            tuple(float(v) for v in item.split("/")) for item in args.rounding.split(",")]
    except ValueError:
        p.error(f"--rounding takes M/C/D triples, comma-separated, got {args.rounding!r}")
    try:
        finer = [] if args.finer_ratios is None else [float(v) for v in args.finer_ratios.split(",")]
    except ValueError:
        p.error(f"--finer-ratios takes comma-separated numbers, got {args.finer_ratios!r}")
    try:
        out = model_from_run(args.run)[0] if args.run else from_pretrained(args.model)
        if args.entropy_from is not None:
            out = with_entropy_of(out, model_from_run_or_saved(args.entropy_from))
        if ratios:
            out = add_levels(out, ratios, rounding)
        if finer:
            out = add_finer_levels(out, finer)
        if args.mean_context:
            out = add_mean_context(out)
    except ModelError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    save_pretrained(out, args.out, model_id=args.id, model_version=args.version)
    steps = out.entropy.step_values().mean(-1)
    print(f"{args.out}: {out.config.entropy_levels} levels, mean steps Z_s "
          + " ".join(f"{v:.3f}" for v in steps[:, 0].tolist()) + ", Z_d "
          + " ".join(f"{v:.3f}" for v in steps[:, 1].tolist()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
