"""Train the Co4DGen prior from token archives.

    python -m vt4dcodec.model.train.tokenize_scenes --tokenizer vt4d-tiny --out data/co4dgen --scenes 512
    python -m vt4dcodec.model.train.prior --shards data/co4dgen --out runs/co4dgen --steps 3000

The data path is the one users take at scale: token shards written by
:mod:`model.train.tokenize_scenes` are read through :class:`vt4dcodec.data.archive_dataset.ArchiveDataset`
(anchor tokens Z^a and cameras P_a) and the conditioning clips (V_c, P_c) through their sidecars.
One sample is an ordered pair (anchor record a, conditioning clip c) of the same event; the dataset
enumerates every such pair, with c != a as in the paper (``--anchors distinct``) or also the pairs whose
anchor is the conditioning camera itself (``--anchors all``, the default: ``vt4d generate``'s default
anchor is the source camera, so the prior is trained on that case too).  Every record must carry the same
tokenizer fingerprint, which the finished prior records (``save_prior``), so it is only ever used with
that tokenizer.

The loop, checkpoints, log and loss plot are :mod:`model.train.common`'s.  With ``--ema-decay`` the run
keeps an exponential moving average of the weights, which validation samples with and the finished prior
is saved from.  With ``--val-shards`` (test-split shards by the same tokenizer) it validates every
``--val-every`` steps (:class:`SampleValidation`): one sample per held-out event from camera 0's video,
anchored at camera 0, rendered at every camera of the event, scored against the ground truth between the
floor (a flat image of the video's mean colour) and the ceiling (the tokenizer's own encode of the video);
the curve is ``<out>/val.jsonl`` and ``<out>/val.png``.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import Dataset

from vt4dcodec.data.archive_dataset import ArchiveDataset
from vt4dcodec.errors import ModelError
from vt4dcodec.format import ModelFingerprint

from ..configs import PriorConfig, get_prior_config
from ..directories import parse_sampler
from ..prior import Co4DGen, PriorCondition
from ..weights_io import save_prior
from .common import (JsonlLog, WeightAverage, cleanup_distributed, cycle, make_loader, parse_overrides, seed_everything,
                     setup_distributed, shard_model_arguments, train_loop)
from .tokenize_scenes import ClipStore

__all__ = ["PriorPairDataset", "PriorBatch", "collate_prior", "token_statistics", "model_card", "SampleValidation",
           "ANCHORS", "main"]

ANCHORS = ("all", "distinct")


@dataclass
class PriorBatch:
    """Anchor tokens Z^a = (z_s (B, N_s, d), z_d (B, N_d, d)) and the condition (V_c, P_c, P_a)."""

    z_s: torch.Tensor
    z_d: torch.Tensor
    cond: PriorCondition
    keys: list[str]


class PriorPairDataset(Dataset):
    """All ordered (anchor record, conditioning clip of the same event) pairs of some token shards: the
    clips of the other cameras (``anchors="distinct"``, the paper's pairs) or of every camera including
    the anchor's own (``anchors="all"``; that pair ``source_repeats`` times, so a share of the batches is the
    ``anchor="source"`` case ``vt4d generate`` defaults to).  Item: dict with ``z_s``, ``z_d``, ``K_a``, ``w2c_a`` (tensors of
    the anchor record), ``frames`` (T, H, W, 3) uint8, ``K_c``, ``w2c_c`` of the conditioning clip, with
    ``condition_tokens`` (for a prior with ``cond_tokens``) ``zc_s``, ``zc_d`` the conditioning camera's own token
    record (Z^c, a second record read per item), and the two keys."""

    def __init__(self, shards: Any, anchors: str = "distinct", source_repeats: int = 1,
                 condition_tokens: bool = False) -> None:
        self.condition_tokens = condition_tokens
        if anchors not in ANCHORS:
            raise ModelError(f"anchors must be one of {ANCHORS}, got {anchors!r}")
        if not isinstance(source_repeats, int) or source_repeats < 1 or (source_repeats > 1 and anchors != "all"):
            raise ModelError(f"source_repeats must be a positive integer, and above 1 only when every anchor's own "
                             f"clip is among the pairs (anchors all); got {source_repeats!r}")
        self.tokens = ArchiveDataset(shards)
        if len(self.tokens) == 0:
            raise ModelError(f"no token records in {shards}")
        self.clips = ClipStore(self.tokens.shards)
        self.index = {key: i for i, (_, key) in enumerate(self.tokens.keys)}
        self.pairs: list[tuple[int, str]] = []
        for i, (_, key) in enumerate(self.tokens.keys):
            event, _, cam = key.rpartition("/cam")
            others = [k for k in self._event_clips(event) if k != key]
            if not event or not others:
                raise ModelError(f"token record {key!r} has no conditioning clip of another camera")
            if anchors == "all":
                if key not in self.clips:
                    raise ModelError(f"token record {key!r} has no clip of its own camera")
                others = sorted(others + [key] * source_repeats)
            self.pairs.extend((i, k) for k in others)

    def _event_clips(self, event: str) -> list[str]:
        cache = getattr(self, "_by_event", None)
        if cache is None:
            cache = self._by_event = {}
            for k in self.clips.keys:
                cache.setdefault(k.rpartition("/cam")[0], []).append(k)
        return sorted(cache.get(event, []))

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, index: int) -> dict[str, Any]:
        i, clip_key = self.pairs[index]
        anchor = self.tokens[i]
        clip = self.clips.load(clip_key)
        if clip["frames"].shape[0] != anchor["K"].shape[0]:
            raise ModelError(f"clip {clip_key} and record {anchor['key']} differ in frame count")
        item = {"z_s": anchor["static_tokens"].float(), "z_d": anchor["dynamic_tokens"].float(),
                "K_a": anchor["K"], "w2c_a": anchor["w2c"], "frames": clip["frames"], "K_c": clip["K"],
                "w2c_c": clip["w2c"], "anchor_key": anchor["key"], "clip_key": clip_key,
                "fingerprint": anchor["metadata"]["fingerprint"]}
        if self.condition_tokens:
            own = self.index.get(clip_key)  # Z^c, the conditioning camera's own record
            if own is None:
                raise ModelError(f"clip {clip_key} has no token record of its own")
            record = anchor if own == i else self.tokens[own]
            item.update(zc_s=record["static_tokens"].float(), zc_d=record["dynamic_tokens"].float())
        return item


def collate_prior(items: list[dict[str, Any]]) -> PriorBatch:
    """Stack dataset items into a :class:`PriorBatch` (frames to float [0, 1], channels first)."""
    frames = torch.from_numpy(np.stack([it["frames"] for it in items])).permute(0, 1, 4, 2, 3).float().div_(255.0)
    cond = PriorCondition(frames=frames,
                          K_c=torch.from_numpy(np.stack([it["K_c"] for it in items])).float(),
                          w2c_c=torch.from_numpy(np.stack([it["w2c_c"] for it in items])).float(),
                          K_a=torch.stack([it["K_a"] for it in items]).float(),
                          w2c_a=torch.stack([it["w2c_a"] for it in items]).float(),
                          z_s=torch.stack([it["zc_s"] for it in items]) if "zc_s" in items[0] else None,
                          z_d=torch.stack([it["zc_d"] for it in items]) if "zc_d" in items[0] else None)
    return PriorBatch(z_s=torch.stack([it["z_s"] for it in items]), z_d=torch.stack([it["z_d"] for it in items]),
                      cond=cond, keys=[it["anchor_key"] for it in items])


def token_statistics(dataset: PriorPairDataset) -> tuple[torch.Tensor, torch.Tensor, dict[str, Any]]:
    """Every anchor record's tokens (M, N_s, d), (M, N_d, d) and the one tokenizer fingerprint they
    share (dict); a second fingerprint among the records is an error."""
    z_s, z_d, fingerprint = [], [], None
    for i in range(len(dataset.tokens)):
        sample = dataset.tokens[i]
        fp = sample["metadata"]["fingerprint"]
        if fingerprint is None:
            fingerprint = fp
        elif fp != fingerprint:
            raise ModelError(f"record {sample['key']} was made by another tokenizer ({fp['model_id']}@"
                             f"{fp['model_version']}) than the others; train a prior on one tokenizer's tokens")
        z_s.append(sample["static_tokens"].float())
        z_d.append(sample["dynamic_tokens"].float())
    return torch.stack(z_s), torch.stack(z_d), fingerprint


def model_card(model_id: str, model_version: str, cfg: PriorConfig, tokenizer: Any, training: dict[str, Any]
               ) -> str:
    """MODEL_CARD.md of a trained prior: what it models, the tokenizer it is bound to, how it was trained."""
    params = sum(p.numel() for p in Co4DGen(cfg).parameters())
    token_note = ("; and the tokenizer's own tokens of the video, Z^c = E(V_c, P_c), added to the input tokens, "
                  "with the relative pose of P_a to P_c in the modulation (so `vt4d generate` encodes the video "
                  "with the tokenizer first)") if cfg.cond_tokens else ""
    return f"""# {model_id} {model_version}

