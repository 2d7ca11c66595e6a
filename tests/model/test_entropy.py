"""The learned entropy model (model/entropy.py): densities, the rate proxy against the real coder, frozen
tables that the format reads, and the torch-free table reader of model/tables.py."""

from __future__ import annotations

import functools

import numpy as np
import pytest
import torch

from vt4dcodec.errors import EntropyTablesError
from vt4dcodec.format import EntropyTables, dumps, loads
from vt4dcodec.format.learned import encode_learned_tokens
from vt4dcodec.model.configs import get_config
from vt4dcodec.model.entropy import (ALPHABET, CHANGE, MAX_VIEWS, MEAN, TokenEntropyModel, bin_probabilities,
                                     frequencies, symbol_count)
from vt4dcodec.model.tables import read_safetensors, tables_from_directory

# a miniature tokenizer with frame copies (80 static tokens on 16 cells: 5 copies a cell with one camera)
SMALL = dict(frames=4, image_size=32, width=32, heads=2, ae_width=8, spatial_layers=1, static_query_layers=1,
             track_layers=1, renderer_layers=1, n_static=80, n_dynamic=4, token_dim=8, n_tracks=8, patch_size=2,
             locality_sigma=0.35, query_from_grid=True, project_anchors=True, prediction="x0", anchor_views=True,
             token_splat=True, token_from_cell=True, frame_copies=True)


@pytest.mark.parametrize("step, cls", [(1.0, MEAN), (0.3, CHANGE), (1 / 32, MEAN), (1 / 32, CHANGE), (0.07, 2)])
def test_bin_probabilities_and_frequencies(step, cls):
    logits = np.random.default_rng(0).normal(0, 2, 256)
    p = bin_probabilities(logits, step, cls)
    assert len(p) == symbol_count(step, cls) <= ALPHABET and abs(p.sum() - 1) < 1e-9 and (p >= 0).all()
    f = frequencies(p)
    assert f.sum() == 1 << 14 and (f >= 1).all()


@functools.lru_cache(maxsize=1)
def fitted_model(d: int = 4, n_static: int = 10, levels: int = 3) -> TokenEntropyModel:
    """Densities fitted to tokens of known spread (one fit per test session; the tests do not change it)."""
    torch.manual_seed(0)
    model = TokenEntropyModel(levels, n_static, d)
    z_s = torch.tanh(torch.randn(32, n_static, d) * torch.linspace(0.1, 1.0, d))
    z_d = torch.tanh(torch.randn(32, 3, d) * 0.5)
    origin = torch.arange(n_static)
    origin[5:] = torch.arange(5, n_static) % 5
    return fit_densities(model, z_s, z_d, origin, 120)


def fit_densities(model: TokenEntropyModel, z_s: torch.Tensor, z_d: torch.Tensor, origin: torch.Tensor,
                  iterations: int) -> TokenEntropyModel:
    """Fit the densities alone (a level in turn each step), then freeze the tables."""
    opt = torch.optim.Adam([model.logits], lr=0.05)
    for it in range(iterations):
        loss = model.density_loss(z_s, z_d, origin, level=it % model.levels)
        opt.zero_grad()
        loss.backward()
        opt.step()
    model.update(torch.stack([origin] * MAX_VIEWS))
    return model


def test_rate_proxy_matches_the_coder():
    """The trained bits of noisy tokens predict what the integer tables really cost, within 10 %."""
    from vt4dcodec.format import ModelFingerprint

    model = fitted_model()
    assert model.frozen
    fp = ModelFingerprint("t", "1", "0" * 64, "1" * 64, (10, 4), (3, 4))
    tables = EntropyTables(model.steps.numpy(), model.freqs.numpy(), model.origins.numpy(), fp)
    torch.manual_seed(1)
    z_s = torch.tanh(torch.randn(100, 10, 4) * torch.linspace(0.1, 1.0, 4))
    z_d = torch.tanh(torch.randn(100, 3, 4) * 0.5)
    origin = torch.as_tensor(model.origins[0], dtype=torch.long)
    for level in range(model.levels):
        with torch.no_grad():
            proxy = float(model.noisy(z_s, z_d, level, origin)[2].sum()) / 8
        real = sum(len(encode_learned_tokens(z_s[i].numpy(), tables, level, 1, "static"))
                   + len(encode_learned_tokens(z_d[i].numpy(), tables, level, 1, "dynamic")) - 12 for i in range(100))
        assert abs(real - proxy) < 0.1 * real + 100, (level, real, proxy)


