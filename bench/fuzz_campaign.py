#!/usr/bin/env python
"""A fuzz campaign over the scene (`.vt4d`, formats 1.0-1.6) and archive (`.vt4da`, 1.0-1.2) readers.

    python bench/fuzz_campaign.py --inputs 1000000 --workers 2    # the recorded campaign (~1 h on 2 cores)
    python bench/fuzz_campaign.py --inputs 20000                   # a quick look (~1 min)

Seeds: every valid and invalid spec vector (spec/vectors), plus archives the writer makes (format 1.0 and
1.1, several commits, real scenes of several encodings).  Each input is a seed mutated by one of the
project's own mutators: bit flips, interesting bytes, truncation, insertion, deletion, duplication of a
range, splicing two seeds, integer fields of the preamble, and -- for scenes -- *structure-aware* mutations
that change one section payload or one header value and rebuild the container with correct checksums
(spec/make_vectors.py's split/rebuild), so the mutation reaches the decoders behind the CRCs instead of
stopping at them.  Every input is read as a user's file is read: scenes by ``open_scene`` + ``verify`` +
``load`` (the spec vectors' entropy tables installed, so learned-rans payloads are decoded), archives by
``open_archive`` + every record + ``verify_archive``.

Outcomes, per input: *rejected* (an exception of the library's one family, ``Vt4dError``), *accepted*
(read), *crash* (any other exception), *warning* (numpy printed a RuntimeWarning on the way: a user would see
it), *hang* (over ``--timeout`` seconds).  Accepted inputs are read again
by the independent reader written from FORMAT.md alone (tests/format/test_independent_reader.py), and a
*silent wrong read* is an input the library reads to other tokens, cameras or records than that reader
does, or reads where that reader refuses it.  The peak resident memory of each worker is recorded (the
issue's bound: no input under 100 KB makes a reader exceed 300 MB).  Crashing, hanging and wrongly read
inputs are written under --save for reproduction.  Results: bench/results/fuzz_campaign.json.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import resource
import signal
import struct
import sys
import time
import traceback
import warnings
import zlib
from collections import Counter
from pathlib import Path
from typing import Any, Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for extra in (ROOT, ROOT / "spec", ROOT / "tests" / "format"):
    if str(extra) not in sys.path:
        sys.path.insert(0, str(extra))

from vt4dcodec.errors import Vt4dError  # noqa: E402

VECTORS = ROOT / "spec" / "vectors"
MAX_INPUT = 100_000       # bytes: the bound concerns inputs under 100 KB
INTERESTING = (0x00, 0x01, 0x7F, 0x80, 0xFE, 0xFF)


class Hang(Exception):
    """Raised by the alarm when one input takes longer than the timeout."""


def _alarm(signum: int, frame: Any) -> None:
    raise Hang()


# --- seeds ----------------------------------------------------------------------------------------------
def _writer_archives() -> list[bytes]:
    """Small archives of real scenes as the writer makes them: 1.0, 1.1 and 1.2, two, five and five commits."""
    import tempfile

    from format_strategies import rig_scene, simple_scene

    from vt4dcodec.archive import ArchiveWriter
    from vt4dcodec.format import dumps

    scenes = [dumps(simple_scene(ns=3, nd=2, d=3, frames=2, encoding="int4")),
              dumps(simple_scene(ns=5, nd=2, d=3, frames=1, encoding="int5-rans"), rans_lanes=3),
              dumps(rig_scene(2, frames=2, ns=3, nd=2, d=3, encoding="int8"))]
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for version, commits in (((1, 0), 2), ((1, 1), 5), ((1, 2), 5)):  # 1.2: light commits with journals
            path = Path(tmp) / f"a{version[1]}.vt4da"
            with ArchiveWriter(path, durable=False, version=version) as w:
                for c in range(commits):
                    w.append(f"scene-{c}", scenes[c % len(scenes)])
                    if c % 2:
                        w.append(f"extra-{c}", scenes[(c + 1) % len(scenes)])
                    w.commit()
            out.append(path.read_bytes())
    return out


def load_seeds() -> dict[str, list[bytes]]:
    scenes = [p.read_bytes() for p in sorted((VECTORS / "valid").glob("*.vt4d"))]
    invalid = [p.read_bytes() for p in sorted((VECTORS / "invalid").glob("*.vt4d"))]
    archives = [p.read_bytes() for p in sorted((VECTORS / "archive").glob("*.vt4da"))] + _writer_archives()
    return {"scene": scenes, "scene_invalid": invalid, "archive": archives}


# --- mutators -------------------------------------------------------------------------------------------
def _bit_flips(rng: np.random.Generator, data: bytes, pool: list[bytes]) -> bytes:
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 9))):
        if b:
            b[int(rng.integers(len(b)))] ^= 1 << int(rng.integers(8))
    return bytes(b)


def _interesting(rng: np.random.Generator, data: bytes, pool: list[bytes]) -> bytes:
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 4))):
        if b:
            b[int(rng.integers(len(b)))] = INTERESTING[int(rng.integers(len(INTERESTING)))]
    return bytes(b)


def _truncate(rng: np.random.Generator, data: bytes, pool: list[bytes]) -> bytes:
    return data[:int(rng.integers(len(data)))] if data else data


def _insert(rng: np.random.Generator, data: bytes, pool: list[bytes]) -> bytes:
    at = int(rng.integers(len(data) + 1))
    return data[:at] + rng.integers(0, 256, int(rng.integers(1, 17)), dtype=np.uint8).tobytes() + data[at:]


def _delete(rng: np.random.Generator, data: bytes, pool: list[bytes]) -> bytes:
    if not data:
        return data
    at = int(rng.integers(len(data)))
    return data[:at] + data[at + int(rng.integers(1, 17)):]


def _duplicate(rng: np.random.Generator, data: bytes, pool: list[bytes]) -> bytes:
    if not data:
        return data
    a = int(rng.integers(len(data)))
    b = min(len(data), a + int(rng.integers(1, 65)))
    at = int(rng.integers(len(data) + 1))
    return data[:at] + data[a:b] + data[at:]


def _splice(rng: np.random.Generator, data: bytes, pool: list[bytes]) -> bytes:
    other = pool[int(rng.integers(len(pool)))]
    return data[:int(rng.integers(len(data) + 1))] + other[int(rng.integers(len(other) + 1)):]


def _field(rng: np.random.Generator, data: bytes, pool: list[bytes]) -> bytes:
    """An integer field of the first 64 bytes (a preamble) set to a boundary value; the scene preamble's own
    CRC repaired half of the time, so the value itself is what the reader meets."""
    if len(data) < 64:
        return _bit_flips(rng, data, pool)
    at, fmt = [(10, "<H"), (12, "<H"), (16, "<Q"), (24, "<Q"), (32, "<Q"), (40, "<I"), (44, "<I"), (48, "<I"),
               (52, "<I"), (8, "<H"), (12, "<I")][int(rng.integers(11))]
    width = struct.calcsize(fmt)
    value = int(rng.choice([0, 1, 2, 255, 256, 65535, 2**31 - 1, 2**32 - 1, 2**63, 2**64 - 1,
                            int(rng.integers(0, 1 << 20))])) & ((1 << (8 * width)) - 1)
    b = bytearray(data)
    struct.pack_into(fmt, b, at, value)
    if rng.random() < 0.5:
        struct.pack_into("<I", b, 60, zlib.crc32(bytes(b[:60])))
    return bytes(b)


def _structured(rng: np.random.Generator, data: bytes, pool: list[bytes]) -> bytes:
    """One section payload or one header value changed, the container rebuilt with correct checksums."""
    import make_vectors as mv

    try:
        header, sections = mv.split(data)
        minor, required = struct.unpack_from("<H", data, 12)[0], struct.unpack_from("<Q", data, 16)[0]
    except Exception:  # not a container split() understands (an invalid seed): mutate its bytes instead
        return _bit_flips(rng, data, pool)
    if rng.random() < 0.75 and sections:
        k = int(rng.integers(len(sections)))
        payload = sections[k][3]
        if sections[k][2] == 1:  # a zstd section: mutate the raw bytes and compress them again
            import zstandard

            try:
                raw = zstandard.ZstdDecompressor().decompress(payload, max_output_size=1 << 20)
            except zstandard.ZstdError:
                raw = payload
            raw = [_bit_flips, _interesting, _truncate, _insert, _delete][int(rng.integers(5))](rng, raw, pool)
            sections[k][3] = zstandard.ZstdCompressor().compress(raw)
            sections[k][4] = len(raw)
        else:
            payload = [_bit_flips, _interesting, _truncate, _insert, _delete][int(rng.integers(5))](rng, payload, pool)
            sections[k][3] = payload
            sections[k][4] = len(payload)
    else:
        keys = [("static_shape",), ("dynamic_shape",), ("encoding",), ("cameras", "num_frames"),
                ("cameras", "width"), ("cameras", "distortion_terms"), ("cameras", "has_timestamps"),
                ("fingerprint", "model_id"), ("metadata",), ("provenance",)]
        path = keys[int(rng.integers(len(keys)))]
        value = [0, 1, -1, 2**31, 2**40, "x", "int4", [1, 2], [3, 0], {"a": 1}, None, True, 1.5, "learned-rans",
                 [2**20, 64]][int(rng.integers(15))]
        target = header
        for key in path[:-1]:
            target = target.get(key, {}) if isinstance(target, dict) else {}
        if isinstance(target, dict):
            target[path[-1]] = value
    try:
        if len(sections[0]) == 6:  # a compact container: the same flags and minor again
            return mv.rebuild_1_3(header, sections, minor=minor, required_flags=required)
        return mv.rebuild(header, sections, minor=minor, required_flags=required)
    except Exception:  # the header or a section the writer itself refuses to build
        return _bit_flips(rng, data, pool)


SCENE_MUTATORS: dict[str, Callable] = {
    "bit_flips": _bit_flips, "interesting": _interesting, "truncate": _truncate, "insert": _insert,
    "delete": _delete, "duplicate": _duplicate, "splice": _splice, "preamble_field": _field,
    "structured": _structured,
}
SCENE_WEIGHTS = {"bit_flips": 2, "interesting": 1, "truncate": 1, "insert": 1, "delete": 1, "duplicate": 1,
                 "splice": 1, "preamble_field": 1, "structured": 4}
ARCHIVE_MUTATORS = {k: v for k, v in SCENE_MUTATORS.items() if k not in ("structured", "preamble_field")}
ARCHIVE_WEIGHTS = {"bit_flips": 3, "interesting": 1, "truncate": 2, "insert": 1, "delete": 1, "duplicate": 1,
                   "splice": 1}


# --- reading ----------------------------------------------------------------------------------------------
def read_scene_library(data: bytes) -> Any:
    from vt4dcodec.format import load, open_scene

    f = open_scene(data)
    f.verify()
    return load(data)


def scene_disagreement(data: bytes, scene: Any) -> str | None:
    """None when the independent reader reads ``data`` as the library read it (tokens, cameras), else why not."""
    import test_independent_reader as spec

    try:
        parsed = spec.read_scene(data)
        h = parsed["header"]
        for tok, quant, key, got in (("ZSTA", "QSTA", "static", scene.static_tokens),
                                     ("ZDYN", "QDYN", "dynamic", scene.dynamic_tokens)):
            want = np.asarray(spec.decode_tokens(parsed, tok, quant, h[f"{key}_shape"]), dtype=np.float32)
            if want.shape != got.shape or not np.array_equal(want.view(np.uint32), np.asarray(got, np.float32).view(np.uint32)):
                return f"{key} tokens differ"
        cams = spec.read_cameras(parsed)
        if not (np.array_equal(np.asarray(cams["K"], np.float64), scene.cameras.K)
                and np.array_equal(np.asarray(cams["w2c"], np.float64), scene.cameras.w2c)):
            return "cameras differ"
        extras = spec.read_extra_cameras(parsed)
        if len(extras) != len(scene.extra_cameras):
            return "extra camera count differs"
    except Exception as exc:  # the spec reader refuses (assert) or cannot follow
        return f"the independent reader refuses: {type(exc).__name__}: {str(exc)[:120]}"
    return None


def read_archive_library(data: bytes) -> dict[str, bytes]:
    from vt4dcodec.archive import open_archive, verify_archive

    with open_archive(data) as ar:
        records = dict(ar.iter_records())
    verify_archive(data)
    return records


def archive_disagreement(data: bytes, records: dict[str, bytes]) -> str | None:
    import test_independent_reader as spec

    try:
        _, want = spec.read_archive(data)
    except Exception as exc:
        return f"the independent reader refuses: {type(exc).__name__}: {str(exc)[:120]}"
    return None if want == records else "records differ"


# --- the campaign -----------------------------------------------------------------------------------------
def peak_rss_mb() -> float:
    """This process's peak resident memory in MB: VmHWM (it starts afresh with the program, unlike ru_maxrss,
    which Linux carries over from a parent across fork and exec), else ru_maxrss."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run_worker(args: tuple[int, int, int, float, str | None]) -> dict[str, Any]:
    """One worker's share of the campaign (the process's warning filters and alarm handler are restored)."""
    previous = signal.getsignal(signal.SIGALRM)
    with warnings.catch_warnings():
        try:
            return _run_worker(args)
        finally:
            signal.signal(signal.SIGALRM, previous)


