"""Capture benchmark: import the real caliscope recording and check its calibration.

Measures, on /work/shared/data/caliscope_4cam (4 cameras, 48 frames, 1280x720):
  * wall time of ``import_caliscope`` (decode + undistort + resize + crop) at several resolutions,
  * median / mean / 90th-percentile reprojection error of the xy.csv board corners triangulated with
    the imported cameras, at each import resolution and through the raw lens model,
  * write/read time of the imported 64x64 capture as PNG and mp4 capture directories.

Run: python bench/bench_capture.py [--data DIR]   (writes bench/results/capture.json)
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from vt4dcodec.capture import read_capture, write_capture
from vt4dcodec.capture.caliscope import find_sample_capture, import_caliscope
from vt4dcodec.capture.reprojection import caliscope_reprojection

RESOLUTIONS = [(64, 64), (256, 256), (720, 1280)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(find_sample_capture() or "caliscope_4cam"))
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "capture.json"))
    args = ap.parse_args()
    results: dict = {"data": args.data, "raw_lens_model": caliscope_reprojection(args.data).as_dict(), "imports": []}
    small = None
    for h, w in RESOLUTIONS:
        t0 = time.perf_counter()
        cap = import_caliscope(args.data, height=h, width=w, num_frames=None if (h, w) == (64, 64) else 8)
        seconds = time.perf_counter() - t0
        entry = {"height": h, "width": w, "frames": cap.num_frames, "import_seconds": round(seconds, 3),
                 "reprojection": caliscope_reprojection(args.data, cap).as_dict()}
        results["imports"].append(entry)
        print(f"{w}x{h}: {cap.num_frames} frames x 4 cameras imported in {seconds:.2f} s; "
              f"median reprojection {entry['reprojection']['median_px']:.3f} px")
        if (h, w) == (64, 64):
            small = cap
    results["capture_dir"] = []
    for media in ("png", "mp4"):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            write_capture(small, tmp, media=media, overwrite=True)
            t1 = time.perf_counter()
            read_capture(tmp)
            t2 = time.perf_counter()
            size = sum(p.stat().st_size for p in Path(tmp).rglob("*") if p.is_file())
        results["capture_dir"].append({"media": media, "write_seconds": round(t1 - t0, 3),
                                       "read_seconds": round(t2 - t1, 3), "bytes": size})
        print(f"64x64 capture as {media}: write {t1 - t0:.2f} s, read {t2 - t1:.2f} s, {size / 1e3:.0f} kB")
    print(f"raw lens model: median {results['raw_lens_model']['median_px']:.3f} px")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
