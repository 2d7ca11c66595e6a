"""Micro-benchmark of the VideoTok4D networks (tiny config) on one CPU thread.

    python bench/bench_model.py [--repeats 5] [--out bench/results/model.json]

Measures, per sample: stage-2 training step (encode + rectified-flow loss + backward) in fp32 and
with bf16 autocast at batch 1 and 4; encoding; rendering a target trajectory with 8 Euler steps;
and the stage-1 autoencoder step. Random inputs of the right shapes (timing does not depend on
content, except the Temporal Branch's mask-restricted attention, run at 20% mask density).
Reports the median of ``--repeats`` runs after one warm-up, and the machine's load average, since
the machine is shared.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "model"))

from network_fixtures import random_batch  # noqa: E402

from vt4dcodec.model import VideoTok4D, get_config  # noqa: E402


def median_seconds(fn, repeats: int) -> tuple[float, float]:
    """Median (wall, process CPU) seconds of ``fn``. On a shared machine the CPU time of this
    single-threaded process is the figure that reflects one core; wall time includes waiting."""
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


def per(pair: tuple[float, float], n: int) -> tuple[float, float]:
    return pair[0] / n, pair[1] / n


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "model.json")
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    cfg = get_config("tiny")
    model = VideoTok4D(cfg)
    model.freeze_autoencoder()
    params = model.tokenizer_parameters()
    opt = torch.optim.AdamW(params, lr=1e-4)
    results: dict[str, tuple[float, float]] = {}

    for B in (1, 4):
        batch = random_batch(cfg, B=B, n_tracks=cfg.n_tracks, mask_density=0.2)
        target = torch.rand(B, cfg.frames, 3, cfg.image_size, cfg.image_size)
        for bf16 in (False, True):
            def step() -> None:
                with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
                    loss, _ = model.rectified_flow_loss(batch, target, batch.K, batch.w2c)
                opt.zero_grad()
                loss.backward()
                opt.step()

            model.train()
            key = f"train_step_{'bf16' if bf16 else 'fp32'}_batch{B}_s_per_sample"
            results[key] = per(median_seconds(step, args.repeats), B)
    model.eval()
    batch = random_batch(cfg, B=1, n_tracks=cfg.n_tracks)
    with torch.no_grad():
        results["encode_s_per_clip"] = median_seconds(lambda: model.encode(batch), args.repeats)
        z_s, z_d = model.encode(batch)
    results["render_8_steps_s_per_trajectory"] = median_seconds(
        lambda: model.render(z_s, z_d, batch.K, batch.w2c, steps=8, source=batch.source), args.repeats)
    ae = model.autoencoder
    ae.requires_grad_(True)
    images = torch.rand(32, 3, cfg.image_size, cfg.image_size)
    ae_opt = torch.optim.AdamW(ae.parameters(), lr=1e-4)

    def ae_step() -> None:
        loss = torch.nn.functional.l1_loss(ae(images), images)
        ae_opt.zero_grad()
        loss.backward()
        ae_opt.step()

    results["autoencoder_step_batch32_s_per_image"] = per(median_seconds(ae_step, args.repeats), 32)
    counts = {name: sum(p.numel() for p in getattr(model, name).parameters())
              for name in ("autoencoder", "spatial_branch", "temporal_branch", "renderer")}
    record = {
        "benchmark": "model", "config": "tiny", "threads": 1, "repeats": args.repeats,
        "torch": torch.__version__, "machine": platform.machine(), "load_average_1min": os.getloadavg()[0],
        "token_floats": cfg.token_floats, "source_values": cfg.frames * cfg.image_size ** 2 * 3,
        "parameters": counts, "parameters_total": sum(p.numel() for p in model.parameters()),
        "cpu_seconds": {k: round(v[1], 4) for k, v in results.items()},
        "wall_seconds": {k: round(v[0], 4) for k, v in results.items()},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=2) + "\n")
    print(json.dumps(record, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
