"""partner_context: partner channels added to a context-coded entropy model, their choice and density fit."""

import numpy as np
import pytest
import torch

from vt4dcodec.errors import ModelError
from vt4dcodec.model import VideoTok4D, get_config
from vt4dcodec.model.entropy import CHANGE, DYNAMIC
from vt4dcodec.model.train.partner_context import add_partner_context, choose_partners, fit_mean_densities


def _context_model() -> VideoTok4D:
    torch.manual_seed(0)
    model = VideoTok4D(get_config("tiny", patch_size=4, entropy_levels=2, entropy_context=True)).eval()
    model.update_entropy()
    return model


def test_choose_partners_finds_the_channel_that_moves_along():
    rng = np.random.default_rng(0)
    q = rng.integers(-1, 2, (4000, 4))
    q[:, 2] = -q[:, 0]  # channel 2 mirrors channel 0
    q[:, 3] = np.where(rng.random(4000) < 0.9, q[:, 1], 0)  # channel 3 mostly follows channel 1
    partners = choose_partners([q], [np.zeros_like(q)])
    assert partners == (-1, -1, 0, 1)  # channel 1 gains nothing from channel 0: none


def test_partner_model_codes_as_before_until_fitted():
    """The six new classes copy the MEAN family's densities of the same previous-token sign, so every token set
    costs the same bytes as with the model it came from; a second call, and a model without context, are refused."""
    from vt4dcodec import codec
    from vt4dcodec.format.learned import encode_learned_tokens

    model = _context_model()
    d = model.config.token_dim
    out = add_partner_context(model, tuple([-1] + list(range(d - 1))))
    assert out.entropy.freqs.shape[1] == 11 and out.config.entropy_partners == tuple([-1] + list(range(d - 1)))
    old, new = codec.model_tables(model), codec.model_tables(out)
    rng = np.random.default_rng(1)
    for views in (1, 5):
        z = np.tanh(rng.normal(0, 0.6, model.config.static_shape)).astype(np.float32)
        for level in (0, 1):
            assert encode_learned_tokens(z, old, level, views, "static") == \
                encode_learned_tokens(z, new, level, views, "static")
    with pytest.raises(ModelError, match="already"):
        add_partner_context(out, out.config.entropy_partners)
    plain = VideoTok4D(get_config("tiny", patch_size=4, entropy_levels=2))
    with pytest.raises(ModelError, match="entropy_context"):
        add_partner_context(plain, tuple([-1] * d))


def test_fit_moves_only_the_mean_family():
    model = _context_model()
    d = model.config.token_dim
    out = add_partner_context(model, tuple([-1] + list(range(d - 1))))
    before = out.entropy.logits.detach().clone()
    zs = torch.tanh(torch.randn(1, model.config.n_static, d))
    zs[..., 1] = zs[..., 0]
    zd = torch.tanh(torch.randn(1, model.config.n_dynamic, d))
    fit = fit_mean_densities(out, [(zs, zd, out.static_origins(1))], iterations=30)
    after = out.entropy.logits.detach()
    assert torch.equal(after[CHANGE], before[CHANGE]) and torch.equal(after[DYNAMIC], before[DYNAMIC])
    assert not torch.equal(after[5:], before[5:])
    assert fit["bits_per_value_after"] < fit["bits_per_value_before"]


def test_command_writes_a_model_whose_files_load(tmp_path):
    """The command end to end on two small synthetic captures: a saved model of 11 classes with its partners,
    whose learned-rans files decode to the writer's codes; a capture of the wrong size is a clear error."""
    import json

    from vt4dcodec import codec
    from vt4dcodec.format import dumps, loads
    from vt4dcodec.model import from_pretrained, save_pretrained
    from vt4dcodec.model.train.partner_context import main
    from vt4dcodec.synth import SynthConfig, write_dataset

    torch.manual_seed(0)
    cfg = get_config("tiny", patch_size=4, frames=4, image_size=32, entropy_levels=2, entropy_context=True)
    src = save_pretrained(VideoTok4D(cfg).eval(), tmp_path / "src", model_id="t", model_version="0")
    write_dataset(tmp_path / "caps", num_scenes=2, split="train", seed=0, workers=1,
                  config=SynthConfig(num_cameras=3, num_frames=4, height=32, width=32))
    out = tmp_path / "out"
    assert main(["--model", str(src), "--captures", str(tmp_path / "caps"), "--out", str(out), "--views", "1,3",
                 "--iterations", "5", "--version", "1", "--id", "t"]) == 0
    model = from_pretrained(out)
    report = json.loads((out / "partner_context.json").read_text())
    assert list(model.config.entropy_partners) == report["partners"] and report["token_sets"] == 4
    assert model.entropy.freqs.shape[1] == 11
    scene = codec.encode(tmp_path / "caps" / "train-000000", model, cameras="all", quality=1)
    tables = codec.model_tables(model)
    assert np.abs(loads(dumps(scene), tables=tables).static_tokens - scene.static_tokens).max() \
        <= tables.steps[0, 0].max() / 2 + 1e-6
    write_dataset(tmp_path / "big", num_scenes=1, split="train", seed=0, workers=1,
                  config=SynthConfig(num_cameras=3, num_frames=4, height=48, width=48))
    assert main(["--model", str(src), "--captures", str(tmp_path / "big"), "--out", str(tmp_path / "x"),
                 "--version", "1"]) == 2
