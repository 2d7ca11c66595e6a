"""add_levels: coarser quality levels prepended to a trained entropy model, everything else kept."""

import dataclasses

import pytest
import torch

from vt4dcodec.errors import ModelError
from vt4dcodec.model import VideoTok4D, from_pretrained, get_config
from vt4dcodec.model.train.add_levels import add_levels, main


def _levels_model(levels: int) -> VideoTok4D:
    torch.manual_seed(0)
    return VideoTok4D(get_config("tiny", patch_size=4, entropy_levels=levels)).eval()


def test_new_levels_are_coarser_and_the_old_ones_and_densities_are_kept():
    old = _levels_model(2)
    new = add_levels(old, [1.4, 2.0])
    assert new.config == dataclasses.replace(old.config, entropy_levels=4)
    steps_old, steps_new = old.entropy.step_values(), new.entropy.step_values()
    assert torch.equal(steps_new[2:], steps_old)
    assert (steps_new[0] >= steps_new[1]).all() and (steps_new[1] > steps_new[2]).all()
    assert torch.equal(new.entropy.logits, old.entropy.logits)
    assert new.entropy.frozen and new.entropy.freqs.shape[0] == 4
    for key, value in old.state_dict().items():
        if not key.startswith("entropy."):
            assert torch.equal(new.state_dict()[key], value), key


def test_refusals():
    with pytest.raises(ModelError, match="entropy"):
        add_levels(VideoTok4D(get_config("tiny", patch_size=4)), [2.0])
    with pytest.raises(ModelError, match="above 1"):
        add_levels(_levels_model(2), [0.5])


def test_command_writes_a_loadable_model(tmp_path):
    from vt4dcodec.model import save_pretrained

    src = save_pretrained(_levels_model(2), tmp_path / "src", model_id="t", model_version="0")
    assert main(["--model", str(src), "--out", str(tmp_path / "out"), "--ratios", "2", "--id", "t"]) == 0
    assert from_pretrained(tmp_path / "out").config.entropy_levels == 3


def test_mean_context_starts_as_the_model_it_came_from():
    """add_mean_context: the two new density classes copy MEAN's, so the model codes every scene exactly as
    before (same bytes) until its densities are fitted again; a second call is refused."""
    from vt4dcodec.model.train.add_levels import add_mean_context

    model = _levels_model(2)
    model.update_entropy()
    out = add_mean_context(model)
    assert out.config.entropy_context and out.entropy.freqs.shape[1] == 5
    assert torch.equal(out.entropy.freqs[:, :3], model.entropy.freqs)
    assert torch.equal(out.entropy.freqs[:, 3], model.entropy.freqs[:, 0])
    with pytest.raises(ModelError, match="already"):
        add_mean_context(out)
