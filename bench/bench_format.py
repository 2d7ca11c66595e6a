#!/usr/bin/env python
"""Write and read paper-size scenes (Z_s 1024x64 + Z_d 512x64, 32 frames) in every .vt4d encoding, and the
same arrays with np.savez_compressed and safetensors (+zstd), in one run.

    python bench/bench_format.py                 # 1,000 scenes per format (about a minute on 2 cores)
    python bench/bench_format.py --scenes 100    # quicker
    python bench/bench_format.py --scenes 1000 --round-size 50 --encodings int8,int4-rans,int8-rans,float16
                                                 # the entropy-coded 1.1 encodings (C rANS coder)
    python bench/bench_format.py --rans-lanes 0  # ... with one rANS chain per token section (the 1.1-1.4
                                                 # layout) instead of the writer's policy (format 1.5 lanes)
    python bench/bench_format.py --scenes 0 --loader-scenes 0 --decoder-micro   # the C rANS decoder alone

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

rANS layout: every file is written with the writer's lane policy (``--rans-lanes policy``, the default: a
paper-size scene's int<b>-rans sections both get 8 interleaved lanes, format 1.5, FORMAT.md I.6.1), or with
``--rans-lanes 0`` (one chain per section, the 1.1-1.4 layout) or ``--rans-lanes K``; each result says the
layout its files had ("layout": format version and the lanes of ZSTA / ZDYN).  ``--decoder-micro`` times the
compiled decoder alone (``decode_mapped``: symbols to float32 tokens) on one 65,536-code int5 stream and on a
paper-size pair (65,536 + 32,768 codes) in ns per code, one chain against 4 and 8 lanes (best of 50).
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
from vt4dcodec.format.encodings import V1_0_ENCODINGS, is_entropy_coded  # noqa: E402
from vt4dcodec.format.rans_tokens import _parse_payload, encode_rans_tokens  # noqa: E402

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
RANS_LANES: list[int | None] = [None]  # dumps(rans_lanes=...): None = the writer's policy (--rans-lanes)


def layout_of(data: bytes) -> str:
    """"1.5, lanes 8/8" (format version, rANS lanes of ZSTA / ZDYN; 1 where one chain) or "1.3"."""
    f = open_scene(data)
    version = f"{f.preamble.major}.{f.preamble.minor}"
    if not is_entropy_coded(f.encoding):
        return version
    lanes = [_parse_payload(f.raw_section(name), f.encoding, *shape, lanes=f.rans_lanes).lanes
             for name, shape in (("ZSTA", f.static_shape), ("ZDYN", f.dynamic_shape))]
    return f"{version}, lanes {lanes[0]}/{lanes[1]}"


def vt4d(encoding: str):
    def write(scene, path):
        t = time.perf_counter()
        data = dumps(scene, encoding=encoding, rans_lanes=RANS_LANES[0])
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
        self.layout: str | None = None

    def round(self, scenes: list[Scene], start: int, count: int, workdir: str) -> None:
        paths = [os.path.join(workdir, f"{self.name}-{i}.bin") for i in range(count)]
        encode0, t0, c0 = ENCODE_S[0], time.perf_counter(), time.process_time()
        for k, p in enumerate(paths):
            self.write(scenes[(start + k) % POOL], p)
        t1, c1 = time.perf_counter(), time.process_time()
        self.encode_s += ENCODE_S[0] - encode0
        if self.layout is None and self.name.startswith("vt4d-"):
            self.layout = layout_of(Path(paths[0]).read_bytes())
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
               "max_abs_error": self.err, "layout": self.layout}
        encode = f"(encode {res['encode_MBps']:6.0f})" if self.encode_s else " " * 15
        print(f"{self.name:>24}: {res['bytes_per_scene']:>8} B/scene  write {res['write_MBps']:7.1f} MB/s {encode}  "
              f"read {res['read_MBps']:7.1f} MB/s  | per CPU second: write {res['write_cpu_MBps']:6.0f} read "
              f"{res['read_cpu_MBps']:6.0f}  max err {self.err:.3g}"
              + (f"  [{self.layout}]" if self.layout else ""), flush=True)
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
        records = [dumps(s, encoding=enc, rans_lanes=RANS_LANES[0]) for s in scenes]
        with ArchiveWriter(path, "w", durable=False) as w:
            for i in range(n):
                w.append(f"scene-{i:06d}", records[i % POOL])
        datasets[enc] = ArchiveDataset(path)
        loaders[enc] = DataLoader(datasets[enc], batch_size=16, num_workers=2, collate_fn=_collate,
                                  persistent_workers=True)
        for _ in loaders[enc]:  # warm-up epoch: worker start-up and first page-cache touch, not timed
            pass
        rows[enc] = {"encoding": enc, "scenes": n, "archive_bytes": os.path.getsize(path), "layout": layout_of(records[0]),
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
              f"DataLoader(2 workers) {r['dataloader_2w_scenes_per_s']:7.0f} scenes/s  [{r['layout']}]", flush=True)
        out.append(r)
    return out


def decoder_micro(reps: int = 50) -> dict:
    """ns per code of the compiled decoder alone (``decode_mapped``, symbols to float32 tokens), int5-rans
    payloads of i.i.d. N(0, 1) tokens as the writer makes them: one 65,536-code matrix (1024x64) and a
    paper-size pair (1024x64 + 512x64, one call), one chain (the 1.1 layout) against 4 and 8 lanes; best of
    ``reps`` calls."""
    if not rans.NATIVE:
        return {}
    rng = np.random.default_rng(1)
    mats = [rng.standard_normal((NS, D)).astype(np.float32), rng.standard_normal((ND, D)).astype(np.float32)]
    out: dict = {}
    for lanes in (None, 4, 8):
        specs = []
        for x in mats:
            p = _parse_payload(encode_rans_tokens(x, "int5-rans", 1, lanes=lanes), "int5-rans", *x.shape,
                               lanes=lanes is not None)
            lut = (np.arange(32) * np.float64(p.scale[0]) + np.float64(p.offset[0])).astype(np.float32)
            specs.append((bytes(p.stream), np.asarray(p.freqs, np.uint32), np.empty(x.shape, np.float32), D,
                          np.zeros(D, np.uint32), lut, b"" if p.centre is None else p.centre.tobytes(), 31, p.lanes))
        row = {}
        for label, jobs in (("matrix_65536", (specs[0],)), ("pair_98304", tuple(specs))):
            best = min(_timed(rans._rans_native.decode_mapped, jobs) for _ in range(reps))
            row[label] = best / sum(j[2].size for j in jobs) * 1e9
        key = "one_chain" if lanes is None else f"lanes_{lanes}"
        out[key] = row
        print(f"{'rANS decoder ' + key:>24}: {row['matrix_65536']:.2f} ns/code (one 1024x64 matrix), "
              f"{row['pair_98304']:.2f} ns/code (paper-size pair: {row['pair_98304'] * 98304 / 1e3:.0f} us a scene)",
              flush=True)
    return out


def _timed(fn, arg) -> float:
    t = time.perf_counter()
    fn(arg)
    return time.perf_counter() - t


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
    parser.add_argument("--rans-lanes", default="policy",
                        help="rANS lanes of the int<b>-rans files: 'policy' (the writer's default), 0 (one chain, "
                             "the 1.1-1.4 layout) or 1..32")
    parser.add_argument("--decoder-micro", action="store_true",
                        help="also time the compiled rANS decoder alone (one chain vs 4 and 8 lanes)")
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "format.json"))
    args = parser.parse_args()
    RANS_LANES[0] = None if args.rans_lanes == "policy" else int(args.rans_lanes)
    encodings = ENCODINGS if args.encodings == "all" else tuple(args.encodings.split(","))
    unknown = set(encodings) - set(ENCODINGS)
    if unknown:
        parser.error(f"unknown encoding(s) {sorted(unknown)}; choose from {ENCODINGS}")
    scenes = make_scenes(0)
    formats = [(f"vt4d-{e}", *vt4d(e)) for e in encodings]
    formats += [("vt4d-int8-tokens-only", *vt4d_lazy_tokens("int8"))]
    formats += [("npz_compressed-float32", *savez()), ("safetensors+zstd-float32", *safetensors_zstd())]
    tallies = [Tally(name, w, r) for name, w, r in formats]
    rounds = max(1, args.scenes // args.round_size) if args.scenes else 0
    micro = decoder_micro() if args.decoder_micro else None
    with tempfile.TemporaryDirectory(prefix="vt4d-bench-") as workdir:
        # Formats take turns, round by round, so a shared machine's changing load hits them all alike.
        for r in range(rounds):
            count = args.scenes // rounds + (1 if r < args.scenes % rounds else 0)
            for tally in tallies:
                tally.round(scenes, r * args.round_size, count, workdir)
            print(f"round {r + 1}/{rounds} done", file=sys.stderr, flush=True)
        results = [t.result() for t in tallies] if rounds else []
        loader = (loader_throughput(scenes, tuple(args.loader_encodings.split(",")), args.loader_scenes,
                                    args.loader_epochs, workdir) if args.loader_scenes else [])
    report = {"command": " ".join(["python bench/bench_format.py", *sys.argv[1:]]), "token_MB_per_scene": TOKEN_MB,
              "scene": {"static": [NS, D], "dynamic": [ND, D], "frames": FRAMES, "tokens": "iid N(0,1) float32"},
              "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "numpy": np.__version__,
                          "load_average_at_end": os.getloadavg(),
                          "zstd": ".".join(map(str, zstandard.ZSTD_VERSION))},
              "rans_coder": "C (_rans_native)" if rans.NATIVE else "pure Python (no C compiler at install)",
              "rans_lanes": args.rans_lanes, "results": results, "loader": loader}
    if micro is not None:
        report["rans_decoder_ns_per_code"] = micro
    Path(args.out).write_text(json.dumps(report, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
