#!/usr/bin/env python
"""Two real-footage results of the same capture and protocol, paired per clip: each camera's PSNR and SSIM
difference (new - base, mean +- standard error over the clips both files hold) and both models' margin over
the flat image of the clip's mean colour.

    python bench/probes/paired_real.py NEW.json BASE.json [NEW2.json BASE2.json ...] [--out FILE.json]

Inputs are files of ``python -m vt4dcodec.eval.real_footage ... --out F`` (their "rows"); the pairs must
come from the same capture, sources, quality and clips (checked: the same flat-image rows).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def _rows(path: Path) -> tuple[dict, dict]:
    rows = json.loads(path.read_text())["rows"]
    ours = {(r["camera"], r["clip_start"]): r for r in rows if r["method"] == "ours"}
    flat = {(r["camera"], r["clip_start"]): r for r in rows if r["method"] == "mean_colour"}
    return ours, flat


def _mean_se(values: list[float]) -> tuple[float, float]:
    v = np.asarray(values, dtype=np.float64)
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(len(v))) if len(v) > 1 else 0.0


def pair(new: Path, base: Path) -> dict:
    a, flat_a = _rows(new)
    b, flat_b = _rows(base)
    out = {"new": str(new), "base": str(base), "cameras": {}}
    for cam in sorted({k[0] for k in a}):
        keys = sorted(k for k in a if k[0] == cam and k in b)
        if not keys:
            continue
        if any(abs(flat_a[k]["psnr"] - flat_b[k]["psnr"]) > 1e-3 for k in keys if k in flat_a and k in flat_b):
            raise SystemExit(f"{new} and {base} differ in their flat-image rows for {cam}: not the same protocol")
        dp, dp_se = _mean_se([a[k]["psnr"] - b[k]["psnr"] for k in keys])
        ds, ds_se = _mean_se([a[k]["ssim"] - b[k]["ssim"] for k in keys])
        out["cameras"][cam] = {
            "clips": len(keys), "psnr_diff": dp, "psnr_diff_se": dp_se, "ssim_diff": ds, "ssim_diff_se": ds_se,
            "new_over_flat": _mean_se([a[k]["psnr"] - flat_a[k]["psnr"] for k in keys])[0],
            "base_over_flat": _mean_se([b[k]["psnr"] - flat_b[k]["psnr"] for k in keys])[0],
            "new_ssim": float(np.mean([a[k]["ssim"] for k in keys])),
            "base_ssim": float(np.mean([b[k]["ssim"] for k in keys])),
        }
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+", type=Path, help="NEW BASE pairs")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    if len(args.files) % 2:
        print("give the files in NEW BASE pairs", file=sys.stderr)
        return 2
    pairs = [pair(n, b) for n, b in zip(args.files[::2], args.files[1::2])]
    for p in pairs:
        print(f"{p['new']}  vs  {p['base']}")
        for cam, r in p["cameras"].items():
            print(f"  {cam}: {r['clips']} clips  PSNR {r['psnr_diff']:+.3f} +- {r['psnr_diff_se']:.3f} dB  SSIM "
                  f"{r['ssim_diff']:+.4f} +- {r['ssim_diff_se']:.4f}  over flat {r['new_over_flat']:+.2f} "
                  f"(base {r['base_over_flat']:+.2f}), SSIM {r['new_ssim']:.3f} (base {r['base_ssim']:.3f})")
    if args.out is not None:
        args.out.write_text(json.dumps({"command": "python bench/probes/paired_real.py "
                                        + " ".join(argv if argv is not None else sys.argv[1:]), "pairs": pairs},
                                       indent=1) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
