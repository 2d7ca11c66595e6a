"""Batched rendering against single renders (issue 51.2): N views of one scene as one batch, side by side
with the same N views rendered one at a time, in one run.

    python bench/bench_render_batch.py [--model vt4d-tiny] [--views 10] [--repeats 5] [--threads 1,2]
                                       [--runtime torch|onnx] [--stages] [--out bench/results/render_batch.json]

Encodes camera 0 of a held-out synthetic 10-camera capture (split "test", seed ``--seed``) with the model's
default encoding, opens it once (``codec.SceneDecoder``) and renders the capture's cameras as targets
(``--views`` of them, cycling if more are asked): ``render`` once per view, then ``render_many`` of all of
them with ``RENDER_BATCH`` set to ``--views`` (one forward pass), alternating which goes first in each
repeat.  For every torch thread count it reports the median wall and process CPU time per view of both, the
speed-up per view (single / batched; also of the best repeats, the least disturbed on a shared machine), and the largest difference between a batched view and the same view
alone (uint8 grey levels, and the renderer's float frames in [0, 1]).  ``--stages`` adds the split of one forward pass into the renderer's sampler
(tokens -> latents) and the frozen decoder (latents -> frames), at batch 1 and at ``--views``, CPU time, and the
decoder alone in its channels-last layout (as the codec runs it) beside the same convolutions on NCHW tensors.
The machine is shared: load averages before and after are recorded.
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

import numpy as np
import torch

from vt4dcodec import codec
from vt4dcodec.format import dumps
from vt4dcodec.synth import SynthConfig, generate_scene


def timed(fn):
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def model_inputs(decoder: codec.SceneDecoder, targets: list) -> tuple:
    """The renderer's inputs for ``targets`` as one batch, as SceneDecoder.render_many builds them."""
    n = len(targets)
    resolved = [decoder.trajectory(t) for t in targets]
    z_s = torch.from_numpy(np.ascontiguousarray(decoder.scene.static_tokens, dtype=np.float32))[None].expand(n, -1, -1)
    z_d = torch.from_numpy(np.ascontiguousarray(decoder.scene.dynamic_tokens, dtype=np.float32))[None].expand(n, -1, -1)
    K = torch.from_numpy(np.stack([t.K for t in resolved]).astype(np.float32))
    w2c = torch.from_numpy(decoder.model_w2c(np.stack([t.w2c for t in resolved])))
    source = decoder.source_cameras() if decoder.model.needs_source else None
    return z_s, z_d, K, w2c, None if source is None else tuple(t.expand(n, *t.shape[1:]) for t in source)


def float_difference(decoder: codec.SceneDecoder, targets: list) -> float:
    """Largest difference of the renderer's float frames (in [0, 1]) between the batch and each view alone."""
    z_s, z_d, K, w2c, source = model_inputs(decoder, targets)
    batch = decoder.model.render(z_s, z_d, K, w2c, source=source)
    worst = 0.0
    for i in range(len(targets)):
        alone = decoder.model.render(z_s[i:i + 1], z_d[i:i + 1], K[i:i + 1], w2c[i:i + 1],
                                     source=None if source is None else tuple(t[i:i + 1] for t in source))
        worst = max(worst, float((batch[i:i + 1] - alone).abs().max()))
    return worst


def stage_times(decoder: codec.SceneDecoder, targets: list, batch: int, repeats: int) -> dict[str, float]:
    """CPU seconds per view of the sampler and of the decoder for one forward pass of ``batch`` views."""
    net = decoder.model
    z_s, z_d, K, w2c, source = model_inputs(decoder, targets[:batch])
    sampler, frames = [], []
    for _ in range(repeats):
        latents, _, c_lat = timed(lambda: net.render_latents(z_s, z_d, K, w2c, source=source))
        _, _, c_dec = timed(lambda: net.render(z_s, z_d, K, w2c, source=source))
        sampler.append(c_lat / batch)
        frames.append(max(c_dec - c_lat, 0.0) / batch)
    return {"sampler_cpu_s_per_view": statistics.median(sampler), "decoder_cpu_s_per_view": statistics.median(frames)}


