"""Shared training machinery: distributed setup (torchrun, gloo), resumable checkpoints without
pickle, a JSONL log, the loss-curve PNG, bf16 autocast, the device batches go to, a wall-clock budget,
an exponential moving average of the weights, periodic validation and the progress bar.

Checkpoint layout (``<out>/checkpoint/``): ``model.safetensors`` (the module's state dict),
``optimizer.pt`` (``torch.save`` of the optimizer state dict; read back with
``torch.load(weights_only=True)``, which refuses arbitrary objects), ``ema.safetensors`` (the moving
average, for runs that keep one) and ``state.json`` (step, args, RNG seed) written last, so a checkpoint
without ``state.json`` is ignored as incomplete.

A run that trains a subset of a saved model's weights (``train.tokenizer --train-only``) can be committed
slim (:func:`slim_checkpoint`): ``model.safetensors`` then holds only the tensors that differ from the model
it started from, and ``state.json`` names that model under ``"base"`` with a SHA-256 of the tensors taken from
it, so a checkpoint restores only onto the same base weights.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import random
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import torch
import torch.distributed as dist
from safetensors.torch import load_file, save_file
from torch import nn
from torch.utils.data import DataLoader, RandomSampler
from tqdm import tqdm

from vt4dcodec.data.multiview import find_capture_dirs
from vt4dcodec.errors import ModelError

from .data import ScenePool, rank_seeds

__all__ = [
    "DistInfo", "setup_distributed", "cleanup_distributed", "save_checkpoint", "load_checkpoint",
    "JsonlLog", "plot_loss_curve", "autocast", "seed_everything", "common_arguments", "shard_model_arguments", "cycle",
    "parse_overrides", "lr_at", "train_loop", "WeightAverage", "resolve_device", "to_device", "make_loader", "scene_pool_and_seeds", "trained_decode_steps",
    "slim_checkpoint", "model_from_run_or_saved",
]


@dataclass(frozen=True)
class DistInfo:
    rank: int
    world_size: int

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1


def setup_distributed() -> DistInfo:
    """Join the process group torchrun describes in the environment (gloo, CPU); else one process."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not dist.is_initialized():
        dist.init_process_group(backend="gloo")
    if dist.is_initialized():
        return DistInfo(dist.get_rank(), dist.get_world_size())
    return DistInfo(0, 1)


def cleanup_distributed() -> None:
    if dist.is_initialized():
        dist.barrier()
        dist.destroy_process_group()


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % (2 ** 32))
    torch.manual_seed(seed)


def autocast(bf16: bool, device_type: str = "cpu") -> contextlib.AbstractContextManager:
    """bf16 autocast on ``device_type`` ("cpu" or "cuda") when asked (matmuls and attention in bf16,
    losses kept in float32)."""
    return torch.autocast(device_type, dtype=torch.bfloat16) if bf16 else contextlib.nullcontext()


