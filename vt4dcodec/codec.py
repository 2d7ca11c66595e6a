"""The codec: capture -> encoder -> Scene, and Scene -> renderer -> frames.

The encoder is the compressor and the renderer the decompressor.  This module is glue: it fits a
capture to the model's clip (undistort, resize, centre-crop, frame window), runs the non-learned
preprocessing (flow, motion isolation, tracks) and the networks, and checks that a file is decoded by
the model that made it.  It imports torch lazily, so ``import vt4dcodec`` stays light.

Clip policy (documented in README and FORMAT.md "Captures"): a model encodes clips of exactly
``config.frames`` frames at ``config.image_size`` pixels square.  Larger frames are undistorted,
resized (shorter side) and centre-cropped with the intrinsics updated (``fit="pad"`` instead resizes
the longer side and letterboxes: the whole picture on black bars, recorded in the scene so renders
of capture cameras are fitted the same way); :func:`encode` takes the
``config.frames`` frames starting at ``start`` and :func:`encode_clips` splits a long capture into
consecutive clips (a shorter tail is dropped and reported).  A capture with fewer frames than the
clip is rejected with :class:`~vt4dcodec.errors.CaptureError`.

Given a capture directory, encoding reads only the clip: the encoded cameras' frames ``[start,
start + config.frames)`` (videos seeked, not decoded whole; :mod:`vt4dcodec.capture.io`), so time and
memory follow the clip, not the capture, and ``encode_clips`` reads one clip at a time.

Runtimes (``runtime=``): ``"torch"`` runs the networks (the ``train`` extra installs torch); ``"onnx"`` runs
the graphs exported beside the model's weights on onnxruntime without importing torch (~120 MB resident
instead of ~530 MB for torch alone): the encoder for 1 .. 10 cameras (``encoder.onnx``,
``encoder-v{V}.onnx``; ``vt4dcodec.model.onnx_encoder``) and the renderer (``renderer.onnx``;
``vt4dcodec.model.onnx_renderer``).  ``"auto"`` (default): where torch is installed, onnx for encoding one
camera and torch otherwise; where it is not (``pip install ".[codec]"``), onnx for everything.  Both give the
same fingerprint, tokens equal to float rounding (<= 2e-6) and the same frames to float rounding.

Devices (``device=``, :data:`DEVICES`): ``"cpu"`` (default); ``"cuda"``, a GPU through torch (torch runtime) or
onnxruntime's CUDA execution provider (onnx runtime, the ``onnxruntime-gpu`` package), a
:class:`~vt4dcodec.errors.DeviceError` naming the option where none is seen; ``"auto"``, a GPU where one is
seen, else the CPU.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Sequence

import numpy as np

from .cameras import Trajectory
from .capture.capture import Capture
from .capture.io import MANIFEST_NAME, CaptureManifest, read_capture, read_manifest
from .capture.resample import check_fit, fit_capture, fit_trajectory, plan_fit
from .capture.targets import camera_target, check_camera_spec, cut_to_clip, is_camera_spec
from .capture.trajectories import load_trajectory, make_trajectory, parse_trajectory_spec
from .errors import (CaptureError, DeviceError, EntropyTablesError, MissingExtraError, ModelError, ModelMismatchError,
                     ModelNotFoundError, TrajectoryError)
from .format import EntropyTables, ModelFingerprint, Provenance, Scene, load, open_scene
from .reference import CENTRE_KEY, centre_from_metadata, centre_to_metadata, model_centre, move_origin, move_trajectory

if TYPE_CHECKING:  # pragma: no cover
    import torch

    from .model import VideoTok4D
    from .model.onnx_encoder import OnnxEncoder
    from .model.onnx_renderer import OnnxRenderer

__all__ = [
    "DEFAULT_MODEL", "DEFAULT_STEPS", "DEFAULT_ENCODING", "encode", "encode_clips", "decode", "SceneDecoder", "load_model",
    "resolve_trajectory", "model_fingerprint", "parse_camera_list", "read_clip", "scene_fit", "load_encoder", "encode_views",
    "RUNTIMES", "DEVICES", "quality_levels", "default_quality", "model_tables", "torch_available", "load_renderer",
    "torch_device", "TRAIN_EXTRA_HINT",
]

DEFAULT_MODEL = "vt4d-tiny"
TRAIN_EXTRA_HINT = 'pip install "vt4dcodec[train]" (from a clone: pip install -e ".[train]")'
RUNTIMES = ("auto", "torch", "onnx")  # encoder and renderer runtimes (module docstring)
DEVICES = ("auto", "cpu", "cuda")  # where they run (module docstring)
DEFAULT_STEPS = None  # None: the model's recorded decode_steps (its best-fidelity setting)
# The smallest encoding that keeps every held-out novel view within 0.1 dB of float32 tokens, re-chosen
# for each shipped model (docs/benchmarks/rate_distortion.md). vt4d-tiny 1.0.0: int4, worst view +0.074 dB,
# file 6,678 B (int4-rans +0.106 dB at 5,686 B fails; int5-rans passes at +0.057 dB but is larger, 7,187 B).
# (0.13.0: int4, +0.089 dB, 6,442 B; 0.12.0: int4, +0.078 dB, 6,426 B; 0.11.0: int4-rans, +0.061 dB, 5,229 B; 0.10.0: int4, +0.099 dB, 6,410 B; 0.9.0: int4, +0.086 dB; 0.8.0:
# int5-rans, +0.079 dB; 0.7.0: int4-rans, +0.091 dB; 0.6.0: int5-rans; 0.2.0-0.5.0: int4-rans.) Re-measure
# with bench/bench_rate_distortion.py when the model changes.
DEFAULT_ENCODING = "int4"
# Quality levels of models with an entropy model (config entropy_levels): 1 = the coarsest. encode(quality=Q)
# stores the tokens as learned-rans at that level (format 1.6). codec.QUALITY_LEVELS is quality_levels() of the
# default model, read from its config on first access (module __getattr__): () while the shipped model has none.
MAX_REFINE = 1000  # encoder-side refinement iterations one encode accepts (model.refine.MAX_REFINE)
TUNES = ("psnr", "ssim")  # what encoder-side refinement optimises (model.refine.TUNE_SSIM_WEIGHT)
RENDER_BATCH = 8  # views rendered in one forward pass by SceneDecoder.render_many (bounds its memory)


# --- runtimes and devices ---------------------------------------------------------------------------
def torch_available() -> bool:
    """Whether torch is installed (the ``train`` extra): the torch runtime, training, evaluation, generation."""
    from .model.onnx_session import module_available  # torch-free

    return module_available("torch")


def _require_torch(what: str) -> None:
    if not torch_available():
        raise MissingExtraError(f"{what} needs torch, which is not installed: {TRAIN_EXTRA_HINT}")


def _require_a_runtime() -> None:
    """MissingExtraError naming the codec extra where neither onnxruntime nor torch is installed (a core install)."""
    from .model.onnx_session import onnx_available

    if not onnx_available() and not torch_available():
        raise MissingExtraError('the codec runs its networks on onnxruntime, which the core install leaves out: pip '
                                'install "vt4dcodec[codec]" (from a clone: pip install -e ".[codec]")')


def _check_runtime(runtime: str) -> None:
    if runtime not in RUNTIMES:
        raise ModelError(f"runtime must be one of {RUNTIMES}, got {runtime!r}")


def _check_device(device: str) -> None:
    if device not in DEVICES:
        raise DeviceError(f"device must be one of {DEVICES}, got {device!r}")


def torch_device(device: str = "cpu") -> str:
    """``device`` (:data:`DEVICES`) as the torch device the networks run on: ``"cuda"`` where torch sees a GPU
    (DeviceError for ``"cuda"`` where it sees none), else ``"cpu"``."""
    _check_device(device)
    if device == "cpu":
        return "cpu"
    import torch

    if torch.cuda.is_available():
        return "cuda"
    if device == "cuda":
        raise DeviceError("device='cuda' but no GPU is seen: torch finds no CUDA device (no NVIDIA GPU or driver, or "
                          "a CPU-only torch); run on the CPU with device='cpu' (or device='auto', which takes a GPU "
                          "where there is one)")
    return "cpu"


# --- models -----------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=4)
def _load_model_cached(directory: str, device: str = "cpu") -> "VideoTok4D":
    from .model import from_pretrained  # lazy: torch loads on first use, not with `import vt4dcodec` / `vt4d`

    return from_pretrained(directory, device=device)


def load_model(model: "str | os.PathLike | VideoTok4D" = DEFAULT_MODEL, *, device: str = "cpu") -> "VideoTok4D":
    """A model by shipped id, by directory path, by the name of a directory under $VT4D_MODEL_PATH
    (``vt4dcodec.model.weights_io.model_directory``), or an already loaded one (returned as is), on ``device``
    (:data:`DEVICES`).  Each directory is loaded once per process and device.  Needs torch (the ``train``
    extra): MissingExtraError without it."""
    _require_torch("running the model's torch networks (runtime='torch')")
    from .model import VideoTok4D  # lazy: keeps torch out of `import vt4dcodec` / `vt4d` (as above)
    from .model.weights_io import model_directory

    where = torch_device(device)
    if isinstance(model, VideoTok4D):
        return model if device == "cpu" else model.to(where)
    return _load_model_cached(str(model_directory(model).resolve()), where)


@functools.lru_cache(maxsize=8)
def _open_onnx_cached(directory: str, views: int = 1, device: str = "cpu") -> "OnnxEncoder":
    from .model.onnx_encoder import OnnxEncoder

    return OnnxEncoder.open(directory, views=views, device=device)


@functools.lru_cache(maxsize=4)
def _open_renderer_cached(directory: str, device: str = "cpu") -> "OnnxRenderer":
    from .model.onnx_renderer import OnnxRenderer

    return OnnxRenderer.open(directory, device=device)


def load_encoder(model: "str | os.PathLike | VideoTok4D | OnnxEncoder" = DEFAULT_MODEL, runtime: str = "auto", *,
                 cameras: int = 1, device: str = "cpu") -> "VideoTok4D | OnnxEncoder":
    """The encoder of ``model`` for scenes of ``cameras`` source cameras on ``runtime`` (one of
    :data:`RUNTIMES`) and ``device`` (one of :data:`DEVICES`; module docstring).  A loaded model or encoder is
    returned as is (``runtime="onnx"`` then needs an :class:`OnnxEncoder`).  ModelError for an unknown runtime,
    or for ``"onnx"`` without onnxruntime; ModelNotFoundError for ``"onnx"`` where the model has no exported
    encoder for that many cameras; MissingExtraError where the torch runtime is needed and torch is not
    installed; DeviceError where ``device="cuda"`` finds no GPU."""
    from .model.directories import model_directory  # torch-free, as the ONNX encoder
    from .model.onnx_encoder import OnnxEncoder, has_onnx_encoder, onnx_available

    _check_runtime(runtime)
    _check_device(device)
    _require_a_runtime()
    if not isinstance(model, (str, os.PathLike)):  # a loaded VideoTok4D or OnnxEncoder
        if runtime == "onnx" and not isinstance(model, OnnxEncoder):
            raise ModelError("runtime='onnx' takes a model id or directory (or an OnnxEncoder), not a loaded torch model")
        return model if isinstance(model, OnnxEncoder) else load_model(model, device=device)
    if runtime == "torch":
        return load_model(model, device=device)
    directory = model_directory(model)
    exported = onnx_available() and has_onnx_encoder(directory, cameras)
    if runtime == "onnx" or (exported and (cameras == 1 or not torch_available())):
        return _open_onnx_cached(str(directory.resolve()), cameras, device)
    if not torch_available():
        raise MissingExtraError(f"{directory} has no exported encoder for {cameras} camera(s)"
                                f"{'' if onnx_available() else ' usable here (onnxruntime is not installed)'}, and the "
                                f"torch runtime is not installed: {TRAIN_EXTRA_HINT}")
    return load_model(directory, device=device)


def load_renderer(model: "str | os.PathLike | VideoTok4D | OnnxRenderer" = DEFAULT_MODEL, runtime: str = "auto", *,
                  device: str = "cpu") -> "VideoTok4D | OnnxRenderer":
    """The renderer of ``model`` on ``runtime`` and ``device`` (module docstring): the torch model, or the exported
    ``renderer.onnx`` on onnxruntime (``"auto"``: torch where it is installed, else onnx). A loaded model is returned
    as is. Errors as :func:`load_encoder`'s."""
    from .model.directories import model_directory
    from .model.onnx_renderer import OnnxRenderer, has_onnx_renderer
    from .model.onnx_session import onnx_available

    _check_runtime(runtime)
    _check_device(device)
    _require_a_runtime()
    if not isinstance(model, (str, os.PathLike)):
        if runtime == "onnx" and not isinstance(model, OnnxRenderer):
            raise ModelError("runtime='onnx' takes a model id or directory (or an OnnxRenderer), not a loaded torch model")
        return model if isinstance(model, OnnxRenderer) else load_model(model, device=device)
    if runtime == "torch" or (runtime == "auto" and torch_available()):
        return load_model(model, device=device)
    directory = model_directory(model)
    if runtime == "auto" and not (onnx_available() and has_onnx_renderer(directory)):
        raise MissingExtraError(f"{directory} has no exported renderer (renderer.onnx) usable here, and the torch "
                                f"runtime is not installed: {TRAIN_EXTRA_HINT}")
    return _open_renderer_cached(str(directory.resolve()), device)


