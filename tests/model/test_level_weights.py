"""Rate-distortion training draws each batch's quality level uniformly or by --level-weights."""

from types import SimpleNamespace

import pytest
import torch

from vt4dcodec.model.train.tokenizer import flow_step, main


def _levels(n: int, **kw) -> list[int]:
    seen = []

    def module(*args, **kwargs):
        seen.append((kwargs["rate_level"], kwargs["rate_lambda"]))
        return torch.zeros(()), {}

    batch = SimpleNamespace(target_frames=torch.zeros(2, 1), source=None, K_tgt=None, w2c_tgt=None, target_latents=None)
    torch.manual_seed(0)
    for _ in range(n):
        flow_step(module, batch, rate_lambdas=(4.0, 1.0, 0.0), **kw)
    return seen


def test_weights_choose_how_often_each_level_is_drawn():
    assert {lv for lv, _ in _levels(30)} == {0, 1, 2}  # uniform by default
    assert set(_levels(30, level_weights=(0.0, 0.0, 1.0))) == {(2, 0.0)}
    drawn = [lv for lv, _ in _levels(400, level_weights=(1.0, 0.0, 3.0))]
    assert 1 not in drawn and 0.6 < drawn.count(2) / len(drawn) < 0.9


@pytest.mark.parametrize("weights", ["1,1", "1,-1,1", "0,0,0", "a,b,c"])
def test_bad_weights_are_usage_errors(weights, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--out", str(tmp_path / "run"), "--steps", "1", "--rate-lambdas", "4,1,0", "--level-weights", weights,
              "--set", "entropy_levels=3"])
    assert exc.value.code == 2 and "--level-weights" in capsys.readouterr().err
