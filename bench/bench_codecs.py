#!/usr/bin/env python
"""Side-by-side rate-distortion study: .vt4d against H.264, H.265 and AV1 on the same camera clips.

    python bench/bench_codecs.py                          # vt4d-tiny, 20 test scenes x 10 cameras + caliscope
    python bench/bench_codecs.py --quick                  # 2 scenes, 2 caliscope clips, 3-point sweeps (~1 min)
    python bench/bench_codecs.py --model DIR --scenes 2 --out /tmp/c.json --figure /tmp/c.png --doc none

Data: held-out synthetic captures (``generate_scene(seed, split="test", config=SynthConfig(num_cameras=10))``,
seeds 0..N-1) and the real caliscope_4cam recording (4 static webcams, imported at the model's image size and
cut into consecutive clips of the model's frame count, as ``vt4dcodec.eval.real_footage`` does).  Every clip
is the model's clip: 8 frames at 64x64 for vt4d-tiny.

Settings (stored cameras -> evaluated views), per clip:
  single/captured  camera 0 stored; camera 0 evaluated
  single/novel     camera 0 stored; every other camera evaluated
  all/captured     every camera stored; every camera evaluated
  half/captured    cameras 0, 2, 4, ... stored; those evaluated
  half/novel       cameras 0, 2, 4, ... stored; cameras 1, 3, 5, ... evaluated (held out)

.vt4d: one ``codec.encode(capture, model, cameras=stored)`` per stored set (one token set per scene), saved
at every token encoding (``vt4dcodec.format.ENCODINGS``); bytes = the whole file
(``len(dumps(scene, encoding=...))``), every evaluated camera rendered from the decoded bytes with
``SceneDecoder.open(bytes).render_many`` (the model's decode_steps, seed 0, one thread).  The target cameras'
trajectories are an input of the render, not counted in the file.

Video codecs (PyAV): each stored camera's clip is encoded on its own (RGB -> yuv420p, one GOP, constant-
quality sweep: libx264 veryslow, libx265 slow, SVT-AV1 preset 4 -- libaom if the wheel lacks SVT-AV1) and
decoded back with PyAV; quality is measured on the decoded frames.  Bytes = bitstream bytes (packet sizes;
no container) with x264's informational SEI NAL unit (its ~670 B settings string, not needed to decode)
removed -- the stream that is decoded is the stripped one.  The same quality setting is used for every
camera; the bytes of a setting are the sum over its stored cameras.  A video codec has no novel views: an
evaluated camera that was not stored is served the decoded frames of the stored camera whose first-frame
optical axis is closest in direction (``vt4dcodec.eval.protocol.axis_angles_deg``).  For scale, the flat
image of that camera's mean colour (3 bytes) is reported too.

Metrics: PSNR (``vt4dcodec.media.psnr``) and SSIM (kornia, ``vt4dcodec.eval.metrics.video_metrics``) per
evaluated video, averaged over views, then over clips; each curve is the mean over clips per quality step.
Equal-quality rate: the bytes a codec needs to reach vt4d's mean PSNR, interpolated on the codec's
(Pareto) curve linearly in log-bytes; where vt4d's PSNR is below the codec's cheapest point the figure is
an upper bound (``at_most``), where above its best point ``unreachable``.  rate_ratio = vt4d bytes / codec
bytes at equal PSNR (> 1: vt4d needs more).  BD-rate (vt4d as test, the codec as anchor, piecewise-linear
log-rate over the overlapping PSNR range of the two Pareto curves) where the ranges overlap.

Writes bench/results/codecs.json, docs/figures/codecs.png and the generated tables of
docs/benchmarks/codecs.md (between its ``codecs-table`` markers), and prints the tables.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import sys
import time
from fractions import Fraction
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its whole configuration to stderr otherwise

SETTINGS = (  # (row name, stored set, evaluated views)
    ("single/captured", "single", "captured"),
    ("single/novel", "single", "novel"),
    ("all/captured", "all", "captured"),
    ("half/captured", "half", "captured"),
    ("half/novel", "half", "novel"),
)
TABLE_BEGIN, TABLE_END = "<!-- codecs-table:begin -->", "<!-- codecs-table:end -->"


# --- the video codecs ---------------------------------------------------------------------------------
def _x264(q: int) -> dict[str, str]:
    return {"crf": str(q), "preset": "veryslow", "threads": "1", "x264-params": "lookahead-threads=1:sliced-threads=0"}


def _x265(q: int) -> dict[str, str]:
    return {"crf": str(q), "preset": "slow", "x265-params": "log-level=none:info=0:pools=none:frame-threads=1"}


def _svtav1(q: int) -> dict[str, str]:
    return {"crf": str(q), "preset": "4", "svtav1-params": "lp=1"}


def _aom(q: int) -> dict[str, str]:
    return {"crf": str(q), "b": "0", "cpu-used": "4", "threads": "1", "row-mt": "0"}


# name -> (label, encoder, decoder, options(q), sweep from low to high quality, quick sweep).  Besides the
# sweep at the clip's size, LOW_RATE adds encodes of the clip downscaled 2x / 4x (cv2 INTER_AREA) and
# upscaled back (INTER_LINEAR) at the lowest quality settings: the operating points below the native
# sweep's cheapest, reported separately ("any size").
CODEC_TABLE: dict[str, tuple[str, str, str, Callable[[int], dict[str, str]], tuple[int, ...], tuple[int, ...]]] = {
    "h264": ("H.264 (libx264 veryslow)", "libx264", "h264", _x264, (51, 46, 41, 36, 31, 26, 21), (51, 36, 21)),
    "h265": ("H.265 (libx265 slow)", "libx265", "hevc", _x265, (51, 46, 41, 36, 31, 26, 21), (51, 36, 21)),
    "av1": ("AV1 (SVT-AV1 preset 4)", "libsvtav1", "libdav1d", _svtav1, (63, 58, 52, 45, 38, 30, 22), (63, 45, 22)),
}
AOM = ("AV1 (libaom cpu-used 4)", "libaom-av1", "libaom-av1", _aom, (63, 58, 52, 45, 38, 30, 22), (63, 45, 22))
LOW_RATE_SCALES = (2, 4)


def sweep(spec: tuple, quick: bool) -> list[tuple[int, int]]:
    """(quality, downscale factor) of every encode of one codec: the sweep at the clip's size, then the
    lowest and second-lowest quality settings at each LOW_RATE_SCALES factor (quick: the lowest at 4x)."""
    native = spec[5] if quick else spec[4]
    low = [(native[0], 4)] if quick else [(q, f) for f in LOW_RATE_SCALES for q in spec[4][:2]]
    return [(q, 1) for q in native] + low


def _has(name: str, mode: str) -> bool:
    import av

    try:
        av.codec.Codec(name, mode)
        return True
    except Exception:  # noqa: BLE001 - PyAV raises different errors per version for an unknown codec
        return False


def available_codecs(names: Sequence[str]) -> dict[str, tuple]:
    """The codecs of ``names`` this PyAV build can encode and decode (AV1: SVT-AV1, else libaom)."""
    out = {}
    for name in names:
        spec = CODEC_TABLE[name]
        if name == "av1" and not (_has(spec[1], "w") and (_has(spec[2], "r") or _has("libaom-av1", "r"))):
            spec = AOM
        if name == "av1" and not _has(spec[2], "r"):
            spec = spec[:2] + ("libdav1d" if _has("libdav1d", "r") else "libaom-av1",) + spec[3:]
        if _has(spec[1], "w") and _has(spec[2], "r"):
            out[name] = spec
        else:
            print(f"skipping {name}: PyAV has no {spec[1]} encoder or {spec[2]} decoder", file=sys.stderr)
    return out


_START = re.compile(b"\x00\x00\x01")


def strip_sei(data: bytes, codec: str) -> bytes:
    """An Annex-B H.264 / H.265 access unit without its SEI NAL units (H.264 type 6; H.265 39, 40): encoder
    information a decoder does not need.  Other codecs' packets are returned unchanged."""
    if codec not in ("h264", "h265"):
        return data
    starts = [m.start() for m in _START.finditer(data)]
    if not starts:
        return data
    # each NAL unit with its start code (a 4-byte start code's leading zero included; a NAL unit never
    # ends in a zero byte, so a zero before 00 00 01 belongs to the start code)
    begins = [s - 1 if s > 0 and data[s - 1] == 0 else s for s in starts]
    out = [data[:begins[0]]]
    for k, s in enumerate(starts):
        end = begins[k + 1] if k + 1 < len(starts) else len(data)
        kind = data[s + 3] & 0x1F if codec == "h264" else (data[s + 3] >> 1) & 0x3F
        if not ((codec == "h264" and kind == 6) or (codec == "h265" and kind in (39, 40))):
            out.append(data[begins[k]:end])
    return b"".join(out)