def model_fingerprint(model: "VideoTok4D | OnnxEncoder | OnnxRenderer") -> ModelFingerprint:
    """The fingerprint a container stores for ``model`` (``VideoTok4D.stored_fingerprint``)."""
    return model.stored_fingerprint()


# --- encoding ---------------------------------------------------------------------------------------
def _open_source(capture: "Capture | CaptureManifest | str | os.PathLike") -> "Capture | CaptureManifest":
    """An in-memory capture as it is; a capture directory as its manifest (no media read yet)."""
    if isinstance(capture, (Capture, CaptureManifest)):
        return capture
    return read_manifest(capture)


def _pick_camera(capture: "Capture | CaptureManifest", camera: str | None) -> str:
    if camera is None:
        return capture.camera_names[0]
    if camera not in capture.camera_names:
        raise CaptureError(f"capture {capture.capture_id!r} has no camera {camera!r}; it has {capture.camera_names}")
    return camera


def parse_camera_list(cameras: "Sequence[str] | str", available: Sequence[str], *, label: str = "cameras"
                      ) -> list[str]:
    """``"all"``, ``"cam00,cam02"`` or a sequence of names -> the names in order, refused (naming
    ``label``) when empty or repeated. Whether each exists is the caller's check."""
    if isinstance(cameras, str):
        names = list(available) if cameras == "all" else [c.strip() for c in cameras.split(",")]
    else:
        names = list(cameras)
    if not names or any(not isinstance(n, str) or not n for n in names):
        raise CaptureError(f"{label} must name at least one camera ('all' or comma-separated names), got {cameras!r}")
    if len(set(names)) != len(names):
        raise CaptureError(f"{label} names a camera twice: {names}")
    return names


