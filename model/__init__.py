"""vt4dcodec.model: the VideoTok4D networks (never imported by the container code).

    from vt4dcodec.model import ModelConfig, get_config, VideoTok4D, from_pretrained, save_pretrained

The names load lazily (PEP 562), so the torch-free parts -- ``configs``, ``directories``, ``inputs`` and
``onnx_encoder``, which encodes with an exported encoder on onnxruntime -- import without torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .configs import CONFIG_NAMES, PRIOR_CONFIG_NAMES, ModelConfig, PriorConfig, get_config, get_prior_config
    from .inputs.source_inputs import SourceBatch, SourceInputs
    from .videotok4d import VideoTok4D
    from .weights_io import from_pretrained, save_pretrained, shipped_model_ids

_WHERE = {
    "ModelConfig": "configs", "get_config": "configs", "CONFIG_NAMES": "configs", "PriorConfig": "configs",
    "get_prior_config": "configs", "PRIOR_CONFIG_NAMES": "configs",
    "SourceInputs": "inputs.source_inputs", "SourceBatch": "inputs.source_inputs",
    "VideoTok4D": "videotok4d",
    "from_pretrained": "weights_io", "save_pretrained": "weights_io", "shipped_model_ids": "directories",
}

__all__ = [
    "ModelConfig", "get_config", "CONFIG_NAMES", "VideoTok4D", "from_pretrained", "save_pretrained",
    "shipped_model_ids", "SourceInputs", "SourceBatch", "PriorConfig", "get_prior_config", "PRIOR_CONFIG_NAMES",
]


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
