"""Train the dense per-view baseline (Table 2) on the same token shards as the Co4DGen prior.

    python -m vt4dcodec.model.train.dense --shards data/co4dgen-1.0.0 --out runs/dense --steps 1000 \
        --batch-size 16 --lr 5e-4 --threads 1

One sample is an ordered pair (target camera a, conditioning clip c != a) of the same event -- the
pairs the prior trains on (:class:`~.prior.PriorPairDataset`) -- but the target is camera a's video
itself (its latents under the tokenizer's frozen autoencoder) instead of its token state.  The
autoencoder is copied from the tokenizer that wrote the shards (``--tokenizer``, whose fingerprint must
be the shards'), so both pipelines decode through the same latent space.  The loop, resumable
checkpoints, JSONL log and loss plot are :mod:`model.train.common`'s; the finished model is written with
:func:`~model.weights_io.save_dense` to ``<out>/dense``.
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

from vt4dcodec.errors import ModelError
from vt4dcodec.format import ModelFingerprint

from ..configs import DenseConfig
from ..dense_baseline import DenseViewDiffusion
from ..prior import PriorCondition
from ..weights_io import from_pretrained, save_dense
from .common import (cleanup_distributed, cycle, make_loader, parse_overrides, seed_everything, setup_distributed,
                     shard_model_arguments, train_loop)
from .prior import PriorPairDataset

__all__ = ["DensePairDataset", "DenseBatch", "collate_dense", "model_card", "main"]


@dataclass
class DenseBatch:
    """Target videos (B, T, 3, H, W) in [0, 1] and the condition (V_c, P_c, P_a)."""

    target: torch.Tensor
    cond: PriorCondition
    keys: list[str]


class DensePairDataset(PriorPairDataset):
    """Every ordered (target camera, conditioning camera of the same event) pair of some token shards.
    Item: dict with ``target`` (T, H, W, 3) uint8 and ``K_a``, ``w2c_a`` of the target camera, ``frames``,
    ``K_c``, ``w2c_c`` of the conditioning clip, and the two keys."""

    def __getitem__(self, index: int) -> dict[str, Any]:
        i, clip_key = self.pairs[index]
        target_key = self.tokens.keys[i][1]
        target, clip = self.clips.load(target_key), self.clips.load(clip_key)
        if clip["frames"].shape != target["frames"].shape:
            raise ModelError(f"clips {clip_key} and {target_key} differ in shape")
        return {"target": target["frames"], "K_a": target["K"], "w2c_a": target["w2c"], "frames": clip["frames"],
                "K_c": clip["K"], "w2c_c": clip["w2c"], "target_key": target_key, "clip_key": clip_key}

    def fingerprint(self) -> dict[str, Any]:
        """The one tokenizer fingerprint of every record (ModelError if the shards mix tokenizers)."""
        found = {json.dumps(self.tokens[i]["metadata"]["fingerprint"], sort_keys=True) for i in range(len(self.tokens))}
        if len(found) != 1:
            raise ModelError("the shards were written by more than one tokenizer; train on one tokenizer's shards")
        return json.loads(found.pop())


def _video(arrays: list[np.ndarray]) -> torch.Tensor:
    return torch.from_numpy(np.stack(arrays)).permute(0, 1, 4, 2, 3).float().div_(255.0)


def _cameras(arrays: list[np.ndarray]) -> torch.Tensor:
    return torch.from_numpy(np.stack(arrays)).float()


def collate_dense(items: list[dict[str, Any]]) -> DenseBatch:
    """Stack dataset items into a :class:`DenseBatch` (videos to float [0, 1], channels first)."""
    cond = PriorCondition(frames=_video([it["frames"] for it in items]), K_c=_cameras([it["K_c"] for it in items]),
                          w2c_c=_cameras([it["w2c_c"] for it in items]), K_a=_cameras([it["K_a"] for it in items]),
                          w2c_a=_cameras([it["w2c_a"] for it in items]))
    return DenseBatch(target=_video([it["target"] for it in items]), cond=cond,
                      keys=[it["target_key"] for it in items])


def model_card(model_id: str, model_version: str, dense: DenseViewDiffusion, tokenizer: ModelFingerprint,
               training: dict[str, Any]) -> str:
    """MODEL_CARD.md of a trained dense baseline."""
    cfg = dense.config
    return f"""# {model_id} {model_version}

Dense per-view baseline of the VideoTok4D paper's Table 2 (DFoT-style conditional latent video diffusion):
generates one target view's latent video from one conditioning video V_c with its cameras P_c and the
target trajectory, one sampling run per view (rectified flow, Euler/Heun, seeded); decoded by the frozen
autoencoder of the tokenizer below. Evaluate with `bench/bench_dense.py`.