def test_finer_levels_cost_more_bits():
    model = fitted_model()
    z_s = torch.tanh(torch.randn(32, 10, 4))
    z_d = torch.tanh(torch.randn(32, 3, 4))
    origin = torch.as_tensor(model.origins[0], dtype=torch.long)
    with torch.no_grad():
        bits = [float(model.noisy(z_s, z_d, level, origin)[2].mean()) for level in range(model.levels)]
    assert bits == sorted(bits)


def test_rate_gradient_reaches_tokens_and_steps():
    model = fitted_model()
    z_s = torch.tanh(torch.randn(4, 10, 4)).requires_grad_()
    z_d = torch.tanh(torch.randn(4, 3, 4)).requires_grad_()
    origin = torch.as_tensor(model.origins[0], dtype=torch.long)
    model.zero_grad()
    model.noisy(z_s, z_d, 1, origin)[2].sum().backward()
    assert z_s.grad.abs().sum() > 0 and z_d.grad.abs().sum() > 0 and model.log_step.grad[1].abs().sum() > 0
    model.zero_grad()


def test_saved_model_tables_read_without_torch(tmp_path):
    """A model with entropy levels, saved and frozen: the torch-free reader gives the module's tables, checks
    them against weights_sha256, and a scene written with them loads back."""
    from vt4dcodec.model import VideoTok4D
    from vt4dcodec.model.weights_io import save_pretrained

    cfg = get_config("tiny", **SMALL, entropy_levels=3)
    model = VideoTok4D(cfg)
    model.update_entropy()
    directory = save_pretrained(model, tmp_path / "m", model_id="vt4d-entropy-test", model_version="0.0.1")
    tables = tables_from_directory(directory)
    assert np.array_equal(tables.freqs, model.entropy.freqs.numpy()) and tables.levels == 3
    assert np.array_equal(tables.steps, model.entropy.steps.numpy())
    assert np.array_equal(tables.origins[0], model.static_origins(1).numpy())
    assert (tables.origins[0] != np.arange(80)).sum() == 64  # one camera: 4 frame copies of each of 16 cells
    weights = directory / "model.safetensors"
    raw = bytearray(weights.read_bytes())
    raw[-1] ^= 1  # one weight changed: the tables can no longer be trusted to be the fingerprint's model's
    weights.write_bytes(bytes(raw))
    with pytest.raises(EntropyTablesError, match="weights_sha256"):
        tables_from_directory(directory)
    assert read_safetensors(weights)["entropy.freqs"].dtype == np.int16


def test_model_tables_code_a_scene(tmp_path):
    from vt4dcodec.cameras import Trajectory
    from vt4dcodec.format import Scene
    from vt4dcodec.model import VideoTok4D
    from vt4dcodec.model.weights_io import save_pretrained

    cfg = get_config("tiny", **SMALL, entropy_levels=2)
    model = VideoTok4D(cfg)
    model.update_entropy()
    directory = save_pretrained(model, tmp_path / "m", model_id="vt4d-entropy-test", model_version="0.0.2")
    tables = tables_from_directory(directory)
    z_s, z_d = (np.tanh(np.random.default_rng(0).normal(0, 0.5, shape)).astype(np.float32)
                for shape in (cfg.static_shape, cfg.dynamic_shape))
    K = np.tile(np.array([[50.0, 0, 16], [0, 50.0, 16], [0, 0, 1]]), (cfg.frames, 1, 1))
    w2c = np.tile(np.eye(4), (cfg.frames, 1, 1))
    scene = Scene(z_s, z_d, Trajectory(K=K, w2c=w2c, width=32, height=32), tables.fingerprint,
                  encoding="learned-rans", quality=2)
    back = loads(dumps(scene, tables=tables), tables=tables)
    assert np.abs(back.static_tokens - z_s).max() <= tables.steps[1, 0].max() / 2 + 1e-6


