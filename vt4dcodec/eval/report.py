"""Reports of an evaluation: the per-method summary of the scored rows, the results file, the
Markdown tables docs/RESULTS.md shows and the PNG figures.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from vt4dcodec.synth.generator import SynthScene

from .metrics import mean_se, round_metric
from .protocol import METHODS, METRICS, EvaluationError

__all__ = ["summarize", "format_tables", "save_figure", "save_png_small", "write_json"]


# --- summary ----------------------------------------------------------------------------------------
def summarize(rows: list[dict[str, Any]], floats: dict[str, int]) -> dict[str, dict[str, Any]]:
    """Per method: mean, standard error and count of every metric, sizes, and paired comparisons
    against ``ours`` (mean of ours - method, fraction of views where ours is higher)."""
    by_method: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        by_method.setdefault(r["method"], []).append(r)
    ours = {(r["seed"], r["view"]): r for r in by_method.get("ours", [])}
    summary: dict[str, dict[str, Any]] = {}
    for method in [m for m in METHODS if m in by_method]:
        rs = by_method[method]
        entry: dict[str, Any] = {"label": METHODS[method], "views": len(rs), "floats": floats[method]}
        for m in METRICS:
            mean, se, n = mean_se([r[m] for r in rs])
            entry[m] = {"mean": round_metric(mean) if mean is not None else None,
                        "se": round_metric(se) if se is not None else None, "n": n}
        sizes = [r["bytes"] for r in rs if r["bytes"] is not None]
        entry["bytes_int8_vt4d"] = round(float(np.mean(sizes)), 1) if sizes else None
        if method == "depth_warp":
            entry["hole_fraction"] = round_metric(float(np.mean([r["hole_fraction"] for r in rs])))
            entry["surfel_hole_fraction"] = round_metric(float(np.mean([r["surfel_hole_fraction"] for r in rs])))
            entry["psnr_visible"] = round_metric(mean_se([r["psnr_visible"] for r in rs])[0] or float("nan"))
        if method != "ours" and ours:
            for m in ("psnr", "psnr_dynamic"):
                pairs = [(ours[(r["seed"], r["view"])][m], r[m]) for r in rs if (r["seed"], r["view"]) in ours]
                pairs = [(a, b) for a, b in pairs if a is not None and b is not None]
                if pairs:
                    d = np.array([a - b for a, b in pairs])
                    se = float(d.std(ddof=1) / math.sqrt(d.size)) if d.size > 1 else None
                    entry[f"ours_minus_this_{m}"] = {"mean": round_metric(float(d.mean())),
                                                     "se": round_metric(se) if se is not None else None,
                                                     "ours_wins": round_metric(float((d > 0).mean())), "n": int(d.size)}
        summary[method] = entry
    return summary


# --- figure -----------------------------------------------------------------------------------------
FIGURE_COLUMNS = ("ours", "ours_no_dynamic", "unified", "nearest_frame", "depth_warp")


def save_figure(path: str | Path, kept: dict[int, dict[str, dict[str, Any]]], *, view: int = 0,
                times: Sequence[int] | None = None, dpi: int = 100) -> Path:
    """PNG grid: one row per (scene, time), columns source | ground truth | the methods present."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not kept:
        raise EvaluationError("no scenes kept for the figure")
    first = next(iter(kept.values()))
    columns = [c for c in FIGURE_COLUMNS if c in first]
    sc0: SynthScene = first["scene"]["scene"]
    T = sc0.capture.num_frames
    times = list(times) if times is not None else sorted({0, T // 2, T - 1})
    rows = [(seed, t) for seed in kept for t in times]
    ncol = 2 + len(columns)
    fig, axes = plt.subplots(len(rows), ncol, figsize=(1.1 * ncol, 1.15 * len(rows)), squeeze=False)
    titles = ["source (cam 0)", "ground truth"] + [METHODS[c].replace(" (", "\n(") for c in columns]
    for r, (seed, t) in enumerate(rows):
        entry = kept[seed]
        sc: SynthScene = entry["scene"]["scene"]
        names = sc.capture.camera_names
        target = names[1 + view]
        tiles = [sc.capture.frames[names[0]][t], sc.capture.frames[target][t]]
        tiles += [entry[c]["videos"][view][t] for c in columns]
        for c, tile in enumerate(tiles):
            ax = axes[r, c]
            ax.imshow(tile, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(titles[c], fontsize=6)
            if c == 0:
                ax.set_ylabel(f"seed {seed}\n{target} t={t}", fontsize=6)
    fig.tight_layout(pad=0.2)
    return save_png_small(fig, path, dpi=dpi)


def save_png_small(fig: Any, path: str | Path, *, dpi: int = 100) -> Path:
    """Save a matplotlib figure as a 256-colour PNG (docs figures stay well under 300 KB), then close it."""
    import io

    import matplotlib.pyplot as plt
    from PIL import Image

    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, format="png")
    plt.close(fig)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    image = Image.open(buf).convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    image.save(path, optimize=True)
    return path


# --- tables -----------------------------------------------------------------------------------------
def _fmt(entry: dict[str, Any] | None, nd: int = 2) -> str:
    if not entry or entry.get("mean") is None:
        return "n/a"
    se = entry.get("se")
    return f"{entry['mean']:.{nd}f} ± {se:.{nd}f}" if se is not None else f"{entry['mean']:.{nd}f}"


def format_tables(results: dict[str, Any]) -> str:
    """Markdown tables of a results file: the main comparison (Table 1) and token masking (Table 4)."""
    s = results["summary"]
    lines = ["| method | floats | int8 .vt4d bytes | PSNR (dB) | SSIM | dynamic PSNR (dB) | static PSNR (dB) | "
             "ours − this, PSNR (ours wins) | ours − this, dyn. PSNR (ours wins) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]

    def paired(e: dict[str, Any], key: str) -> str:
        p = e.get(f"ours_minus_this_{key}")
        if not p:
            return "—"
        se = f" ± {p['se']:.2f}" if p.get("se") is not None else ""
        return f"{p['mean']:+.2f}{se} ({100 * p['ours_wins']:.0f}%)"

    for m in ("ours", "unified", "nearest_frame", "depth_warp", "mean_colour"):
        if m not in s:
            continue
        e = s[m]
        size = f"{e['bytes_int8_vt4d']:.0f}" if e.get("bytes_int8_vt4d") else "—"
        lines.append(f"| {e['label']} | {e['floats']:,} | {size} | {_fmt(e['psnr'])} | {_fmt(e['ssim'], 3)} | "
                     f"{_fmt(e['psnr_dynamic'])} | {_fmt(e['psnr_static'])} | {paired(e, 'psnr')} | "
                     f"{paired(e, 'psnr_dynamic')} |")
    out = "\n".join(lines)
    if "depth_warp" in s:
        e = s["depth_warp"]
        out += (f"\n\nDepth forward-warp: {100 * e['hole_fraction']:.1f}% of target pixels receive no splat "
                f"(single-pixel splats, before inpainting; {100 * e['surfel_hole_fraction']:.1f}% with surfel "
                f"splats, i.e. not seen by the source camera at all); PSNR over the pixels that do receive a "
                f"splat: {e['psnr_visible']:.2f} dB.")
    mask_rows = [m for m in ("ours_no_static", "ours_no_dynamic", "ours") if m in s]
    if len(mask_rows) > 1:
        out += ("\n\n| tokens rendered | PSNR (dB) | SSIM | dynamic PSNR (dB) | static PSNR (dB) |\n"
                "|---|---:|---:|---:|---:|")
        for m, label in (("ours_no_static", "Z_d only (w/o Z_s)"), ("ours_no_dynamic", "Z_s only (w/o Z_d)"),
                         ("ours", "Z_s + Z_d")):
            if m in s:
                e = s[m]
                out += (f"\n| {label} | {_fmt(e['psnr'])} | {_fmt(e['ssim'], 3)} | {_fmt(e['psnr_dynamic'])} | "
                        f"{_fmt(e['psnr_static'])} |")
    return out + "\n"


def write_json(path: str | Path, data: dict[str, Any]) -> Path:
    """Indented JSON, except that every element of a top-level ``rows`` list takes one line."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps({k: v for k, v in data.items() if k != "rows"}, indent=1)
    if "rows" in data:
        inner = text[1:-1].rstrip()
        rows = ",\n".join("  " + json.dumps(r, separators=(",", ":")) for r in data["rows"])
        text = "{" + inner + (",\n" if inner else "\n") + ' "rows": [\n' + rows + "\n ]\n}"
    path.write_text(text + "\n")
    return path
