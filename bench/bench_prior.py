"""Co4DGen evaluation: quality of views rendered from one prior sample against the
ground truth of held-out scenes, and the time for 9 views from one sample against 9 independent samples.

    python bench/bench_prior.py --shards data/co4dgen_test --prior co4dgen-tiny

Held-out data: token shards of split="test" scenes written by ``model.train.tokenize_scenes`` (their clip
sidecars hold every camera's ground-truth video and cameras).  For each event the conditioning camera
is c = 0 and the anchor a = 1: the prior samples Z^a ~ p(. | V_c, P_c, P_a) once (seed 0) and the frozen
renderer draws every camera k of the event from it.  PSNR/SSIM (kornia) are reported for the anchor view
(k = a), the conditioning view (k = c) and the other cameras, next to three references rendered the
same way:

* ``encoded_anchor``: the tokenizer's own Z^a = E(V_a, P_a) (the record) -- the ceiling of the prior,
  which can at best reproduce this state;
* ``encoded_conditioning``: the tokenizer's Z^c = E(V_c, P_c) rendered at every camera -- what the
  tokenizer alone makes of the same single video (no prior);
* ``mean_tokens``: the prior's training-set mean tokens (no information about the event);
* ``flat_image``: every pixel of every view the conditioning video's mean colour -- the floor a user
  gets from the input alone.

``gap_closed``: how much of the floor-to-ceiling PSNR gap over all cameras the sample closes,
(co4dgen - flat_image) / (encoded_conditioning - flat_image), from the means and per event (mean +- SE):
with ``--anchor-camera`` equal to ``--cond-camera`` (the anchor ``source`` of ``vt4d generate``) the
ceiling is the tokenizer's own encode of the conditioning video.

Timing (one event, measured in this one run, best of ``--repeats``): sampling one state and rendering
9 trajectories around the anchor, against 9 independent (sample + render one view) runs; wall and
process CPU seconds (the machine is shared).  Results -> ``--results`` (JSON), picture -> ``--figure``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
NINE_VIEWS = ["source", "orbit:degrees=10", "orbit:degrees=-10", "orbit:degrees=20", "orbit:degrees=-20",
              "pan:degrees=15", "pan:degrees=-15", "dolly_in:metres=0.3", "tilt:degrees=10"]
METHODS = ("co4dgen", "encoded_anchor", "encoded_conditioning", "mean_tokens", "flat_image")


def quality(pred: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """PSNR (dB) and SSIM (11x11 Gaussian window) of (T, H, W, 3) uint8 videos: the training validation's
    measure (``model.diagnostics.video_quality``)."""
    from vt4dcodec.model.diagnostics import video_quality

    return video_quality(pred, truth)


def videos(frames: torch.Tensor) -> list[np.ndarray]:
    """(B, T, 3, H, W) in [0, 1] -> B uint8 videos (T, H, W, 3)."""
    return list((frames.permute(0, 1, 3, 4, 2).numpy() * 255.0).round().clip(0, 255).astype(np.uint8))


def _to_video(frames: torch.Tensor) -> np.ndarray:
    return videos(frames)[0]


def _tensor(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))[None]


def render(tokenizer: Any, z_s: torch.Tensor, z_d: torch.Tensor, K: np.ndarray, w2c: np.ndarray, steps: int,
           source: dict[str, np.ndarray]) -> np.ndarray:
    """``source``: the clip whose camera the tokens belong to (its K, w2c place them, where the model needs it)."""
    return _to_video(tokenizer.render(z_s, z_d, _tensor(K), _tensor(w2c), steps=steps, seed=0,
                                      source=(_tensor(source["K"]), _tensor(source["w2c"]))))


def condition(clip_c: dict[str, np.ndarray], K_a: np.ndarray, w2c_a: np.ndarray,
              tokens: tuple[torch.Tensor, torch.Tensor] | None = None) -> Any:
    from vt4dcodec.model.prior import PriorCondition

    frames = torch.from_numpy(clip_c["frames"]).permute(0, 3, 1, 2).float().div(255.0)[None]
    return PriorCondition(frames=frames, K_c=_tensor(clip_c["K"]), w2c_c=_tensor(clip_c["w2c"]), K_a=_tensor(K_a),
                          w2c_a=_tensor(w2c_a), z_s=None if tokens is None else tokens[0],
                          z_d=None if tokens is None else tokens[1])


def condition_tokens(prior: Any, tokenizer: Any, cam_c: dict[str, Any], mode: str
                     ) -> tuple[torch.Tensor, torch.Tensor] | None:
    """Z^c for a prior with ``cond_tokens`` (None otherwise): ``"encode"`` -- what ``vt4d generate`` computes, the
    tokenizer's encode of the conditioning video with estimated depth (``generate.conditioning_tokens``); ``"record"``
    -- the conditioning camera's token record (encoded with the synthetic scene's depth, as in training)."""
    if not prior.config.cond_tokens:
        return None
    if mode == "record":
        return cam_c["z_s"], cam_c["z_d"]
    from vt4dcodec.cameras import Trajectory
    from vt4dcodec.generate import conditioning_tokens

    clip, size = cam_c["clip"], tokenizer.config.image_size
    traj = Trajectory(K=clip["K"].astype(np.float64), w2c=clip["w2c"].astype(np.float64), width=size, height=size)
    z_s, z_d = conditioning_tokens(prior, clip["frames"], traj, tokenizer, runtime="torch")
    return torch.from_numpy(z_s), torch.from_numpy(z_d)


def load_models(prior_spec: str, tokenizer_spec: str | None) -> tuple[Any, Any, Any]:
    """(prior, tokenizer, tokenizer fingerprint): the tokenizer defaults to the prior's, and a tokenizer
    other than the one the prior was trained on is refused, unless its networks are exactly that one's (an
    entropy model added: the same tokens, as ``vt4d generate`` accepts it)."""
    from vt4dcodec.codec import load_model, model_fingerprint
    from vt4dcodec.generate import load_prior_model
    from vt4dcodec.model.prior import check_tokenizer

    prior = load_prior_model(prior_spec)
    tokenizer = load_model(tokenizer_spec or prior.tokenizer_fingerprint.model_id)
    fp = model_fingerprint(tokenizer)
    check_tokenizer(prior, fp, networks=getattr(tokenizer, "network_digests", None),
                    sources=getattr(tokenizer, "token_sources", ()))
    return prior, tokenizer, fp


def held_out_events(shards: str, count: int, cond_camera: int, fp: Any) -> dict[str, dict[int, dict[str, Any]]]:
    """The first ``count`` events of ``shards`` (:func:`load_events`); SystemExit when there are none or one
    was tokenized by another tokenizer than ``fp``."""
    events = dict(list(load_events(shards).items())[:count])
    if not events:
        raise SystemExit(f"no events in {shards}")
    for event, cams in events.items():
        if cams[cond_camera]["fingerprint"] != fp.to_dict():
            raise SystemExit(f"{event} was tokenized by another tokenizer than {fp.short()}")
    return events


def load_events(shards: str) -> dict[str, dict[int, dict[str, Any]]]:
    """event -> camera -> {"z_s", "z_d" (1, N, d) tensors, "clip": frames/K/w2c} from test shards."""
    from vt4dcodec.data.archive_dataset import ArchiveDataset
    from vt4dcodec.model.train.tokenize_scenes import ClipStore

    tokens = ArchiveDataset(shards)
    clips = ClipStore(tokens.shards)
    events: dict[str, dict[int, dict[str, Any]]] = {}
    for i in range(len(tokens)):
        sample = tokens[i]
        meta = sample["metadata"]["user"]["co4dgen"]
        events.setdefault(meta["event"], {})[int(meta["camera"])] = {
            "z_s": sample["static_tokens"][None].float(), "z_d": sample["dynamic_tokens"][None].float(),
            "clip": clips.load(sample["key"]), "fingerprint": sample["metadata"]["fingerprint"]}
    return dict(sorted(events.items()))


def parse_samplers(text: str) -> list[Any]:
    """"heun:16,euler:1,heun:16:2" -> [("heun", 16, 1.0), ("euler", 1, 1.0), ("heun", 16, 2.0)] (SamplerSetting:
    method, steps, classifier-free guidance, default 1); SystemExit naming --samplers on bad input."""
    from vt4dcodec.errors import ModelError
    from vt4dcodec.model.directories import parse_sampler

    try:
        return [parse_sampler(item) for item in text.split(",")]
    except ModelError as exc:
        raise SystemExit(f"--samplers takes METHOD:STEPS[:GUIDANCE] items (euler or heun, steps >= 1, guidance "
                         f"in [0, 20]): {exc}") from None


def sampler_name(method: str, steps: int, guidance: float) -> str:
    from vt4dcodec.model.directories import SamplerSetting

    return f"co4dgen[{SamplerSetting(method, steps, guidance)}]"


def evaluate(tokenizer: Any, prior: Any, events: dict, cond_cam: int, anchor_cam: int, prior_steps: int,
             render_steps: int, seed: int, samplers: list[tuple[str, int, float]] | None = None,
             tokens_from: str = "encode") -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """One sample per event with heun:``prior_steps`` ("co4dgen"), and with each extra sampler setting
    ("co4dgen[euler:1]", ...) from the same seed, every one rendered at every camera beside the references."""
    rows: list[dict[str, Any]] = []
    figure_rows: list[dict[str, Any]] = []
    mean_s = prior.static_mean.expand(1, prior.config.n_static, -1)
    mean_d = prior.dynamic_mean.expand(1, prior.config.n_dynamic, -1)
    for event, cams in events.items():
        clip_c, clip_a = cams[cond_cam]["clip"], cams[anchor_cam]["clip"]
        cond = condition(clip_c, clip_a["K"], clip_a["w2c"], condition_tokens(prior, tokenizer, cams[cond_cam],
                                                                               tokens_from))
        z_s, z_d = prior.sample(cond, steps=prior_steps, seed=seed)
        extra = {sampler_name(m, n, g): (*prior.sample(cond, steps=n, seed=seed, method=m, guidance=g), clip_a)
                 for m, n, g in samplers or []}
        states = {"co4dgen": (z_s, z_d, clip_a), **extra, "encoded_anchor": (cams[anchor_cam]["z_s"], cams[anchor_cam]["z_d"], clip_a),
                  "encoded_conditioning": (cams[cond_cam]["z_s"], cams[cond_cam]["z_d"], clip_c),
                  "mean_tokens": (mean_s, mean_d, clip_a)}
        fig = {"event": event, "cond": clip_c["frames"], "truth": {}, "pred": {}}
        flat = clip_c["frames"].reshape(-1, 3).mean(0).round().astype(np.uint8)
        for k, cam in sorted(cams.items()):
            kind = "anchor" if k == anchor_cam else "conditioning" if k == cond_cam else "other"
            truth = cam["clip"]["frames"]
            fig["truth"][k] = truth
            for method in (*METHODS, *extra):
                if method == "flat_image":
                    pred = np.broadcast_to(flat, truth.shape)
                else:
                    s, d, src = states[method]
                    pred = render(tokenizer, s, d, cam["clip"]["K"], cam["clip"]["w2c"], render_steps, src)
                psnr, ssim = quality(pred, truth)
                rows.append({"event": event, "camera": k, "view": kind, "method": method, "psnr": psnr, "ssim": ssim})
                if method == "co4dgen":
                    fig["pred"][k] = pred
        figure_rows.append(fig)
        print(f"  {event}: " + ", ".join(f"{r['method']}@{r['view']}{r['camera']} {r['psnr']:.1f}"
                                        for r in rows if r["event"] == event and r["method"] == "co4dgen"),
              file=sys.stderr)
    summary: dict[str, Any] = {}
    for method in (*METHODS, *(sampler_name(*x) for x in samplers or [])):
        for view in ("anchor", "conditioning", "other", "all"):
            sel = [r for r in rows if r["method"] == method and (view == "all" or r["view"] == view)]
            if sel:
                summary.setdefault(method, {})[view] = {
                    "psnr_db": round(float(np.mean([r["psnr"] for r in sel])), 3),
                    "ssim": round(float(np.mean([r["ssim"] for r in sel])), 4), "videos": len(sel)}
    closed = {"co4dgen": gap_closed(rows)}
    closed.update({sampler_name(*x): gap_closed(rows, sampler_name(*x)) for x in samplers or []})
    return {"summary": summary, "rows": rows, "gap_closed": closed}, figure_rows


def gap_closed(rows: list[dict[str, Any]], method: str = "co4dgen") -> dict[str, Any]:
    """Share of the flat-image-to-encode PSNR gap (all cameras) that ``method``'s sample closes: of the
    means, and per event (mean, standard error, events)."""
    def event_mean(method: str, event: str) -> float:
        return float(np.mean([r["psnr"] for r in rows if r["method"] == method and r["event"] == event]))

    events = sorted({r["event"] for r in rows})
    per_event = []
    for e in events:
        gap = event_mean("encoded_conditioning", e) - event_mean("flat_image", e)
        if gap > 0.25:  # an event where the encode barely beats a flat image says nothing about the gap
            per_event.append((event_mean(method, e) - event_mean("flat_image", e)) / gap)
    means = {m: float(np.mean([event_mean(m, e) for e in events])) for m in (method, "encoded_conditioning",
                                                                              "flat_image")}
    of_means = (means[method] - means["flat_image"]) / (means["encoded_conditioning"] - means["flat_image"])
    se = float(np.std(per_event, ddof=1) / np.sqrt(len(per_event))) if len(per_event) > 1 else None
    return {"of_means": round(of_means, 4), "per_event_mean": round(float(np.mean(per_event)), 4) if per_event
            else None, "per_event_se": None if se is None else round(se, 4), "events": len(per_event),
            "events_skipped": len(events) - len(per_event)}


def timing(tokenizer: Any, prior: Any, event: dict, cond_cam: int, anchor_cam: int, prior_steps: int,
           render_steps: int, repeats: int) -> dict[str, Any]:
    """9 views from one sample vs 9 independent samples, interleaved, best of ``repeats``; a prior with
    ``cond_tokens`` pays the tokenizer's encode of the conditioning video in every sample (as ``vt4d generate``)."""
    from vt4dcodec.codec import resolve_trajectory

    clip_c, clip_a = event[cond_cam]["clip"], event[anchor_cam]["clip"]
    cfg = tokenizer.config
    from vt4dcodec.cameras import Trajectory

    ref = Trajectory(K=clip_a["K"].astype(np.float64), w2c=clip_a["w2c"].astype(np.float64), width=cfg.image_size,
                     height=cfg.image_size)
    views = [resolve_trajectory(v, ref, size=cfg.image_size, max_frames=cfg.frames) for v in NINE_VIEWS]
    def cond() -> Any:
        return condition(clip_c, clip_a["K"], clip_a["w2c"], condition_tokens(prior, tokenizer, event[cond_cam], "encode"))

    def one_sample() -> None:
        z_s, z_d = prior.sample(cond(), steps=prior_steps, seed=0)
        for v in views:
            render(tokenizer, z_s, z_d, v.K, v.w2c, render_steps, clip_a)

    def independent() -> None:
        for i, v in enumerate(views):
            z_s, z_d = prior.sample(cond(), steps=prior_steps, seed=i)
            render(tokenizer, z_s, z_d, v.K, v.w2c, render_steps, clip_a)

    def sample_only() -> None:
        prior.sample(cond(), steps=prior_steps, seed=0)

    results: dict[str, dict[str, list[float]]] = {n: {"wall": [], "cpu": []} for n in ("one", "nine", "sample")}
    for _ in range(repeats):
        for name, fn in (("one", one_sample), ("nine", independent), ("sample", sample_only)):
            w0, c0 = time.perf_counter(), time.process_time()
            fn()
            results[name]["wall"].append(time.perf_counter() - w0)
            results[name]["cpu"].append(time.process_time() - c0)
    best = {n: {k: min(v) for k, v in r.items()} for n, r in results.items()}
    render_one = (best["one"]["cpu"] - best["sample"]["cpu"]) / len(views)
    return {
        "views": NINE_VIEWS, "repeats": repeats, "prior_steps": prior_steps, "render_steps": render_steps,
        "one_sample_nine_views_s": {k: round(v, 3) for k, v in best["one"].items()},
        "nine_independent_samples_s": {k: round(v, 3) for k, v in best["nine"].items()},
        "one_prior_sample_s": {k: round(v, 3) for k, v in best["sample"].items()},
        "render_one_view_cpu_s": round(render_one, 3),
        "speedup_cpu": round(best["nine"]["cpu"] / best["one"]["cpu"], 3),
        "speedup_wall": round(best["nine"]["wall"] / best["one"]["wall"], 3),
        "all_runs": results,
    }