def resolve_device(name: str) -> torch.device:
    """``--device``: "cpu", "cuda" (ModelError where torch sees no CUDA device) or "auto" (CUDA when
    available, else CPU)."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ModelError("--device cuda: torch sees no CUDA device here (use --device cpu or auto)")
    if name not in ("cpu", "cuda"):
        raise ModelError(f"--device must be cpu, cuda or auto, got {name!r}")
    return torch.device(name)


def to_device(value: Any, device: torch.device) -> Any:
    """``value`` with every tensor in it moved to ``device``: tensors, dataclasses (a new instance, the
    input unchanged), lists, tuples and dicts, recursively; anything else as is."""
    if isinstance(value, torch.Tensor):
        return value.to(device, non_blocking=True)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.replace(value, **{f.name: to_device(getattr(value, f.name), device)
                                             for f in dataclasses.fields(value) if f.init})
    if isinstance(value, (list, tuple)):
        return type(value)(to_device(v, device) for v in value)
    if isinstance(value, dict):
        return {k: to_device(v, device) for k, v in value.items()}
    return value


def cycle(loader: Any) -> Iterator[Any]:
    """Iterate a DataLoader forever (re-shuffling every pass)."""
    epoch = 0
    while True:
        sampler = getattr(loader, "sampler", None)
        if hasattr(sampler, "set_epoch"):
            sampler.set_epoch(epoch)
        yield from loader
        epoch += 1


def scene_pool_and_seeds(args: argparse.Namespace, cfg: Any, info: DistInfo) -> tuple[Any, list[int]]:
    """The rank's share of the training scenes: seeds to generate, or indices into ``--data``."""
    cache = args.cache or args.out.parent / "scene_cache"
    if args.data is None:
        pool = ScenePool.for_config(cfg, cache, args.cameras, room_share=getattr(args, "room_share", 0.0),
                                    closeup_share=getattr(args, "closeup_share", 0.0))
        return pool, rank_seeds(args.scene_seed, args.scenes, info.rank, info.world_size)
    captures = tuple(find_capture_dirs(args.data)[:args.scenes])
    pool = ScenePool.for_config(cfg, cache, args.cameras, captures=captures)
    return pool, rank_seeds(0, len(captures), info.rank, info.world_size)


def make_loader(dataset: Any, args: argparse.Namespace, info: DistInfo, collate_fn: Any = None,
                batch_sampler: Any = None) -> Any:
    """Shuffled DataLoader with a per-rank seeded order (ranks already hold disjoint scenes), or the
    given ``batch_sampler`` (a callable taking the rank's seeded generator)."""
    generator = torch.Generator().manual_seed(args.seed + info.rank)
    if batch_sampler is not None:
        return DataLoader(dataset, batch_sampler=batch_sampler(generator), num_workers=args.workers,
                          collate_fn=collate_fn, persistent_workers=args.workers > 0)
    return DataLoader(dataset, batch_size=args.batch_size, sampler=RandomSampler(dataset, generator=generator),
                      num_workers=args.workers, drop_last=True, collate_fn=collate_fn,
                      persistent_workers=args.workers > 0)


def _atomic_write(path: Path, write) -> None:
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


class WeightAverage:
    """Exponential moving average of a module's floating-point state (parameters and buffers), in float32.

    ``update(module)`` after each optimizer step: avg <- d avg + (1 - d) w with d = min(decay, (1 + n) /
    (10 + n)) after n updates, so the first steps are not dominated by the initial weights.  ``copy_to``
    writes the average into a module of the same architecture (for validation and the saved model);
    non-float entries (integer buffers) are copied as they are.
    """

    def __init__(self, module: nn.Module, decay: float) -> None:
        if not 0.0 < decay < 1.0:
            raise ModelError(f"the weight-average decay must lie in (0, 1), got {decay!r}")
        self.decay = float(decay)
        self.updates = 0
        self.shadow = {k: v.detach().float().clone() if v.is_floating_point() else v.detach().clone()
                       for k, v in module.state_dict().items()}

    @torch.no_grad()
    def update(self, module: nn.Module) -> None:
        d = min(self.decay, (1 + self.updates) / (10 + self.updates))
        for k, v in module.state_dict().items():
            avg = self.shadow[k]
            if avg.is_floating_point():
                avg.mul_(d).add_(v.detach().float(), alpha=1.0 - d)
            else:
                avg.copy_(v)
        self.updates += 1

    @torch.no_grad()
    def copy_to(self, module: nn.Module) -> None:
        state = module.state_dict()
        module.load_state_dict({k: self.shadow[k].to(state[k].dtype) for k in state}, strict=True)

    def tensors(self) -> dict[str, torch.Tensor]:
        return {k: v.contiguous().clone() for k, v in self.shadow.items()}

    def load(self, tensors: dict[str, torch.Tensor], updates: int) -> None:
        if set(tensors) != set(self.shadow):
            raise ModelError("the checkpoint's weight average does not match the model's state")
        self.shadow = {k: (v.detach().float() if v.is_floating_point() else v.detach()).clone()
                       for k, v in tensors.items()}
        self.updates = int(updates)


