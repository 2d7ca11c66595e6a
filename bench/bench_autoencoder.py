"""How much of the picture the frozen latent autoencoder keeps: reconstruction PSNR of candidates side
by side, on held-out synthetic frames and on the real caliscope frames.

    python bench/bench_autoencoder.py --candidate NAME=PATH [...] [--scenes 16] \
        [--out bench/results/autoencoder.json]

A candidate is a shipped model id or model directory (its ``autoencoder.*`` tensors), a stage-1
``autoencoder.safetensors``, or a stage-1 ``checkpoint/model.safetensors``; its config is read from
the file's shapes (latent channels, width). Every render the codec makes goes through this decoder,
so this PSNR is a ceiling for the codec's; the targets are >= 31 dB on held-out synthetic frames and
>= 28 dB on the caliscope frames. Frames: every camera and frame of ``--scenes`` 10-camera test-split
scenes (textures no training scene uses) and all 4 x 48 caliscope frames at 64x64 (never trained on).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file

from vt4dcodec.capture.caliscope import find_sample_capture, import_caliscope
from vt4dcodec.model import get_config
from vt4dcodec.model.autoencoder import LatentAutoencoder
from vt4dcodec.model.weights_io import model_directory
from vt4dcodec.synth import SynthConfig, generate_scene


def load_candidate(spec: str) -> LatentAutoencoder:
    path = Path(spec)
    if not path.is_file():  # a model directory, shipped id or $VT4D_MODEL_PATH name
        path = model_directory(spec) / "model.safetensors"
    tensors = load_file(str(path))
    if any(k.startswith("autoencoder.") for k in tensors):  # a whole model: its autoencoder's tensors only
        tensors = {k.removeprefix("autoencoder."): v for k, v in tensors.items() if k.startswith("autoencoder.")}
    state = {k: v.float() for k, v in tensors.items()}
    latent = state["encoder.{}.weight".format(max(int(k.split(".")[1]) for k in state if k.startswith("encoder.")
                                                  and k.endswith("weight") and state[k].ndim == 4))]
    cfg = get_config("tiny", latent_channels=int(latent.shape[0]), ae_width=int(state["encoder.0.weight"].shape[0]))
    ae = LatentAutoencoder(cfg)
    ae.load_state_dict(state)
    return ae.eval()


def frames_to_tensor(frames: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2).float().div_(255.0)


@torch.no_grad()
def psnr(ae: LatentAutoencoder, images: torch.Tensor) -> float:
    mse = torch.cat([((ae(x) - x) ** 2).flatten(1).mean(1) for x in images.split(64)])
    return float((10 * torch.log10(1.0 / mse.clamp_min(1e-10))).mean())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--candidate", action="append", required=True, metavar="NAME=PATH")
    parser.add_argument("--scenes", type=int, default=16)
    parser.add_argument("--out", type=Path, default=Path("bench/results/autoencoder.json"))
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    synth = []
    for seed in range(args.scenes):
        cap = generate_scene(seed, split="test", config=SynthConfig(num_cameras=10)).capture
        synth += [cap.frames[n] for n in sorted(cap.cameras)]
    synth_t = frames_to_tensor(np.concatenate(synth))
    sample = find_sample_capture()
    real_t = None
    if sample is not None:
        cap = import_caliscope(sample)
        real_t = frames_to_tensor(np.concatenate([cap.frames[n] for n in cap.camera_names]))
    rows = []
    for item in args.candidate:
        name, _, spec = item.partition("=")
        ae = load_candidate(spec)
        t0 = time.perf_counter()
        row = {"name": name, "path": spec, "latent_channels": ae.latent_mean.numel(),
               "parameters": sum(p.numel() for p in ae.parameters()),
               "synthetic_test_psnr_db": round(psnr(ae, synth_t), 3),
               "caliscope_psnr_db": None if real_t is None else round(psnr(ae, real_t), 3)}
        row["seconds"] = round(time.perf_counter() - t0, 1)
        rows.append(row)
        print(json.dumps(row))
    result = {"command": "python bench/bench_autoencoder.py " + " ".join(sys.argv[1:] if argv is None else argv),
              "synthetic_frames": int(synth_t.shape[0]), "caliscope_frames": 0 if real_t is None else int(real_t.shape[0]),
              "machine": platform.platform(), "rows": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