Co4DGen token-space prior (VideoTok4D paper, Sec. 3.3): samples the joint token state
Z^a = [Z_s^a; Z_d^a] of an anchor camera a given one conditioning video V_c with its cameras P_c and the
anchor trajectory P_a, by flow matching (Euler/Heun sampler, seeded).  Render the sample with the
tokenizer's renderer along any trajectory: `vt4d generate CAPTURE --anchor PRESET --views ...`.

* Tokenizer (the only one it may be used with): {tokenizer.short()}
  config sha256 {tokenizer.config_sha256}, weights sha256 {tokenizer.weights_sha256}
* Architecture: {cfg.layers} co-denoising blocks (Static-Dynamic Cross-Token Attention, cross-attention to
  E_cond, adaLN from tau + pooled condition), width {cfg.width}, {cfg.heads} heads; E_cond with
  {cfg.cond_layers} blocks over {cfg.cond_patch}x{cfg.cond_patch}-pixel video patches + Plucker rays and
  {cfg.anchor_grid}x{cfg.anchor_grid} anchor-ray tokens per frame{token_note}; {params / 1e6:.2f} M parameters.
* Token state: N_s = {cfg.n_static}, N_d = {cfg.n_dynamic}, d = {cfg.token_dim}; clips of {cfg.frames} frames at
  {cfg.image_size}x{cfg.image_size}.