def draw_figure(rows: list[dict[str, Any]], path: Path, cond_cam: int, anchor_cam: int, count: int = 3) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = rows[:count]
    cams = sorted(rows[0]["truth"])
    cols = [("V_c (input)", None, None), (f"cam{cond_cam} sample", cond_cam, "pred")] + \
        [(f"cam{k} {'GT'}", k, "truth") for k in cams if k != cond_cam] + \
        [(f"cam{k} sample", k, "pred") for k in cams if k != cond_cam]
    fig, axes = plt.subplots(len(rows), len(cols), figsize=(1.25 * len(cols), 1.35 * len(rows)), dpi=90,
                             squeeze=False)
    for r, row in enumerate(rows):
        t = row["cond"].shape[0] // 2
        for c, (title, k, which) in enumerate(cols):
            image = row["cond"][t] if k is None else row[which][k][t]
            axes[r, c].imshow(image)
            axes[r, c].set_axis_off()
            if r == 0:
                label = title + (" (anchor)" if k == anchor_cam else "")
                axes[r, c].set_title(label, fontsize=6)
    fig.suptitle(f"Co4DGen: one sample per row (conditioning cam{cond_cam}, anchor cam{anchor_cam}), middle frame",
                 fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--shards", required=True, help="test-split token shards (tokenize_scenes --split test)")
    parser.add_argument("--prior", default="co4dgen-tiny", help="prior id or directory")
    parser.add_argument("--tokenizer", default=None, help="tokenizer id or directory (default: the prior's)")
    parser.add_argument("--events", type=int, default=8, help="held-out events to evaluate")
    parser.add_argument("--cond-camera", type=int, default=0)
    parser.add_argument("--anchor-camera", type=int, default=1)
    parser.add_argument("--prior-steps", type=int, default=16, help="Heun steps of the headline sample")
    parser.add_argument("--samplers", default="", metavar="METHOD:STEPS,...",
                        help="further sampler settings to score from the same seed, e.g. euler:1,euler:4,heun:8,heun:16:2 "
                             "(METHOD:STEPS[:GUIDANCE])")
    parser.add_argument("--cond-tokens", choices=("encode", "record"), default="encode",
                        help="for a prior conditioned on the tokenizer's tokens of the video: compute them as vt4d "
                             "generate does (encode, default) or take the conditioning camera's token record")
    parser.add_argument("--render-steps", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=2, help="timing repeats (best is kept)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--results", type=Path, default=ROOT / "bench" / "results" / "prior.json")
    parser.add_argument("--figure", type=Path, default=ROOT / "docs" / "figures" / "co4dgen.png")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    prior, tokenizer, fp = load_models(args.prior, args.tokenizer)
    events = held_out_events(args.shards, args.events, args.cond_camera, fp)
    t0 = time.perf_counter()
    quality_result, figure_rows = evaluate(tokenizer, prior, events, args.cond_camera, args.anchor_camera,
                                           args.prior_steps, args.render_steps, args.seed,
                                           parse_samplers(args.samplers) if args.samplers else None,
                                           args.cond_tokens)
    eval_s = time.perf_counter() - t0
    timing_result = timing(tokenizer, prior, next(iter(events.values())), args.cond_camera, args.anchor_camera,
                           args.prior_steps, args.render_steps, args.repeats)
    result = {
        "command": "python bench/bench_prior.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "tokenizer": fp.to_dict(), "prior": {"model_id": prior.model_id, "model_version": prior.model_version,
                                             "config": prior.config.to_dict()},
        "events": list(events), "cond_camera": args.cond_camera, "anchor_camera": args.anchor_camera,
        "prior_steps": args.prior_steps, "render_steps": args.render_steps, "seed": args.seed,
        "cond_tokens": args.cond_tokens if prior.config.cond_tokens else None,
        "threads": args.threads, "evaluation_seconds": round(eval_s, 1),
        "quality": quality_result["summary"], "gap_closed": quality_result["gap_closed"],
        "per_video": quality_result["rows"], "timing": timing_result,
    }
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text(json.dumps(result, indent=1) + "\n")
    draw_figure(figure_rows, args.figure, args.cond_camera, args.anchor_camera)
    for method, views in result["quality"].items():
        print(f"{method:22s} " + "  ".join(f"{v}: {m['psnr_db']:.2f} dB / {m['ssim']:.3f}" for v, m in views.items()))
    for method, g in result["gap_closed"].items():
        print(f"{method}: gap closed (flat image -> encode, all cameras) {100 * g['of_means']:.1f} % of the means; "
              f"per event {100 * (g['per_event_mean'] or float('nan')):.1f} +- "
              f"{100 * (g['per_event_se'] or float('nan')):.1f} % ({g['events']} events)")
    t = timing_result
    print(f"9 views from 1 sample: {t['one_sample_nine_views_s']['cpu']:.2f} s CPU; 9 independent samples: "
          f"{t['nine_independent_samples_s']['cpu']:.2f} s CPU -> {t['speedup_cpu']:.2f}x "
          f"(wall {t['speedup_wall']:.2f}x); results -> {args.results}, figure -> {args.figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
