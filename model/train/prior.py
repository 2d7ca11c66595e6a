"""Train the Co4DGen prior from token archives.

    python -m vt4dcodec.model.train.tokenize_scenes --tokenizer vt4d-tiny --out data/co4dgen --scenes 512
    python -m vt4dcodec.model.train.prior --shards data/co4dgen --out runs/co4dgen --steps 3000

The data path is the one users take at scale: token shards written by
:mod:`model.train.tokenize_scenes` are read through :class:`vt4dcodec.data.archive_dataset.ArchiveDataset`
(anchor tokens Z^a and cameras P_a) and the conditioning clips (V_c, P_c) through their sidecars.
One sample is an ordered pair (anchor record a, conditioning clip c != a) of the same event; the
dataset enumerates every such pair.  Every record must carry the same tokenizer fingerprint, which the
finished prior records (``save_prior``), so it is only ever used with that tokenizer.
The loop, checkpoints, log and loss plot are :mod:`model.train.common`'s.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import Dataset

from vt4dcodec.data.archive_dataset import ArchiveDataset
from vt4dcodec.errors import ModelError
from vt4dcodec.format import ModelFingerprint

from ..configs import PriorConfig, get_prior_config
from ..prior import Co4DGen, PriorCondition
from ..weights_io import save_prior
from .common import (cleanup_distributed, cycle, make_loader, parse_overrides, seed_everything, setup_distributed,
                     shard_model_arguments, train_loop)
from .tokenize_scenes import ClipStore

__all__ = ["PriorPairDataset", "PriorBatch", "collate_prior", "token_statistics", "model_card", "main"]


@dataclass
class PriorBatch:
    """Anchor tokens Z^a = (z_s (B, N_s, d), z_d (B, N_d, d)) and the condition (V_c, P_c, P_a)."""

    z_s: torch.Tensor
    z_d: torch.Tensor
    cond: PriorCondition
    keys: list[str]


class PriorPairDataset(Dataset):
    """All ordered (anchor record, conditioning clip of another camera of the same event) pairs of some
    token shards.  Item: dict with ``z_s``, ``z_d``, ``K_a``, ``w2c_a`` (tensors of the anchor record),
    ``frames`` (T, H, W, 3) uint8, ``K_c``, ``w2c_c`` of the conditioning clip, and the two keys."""

    def __init__(self, shards: Any) -> None:
        self.tokens = ArchiveDataset(shards)
        if len(self.tokens) == 0:
            raise ModelError(f"no token records in {shards}")
        self.clips = ClipStore(self.tokens.shards)
        self.pairs: list[tuple[int, str]] = []
        for i, (_, key) in enumerate(self.tokens.keys):
            event, _, cam = key.rpartition("/cam")
            others = [k for k in self._event_clips(event) if k != key]
            if not event or not others:
                raise ModelError(f"token record {key!r} has no conditioning clip of another camera")
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
        return {"z_s": anchor["static_tokens"].float(), "z_d": anchor["dynamic_tokens"].float(),
                "K_a": anchor["K"], "w2c_a": anchor["w2c"], "frames": clip["frames"], "K_c": clip["K"],
                "w2c_c": clip["w2c"], "anchor_key": anchor["key"], "clip_key": clip_key,
                "fingerprint": anchor["metadata"]["fingerprint"]}


def collate_prior(items: list[dict[str, Any]]) -> PriorBatch:
    """Stack dataset items into a :class:`PriorBatch` (frames to float [0, 1], channels first)."""
    frames = torch.from_numpy(np.stack([it["frames"] for it in items])).permute(0, 1, 4, 2, 3).float().div_(255.0)
    cond = PriorCondition(frames=frames,
                          K_c=torch.from_numpy(np.stack([it["K_c"] for it in items])).float(),
                          w2c_c=torch.from_numpy(np.stack([it["w2c_c"] for it in items])).float(),
                          K_a=torch.stack([it["K_a"] for it in items]).float(),
                          w2c_a=torch.stack([it["w2c_a"] for it in items]).float())
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
  {cfg.anchor_grid}x{cfg.anchor_grid} anchor-ray tokens per frame; {params / 1e6:.2f} M parameters.
* Token state: N_s = {cfg.n_static}, N_d = {cfg.n_dynamic}, d = {cfg.token_dim}; clips of {cfg.frames} frames at
  {cfg.image_size}x{cfg.image_size}.
* Training: {training["steps"]} steps, batch {training["batch_size"]}, on {training["pairs"]} ordered camera
  pairs ({training["records"]} anchor records) read from `{training["shards"]}` through
  vt4dcodec.data.archive_dataset; loss {training["first_loss"]} -> {training["final_loss"]}
  in {training["seconds"]} s wall time on a shared CPU.
* Data: procedurally generated synthetic multi-camera scenes (vt4dcodec.synth, train split); evaluate on
  split="test" (disjoint assets) with bench/bench_prior.py.
* Limits: a CPU-size model trained for minutes; samples are coarse.  Only valid with the tokenizer above
  (load_prior + check_tokenizer refuse others).
"""


def _prior_step(module: torch.nn.Module, batch: PriorBatch) -> tuple[torch.Tensor, dict[str, float]]:
    return module(batch.z_s, batch.z_d, batch.cond)


def arguments() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m vt4dcodec.model.train.prior", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    shard_model_arguments(parser, what="prior", config="co4dgen-tiny", model_id="co4dgen-tiny",
                          model_version="0.1.0", ckpt_every=250)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = arguments().parse_args(argv)
    info = setup_distributed()
    torch.set_num_threads(args.threads)
    seed_everything(args.seed + info.rank)
    args.out.mkdir(parents=True, exist_ok=True)
    dataset = PriorPairDataset(args.shards)
    all_s, all_d, fp_dict = token_statistics(dataset)
    cfg = get_prior_config(args.config, **parse_overrides(args.set))
    first = dataset.tokens[0]["metadata"]  # the token state and clip sizes come from the data
    cfg = PriorConfig.from_dict({**cfg.to_dict(), "n_static": all_s.shape[1], "n_dynamic": all_d.shape[1],
                                 "token_dim": all_s.shape[2], "frames": first["frames"],
                                 "image_size": first["width"]})
    prior = Co4DGen(cfg)
    prior.set_token_statistics(all_s, all_d)
    optimizer = torch.optim.AdamW(prior.parameters(), lr=args.lr, weight_decay=0.01)
    module = DistributedDataParallel(prior) if info.distributed else prior
    batches = cycle(make_loader(dataset, args, info, collate_fn=collate_prior))
    records = train_loop(args, info, module, prior, optimizer, batches, _prior_step, title="Co4DGen prior",
                         extra_state={"config": cfg.to_dict(), "tokenizer": fp_dict})
    if info.is_main:
        tokenizer = ModelFingerprint.from_dict(fp_dict)
        training = {"shards": str(args.shards), "pairs": len(dataset), "records": len(dataset.tokens),
                    "steps": args.steps, "batch_size": args.batch_size,
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
