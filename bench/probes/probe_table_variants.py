#!/usr/bin/env python
"""What would a per-file choice among tempered variants of each channel's entropy tables save on learned-rans
tokens? For each token matrix of a ``.vt4d`` file, the ideal code length of its symbols under the model's
tables, and under the best of a few tempered versions ``p^a`` (renormalised) of each channel's tables, chosen
per channel with log2(variants) bits of side information each.

    python bench/probes/probe_table_variants.py FILE.vt4d [FILE.vt4d ...]

Ideal code lengths (no rANS overhead); the variants are float, so this bounds what integer variant tables stored
with a model could save.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from vt4dcodec.format import loads, open_scene  # noqa: E402
from vt4dcodec.format.learned import coded_symbols, writer_codes  # noqa: E402

ALPHAS = (0.6, 0.75, 0.9, 1.0, 1.15, 1.35)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+", type=Path)
    args = ap.parse_args()
    for path in args.files:
        data = path.read_bytes()
        scene, f = loads(data), open_scene(data)
        tables = f.entropy_tables()
        level, views = scene.quality - 1, 1 + len(scene.extra_cameras)
        d = tables.freqs.shape[2]
        base = best = 0.0
        for which, tokens in (("static", scene.static_tokens), ("dynamic", scene.dynamic_tokens)):
            codes = writer_codes(tokens, tables, level, which, views)
            symbols, contexts = coded_symbols(codes, tables, level, views, which)
            freqs = tables.freqs[level].reshape(-1, tables.freqs.shape[3]).astype(np.float64) + 1e-9
            contexts, symbols = contexts.reshape(-1), symbols.reshape(-1)
            channel = contexts % d
            for c in range(d):
                mask = channel == c
                costs = []
                for a in ALPHAS:
                    p = freqs[contexts[mask]] ** a
                    p /= p.sum(axis=1, keepdims=True)
                    costs.append(-np.log2(p[np.arange(mask.sum()), symbols[mask]]).sum())
                base += costs[ALPHAS.index(1.0)]
                best += min(costs) + np.log2(len(ALPHAS))
        print(f"{path}: tokens {base / 8:.0f} B under the model's tables, {best / 8:.0f} B with the best variant "
              f"per channel ({100 * (1 - best / base):.1f} % less)")


if __name__ == "__main__":
    main()