def _pick_cameras(capture: "Capture | CaptureManifest", camera: str | None,
                  cameras: "Sequence[str] | str | None") -> list[str]:
    """The encoded cameras: ``cameras`` ("all", or names in the order given) or the one ``camera``."""
    if cameras is None:
        return [_pick_camera(capture, camera)]
    if camera is not None:
        raise CaptureError("give camera= (one camera) or cameras= (several), not both")
    names = parse_camera_list(cameras, capture.camera_names)
    for name in names:
        _pick_camera(capture, name)
    return names


def _check_start(source: "Capture | CaptureManifest", start: int, frames: int) -> None:
    if isinstance(start, bool) or not isinstance(start, (int, np.integer)) or start < 0:
        raise CaptureError(f"start must be a non-negative frame index, got {start!r}")
    if start + frames > source.num_frames:
        raise CaptureError(
            f"capture {source.capture_id!r} has {source.num_frames} frames; a clip of {frames} frames starting at "
            f"frame {start} does not fit (this model encodes exactly {frames} frames per scene)"
        )


def read_clip(capture: "Capture | CaptureManifest | str | os.PathLike", names: Sequence[str], start: int,
              frames: int) -> Capture:
    """Cameras ``names`` over frames ``[start, start + frames)`` as a capture of ``frames`` frames (frame 0 is
    capture frame ``start``).  From a directory only that window of those cameras is decoded; an
    in-memory capture is sliced without copying."""
    source = _open_source(capture)
    _check_start(source, start, frames)
    if isinstance(source, CaptureManifest):
        return read_capture(source, cameras=list(names), start=int(start), num_frames=frames)
    stop = int(start) + frames
    return Capture(cameras={n: source.cameras[n][start:stop] for n in names},
                   frames={n: source.frames[n][start:stop] for n in names},
                   depth={n: source.depth[n][start:stop] for n in names if source.has_depth(n)} or None,
                   fps=source.fps, capture_id=source.capture_id, metadata=source.metadata)


