"""Table 2 at this scale: Co4DGen (one token-state sample, every view rendered from it) against the dense
per-view baseline (one latent video-diffusion run per view), quality and wall time for 9 views, in one run.

    python bench/bench_table2.py --shards data/co4dgen-2.0.0-test64 --dense checkpoints/dense-tiny-2k/dense \
        --prior co4dgen-tiny --events 16 --prior-steps 16,4,1 --dense-steps 1,2,4,8,16,32 --threads 1 \
        --results docs/results/table2.json --figure docs/figures/table2.png

Held-out (split="test") events from ``model.train.tokenize_scenes`` shards: conditioning camera c = 0, the
9 target views are the event's other cameras 1..9, whose ground truth the clip sidecars hold.

* **co4dgen@P**: the prior samples Z^a ~ p(. | V_c, P_c, P_a) once (anchor ``--anchor-camera``, default 1; P a
  number of Heun steps or a sampler setting such as ``euler:2``, seed 0; the first of ``--prior-steps`` is the
  headline setting, e.g. the one the prior records for ``vt4d generate``); the tokenizer's
  renderer draws all 9 cameras from that one state in one batched call (``--render-steps``, the
  tokenizer's recorded decode steps by default).
* **dense@S**: the dense baseline generates each target camera's latent video from (V_c, P_c, P_k) with
  S Euler steps (seed 0), decoded by the same frozen autoencoder; 9 sampling runs.  Batched (the 9 runs
  as one batch) and sequential (one run after another) are both timed.
* **encoded_anchor**: the tokenizer's own Z^a = E(V_a, P_a) rendered at every camera: Co4DGen's ceiling
  (what a perfect prior sample would give), for reference.

Quality: PSNR / SSIM (kornia, 11x11) of each generated video against its camera's ground truth; per
event the mean over the 9 cameras; mean +- standard error over events, and the paired per-event
difference headline - dense@S with its standard error.  ``equal_quality`` names, per metric, the fastest
dense setting whose mean is at least the headline's, and the headline's speed-up over it.  Timing (first ``--timing-events`` events, best
of ``--repeats``, wall and process CPU, one thread): each method end to end for 9 views (condition
encoding, sampling, rendering/decoding to pixels).  Sequence lengths per run come from the configs.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from bench_prior import condition_tokens, held_out_events, load_models, quality, videos as _videos  # noqa: E402


def _tensor(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))


def conditions(cams: dict[int, dict[str, Any]], cond_cam: int, targets: list[int]) -> Any:
    """One PriorCondition per target camera: (V_c, P_c) of ``cond_cam`` and that camera's trajectory."""
    from vt4dcodec.model.prior import PriorCondition

    clip = cams[cond_cam]["clip"]
    n = len(targets)
    frames = torch.from_numpy(clip["frames"]).permute(0, 3, 1, 2).float().div(255.0)[None].expand(n, -1, -1, -1, -1)
    return PriorCondition(frames=frames.contiguous(), K_c=_tensor(clip["K"])[None].expand(n, -1, -1, -1).contiguous(),
                          w2c_c=_tensor(clip["w2c"])[None].expand(n, -1, -1, -1).contiguous(),
                          K_a=torch.stack([_tensor(cams[k]["clip"]["K"]) for k in targets]),
                          w2c_a=torch.stack([_tensor(cams[k]["clip"]["w2c"]) for k in targets]))


class Labelled:
    """A ``--prior-steps`` entry: a number of Heun steps (named by the number, ``co4dgen@16``) or a sampler
    setting METHOD:STEPS[:GUIDANCE] (``co4dgen@euler:2``)."""

    def __init__(self, text: str) -> None:
        from vt4dcodec.model.directories import SamplerSetting, parse_sampler

        self.label = text
        setting = SamplerSetting("heun", int(text)) if text.isdigit() else parse_sampler(text)
        self.method, self.steps, self.guidance = setting.method, setting.steps, setting.guidance

    def __str__(self) -> str:
        return self.label


