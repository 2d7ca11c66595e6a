"""onnxruntime sessions for the exported graphs, on the CPU or a CUDA GPU, without torch.

``device`` is one of :data:`DEVICES`: ``"cpu"``; ``"cuda"``, onnxruntime's CUDA execution provider (the
``onnxruntime-gpu`` package on a machine with an NVIDIA GPU), a :class:`~vt4dcodec.errors.DeviceError` where
it is not there or finds no GPU; ``"auto"``, CUDA where it works, else the CPU.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import Any

from vt4dcodec.errors import DeviceError, ModelError

__all__ = ["DEVICES", "onnx_available", "module_available", "onnx_cuda_available", "open_session", "check_device",
           "open_checked", "MAX_ONNX_BYTES"]

DEVICES = ("auto", "cpu", "cuda")
CUDA_PROVIDER, CPU_PROVIDER = "CUDAExecutionProvider", "CPUExecutionProvider"
MAX_ONNX_BYTES = 1 << 28  # 256 MiB: far above any graph this project ships (their weights stay in the safetensors)


def module_available(name: str) -> bool:
    """Whether the top-level package ``name`` is installed (without importing it)."""
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):  # a finder that refuses it: not importable here
        return False


def onnx_available() -> bool:
    """Whether onnxruntime is installed (``pip install "vt4dcodec[codec]"`` installs it)."""
    return module_available("onnxruntime")


def check_device(device: str) -> str:
    if device not in DEVICES:
        raise DeviceError(f"device must be one of {DEVICES}, got {device!r}")
    return device


def onnx_cuda_available() -> bool:
    """Whether onnxruntime here offers its CUDA execution provider (a GPU may still be missing)."""
    if not onnx_available():
        return False
    import onnxruntime as ort

    return CUDA_PROVIDER in ort.get_available_providers()


def no_gpu_message(detail: str) -> str:
    return (f"device='cuda' but no GPU is seen: {detail}; run on the CPU with device='cpu' (or 'auto', which takes "
            "a GPU where there is one)")


def open_session(path: str | os.PathLike[str], *, device: str = "cpu", threads: int | None = None,
                 what: str = "graph") -> tuple[Any, str]:
    """An onnxruntime session of the graph at ``path`` on ``device`` (:data:`DEVICES`) and the device it runs
    on (``"cpu"`` or ``"cuda"``). ModelError without onnxruntime or for a file that is not a valid graph;
    DeviceError for ``device="cuda"`` where onnxruntime has no CUDA provider or the provider finds no GPU."""
    check_device(device)
    if not onnx_available():
        raise ModelError("the exported graphs need onnxruntime (pip install onnxruntime), or use runtime='torch'")
    import onnxruntime as ort

    cuda = CUDA_PROVIDER in ort.get_available_providers()
    if device == "cuda" and not cuda:
        raise DeviceError(no_gpu_message("onnxruntime here has no CUDA execution provider (install onnxruntime-gpu "
                                         "on a machine with an NVIDIA GPU and its driver)"))
    options = ort.SessionOptions()
    options.log_severity_level = 3  # errors only: no warnings about unused initializers on stderr
    if threads is not None:
        options.intra_op_num_threads = int(threads)
    providers = [CUDA_PROVIDER, CPU_PROVIDER] if device != "cpu" and cuda else [CPU_PROVIDER]
    try:
        session = ort.InferenceSession(str(Path(path)), options, providers=providers)
    except Exception as exc:  # onnxruntime raises its own (pybind) exception types
        if device == "cuda":
            raise DeviceError(no_gpu_message(f"onnxruntime's CUDA provider failed ({exc})")) from None
        raise ModelError(f"{path} is not a valid ONNX {what}: {exc}") from None
    on_gpu = session.get_providers()[0] == CUDA_PROVIDER
    if device == "cuda" and not on_gpu:  # the provider is installed but found no GPU or driver
        raise DeviceError(no_gpu_message("onnxruntime's CUDA provider found no usable GPU"))
    return session, "cuda" if on_gpu else "cpu"


def open_checked(path: Path, meta: dict[str, Any], *, fmt: str, inputs: tuple[str, ...], outputs: tuple[str, ...],
                 what: str, device: str = "cpu", threads: int | None = None) -> tuple[Any, str, dict[str, str]]:
    """:func:`open_session` of an exported graph whose metadata must say ``vt4d_format`` ``fmt`` and the weights and
    config hashes of the model whose parsed config.json is ``meta``, with ``inputs`` and ``outputs`` by name: the
    session, its device and its metadata. ModelError otherwise (a graph of other weights: export it again)."""
    if path.stat().st_size > MAX_ONNX_BYTES:
        raise ModelError(f"{path} is larger than {MAX_ONNX_BYTES} bytes")
    session, where = open_session(path, device=device, threads=threads, what=what)
    props = session.get_modelmeta().custom_metadata_map
    if props.get("vt4d_format") != fmt:
        raise ModelError(f"{path}: metadata vt4d_format must be {fmt!r}")
    for key in ("weights_sha256", "config_sha256"):
        if props.get(f"vt4d_{key}") != meta[key]:
            raise ModelError(f"{path} was exported from other weights than {path.parent / 'config.json'} "
                             f"describes ({key} differs): export it again")
    if tuple(i.name for i in session.get_inputs()) != inputs or tuple(o.name for o in session.get_outputs()) != outputs:
        raise ModelError(f"{path}: inputs must be {inputs} and outputs {outputs}")
    return session, where, dict(props)