* Latent space: the autoencoder of {tokenizer.short()} (weights sha256 {tokenizer.weights_sha256}), frozen.
* Architecture: E_cond as Co4DGen's ({cfg.cond_layers} blocks over {cfg.cond_patch}x{cfg.cond_patch}-pixel patches
  + Plucker rays, {cfg.anchor_grid}x{cfg.anchor_grid} target-ray tokens per frame); {cfg.layers} factorised
  space-time DiT blocks (spatial, temporal, cross-attention to E_cond, MLP; adaLN-zero) of width {cfg.width},
  {cfg.heads} heads, over {cfg.frames} x {(cfg.latent_size // cfg.patch_size) ** 2} latent patches of
  {cfg.patch_size}x{cfg.patch_size}; {dense.trainable_parameters() / 1e6:.2f} M trainable parameters.
* Training: {training["steps"]} steps, batch {training["batch_size"]}, on {training["pairs"]} ordered camera pairs of
  `{training["shards"]}`; loss {training["first_loss"]} -> {training["final_loss"]} in {training["seconds"]} s on a
  shared CPU core.
* Data: procedurally generated synthetic multi-camera scenes (vt4dcodec.synth, train split).
* Limits: a CPU-size baseline trained for minutes, for timing and quality comparison only.
"""


def _dense_step(module: torch.nn.Module, batch: DenseBatch) -> tuple[torch.Tensor, dict[str, float]]:
    trained = module.module if isinstance(module, DistributedDataParallel) else module
    return module(trained.latents(batch.target), batch.cond)


def arguments() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m vt4dcodec.model.train.dense", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    shard_model_arguments(parser, what="dense", config="dense-tiny", model_id="dense-tiny", model_version="1.0.0",
                          ckpt_every=100)
    parser.add_argument("--tokenizer", default="vt4d-tiny", help="tokenizer whose autoencoder is the latent space")
    parser.add_argument("--storage-dtype", choices=("float32", "float16"), default="float32",
                        help="dtype of the exported dense.safetensors (float16 halves the file; the weights are "
                             "rounded first, so what is stored is what is measured)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = arguments().parse_args(argv)
    info = setup_distributed()
    torch.set_num_threads(args.threads)
    seed_everything(args.seed + info.rank)
    args.out.mkdir(parents=True, exist_ok=True)
    dataset = DensePairDataset(args.shards)
    tokenizer = from_pretrained(args.tokenizer)
    fingerprint = tokenizer.stored_fingerprint()
    if dataset.fingerprint() != fingerprint.to_dict():
        raise ModelError(f"the shards were tokenized by another tokenizer than {fingerprint.short()}: "
                         "pass --tokenizer with the shards' tokenizer")
    cfg = DenseConfig.for_tokenizer(tokenizer.config, args.config, **parse_overrides(args.set))
    dense = DenseViewDiffusion(cfg)
    dense.autoencoder.load_state_dict(tokenizer.autoencoder.state_dict(), strict=True)
    trainable = [p for p in dense.parameters() if p.requires_grad]
    optimizer = torch.optim.AdamW(trainable, lr=args.lr, weight_decay=0.01)
    module = DistributedDataParallel(dense) if info.distributed else dense
    batches = cycle(make_loader(dataset, args, info, collate_fn=collate_dense))
    records = train_loop(args, info, module, dense, optimizer, batches, _dense_step, title="dense baseline",
                         extra_state={"config": cfg.to_dict(), "tokenizer": fingerprint.to_dict()})
    if info.is_main:
        done = int(records[-1]["step"]) if records else 0
        training = {"shards": str(args.shards), "pairs": len(dataset), "steps": done, "batch_size": args.batch_size,
                    "first_loss": records[0]["loss"] if records else None,
                    "final_loss": records[-1]["loss"] if records else None,
                    "seconds": records[-1].get("elapsed_s") if records else None,
                    "trainable_parameters": dense.trainable_parameters()}
        card = model_card(args.model_id, args.model_version, dense, fingerprint, training)
        directory = save_dense(dense, args.out / "dense", model_id=args.model_id, model_version=args.model_version,
                               tokenizer=fingerprint, card=card, extra={"training": training},
                               storage_dtype=args.storage_dtype)
        (args.out / "summary.json").write_text(json.dumps({"config": cfg.to_dict(), **training}, indent=2) + "\n")
        print(f"dense baseline: loss {training['first_loss']} -> {training['final_loss']} at step {done} on "
              f"{len(dataset)} pairs; model -> {directory}")
    cleanup_distributed()
    return 0


if __name__ == "__main__":
    sys.exit(main())