def video_roundtrip(frames: np.ndarray, name: str, spec: tuple, q: int, fps: float = 8.0, scale: int = 1
                    ) -> tuple[int, np.ndarray]:
    """Encode (T, H, W, 3) uint8 ``frames`` with codec ``name`` at quality ``q`` (``scale`` > 1: downscaled by
    that factor first, the decoded frames upscaled back); (bitstream bytes, decoded RGB frames at the
    input size).  The bytes counted are exactly the packets the decoder is given."""
    import av
    import cv2

    _, encoder, decoder, options, _, _ = spec
    size = frames.shape[1:3]
    if scale > 1:
        frames = np.stack([cv2.resize(f, (size[1] // scale, size[0] // scale), interpolation=cv2.INTER_AREA)
                           for f in frames])
    T, H, W, _ = frames.shape
    ctx = av.CodecContext.create(encoder, "w")
    ctx.width, ctx.height, ctx.pix_fmt = W, H, "yuv420p"
    ctx.time_base = Fraction(1, 1000)
    ctx.framerate = Fraction(fps).limit_denominator(1001)
    ctx.options = options(q)
    packets = []
    for i, f in enumerate(frames):
        vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="rgb24").reformat(format="yuv420p")
        vf.pts = round(i * 1000 / fps)
        packets += ctx.encode(vf)
    packets += ctx.encode(None)
    data = [strip_sei(bytes(p), name) for p in packets]
    dec = av.CodecContext.create(decoder, "r")
    out = []
    for d in data:
        out += dec.decode(av.Packet(d))
    out += dec.decode(None)
    decoded = np.stack([o.to_ndarray(format="rgb24") for o in out])
    if decoded.shape != frames.shape:
        raise RuntimeError(f"{encoder} q={q}: decoded {decoded.shape}, expected {frames.shape}")
    if scale > 1:
        decoded = np.stack([cv2.resize(f, (size[1], size[0]), interpolation=cv2.INTER_LINEAR) for f in decoded])
    return sum(len(d) for d in data), decoded


# --- rate functions -------------------------------------------------------------------------------------
def pareto(points: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """The (bytes, psnr) points no cheaper point matches in PSNR, cheapest first (PSNR strictly rising)."""
    out: list[tuple[float, float]] = []
    for b, p in sorted(points, key=lambda x: (x[0], -x[1])):
        if math.isfinite(p) and b > 0 and (not out or p > out[-1][1]):
            out.append((float(b), float(p)))
    return out


def bytes_at_psnr(points: Sequence[tuple[float, float]], target: float) -> tuple[float | None, str]:
    """Bytes a codec with RD ``points`` [(bytes, psnr)] needs to reach ``target`` PSNR, interpolated
    linearly in log-bytes between the Pareto points around it: (bytes, "interpolated"); (cheapest bytes,
    "at_most") where even the cheapest point is better than ``target``; (None, "unreachable") where no
    point reaches it."""
    front = pareto(points)
    if not front or target > front[-1][1]:
        return None, "unreachable"
    if target < front[0][1]:
        return front[0][0], "at_most"
    for (b0, p0), (b1, p1) in zip(front, front[1:]):
        if p0 <= target <= p1:
            t = (target - p0) / (p1 - p0)
            return float(10 ** (math.log10(b0) + t * (math.log10(b1) - math.log10(b0)))), "interpolated"
    return front[0][0], "interpolated"  # a one-point front hit exactly


def bd_rate(test: Sequence[tuple[float, float]], anchor: Sequence[tuple[float, float]]) -> float | None:
    """Bjontegaard delta rate (%) of ``test`` against ``anchor``: the mean log-rate difference at equal
    PSNR over the PSNR range both Pareto curves cover, piecewise linear in (PSNR, log10 bytes); > 0 means
    ``test`` needs more bytes.  None where a curve has fewer than two points or the ranges do not overlap."""
    a, b = pareto(test), pareto(anchor)
    if len(a) < 2 or len(b) < 2:
        return None
    lo, hi = max(a[0][1], b[0][1]), min(a[-1][1], b[-1][1])
    if hi <= lo:
        return None
    grid = np.unique(np.clip([p for _, p in a + b] + [lo, hi], lo, hi))

    def area(front: list[tuple[float, float]]) -> float:
        y = np.interp(grid, [p for _, p in front], [math.log10(r) for r, _ in front])
        return float(np.sum((y[1:] + y[:-1]) / 2 * np.diff(grid)))

    return float((10 ** ((area(a) - area(b)) / (hi - lo)) - 1) * 100)


# --- one clip -------------------------------------------------------------------------------------------
def stored_sets(names: Sequence[str]) -> dict[str, list[str]]:
    return {"single": [names[0]], "all": list(names), "half": list(names[::2])}


def views_of(names: Sequence[str], stored: Sequence[str], kind: str) -> list[str]:
    return list(stored) if kind == "captured" else [n for n in names if n not in stored]


def nearest_stored(w2c: dict[str, np.ndarray], target: str, stored: Sequence[str]) -> tuple[str, float]:
    """The stored camera whose first-frame optical axis is closest in direction to ``target``'s."""
    from vt4dcodec.eval.protocol import axis_angles_deg

    if target in stored:
        return target, 0.0
    angles = axis_angles_deg(np.stack([w2c[target]] + [w2c[s] for s in stored]))[0, 1:]
    i = int(np.argmin(angles))
    return stored[i], float(angles[i])


def quality(pred: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    from vt4dcodec.eval.metrics import video_metrics

    m = video_metrics(pred, truth, np.zeros(truth.shape[:3], bool))
    return m["psnr"], m["ssim"]


def vt4d_bytes(scene: Any, encoding: str, net: Any) -> bytes:
    """The file of ``scene`` at a token encoding, or at quality level N of the model's entropy model for
    ``encoding = "qN"`` (learned-rans, format 1.6, with the model's own frozen tables)."""
    from vt4dcodec import codec
    from vt4dcodec.format import dumps

    if re.fullmatch(r"q\d+", encoding):
        return dumps(scene, encoding="learned-rans", quality=int(encoding[1:]), tables=codec.model_tables(net))
    return dumps(scene, encoding=encoding)


def evaluate_clip(capture: Any, start: int, net: Any, codecs: dict[str, tuple], encodings: Sequence[str],
                  quick: bool, seed: int = 0) -> dict[str, Any]:
    """Every setting of one clip: vt4d per encoding and each codec per quality step, each as
    {bytes, psnr, ssim} (bytes of the stored cameras, PSNR / SSIM averaged over the evaluated views).
    An encoding ``qNrM`` stores the tokens of ``codec.encode(..., quality=N, refine=M)`` (refined for that
    level), ``qNrMs`` those refined with ``tune="ssim"``; every other encoding stores the encoder's tokens."""
    from vt4dcodec import codec
    from vt4dcodec.eval.baselines import mean_colour
    from vt4dcodec.format import dumps

    t0 = time.perf_counter()
    T = net.config.frames
    pixels = T * net.config.image_size ** 2  # of one stored camera's clip: bits per pixel of the source video
    names = list(capture.camera_names)
    truth = {n: np.ascontiguousarray(capture.frames[n][start:start + T]) for n in names}
    trajs = {n: capture.cameras[n][start:start + T] for n in names}
    w2c = {n: trajs[n].w2c[0] for n in names}
    sets = stored_sets(names)

    rendered: dict[str, dict[str, dict[str, tuple[float, float]]]] = {}  # set -> encoding -> camera -> (psnr, ssim)
    file_bytes: dict[str, dict[str, int]] = {}
    for set_name, stored in sets.items():
        scenes: dict[bool, Any] = {}  # the encoder's tokens, per pass: a model with render feedback stores the
        rendered[set_name], file_bytes[set_name] = {}, {}  # first pass below its feedback_quality (feeds_back)
        targets = [n for n in names if any(n in views_of(names, stored, k) for k in ("captured", "novel"))]
        for enc in encodings:
            refined = re.fullmatch(r"q(\d+)r(\d+)(s?)", enc)
            level = int(enc[1:]) if re.fullmatch(r"q\d+", enc) else None
            key = net.config.feeds_back(level)
            if refined is None and key not in scenes:  # the tokens `vt4d encode` stores at enc
                scenes[key] = codec.encode(capture, net, cameras=stored, start=start, seed=seed,
                                           **({"quality": level} if level is not None else {"encoding": enc}))
            data = vt4d_bytes(scenes[key], enc, net) if refined is None else dumps(codec.encode(
                capture, net, cameras=stored, start=start, seed=seed, quality=int(refined.group(1)),
                refine=int(refined.group(2)), tune="ssim" if refined.group(3) else "psnr"))
            file_bytes[set_name][enc] = len(data)
            videos = codec.SceneDecoder.open(data, model=net).render_many([trajs[n] for n in targets], seed=seed)
            rendered[set_name][enc] = {n: quality(v, truth[n]) for n, v in zip(targets, videos)}

    t_vt4d = time.perf_counter() - t0
    decoded: dict[str, dict[tuple[int, int], dict[str, tuple[int, np.ndarray]]]] = {}
    for name, spec in codecs.items():
        decoded[name] = {}
        for q, f in sweep(spec, quick):
            decoded[name][q, f] = {n: video_roundtrip(truth[n], name, spec, q, float(capture.fps or 8.0), f)
                                   for n in names}

    out: dict[str, Any] = {"start": start, "settings": {}, "vt4d_s": round(t_vt4d, 2),
                           "codecs_s": round(time.perf_counter() - t0 - t_vt4d, 2)}
    for row, set_name, kind in SETTINGS:
        stored = sets[set_name]
        views = views_of(names, stored, kind)
        if not views:
            continue
        served = {v: nearest_stored(w2c, v, stored) for v in views}
        r: dict[str, Any] = {"stored": stored, "views": views,
                             "served_by": {v: s for v, (s, _) in served.items() if s != v},
                             "angle_deg": float(np.mean([a for _, a in served.values()])), "vt4d": {}, "codecs": {}}
        for enc in encodings:
            pq = [rendered[set_name][enc][v] for v in views]
            r["vt4d"][enc] = {"bytes": file_bytes[set_name][enc], "psnr": float(np.mean([p for p, _ in pq])),
                              "ssim": float(np.mean([s for _, s in pq])),
                              "bpp": 8.0 * file_bytes[set_name][enc] / (len(stored) * pixels)}
        for name, by_q in decoded.items():
            pts = []
            for (q, f), clips in by_q.items():
                pq = [quality(clips[served[v][0]][1], truth[v]) for v in views]
                pts.append({"q": q, "scale": f, "bytes": int(sum(clips[s][0] for s in stored)),
                            "psnr": float(np.mean([p for p, _ in pq])), "ssim": float(np.mean([s for _, s in pq]))})
            r["codecs"][name] = pts
        flat = [quality(mean_colour(truth[served[v][0]]), truth[v]) for v in views]
        r["flat_mean_colour"] = {"bytes": 3 * len(stored), "psnr": float(np.mean([p for p, _ in flat])),
                                 "ssim": float(np.mean([s for _, s in flat]))}
        out["settings"][row] = r
    return out


# --- summary --------------------------------------------------------------------------------------------
def compact_clip(clip: dict[str, Any]) -> dict[str, Any]:
    """A clip's record for the results file: each point as [bytes, psnr, ssim] (codec points in the order of
    the codec's ``sweep``)."""
    def triple(x: dict[str, float]) -> list[float]:
        return [x["bytes"], x["psnr"], x["ssim"]]

    settings = {row: {**{k: v for k, v in r.items() if k not in ("vt4d", "codecs", "flat_mean_colour")},
                      "flat_mean_colour": triple(r["flat_mean_colour"]),
                      "vt4d": {enc: triple(v) for enc, v in r["vt4d"].items()},
                      "codecs": {name: [triple(p) for p in pts] for name, pts in r["codecs"].items()}}
                for row, r in clip["settings"].items()}
    return {**clip, "settings": settings}


def to_json(result: dict[str, Any]) -> str:
    """The results file: floats to 4 decimals, lists of numbers on one line."""
    def rounded(x: Any) -> Any:
        if isinstance(x, float):
            return round(x, 4) if math.isfinite(x) else None
        if isinstance(x, dict):
            return {k: rounded(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [rounded(v) for v in x]
        return x

    def one_line(m: re.Match[str]) -> str:
        return re.sub(r"\s*\n\s*", " ", m.group(0)).replace("[ ", "[").replace(" ]", "]").replace("{ ", "{").replace(" }", "}")

    text = json.dumps(rounded(result), indent=1)
    text = re.sub(r"\[[^\[\]{}\"]*\]", one_line, text)  # lists of numbers
    return re.sub(r"\{[^\[\]{}]*\}", one_line, text) + "\n"  # objects of scalars


def _mean(rows: list[dict[str, float]]) -> dict[str, float]:
    return {k: float(np.mean([r[k] for r in rows])) for k in ("bytes", "psnr", "ssim")}


def _se(values: Sequence[float]) -> float | None:
    """Standard error of the mean (None for fewer than 2 values)."""
    return float(np.std(values, ddof=1) / math.sqrt(len(values))) if len(values) > 1 else None


def per_clip_ratios(rs: list[dict[str, Any]], name: str) -> dict[str, dict[str, Any]]:
    """Per vt4d encoding: each clip's vt4d bytes over the bytes the codec needs for that clip's vt4d PSNR
    (its own curve, every size), as mean and standard error over the clips where the codec's curve brackets
    the PSNR, with the counts of clips where its cheapest point is already better ("at_most": the ratio there
    is at least vt4d bytes / cheapest bytes) or which it never reaches."""
    out: dict[str, dict[str, Any]] = {}
    for enc in rs[0]["vt4d"]:
        ratios, at_most, never = [], 0, 0
        for r in rs:
            need, bound = bytes_at_psnr([(p["bytes"], p["psnr"]) for p in r["codecs"][name]], r["vt4d"][enc]["psnr"])
            if bound == "interpolated":
                ratios.append(r["vt4d"][enc]["bytes"] / need)
            elif bound == "at_most":
                at_most += 1
            else:
                never += 1
        out[enc] = {"mean": float(np.mean(ratios)) if ratios else None, "se": _se(ratios), "clips": len(ratios),
                    "at_most": at_most, "unreachable": never}
    return out


def equal_quality(points: list[tuple[float, float]], ref: dict[str, float]) -> dict[str, Any]:
    need, bound = bytes_at_psnr(points, ref["psnr"])
    return {"target_psnr": ref["psnr"], "codec_bytes": need, "bound": bound,
            "rate_ratio": None if need is None else ref["bytes"] / need}


def summarize_clips(clips: list[dict[str, Any]], reference: str) -> dict[str, Any]:
    """Per setting: mean vt4d point per encoding, mean codec curve per quality step, equal-quality bytes
    and rate ratio against vt4d at ``reference`` encoding, BD-rate of vt4d's encodings against each codec."""
    out: dict[str, Any] = {}
    for row, _, _ in SETTINGS:
        rs = [c["settings"][row] for c in clips if row in c["settings"]]
        if not rs:
            continue
        vt4d = {enc: {**_mean([r["vt4d"][enc] for r in rs]),
                      "bpp": float(np.mean([r["vt4d"][enc]["bpp"] for r in rs]))} for enc in rs[0]["vt4d"]}
        ref = vt4d[reference]
        entry: dict[str, Any] = {"clips": len(rs), "stored_cameras": len(rs[0]["stored"]),
                                 "views": len(rs[0]["views"]), "angle_deg_mean": float(np.mean([r["angle_deg"] for r in rs])),
                                 "novel_served_by_nearest_stored_camera": row.endswith("novel"),
                                 "flat_mean_colour": _mean([r["flat_mean_colour"] for r in rs]),
                                 "vt4d": vt4d, "reference_encoding": reference, "codecs": {},
                                 "vt4d_se": {enc: {"psnr": _se([r["vt4d"][enc]["psnr"] for r in rs]),
                                                   "bytes": _se([r["vt4d"][enc]["bytes"] for r in rs])}
                                             for enc in rs[0]["vt4d"]}}
        vt4d_curve = [(v["bytes"], v["psnr"]) for v in vt4d.values()]
        for name in rs[0]["codecs"]:
            keys = [(p["q"], p["scale"]) for p in rs[0]["codecs"][name]]
            points = [{"q": q, "scale": f, **_mean([r["codecs"][name][i] for r in rs])} for i, (q, f) in enumerate(keys)]
            curve = [p for p in points if p["scale"] == 1]
            pts = [(c["bytes"], c["psnr"]) for c in curve]
            entry["codecs"][name] = {
                "curve": curve, "low_rate": [p for p in points if p["scale"] > 1],
                "equal_quality": equal_quality(pts, ref),
                "equal_quality_any_size": equal_quality([(c["bytes"], c["psnr"]) for c in points], ref),
                "bd_rate_percent": bd_rate(vt4d_curve, pts),
                "best_psnr": max(p for _, p in pts), "cheapest": min(pts)[0],
                "rate_ratio_per_clip": per_clip_ratios(rs, name),
            }
        out[row] = entry
    return out


def _fmt_bytes(x: float | None) -> str:
    return "-" if x is None else f"{x:,.0f}"


def _equal_text(eq: dict[str, Any]) -> tuple[str, str]:
    """(bytes, rate ratio) cells: "<= B" / ">= R" where the codec's cheapest point is already better."""
    if eq["bound"] == "unreachable":
        return "never reaches it", "-"
    bound = eq["bound"] == "at_most"
    return f"{'<= ' if bound else ''}{eq['codec_bytes']:,.0f}", f"{'>= ' if bound else ''}{eq['rate_ratio']:.2f}x"


def markdown(result: dict[str, Any]) -> str:
    """The generated tables of docs/benchmarks/codecs.md."""
    m = result["model"]
    lines = [f"Model {m['id']} {m['version']} ({m['fingerprint']}); {result['decode_steps']} decode step(s); "
             f"vt4d at `{result['reference_encoding']}` (the default token encoding; `qNrM`: level N refined M "
             f"iterations at encode, codec.encode(refine=M)). Command: "
             f"`{result['command']}`.", ""]
    for ds, data in result["datasets"].items():
        s = data["summary"]
        lines += [f"**{data['title']}** ({data['clips']} clips, {data['cameras']} cameras each)", "",
                  "| setting | stored | views | vt4d bytes | vt4d PSNR / SSIM | codec | codec bytes at vt4d's PSNR "
                  "| rate ratio vt4d / codec | with 1/2, 1/4-size encodes | BD-rate | codec sweep: cheapest -> best |",
                  "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---|"]
        for row, e in s.items():
            v = e["vt4d"][result["reference_encoding"]]
            note = " (nearest stored camera's frames)" if e["novel_served_by_nearest_stored_camera"] else ""
            for k, (name, c) in enumerate(e["codecs"].items()):
                need, ratio = _equal_text(c["equal_quality"])
                low = "/".join(_equal_text(c["equal_quality_any_size"]))
                bd = "no overlap" if c["bd_rate_percent"] is None else f"{c['bd_rate_percent']:+.0f} %"
                lo = min(c["curve"], key=lambda p: p["bytes"])
                hi = max(c["curve"], key=lambda p: p["psnr"])
                span = f"{lo['bytes']:,.0f} B {lo['psnr']:.1f} dB -> {hi['bytes']:,.0f} B {hi['psnr']:.1f} dB"
                head = (f"| {row} | {e['stored_cameras']} | {e['views']} | {v['bytes']:,.0f} | "
                        f"{v['psnr']:.2f} / {v['ssim']:.3f} |") if k == 0 else "| | | | | |"
                lines.append(f"{head} {name}{note} | {need} | {ratio} | {low} | {bd} | {span} |")
            f = e["flat_mean_colour"]
            lines.append(f"| | | | | | flat mean colour{note.replace('frames', 'mean colour')} | {f['bytes']:.0f} | | | | "
                         f"{f['psnr']:.2f} dB / {f['ssim']:.3f} |")
        lines += ["", "vt4d file bytes / PSNR (dB) per token encoding:", "",
                  "| setting | " + " | ".join(next(iter(s.values()))["vt4d"]) + " |",
                  "|---|" + "---:|" * len(next(iter(s.values()))["vt4d"])]
        for row, e in s.items():
            lines.append(f"| {row} | " + " | ".join(f"{v['bytes']:,.0f} / {v['psnr']:.2f}" for v in e["vt4d"].values())
                         + " |")
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def headline(result: dict[str, Any], dataset: str = "synthetic", codec: str = "h265") -> dict[str, Any]:
    """Whole capture as .vt4d vs per-camera ``codec`` at equal PSNR: captured views (all cameras stored)
    and novel views (every other camera stored, the rest rendered / served the nearest stored camera)."""
    s = result["datasets"][dataset]["summary"]
    out = {}
    for key, row in (("captured", "all/captured"), ("novel", "half/novel")):
        if row in s and codec in s[row]["codecs"]:
            e = s[row]
            v = e["vt4d"][result["reference_encoding"]]
            out[key] = {"setting": row, "vt4d_bytes": v["bytes"], "vt4d_psnr": v["psnr"],
                        **e["codecs"][codec]["equal_quality"], "codec_best_psnr": e["codecs"][codec]["best_psnr"],
                        "flat_mean_colour_psnr": e["flat_mean_colour"]["psnr"]}
    return out


# --- figure ---------------------------------------------------------------------------------------------
def figure_codecs(result: dict[str, Any]) -> str:
    """The codecs a study ran, as the figure names them ("H.265", "H.264 / H.265 / AV1")."""
    labels = {"h264": "H.264", "h265": "H.265", "av1": "AV1"}
    return " / ".join(labels.get(k, k) for k in result.get("codecs", {})) or "no codec"


def plot(result: dict[str, Any], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    from vt4dcodec.eval.report import save_png_small

    datasets = list(result["datasets"].items())
    rows = [r for r, _, _ in SETTINGS]
    fig, axes = plt.subplots(len(datasets), len(rows), figsize=(3.3 * len(rows), 3.0 * len(datasets)),
                             squeeze=False)
    colours = {"h264": "C0", "h265": "C1", "av1": "C2"}
    for i, (ds, data) in enumerate(datasets):
        for j, row in enumerate(rows):
            ax = axes[i, j]
            e = data["summary"].get(row)
            if e is None:
                ax.axis("off")
                continue
            for name, c in e["codecs"].items():
                ax.plot([p["bytes"] for p in c["curve"]], [p["psnr"] for p in c["curve"]], "o-", ms=3, lw=1,
                        color=colours.get(name), label=name + (" (nearest cam)" if row.endswith("novel") else ""))
                ax.plot([p["bytes"] for p in c["low_rate"]], [p["psnr"] for p in c["low_rate"]], "o", ms=4,
                        mfc="none", color=colours.get(name), label=None if j or i or name != next(iter(e["codecs"]))
                        else "1/2, 1/4-size encodes")
            pts = sorted((v["bytes"], v["psnr"], k) for k, v in e["vt4d"].items())
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "s", ms=3, color="C3", label="vt4d encodings")
            ref = e["vt4d"][result["reference_encoding"]]
            ax.plot(ref["bytes"], ref["psnr"], "*", ms=11, color="C3", mec="black",
                    label=f"vt4d {result['reference_encoding']}")
            ax.axhline(e["flat_mean_colour"]["psnr"], color="gray", ls="--", lw=0.8, label="flat mean colour")
            ax.set_xscale("log")
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.grid(alpha=0.3)
            ax.set_title(f"{data['short']}: {row} ({e['stored_cameras']} stored, {e['views']} views)", fontsize=8)
            ax.tick_params(labelsize=7)
            if i == len(datasets) - 1:
                ax.set_xlabel("bytes (stored cameras, whole .vt4d file)", fontsize=7)
            if j == 0:
                ax.set_ylabel("PSNR (dB)", fontsize=8)
            if i == 0 and j == 0:
                ax.legend(fontsize=6, loc="best")
    m = result["model"]
    fig.suptitle(f".vt4d ({m['id']} {m['version']}) vs {figure_codecs(result)} per camera clip "
                 f"({result['clip']}); novel views: codecs show the nearest stored camera", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    return save_png_small(fig, path, dpi=80)


def update_doc(doc: Path, table: str) -> bool:
    """Replace the text between the codecs-table markers of ``doc``; False if the markers are missing."""
    if not doc.is_file():
        return False
    text = doc.read_text()
    if TABLE_BEGIN not in text or TABLE_END not in text:
        return False
    head, rest = text.split(TABLE_BEGIN, 1)
    _, tail = rest.split(TABLE_END, 1)
    doc.write_text(f"{head}{TABLE_BEGIN}\n{table}{TABLE_END}{tail}")
    return True


# --- command --------------------------------------------------------------------------------------------
def run(args: argparse.Namespace, argv: Sequence[str]) -> dict[str, Any]:
    import torch

    from vt4dcodec import codec
    from vt4dcodec.format import ENCODINGS
    from vt4dcodec.synth import SynthConfig, generate_scene

    torch.set_num_threads(args.threads)
    net = codec.load_model(args.model).eval()
    cfg = net.config
    levels = tuple(f"q{q}" for q in codec.quality_levels(net))
    encodings = ENCODINGS + levels if args.encodings == "all" else levels if args.encodings == "levels" else \
        tuple(e.strip() for e in args.encodings.split(","))
    bad = [e for e in encodings if e not in ENCODINGS + levels
           and not (re.fullmatch(r"q\d+r\d+s?", e) and e[:e.index("r")] in levels)]
    if bad:
        raise SystemExit(f"--encodings: unknown {bad}; the model's quality levels are {list(levels) or 'none'} "
                         "(qNrM: level N refined M iterations; qNrMs: for SSIM)")
    reference = args.reference or (codec.DEFAULT_ENCODING if codec.DEFAULT_ENCODING in encodings else encodings[0])
    codecs = available_codecs([c.strip() for c in args.codecs.split(",")])
    fp = codec.model_fingerprint(net)
    started, cpu0 = time.perf_counter(), time.process_time()
    datasets: dict[str, Any] = {}

    clips = []
    for seed in range(args.first_seed, args.first_seed + args.scenes):
        t0 = time.perf_counter()
        synth = generate_scene(seed, split="test", config=SynthConfig(
            num_cameras=args.cameras, num_frames=cfg.frames, height=cfg.image_size, width=cfg.image_size))
        clip = evaluate_clip(synth.capture, 0, net, codecs, encodings, args.quick)
        clips.append({"seed": seed, **clip})
        print(f"synthetic seed {seed}: {time.perf_counter() - t0:.1f} s", flush=True)
    if clips:
        datasets["synthetic"] = {"title": f"Held-out synthetic captures (split test, seeds {args.first_seed}.."
                                          f"{args.first_seed + args.scenes - 1})", "short": "synthetic",
                                 "clips": len(clips), "cameras": args.cameras,
                                 "summary": summarize_clips(clips, reference),
                                 "per_clip": [compact_clip(c) for c in clips]}

    real = None if args.real_clips == 0 else (args.capture or _find_caliscope())
    if real is not None:
        key, title, cameras, clips = real_footage_clips(Path(real), net, codecs, encodings, args)
        datasets[key] = {"title": title, "short": key, "clips": len(clips), "cameras": cameras,
                         "summary": summarize_clips(clips, reference), "per_clip": [compact_clip(c) for c in clips]}
    elif args.real_clips != 0:
        print("caliscope_4cam not found (--capture or $VT4D_CALISCOPE): real footage skipped", file=sys.stderr)

    result = {
        "command": " ".join(["python bench/bench_codecs.py", *argv]),
        "model": {"id": fp.model_id, "version": fp.model_version, "fingerprint": fp.short(),
                  "training_step": net.training_step},
        "decode_steps": int(net.decode_steps), "clip": f"{cfg.frames} frames at {cfg.image_size}x{cfg.image_size}",
        "encodings": list(encodings), "reference_encoding": reference,
        "codecs": {k: {"label": v[0], "encoder": v[1], "decoder": v[2], "options": v[3]("Q"),
                       "sweep": sweep(v, args.quick)} for k, v in codecs.items()},
        "bytes": "vt4d: whole file; codecs: bitstream packets (x264's informational SEI removed), summed over "
                 "the stored cameras",
        "quick": bool(args.quick), "datasets": datasets,
        "wall_s": round(time.perf_counter() - started, 1), "cpu_s": round(time.process_time() - cpu0, 1),
        "threads": args.threads,
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "load_avg_1min": os.getloadavg()[0]},
    }
    if "synthetic" in datasets:
        result["headline"] = headline(result)
    return result


def real_footage_clips(path: Path, net: Any, codecs: dict[str, tuple], encodings: Sequence[str],
                       args: argparse.Namespace) -> tuple[str, str, int, list[dict[str, Any]]]:
    """(dataset key, title, cameras, evaluated clips) of consecutive model-length clips of ``path``: a capture
    directory (``vt4d import`` / ``vt4d synth`` output; each clip read and centre-cropped to the model's
    square) or a caliscope recording (imported at the model's size)."""
    from vt4dcodec import codec
    from vt4dcodec.capture.capture import Capture
    from vt4dcodec.capture.resample import fit_capture
    from vt4dcodec.eval.real_footage import open_capture

    cfg = net.config
    source = open_capture(path, size=cfg.image_size)  # a directory's manifest, or caliscope imported at that size
    starts = list(range(0, source.num_frames - cfg.frames + 1, cfg.frames))
    if isinstance(source, Capture):
        key, title = "caliscope", f"Real caliscope_4cam recording ({source.num_frames} frames at {source.fps:.1f} fps, consecutive clips)"
        cameras = len(source.camera_names)

        def clip_of(start: int) -> tuple[Any, int]:
            return source, start
    else:
        names = [c.name for c in source.cameras]
        key, title = "capture", f"Capture {source.capture_id or path.name} ({source.num_frames} frames, consecutive clips)"
        cameras = len(names)

        def clip_of(start: int) -> tuple[Any, int]:
            clip = codec.read_clip(source, names, start, cfg.frames)
            return fit_capture(clip, height=cfg.image_size, width=cfg.image_size), 0
    if not starts:
        raise SystemExit(f"--capture {path}: fewer frames than the model's {cfg.frames}-frame clip")
    clips = []
    for start in starts[:args.real_clips if args.real_clips > 0 else None]:
        t0 = time.perf_counter()
        clips.append(evaluate_clip(*clip_of(start), net, codecs, encodings, args.quick))
        print(f"{key} clip {start}: {time.perf_counter() - t0:.1f} s", flush=True)
    return key, title, cameras, clips


def _find_caliscope() -> Path | None:
    from vt4dcodec.capture.caliscope import find_sample_capture

    return find_sample_capture()


def _path(value: str) -> Path | None:
    return None if value.lower() == "none" else Path(value)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default="vt4d-tiny", help="shipped model id or model directory")
    p.add_argument("--scenes", type=int, default=20, help="held-out synthetic captures (seeds first..first+N-1)")
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--cameras", type=int, default=10, help="cameras per synthetic capture")
    p.add_argument("--capture", default=None, help="real footage: a capture directory (vt4d import / vt4d synth) or a "
                   "caliscope recording (default: shared/data/caliscope_4cam)")
    p.add_argument("--real-clips", type=int, default=-1, help="clips of --capture (-1: all, 0: skip real footage)")
    p.add_argument("--encodings", default="all",
                   help="token encodings and quality levels (q1, q2, ... of a model with an entropy model: learned-rans "
                        "at that level; qNrM: level N refined M iterations at encode; qNrMs: refined with --tune ssim), comma-separated; 'levels' (every quality level) or 'all' (every encoding and level)")
    p.add_argument("--reference", default=None,
                   help="the encoding or level whose point the equal-quality tables compare (default: the codec's "
                        "default encoding when measured, else the first)")
    p.add_argument("--codecs", default="h264,h265,av1")
    p.add_argument("--quick", action="store_true", help="3-point codec sweeps; with the defaults also 2 scenes "
                   "and 2 caliscope clips")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", default=str(ROOT / "bench/results/codecs.json"))
    p.add_argument("--figure", default=str(ROOT / "docs/figures/codecs.png"), help="PNG path, or 'none'")
    p.add_argument("--doc", default=str(ROOT / "docs/benchmarks/codecs.md"),
                   help="Markdown file whose codecs-table block is regenerated, or 'none'")
    args = p.parse_args(argv)
    if args.quick:
        args.scenes = 2 if "--scenes" not in argv else args.scenes
        args.real_clips = 2 if "--real-clips" not in argv else args.real_clips
    result = run(args, argv)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(to_json(result))
    table = markdown(result)
    print(table)
    if (fig := _path(args.figure)) is not None and result["datasets"]:
        plot(result, fig)
    if (doc := _path(args.doc)) is not None:
        print(f"{doc}: table {'updated' if update_doc(doc, table) else 'not updated (no codecs-table markers)'}")
    for key, h in result.get("headline", {}).items():
        print(f"headline {key}: vt4d {h['vt4d_bytes']:,.0f} B at {h['vt4d_psnr']:.2f} dB; H.265 {h['bound']} "
              f"{_fmt_bytes(h['codec_bytes'])} B (best {h['codec_best_psnr']:.2f} dB)")
    print(f"wall {result['wall_s']} s, cpu {result['cpu_s']} s -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