def correlated_tokens(n: int, n_static: int, d: int, seed: int) -> torch.Tensor:
    """Static tokens whose signs run in streaks along the token index (neighbouring cells agree)."""
    g = torch.Generator().manual_seed(seed)
    sign = torch.where(torch.rand(n, 1, d, generator=g) < 0.5, -1.0, 1.0)
    flips = torch.where(torch.rand(n, n_static, d, generator=g) < 0.05, -1.0, 1.0).cumprod(dim=1)
    return torch.tanh(sign * flips * (0.4 + 0.4 * torch.rand(n, n_static, d, generator=g)))


def test_context_coded_mean_tokens_proxy_matches_the_coder_and_costs_less():
    """With 5 classes (config.entropy_context) the rate proxy still predicts the coder within 10 %, and tokens
    whose signs run in streaks cost less than with one MEAN density per channel (3 classes)."""
    from vt4dcodec.format import ModelFingerprint

    d, n_static, levels = 4, 12, 2
    origin = torch.arange(n_static)
    z_s, z_d = correlated_tokens(64, n_static, d, 0), torch.tanh(torch.randn(64, 2, d) * 0.5)
    test_s = correlated_tokens(100, n_static, d, 1)
    fp = ModelFingerprint("t", "1", "0" * 64, "1" * 64, (n_static, d), (2, d))
    static = {}
    for classes in (3, 5):
        torch.manual_seed(0)
        model = fit_densities(TokenEntropyModel(levels, n_static, d, classes=classes), z_s, z_d, origin, 160)
        tables = EntropyTables(model.steps.numpy(), model.freqs.numpy(), model.origins.numpy(), fp)
        assert tables.contextual == (classes == 5)
        level = levels - 1
        with torch.no_grad():
            proxy = float(model.noisy(test_s, torch.zeros(100, 2, d), level, origin)[2].sum()) / 8
        static[classes] = sum(len(encode_learned_tokens(test_s[i].numpy(), tables, level, 1, "static")) - 6
                              for i in range(100))
        dynamic = sum(len(encode_learned_tokens(np.zeros((2, d), np.float32), tables, level, 1, "dynamic")) - 6
                      for i in range(100))
        real = static[classes] + dynamic
        assert abs(real - proxy) < 0.1 * real + 100, (classes, real, proxy)
    assert static[5] < 0.9 * static[3], static


def test_rounding_offsets_ship_in_the_config_and_reach_both_table_readers(tmp_path):
    """config.entropy_rounding: validated, left out of the canonical config when empty (old fingerprints
    stay), and handed to the writer by the torch and the torch-free table readers alike."""
    from vt4dcodec import codec
    from vt4dcodec.errors import ModelError
    from vt4dcodec.model import VideoTok4D
    from vt4dcodec.model.weights_io import save_pretrained

    plain = get_config("tiny", **SMALL, entropy_levels=2)
    assert "entropy_rounding" not in plain.canonical_json()
    for bad in ([0.5] * 5, [0.5] * 5 + [0.6], [0.5] * 5 + [-0.1], [True] * 6, "0.5"):
        with pytest.raises(ModelError, match="entropy_rounding"):
            get_config("tiny", **SMALL, entropy_levels=2, entropy_rounding=bad)
    cfg = get_config("tiny", **SMALL, entropy_levels=2, entropy_rounding=[0.5, 0.2, 0.45, 0.5, 0.5, 0.5])
    assert cfg.entropy_rounding == (0.5, 0.2, 0.45, 0.5, 0.5, 0.5) and cfg.sha256() != plain.sha256()
    assert type(cfg).from_dict(cfg.to_dict()) == cfg  # a JSON list reads back as the tuple
    model = VideoTok4D(cfg)
    model.update_entropy()
    directory = save_pretrained(model, tmp_path / "m", model_id="vt4d-entropy-test", model_version="0.0.3")
    want = np.array([[0.5, 0.2, 0.45], [0.5, 0.5, 0.5]])
    assert np.array_equal(tables_from_directory(directory).rounding, want)
    assert np.array_equal(codec.model_tables(model).rounding, want)
    model_plain = VideoTok4D(plain)
    model_plain.update_entropy()
    assert codec.model_tables(model_plain).rounding is None


