"""Stage 1: train the latent autoencoder on synthetic frames, then freeze it (issue #6 item 1).

    python -m vt4dcodec.model.train.autoencoder --out runs/ae --steps 2000
    torchrun --nproc_per_node=2 -m vt4dcodec.model.train.autoencoder --out runs/ae --steps 2000

Loss: L1 + MSE between frames and their reconstructions. At the end the per-channel latent
statistics are measured on training frames (so stage 2 sees unit-variance latents) and the frozen
autoencoder is written to ``<out>/autoencoder.safetensors`` with ``<out>/autoencoder.json``
(the model config it belongs to). Re-running the same command resumes from ``<out>/checkpoint``.
"""

from __future__ import annotations

import argparse
import json
import sys

import torch
import torch.nn.functional as F
from safetensors.torch import save_file
from torch.nn.parallel import DistributedDataParallel

from ..autoencoder import LatentAutoencoder
from ..configs import get_config
from .common import (cleanup_distributed, common_arguments, cycle, make_loader, parse_overrides,
                     scene_pool_and_seeds, seed_everything, setup_distributed, train_loop)
from .data import FrameDataset

__all__ = ["main", "AE_WEIGHTS", "AE_CONFIG"]

AE_WEIGHTS, AE_CONFIG = "autoencoder.safetensors", "autoencoder.json"


def reconstruction_step(module: torch.nn.Module, images: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
    recon = module(images).float()
    l1, mse = F.l1_loss(recon, images), F.mse_loss(recon, images)
    psnr = float(10 * torch.log10(1.0 / mse.detach().clamp_min(1e-10)))
    return l1 + mse, {"l1": float(l1.detach()), "mse": float(mse.detach()), "psnr": psnr}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m vt4dcodec.model.train.autoencoder", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    common_arguments(parser)
    parser.set_defaults(batch_size=32, lr=1e-3, scenes=32)
    args = parser.parse_args(argv)
    info = setup_distributed()
    torch.set_num_threads(args.threads)
    seed_everything(args.seed + info.rank)
    cfg = get_config(args.config, **parse_overrides(args.set))
    args.out.mkdir(parents=True, exist_ok=True)

    ae = LatentAutoencoder(cfg)
    optimizer = torch.optim.AdamW(ae.parameters(), lr=args.lr, weight_decay=0.0)
    module = DistributedDataParallel(ae) if info.distributed else ae
    dataset = FrameDataset(*scene_pool_and_seeds(args, cfg, info))
    records = train_loop(args, info, module, ae, optimizer, cycle(make_loader(dataset, args, info)),
                         reconstruction_step, title="stage 1: autoencoder",
                         extra_state={"config": cfg.to_dict()})
    if info.is_main:
        ae.eval()
        sample = torch.stack([dataset[i] for i in torch.randperm(len(dataset))[:256].tolist()])
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