def encode(
    capture: "Capture | CaptureManifest | str | os.PathLike",
    model: "str | os.PathLike | VideoTok4D | OnnxEncoder" = DEFAULT_MODEL,
    encoding: str | None = None,
    *,
    camera: str | None = None,
    cameras: "Sequence[str] | str | None" = None,
    start: int = 0,
    seed: int = 0,
    metadata: dict[str, Any] | None = None,
    fit: str = "crop",
    runtime: str = "auto",
    quality: int | None = None,
    device: str = "cpu",
    refine: int = 0,
    tune: str = "psnr",
) -> Scene:
    """Compress one clip of a capture -- one camera or several synchronized ones -- into a
    :class:`~vt4dcodec.format.Scene`.

    The token budget is per scene: encoding more cameras gives the same N_s static and N_d dynamic
    tokens, fused from every encoded camera (the encoder's queries attend to all of them; a model with
    ``anchor_views`` gives each encoded camera its share of the static tokens, anchored in its view).
    The file stores every encoded camera's trajectory (``Scene.extra_cameras`` after the first).

    Args:
        capture: a :class:`Capture`, or a capture directory (or its manifest): then only the clip's
            frames of the encoded cameras are read.
        model: shipped model id, model directory, or a loaded model (or :class:`OnnxEncoder`).
        encoding: token encoding used when the scene is saved (one of ``vt4dcodec.format.ENCODINGS``).
            Default (None, and no ``quality``): the model's default quality level (:func:`default_quality`)
            where it has one, else :data:`DEFAULT_ENCODING`.
        camera: the source camera (default: the capture's first camera).
        cameras: several source cameras instead: ``"all"``, or names (a list or ``"cam00,cam02"``).
            The first is the reference camera: its trajectory is the scene's stored cameras
            (``decode(..., "source")``), the others' are ``Scene.extra_cameras`` (pinhole, in order); the
            metadata lists every encoded camera's name (``metadata["vt4d"]["source_cameras"]``). Any
            trajectory, encoded or not, renders.
        start: first frame of the clip; the clip is ``model.config.frames`` frames long.
        seed: seeds track sampling, so the same capture and seed give the same tokens.
        metadata: user key/values stored in the file (bounded; see FORMAT.md "Metadata").
        fit: how frames of another aspect ratio become the model's square: ``"crop"`` (resize the
            shorter side, centre-crop: a portrait 9:16 frame loses 44 % of its pixels) or ``"pad"``
            (resize the longer side, letterbox on black bars: the whole picture is kept, at fewer
            pixels; recorded as ``metadata["vt4d"]["fit"]``).
        runtime: ``"auto"``, ``"torch"`` or ``"onnx"``: which runtime runs the encoder (module docstring).
        device: ``"cpu"``, ``"cuda"`` or ``"auto"``: where the encoder runs (module docstring).
        quality: a quality level of the model's entropy model (:func:`quality_levels`; 1 = the fewest bytes):
            the scene is stored as ``learned-rans`` at that level (``encoding`` is then ignored). ModelError for
            a model without quality levels.
        refine: iterations of encoder-side token refinement (:mod:`vt4dcodec.model.refine`): the tokens are moved
            so that the encoded cameras' renders from the stored values match their frames at a rate cost --
            fewer bytes and sharper encoded views for encode time (each iteration renders every encoded
            camera once, forward and backward). Needs a quality level and torch (the refinement runs on the
            torch model whatever runs the encoder). 0 (default): the encoder's tokens as they are.
        tune: what refinement optimises beside the rate: ``"psnr"`` (default; pixel MSE) or ``"ssim"`` (pixel MSE
            plus a small 1 - SSIM term: sharper structure and a higher SSIM for a few per cent more bytes and a
            PSNR about equal; docs/benchmarks/codecs.md). Only with ``refine`` > 0.
    Returns:
        The scene: tokens (float32, rounded to ``encoding`` only when saved), the fitted source
        cameras, the model fingerprint, metadata and provenance ("encoded").
    """
    source = _open_source(capture)
    check_fit(fit)
    names = _pick_cameras(source, camera, cameras)
    net = load_encoder(model, runtime, cameras=len(names), device=device)
    encoding, quality = _quality_encoding(net, encoding, quality, model)
    refiner = _refiner(net, model, refine, quality, device, tune)
    clip = read_clip(source, names, start, net.config.frames)
    return _encode_clip(clip, net, encoding, names, int(start), seed, metadata, fit, quality, refine, refiner, tune)


def quality_levels(model: "str | os.PathLike | VideoTok4D | OnnxEncoder" = DEFAULT_MODEL) -> tuple[int, ...]:
    """The quality levels (1 .. L) a model offers: ``()`` for a model without an entropy model."""
    from .model.directories import model_directory, read_model_meta  # torch-free

    config = model.config if not isinstance(model, (str, os.PathLike)) else \
        read_model_meta(model_directory(model))["config"]
    return tuple(range(1, config.entropy_levels + 1))


def default_quality(model: "str | os.PathLike | VideoTok4D | OnnxEncoder" = DEFAULT_MODEL) -> int | None:
    """The quality level a model's scenes are stored at when neither a level nor an encoding is asked for
    (recorded in its directory when it ships, chosen by the rate-distortion rule of docs/training.md); None for
    a model without one (then :data:`DEFAULT_ENCODING`)."""
    if not isinstance(model, (str, os.PathLike)):
        return getattr(model, "default_quality", None)
    from .model.directories import model_directory, read_model_meta  # torch-free

    value = read_model_meta(model_directory(model)).get("default_quality")
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def model_tables(model: "VideoTok4D") -> EntropyTables | None:
    """The frozen entropy tables of a loaded model (None without an entropy model or before
    ``update_entropy``): what a learned-rans file of this model is read and written with."""
    from .model.tables import frozen_tables  # torch-free

    if getattr(model, "entropy", None) is None:
        return None
    return frozen_tables(model, model_fingerprint(model))


