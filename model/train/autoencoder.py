"""Stage 1: train the latent autoencoder on synthetic frames, then freeze it (issue #6 item 1).

    python -m vt4dcodec.model.train.autoencoder --out runs/ae --steps 2000
    torchrun --nproc_per_node=2 -m vt4dcodec.model.train.autoencoder --out runs/ae --steps 2000

Data: every frame of every camera of the training scenes, plus (``--photo-share``) random crops of
the training-split photos at full resolution, so real footage is not decoded by an autoencoder that
has only seen rendered textures. ``--init`` warm-starts from earlier weights where shapes match;
with ``--decoder-only`` only the decoder trains, so the latents (and a tokenizer trained on them) stay.
Loss: L1 + MSE between frames and their reconstructions. At the end the per-channel latent
statistics are measured on training frames, so stage 2 sees unit-variance latents (with ``--decoder-only``
they stay the --init ones), and the frozen
autoencoder is written to ``<out>/autoencoder.safetensors`` with ``<out>/autoencoder.json``
(the model config it belongs to). Re-running the same command resumes from ``<out>/checkpoint``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch
import torch.nn.functional as F
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from torch.nn.parallel import DistributedDataParallel

from vt4dcodec.errors import ModelError

from ..autoencoder import LatentAutoencoder
from ..configs import get_config
from .common import (cleanup_distributed, common_arguments, cycle, make_loader, parse_overrides,
                     scene_pool_and_seeds, seed_everything, setup_distributed, train_loop)
from .data import FrameDataset, MixedFrames

__all__ = ["main", "AE_WEIGHTS", "AE_CONFIG"]

AE_WEIGHTS, AE_CONFIG = "autoencoder.safetensors", "autoencoder.json"


def reconstruction_step(module: torch.nn.Module, images: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
    recon = module(images).float()
    l1, mse = F.l1_loss(recon, images), F.mse_loss(recon, images)
    psnr = float(10 * torch.log10(1.0 / mse.detach().clamp_min(1e-10)))
    return l1 + mse, {"l1": float(l1.detach()), "mse": float(mse.detach()), "psnr": psnr}


def warm_start(ae: LatentAutoencoder, path: Path) -> int:
    """Copy the tensors of ``path`` that fit ``ae`` (names with or without an ``autoencoder.`` prefix,
    equal shapes); the latent statistics are re-measured at the end anyway. Returns how many."""
    try:
        state = load_file(str(path))
    except (OSError, SafetensorError, ValueError) as exc:
        raise ModelError(f"cannot read {path}: {exc}") from None
    state = {k.removeprefix("autoencoder."): v for k, v in state.items()}
    own = ae.state_dict()
    fits = {k: v.to(own[k].dtype) for k, v in state.items() if k in own and v.shape == own[k].shape}
    ae.load_state_dict(fits, strict=False)
    return len(fits)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m vt4dcodec.model.train.autoencoder", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    common_arguments(parser)
    parser.set_defaults(batch_size=32, lr=1e-3, scenes=32)
    parser.add_argument("--photo-share", type=float, default=0.25,
                        help="share of each epoch that is random crops of the training-split photos "
                             "(natural-image statistics for real captures); 0 = rendered frames only")
    parser.add_argument("--init", type=Path, default=None,
                        help="warm start: copy every autoencoder tensor of this safetensors file (stage-1 "
                             "output or a model directory's model.safetensors) whose name and shape match")
    parser.add_argument("--decoder-only", action="store_true",
                        help="train the decoder alone (needs --init): the encoder and its latent statistics stay "
                             "bit-identical, so a tokenizer trained on the --init latents stays valid")
    args = parser.parse_args(argv)
    if args.decoder_only and args.init is None:
        parser.error("--decoder-only needs --init (the encoder whose latents it keeps)")
    info = setup_distributed()
    torch.set_num_threads(args.threads)
    seed_everything(args.seed + info.rank)
    cfg = get_config(args.config, **parse_overrides(args.set))
    args.out.mkdir(parents=True, exist_ok=True)

    ae = LatentAutoencoder(cfg)
    if args.init is not None:
        copied = warm_start(ae, args.init)
        if info.is_main:
            print(f"warm start from {args.init}: {copied} of {len(ae.state_dict())} tensors copied")
    if args.decoder_only:
        ae.encoder.requires_grad_(False)
    optimizer = torch.optim.AdamW([p for p in ae.parameters() if p.requires_grad], lr=args.lr, weight_decay=0.0)
    module = DistributedDataParallel(ae) if info.distributed else ae
    frames = FrameDataset(*scene_pool_and_seeds(args, cfg, info))
    dataset = MixedFrames(frames, args.photo_share, seed=args.seed + info.rank) if args.photo_share > 0 else frames
    records = train_loop(args, info, module, ae, optimizer, cycle(make_loader(dataset, args, info)),
                         reconstruction_step, title="stage 1: autoencoder",
                         extra_state={"config": cfg.to_dict()})
    if info.is_main:
        ae.eval()
        # the statistics the tokenizer will see: rendered frames only
        sample = torch.stack([frames[i] for i in torch.randperm(len(frames))[:256].tolist()])
        if not args.decoder_only:  # a kept encoder keeps the statistics the tokenizer was trained with
            ae.set_latent_statistics(sample)
        with torch.no_grad():
            _, logs = reconstruction_step(ae, sample)
        save_file({k: v.contiguous() for k, v in ae.state_dict().items()}, str(args.out / AE_WEIGHTS))
        summary = {"config": cfg.to_dict(), "steps": args.steps, "final_loss": records[-1]["loss"] if records else None,
                   "sample_psnr_db": logs["psnr"], "latent_mean": ae.latent_mean.tolist(),
                   "latent_std": ae.latent_std.tolist()}
        (args.out / AE_CONFIG).write_text(json.dumps(summary, indent=2) + "\n")
        print(f"autoencoder: PSNR {logs['psnr']:.2f} dB on {len(sample)} training frames -> {args.out / AE_WEIGHTS}")
    cleanup_distributed()
    return 0


if __name__ == "__main__":
    sys.exit(main())