* Training: {training["steps"]} steps, batch {training["batch_size"]}, on {training["pairs"]} ordered camera
  pairs ({training["records"]} anchor records) read from `{training["shards"]}` through
  vt4dcodec.data.archive_dataset (anchors: {training.get("anchors", "distinct")}{", the anchor's own clip " + str(training["source_repeats"]) +
  " times" if training.get("source_repeats", 1) > 1 else ""}); loss {training["first_loss"]} ->
  {training["final_loss"]} in {training["seconds"]} s wall time on a shared CPU{
  ", starting from the weights of " + training["init"] if training.get("init") else ""}; learning rate {training.get("lr")}
  (warm-up, cosine decay); {"the weights are the exponential moving average (decay " + str(training["ema_decay"]) + ")"
  if training.get("ema_decay") else "the last weights"}; null condition for classifier-free guidance:
  {"a share of " + str(cfg.cond_dropout) + " of the conditions" if cfg.cond_dropout else "none"}.
* Data: procedurally generated synthetic multi-camera scenes (vt4dcodec.synth, train split); evaluate on
  split="test" (disjoint assets) with bench/bench_prior.py.
* Limits: a CPU-size model trained on one machine's CPUs; samples are coarse (docs/co4dgen.md has the
  measured quality).  Only valid with the tokenizer above (load_prior + check_tokenizer refuse others).