def save_checkpoint(directory: Path, module: nn.Module, optimizer: torch.optim.Optimizer, step: int,
                    extra: dict[str, Any], average: WeightAverage | None = None) -> None:
    """Write model (safetensors), optimizer (weights-only torch.save), the weight average when there is
    one, and state.json, atomically each."""
    directory.mkdir(parents=True, exist_ok=True)
    state_json = directory / "state.json"
    if state_json.exists():
        state_json.unlink()  # the commit marker goes last; a crash in between leaves no valid checkpoint
    tensors = {k: v.detach().cpu().contiguous().clone() for k, v in module.state_dict().items()}
    _atomic_write(directory / "model.safetensors", lambda p: save_file(tensors, str(p)))
    _atomic_write(directory / "optimizer.pt", lambda p: torch.save(optimizer.state_dict(), p))
    if average is not None:
        shadow = average.tensors()
        _atomic_write(directory / "ema.safetensors", lambda p: save_file(shadow, str(p)))
        extra = {**extra, "ema_updates": average.updates, "ema_decay": average.decay}
    payload = {"step": int(step), "time": time.time(), **extra}
    _atomic_write(state_json, lambda p: p.write_text(json.dumps(payload, indent=2, sort_keys=True)))


def _on_base(base: dict[str, Any], tensors: dict[str, torch.Tensor], expected: dict[str, torch.Tensor],
             directory: Path) -> dict[str, torch.Tensor]:
    """A slim checkpoint's ``tensors`` completed from its base model: every tensor of ``expected`` (the module's
    state) that the checkpoint lacks comes from the base, whose taken tensors must hash to ``base["sha256"]``."""
    from ..identity import weights_sha256
    from ..weights_io import from_pretrained

    try:
        source = from_pretrained(base["model"]).state_dict()
    except ModelError as exc:
        raise ModelError(f"{directory}: its base model {base.get('model')!r} cannot be loaded: {exc}") from None
    taken = {k: source[k].to(v.dtype) for k, v in expected.items() if k not in tensors and k in source}
    if set(taken) | set(tensors) != set(expected) or weights_sha256(taken) != base.get("sha256"):
        raise ModelError(f"{directory}: a slim checkpoint on {base.get('model')!r}, but that model's weights are "
                         "not the ones the run started from (install or point \"base\" at that model)")
    return {**taken, **tensors}


def slim_checkpoint(run: Path, base: str, out: Path) -> tuple[int, int]:
    """Write ``run``'s latest checkpoint to ``out/checkpoint`` keeping only the tensors that differ from the
    saved model ``base`` (id or directory), with ``state.json`` naming it; copies the run's ``log.jsonl`` and
    ``summary.json``. Returns (tensors kept, tensors taken from the base)."""
    import shutil

    from ..identity import weights_sha256
    from ..weights_io import from_pretrained

    src = Path(run) / "checkpoint"
    state = json.loads((src / "state.json").read_text())
    tensors = load_file(str(src / "model.safetensors"))
    reference = from_pretrained(base).state_dict()
    taken = {k: v for k, v in tensors.items()
             if k in reference and reference[k].shape == v.shape and torch.equal(reference[k].to(v.dtype), v)}
    kept = {k: v for k, v in tensors.items() if k not in taken}
    dest = Path(out) / "checkpoint"
    dest.mkdir(parents=True, exist_ok=True)
    save_file(kept, str(dest / "model.safetensors"))
    state["base"] = {"model": str(base), "sha256": weights_sha256(taken)}
    (dest / "state.json").write_text(json.dumps(state, indent=2, sort_keys=True))
    for name in ("log.jsonl", "summary.json"):
        if (Path(run) / name).is_file():
            shutil.copyfile(Path(run) / name, Path(out) / name)
    return len(kept), len(taken)


