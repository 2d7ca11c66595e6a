"""Evaluate models on held-out synthetic scenes: the command behind ``python -m vt4dcodec.eval``.

    python -m vt4dcodec.eval --model vt4d-tiny [--unified runs/tok_unified/model] [--sets far,near,source] \
        --scenes 50 --views 3 --out docs/results/eval.json --figure docs/figures/eval_scenes.png

Table 5's other ablations come in the same way (``--no-motion-isolation RUN``, ``--fixed-grid RUN``; each
model's config must be that ablation), usually added later to the same file with ``--merge --methods``.

The protocol is :mod:`vt4dcodec.eval.protocol`'s; models are given as shipped ids, model directories or
training run directories (their latest checkpoint).  ``--sets`` chooses the target sets (default all
three); the results file holds their rows (field ``"set"``), ``summary_by_set`` (set -> method ->
summary), ``summary`` (the far set's, as before sets existed) and ``token_health``.  ``--steps``
forces the sampler steps; by default each model renders with its recorded ``decode_steps`` (recorded
per model under ``models.<key>.steps``; a training checkpoint records none and decodes in one step when
its run trained the renderer at tau = 1 only, else in 8).  ``--merge`` adds or replaces some methods (in the sets
evaluated) in an existing results file (same protocol; rows of files without sets are far rows), so a
model that finishes training later is added without rerunning the rest; ``--tables FILE`` prints the
Markdown tables of a results file (what docs/RESULTS.md shows).  The figure of the far set is written
to ``--figure``, those of the other sets beside it as ``<stem>_<set>.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Callable, Sequence

import torch

from vt4dcodec import codec
from vt4dcodec.errors import ModelError, Vt4dError
from vt4dcodec.model import VideoTok4D
from vt4dcodec.model.train.common import model_from_run

from . import baselines
from .protocol import (ABLATIONS, ENCODING, METHODS, TOKEN_METHODS, VIEW_SETS, EvalSettings, EvaluationError, describe_model,
                       parse_sets, representation_floats, run_evaluation)

from .report import format_tables, row_set, save_figure, summarize_sets, write_json

__all__ = ["load_run_checkpoint", "resolve_model", "run_command", "main"]


# --- models ----------------------------------------------------------------------------------------
def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m vt4dcodec.eval", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default="vt4d-tiny", help="main model: shipped id, model directory, or a training "
                   "run directory (its latest checkpoint)")
    p.add_argument("--unified", default=None, help="unified-token ablation: model or training run directory")
    p.add_argument("--no-motion-isolation", default=None, metavar="MODEL",
                   help="Table 5's w/o-motion-isolation ablation: model or training run directory")
    p.add_argument("--fixed-grid", default=None, metavar="MODEL",
                   help="Table 5's fixed-grid temporal-attention ablation: model or training run directory")
    p.add_argument("--scenes", type=int, default=50)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--views", type=int, default=3, help="target cameras per scene (cameras 1..views)")
    p.add_argument("--cameras", type=int, default=None, help="cameras per scene (default max(4, views + 1))")
    p.add_argument("--sets", default=",".join(VIEW_SETS), help="comma-separated target sets of "
                   f"{','.join(VIEW_SETS)} (default: all)")
    p.add_argument("--steps", type=int, default=None, help="Euler steps of the renderer (default: each model's "
                   "recorded decode_steps)")
    p.add_argument("--seed", type=int, default=0, help="sampling noise and track seed")
    p.add_argument("--quality", type=int, default=None, metavar="N",
                   help="store the tokens of models with quality levels as learned-rans at level N (default: int8 "
                        "for every model; models without levels stay int8)")
    p.add_argument("--methods", default=None, help=f"comma-separated subset of {','.join(METHODS)} (default: all "
                   "that have a model)")
    p.add_argument("--merge", action="store_true", help="add/replace these methods in an existing --out file")
    p.add_argument("--out", default="docs/results/eval.json")
    p.add_argument("--figure", default=None, help="PNG of a few scenes across time")
    p.add_argument("--figure-scenes", type=int, default=3)
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--tables", metavar="RESULTS_JSON", default=None, help="print the Markdown tables of a results "
                   "file and exit")
    return p


def load_run_checkpoint(run_dir: str | Path) -> VideoTok4D:
    """The model of a training run's latest checkpoint (``<run>/checkpoint/``, written by the training
    commands), for evaluating a run in progress.  Its fingerprint version is ``<version>+step<N>``; its
    ``decode_steps`` follow the run's flow times (one step for a run trained at tau = 1 only)."""
    try:
        net, state = model_from_run(Path(run_dir))  # decode_steps: what the run's renderer was trained for
    except ModelError as exc:
        raise EvaluationError(str(exc)) from None
    train_args = state.get("args", {})
    net.set_identity(str(train_args.get("model_id", "unnamed")),
                     f"{train_args.get('model_version', '0')}+step{int(state['step'])}",
                     training_step=int(state["step"]))
    return net


def resolve_model(spec: str) -> VideoTok4D:
    """A shipped id, a model directory, or a training run directory (its latest checkpoint)."""
    path = Path(spec)
    if path.is_dir() and not (path / "config.json").is_file() and (path / "checkpoint" / "state.json").is_file():
        return load_run_checkpoint(path)
    return codec.load_model(spec)