def _run_worker(args: tuple[int, int, int, float, str | None]) -> dict[str, Any]:
    worker, first, count, timeout, save = args
    import make_vectors as mv

    mv.install_spec_tables()  # the learned-rans spec vectors' tables, found by fingerprint
    seeds = load_seeds()
    rng = np.random.default_rng([20261205, worker, first])
    signal.signal(signal.SIGALRM, _alarm)
    warnings.simplefilter("error", RuntimeWarning)  # a numeric warning on a hostile file is a finding
    counts: Counter = Counter()
    by_mutator: Counter = Counter()
    errors: Counter = Counter()
    findings: list[dict[str, Any]] = []
    slowest = 0.0
    for i in range(first, first + count):
        kind = "archive" if rng.random() < 0.25 else "scene"
        # scenes: mostly the valid vectors (a mutation of a valid file goes deepest), some invalid ones
        pool = seeds["scene_invalid"] if kind == "scene" and rng.random() < 0.15 else seeds[kind]
        mutators, weights = (ARCHIVE_MUTATORS, ARCHIVE_WEIGHTS) if kind == "archive" else (SCENE_MUTATORS, SCENE_WEIGHTS)
        names = list(mutators)
        p = np.array([weights[n] for n in names], dtype=np.float64)
        name = names[int(rng.choice(len(names), p=p / p.sum()))]
        seed_data = pool[int(rng.integers(len(pool)))]
        try:
            data = mutators[name](rng, seed_data, pool)[:MAX_INPUT]
        except Exception:  # a mutator's own failure is not the reader's
            counts["mutator_failed"] += 1
            continue
        by_mutator[f"{kind}:{name}"] += 1
        outcome, detail = "accepted", None
        start = time.perf_counter()
        signal.setitimer(signal.ITIMER_REAL, timeout)
        try:
            result = read_archive_library(data) if kind == "archive" else read_scene_library(data)
        except Hang:
            outcome = "hang"
        except Vt4dError as exc:
            outcome = "rejected"
            errors[f"{kind}:{type(exc).__name__}"] += 1
        except RuntimeWarning as exc:
            outcome, detail = "warning", "".join(traceback.format_exception(type(exc), exc, exc.__traceback__)[-2:])[:300]
        except Exception as exc:
            outcome, detail = "crash", "".join(traceback.format_exception_only(type(exc), exc)).strip()[:300]
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
        elapsed = time.perf_counter() - start
        slowest = max(slowest, elapsed)
        if outcome == "accepted":
            detail = (archive_disagreement(data, result) if kind == "archive" else scene_disagreement(data, result))
            if detail is not None:
                outcome = "silent_wrong_read"
        counts[f"{kind}:{outcome}"] += 1
        if outcome in ("crash", "warning", "hang", "silent_wrong_read"):
            finding = {"input": i, "kind": kind, "mutator": name, "outcome": outcome, "detail": detail, "bytes": len(data)}
            if save:
                path = Path(save) / f"{outcome}-{kind}-{i}.{'vt4da' if kind == 'archive' else 'vt4d'}"
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_bytes(data)
                finding["file"] = str(path)
            if len(findings) < 200:
                findings.append(finding)
    return {"worker": worker, "inputs": count, "counts": dict(counts), "by_mutator": dict(by_mutator),
            "errors": dict(errors), "findings": findings, "slowest_s": slowest,
            "max_rss_mb": peak_rss_mb()}