def trained_decode_steps(train_args: dict[str, Any]) -> int:
    """The sampler steps a tokenizer run's renderer was trained for, from the run's arguments: one when
    every sample was trained at tau = 1 (``--tau-one 1``: the renderer never saw another flow time, so a
    second Euler step asks it about inputs it was not trained on), else the codec's general default."""
    from ..videotok4d import DEFAULT_DECODE_STEPS

    tau_one = train_args.get("tau_one", 0.0)
    return 1 if isinstance(tau_one, (int, float)) and tau_one >= 1.0 else DEFAULT_DECODE_STEPS


def model_from_run(run: Path) -> tuple[Any, dict[str, Any]]:
    """The tokenizer of a training run's latest checkpoint (``run/checkpoint``), in eval mode, with the
    checkpoint's state (step, arguments, config): what the probes under bench/ read."""
    from ..configs import ModelConfig
    from ..videotok4d import VideoTok4D

    directory = Path(run) / "checkpoint"
    try:
        config = json.loads((directory / "state.json").read_text())["config"]
        model = VideoTok4D(ModelConfig.from_dict(config))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ModelError(f"{directory} holds no complete training checkpoint: {exc}") from None
    state = load_checkpoint(directory, model, None)
    assert state is not None  # state.json was read above
    model.decode_steps = trained_decode_steps(state.get("args", {}))
    return model.eval(), state


def model_from_run_or_saved(name_or_path: str | Path) -> Any:
    """A training run's latest checkpoint (a directory holding ``checkpoint/state.json``, :func:`model_from_run`)
    or else a saved model (shipped id or model directory, ``from_pretrained``)."""
    if (Path(name_or_path) / "checkpoint" / "state.json").is_file():
        return model_from_run(Path(name_or_path))[0]
    from ..weights_io import from_pretrained

    return from_pretrained(name_or_path)


def load_checkpoint(directory: Path, module: nn.Module, optimizer: torch.optim.Optimizer | None,
                    average: WeightAverage | None = None) -> dict[str, Any] | None:
    """Restore a checkpoint written by :func:`save_checkpoint`; None when there is no complete one.
    ``average`` is restored from ``ema.safetensors``, or started from the restored weights when the
    checkpoint has none (a run that kept no average before).

    A checkpoint without ``optimizer.pt`` (the weights and state.json committed to carry a run to
    another machine, ``checkpoints/README.md``) restores the weights and leaves ``optimizer`` fresh; the
    returned state then says ``"fresh_optimizer": True`` and :func:`train_loop` re-warms the learning rate."""
    state_json = directory / "state.json"
    if not state_json.is_file():
        return None
    try:
        state = json.loads(state_json.read_text())
        tensors = load_file(str(directory / "model.safetensors"))
        if state.get("base") is not None:
            tensors = _on_base(state["base"], tensors, module.state_dict(), directory)
        module.load_state_dict(tensors, strict=True)
        if optimizer is not None:
            if (directory / "optimizer.pt").exists():
                optimizer.load_state_dict(torch.load(directory / "optimizer.pt", weights_only=True))
            else:
                state["fresh_optimizer"] = True
        if average is not None:
            if (directory / "ema.safetensors").is_file():
                average.load(load_file(str(directory / "ema.safetensors")), state.get("ema_updates", 0))
            else:
                average.load(module.state_dict(), 0)
    except (OSError, ValueError, RuntimeError, KeyError) as exc:
        raise ModelError(f"cannot resume from {directory}: {exc}") from None
    return state


class JsonlLog:
    """Append-only JSON-lines log; one object per logged step."""

    def __init__(self, path: Path, enabled: bool = True) -> None:
        self.path, self.enabled = path, enabled
        if enabled:
            path.parent.mkdir(parents=True, exist_ok=True)

    def write(self, record: dict[str, Any]) -> None:
        if self.enabled:
            with self.path.open("a", encoding="utf-8") as f:
                f.write(json.dumps(record, sort_keys=True) + "\n")

    def read(self) -> list[dict[str, Any]]:
        if not self.path.is_file():
            return []
        return [json.loads(line) for line in self.path.read_text().splitlines() if line.strip()]


