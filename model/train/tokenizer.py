"""Stage 2: train the tokenizer (Spatial + Temporal Branch) and the renderer with the frozen stage-1
autoencoder: the rectified-flow loss L_tok = E || (Y^1 - Y^0) - v_theta(Y^tau, Z_s, Z_d, P_tgt, tau) ||^2
(paper Eq. 2), or its x0 form for ``prediction="x0"`` models, on camera pairs of synthetic dynamic scenes.

    python -m vt4dcodec.model.train.tokenizer --autoencoder runs/ae/autoencoder.safetensors \
        --out runs/tok --steps 3000 [recipe flags]
    python -m vt4dcodec.model.train.tokenizer --init vt4d-tiny --out runs/tok2 --steps 20000 [same --set]
    torchrun --nproc_per_node=2 -m vt4dcodec.model.train.tokenizer --autoencoder ... --out ... --steps ...
    python -m vt4dcodec.model.train.tokenizer --device cuda --prefill-workers 16 --time-budget 300 ...

Each sample: one scene, a source camera c (its clip, cameras, motion mask and tracks from
``model.inputs.preprocess``) and a target camera a (its video is Y^0, its trajectory P_tgt): every ordered
pair a != c, or with the recipe flags a sampled target (c itself for reconstruction, else a camera
that overlaps c), flow times with a share at tau = 1, static-token dropout and a saturation penalty
(docs/training.md says what each does and what was measured). ``--init`` continues a saved model
(e.g. the shipped one on another machine). Ranks train on disjoint scene seeds. The finished model
is written with ``save_pretrained`` to ``<out>/model``; ``<out>/samples.png`` shows source | target |
render for a few training pairs, and ``<out>/summary.json`` their PSNR.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import sys
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file
from torch.nn.parallel import DistributedDataParallel

from vt4dcodec.errors import ModelError
from vt4dcodec.format.learned import EntropyTables

from ..configs import ModelConfig, get_config
from ..refine import stored_values
from ..tables import frozen_tables
from ..videotok4d import VideoTok4D
from ..weights_io import from_pretrained, save_pretrained
from .common import (cleanup_distributed, common_arguments, cycle, make_loader, parse_overrides,
                     model_from_run_or_saved, resolve_device, scene_pool_and_seeds, seed_everything, setup_distributed, to_device,
                     train_loop, trained_decode_steps)
from .data import PairBatch, PairDataset, ViewsBatchSampler, collate_pairs, precompute_latents, prefill_scenes

__all__ = ["main", "load_autoencoder", "draw_tau", "flow_step"]


def load_autoencoder(model: VideoTok4D, path: Path) -> None:
    """Copy stage-1 weights (``autoencoder.safetensors``) into ``model`` and freeze them."""
    try:
        state = load_file(str(path))
    except (OSError, SafetensorError, ValueError) as exc:
        raise ModelError(f"cannot read autoencoder weights {path}: {exc}") from None
    set_autoencoder(model, state, str(path))


def set_autoencoder(model: VideoTok4D, state: dict[str, torch.Tensor], what: str) -> None:
    """Copy autoencoder tensors ``state`` (from ``what``, for the error) into ``model`` as float32 and
    freeze them."""
    expected = model.autoencoder.state_dict()
    if set(state) != set(expected) or any(state[k].shape != expected[k].shape for k in state):
        raise ModelError(f"{what}: its autoencoder does not fit this config (ae_width, latent_channels, "
                         f"ae_downsample must match stage 1)")
    model.autoencoder.load_state_dict({k: v.float() for k, v in state.items()})
    model.freeze_autoencoder()


def draw_tau(batch_size: int, tau_one: float) -> torch.Tensor:
    """Flow times for one batch: 1 with probability ``tau_one`` (the renderer sees pure noise and
    must produce the target from tokens and rays alone), else U(0, 1)."""
    tau = torch.rand(batch_size)
    return torch.where(torch.rand(batch_size) < tau_one, torch.ones_like(tau), tau)


def flow_step(module: torch.nn.Module, batch: PairBatch, *, tau_one: float = 0.0, x0_weight: float = 0.0,
              saturation_weight: float = 0.0, drop_static: float = 0.0, pixel_weight: float = 0.0,
              cell_weight: float = 0.0, ssim_weight: float = 0.0, diversity_weight: float = 0.0,
              track_weight: float = 0.0, patch_weight: float = 0.0, rate_lambdas: tuple[float, ...] = (),
              level_weights: tuple[float, ...] = (), quantized_share: float = 0.0,
              stored_tables: EntropyTables | None = None, stored_weights: tuple[float, ...] = ()
              ) -> tuple[torch.Tensor, dict[str, float]]:
    """One training loss. With ``rate_lambdas`` (one per quality level of the entropy model) each batch
    draws a level -- uniformly, or in proportion to ``level_weights`` -- and trains D + lambda_level R at
    that level's quantization; in a ``quantized_share`` of the batches the renderer reads the level's stored
    token values (straight-through) instead of the noisy ones. With ``stored_tables`` (a model's frozen entropy
    tables; no rate term, the tables stay as they are) each batch draws a level in proportion to ``stored_weights`` and the renderer reads
    the tokens exactly as a file stores them at that level (:func:`stored_tokens`)."""
    B = batch.target_frames.shape[0]
    tau = draw_tau(B, tau_one)
    drop = torch.rand(B) < drop_static if drop_static > 0 else None
    rate: dict[str, object] = {}
    level = None
    if stored_tables is not None:
        level = int(torch.multinomial(torch.tensor(stored_weights, dtype=torch.float64), 1))
        rate = {"stored": functools.partial(stored_tokens, stored_tables, level)}
    elif rate_lambdas:
        level = int(torch.multinomial(torch.tensor(level_weights, dtype=torch.float64), 1)) if level_weights \
            else int(torch.randint(len(rate_lambdas), ()))
        rate = {"rate_level": level, "rate_lambda": rate_lambdas[level],
                "rate_quantized": bool(quantized_share > 0 and float(torch.rand(())) < quantized_share)}
    loss, logs = module(batch.source, batch.target_frames, batch.K_tgt, batch.w2c_tgt, tau=tau, x0_weight=x0_weight,
                        saturation_weight=saturation_weight, target_latents=batch.target_latents, drop_static=drop,
                        pixel_weight=pixel_weight, cell_weight=cell_weight, ssim_weight=ssim_weight,
                        diversity_weight=diversity_weight, track_weight=track_weight,
                        patch_weight=patch_weight, **rate)
    if level is not None:
        logs["level"] = float(level)
    return loss, logs


def stored_tokens(tables: EntropyTables, level: int, z_s: torch.Tensor, z_d: torch.Tensor, views: int
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    """The values a file of these ``tables`` stores for each scene's tokens z_s (S, N_s, d), z_d (S, N_d, d) of
    ``views`` encoded cameras at ``level`` (0-based): the reference writer's codes (dead zones and frame-copy
    differences included) times the step, as the decoder reads them, with a straight-through gradient (identity to
    z: an encoder trained through a frozen renderer learns the tokens it stores)."""
    return (torch.stack([stored_values(item, tables, level, "static", views) for item in z_s]),
            torch.stack([stored_values(item, tables, level, "dynamic", views) for item in z_d]))


def calibrate_entropy(model: VideoTok4D, batches, count: int, iterations: int = 300, lr: float = 0.05) -> dict[str, float]:
    """Fit a fresh entropy model's densities (steps fixed) to the noise-free tokens of ``count`` training
    batches before rate training starts, so the rate term's first gradients come from the real token
    distribution rather than a uniform density. Returns the bits per value before and after."""
    entropy = model.entropy
    assert entropy is not None
    samples = []
    model.eval()
    with torch.no_grad():
        for _ in range(count):
            batch = next(batches)
            src = to_device(batch.source, entropy.logits.device)
            a_s, a_d = model.encode_preactivations(src)
            samples.append((torch.tanh(a_s), torch.tanh(a_d), model.static_origins(src.views)))
    model.train()
    opt = torch.optim.Adam([entropy.logits], lr=lr)
    before = after = 0.0
    gen = torch.Generator().manual_seed(0)
    for it in range(iterations):  # one sample at one level a step (~70 ms), each level and sample in turn
        zs, zd, origin = samples[it % len(samples)]
        loss = entropy.density_loss(zs, zd, origin, level=int(torch.randint(entropy.levels, (), generator=gen)))
        if it < len(samples):
            before += float(loss.detach()) / len(samples)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if it >= iterations - len(samples):
            after += float(loss.detach()) / len(samples)
    entropy.log_step.grad = None
    return {"bits_per_value_before": before, "bits_per_value_after": after}


@torch.no_grad()
def render_samples(model: VideoTok4D, dataset: PairDataset, count: int, png: Path, steps: int = 1
                   ) -> dict[str, float]:
    """PSNR of renders against the target camera for ``count`` pairs, and a PNG: rows are pairs,
    columns source | target | render at the first, middle and last frame."""
    matplotlib.use("Agg")
    model.eval()
    idx = np.linspace(0, len(dataset) - 1, count).astype(int).tolist()
    batch = collate_pairs([dataset[i] for i in idx])
    z_s, z_d = model.encode(batch.source)
    frames = model.render(z_s, z_d, batch.K_tgt, batch.w2c_tgt, steps=steps, seed=0, source=batch.source.source)
    mse = ((frames - batch.target_frames) ** 2).mean(dim=(1, 2, 3, 4)).clamp_min(1e-10)
    psnr = (10 * torch.log10(1.0 / mse)).tolist()
    T = frames.shape[1]
    cols = [(batch.source.frames, t, "source") for t in (0, T - 1)] + \
           [(batch.target_frames, t, "target") for t in (0, T - 1)] + [(frames, t, "render") for t in (0, T - 1)]
    fig, axes = plt.subplots(count, len(cols), figsize=(1.4 * len(cols), 1.5 * count), dpi=80, squeeze=False)
    for r in range(count):
        for c, (video, t, name) in enumerate(cols):
            axes[r, c].imshow(video[r, t].permute(1, 2, 0).clamp(0, 1).numpy())
            axes[r, c].set_axis_off()
            if r == 0:
                axes[r, c].set_title(f"{name} t={t}", fontsize=7)
        axes[r, -1].text(66, 32, f"{psnr[r]:.1f} dB", fontsize=7, va="center")
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)
    return {"psnr_db": psnr, "mean_psnr_db": float(np.mean(psnr)), "pairs": idx, "render_steps": steps}


def grown_static_tokens(state: dict[str, torch.Tensor], old: ModelConfig, new: ModelConfig) -> dict[str, torch.Tensor]:
    """``state`` of a model with ``old.n_static`` static tokens, its per-token tensors repeated for
    ``new.n_static`` = k * ``old.n_static`` (k > 1; otherwise ``state`` unchanged): static query i, its
    locality bias and its renderer slot start as those of query i mod ``old.n_static``. Anchors are
    i mod P and encoded cameras i mod V (configs), so the new query i has the cell of the old query it
    copies; with one encoded camera a grown encoder gives each token k times, and with V cameras where
    k is a multiple of V every camera gets a whole grid of tokens (with P coprime to V)."""
    k, rem = divmod(new.n_static, old.n_static)
    if k < 2 or rem or old.unified_tokens or new.unified_tokens or old.n_dynamic != new.n_dynamic:
        return state
    grown = dict(state)
    for name, axis in (("spatial_branch.queries", 0), ("spatial_branch.query_bias", 1)):
        if name in state:
            grown[name] = torch.cat([state[name]] * k, dim=axis)
    if "renderer.token_slot" in state:
        slot = state["renderer.token_slot"]
        grown["renderer.token_slot"] = torch.cat([slot[:old.n_static]] * k + [slot[old.n_static:]], dim=0)
    return grown


def frame_copy_maps(state: dict[str, torch.Tensor], old: ModelConfig, new: ModelConfig) -> dict[str, torch.Tensor]:
    """``state`` of a model without ``frame_copies``, given the two maps a model with it adds, when ``new``
    has it: the encoder's frame map starts as its cell map (``cell_direct``) and the renderer's frame
    splat as its splat, biases zero, so a copy holds its frame group's change from the time average in
    the code its time-average copy uses for the cell, and the frame splat reads it back from the first
    step (two zero maps would start at a saddle: each one's gradient is zero while the other is zero).
    Otherwise ``state`` unchanged."""
    if not new.frame_copies or old.frame_copies or "cell_direct.weight" not in state \
            or "renderer.splat.weight" not in state:
        return state
    maps = dict(state)
    for into, source in (("cell_frames", "cell_direct"), ("renderer.splat_frames", "renderer.splat")):
        maps[f"{into}.weight"] = state[f"{source}.weight"].clone()
        maps[f"{into}.bias"] = torch.zeros_like(state[f"{source}.bias"])
    return maps


def repeated_feedback(state: dict[str, torch.Tensor], old: ModelConfig, new: ModelConfig,
                      scale: float | None) -> dict[str, torch.Tensor]:
    """``state`` of a model with ``old.feedback_passes`` render feedback passes, with each pass that ``new`` adds
    (``feedback_later.{k}.*``) a copy of the saved model's last pass whose output layers are multiplied by
    ``scale``: the new pass starts as the last look taken again at ``scale`` times its step (the first pass read
    afresh at the tokens it made; scale 1/2 is a damped second step of a learned optimiser). ``state`` unchanged
    where ``scale`` is None (the new passes start fresh: zero output, the saved model's encode) or nothing is
    added."""
    if scale is None or not old.feedback_width or new.feedback_passes <= old.feedback_passes:
        return state
    last = "feedback." if old.feedback_passes == 1 else f"feedback_later.{old.feedback_passes - 2}."
    pass_state = {k[len(last):]: v for k, v in state.items() if k.startswith(last)}
    out = dict(state)
    for k in range(old.feedback_passes - 1, new.feedback_passes - 1):
        for name, value in pass_state.items():
            output_layer = name.split(".")[1:2] == ["2"]  # (static|dynamic|static_grad|dynamic_grad).2.*: the MLPs' last
            out[f"feedback_later.{k}.{name}"] = value * scale if output_layer else value.clone()
    return out


def warm_start_model(cfg: ModelConfig, name_or_path: str, *, partial: bool = False,
                     repeat_feedback: float | None = None) -> VideoTok4D:
    """A saved model (shipped id, model directory or training run directory) to continue training: its weights, autoencoder included
    (frozen), as float32. Its config must equal this run's; with ``partial`` it may differ in sizes
    outside the autoencoder (e.g. ``render_patch_size``): every tensor whose name and shape match is
    copied, the others keep their fresh initialisation and are listed on stdout; a static token set grown
    by a whole factor (``n_static``) starts as copies of the saved tokens (:func:`grown_static_tokens`), and
    ``frame_copies`` switched on starts from the saved cell and splat maps (:func:`frame_copy_maps`), and feedback
    passes added start as the saved last pass scaled by ``repeat_feedback`` (:func:`repeated_feedback`; None:
    fresh)."""
    source = model_from_run_or_saved(name_or_path)  # a run's latest checkpoint (e.g. under checkpoints/) or a model
    if source.config == cfg:
        model = source
    elif not partial:
        raise ModelError(f"--init {name_or_path}: its config differs from this run's "
                         f"({source.config.sha256()[:12]} vs {cfg.sha256()[:12]}); pass the same --config/--set, "
                         f"or --init-partial to copy only the tensors that fit")
    else:
        model = VideoTok4D(cfg)
        fresh = model.state_dict()
        saved = frame_copy_maps(grown_static_tokens(source.state_dict(), source.config, cfg), source.config, cfg)
        saved = repeated_feedback(saved, source.config, cfg, repeat_feedback)
        fits = {k: v.to(fresh[k].dtype) for k, v in saved.items() if k in fresh and fresh[k].shape == v.shape}
        ae = [k for k in fresh if k.startswith("autoencoder.")]
        if any(k not in fits for k in ae):
            raise ModelError(f"--init-partial {name_or_path}: its autoencoder does not fit this config "
                             f"(latent_channels, ae_width, ae_downsample must match)")
        model.load_state_dict(fits, strict=False)
        model.decode_steps, model.default_quality = source.decode_steps, source.default_quality  # renders in training
        skipped = sorted(set(fresh) - set(fits))
        print(f"--init-partial: copied {len(fits)} of {len(fresh)} tensors; fresh: {', '.join(skipped) or 'none'}")
    model.set_identity(None, None)
    model.freeze_autoencoder()
    return model


def parameter_groups(model: VideoTok4D, spec: str, train_only: str = "") -> list[dict]:
    """The optimizer's parameter groups for ``--lr-scale PREFIX=F,...``: each parameter of
    ``model.tokenizer_parameters()`` whose name starts with a PREFIX (the first that matches) gets
    ``lr_scale`` F (train_loop multiplies the scheduled rate by it), the rest 1. With ``train_only``
    (``--train-only PREFIX,...``) every other parameter is frozen (``requires_grad`` off, not in a group):
    gradients still flow through it to the parameters trained. ModelError for a bad spec or a prefix that names
    no trained parameter."""
    scales: list[tuple[str, float]] = []
    for item in filter(None, (part.strip() for part in spec.split(","))):
        prefix, _, value = item.partition("=")
        try:
            scale = float(value)
        except ValueError:
            scale = -1.0
        if not prefix or not scale > 0:
            raise ModelError(f"--lr-scale {item!r}: give PREFIX=F with F > 0")
        scales.append((prefix, scale))
    trained = {id(p) for p in model.tokenizer_parameters()}
    only = [prefix for prefix in (part.strip() for part in train_only.split(",")) if prefix]
    if only:
        named = dict(model.named_parameters())
        missing = [prefix for prefix in only if not any(n.startswith(prefix) and id(p) in trained
                                                            for n, p in named.items())]
        if missing:
            raise ModelError(f"--train-only: no trained parameter starts with {', '.join(missing)}")
        for name, param in named.items():
            if id(param) in trained and not any(name.startswith(prefix) for prefix in only):
                param.requires_grad_(False)
                trained.discard(id(param))
    groups: dict[float, list] = {}
    used: set[str] = set()
    for name, param in model.named_parameters():
        if id(param) not in trained:
            continue
        scale = next((s for prefix, s in scales if name.startswith(prefix)), 1.0)
        used.update(prefix for prefix, s in scales if name.startswith(prefix))
        groups.setdefault(scale, []).append(param)
    unused = [prefix for prefix, _ in scales if prefix not in used]
    if unused:
        raise ModelError(f"--lr-scale: no trained parameter starts with {', '.join(unused)}")
    return [{"params": params, "lr_scale": scale} for scale, params in sorted(groups.items())]


def fresh_on_saved_autoencoder(cfg: ModelConfig, name_or_path: str) -> VideoTok4D:
    """Fresh tokenizer weights on the frozen stage-1 autoencoder of a saved model (shipped id or
    directory): training a tokenizer from scratch without re-running stage 1."""
    model = VideoTok4D(cfg)
    set_autoencoder(model, from_pretrained(name_or_path).autoencoder.state_dict(), f"--autoencoder-from {name_or_path}")
    return model


def build_model(cfg: ModelConfig, autoencoder: Path) -> VideoTok4D:
    model = VideoTok4D(cfg)
    load_autoencoder(model, autoencoder)
    return model


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m vt4dcodec.model.train.tokenizer", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    common_arguments(parser)
    parser.add_argument("--autoencoder", type=Path, default=None,
                        help="a fresh tokenizer on this stage-1 autoencoder.safetensors")
    parser.add_argument("--autoencoder-from", default=None, metavar="MODEL",
                        help="train from scratch on the frozen autoencoder of a saved model (shipped id or "
                             "model directory) instead of a stage-1 file")
    parser.add_argument("--model-id", default="vt4d-tiny")
    parser.add_argument("--model-version", default="0.1.0")
    parser.add_argument("--samples", type=int, default=4, help="pairs rendered into samples.png at the end (0: none)")
    parser.add_argument("--render-steps", type=int, default=1, help="Euler steps of the samples.png renders")
    parser.add_argument("--init", default=None, metavar="MODEL",
                        help="start from a saved model (shipped id or model directory, same config), its "
                             "frozen autoencoder included, instead of fresh weights: continues a shipped "
                             "model's training on another machine; a checkpoint in --out still takes precedence")
    parser.add_argument("--init-partial", action="store_true",
                        help="with --init: the saved model's config may differ outside the autoencoder (e.g. "
                             "render_patch_size); copy the tensors whose shapes fit, start the rest fresh; "
                             "n_static = k x the saved one repeats each static token's query k times")
    parser.add_argument("--repeat-feedback", type=float, default=None, metavar="SCALE",
                        help="with --init-partial and more feedback_passes than the saved model: each added pass "
                             "starts as the saved last pass with its output scaled by SCALE (default: fresh, "
                             "zero output)")
    parser.add_argument("--device", default="cpu", choices=("cpu", "cuda", "auto"),
                        help="where the model trains (auto: CUDA when torch sees it); the data stays on the CPU")
    parser.add_argument("--prefill-workers", type=int, default=0, metavar="N",
                        help="generate and preprocess every training scene into --cache with N processes before "
                             "training (default: lazily, in the DataLoader worker)")
    parser.add_argument("--cache-latents", action="store_true",
                        help="encode every training frame once with the frozen autoencoder and read the latents "
                             "from the scene cache (saves the encoder pass of every step)")
    recipe = parser.add_argument_group("recipe (docs/training.md says what was measured)")
    recipe.add_argument("--recon-share", type=float, default=0.0,
                        help="share of samples whose target is the source camera itself (reconstruction)")
    recipe.add_argument("--neighbour-sigma", type=float, default=None, metavar="DEG",
                        help="draw other targets with weight exp(-axis angle / DEG) (default: all pairs, uniform)")
    recipe.add_argument("--tau-one", type=float, default=0.0,
                        help="share of samples trained at tau = 1 (pure regression of the target latents)")
    recipe.add_argument("--x0-weight", type=float, default=0.0, help="weight of the one-step x0 error")
    recipe.add_argument("--drop-static", type=float, default=0.0,
                        help="share of samples rendered without Z_s, so Z_d must carry what it can")
    recipe.add_argument("--pixel-weight", type=float, default=0.0,
                        help="weight of the pixel MSE of the one-step estimate through the frozen decoder")
    recipe.add_argument("--multi-share", type=float, default=0.0,
                        help="share of batches that encode several cameras of the event into one token set")
    recipe.add_argument("--multi-views", default="2,3,5", metavar="V,V,...",
                        help="numbers of encoded cameras a multi-camera batch draws from (default 2,3,5)")
    recipe.add_argument("--multi-spread", type=float, default=0.0, metavar="P",
                        help="share of multi-camera items whose cameras are spread over the rig (farthest "
                             "optical axes) instead of drawn at random")
    recipe.add_argument("--ssim-weight", type=float, default=0.0,
                        help="weight of 1 - SSIM of the one-step estimate through the frozen decoder")
    recipe.add_argument("--cell-weight", type=float, default=0.0,
                        help="weight of the cell loss (config token_splat): each anchored static token, read by the "
                             "splat's linear map, must give its source cell's time-averaged latent")
    recipe.add_argument("--saturation-weight", type=float, default=0.0,
                        help="weight of the penalty on bottleneck pre-activations beyond |a| = 2")
    recipe.add_argument("--dynamic-diversity", type=float, default=0.0, metavar="W",
                        help="weight of the slot-diversity hinge on Z_d (centred slot spread below 0.3 is "
                             "penalised): keeps the dynamic tokens of a scene from collapsing onto one vector")
    parser.add_argument("--lr-scale", default="", metavar="PREFIX=F,...",
                        help="learning rate x F for the trained parameters whose names start with PREFIX (e.g. new "
                             "zero-initialised maps in a warm start, which Adam grows by about lr a step)")
    parser.add_argument("--train-only", default="", metavar="PREFIX,...",
                        help="train only the parameters whose names start with one of these prefixes (e.g. "
                             "'entropy.' to fit a model's quantizer steps and densities to its frozen encoder and "
                             "renderer with the rate-distortion loss); the rest are frozen")
    recipe.add_argument("--track-weight", type=float, default=0.0, metavar="W",
                        help="weight of the track loss (config dynamic_splat): each dynamic token must decode where "
                             "its track goes, supervised by the synthetic scenes' depth")
    recipe.add_argument("--rate-lambdas", default="", metavar="L,L,...",
                        help="rate-distortion training (config entropy_levels = the number of values): lambda of each "
                             "quality level, coarsest first; each batch draws a level and adds lambda x bits per "
                             "source pixel to the loss")
    recipe.add_argument("--level-weights", default="", metavar="W,W,...",
                        help="with --rate-lambdas: how often each quality level is drawn, one weight >= 0 per level "
                             "(coarsest first; default: uniform), e.g. to train the finest levels back to fidelity")
    recipe.add_argument("--quantized-share", type=float, default=0.0, metavar="P",
                        help="with --rate-lambdas: share of the batches whose renderer reads the quality level's "
                             "stored token values (rounded, straight-through gradient) instead of noisy ones")
    recipe.add_argument("--calibrate-batches", type=int, default=16, metavar="N",
                        help="with --rate-lambdas, a run that starts without a checkpoint first fits the entropy "
                             "model's densities to the tokens of N batches")
    recipe.add_argument("--calibrate-iterations", type=int, default=300, metavar="N",
                        help="Adam steps of the density calibration (one batch at one level each)")
    recipe.add_argument("--stored-levels", default="", metavar="W,W,...",
                        help="renderer training on the tokens as files store them: each batch draws a quality level "
                             "of the --init model's frozen entropy tables (one weight >= 0 per level, coarsest first) "
                             "and the renderer reads the writer's stored values at it (straight-through to the "
                             "encoder; with --config init and --train-only, e.g. renderer.; not with --rate-lambdas)")
    recipe.add_argument("--patch-weight", type=float, default=0.0, metavar="W",
                        help="weight of the patch loss (config dynamic_splat): each dynamic token's splat patch must "
                             "hold the source latent around its track")
    args = parser.parse_args(argv)
    if args.prefill_workers < 0:
        parser.error("--prefill-workers must be >= 0")
    if not 0.0 <= args.quantized_share <= 1.0:
        parser.error("--quantized-share must lie in [0, 1]")
    try:
        device = resolve_device(args.device)
    except ModelError as exc:
        parser.error(str(exc))
    info = setup_distributed()
    torch.set_num_threads(args.threads)
    seed_everything(args.seed + info.rank)
    if args.samples < 0:
        parser.error(f"--samples must be >= 0, got {args.samples}")
    if args.config == "init":  # the warm start's own config (e.g. a shipped model's entropy fields), --set on top
        if args.init is None:
            parser.error("--config init needs --init MODEL")
        base = model_from_run_or_saved(args.init).config.to_dict()
        cfg = ModelConfig.from_dict({**base, **parse_overrides(args.set)})
    else:
        cfg = get_config(args.config, **parse_overrides(args.set))
    if args.dynamic_diversity < 0:
        parser.error("--dynamic-diversity must be >= 0")
    if args.ssim_weight < 0:
        parser.error("--ssim-weight must be >= 0")
    if args.track_weight < 0 or (args.track_weight > 0 and not cfg.dynamic_splat):
        parser.error("--track-weight must be >= 0 and needs --set dynamic_splat=N (it trains the dynamic tokens' track)")
    if args.patch_weight < 0 or (args.patch_weight > 0 and not cfg.dynamic_splat):
        parser.error("--patch-weight must be >= 0 and needs --set dynamic_splat=N (it trains the dynamic patches)")
    if not 0.0 <= args.multi_spread <= 1.0:
        parser.error("--multi-spread must be in [0, 1]")
    if args.cell_weight < 0 or (args.cell_weight > 0 and not cfg.token_splat):
        parser.error("--cell-weight must be >= 0 and needs --set token_splat=true (it trains the splat's read)")
    try:
        rate_lambdas = tuple(float(v) for v in args.rate_lambdas.split(",")) if args.rate_lambdas else ()
    except ValueError:
        parser.error(f"--rate-lambdas takes comma-separated numbers, got {args.rate_lambdas!r}")
    if rate_lambdas and (len(rate_lambdas) != cfg.entropy_levels or not all(v >= 0 for v in rate_lambdas)):
        parser.error(f"--rate-lambdas needs one lambda >= 0 per quality level: the config has entropy_levels="
                     f"{cfg.entropy_levels} (--set entropy_levels=N)")
    try:
        level_weights = tuple(float(v) for v in args.level_weights.split(",")) if args.level_weights else ()
    except ValueError:
        parser.error(f"--level-weights takes comma-separated numbers, got {args.level_weights!r}")
    if level_weights and (len(level_weights) != len(rate_lambdas) or min(level_weights) < 0
                          or sum(level_weights) <= 0):
        parser.error("--level-weights needs one weight >= 0 per --rate-lambdas value, not all zero")
    try:
        stored_weights = tuple(float(v) for v in args.stored_levels.split(",")) if args.stored_levels else ()
    except ValueError:
        parser.error(f"--stored-levels takes comma-separated numbers, got {args.stored_levels!r}")
    if stored_weights and (rate_lambdas or len(stored_weights) != cfg.entropy_levels or min(stored_weights) < 0
                           or sum(stored_weights) <= 0):
        parser.error(f"--stored-levels needs one weight >= 0 per quality level of the model ({cfg.entropy_levels}), "
                     "not all zero, and no --rate-lambdas")
    if args.repeat_feedback is not None and (not args.init_partial or not math.isfinite(args.repeat_feedback)):
        parser.error("--repeat-feedback takes a finite scale and goes with --init-partial (passes added to a saved "
                     "model's render feedback)")
    args.out.mkdir(parents=True, exist_ok=True)

    starts = [flag for flag, value in (("--init", args.init), ("--autoencoder", args.autoencoder),
                                       ("--autoencoder-from", args.autoencoder_from)) if value is not None]
    if len(starts) != 1:
        parser.error("give one of --init (a saved model to continue), --autoencoder (a stage-1 output) or "
                     f"--autoencoder-from (a saved model whose autoencoder a fresh tokenizer uses); got {starts or 'none'}")
    if args.init is not None:
        model = warm_start_model(cfg, args.init, partial=args.init_partial, repeat_feedback=args.repeat_feedback)  # a checkpoint in --out, if any, still wins (train_loop)
    elif args.autoencoder is not None:
        model = build_model(cfg, args.autoencoder)
    else:
        model = fresh_on_saved_autoencoder(cfg, args.autoencoder_from)
    stored_tables = None
    if stored_weights:
        if model.entropy is None or not model.entropy.frozen:
            parser.error("--stored-levels needs an --init model with frozen entropy tables (a shipped model)")
        stored_tables = frozen_tables(model, model.fingerprint("training", "0"))
    model.to(device)
    optimizer = torch.optim.AdamW(parameter_groups(model, args.lr_scale, args.train_only), lr=args.lr,
                                  weight_decay=0.01)
    module = DistributedDataParallel(model) if info.distributed else model
    pool, seeds = scene_pool_and_seeds(args, cfg, info)
    if args.prefill_workers:
        prefill_scenes(pool, seeds, args.prefill_workers, progress=not args.no_progress)
    latent_key = None
    if args.cache_latents:
        latent_key = precompute_latents(pool, seeds, model.autoencoder, progress=not args.no_progress)
    dataset = PairDataset(pool, seeds, recon_share=args.recon_share, neighbour_sigma_deg=args.neighbour_sigma,
                          spread_share=args.multi_spread, latent_key=latent_key, reference_frame=cfg.reference_frame)
    sampler = None
    if args.multi_share > 0:
        try:
            views = tuple(int(v) for v in args.multi_views.split(","))
        except ValueError:
            parser.error(f"--multi-views takes comma-separated integers, got {args.multi_views!r}")
        if any(not 2 <= v <= pool.cameras for v in views):
            parser.error(f"--multi-views must lie in 2..{pool.cameras} (the training rig's cameras)")
        if not (args.recon_share > 0 or args.neighbour_sigma is not None):
            parser.error("--multi-share needs --recon-share or --neighbour-sigma (sampled targets)")
        sampler = functools.partial(ViewsBatchSampler, len(dataset), args.batch_size, multi_share=args.multi_share,
                                    multi_views=views)  # called with the rank's seeded generator
    batches = cycle(make_loader(dataset, args, info, collate_fn=collate_pairs, batch_sampler=sampler))
    step = functools.partial(flow_step, tau_one=args.tau_one, x0_weight=args.x0_weight,
                             saturation_weight=args.saturation_weight, drop_static=args.drop_static,
                             pixel_weight=args.pixel_weight, cell_weight=args.cell_weight,
                             ssim_weight=args.ssim_weight, diversity_weight=args.dynamic_diversity,
                             track_weight=args.track_weight, patch_weight=args.patch_weight,
                             rate_lambdas=rate_lambdas, level_weights=level_weights,
                             quantized_share=args.quantized_share, stored_tables=stored_tables,
                             stored_weights=stored_weights)
    if rate_lambdas and args.calibrate_batches > 0 and not (args.out / "checkpoint" / "state.json").is_file():
        fit = calibrate_entropy(model, batches, args.calibrate_batches, iterations=args.calibrate_iterations)
        if info.is_main:
            print(f"entropy model calibrated on {args.calibrate_batches} batches: {fit['bits_per_value_before']:.3f} -> "
                  f"{fit['bits_per_value_after']:.3f} bits per token value (mean over levels)")
    records = train_loop(args, info, module, model, optimizer, batches, step,
                         title="stage 2: tokenizer + renderer", extra_state={"config": cfg.to_dict()},
                         device=device)
    model.cpu()  # saved and sampled on the CPU, wherever it trained
    if info.is_main:
        if stored_tables is None:  # with --stored-levels the init model's tables, which the renderer learned, stay
            model.update_entropy()  # the integer tables the codec reads, from the final densities and steps
        model.decode_steps = trained_decode_steps(vars(args))
        directory = save_pretrained(model, args.out / "model", model_id=args.model_id,
                                    model_version=args.model_version)
        summary = {"config": cfg.to_dict(), "steps": records[-1]["step"] if records else args.steps,
                   "final_loss": records[-1]["loss"] if records else None,
                   "first_loss": records[0]["loss"] if records else None,
                   **(render_samples(model, dataset, min(args.samples, len(dataset)), args.out / "samples.png",
                                      steps=args.render_steps) if args.samples > 0 else {})}
        (args.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        rendered = (f", render PSNR {summary['mean_psnr_db']:.2f} dB on {len(summary['pairs'])} training pairs"
                    if "pairs" in summary else "")
        print(f"tokenizer: loss {summary['first_loss']} -> {summary['final_loss']}{rendered}; model -> {directory}")
    cleanup_distributed()
    return 0


if __name__ == "__main__":
    sys.exit(main())
