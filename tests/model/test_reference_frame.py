"""ModelConfig.reference_frame: the world frame the training pairs are in is the one the codec encodes in."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vt4dcodec.errors import ModelError
from vt4dcodec.model import get_config
from vt4dcodec.model.train import data
from vt4dcodec.reference import model_centre


def test_the_default_frame_keeps_every_config_hash_and_a_bad_one_is_refused():
    assert get_config("tiny").sha256() == get_config("tiny", reference_frame="origin").sha256()
    assert get_config("tiny", reference_frame="cameras").sha256() != get_config("tiny").sha256()
    with pytest.raises(ModelError, match="reference_frame"):
        get_config("tiny", reference_frame="floor")


@pytest.mark.parametrize("frame", ["origin", "cameras"])
def test_pairs_are_in_the_frame_the_codec_encodes_in(tmp_path, frame):
    pool = data.ScenePool(tmp_path, cameras=3, frames=8, image_size=64, latent_size=16, n_tracks=8)
    pairs = data.PairDataset(pool, [5], recon_share=0.0, neighbour_sigma_deg=45.0, reference_frame=frame)
    torch.manual_seed(0)
    source, _, _, w2c_tgt = pairs[0]
    scene = pool.scene(5)
    centre = model_centre(frame, scene["w2c"][[0]])
    assert (centre is None) == (frame == "origin")  # a synthetic rig's origin is in front of its cameras
    shift = np.zeros(3) if centre is None else centre
    tgt = int(np.argmin([np.abs(w2c_tgt - scene["w2c"][c] @ _translation(shift)).max() for c in range(3)]))
    np.testing.assert_allclose(w2c_tgt, scene["w2c"][tgt] @ _translation(shift), atol=1e-9)
    np.testing.assert_allclose(source.w2c, (scene["w2c"][0] @ _translation(shift)).astype(np.float32), atol=1e-5)


def _translation(point: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = point
    return T
