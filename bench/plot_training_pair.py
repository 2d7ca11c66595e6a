#!/usr/bin/env python
"""Learning curves of a tokenizer and its ablation trained side by side, from evaluations at checkpoints.

    python bench/plot_training_pair.py --eval E500.json --eval E2000.json ... [--reference SHIPPED.json] \
        [--log RUN/log.jsonl --log RUN2/log.jsonl] --out CURVE.json --figure CURVE.png

Each ``--eval`` is the JSON of one ``python -m vt4dcodec.eval --model RUN --unified RUN2 ... --out E.json``
at a checkpoint (the training step is read from it). All must be one protocol: the same scenes, cameras,
views, sets and decode steps, or the script refuses (a curve over different scenes says nothing).
``--reference`` is an evaluation of another model (e.g. the shipped one) on the same protocol, drawn as a
line. ``--log`` adds the runs' training logs (mean x0 error over 250 steps). Writes the points (PSNR with
its standard error, the paired difference ours - ablation, token health) to ``--out`` and the figure to
``--figure``.

A long run is evaluated across sessions whose evaluation files do not travel: ``--extend CURVE.json``
starts from the points (and reference) of a curve this script wrote before, on the same protocol, and adds
the ``--eval`` points to it (an evaluation at a step the curve already has replaces that point).

    python bench/plot_training_pair.py --extend docs/results/training_pair.json --eval E4000.json \
        --log RUN/log.jsonl --log RUN2/log.jsonl --out docs/results/training_pair.json --figure CURVE.png
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

PROTOCOL = ("scenes", "first_seed", "views", "num_cameras", "frames", "image_size")
METRICS = ("psnr", "ssim", "psnr_dynamic", "psnr_static")
THRESHOLDS = {"source": 25.0, "multi-held": 23.0}  # issue 12's "Done when" (50 scenes)
SET_ORDER = ("source", "near", "far", "multi-enc", "multi-held")
WINDOW = 250  # training-log steps per point (single batches vary a lot: camera counts, reconstructions)


class CurveError(ValueError):
    """The evaluations given cannot form one curve."""


def _load(path: Path, keys: tuple[str, ...], what: str) -> dict[str, Any]:
    """The JSON object at ``path`` holding ``keys``; ``what`` names the file for the error."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise CurveError(f"{path}: not {what} ({exc})") from None
    missing = [k for k in keys if not isinstance(data, dict) or k not in data]
    if missing:
        raise CurveError(f"{path}: not {what} (no {', '.join(missing)})")
    return data


def _read(path: Path) -> dict[str, Any]:
    return _load(path, ("settings", "summary_by_set", "models"), "an evaluation JSON of python -m vt4dcodec.eval")


def _set_rank(name: str) -> tuple[int, str]:
    return (SET_ORDER.index(name) if name in SET_ORDER else len(SET_ORDER), name)


def protocol(data: dict[str, Any]) -> dict[str, Any]:
    """What must match between two evaluations for their numbers to lie on one curve."""
    models = data["models"]
    steps = {m.get("steps") for m in models.values()}
    return {**{k: data["settings"].get(k) for k in PROTOCOL}, "sets": sorted(data["summary_by_set"], key=_set_rank),
            "decode_steps": sorted(steps, key=str)}


def point(data: dict[str, Any]) -> dict[str, Any]:
    """One checkpoint: training steps of both runs, per set each method's metrics (mean, se) and the
    paired difference ours - unified, and token health."""
    models = data["models"]
    out: dict[str, Any] = {"step": models["main"].get("training_step"),
                           "step_unified": models.get("unified", {}).get("training_step"), "sets": {}}
    for name, summary in data["summary_by_set"].items():
        row: dict[str, Any] = {}
        for method, values in summary.items():
            row[method] = {m: values[m] for m in METRICS if m in values}
            for key in ("ours_minus_this_psnr", "ours_minus_this_psnr_dynamic"):
                if key in values:
                    row[method][key] = values[key]
        out["sets"][name] = row
    health = data.get("token_health", {}).get("models", {})
    out["token_health"] = {k: {f: v[f] for f in ("static_spread", "dynamic_spread", "dynamic_saturation",
                                                   "swap_drop_db") if f in v} for k, v in health.items()}
    return out


def training_curve(log: Path, window: int = WINDOW) -> list[tuple[int, float]]:
    """(step, mean x0 error over the last ``window`` steps) every ``window`` steps of a run's log.jsonl."""
    records = [json.loads(line) for line in Path(log).read_text().splitlines() if line.strip()]
    records = [r for r in records if "x0" in r and "step" in r]
    curve = []
    for end in range(window, max((r["step"] for r in records), default=0) + 1, window):
        chunk = [r["x0"] for r in records if end - window < r["step"] <= end]
        if chunk:
            curve.append((end, sum(chunk) / len(chunk)))
    return curve


