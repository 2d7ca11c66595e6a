"""Co4DGen generation: one video + its cameras + an anchor trajectory -> one sampled 4D token state.

    from vt4dcodec.generate import generate
    scene = generate(frames, trajectory, "orbit:degrees=20", seed=0)      # a Scene, provenance "generated"
    views = SceneDecoder.open(scene).render_many(["source", "pan:degrees=15", ...])

The prior samples the token state of the anchor camera a, Z^a = [Z_s^a; Z_d^a], conditioned on the
video V_c with its cameras P_c and on P_a.  The scene stores those tokens, the anchor trajectory as its
cameras and the fingerprint of the tokenizer the prior was trained on, so the ordinary decoder renders
any number of views from it without sampling again.  Torch is imported lazily.  The prior runs on torch or,
like the codec's networks, as graphs exported beside its weights on onnxruntime (``prior-condition.onnx``,
``prior-velocity.onnx``; ``vt4dcodec.model.onnx_prior``; tokens equal to float rounding): ``runtime="auto"``
takes torch where it is installed, else the graphs (a prior without them then raises
:class:`~vt4dcodec.errors.MissingExtraError` naming the ``train`` extra).  ``device=`` runs it on the CPU or a
CUDA GPU (``vt4dcodec.codec.DEVICES``).
"""

from __future__ import annotations

import functools
import os
from typing import TYPE_CHECKING, Any

import numpy as np

from .cameras import Trajectory
from .capture.capture import Capture
from .capture.resample import fit_capture
from .errors import CaptureError, MissingExtraError, ModelError, TrajectoryError
from .format import Provenance, Scene
from .reference import CENTRE_KEY, centre_to_metadata, model_centre, move_trajectory

if TYPE_CHECKING:  # pragma: no cover
    from .model.onnx_prior import OnnxPrior
    from .model.prior import Co4DGen

__all__ = ["generate", "load_prior_model", "fit_conditioning", "conditioning_tokens", "sampler_setting", "DEFAULT_PRIOR", "DEFAULT_PRIOR_STEPS",
           "GENERATED_ENCODING"]

DEFAULT_PRIOR = "co4dgen-tiny"
DEFAULT_PRIOR_STEPS = 16  # the steps of a prior that records no sampler setting (model.directories.DEFAULT_SAMPLER)
# Generated scenes are saved in codec.DEFAULT_ENCODING, int4, also beside vt4d-tiny 2.0.0 (whose encoded scenes are learned-rans
# at its default level): they carry the fingerprint of the tokenizer the prior was trained on (1.0.0's networks), which has no
# entropy tables of its own.  Before 2.0.0 encoded scenes used the same default (int4 for vt4d-tiny 1.0.0, 0.13.0 and 0.12.0, int4-rans
# for 0.11.0, int4 for 0.10.0 and 0.9.0, chosen by the rate-distortion rule on encoded scenes; int5-rans for 0.8.0, int4-rans for 0.7.0).  Measured earlier on co4dgen-tiny 0.3.0
# samples (6 held-out test scenes, camera 0, anchor "source", seed 0, rendered by vt4d-tiny 0.3.0
# against the conditioning video): int4-rans was within 0.07 dB of float32 tokens on every scene.
GENERATED_ENCODING = "int4"


@functools.lru_cache(maxsize=4)
def _load_prior_cached(directory: str, device: str = "cpu") -> "Co4DGen":
    from .model.weights_io import load_prior

    return load_prior(directory).to(device)


@functools.lru_cache(maxsize=4)
def _open_onnx_prior_cached(directory: str, device: str = "cpu") -> "OnnxPrior":
    from .model.onnx_prior import OnnxPrior

    return OnnxPrior.open(directory, device=device)


