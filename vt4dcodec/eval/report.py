"""Reports of an evaluation: the per-method summary of the scored rows, the results file, the
Markdown tables docs/RESULTS.md shows and the PNG figures.
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path
from typing import Any, Sequence

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from PIL import Image

from vt4dcodec.synth.generator import SynthScene

from .metrics import mean_se, round_metric
from .protocol import HEALTH_THRESHOLDS, METHODS, METRICS, SKIPPED_ON_SOURCE, VIEW_SETS, EvaluationError

__all__ = ["summarize", "summarize_sets", "file_bytes", "row_set", "format_tables", "format_health", "save_figure",
           "save_png_small", "write_json"]

SET_TITLES = {
    "far": "Far views (the original protocol: cameras 1..views of 4-camera rigs)",
    "near": "Near views (the two cameras nearest in viewing direction to the source, 10-camera rigs)",
    "source": "Source view (camera 0 itself: reconstruction of the encoded view, 10-camera rigs)",
    "multi-held": "Multi-camera, held-out views (cameras 0, 2, 4, 6, 8 encoded into one scene; cameras 1, 3, 5, "
                  "7, 9 rendered)",
    "multi-enc": "Multi-camera, encoded views (cameras 0, 2, 4, 6, 8 encoded into one scene and rendered)",
}


# --- summary ----------------------------------------------------------------------------------------
def file_bytes(entry: dict[str, Any]) -> float | None:
    """A method's mean .vt4d file bytes from its summary entry, in this module's results files of any age."""
    value = entry.get("file_bytes", entry.get("bytes_int8_vt4d"))
    return None if value is None else float(value)


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
        # mean .vt4d file bytes at the evaluated encoding (results files before Session 48 named this
        # "bytes_int8_vt4d", whatever the encoding; :func:`file_bytes` reads both)
        entry["file_bytes"] = round(float(np.mean(sizes)), 1) if sizes else None
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


def row_set(row: dict[str, Any]) -> str:
    """The target set of a row; rows of results files written before sets existed are "far"."""
    return row.get("set", "far")


def summarize_sets(rows: list[dict[str, Any]], floats: dict[str, int]) -> dict[str, dict[str, dict[str, Any]]]:
    """:func:`summarize` per target set present in ``rows`` (set -> method -> entry), in VIEW_SETS order."""
    present = {row_set(r) for r in rows}
    return {v: summarize([r for r in rows if row_set(r) == v], floats) for v in VIEW_SETS if v in present}


# --- figure -----------------------------------------------------------------------------------------
# column order of the scene figures: every method of METHODS but the Z_d-only render and the flat reference
# (tests/eval/test_report_figure.py keeps the two lists in step); the methods a run did not predict are skipped
FIGURE_COLUMNS = ("ours", "ours_no_dynamic", "no_motion_isolation", "fixed_grid", "unified", "nearest_frame",
                  "depth_warp")


def save_figure(path: str | Path, kept: dict[int, dict[str, dict[str, Any]]], *, view: int = 0,
                times: Sequence[int] | None = None, dpi: int = 100) -> Path:
    """PNG grid: one row per (scene, time), columns source | ground truth | the methods present."""
    matplotlib.use("Agg")
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
        target = entry["scene"].get("targets", names[1:])[view]
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
    """Markdown tables of a results file: per target set the main comparison (Table 1), the flat
    mean-colour reference next to ours and token masking (Table 4); then token health, if measured.
    Files written before target sets existed hold only the far set."""
    by_set = results.get("summary_by_set") or {"far": results["summary"]}
    stored = results.get("models", {}).get("main", {}).get("encoding", "int8")  # learned-rans qN with --quality
    parts = []
    for view_set in [v for v in VIEW_SETS if v in by_set]:
        s = by_set[view_set]
        views = max((e["views"] for e in s.values()), default=0)
        parts.append(f"### {SET_TITLES[view_set]}: {views} target videos\n\n" + _set_tables(s, view_set, stored))
    if results.get("token_health"):
        parts.append(format_health(results["token_health"], stored))
    return "\n".join(parts)


def _set_tables(s: dict[str, Any], view_set: str, stored: str = "int8") -> str:
    lines = [f"| method | floats | {stored} .vt4d bytes | PSNR (dB) | SSIM | dynamic PSNR (dB) | static PSNR (dB) | "
             "ours − this, PSNR (ours wins) | ours − this, dyn. PSNR (ours wins) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]

    def paired(e: dict[str, Any], key: str) -> str:
        p = e.get(f"ours_minus_this_{key}")
        if not p:
            return "—"
        se = f" ± {p['se']:.2f}" if p.get("se") is not None else ""
        return f"{p['mean']:+.2f}{se} ({100 * p['ours_wins']:.0f}%)"

    for m in ("ours", "unified", "no_motion_isolation", "fixed_grid", "nearest_frame", "depth_warp", "mean_colour"):
        if view_set == "source" and m in SKIPPED_ON_SOURCE:
            lines.append(f"| {METHODS[m]} | skipped: the target is the source camera (trivially exact) |"
                         + " |" * 7)
            continue
        if view_set.startswith("multi") and m in SKIPPED_ON_SOURCE:
            lines.append(f"| {METHODS[m]} | skipped: a single-source baseline |" + " |" * 7)
            continue
        if m not in s:
            continue
        e = s[m]
        size = f"{file_bytes(e):.0f}" if file_bytes(e) else "—"
        lines.append(f"| {e['label']} | {e['floats']:,} | {size} | {_fmt(e['psnr'])} | {_fmt(e['ssim'], 3)} | "
                     f"{_fmt(e['psnr_dynamic'])} | {_fmt(e['psnr_static'])} | {paired(e, 'psnr')} | "
                     f"{paired(e, 'psnr_dynamic')} |")
    out = "\n".join(lines)
    if "ours" in s and "mean_colour" in s:
        p = s["mean_colour"].get("ours_minus_this_psnr")
        se = f" ± {p['se']:.2f}" if p and p.get("se") is not None else ""
        diff = (f"ours − flat {p['mean']:+.2f}{se} dB (ours higher on {100 * p['ours_wins']:.0f}% of the views)"
                if p else "no paired difference")
        out += (f"\n\nFlat mean-colour reference: {_fmt(s['mean_colour']['psnr'])} dB; ours "
                f"{_fmt(s['ours']['psnr'])} dB; {diff}.")
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


HEALTH_LABELS = {"main": "ours", "unified": "unified", "no_motion": "w/o motion isolation", "fixed_grid": "fixed grid"}


def format_health(health: dict[str, Any], stored: str = "int8") -> str:
    """The token-health table: one column per token model, PASS/FAIL next to issue 12's thresholds."""
    keys = list(health["models"])
    th = health.get("thresholds", HEALTH_THRESHOLDS)
    n = max(e["scenes"] for e in health["models"].values())

    def num(v: Any, nd: int = 3) -> str:
        return "n/a" if v is None else f"{v:.{nd}f}"

    def verdict(ok: Any) -> str:
        return "" if ok is None else (" PASS" if ok else " FAIL")

    def spread(e: dict[str, Any], group: str) -> str:
        v = e[f"{group}_spread"]
        return num(v) + verdict(None if v is None else v >= th["spread_min"])

    def swap(e: dict[str, Any]) -> str:
        if e.get("swap_drop_db") is None:
            return "n/a"
        se = f" ± {e['swap_drop_se_db']:.2f}" if e.get("swap_drop_se_db") is not None else ""
        return f"{e['swap_drop_db']:.2f}{se}" + verdict(e["swap_drop_db"] >= th["swap_drop_min_db"])

    rows = [
        (f"Z_s spread across slots / overall std (≥ {th['spread_min']})", lambda e: spread(e, "static")),
        (f"Z_d spread across slots / overall std (≥ {th['spread_min']})", lambda e: spread(e, "dynamic")),
        ("Z_s effective rank across scenes", lambda e: num(e["static_rank"], 2)),
        ("Z_d effective rank across scenes", lambda e: num(e["dynamic_rank"], 2)),
        ("Z_s saturation (abs z > 0.95)", lambda e: num(e["static_saturation"])),
        ("Z_d saturation (abs z > 0.95)", lambda e: num(e["dynamic_saturation"])),
        ("source-view PSNR, own tokens (dB)", lambda e: num(e.get("psnr_own_db"), 2)),
        ("source-view PSNR, next scene's tokens (dB)", lambda e: num(e.get("psnr_swapped_db"), 2)),
        (f"token-swap drop (dB, ≥ {th['swap_drop_min_db']})", swap),
    ]
    out = [f"### Token health ({n} held-out scenes of the {health['set']} set; {stored} tokens as stored)\n",
           "| | " + " | ".join(HEALTH_LABELS.get(k, k) for k in keys) + " |",
           "|---|" + "---:|" * len(keys)]
    out += [f"| {label} | " + " | ".join(f(health["models"][k]) for k in keys) + " |" for label, f in rows]
    return "\n".join(out) + "\n"


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
