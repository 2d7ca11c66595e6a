"""Session fixtures of the Co4DGen tests (helpers and sizes live in co4dgen_helpers.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from co4dgen_helpers import CAMERAS, EVENTS, SMALL_PRIOR, SMALL_TOKENIZER
from vt4dcodec.model import VideoTok4D, get_config, save_pretrained

torch.set_num_threads(1)  # 2 shared cores: more threads only contend


@pytest.fixture(scope="session")
def tokenizer_dir(tmp_path_factory) -> Path:
    """A random small tokenizer saved as model directory ``<tmp>/models/tok-test`` (so
    $VT4D_MODEL_PATH=<tmp>/models finds it by its id)."""
    torch.manual_seed(0)
    model = VideoTok4D(get_config("tiny", **SMALL_TOKENIZER))
    return save_pretrained(model, tmp_path_factory.mktemp("models") / "tok-test", model_id="tok-test",
                           model_version="0")


@pytest.fixture(scope="session")
def shards(tmp_path_factory, tokenizer_dir) -> Path:
    from vt4dcodec.model import from_pretrained
    from vt4dcodec.model.train.data import ScenePool
    from vt4dcodec.model.train.tokenize_scenes import write_shards

    tok = from_pretrained(tokenizer_dir)
    tok.set_identity("tok-test", "0")
    root = tmp_path_factory.mktemp("co4dgen")
    pool = ScenePool.for_config(tok.config, root / "cache", CAMERAS)
    write_shards(tok, pool, list(range(EVENTS)), root / "shards", per_shard=1, encoding="float16")
    return root / "shards"


@pytest.fixture(scope="session")
def trained_prior(tmp_path_factory, shards) -> Path:
    """Run the real training entry point for a few steps; returns the saved prior directory."""
    from vt4dcodec.model.train.prior import main

    out = tmp_path_factory.mktemp("prior_run")
    overrides = [f"{k}={v}" for k, v in SMALL_PRIOR.items() if k not in ("n_static", "n_dynamic", "token_dim",
                                                                      "frames", "image_size")]
    assert main(["--shards", str(shards), "--out", str(out), "--steps", "6", "--batch-size", "4", "--warmup", "2",
                 "--log-every", "2", "--ckpt-every", "3", "--no-progress", "--set", *overrides]) == 0
    return out
