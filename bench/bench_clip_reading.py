"""Clip-reading benchmark (issue 14 item 3): encode one 8-frame clip of one camera of a large capture.

Makes a synthetic 4-camera 1080p H.264 capture of 100 frames with PyAV in a temporary directory
(textured, moving content; libx264 ``veryfast``, a keyframe every ``--gop`` frames, as cameras write
them), then runs each case in a fresh Python process and records its wall time and peak memory:

  * ``api_clip``: ``codec.encode(CAPTURE_DIR, camera="cam00", start=S)``, which reads only that camera's
    frames S..S+7 (seek to the keyframe before S, decode forward).  Once at the first clip (S = 0) and
    once at the last one (S = frames - 8, the most frames decoded before the window).  The default
    runtime ("auto"): the model's exported encoder on onnxruntime, torch never imported.
  * ``cli_clip``: ``vt4d encode CAPTURE_DIR --camera cam00 --start S -o scene.vt4d``, whole command.
  * ``api_clip_torch``: ``api_clip`` with ``runtime="torch"`` (the networks in torch, one thread).
  * ``api_whole``: the path before clip reading: ``read_capture(CAPTURE_DIR)`` (every frame of every
    camera) and then the same encode.  ``--skip-whole`` leaves it out (it needs ~2.5 GB).
  * ``import_torch``: a process that only imports torch and loads the model: the floor under every
    torch encode's memory (the CUDA build of torch maps ~0.5 GB of shared libraries at import).

Per case: ``wall_s`` (the whole process, interpreter start to exit), ``encode_s`` (the encode call,
or the command's own time), ``cpu_s`` (process user + system CPU), ``peak_rss_mb`` (``ru_maxrss``:
every resident page, the shared libraries too), ``peak_private_mb`` (the largest ``RssAnon`` sampled
every 2 ms: the process's own memory, i.e. decoded frames, arrays, tensors) and ``rss_before_mb``
(resident before the encode, after imports and model loading).  The tokens of the clip read and the
whole read are compared (they must be equal), and so are those of the two runtimes (float rounding).

Run: python bench/bench_clip_reading.py [--skip-whole]   (writes bench/results/clip_reading.json)
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
from fractions import Fraction
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


# --- the synthetic capture ---------------------------------------------------------------------------
def _look_at(eye: np.ndarray) -> np.ndarray:
    """World-to-camera pose (OpenCV axes) of a camera at ``eye`` looking at the origin, world up = -y."""
    z = -eye / np.linalg.norm(eye)
    x = np.cross(np.array([0.0, -1.0, 0.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    w2c = np.eye(4)
    w2c[:3, :3] = np.stack([x, y, z])
    w2c[:3, 3] = -w2c[:3, :3] @ eye
    return w2c


def _frame(t: int, cam: int, width: int, height: int, base: np.ndarray) -> np.ndarray:
    """Textured, moving content: a scrolling texture with a bright square crossing it."""
    shift = (7 * t + 131 * cam) % width
    img = np.roll(base, shift, axis=1)
    size = height // 6
    x0 = int((width - size) * (0.5 + 0.45 * np.sin(0.07 * t + cam)))
    y0 = int((height - size) * (0.5 + 0.4 * np.cos(0.05 * t + cam)))
    img[y0:y0 + size, x0:x0 + size] = (230, 60 + 40 * cam, 40)
    return img


def make_capture(directory: Path, *, cameras: int, frames: int, width: int, height: int, fps: float, gop: int
                 ) -> dict:
    import av

    from vt4dcodec.cameras import Trajectory
    from vt4dcodec.capture.io import CAPTURE_FORMAT, CAPTURE_VERSION, camera_json, write_manifest

    rng = np.random.default_rng(0)
    coarse = rng.integers(0, 256, size=(height // 16 + 1, width // 16 + 1, 3), dtype=np.uint8)
    base = np.repeat(np.repeat(coarse, 16, axis=0), 16, axis=1)[:height, :width]
    fine = rng.integers(-20, 21, size=(height, width, 1))
    base = np.clip(base.astype(int) + fine, 0, 255).astype(np.uint8)
    f = 1.2 * width
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])
    docs = []
    t0 = time.perf_counter()
    for c in range(cameras):
        name = f"cam{c:02d}"
        (directory / name).mkdir(parents=True, exist_ok=True)
        with av.open(str(directory / name / "rgb.mp4"), "w", format="mp4") as out:
            stream = out.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
            stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
            stream.options = {"preset": "veryfast", "crf": "23", "g": str(gop), "keyint_min": str(gop)}
            for t in range(frames):
                frame = av.VideoFrame.from_ndarray(_frame(t, c, width, height, base.copy()), format="rgb24")
                out.mux(stream.encode(frame))
            out.mux(stream.encode(None))
        angle = 2 * np.pi * c / cameras
        traj = Trajectory(K=K, w2c=_look_at(np.array([3 * np.sin(angle), -0.5, -3 * np.cos(angle)]))[None],
                          width=width, height=height)
        docs.append(camera_json(name, traj, {"type": "mp4", "path": f"{name}/rgb.mp4"}, None))
    write_manifest(directory, {"format": CAPTURE_FORMAT, "version": CAPTURE_VERSION, "capture_id": "synthetic1080",
                               "fps": fps, "num_frames": frames, "metadata": {}, "cameras": docs})
    size = sum(p.stat().st_size for p in directory.rglob("*.mp4"))
    return {"cameras": cameras, "frames": frames, "width": width, "height": height, "fps": fps, "gop": gop,
            "codec": "h264 (libx264 veryfast, crf 23, yuv420p)", "bytes": size,
            "seconds_to_make": round(time.perf_counter() - t0, 1)}


# --- one case, in a child process --------------------------------------------------------------------
def _rss_anon_kb() -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("RssAnon:"):
                return int(line.split()[1])
    return 0


class _PeakPrivate:
    """Samples RssAnon every 2 ms on a thread; ``peak_kb`` is the largest value seen."""

    def __init__(self) -> None:
        self.peak_kb = _rss_anon_kb()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.002):
            self.peak_kb = max(self.peak_kb, _rss_anon_kb())

    def stop(self) -> int:
        self._stop.set()
        self._thread.join()
        return max(self.peak_kb, _rss_anon_kb())


def child(case: str, capture: str, start: int, model: str, out: str) -> None:
    sampler = _PeakPrivate()
    from vt4dcodec import codec
    from vt4dcodec.capture import read_capture

    runtime = "torch" if case in ("api_clip_torch", "import_torch") else "auto"
    if runtime == "torch":
        import torch

        torch.set_num_threads(1)
    net = codec.load_encoder(model, runtime)
    with open("/proc/self/status") as fh:
        rss_before = next(int(line.split()[1]) for line in fh if line.startswith("VmRSS:"))
    t0 = time.perf_counter()
    result: dict = {}
    if case in ("api_clip", "api_clip_torch"):
        scene = codec.encode(capture, net, camera="cam00", start=start)
    elif case == "api_whole":
        scene = codec.encode(read_capture(capture), net, camera="cam00", start=start)
    elif case == "cli_clip":
        from vt4dcodec.cli import main as cli_main

        rc = cli_main(["encode", capture, "--camera", "cam00", "--start", str(start), "-o", out + ".vt4d",
                       "--model", model, "-q"])
        if rc != 0:
            raise SystemExit(f"vt4d encode exited with {rc}")
        scene = None
    else:  # import_torch: nothing more
        scene = None
    encode_s = time.perf_counter() - t0
    if scene is not None:
        np.savez(out + ".npz", static=scene.static_tokens, dynamic=scene.dynamic_tokens)
    usage = resource.getrusage(resource.RUSAGE_SELF)
    result.update({"runtime": type(net).__name__, "torch_imported": "torch" in sys.modules,
                   "encode_s": round(encode_s, 3), "cpu_s": round(usage.ru_utime + usage.ru_stime, 2),
                   "peak_rss_mb": round(usage.ru_maxrss / 1024, 1), "peak_private_mb": round(sampler.stop() / 1024, 1),
                   "rss_before_mb": round(rss_before / 1024, 1)})
    print("RESULT " + json.dumps(result))


def run_case(case: str, capture: Path, start: int, model: str, work: Path) -> dict:
    out = str(work / f"{case}_{start}")
    cmd = [sys.executable, __file__, "--child", case, "--capture", str(capture), "--start", str(start),
           "--model", model, "--child-out", out]
    env = dict(os.environ, PYTHONPATH=str(REPO))  # this checkout's vt4dcodec, whatever is installed
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=str(REPO))
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{case} failed:\n{proc.stderr[-3000:]}")
    line = next(x for x in proc.stdout.splitlines() if x.startswith("RESULT "))
    return {"case": case, "start": start, "wall_s": round(wall, 2), **json.loads(line[len("RESULT "):])}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", type=int, default=4)
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--fps", type=float, default=60.0)
    ap.add_argument("--gop", type=int, default=60, help="frames between keyframes (default 60: 1 s at 60 fps)")
    ap.add_argument("--model", default="vt4d-tiny")
    ap.add_argument("--repeats", type=int, default=2, help="runs of each clip case (the best is reported too)")
    ap.add_argument("--skip-whole", action="store_true", help="leave out the whole-capture read (~2.5 GB)")
    ap.add_argument("--out", default=str(REPO / "bench" / "results" / "clip_reading.json"))
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--capture", help=argparse.SUPPRESS)
    ap.add_argument("--start", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--child-out", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(args.child, args.capture, args.start, args.model, args.child_out)
        return 0
    clip = 8
    results: dict = {"command": "python bench/bench_clip_reading.py " + " ".join(sys.argv[1:] if argv is None else argv),
                     "clip_frames": clip, "load_average_before": list(os.getloadavg()), "runs": []}
    with tempfile.TemporaryDirectory(prefix="vt4d_clip_bench_") as tmp:
        work = Path(tmp)
        capture = work / "capture"
        results["capture"] = make_capture(capture, cameras=args.cameras, frames=args.frames, width=args.width,
                                          height=args.height, fps=args.fps, gop=args.gop)
        print(f"made {args.cameras} x {args.frames} frames of {args.width}x{args.height} H.264 "
              f"({results['capture']['bytes'] / 1e6:.1f} MB) in {results['capture']['seconds_to_make']} s")
        last = args.frames - clip
        cases = [("import_torch", 0)] + [(c, s) for _ in range(args.repeats)
                                        for c in ("api_clip", "cli_clip", "api_clip_torch") for s in (0, last)]
        if not args.skip_whole:
            cases.append(("api_whole", last))
        for case, start in cases:
            r = run_case(case, capture, start, args.model, work)
            results["runs"].append(r)
            print(f"{case:14s} start {start:3d}: wall {r['wall_s']:6.2f} s, encode {r['encode_s']:6.2f} s, "
                  f"CPU {r['cpu_s']:6.2f} s, peak RSS {r['peak_rss_mb']:7.1f} MB, private {r['peak_private_mb']:7.1f} MB"
                  f" (RSS before encoding {r['rss_before_mb']:.0f} MB)")
        clip_tokens = np.load(work / f"api_clip_{last}.npz")
        torch_tokens = np.load(work / f"api_clip_torch_{last}.npz")
        results["onnx_vs_torch_max_token_difference"] = float(max(
            np.abs(clip_tokens[k] - torch_tokens[k]).max() for k in ("static", "dynamic")))
        print(f"largest token difference, onnx runtime vs torch: {results['onnx_vs_torch_max_token_difference']:.2e}")
        if not args.skip_whole:
            whole = np.load(work / f"api_whole_{last}.npz")
            results["tokens_equal_to_whole_read"] = bool(
                np.array_equal(clip_tokens["static"], whole["static"])
                and np.array_equal(clip_tokens["dynamic"], whole["dynamic"]))
            print(f"tokens from the clip read equal those from the whole read: {results['tokens_equal_to_whole_read']}")
    results["load_average_after"] = list(os.getloadavg())
    summary = {}
    for case in ("api_clip", "cli_clip", "api_clip_torch", "api_whole", "import_torch"):
        for start in sorted({r["start"] for r in results["runs"] if r["case"] == case}):
            rs = [r for r in results["runs"] if r["case"] == case and r["start"] == start]
            summary[f"{case}@{start}"] = {k: (min(r[k] for r in rs), max(r[k] for r in rs))
                                          for k in ("wall_s", "encode_s", "cpu_s", "peak_rss_mb", "peak_private_mb")}
    results["summary_min_max"] = summary
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