"""


class SampleValidation:
    """Sample quality on held-out events during training, against the floor and ceiling of each event.

    For each of the first ``events`` events of ``shards`` (test split, tokenized by ``tokenizer``): one
    sample (``steps`` steps of ``method``, seed 0) conditioned on camera 0's video and anchored at camera 0, rendered
    by the tokenizer at every camera of the event.  Reported (means over every rendered video): PSNR and
    SSIM of the sample, of the ceiling (camera 0's own record, E(V_0, P_0), rendered the same way) and of
    the floor (every pixel the conditioning video's mean colour), ``gap_closed`` = (sample - floor) /
    (ceiling - floor) of the mean PSNRs, and the own view's SSIM beside the ceiling's.  ``average`` (a
    :class:`WeightAverage`) is what is sampled when given; ``prior``'s own weights are left unchanged.
    """

    def __init__(self, shards: Any, tokenizer: Any, events: int = 8, steps: int = 16, method: str = "heun") -> None:
        from ..diagnostics import video_quality

        self._quality = video_quality
        self.tokenizer, self.steps, self.method = tokenizer, int(steps), method
        stored = tokenizer.stored_fingerprint()
        fingerprint = stored.to_dict()
        dataset = ArchiveDataset(shards)
        clips = ClipStore(dataset.shards)
        by_event: dict[str, dict[int, dict[str, Any]]] = {}
        for i in range(len(dataset)):
            sample = dataset[i]
            if sample["metadata"]["fingerprint"] != fingerprint:
                raise ModelError(f"validation record {sample['key']} was not tokenized by {stored.short()}")
            meta = sample["metadata"]["user"]["co4dgen"]
            by_event.setdefault(meta["event"], {})[int(meta["camera"])] = {
                "z_s": sample["static_tokens"].float(), "z_d": sample["dynamic_tokens"].float(),
                "clip": clips.load(sample["key"])}
        chosen = sorted(by_event)[:events]
        if not chosen or any(0 not in by_event[e] or len(by_event[e]) < 2 for e in chosen):
            raise ModelError(f"validation needs events with a camera 0 and another camera in {shards}")
        self.events = [[by_event[e][k] for k in sorted(by_event[e])] for e in chosen]
        self.names = chosen
        self.truth = [np.stack([cam["clip"]["frames"] for cam in cams]) for cams in self.events]
        self.floor = [np.broadcast_to(cams[0]["clip"]["frames"].reshape(-1, 3).mean(0).round().astype(np.uint8),
                                      t.shape) for cams, t in zip(self.events, self.truth)]
        self.ceiling = [self._render(cams, cams[0]["z_s"][None], cams[0]["z_d"][None]) for cams in self.events]
        self.reference = {"ceiling": self._score(self.ceiling), "floor": self._score(self.floor)}

    def _render(self, cams: list[dict[str, Any]], z_s: torch.Tensor, z_d: torch.Tensor) -> np.ndarray:
        """Tokens (1, N, d) of camera 0 rendered at every camera: (V, T, H, W, 3) uint8."""
        V = len(cams)
        K = torch.from_numpy(np.stack([c["clip"]["K"] for c in cams])).float()
        w2c = torch.from_numpy(np.stack([c["clip"]["w2c"] for c in cams])).float()
        src = cams[0]["clip"]
        source = (torch.from_numpy(src["K"]).float()[None].expand(V, -1, -1, -1),
                  torch.from_numpy(src["w2c"]).float()[None].expand(V, -1, -1, -1))
        with torch.no_grad():
            frames = self.tokenizer.render(z_s.expand(V, -1, -1), z_d.expand(V, -1, -1), K, w2c, seed=0,
                                           source=source)
        return (frames.permute(0, 1, 3, 4, 2).numpy() * 255.0).round().clip(0, 255).astype(np.uint8)

    def _score(self, videos: list[np.ndarray]) -> dict[str, float]:
        psnr, ssim, own = [], [], []
        for pred, truth in zip(videos, self.truth):
            for v in range(truth.shape[0]):
                p, q = self._quality(pred[v], truth[v])
                psnr.append(p)
                ssim.append(q)
                if v == 0:
                    own.append(q)
        return {"psnr": float(np.mean(psnr)), "ssim": float(np.mean(ssim)), "own_ssim": float(np.mean(own))}

    def sample(self, prior: Co4DGen) -> list[np.ndarray]:
        prior.eval()
        out = []
        for cams in self.events:
            clip = cams[0]["clip"]
            K = torch.from_numpy(clip["K"]).float()[None]
            w2c = torch.from_numpy(clip["w2c"]).float()[None]
            frames = torch.from_numpy(clip["frames"]).permute(0, 3, 1, 2).float().div(255.0)[None]
            z_s, z_d = prior.sample(PriorCondition(frames=frames, K_c=K, w2c_c=w2c, K_a=K, w2c_a=w2c,
                                                   z_s=cams[0]["z_s"][None], z_d=cams[0]["z_d"][None]),
                                    steps=self.steps, seed=0, method=self.method)
            out.append(self._render(cams, z_s, z_d))
        return out

    def __call__(self, prior: Co4DGen, average: WeightAverage | None = None) -> dict[str, float]:
        model = prior
        if average is not None:
            model = Co4DGen(prior.config)
            average.copy_to(model)
        got = self._score(self.sample(model))
        ceiling, floor = self.reference["ceiling"], self.reference["floor"]
        gap = ceiling["psnr"] - floor["psnr"]
        return {"val_psnr": round(got["psnr"], 3), "val_ssim": round(got["ssim"], 4),
                "val_own_ssim": round(got["own_ssim"], 4),
                "gap_closed": round((got["psnr"] - floor["psnr"]) / gap, 4) if gap > 0 else float("nan"),
                "ceiling_psnr": round(ceiling["psnr"], 3), "ceiling_own_ssim": round(ceiling["own_ssim"], 4),
                "floor_psnr": round(floor["psnr"], 3), "events": len(self.events)}


def plot_validation(records: list[dict[str, Any]], png: Any, title: str) -> None:
    """The validation curve: sample PSNR against step between the ceiling and the floor, and the own
    view's SSIM against the ceiling's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not records:
        return
    steps = [r["step"] for r in records]
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4), dpi=100)
    panels = [("PSNR (dB)", [("val_psnr", "o-", "C0", "sample, all cameras"),
                             ("ceiling_psnr", "--", "C2", "ceiling: the encode"),
                             ("floor_psnr", "--", "0.5", "floor: flat image")]),
              ("SSIM", [("val_own_ssim", "o-", "C1", "sample, own view"),
                        ("ceiling_own_ssim", "--", "C2", "the encode, own view")])]
    for ax, (ylabel, lines) in zip(axes, panels):
        for key, style, colour, label in lines:
            ax.plot(steps, [r[key] for r in records], style, color=colour, label=label)
        ax.set_xlabel("step")
        ax.set_ylabel(ylabel)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)


