#!/usr/bin/env python
"""Write and read paper-size scenes (Z_s 1024x64 + Z_d 512x64, 32 frames) in every .vt4d encoding, and the
same arrays with np.savez_compressed and safetensors (+zstd), in one run.

    python bench/bench_format.py                 # 1,000 scenes per format (about a minute on 2 cores)
    python bench/bench_format.py --scenes 100    # quicker
    python bench/bench_format.py --scenes 1000 --round-size 50 --encodings int8,int4-rans,int8-rans,float16
                                                 # the entropy-coded 1.1 encodings (C rANS coder)

Throughput is "logical" MB/s: float32 token megabytes (1536 x 64 x 4 B = 0.393 MB per scene) handled per
second, the same yardstick for every format.  Write = encode + write the file (for vt4d exactly what save()
does: dumps(), then temp file, fsync, rename; "encode" is the dumps() part alone); read = read the file +
full validation + tokens as float32 arrays
(``load``); "tokens-only" reads the same int8 files with ``open_scene`` and decodes just the two token
sections (checksummed, but cameras and padding not checked).  Files go to a temporary directory (page cache warm, as in
repeated access to an archive).  "Per CPU second" divides by this process's CPU time instead of wall
time: on a shared machine it moves far less with the other jobs' load.  Tokens are i.i.d. Gaussian, the hardest case for compression; real encoder
outputs are smoother.  Results: bench/results/format.json.

Loader throughput (``--loader-scenes``, default 256; 0 skips it): the same paper-size scenes packed into one
``.vt4da`` archive per encoding (``--loader-encodings``, default int8 and the codec's default),
then scenes/s (wall, and per CPU second of this process) through ``ArchiveDataset`` in this process (every index in order: dequantized float32 token
tensors, K, w2c, metadata) and through a ``torch.utils.data.DataLoader`` with 2 worker processes
(batches of 16, token/camera tensors stacked; persistent workers, one untimed warm-up epoch, then
``--loader-epochs`` timed epochs).  Encodings take turns epoch by epoch, like the formats above.
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
import safetensors.numpy
import zstandard

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from vt4dcodec.cameras import Trajectory  # noqa: E402
from vt4dcodec.codec import DEFAULT_ENCODING  # noqa: E402
from vt4dcodec.format import ENCODINGS, ModelFingerprint, Provenance, Scene, dumps, load, open_scene  # noqa: E402
from vt4dcodec.format import rans  # noqa: E402
from vt4dcodec.format.encodings import V1_0_ENCODINGS  # noqa: E402

NS, ND, D, FRAMES = 1024, 512, 64, 32
TOKEN_MB = (NS + ND) * D * 4 / 1e6
POOL = 16  # distinct scenes, cycled (making them is not timed)


def make_scenes(seed: int) -> list[Scene]:
    rng = np.random.default_rng(seed)
    fp = ModelFingerprint("videotok4d-paper", "1.0", hashlib.sha256(b"cfg").hexdigest(),
                          hashlib.sha256(b"w").hexdigest(), (NS, D), (ND, D))
    K = np.tile([[220.0, 0, 127.5], [0, 220.0, 127.5], [0, 0, 1]], (FRAMES, 1, 1))
    out = []
    for i in range(POOL):
        w2c = np.tile(np.eye(4), (FRAMES, 1, 1))
        w2c[:, 0, 3] = np.linspace(-1, 1, FRAMES) + i
        w2c[:, 2, 3] = 3.0
        out.append(Scene(rng.standard_normal((NS, D)).astype(np.float32), rng.standard_normal((ND, D)).astype(np.float32),
                         Trajectory(K, w2c, 256, 256, timestamps=np.arange(FRAMES) / 30.0), fp,
                         {"pool_index": i}, Provenance("0.1.0", "2026-01-01T00:00:00Z", f"cap{i}", "encoded")))
    return out


def arrays_of(scene: Scene) -> dict[str, np.ndarray]:
    return {"static": scene.static_tokens, "dynamic": scene.dynamic_tokens, "K": scene.cameras.K,
            "w2c": scene.cameras.w2c, "timestamps": scene.cameras.timestamps}


# --- the formats: (write(scene, path) -> None, read(path) -> (static, dynamic)) ---------------------------
ENCODE_S = [0.0]  # seconds spent in dumps() (the CPU part of a vt4d write, without the durable file write)


def vt4d(encoding: str):
    def write(scene, path):
        t = time.perf_counter()
        data = dumps(scene, encoding=encoding)
        ENCODE_S[0] += time.perf_counter() - t
        save_bytes(data, path)

    def read(path):
        s = load(path)
        return s.static_tokens, s.dynamic_tokens
    return write, read


def save_bytes(data: bytes, path: str) -> None:
    """What save() does with dumps()'s bytes: temp file, fsync, atomic rename."""
    tmp = f"{path}.tmp-{os.getpid()}"
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def vt4d_lazy_tokens(encoding: str):
    """Same files as vt4d(encoding); read only the two token sections (CRC-checked) via open_scene."""
    write, _ = vt4d(encoding)

    def read(path):
        f = open_scene(path)
        return f.static_tokens(), f.dynamic_tokens()
    return write, read