def load_prior_model(model: "str | os.PathLike | Co4DGen | OnnxPrior" = DEFAULT_PRIOR, *, runtime: str = "auto",
                     device: str = "cpu") -> "Co4DGen | OnnxPrior":
    """A prior by shipped id, by directory, by the name of a directory under $VT4D_MODEL_PATH (the
    lookup of ``vt4dcodec.model.directories.model_directory``, as for tokenizers), or an already loaded
    :class:`Co4DGen` or ``OnnxPrior`` (returned as is), on ``runtime`` (``codec.RUNTIMES``: ``"auto"`` takes
    torch where it is installed, else the exported graphs) and ``device`` (``codec.DEVICES``).  Each directory is
    loaded once per process, runtime and device.  MissingExtraError where torch is needed and not installed."""
    from .codec import RUNTIMES, TRAIN_EXTRA_HINT, torch_available, torch_device
    from .model.directories import PRIOR_META_FILE, model_directory
    from .model.onnx_prior import OnnxPrior, has_onnx_prior
    from .model.onnx_session import check_device, onnx_available

    if runtime not in RUNTIMES:
        raise ModelError(f"runtime must be one of {RUNTIMES}, got {runtime!r}")
    check_device(device)
    if isinstance(model, OnnxPrior):
        return model
    if not isinstance(model, (str, os.PathLike)):  # a loaded Co4DGen (torch is installed)
        if model.tokenizer_fingerprint is None:
            raise ModelError("this prior records no tokenizer fingerprint: load it with load_prior")
        return model if device == "cpu" else model.to(torch_device(device))
    directory = model_directory(model, PRIOR_META_FILE)
    if runtime == "torch" or (runtime == "auto" and torch_available()):
        if not torch_available():
            raise MissingExtraError(f"runtime='torch' samples the prior with torch, which is not installed: "
                                    f"{TRAIN_EXTRA_HINT}")
        return _load_prior_cached(str(directory.resolve()), torch_device(device))
    if runtime == "auto" and not (onnx_available() and has_onnx_prior(directory)):
        raise MissingExtraError(f"{directory} has no exported prior graphs usable here, and torch, which samples the "
                                f"prior otherwise, is not installed: {TRAIN_EXTRA_HINT}")
    return _open_onnx_prior_cached(str(directory.resolve()), device)


def fit_conditioning(video: np.ndarray, cameras: Trajectory, *, size: int, frames: int, start: int = 0
                     ) -> tuple[np.ndarray, Trajectory]:
    """The conditioning clip as the prior takes it: ``frames`` frames from ``start``, undistorted,
    resized and centre-cropped to ``size`` x ``size`` with the intrinsics updated (like ``encode``)."""
    if not isinstance(cameras, Trajectory):
        raise TrajectoryError("cameras must be a vt4dcodec.cameras.Trajectory (one pose per video frame)")
    if not isinstance(video, np.ndarray) or video.dtype != np.uint8 or video.ndim != 4 or video.shape[-1] != 3:
        raise CaptureError("video must be a (T, H, W, 3) uint8 array")
    if isinstance(start, bool) or not isinstance(start, (int, np.integer)) or start < 0:
        raise CaptureError(f"start must be a non-negative frame index, got {start!r}")
    if start + frames > video.shape[0]:
        raise CaptureError(f"the video has {video.shape[0]} frames; the prior takes a clip of {frames} frames "
                           f"starting at frame {start}")
    single = Capture(cameras={"c": cameras}, frames={"c": video}, capture_id="generate-input")
    fitted = fit_capture(single, height=size, width=size, num_frames=frames, start=start)
    return fitted.frames["c"], fitted.cameras["c"]


