"""Fixtures for codec tests: a small randomly initialised model saved as a user model directory.

The codec's contract (fingerprints, determinism, errors, clip fitting) does not depend on trained
weights, so these tests use a reduced config that runs fast; the shipped weights are exercised in
test_shipped.py.
"""

import pytest
import torch

from vt4dcodec.synth import SynthConfig, generate_scene


@pytest.fixture(scope="session")
def small_config():
    from vt4dcodec.model import get_config

    return get_config("tiny", width=64, heads=2, renderer_layers=1, spatial_layers=1, static_query_layers=1,
                      track_layers=1, dynamic_spatial_layers=1, n_tracks=16)


def _save_model(directory, config, seed, model_id):
    from vt4dcodec.model import VideoTok4D, save_pretrained

    torch.manual_seed(seed)
    return save_pretrained(VideoTok4D(config), directory / model_id, model_id=model_id, model_version="0.0")


@pytest.fixture(scope="session")
def model_dir(tmp_path_factory, small_config):
    return _save_model(tmp_path_factory.mktemp("models"), small_config, 0, "test-model")


@pytest.fixture(scope="session")
def other_model_dir(tmp_path_factory, small_config):
    """Same config and id, different weights: a different fingerprint."""
    return _save_model(tmp_path_factory.mktemp("models_other"), small_config, 1, "test-model")


@pytest.fixture(scope="session")
def synth_scene():
    return generate_scene(7, split="test", config=SynthConfig(num_cameras=3))


@pytest.fixture(scope="session")
def encoded(synth_scene, model_dir):
    from vt4dcodec import codec

    return codec.encode(synth_scene.capture, model=model_dir, seed=0)