def __getattr__(name: str) -> Any:
    if name == "QUALITY_LEVELS":
        return quality_levels(DEFAULT_MODEL)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _quality_encoding(net: "VideoTok4D | OnnxEncoder", encoding: str | None, quality: int | None,
                      source: "str | os.PathLike | VideoTok4D | OnnxEncoder") -> tuple[str, int | None]:
    """(encoding, quality level) a scene of ``net`` (loaded from ``source``) is stored with: learned-rans when a
    quality level is asked for -- or when nothing is asked for and the model has a default level -- its model's
    tables then registered so that the scene saves wherever the model lives; else ``encoding`` (default
    :data:`DEFAULT_ENCODING`)."""
    if quality is None and encoding is None:  # an exported encoder (OnnxEncoder) reads it from its directory
        quality = net.default_quality if hasattr(net, "default_quality") else \
            default_quality(source) if isinstance(source, (str, os.PathLike)) else None
    if quality is None:
        return encoding or DEFAULT_ENCODING, None
    from .errors import ModelError

    levels = quality_levels(net)
    if not levels:
        raise ModelError(f"--quality {quality}: model {model_fingerprint(net).short()} has no quality levels (no "
                         f"entropy model); leave --quality out and choose an --encoding")
    if isinstance(quality, bool) or not isinstance(quality, int) or quality not in levels:
        raise ModelError(f"--quality must be one of {list(levels)} for this model, got {quality!r}")
    from .format.learned import register_tables

    if isinstance(source, (str, os.PathLike)):
        from .model.directories import model_directory
        from .model.tables import tables_from_directory

        tables = tables_from_directory(model_directory(source), model_fingerprint(net))
    elif not hasattr(net, "entropy") and isinstance(getattr(net, "directory", None), Path):
        from .model.tables import tables_from_directory  # an exported encoder: the tables beside its graphs

        tables = tables_from_directory(net.directory, model_fingerprint(net))
    else:
        found = model_tables(net) if hasattr(net, "entropy") else None
        if found is None:
            raise ModelError("--quality with a loaded model needs its frozen tables (VideoTok4D.update_entropy); "
                             "or pass the model directory")
        tables = found
    register_tables(tables)
    return "learned-rans", quality


def encode_clips(
    capture: "Capture | CaptureManifest | str | os.PathLike",
    model: "str | os.PathLike | VideoTok4D | OnnxEncoder" = DEFAULT_MODEL,
    encoding: str | None = None,
    *,
    camera: str | None = None,
    cameras: "Sequence[str] | str | None" = None,
    seed: int = 0,
    metadata: dict[str, Any] | None = None,
    fit: str = "crop",
    runtime: str = "auto",
    quality: int | None = None,
    device: str = "cpu",
    refine: int = 0,
    tune: str = "psnr",
) -> list[Scene]:
    """Split a long capture into consecutive clips of ``model.config.frames`` frames and encode each
    (from a directory, one clip is read at a time); the arguments are :func:`encode`'s.

    A tail shorter than one clip is dropped; each scene's metadata records its ``clip_start``.
    """
    source = _open_source(capture)
    check_fit(fit)
    names = _pick_cameras(source, camera, cameras)
    net = load_encoder(model, runtime, cameras=len(names), device=device)
    encoding, quality = _quality_encoding(net, encoding, quality, model)
    refiner = _refiner(net, model, refine, quality, device, tune)
    T = net.config.frames
    if source.num_frames < T:
        raise CaptureError(f"capture has {source.num_frames} frames; model clips are {T} frames")
    return [_encode_clip(read_clip(source, names, s, T), net, encoding, names, s, seed, metadata, fit, quality,
                         refine, refiner, tune)
            for s in range(0, source.num_frames - T + 1, T)]


def _refiner(net: "VideoTok4D | OnnxEncoder", model: "str | os.PathLike | VideoTok4D | OnnxEncoder", refine: int,
             quality: int | None, device: str, tune: str = "psnr") -> "VideoTok4D | None":
    """The torch model that refines the tokens of ``net``'s scenes (``refine`` iterations; None for 0): ``net``
    itself when it runs on torch, else the torch model of the same directory. ModelError without a quality level,
    MissingExtraError without torch."""
    from .model.onnx_encoder import OnnxEncoder  # torch-free

    if isinstance(refine, bool) or not isinstance(refine, int) or not 0 <= refine <= MAX_REFINE:
        raise ModelError(f"--refine must be an integer from 0 to {MAX_REFINE} (iterations), got {refine!r}")
    if tune not in TUNES:
        raise ModelError(f"--tune must be one of {', '.join(TUNES)}, got {tune!r}")
    if refine == 0:
        if tune != "psnr":
            raise ModelError(f"--tune {tune} sets what refinement optimises: give --refine N (N > 0) with it")
        return None
    if quality is None:
        raise ModelError("--refine works on the stored values of a quality level: give --quality (or leave "
                         "--encoding out for the model's default level)")
    _require_torch("--refine (encoder-side refinement)")
    if not isinstance(net, OnnxEncoder):
        return net
    if not isinstance(model, (str, os.PathLike)):
        raise ModelError("--refine needs the torch model: pass a model id or directory (or a loaded VideoTok4D), "
                         "not an OnnxEncoder")
    return load_model(model, device=device)


