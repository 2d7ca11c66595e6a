#!/usr/bin/env python
"""Speed and size of the synthetic scene generator (vt4dcodec.synth).

    python bench/bench_synth.py                      # ~2 min: 12 in-memory scenes + 200 on disk
    python bench/bench_synth.py --disk-scenes 0      # in-memory timing only
    python bench/bench_synth.py --full               # ALSO the real 2,000 train + 100 test run

Measures, for the default config (10 cameras, 8 frames, 64x64):
* generate: ms per scene for ``generate_scene`` in one process (CPU time and wall time, median);
* write: ms per scene for ``write_scene`` (PNG RGB, 16-bit PNG depth, flow .npy, masks .npz);
* dataset: wall seconds for ``write_dataset(..., workers=2)`` of ``--disk-scenes`` train scenes
  (the `vt4d synth` path), extrapolated linearly to 2,100 scenes; the workers' CPU seconds per scene
  (independent of other users' load) and from them the time on an idle 2-core machine; bytes on disk;
* with ``--full``: the two documented commands, timed end to end.
The machine is shared, so the 1-minute load average before and after is recorded with the numbers.
Scenes are written under a temporary directory that is deleted afterwards.
Results: bench/results/synth.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vt4dcodec.synth import SynthConfig, generate_scene, write_dataset, write_scene  # noqa: E402
from vt4dcodec.synth.assets import texture_bank  # noqa: E402


def _du(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def _count_files(path: Path) -> int:
    return sum(1 for f in path.rglob("*") if f.is_file())


def bench_memory(n: int, tmp: Path) -> dict:
    texture_bank("train")                       # one-time per process, reported separately
    generate_scene(10_000)                      # warm-up
    cpu, wall, write = [], [], []
    for seed in range(n):
        c0, w0 = time.process_time(), time.perf_counter()
        scene = generate_scene(seed)
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
        w0 = time.perf_counter()
        write_scene(scene, tmp / f"w{seed}")
        write.append(time.perf_counter() - w0)
    return {
        "scenes": n,
        "generate_cpu_ms_median": 1e3 * float(np.median(cpu)),
        "generate_cpu_ms_min": 1e3 * float(np.min(cpu)),
        "generate_wall_ms_median": 1e3 * float(np.median(wall)),
        "write_wall_ms_median": 1e3 * float(np.median(write)),
        "bytes_per_scene": _du(tmp / "w0"),
        "files_per_scene": _count_files(tmp / "w0"),
    }


def bench_texture_bank() -> dict:
    texture_bank.cache_clear()
    from vt4dcodec.synth.assets import load_texture

    load_texture.cache_clear()
    t0 = time.perf_counter()
    texture_bank("train")
    t1 = time.perf_counter()
    texture_bank("test")
    return {"train_bank_s": t1 - t0, "test_bank_s": time.perf_counter() - t1}


def _cpu_children() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def bench_dataset(n: int, workers: int, tmp: Path) -> dict:
    """The `vt4d synth` path.  Worker CPU time (rusage of the joined worker processes) does not depend
    on how busy the shared machine is, so it also gives the time on an otherwise idle machine."""
    out = tmp / "dataset"
    cpu0, t0 = _cpu_children(), time.perf_counter()
    write_dataset(out, num_scenes=n, split="train", seed=0, config=SynthConfig(), workers=workers)
    secs = time.perf_counter() - t0
    cpu = _cpu_children() - cpu0
    return {
        "scenes": n, "workers": workers, "wall_s": secs, "scenes_per_s": n / secs,
        "extrapolated_2100_scenes_min": 2100 * secs / n / 60.0,
        "worker_cpu_s": cpu, "worker_cpu_ms_per_scene": 1e3 * cpu / n,
        "idle_machine_estimate_2100_scenes_min": 2100 * cpu / n / min(workers, os.cpu_count() or 1) / 60.0,
        "bytes_per_scene": _du(out) / n,
    }


def bench_full(tmp: Path) -> dict:
    out = tmp / "synth"
    cmds = [["vt4d", "synth", "-n", "2000", "--split", "train", "-o", str(out / "train"), "-q"],
            ["vt4d", "synth", "-n", "100", "--split", "test", "-o", str(out / "test"), "-q"]]
    t0 = time.perf_counter()
    for cmd in cmds:
        subprocess.run(cmd, check=True)
    secs = time.perf_counter() - t0
    return {"commands": [" ".join(c[:-3] + [c[-2].replace(str(tmp), "data")]) for c in cmds],
            "wall_s": secs, "wall_min": secs / 60.0, "bytes": _du(out), "files": _count_files(out)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--memory-scenes", type=int, default=12)
    ap.add_argument("--disk-scenes", type=int, default=200)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--full", action="store_true", help="also time the full 2,000 + 100 scene run")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "synth.json"))
    args = ap.parse_args()
    result: dict = {
        "config": SynthConfig().to_dict(),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "load_avg_1min_before": os.getloadavg()[0]},
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    tmp = Path(tempfile.mkdtemp(prefix="bench_synth_"))
    try:
        result["texture_bank"] = bench_texture_bank()
        result["in_memory"] = bench_memory(args.memory_scenes, tmp)
        print(json.dumps(result["in_memory"], indent=1))
        if args.disk_scenes > 0:
            result["dataset"] = bench_dataset(args.disk_scenes, args.workers, tmp)
            print(json.dumps(result["dataset"], indent=1))
        if args.full:
            result["full"] = bench_full(tmp)
            print(json.dumps(result["full"], indent=1))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    result["machine"]["load_avg_1min_after"] = os.getloadavg()[0]
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
