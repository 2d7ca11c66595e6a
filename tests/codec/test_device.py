"""``device=`` / ``--device cpu|cuda|auto`` on encode, decode and generate (issue 51): the CPU and auto paths run,
and where no GPU is seen ``cuda`` is a DeviceError (one of the Vt4dError family) naming the option, on the torch
and the onnx runtime alike; on the command line the message names ``--device`` and there is no traceback."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from vt4dcodec import codec
from vt4dcodec.capture.io import write_capture
from vt4dcodec.errors import DeviceError, Vt4dError
from vt4dcodec.generate import generate
from vt4dcodec.model.onnx_session import onnx_cuda_available
from vt4dcodec.synth import SynthConfig, generate_scene

NO_GPU = not torch.cuda.is_available() and not onnx_cuda_available()
needs_no_gpu = pytest.mark.skipif(not NO_GPU, reason="a GPU is seen here: the no-GPU error cannot be provoked")


@pytest.fixture(scope="module")
def capture():
    return generate_scene(5, split="test", config=SynthConfig(num_cameras=3)).capture


@pytest.fixture(scope="module")
def scene(capture):
    return codec.encode(capture, "vt4d-tiny", cameras="all")


def test_device_error_is_of_the_family():
    assert issubclass(DeviceError, Vt4dError)
    with pytest.raises(DeviceError, match="device must be one of"):
        codec.load_encoder("vt4d-tiny", device="tpu")
    with pytest.raises(DeviceError, match="device must be one of"):
        codec.SceneDecoder.open(codec.encode(generate_scene(1, split="test").capture), device="gpu")


@pytest.mark.parametrize("runtime", ["onnx", "torch"])
def test_cpu_and_auto_encode_and_decode(capture, scene, runtime):
    for device in ("cpu", "auto"):
        got = codec.encode(capture, "vt4d-tiny", cameras="all", runtime=runtime, device=device)
        assert np.abs(got.static_tokens - scene.static_tokens).max() <= 2e-6
        decoder = codec.SceneDecoder.open(scene, runtime=runtime, device=device)
        frames = decoder.render("source")
        assert frames.shape == (8, 64, 64, 3)
        if NO_GPU:  # auto falls back to the CPU
            assert (decoder.model.device if runtime == "onnx" else next(decoder.model.parameters()).device.type) == "cpu"


@needs_no_gpu
@pytest.mark.parametrize("runtime", ["onnx", "torch"])
def test_cuda_without_a_gpu_is_a_clear_error(capture, scene, runtime):
    with pytest.raises(DeviceError, match=r"device='cuda' but no GPU is seen.*device='cpu'"):
        codec.encode(capture, "vt4d-tiny", runtime=runtime, device="cuda")
    with pytest.raises(DeviceError, match="no GPU is seen"):
        codec.SceneDecoder.open(scene, runtime=runtime, device="cuda")
    with pytest.raises(DeviceError, match="no GPU is seen"):
        codec.decode(scene, runtime=runtime, device="cuda")


@needs_no_gpu
def test_generate_on_cuda_without_a_gpu_is_a_clear_error(capture):
    with pytest.raises(DeviceError, match="no GPU is seen"):
        generate(capture.frames["cam00"], capture.cameras["cam00"], device="cuda")


def test_generate_on_cpu_and_auto_gives_the_same_sample(capture):
    a = generate(capture.frames["cam00"], capture.cameras["cam00"], steps=2, device="cpu")
    b = generate(capture.frames["cam00"], capture.cameras["cam00"], steps=2, device="auto")
    if NO_GPU:
        np.testing.assert_array_equal(a.static_tokens, b.static_tokens)


@needs_no_gpu
def test_cli_names_the_flag(tmp_path, capture, scene):
    from vt4dcodec.format import save

    write_capture(capture, tmp_path / "cap")
    save(scene, tmp_path / "s.vt4d")
    commands = [["encode", str(tmp_path / "cap"), "-o", str(tmp_path / "o.vt4d")],
                ["decode", str(tmp_path / "s.vt4d"), "-o", str(tmp_path / "v.mp4")],
                ["decode", str(tmp_path / "s.vt4d"), "-o", str(tmp_path / "w.mp4"), "--runtime", "onnx"],
                ["generate", str(tmp_path / "cap"), "-o", str(tmp_path / "gen"), "--steps", "1"]]
    for command in commands:
        run = subprocess.run([sys.executable, "-m", "vt4dcodec", *command, "--device", "cuda"], capture_output=True,
                             text=True, timeout=300)
        assert run.returncode == 1, (command, run.stderr)
        assert "--device cuda but no GPU is seen" in run.stderr and "--device cpu" in run.stderr, run.stderr
        assert "Traceback" not in run.stderr and "device=" not in run.stderr
    run = subprocess.run([sys.executable, "-m", "vt4dcodec", "decode", str(tmp_path / "s.vt4d"), "-o",
                          str(tmp_path / "a.mp4"), "--device", "auto"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
