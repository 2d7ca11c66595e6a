"""``vt4d demo``: the whole codec on one held-out synthetic scene, in well under a minute.

Makes a synthetic multi-camera capture from the test split (assets no training scene used), encodes one
camera into a ``.vt4d`` file, decodes the source view and two other cameras' trajectories (novel views
with ground truth), writes H.264 mp4s (each view, its ground truth, and both side by side, enlarged 4x for
viewing) and a PNG contact sheet, and reports the file size and PSNR.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from . import codec
from .capture import Capture
from .capture.contact_sheet import write_contact_sheet
from .capture.io import MANIFEST_NAME, write_capture
from .errors import CaptureError
from .format import save
from .media import psnr, side_by_side, write_mp4
from .media import upscale as enlarge
from .synth import SynthConfig, generate_scene

__all__ = ["run_demo", "REPORT_FILE"]

REPORT_FILE = "demo_report.json"  # written last; marks a directory as the demo's own output


def run_demo(output: str | Path, *, model: str = "vt4d-tiny", seed: int = 0, steps: int | None = None,
             overwrite: bool = False, upscale: int = 4,
             log: Callable[[str], Any] | None = print) -> dict[str, Any]:
    """Run the demo into ``output``; returns a JSON-able summary (paths, bytes, PSNR per view), also
    written to ``output/demo_report.json``.

    A directory that holds an earlier demo's report is the demo's own and is rewritten; a capture the
    demo did not write is replaced only with ``overwrite=True`` (``vt4d demo --overwrite``).  Videos are
    enlarged ``upscale`` times by pixel repetition (PSNR is measured on the rendered pixels)."""
    say = log or (lambda *_: None)
    enlarge(np.zeros((1, 1, 1, 3), np.uint8), upscale)  # a bad factor fails before any work
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    net = codec.load_encoder(model)  # the exported encoder on onnxruntime where the model has one (no torch)
    cfg = net.config
    synth = generate_scene(seed, split="test", config=SynthConfig(num_frames=cfg.frames, height=cfg.image_size,
                                                                   width=cfg.image_size))
    cap = synth.capture
    replace = overwrite or (out / REPORT_FILE).is_file()  # an earlier demo's output is the demo's own
    if (out / "capture" / MANIFEST_NAME).exists() and not replace:
        raise CaptureError(f"{out / 'capture'} already holds a capture the demo did not write; pass "
                           "--overwrite to replace it, or choose another -o/--output")
    write_capture(cap, out / "capture", media="png", overwrite=replace)
    names = cap.camera_names
    source, novel = names[0], [names[len(names) // 3], names[(2 * len(names)) // 3]]
    say(f"capture: {len(names)} cameras x {cap.num_frames} frames at {cfg.image_size}x{cfg.image_size} "
        f"-> {out / 'capture'}")

    t0 = time.perf_counter()
    scene = codec.encode(cap, net, camera=source, seed=seed)  # the model's default level (or encoding)
    scene_path = out / "scene.vt4d"
    nbytes = save(scene, scene_path)
    encode_s = time.perf_counter() - t0
    raw_bytes = int(cap.frames[source].nbytes)
    stored_as = scene.encoding + ("" if scene.quality is None else f" at quality {scene.quality}")
    say(f"encoded camera {source} ({stored_as}): {scene_path} is {nbytes} bytes ({raw_bytes / nbytes:.0f}x smaller "
        f"than its {raw_bytes} bytes of raw RGB) in {encode_s:.1f} s")

    t0 = time.perf_counter()
    decoder = codec.SceneDecoder.open(scene_path)
    views = {source: "source"} | {n: cap.cameras[n] for n in novel}
    rendered = dict(zip(views, decoder.render_many(list(views.values()), steps=steps, seed=seed)))
    decode_s = time.perf_counter() - t0

    report: dict[str, Any] = {"scene_file": str(scene_path), "scene_bytes": nbytes, "raw_rgb_bytes": raw_bytes,
                              "encoding": scene.encoding, "quality": scene.quality,
                              "encode_seconds": round(encode_s, 2), "decode_seconds": round(decode_s, 2),
                              "steps": decoder.model.decode_steps if steps is None else steps, "seed": seed, "model": decoder.model.model_id, "views": {}}
    source_mean = cap.frames[source].reshape(-1, 3).mean(axis=0).round().astype(np.uint8)
    rows_frames, rows_cams = {}, {}
    for name, video in rendered.items():
        kind = "source" if name == source else "novel"
        gt = cap.frames[name]
        path = write_mp4(out / f"{kind}_{name}.mp4", video, fps=cap.fps, scale=upscale)
        write_mp4(out / f"{kind}_{name}_ground_truth.mp4", gt, fps=cap.fps, scale=upscale)
        both = write_mp4(out / f"{kind}_{name}_truth_vs_decoded.mp4",
                         side_by_side(enlarge(gt, upscale), enlarge(video, upscale)), fps=cap.fps)
        value = psnr(video, gt)
        dyn = psnr(video, gt, synth.dynamic_mask[name])
        # the structure-free reference: every pixel the source clip's mean colour (what a codec that
        # kept 3 numbers would score); a render must beat it clearly to carry the scene
        flat = psnr(np.broadcast_to(source_mean, gt.shape), gt)
        report["views"][name] = {"kind": kind, "video": str(path), "side_by_side_video": str(both),
                                 "psnr_db": round(value, 2),
                                 "flat_mean_colour_psnr_db": round(flat, 2),
                                 "dynamic_psnr_db": None if np.isnan(dyn) else round(dyn, 2)}
        say(f"{kind} view {name}: PSNR {value:.2f} dB (flat source mean colour {flat:.2f} dB; moving objects "
            f"{dyn:.2f} dB) -> {path}")
        rows_frames[f"{name} gt"], rows_cams[f"{name} gt"] = gt, cap.cameras[name]
        rows_frames[f"{name} ours"], rows_cams[f"{name} ours"] = video, cap.cameras[name]
    sheet = out / "contact_sheet.png"
    write_contact_sheet(Capture(cameras=rows_cams, frames=rows_frames, fps=cap.fps, capture_id="demo"), sheet)
    report["contact_sheet"] = str(sheet)
    report["total_seconds"] = round(time.perf_counter() - started, 2)
    (out / REPORT_FILE).write_text(json.dumps(report, indent=2, sort_keys=True) + "\n")
    say(f"contact sheet (rows: ground truth / decoded per view) -> {sheet}")
    say(f"done in {report['total_seconds']:.1f} s")
    return report
