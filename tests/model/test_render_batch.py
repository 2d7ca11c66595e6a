"""Batched rendering gives each view what it gets alone (issue 51.2): the shipped model, a batch of views.

render_many renders views of one scene in one forward pass; the renderer's batch-wide pieces (the
splat's separable sums, the frozen decoder) run one item at a time to keep their intermediates small,
and its Gaussian weights skip exp's slow path below EXP_MIN. None of that may change a view.
"""

import pytest
import torch
from network_fixtures import orbit_cameras

from vt4dcodec.model.renderer import EXP_MIN, _exp, _splat_sum


def test_exp_is_torch_exp_above_the_floor_and_zero_below():
    x = torch.cat([torch.linspace(-200.0, 5.0, 4001), torch.tensor([EXP_MIN, EXP_MIN - 1e-3, -1e4, 0.0])])
    fast, exact = _exp(x), torch.exp(x)
    above = x >= EXP_MIN
    assert torch.equal(fast[above], exact[above])
    assert torch.all(fast[~above] == 0.0) and exact[~above].max() < 2e-38  # float32 denormals or zero


def test_exp_keeps_a_gradient_above_the_floor():
    x = torch.tensor([-1.0, -100.0], requires_grad=True)
    _exp(x).sum().backward()
    assert torch.allclose(x.grad, torch.tensor([torch.exp(torch.tensor(-1.0)).item(), 0.0]))


@pytest.mark.parametrize("frames_of_values", [1, 3])
def test_splat_sum_is_the_three_way_contraction(frames_of_values: int):
    g = torch.Generator().manual_seed(0)
    B, T, N, h, w, K = 3, 3, 40, 5, 6, 4
    rows, cols = torch.rand(B, T, N, h, generator=g), torch.rand(B, T, N, w, generator=g)
    values = torch.rand(B, frames_of_values, N, K, generator=g)
    want = torch.einsum("btny,btnk,btnx->btkyx", rows, values.expand(B, T, N, K), cols)
    assert torch.allclose(_splat_sum(rows, values, cols), want, atol=1e-5)


@pytest.fixture(scope="module")
def shipped():
    from vt4dcodec.model import from_pretrained, shipped_model_ids

    if "vt4d-tiny" not in shipped_model_ids():
        pytest.skip("the shipped vt4d-tiny weights are not in this checkout")
    return from_pretrained("vt4d-tiny").eval()


def test_views_in_one_batch_equal_each_view_rendered_alone(shipped):
    """The shipped model (pixel, patch and dynamic splats, frame copies, view gates) on five target
    trajectories around two encoded cameras: one batch of five against five renders of one, within 1e-5
    (bench/bench_render_batch.py checks ten views of a real scene the same way, in grey levels)."""
    cfg = shipped.config
    g = torch.Generator().manual_seed(1)
    z_s = torch.rand(1, cfg.n_static, cfg.token_dim, generator=g) * 1.6 - 0.8
    z_d = torch.rand(1, cfg.n_dynamic, cfg.token_dim, generator=g) * 1.6 - 0.8
    K_src, w2c_src = orbit_cameras(2, cfg.frames, cfg.image_size, seed=2)
    source = (K_src[None], w2c_src[None])  # (1, V=2, T, ...)
    n = 5
    K, w2c = orbit_cameras(n, cfg.frames, cfg.image_size, seed=3)
    batch = shipped.render(z_s.expand(n, -1, -1), z_d.expand(n, -1, -1), K, w2c, seed=5,
                           source=tuple(t.expand(n, *t.shape[1:]) for t in source))
    for i in range(n):
        alone = shipped.render(z_s, z_d, K[i:i + 1], w2c[i:i + 1], seed=5, source=source)
        assert (batch[i:i + 1] - alone).abs().max().item() <= 1e-5
    assert (batch[0] - batch[1]).abs().max().item() > 0.01  # the views differ: the test compares something


def test_decoder_in_channels_last_gives_the_nchw_frames_in_nchw_order():
    """The decoder's convolutions run channels-last for speed (docs/benchmarks/render_batch.md); the frames are
    the NCHW network's to float rounding, returned contiguous in NCHW order, and gradients still reach them."""
    from vt4dcodec.model.autoencoder import LatentAutoencoder
    from vt4dcodec.model.configs import get_config

    torch.manual_seed(0)
    ae = LatentAutoencoder(get_config("tiny"))
    latents = torch.randn(3, ae.latent_mean.shape[0], 16, 16, requires_grad=True)
    frames = ae.decode_raw(latents)
    reference = torch.sigmoid(ae.decoder(latents.detach().contiguous()))
    assert frames.is_contiguous() and frames.shape == reference.shape
    assert float((frames - reference).abs().max()) <= 1e-5
    frames.sum().backward()
    assert latents.grad is not None and torch.isfinite(latents.grad).all() and latents.grad.abs().sum() > 0