def plot_loss_curve(records: list[dict[str, Any]], png: Path, title: str, key: str = "loss",
                    smooth: int = 20) -> None:
    """Loss against step (raw and a moving average), matplotlib Agg, log-scale y."""
    matplotlib.use("Agg")
    pts = [(r["step"], r[key]) for r in records if key in r and "step" in r]
    if not pts:
        return
    steps, values = np.array(pts, dtype=np.float64).T
    smooth = max(1, min(smooth, len(values) // 5))
    fig, ax = plt.subplots(figsize=(6, 3.5), dpi=100)
    ax.plot(steps, values, color="0.7", linewidth=0.8, label=key)
    if len(values) >= smooth:
        kernel = np.ones(smooth) / smooth
        ax.plot(steps[smooth - 1:], np.convolve(values, kernel, mode="valid"), color="C0",
                label=f"{key} (mean of {smooth})")
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_title(title)
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png)
    plt.close(fig)


def common_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags both stages share."""
    parser.add_argument("--out", type=Path, required=True, help="run directory (checkpoint, log, PNG)")
    parser.add_argument("--config", default="tiny",
                        help="model config name (tiny | paper), or 'init' for the --init model's own config")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="config overrides, e.g. unified_tokens=true renderer_layers=3")
    parser.add_argument("--steps", type=int, required=True, help="total optimizer steps (resume continues to it)")
    parser.add_argument("--batch-size", type=int, default=4, help="per process")
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--warmup", type=int, default=100, help="linear learning-rate warm-up steps")
    parser.add_argument("--scenes", type=int, default=64, help="training scenes in the pool")
    parser.add_argument("--data", type=Path, default=None,
                        help="a directory of capture directories (e.g. from `vt4d synth`) instead of "
                             "generating scenes from seeds; uses its first --scenes captures")
    parser.add_argument("--cameras", type=int, default=4, help="cameras per synthetic scene")
    parser.add_argument("--scene-seed", type=int, default=0, help="first synthetic scene seed")
    parser.add_argument("--room-share", type=float, default=0.0, metavar="P",
                        help="share of the synthetic scenes drawn in the \"room\" style (people in a furnished "
                             "room, webcam rigs, a sensor model; vt4dcodec.synth.room), by a hash of the seed "
                             "(default 0: every scene in the \"objects\" style)")
    parser.add_argument("--closeup-share", type=float, default=0.0, metavar="P",
                        help="share of the synthetic scenes drawn in the \"closeup\" style (the room style with "
                             "webcams near one person, clutter and a contrastier sensor; vt4dcodec.synth.room.CLOSEUP), "
                             "taken from the \"objects\" scenes: the room scenes stay where they are (default 0)")
    parser.add_argument("--cache", type=Path, default=None,
                        help="scene cache directory (default <out>/../scene_cache); shared across runs")
    parser.add_argument("--workers", type=int, default=1, help="DataLoader workers per process")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads per process")
    parser.add_argument("--bf16", action="store_true", help="bf16 autocast (on the training device)")
    parser.add_argument("--time-budget", type=float, default=None, metavar="SECONDS",
                        help="stop after this much wall-clock training time (checkpointed and finished as at "
                             "--steps; re-running the command continues to --steps): for a lent accelerator")
    parser.add_argument("--stop-at", type=int, default=None, metavar="STEP",
                        help="stop at this step (checkpointed and finished as at --steps, on the schedule of "
                             "--steps): to change a flag mid-run, stop here and re-run the command with it")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--log-every", type=int, default=10)
    parser.add_argument("--ckpt-every", type=int, default=200)
    parser.add_argument("--no-progress", action="store_true", help="hide the tqdm bar")


def shard_model_arguments(parser: argparse.ArgumentParser, *, what: str, config: str, model_id: str,
                          model_version: str, ckpt_every: int) -> None:
    """Flags of the models trained on token shards (the Co4DGen prior, the dense baseline): ``what`` names
    the saved model directory and its config in the help texts."""
    parser.add_argument("--shards", required=True, help="token shard directory, glob or file (.vt4da) with clips")
    parser.add_argument("--out", type=Path, required=True, help=f"run directory (checkpoint, log, PNG, {what})")
    parser.add_argument("--config", default=config, help=f"{what} config name")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help=f"{what} config overrides")
    parser.add_argument("--steps", type=int, required=True, help="total optimizer steps (resume continues to it)")
    parser.add_argument("--time-budget", type=float, default=None, metavar="SECONDS",
                        help="stop after this much wall-clock training time (checkpointed; re-running continues)")
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--lr", type=float, default=4e-4)
    parser.add_argument("--warmup", type=int, default=100)
    parser.add_argument("--workers", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--bf16", action="store_true")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--log-every", type=int, default=20)
    parser.add_argument("--ckpt-every", type=int, default=ckpt_every)
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument("--model-id", default=model_id)
    parser.add_argument("--model-version", default=model_version)


def parse_overrides(items: list[str]) -> dict[str, Any]:
    """["a=1", "b=true"] -> {"a": 1, "b": True} (JSON values; bare words stay strings)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise ModelError(f"--set expects KEY=VALUE, got {item!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def lr_at(step: int, base: float, warmup: int, total: int) -> float:
    """Linear warm-up, then cosine decay to 10% of ``base``."""
    if step < warmup:
        return float(base * (step + 1) / warmup)
    progress = min(1.0, (step - warmup) / max(1, total - warmup))
    return float(base * (0.1 + 0.9 * 0.5 * (1.0 + np.cos(np.pi * progress))))  # python float: weights_only loads it


def train_loop(args: argparse.Namespace, info: DistInfo, module: nn.Module, trained: nn.Module,
               optimizer: torch.optim.Optimizer, batches: Iterator[Any], step_fn, *, title: str,
               extra_state: dict[str, Any], device: torch.device | None = None,
               average: WeightAverage | None = None, validate: Callable[[int], dict[str, Any]] | None = None,
               validate_every: int = 0) -> list[dict[str, Any]]:
    """Run optimizer steps up to ``args.steps``, resuming from ``<out>/checkpoint``.

    ``device``: where the batches go (the modules must already be there); default CPU. With
    ``args.time_budget`` (seconds, optional) the loop stops at the first step that ends past it, and
    checkpoints and logs that step as if it were the last; with ``args.stop_at`` (a step, optional) it
    stops there the same way (the learning-rate schedule stays that of ``args.steps``, so a run resumed
    past it continues as if it had never stopped).

    ``trained`` is the bare module whose state is checkpointed (``module`` may be its DDP wrapper,
    which ``step_fn(module, batch) -> (loss, logs)`` calls). Rank 0 logs every ``log_every`` steps to
    ``<out>/log.jsonl`` (losses averaged over ranks), checkpoints every ``ckpt_every`` steps and at
    the end, and draws ``<out>/loss.png``. Returns the log records.

    ``average`` (optional) is updated after every optimizer step and checkpointed with the weights.
    ``validate(step) -> metrics`` (optional, rank 0) runs every ``validate_every`` steps and at the last
    step; its records go to ``<out>/val.jsonl`` (trimmed to the checkpoint on resume like the log).
    """
    out: Path = args.out
    ckpt = out / "checkpoint"
    state = load_checkpoint(ckpt, trained, optimizer, average)
    start = int(state["step"]) if state else 0
    rewarm = bool(state and state.get("fresh_optimizer")) and start > 0
    if rewarm and info.is_main:  # Adam's moments start over: ramp the schedule's rate up again
        print(f"resuming at step {start} without optimizer state: learning rate re-warmed over {args.warmup} steps")
    log = JsonlLog(out / "log.jsonl", enabled=info.is_main)
    val_log = JsonlLog(out / "val.jsonl", enabled=info.is_main and validate is not None)
    if info.is_main:  # drop records a crash left after the last checkpoint
        for kept_log in (log, val_log):
            if kept_log.enabled:
                kept = [r for r in kept_log.read() if r.get("step", -1) <= start]
                kept_log.path.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in kept))
    bar = tqdm(range(start, args.steps), initial=start, total=args.steps, desc=title,
               disable=args.no_progress or not info.is_main, dynamic_ncols=True)
    window: list[float] = []
    t0 = time.time()
    device = torch.device("cpu") if device is None else device
    budget = getattr(args, "time_budget", None)
    stop_at = getattr(args, "stop_at", None)
    if stop_at is not None and (isinstance(stop_at, bool) or not isinstance(stop_at, int) or stop_at < 1):
        raise ModelError(f"--stop-at must be a positive step number, got {stop_at!r}")
    module.train()
    for step in bar:
        if stop_at is not None and step >= stop_at:
            break
        lr = lr_at(step, args.lr, args.warmup, args.steps)
        if rewarm:
            lr *= min(1.0, (step - start + 1) / max(1, args.warmup))
        for group in optimizer.param_groups:
            group["lr"] = lr * group.get("lr_scale", 1.0)
        batch = next(batches)
        if device.type != "cpu":
            batch = to_device(batch, device)
        with autocast(args.bf16, device.type):
            loss, logs = step_fn(module, batch)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        grad_norm = torch.nn.utils.clip_grad_norm_([p for p in trained.parameters() if p.requires_grad], 1.0)
        optimizer.step()
        if average is not None:
            average.update(trained)
        window.append(float(loss.detach()))
        out_of_time = budget is not None and time.time() - t0 >= budget
        if budget is not None and info.distributed:  # every rank takes part, and stops at the same step
            flag = torch.tensor([float(out_of_time)])
            dist.all_reduce(flag, op=dist.ReduceOp.MAX)
            out_of_time = bool(flag.item())
        stop_here = stop_at is not None and step + 1 == stop_at
        last = step + 1 == args.steps or out_of_time or stop_here
        if (step + 1) % args.log_every == 0 or last:
            mean = torch.tensor([sum(window) / len(window)], dtype=torch.float64)
            if info.distributed:
                dist.all_reduce(mean)
                mean /= info.world_size
            record = {"step": step + 1, "loss": float(mean), "lr": optimizer.param_groups[0]["lr"],
                      "grad_norm": float(grad_norm), "elapsed_s": round(time.time() - t0, 2),
                      **{k: v for k, v in logs.items() if k != "loss"}}
            log.write(record)
            bar.set_postfix(loss=f"{float(mean):.4f}")
            window.clear()
        if validate is not None and info.is_main and ((validate_every > 0 and (step + 1) % validate_every == 0)
                                                      or last):
            t_val = time.time()
            metrics = validate(step + 1)
            val_log.write({"step": step + 1, **metrics, "seconds": round(time.time() - t_val, 2)})
            module.train()
        if (step + 1) % args.ckpt_every == 0 or last:
            if info.is_main:
                save_checkpoint(ckpt, trained, optimizer, step + 1, {"args": _jsonable(vars(args)), **extra_state},
                                average)
            if info.distributed:
                dist.barrier()
        if out_of_time or stop_here:
            if info.is_main:
                reason = f"--time-budget {budget:g} s reached" if out_of_time else "--stop-at"
                print(f"{reason} at step {step + 1} of {args.steps}: checkpointed")
            break
    bar.close()
    records = log.read() if info.is_main else []
    if info.is_main:
        plot_loss_curve(records, out / "loss.png", title)
    return records


def _jsonable(values: dict[str, Any]) -> dict[str, Any]:
    return {k: (str(v) if isinstance(v, Path) else v) for k, v in values.items()}