def savez():
    def write(scene, path):
        with open(path, "wb") as fh:
            np.savez_compressed(fh, **arrays_of(scene))

    def read(path):
        with np.load(path, allow_pickle=False) as z:
            return z["static"], z["dynamic"]
    return write, read


def safetensors_zstd():
    cctx, dctx = zstandard.ZstdCompressor(level=3), zstandard.ZstdDecompressor()

    def write(scene, path):
        with open(path, "wb") as fh:
            fh.write(cctx.compress(safetensors.numpy.save(arrays_of(scene))))

    def read(path):
        with open(path, "rb") as fh:
            t = safetensors.numpy.load(dctx.decompress(fh.read()))
        return t["static"], t["dynamic"]
    return write, read


class Tally:
    """Accumulated timings of one format over all rounds."""

    def __init__(self, name: str, write, read) -> None:
        self.name, self.write, self.read = name, write, read
        self.n, self.write_s, self.read_s, self.bytes, self.err, self.encode_s = 0, 0.0, 0.0, 0, 0.0, 0.0
        self.write_cpu_s, self.read_cpu_s = 0.0, 0.0

    def round(self, scenes: list[Scene], start: int, count: int, workdir: str) -> None:
        paths = [os.path.join(workdir, f"{self.name}-{i}.bin") for i in range(count)]
        encode0, t0, c0 = ENCODE_S[0], time.perf_counter(), time.process_time()
        for k, p in enumerate(paths):
            self.write(scenes[(start + k) % POOL], p)
        t1, c1 = time.perf_counter(), time.process_time()
        self.encode_s += ENCODE_S[0] - encode0
        for k, p in enumerate(paths):
            static, dynamic = self.read(p)
            if k < POOL:  # check decoded values against the originals
                ref = scenes[(start + k) % POOL]
                self.err = max(self.err, float(np.abs(static - ref.static_tokens).max()),
                               float(np.abs(dynamic - ref.dynamic_tokens).max()))
        t2, c2 = time.perf_counter(), time.process_time()
        self.write_cpu_s += c1 - c0
        self.read_cpu_s += c2 - c1
        self.bytes += sum(os.path.getsize(p) for p in paths)
        for p in paths:
            os.unlink(p)
        self.n += count
        self.write_s += t1 - t0
        self.read_s += t2 - t1

    def result(self) -> dict:
        res = {"format": self.name, "scenes": self.n, "bytes_per_scene": round(self.bytes / self.n),
               "write_ms_per_scene": self.write_s / self.n * 1e3, "read_ms_per_scene": self.read_s / self.n * 1e3,
               "write_MBps": TOKEN_MB * self.n / self.write_s, "read_MBps": TOKEN_MB * self.n / self.read_s,
               "encode_MBps": TOKEN_MB * self.n / self.encode_s if self.encode_s else None,
               "write_cpu_MBps": TOKEN_MB * self.n / self.write_cpu_s, "read_cpu_MBps": TOKEN_MB * self.n / self.read_cpu_s,
               "max_abs_error": self.err}
        encode = f"(encode {res['encode_MBps']:6.0f})" if self.encode_s else " " * 15
        print(f"{self.name:>24}: {res['bytes_per_scene']:>8} B/scene  write {res['write_MBps']:7.1f} MB/s {encode}  "
              f"read {res['read_MBps']:7.1f} MB/s  | per CPU second: write {res['write_cpu_MBps']:6.0f} read "
              f"{res['read_cpu_MBps']:6.0f}  max err {self.err:.3g}", flush=True)
        return res


def _collate(batch: list[dict]) -> dict:
    import torch
    return {k: torch.stack([b[k] for b in batch]) for k in ("static_tokens", "dynamic_tokens", "K", "w2c")}