def initialise_from(prior: Co4DGen, source: Path) -> list[str]:
    """Copy the weights of a saved prior or training checkpoint into ``prior`` (``--init``): every tensor of
    the source must exist in ``prior`` with the same shape; tensors only ``prior`` has (parameters its config
    adds) keep their initial values.  Returns the names copied; ModelError for anything else."""
    from safetensors.torch import load_file

    from ..directories import PRIOR_WEIGHTS_FILE

    candidates = [source / PRIOR_WEIGHTS_FILE, source / "ema.safetensors", source / "model.safetensors"]
    path = next((p for p in candidates if p.is_file()), None)
    if path is None:
        raise ModelError(f"--init {source}: no {PRIOR_WEIGHTS_FILE}, ema.safetensors or model.safetensors there")
    weights = load_file(str(path))
    own = prior.state_dict()
    wrong = [k for k, v in weights.items() if k not in own or tuple(own[k].shape) != tuple(v.shape)]
    if wrong:
        raise ModelError(f"--init {path}: {len(wrong)} tensors do not fit this prior's config, e.g. {wrong[:3]}")
    prior.load_state_dict({**own, **weights})
    return sorted(weights)


def _prior_step(module: torch.nn.Module, batch: PriorBatch) -> tuple[torch.Tensor, dict[str, float]]:
    return module(batch.z_s, batch.z_d, batch.cond)