def co4dgen_views(tokenizer: Any, prior: Any, cams: dict, cond_cam: int, anchor_cam: int, targets: list[int],
                  setting: Any, render_steps: int, seed: int = 0) -> list[np.ndarray]:
    """Sample Z^a once, render every target camera from it in one batched call (a prior conditioned on the
    tokenizer's tokens of the video encodes it first, as ``vt4d generate`` does: inside the timed call)."""
    cond = conditions(cams, cond_cam, [anchor_cam])
    tokens = condition_tokens(prior, tokenizer, cams[cond_cam], "encode")
    if tokens is not None:
        cond.z_s, cond.z_d = tokens
    z_s, z_d = prior.sample(cond, steps=setting.steps, seed=seed, method=setting.method, guidance=setting.guidance)
    return render_state(tokenizer, z_s, z_d, cams, anchor_cam, targets, render_steps)


def render_state(tokenizer: Any, z_s: torch.Tensor, z_d: torch.Tensor, cams: dict, anchor_cam: int,
                 targets: list[int], render_steps: int) -> list[np.ndarray]:
    n = len(targets)
    K = torch.stack([_tensor(cams[k]["clip"]["K"]) for k in targets])
    w2c = torch.stack([_tensor(cams[k]["clip"]["w2c"]) for k in targets])
    anchor = cams[anchor_cam]["clip"]
    source = (_tensor(anchor["K"])[None].expand(n, -1, -1, -1).contiguous(),
              _tensor(anchor["w2c"])[None].expand(n, -1, -1, -1).contiguous())
    frames = tokenizer.render(z_s.expand(n, -1, -1), z_d.expand(n, -1, -1), K, w2c, steps=render_steps, seed=0,
                              source=source)
    return _videos(frames)


def dense_views(dense: Any, cams: dict, cond_cam: int, targets: list[int], steps: int, batched: bool = True,
                seed: int = 0) -> list[np.ndarray]:
    """One sampling run per target camera (as one batch, or one after another)."""
    if batched:
        return _videos(dense.generate(conditions(cams, cond_cam, targets), steps=steps, seed=seed))
    out: list[np.ndarray] = []
    for k in targets:
        out += _videos(dense.generate(conditions(cams, cond_cam, [k]), steps=steps, seed=seed))
    return out