def generate(
    video: np.ndarray,
    cameras: Trajectory,
    anchor_trajectory: "Trajectory | str | os.PathLike" = "source",
    *,
    seed: int = 0,
    model: "str | os.PathLike | Co4DGen" = DEFAULT_PRIOR,
    steps: int | None = None,
    method: str | None = None,
    guidance: float | None = None,
    start: int = 0,
    encoding: str = GENERATED_ENCODING,
    metadata: dict[str, Any] | None = None,
    source_capture_id: str | None = None,
    runtime: str = "auto",
    device: str = "cpu",
    tokenizer: "str | os.PathLike | Any | None" = None,
) -> Scene:
    """Sample one joint token state Z^a ~ p(Z^a | V_c, P_c, P_a) and return it as a Scene.

    Args:
        video: (T, H, W, 3) uint8 conditioning video V_c (any size; fitted like an encoded clip).
        cameras: its trajectory P_c (one pose per video frame).
        anchor_trajectory: P_a -- a :class:`Trajectory`, ``"source"`` (P_c itself), a preset spec such as
            ``"orbit:degrees=30"`` built from the first conditioning camera, or a trajectory JSON path;
            it must cover the clip's frames.
        seed: seeds the prior's noise: same inputs, seed and sampler setting -> the same tokens.
        model: prior id ("co4dgen-tiny"), prior directory, or a loaded prior.
        steps, method, guidance: sampler steps, "euler" / "heun" and classifier-free guidance (1: none);
            each None takes the setting the prior records (``prior.sampler``, chosen for it by measurement;
            heun, 16 steps, no guidance for a prior that records none).
        start: first video frame of the clip.
        encoding: token encoding used when the scene is saved (default int4, the codec's default;
            see GENERATED_ENCODING for the measurement on generated tokens).
        metadata: user key/values stored in the file.
        source_capture_id: the capture the video came from, recorded in the provenance (``vt4d info``).
        runtime: ``"auto"``, ``"torch"`` or ``"onnx"``: which runtime samples the prior (module docstring).
        device: ``"cpu"``, ``"cuda"`` or ``"auto"``: where the prior runs (DeviceError for ``"cuda"`` without a GPU).
        tokenizer: for a prior conditioned on the tokenizer's tokens of the video (``config.cond_tokens``), the
            encoder that computes them (an id, a directory or a loaded encoder; default: the tokenizer the prior
            was trained on), on ``runtime`` and ``device``; it must be that tokenizer (ModelError otherwise).
    Returns:
        A :class:`Scene` whose tokens are the sample, cameras P_a, fingerprint the tokenizer's the prior
        was trained on, and provenance kind "generated".
    """
    from .codec import resolve_trajectory  # (the package root loads the codec on first use too)
    from .model.onnx_prior import OnnxPrior  # torch-free

    prior = load_prior_model(model, runtime=runtime, device=device)
    cfg = prior.config
    steps, method, guidance = sampler_setting(prior, steps, method, guidance)
    frames, cond_traj = fit_conditioning(video, cameras, size=cfg.image_size, frames=cfg.frames, start=start)
    anchor = resolve_trajectory(anchor_trajectory, cond_traj, size=cfg.image_size, max_frames=cfg.frames)
    if anchor.num_frames != cfg.frames:
        raise TrajectoryError(f"the anchor trajectory has {anchor.num_frames} frames; the prior samples scenes of "
                              f"{cfg.frames} frames")

    stored_anchor = anchor  # the file keeps the capture's frame; a degenerate origin moves (vt4dcodec.reference)
    centre = model_centre("origin", [cond_traj])
    if centre is not None:
        cond_traj, anchor = move_trajectory(cond_traj, centre), move_trajectory(anchor, centre)
    tokens = None
    if cfg.cond_tokens:
        tokens = conditioning_tokens(prior, frames, cond_traj, tokenizer, runtime=runtime, device=device)
    if isinstance(prior, OnnxPrior):
        pixels = frames.transpose(0, 3, 1, 2).astype(np.float32) / np.float32(255.0)
        z_s, z_d = prior.sample(pixels[None], *(np.asarray(a, np.float32)[None] for a in (
            cond_traj.K, cond_traj.w2c, anchor.K, anchor.w2c)), steps=steps, seed=seed, method=method,
            guidance=guidance, **({} if tokens is None else {"z_s": tokens[0], "z_d": tokens[1]}))
    else:
        z_s, z_d = (t.cpu().numpy() for t in _sample_torch(prior, frames, cond_traj, anchor, steps, seed, method,
                                                             guidance, tokens))
    info = {"prior_id": prior.model_id or "unnamed", "prior_version": prior.model_version or "0",
            "prior_config_sha256": cfg.sha256(), "seed": int(seed), "steps": int(steps), "method": method,
            "clip_start": int(start), "clip_frames": int(cfg.frames)}
    if guidance != 1.0:
        info["guidance"] = float(guidance)
    moved = {} if centre is None else {"vt4d": {CENTRE_KEY: centre_to_metadata(centre)}}
    return Scene(
        static_tokens=z_s[0].astype(np.float32),
        dynamic_tokens=z_d[0].astype(np.float32),
        cameras=stored_anchor,
        fingerprint=prior.tokenizer_fingerprint,
        metadata={**(metadata or {}), "co4dgen": info, **moved},
        provenance=Provenance.now(source_capture_id, "generated"),
        encoding=encoding,
    )


