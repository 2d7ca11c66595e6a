#!/usr/bin/env python
"""Why adaptive rows are what they are (FORMAT.md I.6.2, required flag bit 10): ideal code lengths of learned-rans
tokens under the model's fixed rows, under the adaptive rule with other parameters, with each row split further by
a neighbour token's sign, and with a per-channel choice among tempered starting rows.

    python bench/probes/probe_adaptive_rows.py [--model vt4d-tiny] [--first-seed 2000] [--scenes 12]
        [--real-clips 6] [--levels 1,5,9] [--out FILE.json]

Tokens: held-out synthetic 10-camera captures (split test, tuning seeds) encoded whole, and caliscope's clips
(4 cameras each) when the sample data is found. For each level, every variant's bytes are the integer rule of
``rans.AdaptiveRows`` with its parameters (the rANS start of each symbol, ``-log2(f / 2^14)`` bits, no stream
overhead), summed over both matrices and averaged over the files of a set; printed as the saving against the
fixed rows (or, for the splits and tempered rows, against the shipped rule).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from vt4dcodec import codec  # noqa: E402
from vt4dcodec.format.learned import EntropyTables, coded_symbols, writer_codes  # noqa: E402
from vt4dcodec.synth import SynthConfig, generate_scene  # noqa: E402

M, P = 1 << 14, 1 << 16
RULES = {"shipped: D = n + k + 3": (1, 3, None), "D = n + k + 1": (1, 1, None), "D = k + 5": (0, 5, None),
         "D = 2n + k + 3": (2, 3, None), "shipped, D at most 24": (1, 3, 24), "shipped, D at most 96": (1, 3, 96)}
SPLITS = (8, 32)        # rows split by the sign of the same channel's code this many tokens back (MEAN tokens)
ALPHAS = (0.6, 0.8, 1.0, 1.25)  # tempered starting rows p^a, one choice per channel (2 bits each)


def bits(symbols: list[int], rows: list[int], freqs: np.ndarray, k0: int, c0: int, cap: int | None,
         keys: list[int] | None = None, alpha: np.ndarray | None = None) -> float:
    """Ideal bits of ``symbols`` coded with adaptive rows: row ``rows[i]`` (split by ``keys[i]``), starting from
    the table (tempered by ``alpha[channel]``, float) and moving by 1 / D, D = min(k0 n + k + c0, cap)."""
    state: dict[tuple[int, int], list] = {}
    total = 0.0
    for i, (s, t) in enumerate(zip(symbols, rows)):
        key = (t, keys[i] if keys is not None else 0)
        row = state.get(key)
        if row is None:
            f = freqs[t]
            n = int((f > 0).sum())
            if alpha is None:
                cum = np.concatenate([[0], np.cumsum(f[:n])]).astype(np.int64) << 2
            else:
                p = (f[:n] / M) ** alpha[t % len(alpha)]
                cum = np.round(np.concatenate([[0], np.cumsum(p / p.sum())]) * P).astype(np.int64)
                cum = np.maximum.accumulate(cum)
            row = state[key] = [cum.tolist(), n, 0]
        cum, n, k = row
        lo = ((cum[s] * (M - n)) >> 16) + s
        hi = ((cum[s + 1] * (M - n)) >> 16) + s + 1
        total -= np.log2((hi - lo) / M)
        D = k0 * n + k + c0
        D = min(D, cap) if cap else D
        for j in range(1, n):
            cum[j] = cum[j] - cum[j] // D if j <= s else cum[j] + (P - cum[j]) // D
        row[2] = k + 1
    return total


def file_bits(tokens: tuple[np.ndarray, np.ndarray], views: int, tables: EntropyTables, level: int
              ) -> dict[str, float]:
    freqs = tables.freqs[level].reshape(-1, tables.freqs.shape[3]).astype(np.int64)
    d = tables.freqs.shape[2]
    out: dict[str, float] = {}
    for which, x in zip(("static", "dynamic"), tokens):
        codes = writer_codes(x, tables, level, which, views)
        sym, ctx = (a.reshape(-1) for a in coded_symbols(codes, tables, level, views, which))
        symbols, rows = sym.tolist(), ctx.tolist()
        out["fixed rows"] = out.get("fixed rows", 0.0) - float(np.log2(freqs[ctx, sym] / M).sum())
        for name, (k0, c0, cap) in RULES.items():
            out[name] = out.get(name, 0.0) + bits(symbols, rows, freqs, k0, c0, cap)
        origin = np.asarray(tables.origins[views - 1])
        mean = np.repeat(origin == np.arange(len(origin)), d) if which == "static" else np.zeros(sym.size, bool)
        for off in SPLITS:
            sign = np.zeros_like(codes)
            sign[off:] = np.sign(codes[:-off])
            keys = np.where(mean, sign.reshape(-1) + 1, 3).tolist()
            name = f"shipped, MEAN rows split by token i-{off}"
            out[name] = out.get(name, 0.0) + bits(symbols, rows, freqs, 1, 3, None, keys)
        per_channel = np.zeros((len(ALPHAS), d))
        for a, alpha in enumerate(ALPHAS):
            for c in range(d):
                pick = [i for i, t in enumerate(rows) if t % d == c]
                per_channel[a, c] = bits([symbols[i] for i in pick], [rows[i] for i in pick], freqs, 1, 3, None,
                                         alpha=np.full(d, alpha))
        name = "shipped, tempered start chosen per channel"
        out[name] = out.get(name, 0.0) + float(per_channel.min(axis=0).sum() + 2 * d)
    return {k: v / 8 for k, v in out.items()}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default="vt4d-tiny")
    p.add_argument("--first-seed", type=int, default=2000)
    p.add_argument("--scenes", type=int, default=12)
    p.add_argument("--real-clips", type=int, default=6)
    p.add_argument("--levels", default="1,5,9")
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args()
    torch.set_num_threads(2)
    net = codec.load_model(args.model).eval()
    tables, frames = codec.model_tables(net), net.config.frames
    sets: dict[str, list[tuple[tuple[np.ndarray, np.ndarray], int]]] = {"synthetic": [], "caliscope": []}
    for seed in range(args.first_seed, args.first_seed + args.scenes):
        cap = generate_scene(seed, split="test", config=SynthConfig(num_cameras=10, num_frames=frames,
                                                                      height=net.config.image_size,
                                                                      width=net.config.image_size)).capture
        scene = codec.encode(cap, net, cameras=list(cap.camera_names), seed=0)
        sets["synthetic"].append(((scene.static_tokens, scene.dynamic_tokens), len(cap.camera_names)))
    if args.real_clips:
        from vt4dcodec.capture.caliscope import find_sample_capture
        from vt4dcodec.eval.real_footage import open_capture

        found = find_sample_capture()
        if found is not None:
            source = open_capture(found, size=net.config.image_size)
            for start in list(range(0, source.num_frames - frames + 1, frames))[:args.real_clips]:
                scene = codec.encode(source, net, cameras=list(source.camera_names), start=start, seed=0)
                sets["caliscope"].append(((scene.static_tokens, scene.dynamic_tokens), len(source.camera_names)))
    result: dict[str, dict[str, dict[str, float]]] = {}
    for level in (int(v) for v in args.levels.split(",")):
        for name, files in sets.items():
            if not files:
                continue
            rows = [file_bits(tok, views, tables, level - 1) for tok, views in files]
            mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
            result[f"q{level} {name}"] = mean
            fixed, shipped = mean["fixed rows"], mean["shipped: D = n + k + 3"]
            print(f"q{level} {name} ({len(files)} files): fixed rows {fixed:,.0f} B")
            for k, v in mean.items():
                if k != "fixed rows":
                    ref = fixed if k in RULES else shipped
                    print(f"    {k}: {v:,.0f} B ({100 * (1 - v / ref):+.1f} % against "
                          f"{'the fixed rows' if k in RULES else 'the shipped rule'})")
    if args.out:
        args.out.write_text(json.dumps({"command": " ".join(sys.argv), "bytes": result}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
