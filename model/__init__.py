"""vt4dcodec.model: the VideoTok4D networks (imports torch; never imported by the container code).

    from vt4dcodec.model import ModelConfig, get_config, VideoTok4D, from_pretrained, save_pretrained
"""

from .configs import CONFIG_NAMES, PRIOR_CONFIG_NAMES, ModelConfig, PriorConfig, get_config, get_prior_config
from .inputs.source_inputs import SourceBatch, SourceInputs
from .videotok4d import VideoTok4D
from .weights_io import from_pretrained, save_pretrained, shipped_model_ids

__all__ = [
    "ModelConfig", "get_config", "CONFIG_NAMES", "VideoTok4D", "from_pretrained", "save_pretrained",
    "shipped_model_ids", "SourceInputs", "SourceBatch", "PriorConfig", "get_prior_config", "PRIOR_CONFIG_NAMES",
]
