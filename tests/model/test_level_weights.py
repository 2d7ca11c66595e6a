"""Rate-distortion training draws each batch's quality level uniformly or by --level-weights."""

from types import SimpleNamespace

import pytest
import torch

from vt4dcodec.model.train.tokenizer import flow_step, main


quantized: list[bool] = []


def _levels(n: int, **kw) -> list[int]:
    seen = []
    quantized.clear()

    def module(*args, **kwargs):
        seen.append((kwargs["rate_level"], kwargs["rate_lambda"]))
        quantized.append(kwargs["rate_quantized"])
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


def test_quantized_share_chooses_how_often_the_renderer_reads_stored_values():
    _levels(20)
    assert not any(quantized)  # noisy tokens by default
    _levels(20, quantized_share=1.0)
    assert all(quantized)
    _levels(400, quantized_share=0.5)
    assert 0.35 < sum(quantized) / len(quantized) < 0.65


@pytest.mark.parametrize("share", ["-0.1", "1.5"])
def test_a_share_outside_0_1_is_a_usage_error(share, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--out", str(tmp_path / "run"), "--steps", "1", "--rate-lambdas", "4,1,0", "--quantized-share", share,
              "--set", "entropy_levels=3"])
    assert exc.value.code == 2 and "--quantized-share" in capsys.readouterr().err