def _read_curve(path: Path) -> dict[str, Any]:
    """A curve JSON this script wrote (for ``--extend``)."""
    return _load(path, ("protocol", "points", "evaluations"), "a curve JSON of this script (--extend)")


def build(evals: list[Path], reference: Path | None, logs: list[Path], extend: Path | None = None) -> dict[str, Any]:
    earlier = _read_curve(extend) if extend is not None else None
    if not evals and earlier is None:
        raise CurveError("give at least one --eval")
    data = [_read(p) for p in evals]
    first, against = (earlier["protocol"], f"the curve {extend}") if earlier else (protocol(data[0]), str(evals[0]))
    for path, d in zip(evals, data):
        if protocol(d) != first:
            raise CurveError(f"{path} was evaluated with another protocol than {against}: "
                             f"{protocol(d)} != {first}")
    by_step = {p["step"]: p for p in (earlier["points"] if earlier else [])}
    by_step.update((p["step"], p) for p in map(point, data))  # a new evaluation of a step replaces the old
    points = sorted(by_step.values(), key=lambda p: (p["step"] is None, p["step"] or 0))
    sources = [*(earlier["evaluations"] if earlier else []), *map(str, evals)]
    result: dict[str, Any] = {"protocol": first, "evaluations": list(dict.fromkeys(sources)), "points": points,
                              "thresholds_50_scenes": THRESHOLDS}
    if reference is None and earlier is not None and "reference" in earlier:
        result["reference"] = earlier["reference"]
    elif reference is not None:
        ref = _read(reference)
        ref_protocol = protocol(ref)  # its own decode steps are allowed: it is recorded with it
        if any(ref_protocol[k] != first[k] for k in (*PROTOCOL, "sets")):
            raise CurveError(f"--reference {reference} was evaluated on other scenes or sets than the curve")
        result["reference"] = {"fingerprint": ref["models"]["main"].get("fingerprint"),
                               "decode_steps": ref["models"]["main"].get("steps"), **point(ref)}
    result["training_x0"] = {str(p): training_curve(p) for p in logs}
    return result


def plot(result: dict[str, Any], png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = result["protocol"]["sets"]
    panels = len(sets) + (1 if result["training_x0"] else 0)
    fig, axes = plt.subplots(1, panels, figsize=(4.2 * panels, 3.4), dpi=100, squeeze=False)
    colours = {"ours": "tab:blue", "unified": "tab:orange"}
    labels = {"ours": "VideoTok4D (Z_s + Z_d)", "unified": "unified tokens (ablation)"}
    for ax, name in zip(axes[0], sets):
        for method in ("ours", "unified"):
            pts = [(p["step"] if method == "ours" else p["step_unified"], p["sets"][name][method]["psnr"])
                   for p in result["points"] if method in p["sets"].get(name, {})]
            if pts:
                ax.errorbar([s for s, _ in pts], [v["mean"] for _, v in pts], yerr=[v["se"] for _, v in pts],
                            marker="o", ms=4, capsize=3, color=colours[method], label=labels[method])
        ref = result.get("reference")
        if ref and "ours" in ref["sets"].get(name, {}):
            ax.axhline(ref["sets"][name]["ours"]["psnr"]["mean"], color="grey", ls="--",
                       label=f"{ref['fingerprint'].split(' ')[0]} (same scenes)")
        if name in THRESHOLDS:
            ax.axhline(THRESHOLDS[name], color="tab:red", ls=":", label="issue threshold")
        ax.set_title(f"{name}: PSNR on {result['protocol']['scenes']} scenes", fontsize=9)
        ax.set_xlabel("training step")
        ax.set_ylabel("PSNR (dB)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    if result["training_x0"]:
        ax = axes[0][-1]
        for path, curve in result["training_x0"].items():
            ax.plot([s for s, _ in curve], [v for _, v in curve], label=Path(path).parent.name)
        ax.set_title(f"training log: x0 error (mean of {WINDOW} steps)", fontsize=9)
        ax.set_xlabel("training step")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--eval", type=Path, action="append", default=[], help="an evaluation JSON (repeat)")
    parser.add_argument("--reference", type=Path, help="an evaluation JSON of another model, same protocol")
    parser.add_argument("--log", type=Path, action="append", default=[], help="a run's log.jsonl (repeat)")
    parser.add_argument("--extend", type=Path, metavar="CURVE_JSON",
                        help="start from the points and reference of a curve this script wrote (same protocol)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--figure", type=Path)
    args = parser.parse_args(argv)
    try:
        result = build(args.eval, args.reference, args.log, args.extend)
    except CurveError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    result["command"] = "python bench/plot_training_pair.py " + " ".join(sys.argv[1:] if argv is None else argv)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    if args.figure is not None:
        plot(result, args.figure)
    print(json.dumps({p["step"]: {k: v["ours"]["psnr"]["mean"] for k, v in p["sets"].items()}
                      for p in result["points"]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
