"""The encoder on onnxruntime (``runtime="onnx"``, the exported ``encoder.onnx``) against the torch encoder:
same tokens to float rounding, same fingerprint, no torch in the process, and clear errors."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from vt4dcodec import codec
from vt4dcodec.capture.caliscope import find_sample_capture, import_caliscope
from vt4dcodec.capture.io import write_capture
from vt4dcodec.errors import ModelError, ModelNotFoundError
from vt4dcodec.model import SourceBatch, SourceInputs, VideoTok4D, get_config, save_pretrained
from vt4dcodec.model.inputs.source_inputs import stack_inputs
from vt4dcodec.model.onnx_encoder import ONNX_FILE, OnnxEncoder
from vt4dcodec.model.onnx_export import (example_inputs, export_encoder, export_feedback, export_gradient, export_renderer)
from vt4dcodec.model.weights_io import SHIPPED_DIR
from vt4dcodec.synth import SynthConfig, generate_scene

from test_unified_recipe import RECIPE

TOKEN_TOLERANCE = 1e-5  # |onnx - torch| per token value; measured on vt4d-tiny 0.13.0: < 1e-6


def small_model_directory(tmp_path: Path) -> tuple[VideoTok4D, Path]:
    """A small random model of the shipped recipe, saved in float16 (as shipped) and exported."""
    torch.manual_seed(0)
    net = VideoTok4D(get_config("tiny", **RECIPE)).eval()
    directory = save_pretrained(net, tmp_path / "small", model_id="small", model_version="0",
                                storage_dtype="float16")
    net = codec.load_model(directory)  # the float16-rounded model the directory holds
    export_encoder(net, directory)
    return net, directory


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    return small_model_directory(tmp_path_factory.mktemp("onnx"))


def test_exported_small_model_gives_the_torch_tokens(small):
    net, directory = small
    encoder = OnnxEncoder.open(directory)
    assert encoder.stored_fingerprint() == net.stored_fingerprint()
    inputs = example_inputs(net, seed=3)  # other inputs than the export traced
    with torch.no_grad():
        want = [t.numpy() for t in net.encode(SourceBatch(*inputs))]
    got = encoder.session.run(None, {n: t.numpy() for n, t in zip(("frames", "K", "w2c", "motion_mask", "track_xy",
                                                                    "track_valid"), inputs)})
    for a, b in zip(got, want):
        assert a.shape == b.shape and np.abs(a - b).max() <= TOKEN_TOLERANCE


def test_the_dynamic_splat_encoder_exports_and_gives_the_torch_tokens(tmp_path):
    """vt4d-tiny 1.0.0's recipe: dynamic tokens tied to their most moving tracks (a stable sort, which ONNX
    has not: regression for the export error 'Sort, Out parameter is not supported') and read from them."""
    torch.manual_seed(0)
    net = VideoTok4D(get_config("tiny", **RECIPE, dynamic_splat=2, dynamic_from_patch=True,
                                dynamic_gate_deg=8.0, dynamic_gate_copies=True)).eval()
    directory = save_pretrained(net, tmp_path / "dyn", model_id="dyn", model_version="0", storage_dtype="float16")
    net = codec.load_model(directory)
    export_encoder(net, directory)
    encoder = OnnxEncoder.open(directory)
    for seed in (3, 4):
        inputs = example_inputs(net, seed=seed)
        with torch.no_grad():
            want = [t.numpy() for t in net.encode(SourceBatch(*inputs))]
        got = encoder.session.run(None, {n: t.numpy() for n, t in zip(
            ("frames", "K", "w2c", "motion_mask", "track_xy", "track_valid"), inputs)})
        for a, b in zip(got, want):
            assert a.shape == b.shape and np.abs(a - b).max() <= TOKEN_TOLERANCE


BLENDS = {"groups": {}, "blend": {"copy_blend": True}}


@pytest.mark.parametrize("views,passes,blend,gradient", [(1, 1, "groups", False), (2, 1, "groups", False),
                                                        (1, 2, "groups", False), (1, 1, "blend", False),
                                                        (2, 2, "groups", True)])
def test_the_render_feedback_encoder_exports_and_gives_the_torch_tokens(tmp_path, views: int, passes: int,
                                                                        blend: str, gradient: bool):
    """Render feedback in three graphs: the encoder's gives the first pass (z_s0, z_d0: the tokens of the same
    weights without the feedback) and what the feedback reads, ``renderer.onnx`` renders it (seed-0 noise, the
    decoder's steps), and one feedback graph per pass (any camera count) gives the tokens. Blended frame copies
    (their soft weights are tables of the renderer's graph) alike. A feedback that reads the render's gradient
    renders with the render-gradient graph of its camera count instead (a backward pass through the renderer,
    traced by torch.func and the dynamo exporter)."""
    torch.manual_seed(0)
    net = VideoTok4D(get_config("tiny", **RECIPE, dynamic_splat=2, dynamic_from_patch=True, dynamic_gate_deg=8.0,
                                dynamic_gate_copies=True, feedback_width=16, feedback_passes=passes,
                                feedback_gradient=gradient, **BLENDS[blend])).eval()
    for module in [net.feedback, *(net.feedback_later or ())]:
        layers = (module.static, module.dynamic) + ((module.static_grad, module.dynamic_grad) if gradient else ())
        for layer in layers:
            torch.nn.init.normal_(layer[2].weight, std=0.1)  # a feedback that moves the tokens
    net.decode_steps = 1
    directory = save_pretrained(net, tmp_path / "fb", model_id="fb", model_version="0", storage_dtype="float16")
    net = codec.load_model(directory)
    export_renderer(net, directory)
    assert [export_feedback(net, directory, k).name for k in range(1, passes + 1)] == \
        ["feedback.onnx", "feedback-p2.onnx"][:passes]
    if gradient:
        assert export_gradient(net, directory, views).name == f"render-gradient-v{views}.onnx"
        with pytest.raises(ModelNotFoundError, match=f"no render-gradient-v{views + 1}.onnx"):
            export_encoder(net, directory, views=views + 1)  # its feedback needs the graph of its camera count
    export_encoder(net, directory, views=views)
    encoder = OnnxEncoder.open(directory, views=views) if views > 1 else OnnxEncoder.open(directory)
    for seed in (3, 4):
        inputs = example_inputs(net, seed=seed, views=views)
        with torch.no_grad():
            want = [t.numpy() for t in net.encode(SourceBatch(*inputs, views=views))]
            first = [t.numpy() for t in net.encode(SourceBatch(*inputs, views=views), feedback=False)]
            net.feedback, saved = None, net.feedback
            plain = [t.numpy() for t in net.encode(SourceBatch(*inputs, views=views))]
            net.feedback = saved
            if passes > 1:  # the last pass is in the tokens too
                net.feedback_later, later = None, net.feedback_later
                one_pass = [t.numpy() for t in net.encode(SourceBatch(*inputs, views=views))]
                net.feedback_later = later
                assert min(float(np.abs(a - b).max()) for a, b in zip(want, one_pass)) > 1e-3
        assert all(np.array_equal(a, b) for a, b in zip(first, plain))  # the first pass: the model without feedback
        assert min(float(np.abs(a - b).max()) for a, b in zip(want, plain)) > 1e-3  # the feedback is in the tokens
        assert [o.name for o in encoder.session.get_outputs()][:2] == ["z_s0", "z_d0"]
        arrays = {n: t.numpy() for n, t in zip(("frames", "K", "w2c", "motion_mask", "track_xy", "track_valid"), inputs)}
        for got, reference in ((encoder.encode_arrays(arrays), want), (encoder.encode_arrays(arrays, False), plain)):
            for a, b in zip(got, reference, strict=True):
                assert a.shape == b.shape and np.abs(a - b).max() <= TOKEN_TOLERANCE


def test_masks_of_any_size_trace_to_the_same_graph(small):
    """The Temporal Branch gathers masked pixels in torch; the graph attends over the grid with keys
    restricted to the mask. Empty and full masks must agree too (a traced length would not)."""
    net, directory = small
    encoder = OnnxEncoder.open(directory)
    frames, K, w2c, mask, txy, tv = example_inputs(net, seed=5)
    for m in (torch.zeros_like(mask), torch.ones_like(mask), (torch.rand(mask.shape) < 0.6).float()):
        with torch.no_grad():
            want = [t.numpy() for t in net.encode(SourceBatch(frames, K, w2c, m, txy, tv))]
        got = encoder.session.run(None, {"frames": frames.numpy(), "K": K.numpy(), "w2c": w2c.numpy(),
                                         "motion_mask": m.numpy(), "track_xy": txy.numpy(),
                                         "track_valid": tv.numpy()})
        assert max(float(np.abs(a - b).max()) for a, b in zip(got, want)) <= TOKEN_TOLERANCE


def test_float16_weights_are_stored_as_float16_in_the_graph(small):
    import onnx

    _, directory = small
    model = onnx.load(str(directory / ONNX_FILE))

    def elements(dtype: int) -> int:
        return sum(int(np.prod(i.dims)) for i in model.graph.initializer if i.data_type == dtype)

    halves, singles = elements(onnx.TensorProto.FLOAT16), elements(onnx.TensorProto.FLOAT)
    assert halves > 0.95 * (halves + singles)  # only small float32 constants of the trace stay float32


def test_an_encoder_exported_from_other_weights_is_refused(small, tmp_path):
    import onnx

    _, directory = small
    copy = Path(shutil.copytree(directory, tmp_path / "copy"))
    model = onnx.load(str(copy / ONNX_FILE))
    for entry in model.metadata_props:
        if entry.key == "vt4d_weights_sha256":
            entry.value = "0" * 64
    onnx.save(model, str(copy / ONNX_FILE))
    with pytest.raises(ModelError, match="export it again"):
        OnnxEncoder.open(copy)
    (copy / ONNX_FILE).write_bytes(b"not a graph")
    with pytest.raises(ModelError, match="not a valid ONNX encoder"):
        OnnxEncoder.open(copy)
    (copy / ONNX_FILE).unlink()
    with pytest.raises(ModelNotFoundError, match="onnx_export"):
        OnnxEncoder.open(copy)
    assert isinstance(codec.load_encoder(copy), VideoTok4D)  # auto: no exported encoder -> torch


def test_export_refuses_a_directory_of_other_weights(small, tmp_path):
    net, directory = small
    copy = Path(shutil.copytree(directory, tmp_path / "other"))
    meta = json.loads((copy / "config.json").read_text())
    meta["weights_sha256"] = "1" * 64
    (copy / "config.json").write_text(json.dumps(meta))
    with pytest.raises(ModelError, match="other weights"):
        export_encoder(net, copy)


def test_runtime_choice_and_its_errors(small):
    net, directory = small
    assert isinstance(codec.load_encoder(directory), OnnxEncoder)  # auto, one camera
    assert isinstance(codec.load_encoder(directory, cameras=3), VideoTok4D)  # auto, several cameras
    assert isinstance(codec.load_encoder(directory, "torch"), VideoTok4D)
    assert codec.load_encoder(net) is net
    with pytest.raises(ModelError, match="runtime must be one of"):
        codec.load_encoder(directory, "tensorrt")
    with pytest.raises(ModelNotFoundError, match="runtime='torch'"):  # exported for one camera only
        codec.load_encoder(directory, "onnx", cameras=2)
    with pytest.raises(ModelError, match="not a loaded torch model"):
        codec.load_encoder(net, "onnx")
    encoder = codec.load_encoder(directory, "onnx")
    with pytest.raises(ModelError, match="1 source camera"):
        encoder.encode([])


def test_shipped_model_has_an_encoder_that_matches_it():
    encoder = OnnxEncoder.open("vt4d-tiny")
    net = codec.load_model("vt4d-tiny")
    assert encoder.stored_fingerprint() == net.stored_fingerprint()
    cap = generate_scene(4, split="test", config=SynthConfig(num_cameras=2)).capture
    onnx_scene = codec.encode(cap, "vt4d-tiny", runtime="onnx")
    torch_scene = codec.encode(cap, "vt4d-tiny", runtime="torch")
    assert onnx_scene.fingerprint == torch_scene.fingerprint
    for a, b in ((onnx_scene.static_tokens, torch_scene.static_tokens),
                 (onnx_scene.dynamic_tokens, torch_scene.dynamic_tokens)):
        assert np.abs(a - b).max() <= TOKEN_TOLERANCE
    assert (SHIPPED_DIR / "vt4d-tiny" / ONNX_FILE).stat().st_size < 8_000_000


@pytest.mark.skipif(find_sample_capture() is None, reason="caliscope_4cam sample data not present")
def test_real_footage_encodes_without_torch(tmp_path):
    """A real capture directory, `vt4d encode` as a user runs it: no torch module is ever imported."""
    capture = tmp_path / "caliscope"
    write_capture(import_caliscope(find_sample_capture(), height=96, width=96, num_frames=8, frame_step=2), capture)
    out = tmp_path / "scene.vt4d"
    script = textwrap.dedent(f"""
        import sys
        from vt4dcodec.cli import main
        assert main(["encode", {str(capture)!r}, "-o", {str(out)!r}, "--runtime", "onnx"]) == 0
        bad = sorted(m for m in sys.modules if m.split(".")[0] in ("torch", "kornia"))
        assert not bad, bad[:5]
        print("clean")
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "clean" in run.stdout
    torch_scene = codec.encode(capture, runtime="torch")
    onnx_scene = codec.encode(capture, runtime="onnx")
    assert np.abs(onnx_scene.static_tokens - torch_scene.static_tokens).max() <= TOKEN_TOLERANCE


def test_cli_encodes_several_cameras_on_onnx_and_names_the_flag_past_the_exported_counts(tmp_path):
    """Scenes of 1 .. EXPORT_VIEWS cameras have a graph each (issue 51); more cameras need --runtime torch."""
    from vt4dcodec.model.onnx_export import EXPORT_VIEWS

    cap = generate_scene(2, split="test", config=SynthConfig(num_cameras=EXPORT_VIEWS + 1)).capture
    write_capture(cap, tmp_path / "cap")

    def encode(cameras: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "vt4dcodec", "encode", str(tmp_path / "cap"), "--cameras", cameras,
                               "--runtime", "onnx", "-o", str(tmp_path / "s.vt4d"), "-y"], capture_output=True,
                              text=True, timeout=300)

    run = encode(",".join(cap.camera_names[:2]))
    assert run.returncode == 0, run.stderr
    run = encode("all")
    assert run.returncode != 0 and "--runtime torch" in run.stderr and "Traceback" not in run.stderr


@settings(max_examples=20)
@given(st.integers(1, 3), st.integers(1, 4), st.integers(0, 5), st.integers(0, 2**31 - 1))
def test_stack_inputs_are_the_batch_tensors(B: int, T: int, N: int, seed: int):
    rng = np.random.default_rng(seed)
    items = [SourceInputs(frames=rng.integers(0, 256, (T, 8, 8, 3), dtype=np.uint8),
                          K=rng.normal(size=(T, 3, 3)), w2c=rng.normal(size=(T, 4, 4)),
                          motion_mask=rng.random((T, 2, 2)), track_xy=rng.random((N, T, 2)) * 2,
                          track_valid=rng.random((N, T)) < 0.5) for _ in range(B)]
    arrays = stack_inputs(items)
    batch = SourceBatch.collate(items)
    for name, value in arrays.items():
        tensor = getattr(batch, name)
        assert tensor.dtype == (torch.bool if name == "track_valid" else torch.float32)
        assert np.array_equal(tensor.numpy(), value)


def test_a_small_models_renderer_and_two_camera_encoder_export_and_match_torch(small, tmp_path):
    """The exporter itself (issue 51), on a small model of the shipped recipe: the two-camera encoder graph and the
    renderer graph hold no weights of their own (external tensors into model.safetensors), give torch's tokens and
    frames on inputs other than the export traced, and a renderer of other weights is refused."""
    import onnx

    from vt4dcodec.model.onnx_export import _torch_render, example_render_inputs, export_renderer
    from vt4dcodec.model.onnx_renderer import RENDERER_FILE, OnnxRenderer

    net, directory = small
    copy = Path(shutil.copytree(directory, tmp_path / "small"))
    encoder = OnnxEncoder.open(export_encoder(net, copy, views=2).parent, views=2)
    inputs = example_inputs(net, seed=6, views=2)
    with torch.no_grad():
        want = [t.numpy() for t in net.encode(SourceBatch(*inputs, views=2))]
    got = encoder.session.run(None, {n: t.numpy() for n, t in zip(
        ("frames", "K", "w2c", "motion_mask", "track_xy", "track_valid"), inputs)})
    assert max(float(np.abs(a - b).max()) for a, b in zip(got, want)) <= TOKEN_TOLERANCE
    path = export_renderer(net, copy)
    graph = onnx.load(str(path), load_external_data=False)
    external = [i for i in graph.graph.initializer if i.data_location == onnx.TensorProto.EXTERNAL]
    assert external and {e.value for i in external for e in i.external_data if e.key == "location"} == {"model.safetensors"}
    renderer = OnnxRenderer.open(copy)
    assert renderer.stored_fingerprint() == net.stored_fingerprint()
    for views, frames, cameras, steps in ((3, None, 2, 1), (1, 4, 5, 3)):
        case = example_render_inputs(net, views=views, frames=frames, cameras=cameras, seed=9)
        got = renderer.render(*(case[n].numpy() for n in ("z_s", "z_d", "K_tgt", "w2c_tgt", "K_src", "w2c_src")),
                              steps=steps, seed=2)
        assert np.abs(got - _torch_render(net, case, steps, 2)).max() <= 1e-5
    for entry in graph.metadata_props:
        if entry.key == "vt4d_weights_sha256":
            entry.value = "0" * 64
    (copy / RENDERER_FILE).write_bytes(graph.SerializeToString())
    with pytest.raises(ModelError, match="export it again"):
        OnnxRenderer.open(copy)


def test_render_gradient_export_refuses_a_model_without_it(small, tmp_path):
    """Only a feedback that reads the render's gradient has a render-gradient graph; a model without it is refused
    before anything is traced or written."""
    net, directory = small
    before = sorted(p.name for p in Path(directory).glob("*.onnx"))
    with pytest.raises(ModelError, match="feedback_gradient"):
        export_gradient(net, directory)
    assert sorted(p.name for p in Path(directory).glob("*.onnx")) == before