def sampler_setting(prior: Any, steps: int | None = None, method: str | None = None, guidance: float | None = None
                    ) -> tuple[int, str, float]:
    """(steps, method, guidance) to sample ``prior`` with: each one given, or else the setting the prior records
    (``prior.sampler``).  Guidance is checked here (ModelError: a number in [0, 20], other than 1 only for a prior
    with a null condition); steps and method by the sampler."""
    from .model.directories import checked_guidance  # torch-free

    recorded = prior.sampler
    guidance = recorded.guidance if guidance is None else guidance
    return (recorded.steps if steps is None else steps, recorded.method if method is None else method,
            checked_guidance(guidance, prior.config.cond_dropout))


def conditioning_tokens(prior: Any, frames: np.ndarray, cameras: Trajectory, tokenizer: Any = None, *,
                        runtime: str = "auto", device: str = "cpu") -> tuple[np.ndarray, np.ndarray]:
    """Z^c = E(V_c, P_c): the tokens a prior with ``cond_tokens`` is conditioned on, (1, N_s, d) and (1, N_d, d)
    float32, from the fitted clip ``frames`` (T, H, W, 3) uint8 with ``cameras``, encoded by ``tokenizer`` (id,
    directory or loaded encoder; default: the prior's tokenizer) on ``runtime`` / ``device`` like ``encode``
    (depth estimated, seed 0).  They are not rounded to float16 like the token records the prior was trained
    on (a difference of at most 2^-11 relative, below what the prior resolves): rounding would turn the
    encoder runtimes' float32 differences into whole float16 steps where a value sits at a rounding boundary,
    and the torch and ONNX generate paths would part by more than float rounding.  A tokenizer that added render
    feedback to the one the prior was trained on gives its first pass, which is that tokenizer's tokens exactly.
    ModelError when the tokenizer is not the one the prior was trained on."""
    from .codec import encode_views, load_encoder, model_fingerprint
    from .model.directories import check_tokenizer  # torch-free

    net = load_encoder(tokenizer if tokenizer is not None else prior.tokenizer_fingerprint.model_id, runtime,
                       device=device)
    check_tokenizer(prior, model_fingerprint(net), networks=getattr(net, "network_digests", None),
                    sources=getattr(net, "token_sources", ()))
    first_pass = prior.tokenizer_fingerprint.config_sha256 in net.config.first_pass_sha256s()
    z_s, z_d = encode_views(net, [(frames, cameras, None)], seed=0, feedback=not first_pass)
    return np.asarray(z_s, np.float32), np.asarray(z_d, np.float32)


def _sample_torch(prior: "Co4DGen", frames: np.ndarray, cond_traj: Trajectory, anchor: Trajectory, steps: int,
                  seed: int, method: str, guidance: float, tokens: tuple[np.ndarray, np.ndarray] | None = None
                  ) -> tuple[Any, Any]:
    """``Co4DGen.sample`` of the fitted clip ``frames`` (T, H, W, 3) uint8 and its trajectories, on the prior's device."""
    import torch  # the networks and torch load on call: `import vt4dcodec` imports this module

    from .model.prior import PriorCondition

    where = next(prior.parameters()).device

    def tensor(a: np.ndarray) -> "torch.Tensor":
        return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))[None].to(where)

    cond = PriorCondition(frames=torch.from_numpy(frames).permute(0, 3, 1, 2).float().div(255.0)[None].to(where),
                          K_c=tensor(cond_traj.K), w2c_c=tensor(cond_traj.w2c), K_a=tensor(anchor.K),
                          w2c_a=tensor(anchor.w2c),
                          z_s=None if tokens is None else torch.from_numpy(tokens[0]).to(where),
                          z_d=None if tokens is None else torch.from_numpy(tokens[1]).to(where))
    with torch.no_grad():
        return prior.sample(cond, steps=steps, seed=seed, method=method, guidance=guidance)
