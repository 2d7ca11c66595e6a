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
    with pytest.raises(ModelError, match="at least 1"):
        add_levels(_levels_model(2), [0.5])
    with pytest.raises(ModelError, match="wider dead zone"):
        add_levels(_levels_model(2), [1.0])


def test_a_level_at_the_coarsest_steps_with_a_wider_dead_zone():
    """add_levels at ratio 1 with rounding offsets: the coarsest steps again, written with a wider dead zone
    (fewer bytes); the existing levels keep their offsets."""
    base = _levels_model(2)
    old = VideoTok4D(dataclasses.replace(base.config, entropy_rounding=(0.45, 0.2, 0.45, 0.5, 0.5, 0.5)))
    old.load_state_dict(base.state_dict())
    new = add_levels(old, [1.0, 1.4], [(0.35, 0.2, 0.45), (0.45, 0.2, 0.45)])
    assert new.config.entropy_rounding == (0.45, 0.2, 0.45, 0.35, 0.2, 0.45, 0.45, 0.2, 0.45, 0.5, 0.5, 0.5)
    assert torch.equal(new.entropy.step_values()[1], old.entropy.step_values()[0])
    with pytest.raises(ModelError, match="wider dead zone"):
        add_levels(old, [1.0], [(0.45, 0.2, 0.45)])
    with pytest.raises(ModelError, match="triple"):
        add_levels(old, [1.0], [(0.35, 0.2)])


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


def test_finer_levels_are_appended_and_round_to_nearest():
    """add_finer_levels: new levels after the finest (steps = finest x ratio, finest last), every other weight and
    level kept, and a config with writer rounding offsets gets round-to-nearest for the new levels."""
    from vt4dcodec.model.train.add_levels import add_finer_levels

    old = _levels_model(2)
    old = VideoTok4D(dataclasses.replace(old.config, entropy_rounding=(0.45, 0.2, 0.45, 0.5, 0.5, 0.5)))
    old.load_state_dict(_levels_model(2).state_dict())
    with torch.no_grad():
        old.entropy.log_step.copy_(torch.tensor([0.6, 0.3]).log().view(2, 1, 1).expand_as(old.entropy.log_step))
    old.update_entropy()
    new = add_finer_levels(old, [0.3, 0.5])
    assert new.config.entropy_levels == 4
    assert new.config.entropy_rounding == (0.45, 0.2, 0.45) + (0.5,) * 9
    steps_old, steps_new = old.entropy.step_values(), new.entropy.step_values()
    assert torch.equal(steps_new[:2], steps_old)
    assert (steps_new[2] < steps_new[1]).all() and (steps_new[3] < steps_new[2]).all()
    assert torch.allclose(steps_new[2], steps_old[1] * 0.5, rtol=2e-3)  # float16-exact frozen steps
    for key, value in old.state_dict().items():
        if not key.startswith("entropy."):
            assert torch.equal(new.state_dict()[key], value), key
    for bad in ([1.0], [0.0], [1.5], []):
        with pytest.raises(ModelError, match="between 0 and 1"):
            add_finer_levels(old, bad)


def test_command_appends_finer_levels(tmp_path):
    from vt4dcodec.model import save_pretrained

    src = save_pretrained(_levels_model(2), tmp_path / "src", model_id="t", model_version="0")
    assert main(["--model", str(src), "--out", str(tmp_path / "out"), "--finer-ratios", "0.5", "--id", "t"]) == 0
    assert from_pretrained(tmp_path / "out").config.entropy_levels == 3


def test_entropy_from_a_donor_keeps_the_networks():
    """with_entropy_of: a model without an entropy model gets a donor's (levels, steps, densities), every network
    weight its own; a donor without one, or with other networks' config, is refused."""
    from vt4dcodec.model.train.add_levels import with_entropy_of

    torch.manual_seed(3)
    plain = VideoTok4D(get_config("tiny", patch_size=4)).eval()
    donor = _levels_model(2)
    out = with_entropy_of(plain, donor)
    assert out.config == donor.config
    for key, value in plain.state_dict().items():
        assert torch.equal(out.state_dict()[key], value), key
    assert torch.equal(out.entropy.log_step, donor.entropy.log_step)
    assert torch.equal(out.entropy.logits, donor.entropy.logits) and out.entropy.frozen
    with pytest.raises(ModelError, match="no entropy model"):
        with_entropy_of(donor, plain)
    other = VideoTok4D(get_config("tiny", patch_size=4, entropy_levels=2, n_static=32))
    with pytest.raises(ModelError, match="differs"):
        with_entropy_of(plain, other)


def test_an_entropy_model_keeps_the_network_digests_and_load_checks_them(tmp_path):
    """network_digests: a model given an entropy model has the config and weights digests of its networks
    alone, equal to the fingerprint of the model without it; save_pretrained records them as ``networks`` and
    from_pretrained recomputes and checks them (a tampered record is refused)."""
    import json

    from vt4dcodec.model import save_pretrained
    from vt4dcodec.model.directories import meta_networks, read_model_meta
    from vt4dcodec.model.identity import network_digests
    from vt4dcodec.model.train.add_levels import with_entropy_of

    torch.manual_seed(3)
    plain = VideoTok4D(get_config("tiny", patch_size=4)).eval()
    grown = with_entropy_of(plain, _levels_model(2))
    fp = plain.fingerprint("t", "1")
    assert network_digests(grown) == network_digests(plain) == (fp.config_sha256, fp.weights_sha256)
    assert grown.fingerprint("t", "2").weights_sha256 != fp.weights_sha256
    d = save_pretrained(grown, tmp_path / "g", model_id="t", model_version="2")
    meta = read_model_meta(d)
    assert meta_networks(meta) == network_digests(grown) == from_pretrained(d).network_digests
    p = save_pretrained(plain, tmp_path / "p", model_id="t", model_version="1")
    assert "networks" not in json.loads((p / "config.json").read_text())
    assert meta_networks(read_model_meta(p)) == (fp.config_sha256, fp.weights_sha256)
    raw = json.loads((d / "config.json").read_text())
    raw["networks"]["weights_sha256"] = "0" * 64
    (d / "config.json").write_text(json.dumps(raw))
    with pytest.raises(ModelError, match="networks"):
        from_pretrained(d)
