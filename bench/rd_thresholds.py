"""The rate-distortion thresholds of a codec study, read from a bench_codecs.py results file.

    python bench/rd_thresholds.py bench/results/codecs_rd.json [--out docs/benchmarks/rd_thresholds.md]

For each quality level (and token encoding) of the study: the whole capture's, one camera's and caliscope's
bytes over H.265's at equal PSNR (on the mean curves, and per clip as mean +- standard error over the clips
where H.265's curve brackets the PSNR), the five held-out views' PSNR from five stored cameras with the file's
bytes, and the span of the own-view PSNR over the levels. The targets are the codec's acceptance thresholds;
this script only reports, it changes none of them.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_codecs import bytes_at_psnr  # noqa: E402  (the study's own interpolation)

TARGETS = {"whole": 1.0, "single": 4.0, "caliscope": 2.0, "five_psnr": 22.6, "five_bytes": 3700.0, "span": 2.0}


def _ratio_cells(row: dict[str, Any], enc: str) -> tuple[str, str]:
    h = row["codecs"]["h265"]
    v = row["vt4d"][enc]
    # the mean curve: vt4d's mean point against H.265's mean curve (every size)
    from_mean = _equal(h["curve"] + h.get("low_rate", []), v)
    per = h.get("rate_ratio_per_clip", {}).get(enc)
    clip_text = "-"
    if per and per["mean"] is not None:
        se = f" +- {per['se']:.2f}" if per["se"] is not None else ""
        extra = (f", {per['at_most']} below H.265's cheapest" if per["at_most"] else "") + \
                (f", {per['unreachable']} above its best" if per["unreachable"] else "")
        clip_text = f"{per['mean']:.2f}x{se} ({per['clips']} clips{extra})"
    return from_mean, clip_text


def _equal(points: list[dict[str, Any]], v: dict[str, Any]) -> str:
    need, bound = bytes_at_psnr([(p["bytes"], p["psnr"]) for p in points], v["psnr"])
    if need is None:
        return "H.265 never reaches it"
    return f"{'>= ' if bound == 'at_most' else ''}{v['bytes'] / need:.2f}x"


def report(result: dict[str, Any]) -> str:
    lines = [f"Study: `{result['command']}`", ""]
    syn = result["datasets"].get("synthetic")
    cal = result["datasets"].get("caliscope")
    encs = list((syn or cal)["summary"]["single/captured"]["vt4d"])
    if syn:
        lines += _synthetic_lines(result, syn, encs)
    else:
        lines.append(f"Model {result['model']['fingerprint']}; real footage only (--scenes 0).")
    if cal:
        row = cal["summary"]["all/captured"]
        lines += ["", f"Caliscope, {cal['cameras']} cameras in one file ({cal['clips']} clips):", "",
                  "| level | B / dB | ratio (mean curve) | ratio per clip |", "|---|---|---|---|"]
        for enc in encs:
            m, c = _ratio_cells(row, enc)
            lines.append(f"| {enc} | {row['vt4d'][enc]['bytes']:,.0f} / {row['vt4d'][enc]['psnr']:.2f} | {m} | {c} |")
    lines += ["", f"Targets: whole capture <= {TARGETS['whole']}x, one camera <= {TARGETS['single']}x, five stored "
                  f">= {TARGETS['five_psnr']} dB from <= {TARGETS['five_bytes']:,.0f} B, span >= {TARGETS['span']} dB, "
                  f"caliscope <= {TARGETS['caliscope']}x."]
    return "\n".join(lines) + "\n"


def _synthetic_lines(result: dict[str, Any], syn: dict[str, Any], encs: list[str]) -> list[str]:
    s = syn["summary"]
    lines = [f"Model {result['model']['fingerprint']}; {syn['title']}, {syn['clips']} clips; bytes = the whole .vt4d "
             "file, H.265 = bitstream bytes summed over the stored cameras; ratio = vt4d bytes / H.265 bytes at "
             "vt4d's PSNR.", "",
             "| level | whole capture: B / dB | ratio (mean curve) | ratio per clip | one camera: B / dB | "
             "ratio (mean curve) | ratio per clip | five stored, held-out: dB +- SE from B |",
             "|---|---|---|---|---|---|---|---|"]
    for enc in encs:
        w, o, hn = s["all/captured"], s["single/captured"], s["half/novel"]
        w_mean, w_clip = _ratio_cells(w, enc)
        o_mean, o_clip = _ratio_cells(o, enc)
        se = hn.get("vt4d_se", {}).get(enc, {}).get("psnr")
        lines.append(f"| {enc} | {w['vt4d'][enc]['bytes']:,.0f} / {w['vt4d'][enc]['psnr']:.2f} | {w_mean} | {w_clip} | "
                     f"{o['vt4d'][enc]['bytes']:,.0f} / {o['vt4d'][enc]['psnr']:.2f} | {o_mean} | {o_clip} | "
                     f"{hn['vt4d'][enc]['psnr']:.2f}{f' +- {se:.2f}' if se is not None else ''} from "
                     f"{hn['vt4d'][enc]['bytes']:,.0f} |")
    levels = [e for e in encs if e.startswith("q")]
    if levels:
        own = [s["single/captured"]["vt4d"][e]["psnr"] for e in levels]
        rising = all(b > a for a, b in zip(own, own[1:]))
        lines += ["", f"Own-view span over the levels {levels[0]}..{levels[-1]}: {max(own) - min(own):.2f} dB "
                      f"(target >= {TARGETS['span']} dB), PSNR {'rising' if rising else 'NOT rising'} with the level."]
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("results", type=Path, help="a bench_codecs.py results JSON")
    p.add_argument("--out", type=Path, default=None, help="also write the report to this Markdown file")
    args = p.parse_args(argv)
    text = report(json.loads(args.results.read_text()))
    print(text, end="")
    if args.out is not None:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
