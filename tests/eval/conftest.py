"""Fixtures of the evaluation tests: two random tiny models (main and unified) and one run of the
evaluation command on them (2 scenes, all three target sets), shared by the test modules."""

from __future__ import annotations

import json

import pytest
import torch

from vt4dcodec.eval.command import main
from eval_models import random_model as _random_model


@pytest.fixture(scope="session")
def models(tmp_path_factory):
    root = tmp_path_factory.mktemp("eval_models")
    return _random_model(root / "main", 0), _random_model(root / "unified", 1, unified_tokens=True)


@pytest.fixture(scope="session")
def evaluated(models, tmp_path_factory):
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("eval_out")
    args = ["--model", models[0], "--unified", models[1], "--scenes", "2", "--views", "2", "--steps", "2",
            "--out", str(out / "eval.json"), "--figure", str(out / "eval.png"), "--figure-scenes", "1",
            "--no-progress"]
    assert main(args) == 0
    return json.loads((out / "eval.json").read_text()), out