def campaign(inputs: int, workers: int = 1, timeout: float = 5.0, save: str | None = None) -> dict[str, Any]:
    """Run ``inputs`` mutated inputs over ``workers`` processes; the merged tallies (see the module docstring)."""
    share = [inputs // workers + (1 if w < inputs % workers else 0) for w in range(workers)]
    jobs = [(w, sum(share[:w]), share[w], timeout, save) for w in range(workers)]
    if workers == 1:
        parts = [run_worker(jobs[0])]
    else:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            parts = pool.map(run_worker, jobs)
    merged: dict[str, Any] = {"inputs": inputs, "workers": workers, "timeout_s": timeout}
    for key in ("counts", "by_mutator", "errors"):
        total: Counter = Counter()
        for part in parts:
            total.update(part[key])
        merged[key] = dict(sorted(total.items()))
    merged["findings"] = [f for part in parts for f in part["findings"]]
    merged["slowest_s"] = max(part["slowest_s"] for part in parts)
    merged["max_rss_mb"] = max(part["max_rss_mb"] for part in parts)
    c = merged["counts"]
    merged["crashes"] = sum(v for k, v in c.items() if k.endswith(":crash"))
    merged["hangs"] = sum(v for k, v in c.items() if k.endswith(":hang"))
    merged["warnings"] = sum(v for k, v in c.items() if k.endswith(":warning"))
    merged["silent_wrong_reads"] = sum(v for k, v in c.items() if k.endswith(":silent_wrong_read"))
    return merged


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", type=int, default=20_000, help="mutated inputs in all (default 20,000)")
    ap.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1), help="processes (default 2)")
    ap.add_argument("--timeout", type=float, default=5.0, help="seconds one input may take before it counts as a hang")
    ap.add_argument("--save", default=None, help="directory for crashing, hanging or wrongly read inputs")
    ap.add_argument("--out", type=Path, default=ROOT / "bench/results/fuzz_campaign.json")
    ap.add_argument("--no-write", action="store_true", help="print only")
    args = ap.parse_args(argv)
    start = time.time()
    result = campaign(args.inputs, args.workers, args.timeout, args.save)
    result.update(command="python bench/fuzz_campaign.py " + " ".join(argv if argv is not None else sys.argv[1:]),
                  wall_s=round(time.time() - start, 1), python=platform.python_version(), cpus=os.cpu_count())
    print(f"{result['inputs']:,} inputs in {result['wall_s']:.0f} s: crashes {result['crashes']}, numeric warnings "
          f"{result['warnings']}, hangs {result['hangs']}, silent wrong reads {result['silent_wrong_reads']}; slowest input "
          f"{result['slowest_s'] * 1000:.0f} ms, peak memory {result['max_rss_mb']:.0f} MB per worker")
    for key, value in result["counts"].items():
        print(f"  {key:28s} {value:>10,}")
    for f in result["findings"][:20]:
        print(f"  finding: {f}")
    if not args.no_write:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")
        print(f"wrote {args.out}")
    return 1 if result["crashes"] or result["warnings"] or result["hangs"] or result["silent_wrong_reads"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