def test_quantized_tokens_are_the_stored_values_with_a_straight_through_gradient():
    """noisy(..., quantized=True): the renderer's tokens are exactly what a file stores at the level (the format's
    quantizer), the gradient passes to the tokens unchanged, and the rate is the noisy proxy's as before."""
    model = fitted_model()
    origin = torch.as_tensor(model.origins[0], dtype=torch.long)
    z_s = torch.tanh(torch.randn(2, 10, 4) * 2).requires_grad_()
    z_d = torch.tanh(torch.randn(2, 3, 4) * 2).requires_grad_()
    from vt4dcodec.format import ModelFingerprint
    from vt4dcodec.format.learned import dequantize, quantize

    trained_steps = torch.stack([model.step(level) for level in range(model.levels)]).detach().numpy()
    tables = EntropyTables(trained_steps, model.freqs.numpy(), model.origins.numpy(),  # training's own steps
                           ModelFingerprint("t", "1", "0" * 64, "1" * 64, (10, 4), (3, 4)))
    for level in range(model.levels):
        torch.manual_seed(1)
        q_s, q_d, bits = model.noisy(z_s, z_d, level, origin, quantized=True)
        torch.manual_seed(1)
        bits_noisy = model.noisy(z_s, z_d, level, origin)[2]
        assert torch.equal(bits, bits_noisy)
        for got, z, which in ((q_s, z_s, "static"), (q_d, z_d, "dynamic")):
            for s in range(2):
                x = z[s].detach().numpy()
                want = dequantize(quantize(x, tables, level, which), tables, level, which)
                assert np.allclose(got[s].detach().numpy(), want, atol=1e-6)
        grad = torch.autograd.grad((q_s * 3).sum() + q_d.sum(), (z_s, z_d))
        assert torch.equal(grad[0], torch.full_like(z_s, 3.0)) and torch.equal(grad[1], torch.ones_like(z_d))


def partnered_tokens(n: int, n_static: int, d: int, seed: int) -> torch.Tensor:
    """Static tokens whose channel 1 and 3 carry channel 0's sign (a token's channels move together), with no
    streaks along the token index."""
    g = torch.Generator().manual_seed(seed)
    z = torch.randn(n, n_static, d, generator=g) * 0.5
    z[..., 1] = z[..., 0].sign() * (0.3 + 0.4 * torch.rand(n, n_static, generator=g))
    z[..., 3] = -z[..., 0].sign() * (0.3 + 0.4 * torch.rand(n, n_static, generator=g))
    return torch.tanh(z)


