#!/usr/bin/env python
"""Rate-distortion study of the .vt4d token encodings: bytes per scene against novel-view PSNR.

    python bench/bench_rate_distortion.py                       # vt4d-tiny, 20 test scenes x 3 novel views
    python bench/bench_rate_distortion.py --model /tmp/m --scenes 2 --views 1   # a quick run

For each held-out synthetic scene (``generate_scene(seed, split="test")``) camera 0 is encoded once with
``vt4dcodec.codec.encode`` (float32 tokens); the scene is then saved with every encoding below, loaded back
from the bytes, and cameras 1..V (never seen by the encoder) are rendered with ``SceneDecoder`` from the
decoded tokens (same seed and steps for every encoding, so only the tokens differ) and compared with the
ground-truth frames by ``vt4dcodec.media.psnr``.  PSNR loss = PSNR(float32 tokens) - PSNR(encoding), per
view, averaged.  Token sets that decode to identical arrays are rendered once.

Bytes: the whole ``.vt4d`` file, and the token bytes alone (stored payloads of ZSTA, ZDYN, QSTA, QDYN).
For scale: the source camera's clip (the 8 fitted frames the encoder saw) written as an H.264 mp4 by the project's
writer (``vt4dcodec.media.write_mp4``).  Entropy back-ends compared on the *same* codes (so at exactly the
same distortion): the rANS section vs. zstd (level 19) over the codes stored one per byte, and vs. zstd over
the same per-channel centre residuals the rANS section may use (plus the centre bytes), each plus the same
8-byte quantization pair.

Writes bench/results/rate_distortion.json and docs/figures/rate_distortion.png and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zstandard

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vt4dcodec.codec import DEFAULT_ENCODING  # noqa: E402
from vt4dcodec.format import dumps, loads, open_scene  # noqa: E402
from vt4dcodec.format.affine import affine_codes, group_params  # noqa: E402
from vt4dcodec.format.rans_tokens import RANS_BITS, encode_rans_tokens  # noqa: E402

TOKEN_SECTIONS = ("ZSTA", "ZDYN", "QSTA", "QDYN")
MAX_LOSS_DB = 0.1


def configs(d: int) -> list[tuple[str, str, int]]:
    """(label, encoding, groups) of every encoding studied."""
    out = [("float32", "float32", 1), ("float16", "float16", 1), ("int8", "int8", 1), ("int4", "int4", 1)]
    out += [(f"int{b}-rans", f"int{b}-rans", 1) for b in (8, 6, 5, 4, 3, 2)]
    out += [(f"int{b}-rans/g{d}", f"int{b}-rans", d) for b in (6, 4)]  # per-channel scale/offset
    return out


def token_bytes(data: bytes) -> int:
    return sum(e.stored_length for e in open_scene(data).sections if e.type in TOKEN_SECTIONS)


def zstd_codes_bytes(x: np.ndarray, bits: int) -> tuple[int, int]:
    """Bytes of the same one-group b-bit codes as int<b>-rans with zstd -19 instead of rANS, plus the 8-byte
    (scale, offset) pair: (codes one per byte, per-channel centre residuals one per byte + d centre bytes)."""
    scale, offset = group_params(x, bits, 1)
    codes = affine_codes(x, np.repeat(scale, x.shape[1]), np.repeat(offset, x.shape[1]), bits)
    centre = np.sort(codes, axis=0)[(codes.shape[0] - 1) // 2]
    residual = (codes.astype(np.int16) - centre + (1 << bits) - 1).astype(np.uint16)
    zstd = zstandard.ZstdCompressor(level=19)
    plain = len(zstd.compress(codes.tobytes())) + 8
    delta = len(zstd.compress(residual.astype(np.uint8 if bits < 8 else np.uint16).tobytes())) + 8 + x.shape[1]
    return plain, delta


def mp4_bytes(frames: np.ndarray, fps: float) -> int:
    from vt4dcodec.media import write_mp4

    with tempfile.TemporaryDirectory() as tmp:
        return write_mp4(Path(tmp) / "source.mp4", frames, fps).stat().st_size


def run(args: argparse.Namespace) -> dict:
    import torch

    from vt4dcodec.capture.resample import fit_capture
    from vt4dcodec.codec import SceneDecoder, encode, load_model
    from vt4dcodec.media import psnr
    from vt4dcodec.synth import generate_scene

    torch.set_num_threads(args.threads)
    net = load_model(args.model)
    cfg = net.config
    labels = configs(cfg.token_dim)
    per_scene = []
    started, cpu0 = time.perf_counter(), time.process_time()
    for seed in range(args.first_seed, args.first_seed + args.scenes):
        synth = generate_scene(seed, split="test")
        cap = synth.capture
        names = cap.camera_names
        source, novel = names[0], names[1:1 + args.views]
        scene = encode(cap, net, "float32", camera=source)
        fitted = fit_capture(cap, height=cfg.image_size, width=cfg.image_size, num_frames=cfg.frames)
        truth = [fitted.frames[n] for n in novel]
        targets = [fitted.cameras[n] for n in novel]
        rendered: dict[str, list[float]] = {}
        rows = {}
        for label, encoding, groups in labels:
            data = dumps(scene, encoding=encoding, groups=groups)
            decoded = loads(data)
            key = hashlib.sha256(decoded.static_tokens.tobytes() + decoded.dynamic_tokens.tobytes()).hexdigest()
            if key not in rendered:
                videos = SceneDecoder.open(decoded, model=net).render_many(targets, steps=args.steps, seed=0)
                rendered[key] = [psnr(v, t) for v, t in zip(videos, truth)]
            err = np.concatenate([(decoded.static_tokens - scene.static_tokens).ravel(),
                                  (decoded.dynamic_tokens - scene.dynamic_tokens).ravel()])
            rows[label] = {"encoding": encoding, "groups": groups, "file_bytes": len(data),
                           "token_bytes": token_bytes(data), "psnr": rendered[key],
                           "token_rmse": float(np.sqrt(np.mean(err.astype(np.float64) ** 2)))}
            if encoding in RANS_BITS and groups == 1:
                bits = RANS_BITS[encoding]
                alt = [zstd_codes_bytes(x, bits) for x in (scene.static_tokens, scene.dynamic_tokens)]
                rows[label]["zstd_same_codes_bytes"] = sum(a[0] for a in alt)
                rows[label]["zstd_centre_residual_bytes"] = sum(a[1] for a in alt)
                rows[label]["rans_payload_bytes"] = sum(len(encode_rans_tokens(x, encoding, 1)) for x in
                                                        (scene.static_tokens, scene.dynamic_tokens))
        per_scene.append({"seed": seed, "source_camera": source, "novel_cameras": novel,
                          "mp4_bytes": mp4_bytes(fitted.frames[source], cap.fps),
                          "token_range": [float(min(scene.static_tokens.min(), scene.dynamic_tokens.min())),
                                          float(max(scene.static_tokens.max(), scene.dynamic_tokens.max()))],
                          "encodings": rows})
        print(f"scene {seed}: " + ", ".join(f"{k} {v['file_bytes']}B {np.mean(v['psnr']):.2f}dB"
                                            for k, v in rows.items()), flush=True)
    return summarize(args, cfg, labels, per_scene, time.perf_counter() - started, time.process_time() - cpu0)


def summarize(args, cfg, labels, per_scene, wall: float, cpu: float) -> dict:
    ref = np.array([p for s in per_scene for p in s["encodings"]["float32"]["psnr"]])
    fp32_token_bytes = 4 * (cfg.n_static + cfg.n_dynamic) * cfg.token_dim
    table = []
    for label, encoding, groups in labels:
        rows = [s["encodings"][label] for s in per_scene]
        p = np.array([v for r in rows for v in r["psnr"]])
        entry = {"label": label, "encoding": encoding, "groups": groups,
                 "file_bytes": float(np.mean([r["file_bytes"] for r in rows])),
                 "token_bytes": float(np.mean([r["token_bytes"] for r in rows])),
                 "token_fraction_of_fp32": float(np.mean([r["token_bytes"] for r in rows])) / fp32_token_bytes,
                 "psnr_db": float(p.mean()), "psnr_loss_db": float((ref - p).mean()),
                 "psnr_loss_db_max_view": float((ref - p).max()),
                 "token_rmse": float(np.mean([r["token_rmse"] for r in rows]))}
        if "zstd_same_codes_bytes" in rows[0]:
            entry["zstd_same_codes_bytes"] = float(np.mean([r["zstd_same_codes_bytes"] for r in rows]))
            entry["zstd_centre_residual_bytes"] = float(np.mean([r["zstd_centre_residual_bytes"] for r in rows]))
            entry["rans_payload_bytes"] = float(np.mean([r["rans_payload_bytes"] for r in rows]))
        table.append(entry)
    # the codec's rule (vt4dcodec/codec.py, DEFAULT_ENCODING): the smallest file among the encodings a default
    # can name (one scale per stream, no channel groups) whose *worst* held-out view stays within MAX_LOSS_DB
    ok = [t for t in table if t["groups"] == 1 and t["psnr_loss_db_max_view"] <= MAX_LOSS_DB]
    default = min(ok, key=lambda t: t["file_bytes"]) if ok else None
    return {
        "command": "python bench/bench_rate_distortion.py " + " ".join(sys.argv[1:]),
        "model": str(args.model), "model_label": args.label or str(args.model), "model_config": cfg.name, "scenes": args.scenes, "views": args.views,
        "steps": args.steps, "split": "test", "first_seed": args.first_seed,
        "fp32_token_bytes": fp32_token_bytes, "max_loss_db": MAX_LOSS_DB,
        "mp4_bytes_mean": float(np.mean([s["mp4_bytes"] for s in per_scene])),
        "recommended_default": None if default is None else default["label"],
        "recommended_meets_1_16": bool(default and default["token_bytes"] * 16 <= fp32_token_bytes),
        "table": table, "per_scene": per_scene,
        "wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "threads": args.threads,
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                    "load_avg_1min": os.getloadavg()[0]},
    }


def markdown(result: dict) -> str:
    lines = ["| encoding | file bytes | token bytes | tokens / fp32 | PSNR dB | loss dB (mean) | loss dB (worst view) "
             "| token RMSE |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for t in result["table"]:
        lines.append(f"| {t['label']} | {t['file_bytes']:.0f} | {t['token_bytes']:.0f} | "
                     f"1/{result['fp32_token_bytes'] / t['token_bytes']:.1f} | {t['psnr_db']:.3f} | "
                     f"{t['psnr_loss_db']:+.3f} | {t['psnr_loss_db_max_view']:+.3f} | {t['token_rmse']:.4f} |")
    lines.append(f"| source clip, H.264 mp4 (vt4dcodec.media.write_mp4) | {result['mp4_bytes_mean']:.0f} | | | | | | |")
    lines += ["", "Entropy back-ends on the same codes (token payload bytes per scene, both matrices):", "",
              "| codes | rANS section (kept) | zstd -19, codes | zstd -19, centre residuals |", "|---|---:|---:|---:|"]
    for t in result["table"]:
        if "rans_payload_bytes" in t:
            lines.append(f"| {t['label']} | {t['rans_payload_bytes']:.0f} | {t['zstd_same_codes_bytes']:.0f} | "
                         f"{t['zstd_centre_residual_bytes']:.0f} |")
    return "\n".join(lines)


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    markers = "osD^v<>pPX*hH"
    for k, t in enumerate(result["table"]):
        style = {"marker": markers[k % len(markers)], "s": 36, "color": f"C{k % 10}", "label": t["label"]}
        if t["label"] == DEFAULT_ENCODING:  # the codec's default: what users get
            style.update(edgecolor="black", linewidth=1.5, label=t["label"] + " (default)")
        elif t["label"] == result["recommended_default"]:  # what the rule picks, when it is not the default yet
            style.update(label=t["label"] + " (the rule's pick)")
        ax1.scatter(t["token_bytes"], t["psnr_loss_db"], **style)
        ax2.scatter(t["file_bytes"], t["psnr_loss_db"], **{k2: v for k2, v in style.items() if k2 != "label"})
    for ax, title in ((ax1, "token bytes per scene (ZSTA+ZDYN+QSTA+QDYN)"), (ax2, "file bytes per scene")):
        ax.set_xscale("log")
        ax.axhline(MAX_LOSS_DB, color="gray", lw=0.8, ls="--")
        ax.set_xlabel(title)
        ax.set_ylabel("PSNR loss vs float32 tokens (dB)")
        ax.grid(alpha=0.3)
    ax1.axvline(result["fp32_token_bytes"] / 16, color="gray", lw=0.8, ls=":")
    ax2.axvline(result["mp4_bytes_mean"], color="C2", lw=0.8)
    ax2.annotate("H.264 mp4 of the source clip", (result["mp4_bytes_mean"], MAX_LOSS_DB * 0.9), fontsize=7, color="C2")
    ax1.legend(fontsize=7, ncol=2, loc="upper right")
    fig.suptitle(f"{result.get('model_label', result['model'])}: {result['scenes']} test scenes x {result['views']} novel views, "
                 f"{result['steps']} steps (dashed: {MAX_LOSS_DB} dB budget; dotted: 1/16 of fp32 token bytes)",
                 fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="vt4d-tiny", help="shipped model id or model directory")
    parser.add_argument("--label", default=None, help="model name for the plot and JSON (default: --model)")
    parser.add_argument("--scenes", type=int, default=20)
    parser.add_argument("--views", type=int, default=3, help="novel cameras per scene (cameras 1..V)")
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, default=ROOT / "bench/results/rate_distortion.json")
    parser.add_argument("--plot", type=Path, default=ROOT / "docs/figures/rate_distortion.png")
    args = parser.parse_args()
    result = run(args)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    plot(result, args.plot)
    print(markdown(result))
    print(f"recommended default: {result['recommended_default']} (meets 1/16: {result['recommended_meets_1_16']}); "
          f"wall {result['wall_s']} s, cpu {result['cpu_s']} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