def arguments() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m vt4dcodec.model.train.prior", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    shard_model_arguments(parser, what="prior", config="co4dgen-tiny", model_id="co4dgen-tiny",
                          model_version="0.1.0", ckpt_every=250)
    parser.add_argument("--anchors", choices=ANCHORS, default="all",
                        help="training pairs: every (anchor, conditioning camera) pair of an event, the anchor "
                             "itself included (all, default), or only distinct cameras (the paper's pairs)")
    parser.add_argument("--source-repeats", type=int, default=1, metavar="N",
                        help="with --anchors all: each pair whose anchor is the conditioning camera itself N times "
                             "(with 10 cameras, 9 makes it half of the pairs; default 1)")
    parser.add_argument("--ema-decay", type=float, default=0.999,
                        help="keep an exponential moving average of the weights with this decay; validation "
                             "and the saved prior use it (0: none, the last weights)")
    parser.add_argument("--val-shards", default=None, help="test-split shards by the same tokenizer to validate on")
    parser.add_argument("--val-events", type=int, default=8, help="held-out events per validation")
    parser.add_argument("--val-every", type=int, default=500, help="validate every N steps (and at the end)")
    parser.add_argument("--val-sampler", default="heun:16", metavar="METHOD:STEPS",
                        help="sampler of a validation sample (default heun:16)")
    parser.add_argument("--init", type=Path, default=None, metavar="DIR",
                        help="start from these weights: a prior directory (prior.safetensors) or a run's checkpoint "
                             "directory (its ema.safetensors, else model.safetensors); parameters the config adds "
                             "(e.g. cond_tokens) keep their initial values. Ignored when the run resumes")
    parser.add_argument("--tokenizer", default=None,
                        help="the tokenizer that wrote the shards, to render validation samples (default: the "
                             "shipped model the shards' fingerprint names)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = arguments().parse_args(argv)
    info = setup_distributed()
    torch.set_num_threads(args.threads)
    seed_everything(args.seed + info.rank)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.ema_decay and not 0.0 < args.ema_decay < 1.0:
        raise ModelError(f"--ema-decay must lie in (0, 1) or be 0, got {args.ema_decay}")
    cfg = get_prior_config(args.config, **parse_overrides(args.set))
    dataset = PriorPairDataset(args.shards, anchors=args.anchors, source_repeats=args.source_repeats,
                               condition_tokens=cfg.cond_tokens)
    all_s, all_d, fp_dict = token_statistics(dataset)
    first = dataset.tokens[0]["metadata"]  # the token state and clip sizes come from the data
    cfg = PriorConfig.from_dict({**cfg.to_dict(), "n_static": all_s.shape[1], "n_dynamic": all_d.shape[1],
                                 "token_dim": all_s.shape[2], "frames": first["frames"],
                                 "image_size": first["width"]})
    prior = Co4DGen(cfg)
    prior.set_token_statistics(all_s, all_d)
    if args.init is not None and not (args.out / "checkpoint" / "state.json").is_file():
        loaded = initialise_from(prior, args.init)
        print(f"initialised {len(loaded)} tensors from {args.init}")
    optimizer = torch.optim.AdamW(prior.parameters(), lr=args.lr, weight_decay=0.01)
    module = DistributedDataParallel(prior) if info.distributed else prior
    average = WeightAverage(prior, args.ema_decay) if args.ema_decay else None
    validate = None
    if args.val_shards and info.is_main:
        from ..weights_io import from_pretrained

        tokenizer = from_pretrained(args.tokenizer or fp_dict["model_id"])
        if tokenizer.stored_fingerprint().to_dict() != fp_dict:
            raise ModelError(f"--tokenizer {tokenizer.stored_fingerprint().short()} did not write the training shards "
                             f"({fp_dict['model_id']}@{fp_dict['model_version']})")
        setting = parse_sampler(args.val_sampler)
        validation = SampleValidation(args.val_shards, tokenizer, args.val_events, setting.steps, setting.method)
        print(f"validation on {len(validation.events)} held-out events: ceiling "
              f"{validation.reference['ceiling']['psnr']:.2f} dB, floor {validation.reference['floor']['psnr']:.2f} dB")

        def validate(step: int) -> dict[str, Any]:
            metrics = validation(prior, average)
            print(f"step {step}: sample {metrics['val_psnr']:.2f} dB ({100 * metrics['gap_closed']:.0f} % of the "
                  f"gap), own-view SSIM {metrics['val_own_ssim']:.3f} (encode {metrics['ceiling_own_ssim']:.3f})")
            return metrics

    batches = cycle(make_loader(dataset, args, info, collate_fn=collate_prior))
    records = train_loop(args, info, module, prior, optimizer, batches, _prior_step, title="Co4DGen prior",
                         extra_state={"config": cfg.to_dict(), "tokenizer": fp_dict}, average=average,
                         validate=validate, validate_every=args.val_every)
    if info.is_main and validate is not None:
        plot_validation(JsonlLog(args.out / "val.jsonl").read(), args.out / "val.png",
                        f"Co4DGen validation ({args.out.name})")
    if info.is_main:
        if average is not None:
            average.copy_to(prior)  # the saved prior is the weight average
        tokenizer = ModelFingerprint.from_dict(fp_dict)
        training = {"shards": str(args.shards), "pairs": len(dataset), "records": len(dataset.tokens),
                    "steps": args.steps, "batch_size": args.batch_size, "anchors": args.anchors,
                    "source_repeats": args.source_repeats, "init": str(args.init) if args.init else None,
                    "ema_decay": args.ema_decay, "lr": args.lr,
                    "first_loss": records[0]["loss"] if records else None,
                    "final_loss": records[-1]["loss"] if records else None,
                    "seconds": records[-1].get("elapsed_s") if records else None}
        card = model_card(args.model_id, args.model_version, cfg, tokenizer, training)
        directory = save_prior(prior, args.out / "prior", model_id=args.model_id, model_version=args.model_version,
                               tokenizer=tokenizer, card=card, extra={"training": training})
        (args.out / "summary.json").write_text(json.dumps({"config": cfg.to_dict(), **training}, indent=2) + "\n")
        print(f"prior: loss {training['first_loss']} -> {training['final_loss']} over {args.steps} steps on "
              f"{len(dataset)} pairs; prior -> {directory}")
    cleanup_distributed()
    return 0


if __name__ == "__main__":
    sys.exit(main())
