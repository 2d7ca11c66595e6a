"""Random tiny token models for the evaluation tests (a module of its own: test directories share the name
``conftest``, so helpers imported by tests must live in a uniquely named module)."""

from __future__ import annotations

import torch

from vt4dcodec.model import VideoTok4D, get_config, save_pretrained


def random_model(path, seed: int, **overrides) -> str:
    torch.manual_seed(seed)
    net = VideoTok4D(get_config("tiny", patch_size=4, **overrides)).eval()
    with torch.no_grad():  # the renderer's zero-initialised output would ignore the tokens
        for p in net.renderer.parameters():
            p.add_(0.05 * torch.randn_like(p))
    save_pretrained(net, path, model_id=f"test-eval-{seed}", model_version="0")
    return str(path)
