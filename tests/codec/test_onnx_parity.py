"""The exported graphs against the torch networks on every shipped model (issue 51): the encoder's tokens within
2e-6 for one camera and several (``encoder.onnx``, ``encoder-v{V}.onnx``), the renderer's frames
(``renderer.onnx``, seeded noise and the Euler loop in numpy) within 0.01 dB of torch's PSNR against the ground
truth, for the source view and novel views, one step and several, one encoded camera and several, and every
shipped prior's samples (``prior-condition.onnx``, ``prior-velocity.onnx``) within 2e-6 of torch's."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
import torch

from vt4dcodec import codec
from vt4dcodec.media import psnr
from vt4dcodec.generate import generate, load_prior_model
from vt4dcodec.model.directories import PRIOR_META_FILE, model_directory, shipped_model_ids, shipped_prior_ids
from vt4dcodec.model.onnx_prior import OnnxPrior, has_onnx_prior
from vt4dcodec.model.onnx_encoder import OnnxEncoder, gradient_file, has_onnx_encoder
from vt4dcodec.model.onnx_export import EXPORT_VIEWS
from vt4dcodec.model.weights_io import from_pretrained
from vt4dcodec.model.onnx_renderer import OnnxRenderer, has_onnx_renderer, seeded_noise
from vt4dcodec.synth import SynthConfig, generate_scene

TOKEN_TOLERANCE = 2e-6  # |onnx - torch| per token value (issue 51)
PSNR_TOLERANCE = 0.01  # dB, |PSNR(onnx render) - PSNR(torch render)| against the ground truth (issue 51)
SHIPPED = shipped_model_ids()
PRIORS = shipped_prior_ids()


def test_every_shipped_model_ships_its_graphs():
    assert SHIPPED
    for model in SHIPPED:
        directory = model_directory(model)
        assert has_onnx_renderer(directory), model
        for views in range(1, EXPORT_VIEWS + 1):
            assert has_onnx_encoder(directory, views), (model, views)
        graphs = sorted(directory.glob("*.onnx"))
        # the encoders, the renderer and the feedback (the render-gradient graphs, a backward pass each, are extra)
        sizes = sorted(p.stat().st_size for p in graphs if not p.name.startswith("render-gradient"))
        assert sum(sizes) < 4_000_000 and sizes[-1] < 1_000_000, sizes  # the weights stay in model.safetensors
        gradient = [p for p in graphs if p.name.startswith("render-gradient")]
        if from_pretrained(directory).config.feedback_gradient:  # one per camera count, structure only
            assert sorted(p.name for p in gradient) == sorted(gradient_file(v) for v in range(1, EXPORT_VIEWS + 1))
            assert max(p.stat().st_size for p in gradient) < 400_000, [p.stat().st_size for p in gradient]
        else:
            assert not gradient
        weights = {tuple(v.shape) for v in from_pretrained(directory).state_dict().values() if v.numel() >= 4096}
        weights |= {shape[::-1] for shape in weights}
        for path in graphs:  # what a graph stores itself (the render noise, index tables) holds no weight, transposed
            graph = onnx.load(str(path), load_external_data=False).graph
            stored = [t for t in graph.initializer if t.data_location != onnx.TensorProto.EXTERNAL]
            stored += [a.t for node in graph.node if node.op_type == "Constant" for a in node.attribute if a.name == "value"]
            copies = [tuple(t.dims) for t in stored if tuple(t.dims) in weights and
                      t.data_type in (onnx.TensorProto.FLOAT, onnx.TensorProto.FLOAT16)]
            assert not copies, (path.name, copies)
    assert PRIORS
    for prior in PRIORS:
        directory = model_directory(prior, PRIOR_META_FILE)
        assert has_onnx_prior(directory), prior
        assert sum(p.stat().st_size for p in directory.glob("*.onnx")) < 500_000  # weights in prior.safetensors


@pytest.mark.parametrize("shape,seed", [((1, 8, 8, 16, 16), 0), ((1, 5, 8, 16, 16), 7), ((1, 3, 5, 7, 3), 2**40 + 3)])
def test_seeded_noise_is_torchs(shape, seed):
    want = torch.randn(shape, generator=torch.Generator().manual_seed(seed)).numpy()
    assert np.abs(seeded_noise(shape, seed) - want).max() <= 1e-6  # the last bit of log / cos / sin


@pytest.fixture(scope="module")
def capture():
    return generate_scene(3, split="test", config=SynthConfig(num_cameras=10, num_frames=8, height=64, width=64)).capture


@pytest.mark.parametrize("model", SHIPPED)
@pytest.mark.parametrize("views", [1, 3, EXPORT_VIEWS])
def test_encoder_tokens_match_torch(model, views, capture):
    names = capture.camera_names[:views]
    onnx_encoder = codec.load_encoder(model, "onnx", cameras=views)
    assert isinstance(onnx_encoder, OnnxEncoder)
    got = codec.encode(capture, onnx_encoder, cameras=names, seed=1)
    want = codec.encode(capture, model, cameras=names, seed=1, runtime="torch")
    assert got.fingerprint == want.fingerprint
    for a, b in ((got.static_tokens, want.static_tokens), (got.dynamic_tokens, want.dynamic_tokens)):
        assert a.shape == b.shape and np.abs(a - b).max() <= TOKEN_TOLERANCE


@pytest.mark.parametrize("model", SHIPPED)
@pytest.mark.parametrize("views,steps", [(1, None), (3, None), (1, 2)])
def test_renders_match_torch_within_a_hundredth_of_a_db(model, views, steps, capture):
    names = capture.camera_names
    scene = codec.encode(capture, model, cameras=names[:views], seed=0, runtime="torch")
    torch_decoder = codec.SceneDecoder.open(scene, runtime="torch")
    onnx_decoder = codec.SceneDecoder.open(scene, runtime="onnx")
    assert isinstance(onnx_decoder.model, OnnxRenderer)
    targets = [names[0], names[4], names[9]]
    specs = [capture.cameras[n] for n in targets]
    want = torch_decoder.render_many(specs, steps=steps, seed=3)
    got = onnx_decoder.render_many(specs, steps=steps, seed=3)
    for name, a, b in zip(targets, got, want):
        gt = capture.frames[name]
        assert abs(psnr(a, gt) - psnr(b, gt)) <= PSNR_TOLERANCE, name
        assert np.abs(a.astype(int) - b.astype(int)).max() <= 1  # uint8 rounding of float differences ~1e-5
    short = onnx_decoder.render("orbit:degrees=20", seed=1)  # a preset trajectory, and a shorter clip below
    assert np.abs(short.astype(int) - torch_decoder.render("orbit:degrees=20", seed=1).astype(int)).max() <= 1
    clip = capture.cameras[names[2]][:5]
    a, b = onnx_decoder.render(clip, drop_dynamic=True), torch_decoder.render(clip, drop_dynamic=True)
    assert a.shape[0] == 5 and np.abs(a.astype(int) - b.astype(int)).max() <= 1


@pytest.mark.parametrize("prior", PRIORS)
@pytest.mark.parametrize("steps,method", [(3, "heun"), (2, "euler")])
def test_prior_samples_match_torch(prior, steps, method, capture):
    assert isinstance(load_prior_model(prior, runtime="onnx"), OnnxPrior)
    got = generate(capture.frames["cam00"], capture.cameras["cam00"], "orbit:degrees=10", model=prior, steps=steps,
                   method=method, seed=4, runtime="onnx")
    want = generate(capture.frames["cam00"], capture.cameras["cam00"], "orbit:degrees=10", model=prior, steps=steps,
                    method=method, seed=4, runtime="torch")
    assert got.fingerprint == want.fingerprint and got.metadata == want.metadata
    for a, b in ((got.static_tokens, want.static_tokens), (got.dynamic_tokens, want.dynamic_tokens)):
        assert np.abs(a - b).max() <= TOKEN_TOLERANCE