def loader_throughput(scenes: list[Scene], encodings: tuple[str, ...], n: int, epochs: int, workdir: str) -> list[dict]:
    """Scenes/s of ArchiveDataset (in process) and a 2-worker DataLoader, per encoding (module doc)."""
    from torch.utils.data import DataLoader

    from vt4dcodec.archive import ArchiveWriter
    from vt4dcodec.data.archive_dataset import ArchiveDataset
    from vt4dcodec.format import dumps

    datasets, loaders, rows = {}, {}, {}
    for enc in encodings:
        path = os.path.join(workdir, f"loader-{enc}.vt4da")
        records = [dumps(s, encoding=enc) for s in scenes]
        with ArchiveWriter(path, "w", durable=False) as w:
            for i in range(n):
                w.append(f"scene-{i:06d}", records[i % POOL])
        datasets[enc] = ArchiveDataset(path)
        loaders[enc] = DataLoader(datasets[enc], batch_size=16, num_workers=2, collate_fn=_collate,
                                  persistent_workers=True)
        for _ in loaders[enc]:  # warm-up epoch: worker start-up and first page-cache touch, not timed
            pass
        rows[enc] = {"encoding": enc, "scenes": n, "archive_bytes": os.path.getsize(path),
                     "dataset_s": 0.0, "dataset_cpu_s": 0.0, "dataloader_s": 0.0, "epochs": epochs}
    for _ in range(epochs):
        for enc in encodings:
            ds, t0, c0 = datasets[enc], time.perf_counter(), time.process_time()
            for i in range(len(ds)):
                ds[i]
            t1 = time.perf_counter()
            rows[enc]["dataset_cpu_s"] += time.process_time() - c0
            got = sum(b["static_tokens"].shape[0] for b in loaders[enc])
            t2 = time.perf_counter()
            assert got == n
            rows[enc]["dataset_s"] += t1 - t0
            rows[enc]["dataloader_s"] += t2 - t1
    out = []
    for enc in encodings:
        r = rows[enc]
        r["dataset_scenes_per_s"] = n * epochs / r["dataset_s"]
        r["dataset_scenes_per_cpu_s"] = n * epochs / r["dataset_cpu_s"]
        r["dataloader_2w_scenes_per_s"] = n * epochs / r["dataloader_s"]
        print(f"{'loader ' + enc:>24}: ArchiveDataset {r['dataset_scenes_per_s']:7.0f} scenes/s "
              f"({r['dataset_scenes_per_cpu_s']:5.0f} per CPU second)  "
              f"DataLoader(2 workers) {r['dataloader_2w_scenes_per_s']:7.0f} scenes/s", flush=True)
        out.append(r)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=1000, help="scenes written and read per format")
    parser.add_argument("--round-size", type=int, default=100, help="scenes per format per turn")
    parser.add_argument("--encodings", default=",".join(V1_0_ENCODINGS),
                        help=f"comma-separated .vt4d encodings, or 'all' (default: the 1.0 ones; any of {ENCODINGS})")
    parser.add_argument("--loader-scenes", type=int, default=256,
                        help="scenes per archive for the loader benchmark (0: skip it)")
    parser.add_argument("--loader-epochs", type=int, default=3, help="timed epochs of the loader benchmark")
    parser.add_argument("--loader-encodings", default=f"int8,{DEFAULT_ENCODING}",
                        help="encodings of the loader benchmark (default: int8 and the codec's default)")
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "format.json"))
    args = parser.parse_args()
    encodings = ENCODINGS if args.encodings == "all" else tuple(args.encodings.split(","))
    unknown = set(encodings) - set(ENCODINGS)
    if unknown:
        parser.error(f"unknown encoding(s) {sorted(unknown)}; choose from {ENCODINGS}")
    scenes = make_scenes(0)
    formats = [(f"vt4d-{e}", *vt4d(e)) for e in encodings]
    formats += [("vt4d-int8-tokens-only", *vt4d_lazy_tokens("int8"))]
    formats += [("npz_compressed-float32", *savez()), ("safetensors+zstd-float32", *safetensors_zstd())]
    tallies = [Tally(name, w, r) for name, w, r in formats]
    rounds = max(1, args.scenes // args.round_size)
    with tempfile.TemporaryDirectory(prefix="vt4d-bench-") as workdir:
        # Formats take turns, round by round, so a shared machine's changing load hits them all alike.
        for r in range(rounds):
            count = args.scenes // rounds + (1 if r < args.scenes % rounds else 0)
            for tally in tallies:
                tally.round(scenes, r * args.round_size, count, workdir)
            print(f"round {r + 1}/{rounds} done", file=sys.stderr, flush=True)
        results = [t.result() for t in tallies]
        loader = (loader_throughput(scenes, tuple(args.loader_encodings.split(",")), args.loader_scenes,
                                    args.loader_epochs, workdir) if args.loader_scenes else [])
    report = {"command": " ".join(["python bench/bench_format.py", *sys.argv[1:]]), "token_MB_per_scene": TOKEN_MB,
              "scene": {"static": [NS, D], "dynamic": [ND, D], "frames": FRAMES, "tokens": "iid N(0,1) float32"},
              "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "numpy": np.__version__,
                          "load_average_at_end": os.getloadavg(),
                          "zstd": ".".join(map(str, zstandard.ZSTD_VERSION))},
              "rans_coder": "C (_rans_native)" if rans.NATIVE else "pure Python (no C compiler at install)",
              "results": results, "loader": loader}
    Path(args.out).write_text(json.dumps(report, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