def encode_views(net: "VideoTok4D | OnnxEncoder", views: "Sequence[tuple[np.ndarray, Trajectory, np.ndarray | None]]",
                 seed: int = 0, feedback: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The tokens of one scene seen by ``views``, each (frames (T, H, W, 3) uint8, trajectory, depth (T, H, W) or
    None: estimated) already fitted to the model's clip, encoded by ``net`` (torch or ONNX): (Z_s (1, N_s, d),
    Z_d (1, N_d, d)) float32; ``seed`` seeds the track sampling; ``feedback=False``: the first pass of a model
    with render feedback."""
    from .model.inputs.preprocess import prepare_source  # lazy: `import vt4dcodec` / `vt4d` load no OpenCV
    from .model.onnx_encoder import OnnxEncoder  # torch-free

    cfg = net.config
    clips = [prepare_source(frames, trajectory, depth, latent_hw=(cfg.latent_size, cfg.latent_size),
                            num_tracks=cfg.n_tracks, seed=seed, motion_isolation=cfg.motion_isolation)
             for frames, trajectory, depth in views]
    if isinstance(net, OnnxEncoder):
        return net.encode(clips, feedback=feedback)
    import torch  # lazy: only the torch runtime loads it

    from .model.inputs.source_inputs import SourceBatch

    with torch.no_grad():
        t_s, t_d = net.encode(SourceBatch.collate(clips, views=len(clips)).to(next(net.parameters()).device),
                              feedback=feedback)
    return t_s.cpu().numpy(), t_d.cpu().numpy()


def _encode_clip(clip: Capture, net: "VideoTok4D | OnnxEncoder", encoding: str, names: list[str], start: int,
                 seed: int, metadata: dict[str, Any] | None, fit: str = "crop", quality: int | None = None,
                 refine: int = 0, refiner: "VideoTok4D | None" = None, tune: str = "psnr") -> Scene:
    """Encode ``clip`` (exactly the model's frame count; frame 0 is capture frame ``start``); with ``refiner``,
    refine the tokens ``refine`` iterations for ``quality``, optimising ``tune``."""
    cfg = net.config
    fitted = fit_capture(clip, height=cfg.image_size, width=cfg.image_size, num_frames=cfg.frames, fit=fit)
    # the world origin is the renderer's depth reference; one too near an encoded camera moves (vt4dcodec.reference)
    centre = model_centre(cfg.reference_frame, [fitted.cameras[n] for n in names])
    views = [(fitted.frames[n], move_trajectory(fitted.cameras[n], centre), fitted.depth[n] if fitted.has_depth(n) else None)
             for n in names]
    depth_sources = ["capture" if depth is not None else "estimated" for _, _, depth in views]
    z_s, z_d = encode_views(net, views, seed, feedback=cfg.feeds_back(quality))  # (the level's pass)
    info: dict[str, Any] = {"source_camera": names[0], "clip_start": int(start), "clip_frames": int(cfg.frames),
                            "depth_source": depth_sources[0]}
    if centre is not None:
        info[CENTRE_KEY] = centre_to_metadata(centre)
    if refiner is not None:  # _refiner gave one: refine > 0 and a quality level
        from .model.refine import TUNE_SSIM_WEIGHT, refine_tokens

        tables = model_tables(refiner)
        assert tables is not None and quality is not None  # _quality_encoding checked the level and its tables
        s, d = refine_tokens(refiner, z_s[0], z_d[0], np.stack([v[0] for v in views]),
                             np.stack([v[1].K for v in views]), np.stack([v[1].w2c for v in views]),
                             tables=tables, quality=quality, iterations=refine, seed=seed,
                             ssim_weight=TUNE_SSIM_WEIGHT[tune])
        z_s, z_d = s[None], d[None]
    if len(names) > 1:
        info["source_cameras"] = list(names)
    if fit != "crop":
        info["fit"] = fit  # absent: "crop"
    # the further encoded cameras as the extra cameras section stores them (pinhole, the reference camera's
    # frame times): a model with config.anchor_views places its tokens in them, and the file says what was seen
    extra = tuple(dataclasses.replace(fitted.cameras[n], distortion=None, timestamps=None) for n in names[1:])
    return Scene(
        static_tokens=z_s[0].astype(np.float32),
        dynamic_tokens=z_d[0].astype(np.float32),
        cameras=fitted.cameras[names[0]],
        extra_cameras=extra,
        fingerprint=model_fingerprint(net),
        metadata={**(metadata or {}), "vt4d": info},
        provenance=Provenance.now(clip.capture_id, "encoded"),
        encoding=encoding,
        quality=quality,
    )


# --- decoding ---------------------------------------------------------------------------------------
def scene_fit(metadata: dict[str, Any] | None) -> str:
    """How the scene's clip was fitted to the model's square: ``"crop"`` (the default) or ``"pad"``."""
    info = (metadata or {}).get("vt4d")
    fit = info.get("fit", "crop") if isinstance(info, dict) else "crop"
    return fit if fit in ("crop", "pad") else "crop"


def resolve_trajectory(spec: "Trajectory | str | os.PathLike", reference: Trajectory, *, size: int,
                       max_frames: int, metadata: dict[str, Any] | None = None,
                       capture: "Capture | str | os.PathLike | None" = None,
                       source_capture_id: str | None = None) -> Trajectory:
    """A target trajectory for rendering, fitted to the model's ``size`` x ``size`` image.

    ``spec`` is a :class:`Trajectory`, ``"source"`` (the scene's own cameras), ``"camera:NAME"`` (capture
    camera NAME over the scene's clip; needs ``capture``), a preset spec such as
    ``"orbit:degrees=30,distance=2"`` (built from the scene's first source camera), or a path to a
    trajectory JSON file.  A trajectory longer than the scene is cut to the clip window recorded in the
    scene's ``metadata``.  Trajectories for another image size are resized and centre-cropped the way
    captures are (intrinsics updated), with the scene's recorded fit (``metadata["vt4d"]["fit"]``: a
    scene encoded with ``fit="pad"`` letterboxes them too).
    """
    if isinstance(spec, Trajectory):
        traj = cut_to_clip(spec, metadata, max_frames)
    elif is_camera_spec(spec):
        traj = camera_target(str(spec), capture, metadata, source_capture_id, max_frames)
    elif isinstance(spec, (str, os.PathLike)) and str(spec) == "source":
        traj = reference
    elif isinstance(spec, (str, os.PathLike)) and (str(spec).endswith(".json") or Path(spec).is_file()):
        traj = load_trajectory(spec)
    elif isinstance(spec, str):
        preset, params = parse_trajectory_spec(spec)
        traj = make_trajectory(preset, reference, **params)
    else:
        raise TrajectoryError(f"a trajectory must be a Trajectory, 'source', a preset spec or a JSON path, "
                              f"got {type(spec).__name__}")
    if traj.num_frames > max_frames:
        raise TrajectoryError(f"trajectory has {traj.num_frames} frames; a scene covers {max_frames} frames")
    if traj.distortion is not None and np.any(traj.distortion):
        raise TrajectoryError("target trajectories must be pinhole (no distortion terms): the renderer draws "
                              "ideal pinhole images; render the undistorted view with "
                              "dataclasses.replace(trajectory, distortion=None) or 'camera:NAME'")
    if (traj.width, traj.height) != (size, size):
        traj = fit_trajectory(traj, plan_fit(traj.width, traj.height, out_height=size, out_width=size,
                                             fit=scene_fit(metadata)))
    return traj


@dataclass
class SceneDecoder:
    """A loaded scene bound to its model: render as many trajectories as you like, no re-encoding.

    Create with :meth:`open`.  ``render`` returns (T, H, W, 3) uint8 frames.  ``model`` is the torch model or
    the exported renderer on onnxruntime (:class:`~vt4dcodec.model.onnx_renderer.OnnxRenderer`; module
    docstring, "Runtimes").
    """

    scene: Scene
    model: "VideoTok4D | OnnxRenderer"

    @classmethod
    def open(cls, scene_or_path: "Scene | str | os.PathLike | bytes", *,
             model: "str | os.PathLike | VideoTok4D | OnnxRenderer | None" = None, force: bool = False,
             runtime: str = "auto", device: str = "cpu") -> "SceneDecoder":
        """Load the scene and the model that made it (found from the stored fingerprint unless ``model``
        is given), its renderer on ``runtime`` and ``device`` (:func:`load_renderer`).  A different model is
        refused with both fingerprints named unless ``force``."""
        scene = scene_or_path if isinstance(scene_or_path, Scene) else _load_scene(scene_or_path, model)
        stored = scene.fingerprint
        try:
            net = load_renderer(stored.model_id if model is None else model, runtime, device=device)
        except ModelNotFoundError as exc:
            raise ModelNotFoundError(f"the scene was made by {stored.short()}: {exc}") from None
        from .model.directories import same_networks  # torch-free

        have = model_fingerprint(net)
        if not have.matches(stored) and not same_networks(getattr(net, "network_digests", None), have, stored,
                                                     getattr(net, "token_sources", ())):
            if not force:
                raise ModelMismatchError(
                    f"the scene was encoded by {stored.short()} but the model given is {have.short()}; "
                    "decode with the model that made it, or force=True (--force) to try anyway"
                )
            if (have.static_shape, have.dynamic_shape) != (stored.static_shape, stored.dynamic_shape):
                raise ModelMismatchError(
                    f"cannot force: token shapes differ ({stored.short()} vs {have.short()})")
        centre_from_metadata(scene.metadata)  # a malformed reference point: refused now, not at the first render
        return cls(scene=scene, model=net)

    def trajectory(self, spec: "Trajectory | str | os.PathLike", *,
                   capture: "Capture | str | os.PathLike | None" = None) -> Trajectory:
        """``spec`` resolved for this scene (:func:`resolve_trajectory`); ``capture`` serves ``"camera:NAME"``,
        which for an encoded camera the file itself serves when no capture is given."""
        cfg = self.model.config
        if capture is None and is_camera_spec(spec):
            spec = self.encoded_cameras().get(check_camera_spec(str(spec)), spec)
        return resolve_trajectory(spec, self.scene.cameras, size=cfg.image_size, max_frames=cfg.frames,
                                  metadata=self.scene.metadata, capture=capture,
                                  source_capture_id=getattr(self.scene.provenance, "source_capture_id", None))

    def encoded_cameras(self) -> dict[str, Trajectory]:
        """Encoded camera name -> its stored trajectory (the scene's cameras, then its extra cameras, named
        by ``metadata["vt4d"]``); empty when the metadata does not name them."""
        info = self.scene.metadata.get("vt4d")
        info = info if isinstance(info, dict) else {}
        names = info.get("source_cameras", [info["source_camera"]] if "source_camera" in info else [])
        stored = (self.scene.cameras, *self.scene.extra_cameras)
        if not isinstance(names, list) or len(names) != len(stored) or not all(isinstance(n, str) for n in names):
            return {}
        return dict(zip(names, stored))

    def centre(self) -> "np.ndarray | None":
        """The world point the renderer measures depths from, metres (the file's ``metadata["vt4d"]["centre_mm"]``;
        None: the world origin; :mod:`vt4dcodec.reference`)."""
        return centre_from_metadata(self.scene.metadata)

    def model_w2c(self, w2c: np.ndarray) -> np.ndarray:
        """World-to-camera matrices (..., 4, 4) of the capture's frame as the renderer takes them: in the frame
        whose origin is :meth:`centre` (float32)."""
        return move_origin(np.asarray(w2c, np.float64), self.centre()).astype(np.float32)

    def source_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The encoded cameras that place the tokens (the scene's cameras, then its extra cameras), fitted to
        the model's image, as the renderer takes them (:meth:`model_w2c`): (K (V, T, 3, 3), w2c (V, T, 4, 4))
        float32."""
        encoded = [self.trajectory("source")] + [self.trajectory(t) for t in self.scene.extra_cameras]
        return (np.stack([t.K for t in encoded]).astype(np.float32),
                self.model_w2c(np.stack([t.w2c for t in encoded])))

    def source_cameras(self) -> tuple["torch.Tensor", "torch.Tensor"]:
        """:meth:`source_arrays` as torch tensors with a batch axis: (K (1, V, T, 3, 3), w2c (1, V, T, 4, 4))."""
        import torch  # lazy: keeps torch out of `import vt4dcodec` / `vt4d`

        K, w2c = self.source_arrays()
        return torch.from_numpy(K)[None], torch.from_numpy(w2c)[None]

    def render(self, trajectory: "Trajectory | str | os.PathLike" = "source", *, steps: int | None = DEFAULT_STEPS,
               seed: int = 0, drop_static: bool = False, drop_dynamic: bool = False,
               capture: "Capture | str | os.PathLike | None" = None) -> np.ndarray:
        """Frames (T, H, W, 3) uint8 of the scene seen along ``trajectory`` (deterministic per seed)."""
        return self.render_many([trajectory], steps=steps, seed=seed, drop_static=drop_static,
                                drop_dynamic=drop_dynamic, capture=capture)[0]

    def render_many(self, trajectories: Sequence["Trajectory | str | os.PathLike"], *, steps: int | None = DEFAULT_STEPS,
                    seed: int = 0, drop_static: bool = False, drop_dynamic: bool = False,
                    capture: "Capture | str | os.PathLike | None" = None) -> list[np.ndarray]:
        """Render several trajectories from the one token state, each with the same ``seed``.

        ``"camera:NAME"`` takes capture camera NAME over the scene's clip from ``capture`` (a Capture or
        a capture directory: the one the scene was encoded from)."""
        from .model.onnx_renderer import OnnxRenderer  # torch-free

        resolved = [self.trajectory(spec, capture=capture) for spec in trajectories]
        if isinstance(self.model, OnnxRenderer):
            return self._render_onnx(self.model, resolved, steps=steps, seed=seed, drop_static=drop_static,
                                     drop_dynamic=drop_dynamic)
        import torch  # lazy: keeps torch out of `import vt4dcodec` / `vt4d`

        device = next(self.model.parameters()).device
        z_s = torch.from_numpy(np.ascontiguousarray(self.scene.static_tokens, dtype=np.float32))[None].to(device)
        z_d = torch.from_numpy(np.ascontiguousarray(self.scene.dynamic_tokens, dtype=np.float32))[None].to(device)
        source = self.source_cameras() if self.model.needs_source else None
        out: list[np.ndarray | None] = [None] * len(resolved)
        for chunk in _render_batches(resolved):
            n = len(chunk)
            K = torch.from_numpy(np.stack([resolved[i].K for i in chunk]).astype(np.float32))
            w2c = torch.from_numpy(self.model_w2c(np.stack([resolved[i].w2c for i in chunk])))
            src = None if source is None else tuple(t.expand(n, *t.shape[1:]) for t in source)
            frames = self.model.render(z_s.expand(n, -1, -1), z_d.expand(n, -1, -1), K, w2c, steps=steps,
                                       seed=seed, drop_static=drop_static, drop_dynamic=drop_dynamic, source=src)
            videos = (frames.permute(0, 1, 3, 4, 2).cpu().numpy() * 255.0).round().clip(0, 255).astype(np.uint8)
            for i, video in zip(chunk, videos):
                out[i] = video
        return [v for v in out if v is not None]

    def _render_onnx(self, renderer: "OnnxRenderer", resolved: list[Trajectory], *, steps: int | None, seed: int,
                     drop_static: bool, drop_dynamic: bool) -> list[np.ndarray]:
        """:meth:`render_many` on the exported renderer: views of one frame count together, RENDER_BATCH at a time."""
        z_s = np.ascontiguousarray(self.scene.static_tokens, dtype=np.float32)[None]
        z_d = np.ascontiguousarray(self.scene.dynamic_tokens, dtype=np.float32)[None]
        K_src = w2c_src = None
        if renderer.needs_source:  # the encoded cameras at their middle frame, as VideoTok4D.render_cameras
            K_all, w2c_all = self.source_arrays()
            mid = K_all.shape[1] // 2
            K_src, w2c_src = K_all[None, :, mid], w2c_all[None, :, mid]
        out: list[np.ndarray | None] = [None] * len(resolved)
        for chunk in _render_batches(resolved):
            n = len(chunk)
            K = np.stack([resolved[i].K for i in chunk]).astype(np.float32)
            w2c = self.model_w2c(np.stack([resolved[i].w2c for i in chunk]))
            src = (None, None) if K_src is None else (np.repeat(K_src, n, 0), np.repeat(w2c_src, n, 0))
            frames = renderer.render(np.repeat(z_s, n, 0), np.repeat(z_d, n, 0), K, w2c, *src, steps=steps,
                                     seed=seed, drop_static=drop_static, drop_dynamic=drop_dynamic)
            videos = (frames.transpose(0, 1, 3, 4, 2) * np.float32(255.0)).round().clip(0, 255).astype(np.uint8)
            for i, video in zip(chunk, videos):
                out[i] = video
        return [v for v in out if v is not None]


def _render_batches(resolved: Sequence[Trajectory]) -> list[list[int]]:
    """Indices of ``resolved`` in the batches :meth:`SceneDecoder.render_many` renders: views of one frame count
    together, RENDER_BATCH at a time (the renderer gives each item the same seeded noise, so a view is the same
    as rendered alone)."""
    by_length: dict[int, list[int]] = {}
    for i, traj in enumerate(resolved):
        by_length.setdefault(traj.num_frames, []).append(i)
    return [indices[start:start + RENDER_BATCH] for indices in by_length.values()
            for start in range(0, len(indices), RENDER_BATCH)]


def _load_scene(source: "str | os.PathLike | bytes", model: "str | os.PathLike | VideoTok4D | OnnxRenderer | None"
                ) -> Scene:
    """``load(source)``; a learned-rans file whose model is not installed reads with the tables of ``model``
    (a model directory or a loaded model given to the decoder), when that is the file's model."""
    try:
        return load(source)
    except EntropyTablesError:
        if model is None:
            raise
        if not isinstance(model, (str, os.PathLike)):  # a loaded model: its own tables, if it made the file
            if not hasattr(model, "entropy"):  # an exported renderer: its directory's tables
                model = model.directory
                from .model.tables import tables_from_directory

                return load(source, tables=tables_from_directory(model, open_scene(source).fingerprint))
            tables = model_tables(model)
            if tables is None or tables.fingerprint != open_scene(source).fingerprint:
                raise
            return load(source, tables=tables)
        from .model.directories import model_directory
        from .model.tables import tables_from_directory

        stored = open_scene(source).fingerprint
        return load(source, tables=tables_from_directory(model_directory(model), stored))


def decode(scene_or_path: "Scene | str | os.PathLike | bytes", trajectory: "Trajectory | str | os.PathLike" = "source",
           *, steps: int | None = DEFAULT_STEPS, seed: int = 0, model: "str | os.PathLike | VideoTok4D | None" = None,
           force: bool = False, runtime: str = "auto", device: str = "cpu") -> np.ndarray:
    """Render a stored scene along ``trajectory``: (T, H, W, 3) uint8 frames, on ``runtime`` and ``device``
    (module docstring).

    For several trajectories of one scene use :class:`SceneDecoder` (loads the model once).
    """
    return SceneDecoder.open(scene_or_path, model=model, force=force, runtime=runtime,
                             device=device).render(trajectory, steps=steps, seed=seed)


def iter_capture_dirs(root: str | os.PathLike) -> Iterable[Path]:
    """Capture directories (holding a manifest) directly under ``root``, sorted by name."""
    root = Path(root)
    return [p for p in sorted(root.iterdir()) if (p / MANIFEST_NAME).is_file()]