def test_partner_channels_proxy_matches_the_coder_and_costs_less():
    """With 11 classes (config.entropy_partners) the rate proxy still predicts the coder within 10 %, the C and
    the pure-Python decoders give the writer's codes back, and tokens whose channels move together cost less
    than with the previous-token context alone (5 classes)."""
    from vt4dcodec.format import ModelFingerprint, rans
    from vt4dcodec.format.learned import decode_learned_tokens, writer_codes, dequantize

    d, n_static, levels = 4, 12, 2
    origin = torch.arange(n_static)
    z_s, z_d = partnered_tokens(64, n_static, d, 0), torch.tanh(torch.randn(64, 2, d) * 0.5)
    test_s = partnered_tokens(60, n_static, d, 1)
    fp = ModelFingerprint("t", "1", "0" * 64, "1" * 64, (n_static, d), (2, d))
    static = {}
    for classes, partners in ((5, None), (11, (-1, 0, -1, 0))):
        torch.manual_seed(0)
        model = fit_densities(TokenEntropyModel(levels, n_static, d, classes=classes, partners=partners),
                              z_s, z_d, origin, 160)
        tables = EntropyTables(model.steps.numpy(), model.freqs.numpy(), model.origins.numpy(), fp,
                               partners=None if partners is None else model.partners.numpy())
        level = levels - 1
        with torch.no_grad():
            proxy = float(model.noisy(test_s, torch.zeros(60, 2, d), level, origin)[2].sum()) / 8
        payloads = [encode_learned_tokens(test_s[i].numpy(), tables, level, 1, "static") for i in range(60)]
        static[classes] = sum(len(p) - 6 for p in payloads)
        real = static[classes] + sum(len(encode_learned_tokens(np.zeros((2, d), np.float32), tables, level, 1,
                                                               "dynamic")) - 6 for _ in range(60))
        assert abs(real - proxy) < 0.1 * real + 100, (classes, real, proxy)
        for i in (0, 1):
            want = dequantize(writer_codes(test_s[i].numpy(), tables, level, "static", 1), tables, level, "static")
            assert np.array_equal(decode_learned_tokens(payloads[i], tables, n_static, d, "static", 1)[0], want)
            native = rans.NATIVE
            try:
                rans.NATIVE = False  # the pure-Python reference decoder
                assert np.array_equal(decode_learned_tokens(payloads[i], tables, n_static, d, "static", 1)[0], want)
            finally:
                rans.NATIVE = native
    assert static[11] < 0.95 * static[5], static  # 9 % less: channels 1 and 3 carry channel 0's sign only


def test_partner_config_is_checked_and_the_partners_ship_in_the_weights(tmp_path):
    """config.entropy_partners: validated (only with entropy_context, one earlier channel or -1 a channel), left
    out of the canonical config when empty, and read back by the torch-free table reader as the module's."""
    from vt4dcodec import codec
    from vt4dcodec.errors import ModelError
    from vt4dcodec.model import VideoTok4D
    from vt4dcodec.model.weights_io import save_pretrained

    plain = get_config("tiny", **SMALL, entropy_levels=2, entropy_context=True)
    assert "entropy_partners" not in plain.canonical_json()
    good = [-1, 0, 0, 1, -1, 3, 2, 6]
    for bad in ([-1] * 7, [0] + [-1] * 7, [-1, 1] + [-1] * 6, [-1, -2] + [-1] * 6, [-1, True] + [-1] * 6, "x"):
        with pytest.raises(ModelError, match="entropy_partners"):
            get_config("tiny", **SMALL, entropy_levels=2, entropy_context=True, entropy_partners=bad)
    with pytest.raises(ModelError, match="entropy_partners"):
        get_config("tiny", **SMALL, entropy_levels=2, entropy_partners=good)  # needs entropy_context
    cfg = get_config("tiny", **SMALL, entropy_levels=2, entropy_context=True, entropy_partners=good)
    assert type(cfg).from_dict(cfg.to_dict()) == cfg and cfg.sha256() != plain.sha256()
    model = VideoTok4D(cfg)
    model.update_entropy()
    assert model.entropy.freqs.shape[1] == 11
    directory = save_pretrained(model, tmp_path / "m", model_id="vt4d-entropy-test", model_version="0.0.4")
    tables = tables_from_directory(directory)
    assert tables.partners.tolist() == good == codec.model_tables(model).partners.tolist()
    assert np.array_equal(tables.freqs, model.entropy.freqs.numpy())
    with pytest.raises(EntropyTablesError, match="partners"):
        EntropyTables(tables.steps, tables.freqs[:, :5], tables.origins, tables.fingerprint, partners=tables.partners)
    with pytest.raises(EntropyTablesError, match="partners"):
        EntropyTables(tables.steps, tables.freqs, tables.origins, tables.fingerprint)
    with pytest.raises(EntropyTablesError, match="partners"):
        EntropyTables(tables.steps, tables.freqs, tables.origins, tables.fingerprint, partners=[-1, 1] + [-1] * 6)