def mean_se(values: list[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=np.float64)
    se = float(a.std(ddof=1) / np.sqrt(len(a))) if len(a) > 1 else float("nan")
    return {"mean": round(float(a.mean()), 3), "se": round(se, 3), "n": int(len(a))}


def timed(fn: Callable[[], Any], repeats: int) -> dict[str, float]:
    walls, cpus = [], []
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return {"wall_s": round(min(walls), 3), "cpu_s": round(min(cpus), 3)}


def draw_figure(example: dict[str, Any], path: Path, methods: list[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    targets = example["targets"]
    rows = ["truth"] + methods
    fig, axes = plt.subplots(len(rows), len(targets) + 1, figsize=(1.2 * (len(targets) + 1), 1.3 * len(rows)),
                             dpi=90, squeeze=False)
    t = example["cond"].shape[0] // 2
    for r, name in enumerate(rows):
        axes[r, 0].imshow(example["cond"][t] if r == 0 else np.ones_like(example["cond"][t]) * 255)
        axes[r, 0].set_axis_off()
        axes[r, 0].set_title("V_c (input)" if r == 0 else "", fontsize=6)
        axes[r, 0].text(0, 0.5, name if r else "", transform=axes[r, 0].transAxes, fontsize=6, va="center")
        for c, k in enumerate(targets):
            axes[r, c + 1].imshow(example[name][c][t])
            axes[r, c + 1].set_axis_off()
            if r == 0:
                axes[r, c + 1].set_title(f"cam{k}", fontsize=6)
    fig.suptitle(f"{example['event']}: 9 views from one conditioning video (middle frame); rows: ground truth, "
                 + ", ".join(methods), fontsize=6)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--shards", required=True, help="test-split token shards (tokenize_scenes --split test)")
    parser.add_argument("--dense", required=True, help="dense-baseline directory (dense.json)")
    parser.add_argument("--prior", default="co4dgen-tiny", help="prior id or directory")
    parser.add_argument("--tokenizer", default=None, help="tokenizer id or directory (default: the prior's)")
    parser.add_argument("--events", type=int, default=16)
    parser.add_argument("--cond-camera", type=int, default=0)
    parser.add_argument("--anchor-camera", type=int, default=1)
    parser.add_argument("--views", type=int, default=9, help="target cameras per event (the first after cond)")
    parser.add_argument("--prior-steps", default="16,4,1", help="comma-separated Heun step counts or sampler settings "
                        "(METHOD:STEPS[:GUIDANCE], e.g. euler:2); the first is "
                        "the headline setting")
    parser.add_argument("--render-steps", type=int, default=None, help="default: the tokenizer's decode steps")
    parser.add_argument("--dense-steps", default="4,8,16,32", help="comma-separated Euler step counts")
    parser.add_argument("--timing-events", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--results", type=Path, default=ROOT / "bench" / "results" / "table2.json")
    parser.add_argument("--figure", type=Path, default=ROOT / "docs" / "figures" / "table2.png")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    from vt4dcodec.model.weights_io import load_dense

    prior, tokenizer, fp = load_models(args.prior, args.tokenizer)
    dense = load_dense(args.dense)
    if dense.tokenizer_fingerprint.weights_sha256 != fp.weights_sha256:
        raise SystemExit(f"the dense baseline holds the autoencoder of {dense.tokenizer_fingerprint.short()}, "
                         f"not of {fp.short()}: both must decode through the same latent space")
    render_steps = args.render_steps or tokenizer.decode_steps
    dense_steps = [int(s) for s in args.dense_steps.split(",") if s]
    prior_steps = [Labelled(s) for s in args.prior_steps.split(",") if s]  # "16" (Heun steps) or "euler:2"
    headline = f"co4dgen@{prior_steps[0]}"
    events = held_out_events(args.shards, args.events, args.cond_camera, fp)
    methods = [*(f"co4dgen@{p}" for p in prior_steps), *(f"dense@{s}" for s in dense_steps), "encoded_anchor"]
    per_event: dict[str, dict[str, list[float]]] = {m: {"psnr": [], "ssim": []} for m in methods}
    example: dict[str, Any] = {}
    t0 = time.perf_counter()
    for e, (event, cams) in enumerate(events.items()):
        targets = [k for k in sorted(cams) if k != args.cond_camera][: args.views]
        videos = {f"co4dgen@{p}": co4dgen_views(tokenizer, prior, cams, args.cond_camera, args.anchor_camera,
                                                targets, p, render_steps) for p in prior_steps}
        videos |= {"encoded_anchor": render_state(tokenizer, cams[args.anchor_camera]["z_s"],
                                                 cams[args.anchor_camera]["z_d"], cams, args.anchor_camera, targets,
                                                 render_steps)}
        for s in dense_steps:
            videos[f"dense@{s}"] = dense_views(dense, cams, args.cond_camera, targets, s)
        for m in methods:
            scores = [quality(v, cams[k]["clip"]["frames"]) for v, k in zip(videos[m], targets)]
            per_event[m]["psnr"].append(float(np.mean([p for p, _ in scores])))
            per_event[m]["ssim"].append(float(np.mean([s for _, s in scores])))
        if e == 0:
            example = {"event": event, "targets": targets, "cond": cams[args.cond_camera]["clip"]["frames"],
                       "truth": [cams[k]["clip"]["frames"] for k in targets], **videos}
        print(f"  {event}: " + ", ".join(f"{m} {per_event[m]['psnr'][-1]:.2f}" for m in methods), file=sys.stderr)
    quality_s = time.perf_counter() - t0

    summary = {m: {"psnr_db": mean_se(v["psnr"]), "ssim": mean_se(v["ssim"])} for m, v in per_event.items()}
    paired = {f"{headline} - dense@{s}": {
        "psnr_db": mean_se(list(np.subtract(per_event[headline]["psnr"], per_event[f"dense@{s}"]["psnr"]))),
        "ssim": mean_se(list(np.subtract(per_event[headline]["ssim"], per_event[f"dense@{s}"]["ssim"])))}
        for s in dense_steps}

    timing: dict[str, Any] = {}
    for event, cams in list(events.items())[: args.timing_events]:
        targets = [k for k in sorted(cams) if k != args.cond_camera][: args.views]
        row: dict[str, Any] = {f"co4dgen@{p}": timed(lambda: co4dgen_views(
            tokenizer, prior, cams, args.cond_camera, args.anchor_camera, targets, p, render_steps), args.repeats)
            for p in prior_steps}
        for s in dense_steps:
            row[f"dense@{s} batched"] = timed(lambda: dense_views(dense, cams, args.cond_camera, targets, s), args.repeats)
            row[f"dense@{s} sequential"] = timed(
                lambda: dense_views(dense, cams, args.cond_camera, targets, s, batched=False), args.repeats)
        timing[event] = row
    mean_time = {name: {k: round(float(np.mean([timing[e][name][k] for e in timing])), 3)
                        for k in ("wall_s", "cpu_s")} for name in next(iter(timing.values()))}
    speedup = {name: {k: round(v[k] / mean_time[headline][k], 2) for k in ("wall_s", "cpu_s")}
               for name, v in mean_time.items() if name != headline}
    equal_quality: dict[str, Any] = {}
    for metric in ("psnr_db", "ssim"):
        matching = [s for s in dense_steps if summary[f"dense@{s}"][metric]["mean"] >= summary[headline][metric]["mean"]]
        fastest = min(matching, key=lambda s: mean_time[f"dense@{s} batched"]["wall_s"]) if matching else None
        equal_quality[metric] = {"dense": None if fastest is None else f"dense@{fastest}",
                                 "speedup_wall": None if fastest is None else speedup[f"dense@{fastest} batched"]["wall_s"]}

    tcfg, pcfg, dcfg = tokenizer.config, prior.config, dense.config
    render_patch = getattr(tcfg, "renderer_patch", tcfg.patch_size)
    latent = tcfg.latent_size
    cond_tokens = pcfg.frames * ((pcfg.image_size // pcfg.cond_patch) ** 2 + pcfg.anchor_grid ** 2)
    table = {
        "co4dgen": {"sequence_per_run": pcfg.n_static + pcfg.n_dynamic, "context_tokens": cond_tokens,
                    "prior_runs": 1, "prior_samplers": [f"{p.method}:{p.steps}" for p in prior_steps],
                    "render_runs": 1, "render_batch": args.views, "render_steps": render_steps,
                    "render_sequence_per_view": tcfg.frames * (latent // render_patch) ** 2,
                    "trainable_parameters": sum(p.numel() for p in prior.parameters())
                    + sum(p.numel() for p in tokenizer.renderer.parameters())},
        "dense": {"sequence_per_run": dcfg.frames * (dcfg.latent_size // dcfg.patch_size) ** 2,
                  "context_tokens": dcfg.frames * ((dcfg.image_size // dcfg.cond_patch) ** 2 + dcfg.anchor_grid ** 2),
                  "sampling_runs": args.views, "steps": dense_steps, "sampler": "euler",
                  "trainable_parameters": dense.trainable_parameters()},
    }
    result = {
        "command": "python bench/bench_table2.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "tokenizer": fp.to_dict(), "prior": {"model_id": prior.model_id, "model_version": prior.model_version},
        "dense": {"model_id": dense.model_id, "model_version": dense.model_version,
                  "config": dense.config.to_dict()},
        "events": list(events), "cond_camera": args.cond_camera, "anchor_camera": args.anchor_camera,
        "views": len(example["targets"]), "threads": args.threads, "quality_seconds": round(quality_s, 1),
        "headline": headline, "table": table, "quality": summary, "paired": paired, "equal_quality": equal_quality, "timing_mean": mean_time, "speedup": speedup,
        "timing_per_event": timing, "per_event": per_event,
    }
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text(json.dumps(result, indent=1) + "\n")
    draw_figure(example, args.figure, methods)
    for m in methods:
        q = summary[m]
        t = mean_time.get(m) or mean_time.get(f"{m} batched")
        print(f"{m:16s} PSNR {q['psnr_db']['mean']:.2f} +- {q['psnr_db']['se']:.2f} dB  SSIM {q['ssim']['mean']:.3f}"
              + (f"  9 views {t['wall_s']:.2f} s wall" if t else ""))
    for name, v in speedup.items():
        print(f"{headline} is {v['wall_s']:.2f}x faster than {name} (wall; CPU {v['cpu_s']:.2f}x)")
    for metric, v in equal_quality.items():
        print(f"equal {metric}: fastest dense setting at least as good: {v['dense']} -> {headline} {v['speedup_wall']}x")
    for name, v in paired.items():
        print(f"{name}: {v['psnr_db']['mean']:+.2f} +- {v['psnr_db']['se']:.2f} dB")
    print(f"results -> {args.results}, figure -> {args.figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