def _load_models(args: argparse.Namespace) -> dict[str, VideoTok4D]:
    models = {"main": resolve_model(args.model)}
    for key, (field, value, flag) in ABLATIONS.items():
        spec = getattr(args, flag.removeprefix("--").replace("-", "_"))
        if spec:
            models[key] = resolve_model(spec)
            if getattr(models[key].config, field) != value:
                raise EvaluationError(f"{flag} {spec}: not that ablation (config {field} is "
                                      f"{str(getattr(models[key].config, field)).lower()})")
    for net in models.values():
        net.eval()
    return models


def run_command(body: Callable[[], int]) -> int:
    """Run a command body with the project's exit codes: 1 for a Vt4dError, 3 for an OSError."""
    try:
        return body()
    except Vt4dError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 3


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    return run_command(lambda: _run(args, argv))


def _figure_path(figure: str, view_set: str) -> Path:
    """The far set's figure is ``figure`` itself; the others' sit beside it as ``<stem>_<set>.png``."""
    path = Path(figure)
    return path if view_set == "far" else path.with_name(f"{path.stem}_{view_set}{path.suffix or '.png'}")


def _merge_health(previous: dict | None, new: dict | None) -> dict | None:
    if new is None or previous is None or previous.get("set") != new.get("set"):
        return new if new is not None else previous
    return {**new, "models": {**previous["models"], **new["models"]}}


def _run(args: argparse.Namespace, argv: Sequence[str] | None) -> int:
    if args.tables:
        sys.stdout.write(format_tables(json.loads(Path(args.tables).read_text())))
        return 0
    torch.set_num_threads(max(1, args.threads))
    sets = parse_sets(args.sets)
    models = _load_models(args)
    cfg = models["main"].config
    settings = EvalSettings(scenes=args.scenes, first_seed=args.first_seed, views=args.views, steps=args.steps,
                            seed=args.seed, num_cameras=args.cameras or max(4, args.views + 1),
                            frames=cfg.frames, image_size=cfg.image_size, quality=args.quality)
    available = [m for m in METHODS if m not in TOKEN_METHODS or TOKEN_METHODS[m][1][0] in models]
    methods = args.methods.split(",") if args.methods else available
    out = Path(args.out)
    previous = json.loads(out.read_text()) if args.merge and out.is_file() else None
    if previous is not None and previous["settings"] != asdict(settings):
        raise EvaluationError(f"{out} was made with settings {previous['settings']}, not {asdict(settings)}")
    figure_seeds = settings.seeds[:args.figure_scenes] if args.figure else []
    t0, cpu0 = time.perf_counter(), time.process_time()
    rows, kept, seconds, health = run_evaluation(settings, models, methods, sets=sets, figure_seeds=figure_seeds,
                                                 progress=not args.no_progress)
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    if args.figure and set(methods) != set(available):   # the figure shows every available method
        _, kept, _, _ = run_evaluation(replace(settings, scenes=len(figure_seeds)), models, available, sets=sets,
                                       figure_seeds=figure_seeds)
    model_info = {k: describe_model(v, settings) for k, v in models.items()}
    timing = {"wall_s": round(wall, 1), "process_cpu_s": round(cpu, 1), "per_method_wall_s": seconds,
              "threads": args.threads, "load_average_at_end": [round(x, 2) for x in os.getloadavg()]}
    all_sets = list(sets)
    if previous is not None:
        replaced = {(m, v) for m in methods for v in sets}
        rows = [{**r, "set": row_set(r)} for r in previous["rows"] if (r["method"], row_set(r)) not in replaced] + rows
        model_info = {**previous["models"], **model_info}
        timing = {**previous["timing"], f"merge_{'+'.join(methods)}": timing}
        health = _merge_health(previous.get("token_health"), health)
        all_sets = [v for v in VIEW_SETS if v in set(previous.get("sets", ["far"])) | set(sets)]
    command = "python -m vt4dcodec.eval " + " ".join(sys.argv[1:] if argv is None else argv)
    token_floats = {k: baselines.token_floats(v["n_static"], v["n_dynamic"], v["token_dim"]) for k, v in model_info.items()}
    present = sorted({r["method"] for r in rows}, key=list(METHODS).index)
    floats = {m: representation_floats(m, settings, token_floats=token_floats.get(TOKEN_METHODS[m][1][0])
                                       if m in TOKEN_METHODS else None) for m in present}
    by_set = summarize_sets(rows, floats)
    results = {
        "commands": (previous["commands"] if previous is not None else []) + [command],
        "settings": asdict(settings), "sets": all_sets, "encoding": ENCODING, "models": model_info,
        "machine": {"python": platform.python_version(), "torch": torch.__version__},
        "timing": timing, "summary": by_set.get("far", {}), "summary_by_set": by_set, "token_health": health,
        "rows": rows,
    }
    write_json(out, results)
    if args.figure:
        for view_set, scenes in kept.items():
            if scenes:
                save_figure(_figure_path(args.figure, view_set), scenes)
    sys.stdout.write(format_tables(results))
    sys.stdout.write(f"wall {wall:.1f} s, process CPU {cpu:.1f} s; results -> {out}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