def decoder_layouts(decoder: codec.SceneDecoder, targets: list, batch: int, repeats: int) -> dict[str, float]:
    """CPU seconds per view of the frozen decoder alone on one forward pass's latents of ``batch`` views, side by
    side: as the codec runs it (``decode_raw``: channels-last convolutions) and on the same tensors in NCHW order
    (the decoder before), with the largest difference of their frames."""
    net = decoder.model
    z_s, z_d, K, w2c, source = model_inputs(decoder, targets[:batch])
    ae = net.autoencoder
    latents = net.render_latents(z_s, z_d, K, w2c, source=source)
    raw = (latents.flatten(0, 1) * ae.latent_std[:, None, None] + ae.latent_mean[:, None, None]).contiguous()
    timings: dict[str, list[float]] = {"channels_last": [], "nchw": []}
    for r in range(repeats):
        order = ("channels_last", "nchw") if r % 2 == 0 else ("nchw", "channels_last")
        for name in order:
            fn = (lambda: ae.decode_raw(raw)) if name == "channels_last" else (lambda: torch.sigmoid(ae.decoder(raw)))
            _, _, cpu = timed(fn)
            timings[name].append(cpu / batch)
    difference = float((ae.decode_raw(raw) - torch.sigmoid(ae.decoder(raw))).abs().max())
    return {"decoder_channels_last_cpu_s_per_view": statistics.median(timings["channels_last"]),
            "decoder_nchw_cpu_s_per_view": statistics.median(timings["nchw"]),
            "decoder_layouts_max_difference": difference}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default=codec.DEFAULT_MODEL)
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", default="1,2", help="torch thread counts to measure, comma-separated")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--stages", action="store_true", help="also split a forward pass into sampler and decoder")
    parser.add_argument("--runtime", choices=("torch", "onnx"), default="torch",
                        help="renderer runtime: the torch networks, or the exported renderer.onnx on onnxruntime (its "
                             "own threads: --threads, --stages and the float comparison apply to torch only)")
    parser.add_argument("--out", type=Path, default=Path("bench/results/render_batch.json"))
    args = parser.parse_args(argv)
    load_before = os.getloadavg()
    net = codec.load_model(args.model)
    cfg = net.config
    synth = generate_scene(args.seed, split="test", config=SynthConfig(num_cameras=10, num_frames=cfg.frames,
                                                                      height=cfg.image_size, width=cfg.image_size))
    cap = synth.capture
    renderer = net if args.runtime == "torch" else codec.load_renderer(args.model, "onnx")
    decoder = codec.SceneDecoder.open(dumps(codec.encode(cap, net, camera=cap.camera_names[0])), model=renderer)
    targets = [cap.cameras[cap.camera_names[i % len(cap.camera_names)]] for i in range(args.views)]
    codec.RENDER_BATCH = max(codec.RENDER_BATCH, args.views)  # the N views in one forward pass
    runs = []
    thread_counts: list[int | None] = [int(t) for t in args.threads.split(",")] if args.runtime == "torch" else [None]
    for threads in thread_counts:
        if threads is not None:
            torch.set_num_threads(threads)
        decoder.render_many(targets[:2])  # warm-up: first-call allocations and kernels
        decoder.render(targets[0])
        single_wall, single_cpu, batch_wall, batch_cpu = [], [], [], []
        alone = batched = None
        for r in range(args.repeats):
            def singles():
                return [decoder.render(t) for t in targets]

            def batch():
                return decoder.render_many(targets)

            order = (singles, batch) if r % 2 == 0 else (batch, singles)
            for fn in order:
                out, wall, cpu = timed(fn)
                if fn is singles:
                    alone = out
                    single_wall.append(wall / args.views)
                    single_cpu.append(cpu / args.views)
                else:
                    batched = out
                    batch_wall.append(wall / args.views)
                    batch_cpu.append(cpu / args.views)
        assert alone is not None and batched is not None
        differ = max(int(np.abs(a.astype(int) - b.astype(int)).max()) for a, b in zip(alone, batched))
        differ_float = float_difference(decoder, targets) if args.runtime == "torch" else None
        run = {
            "threads": threads,
            "single_wall_s_per_view": statistics.median(single_wall),
            "batch_wall_s_per_view": statistics.median(batch_wall),
            "single_cpu_s_per_view": statistics.median(single_cpu),
            "batch_cpu_s_per_view": statistics.median(batch_cpu),
            "single_wall_s_per_view_all": single_wall, "batch_wall_s_per_view_all": batch_wall,
            "max_grey_level_difference": differ, "max_float_difference": differ_float,
        }
        run["speedup_wall"] = run["single_wall_s_per_view"] / run["batch_wall_s_per_view"]
        run["speedup_cpu"] = run["single_cpu_s_per_view"] / run["batch_cpu_s_per_view"]
        # the best repeat of each: on a shared machine the least disturbed, closest to what the work costs
        run["speedup_wall_best"] = min(single_wall) / min(batch_wall)
        run["speedup_cpu_best"] = min(single_cpu) / min(batch_cpu)
        run["single_cpu_s_per_view_all"], run["batch_cpu_s_per_view_all"] = single_cpu, batch_cpu
        if args.stages and args.runtime == "torch":
            run["stages_batch_1"] = stage_times(decoder, targets, 1, args.repeats)
            run["stages_batch_n"] = stage_times(decoder, targets, args.views, args.repeats)
            with torch.no_grad():
                run["decoder_layouts_batch_1"] = decoder_layouts(decoder, targets, 1, args.repeats)
                run["decoder_layouts_batch_n"] = decoder_layouts(decoder, targets, args.views, args.repeats)
        runs.append(run)
        print(f"{threads or 'onnxruntime default'} thread(s): single {run['single_wall_s_per_view'] * 1000:.0f} ms/view wall "
              f"({run['single_cpu_s_per_view'] * 1000:.0f} CPU), batch of {args.views} "
              f"{run['batch_wall_s_per_view'] * 1000:.0f} ms/view wall ({run['batch_cpu_s_per_view'] * 1000:.0f} CPU): "
              f"{run['speedup_wall']:.2f}x wall, {run['speedup_cpu']:.2f}x CPU per view (best repeats "
              f"{run['speedup_wall_best']:.2f}x, {run['speedup_cpu_best']:.2f}x); views differ by at most "
              f"{differ} grey level(s)" + ("" if differ_float is None else f", {differ_float:.1e} in float"),
              file=sys.stderr)
    result = {
        "model": codec.model_fingerprint(net).to_dict(), "runtime": args.runtime, "views": args.views,
        "repeats": args.repeats,
        "steps": net.decode_steps, "frames": cfg.frames, "image_size": cfg.image_size, "seed": args.seed,
        "runs": runs, "target_speedup": 3.0,
        "load_average_before": load_before, "load_average_after": os.getloadavg(),
        "cpus": os.cpu_count(), "machine": platform.machine(), "processor": platform.processor(),
        "torch": torch.__version__, "python": platform.python_version(),
        "command": "python bench/bench_render_batch.py " + " ".join(argv if argv is not None else sys.argv[1:]),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
