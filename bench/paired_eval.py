#!/usr/bin/env python
"""Paired differences between two models evaluated on one protocol: per target set, the mean PSNR and SSIM of
each and the mean difference over the same (scene, view) rows with its standard error.

    python bench/paired_eval.py --pair q9 NEW_q9.json BASE_q9.json --pair q1 NEW_q1.json BASE_q1.json \
        [--out RESULTS.json]

Each file is the JSON of ``python -m vt4dcodec.eval --model M ... --methods ours --out F.json``. The two files of
a pair must share the protocol (scenes, first seed, views, cameras, frames, decode steps, quality level), or the
script refuses: a difference over other scenes says nothing. Prints one markdown table (a row per pair and set)
and writes the figures to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

PROTOCOL = ("scenes", "first_seed", "views", "num_cameras", "frames", "image_size", "steps", "seed", "quality")


def _rows(path: Path, method: str) -> tuple[dict[str, Any], dict[str, dict[tuple[Any, ...], dict[str, Any]]]]:
    data = json.loads(path.read_text())
    by_set: dict[str, dict[tuple[Any, ...], dict[str, Any]]] = {}
    for row in data["rows"]:
        if row.get("method") == method:
            by_set.setdefault(row["set"], {})[(row.get("seed"), row.get("view"), row.get("held"))] = row
    return data.get("settings", {}), by_set


def _mean_se(values: list[float]) -> tuple[float, float]:
    n = len(values)
    mean = sum(values) / n
    se = math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1) / n) if n > 1 else 0.0
    return mean, se


def compare(label: str, new: Path, base: Path, method: str = "ours") -> list[dict[str, Any]]:
    """One result per target set both files hold: the means of each file and the paired difference new - base."""
    (s_new, a), (s_base, b) = _rows(new, method), _rows(base, method)
    differ = [k for k in PROTOCOL if s_new.get(k) != s_base.get(k)]
    if differ:
        raise SystemExit(f"{label}: {new} and {base} differ in protocol ({', '.join(differ)})")
    out = []
    for name in sorted(set(a) & set(b)):
        keys = sorted(set(a[name]) & set(b[name]), key=str)
        if not keys:
            continue
        result: dict[str, Any] = {"pair": label, "set": name, "rows": len(keys)}
        for metric in ("psnr", "ssim"):
            result[f"{metric}_new"] = _mean_se([a[name][k][metric] for k in keys])[0]
            result[f"{metric}_base"] = _mean_se([b[name][k][metric] for k in keys])[0]
            result[f"{metric}_diff"], result[f"{metric}_diff_se"] = _mean_se(
                [a[name][k][metric] - b[name][k][metric] for k in keys])
        out.append(result)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pair", nargs=3, action="append", required=True, metavar=("LABEL", "NEW", "BASE"))
    parser.add_argument("--method", default="ours")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    results = [r for label, new, base in args.pair for r in compare(label, Path(new), Path(base), args.method)]
    print("| pair | set | rows | PSNR new | PSNR base | new - base (dB) | SSIM new | SSIM base | new - base |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in results:
        print(f"| {r['pair']} | {r['set']} | {r['rows']} | {r['psnr_new']:.2f} | {r['psnr_base']:.2f} | "
              f"{r['psnr_diff']:+.3f} ± {r['psnr_diff_se']:.3f} | {r['ssim_new']:.3f} | {r['ssim_base']:.3f} | "
              f"{r['ssim_diff']:+.4f} ± {r['ssim_diff_se']:.4f} |")
    if args.out is not None:
        args.out.write_text(json.dumps({"command": " ".join(sys.argv), "pairs": args.pair, "results": results},
                                        indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
