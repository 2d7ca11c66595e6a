"""Ship a trained model inside the package: float16 safetensors + config + a model card.

    python -m vt4dcodec.model.train.ship --run runs/tok --autoencoder-run runs/ae --id vt4d-tiny \
        --version 0.1.0 [--dest model/weights] [--notes docs/card_notes.md] [--decoder-from runs/aeD] \
        [--set spread_views=true]

Without ``--autoencoder-run`` (a run warm-started from the shipped model, its autoencoder frozen) the
card carries over the stage-1 record of the model it replaces, after checking the autoencoders are equal.

Reads the stage-2 run's final model (``<run>/model``, written by ``train.tokenizer``), rounds its
weights to float16 storage (half the file; loaded as float32), and writes
``<dest>/<id>/{config.json, model.safetensors, MODEL_CARD.md}``.  The card is generated from the runs'
own records (arguments, steps, wall time from the JSONL logs, training-pair PSNR) so it cannot drift
from what was trained; ``--notes`` appends hand-written sections (evaluation, known limits). ``--set``
changes config fields that add no weights (the trained weights must load into the changed config exactly);
the card names them as set at ship time.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file

from vt4dcodec.errors import ModelError

from ..videotok4d import VideoTok4D
from ..onnx_export import export_model
from ..weights_io import SHIPPED_DIR, from_pretrained, read_model_meta, save_pretrained, storage_state
from .autoencoder import AE_WEIGHTS
from .common import parse_overrides

__all__ = ["main", "model_card", "reconfigure"]


def _log_summary(log: Path) -> dict:
    """Steps and wall seconds of a JSONL training log (resumed segments restart ``elapsed_s``)."""
    records = [json.loads(line) for line in log.read_text().splitlines() if line.strip()]
    if not records:
        return {"steps": 0, "wall_seconds": 0.0}
    wall, prev = 0.0, 0.0
    for r in records:
        e = float(r.get("elapsed_s", 0.0))
        if e < prev:  # a resumed segment
            wall += prev
        prev = e
    wall += prev
    return {"steps": int(records[-1]["step"]), "wall_seconds": round(wall, 1),
            "first_loss": records[0].get("loss"), "last_loss": records[-1].get("loss")}


def _pairs_text(args: dict) -> str:
    recon, sigma = args.get("recon_share", 0.0), args.get("neighbour_sigma")
    if not recon and sigma is None:
        return "every ordered camera pair (source c, target a != c) is a sample"
    near = f"weighted exp(-angle / {sigma} deg) by optical-axis angle" if sigma is not None else "uniform"
    return (f"one sample per (scene, source camera): the target is the source itself with probability {recon} "
            f"(reconstruction), else another camera {near}")


def model_card(model_id: str, version: str, run: Path, ae_run: Path | None, fingerprint: dict, notes: str,
               decoder_run: Path | None = None, shipped_set: dict | None = None,
               stage1_lines: list[str] | None = None, config: dict | None = None,
               graphs: list[str] | None = None) -> str:
    """The card's text. ``ae_run`` None: the stage-1 lines are ``stage1_lines``, taken from the card of the
    shipped predecessor whose autoencoder this model kept (:func:`inherited_stage1_lines`)."""
    state = json.loads((run / "checkpoint" / "state.json").read_text())
    args, cfg = state["args"], {**state["config"], **(shipped_set or {})}
    tok = _log_summary(run / "log.jsonl")
    summary = json.loads((run / "summary.json").read_text()) if (run / "summary.json").is_file() else {}
    if ae_run is not None:
        ae = _log_summary(ae_run / "log.jsonl")
        info_file = ae_run / "autoencoder.json"
        ae_info = json.loads(info_file.read_text()) if info_file.is_file() else {}
        stage1 = [f"- stage 1 autoencoder: {ae['steps']} steps, batch 32 frames, {ae['wall_seconds'] / 60:.0f} min "
                  f"wall; reconstruction PSNR {ae_info.get('sample_psnr_db', float('nan')):.2f} dB on 256 training "
                  "frames"]
    else:
        stage1 = list(stage1_lines or [])
    params = ", ".join(f"{k}={v}" for k, v in sorted((config if config is not None else cfg).items()))
    names = sorted(graphs or ["encoder.onnx"], key=lambda n: (not n.startswith("encoder"), len(n), n))
    encoders = [n for n in names if n.startswith("encoder")]
    most = max([int(n[len("encoder-v"):-len(".onnx")]) for n in encoders if n.startswith("encoder-v")] or [1])
    others = [f"`{n}`: {what}" for n, what in (
        ("renderer.onnx", "the renderer and the autoencoder's decoder"),
        ("feedback.onnx", "the encoder's render feedback (the encoder graphs give the first pass, "
                          + ("`render-gradient*.onnx` render it and differentiate the render by the tokens, one "
                             "graph per camera count)" if any(n.startswith("render-gradient") for n in names)
                             else "`renderer.onnx` renders it)"))) if n in names]
    onnx_line = (f"- `{encoders[0]}`" + (f" ... `{encoders[-1]}`: the encoders for scenes of 1 to {most} cameras"
                                          if len(encoders) > 1 else ": the encoder for one camera per scene")
                 + "".join(f", {part}" for part in others[:-1]) + "".join(f", and {part}" for part in others[-1:])
                 + ", exported for onnxruntime from these weights (`vt4d encode` and `vt4d decode` run them without "
                   "torch; same fingerprint, tokens equal to float rounding)")
    lines = [
        f"# {model_id} {version}",
        "",
        "A VideoTok4D tokenizer + rectified-flow renderer sized for CPU, trained on this project's synthetic",
        "multi-camera dynamic scenes only (no pretrained weights exist offline).",
        "",
        "## Identity",
        f"- config SHA-256: `{fingerprint['config_sha256']}`",
        f"- weights SHA-256: `{fingerprint['weights_sha256']}` (over the float32 weights; stored as float16)",
        f"- tokens: Z_s {fingerprint['static_shape'][0]}x{fingerprint['static_shape'][1]}, "
        f"Z_d {fingerprint['dynamic_shape'][0]}x{fingerprint['dynamic_shape'][1]}, bounded in (-1, 1)",
        f"- config: {params}",
        onnx_line,
        "",
        "## Training (reproduce with the commands in docs/training.md)",
        *stage1,
        f"- stage 2 tokenizer + renderer: {tok['steps']} steps, batch {args['batch_size']}, lr {args['lr']} "
        f"(warm-up {args['warmup']}, cosine), bf16 autocast={args['bf16']}, {tok['wall_seconds'] / 60:.0f} min "
        f"wall on the 2-core CPU machine shared with other jobs; training loss "
        f"{tok['first_loss']:.3f} -> {tok['last_loss']:.3f}",
        *([f"- trained only the parameters named {args['train_only']!r} (`--train-only`); every other tensor "
            "stayed the warm start's"] if args.get("train_only") else []),
        f"- data: {args['scenes']} synthetic training scenes (seeds {args['scene_seed']}..."
        f"{args['scene_seed'] + args['scenes'] - 1}, split 'train'), {args['cameras']} cameras each, 8 frames at "
        "64x64; " + _pairs_text(args),
        *([f"- warm start: the weights of {args['init']} (this model's predecessor; its own training is in "
            "docs/training.md)"
           + (", every tensor whose shape fits (a static token set grown by a whole factor starts as copies, "
              "frame-copy maps switched on start from the cell and splat maps); other tensors new in this "
              "config start fresh" if args.get("init_partial") else "")]
          if args.get("init") else []),
        f"- recipe: prediction={cfg.get('prediction', 'velocity')}, share of samples at tau = 1: "
        f"{args.get('tau_one', 0.0)}, static-token dropout {args.get('drop_static', 0.0)}, saturation penalty "
        f"{args.get('saturation_weight', 0.0)}, x0 weight {args.get('x0_weight', 0.0)}"
        + (f", cell loss weight {args['cell_weight']}" if args.get("cell_weight") else "")
        + (f", SSIM loss weight {args['ssim_weight']}" if args.get("ssim_weight") else "")
        + (f", multi-camera batches {args['multi_share']}" if args.get("multi_share") else ""),
    ]
    if decoder_run is not None:
        dec = _log_summary(decoder_run / "log.jsonl")
        lines.append(f"- decoder fine-tuned alone afterwards (`--decoder-only`, encoder and latents unchanged): "
                     f"{dec['steps']} steps, {dec['wall_seconds'] / 60:.0f} min wall ({decoder_run})")
    if shipped_set:
        lines.append("- set at ship time, no weights added (trained without them): "
                     + ", ".join(f"{k}={v}" for k, v in sorted(shipped_set.items())))
    if summary and summary.get("pairs"):  # (a run with --samples 0 renders none)
        lines.append(f"- render PSNR on {len(summary.get('pairs', []))} training pairs: "
                     f"{summary.get('mean_psnr_db', float('nan')):.2f} dB ({summary.get('render_steps')} Euler steps)")
    lines += ["", notes.strip(), ""] if notes.strip() else [""]
    return "\n".join(lines)


def inherited_stage1_lines(model: VideoTok4D, predecessor: Path) -> list[str]:
    """The stage-1 lines (autoencoder, decoder fine-tune) of the card of the shipped model in ``predecessor``,
    for a model trained on from it whose frozen autoencoder is still exactly that model's (float16 storage),
    so the card can say how the autoencoder was trained without its run directory. ModelError otherwise."""
    card = predecessor / "MODEL_CARD.md"
    try:
        own = from_pretrained(predecessor).autoencoder.state_dict()
        text = card.read_text()
    except (OSError, ModelError) as exc:
        raise ModelError(f"no --autoencoder-run and no shipped predecessor to take the stage-1 record from "
                         f"({predecessor}: {exc})") from None
    new = model.autoencoder.state_dict()
    if set(own) != set(new) or any(not torch.equal(own[k].half().float(), new[k].half().float()) for k in own):
        raise ModelError(f"the model's autoencoder is not the one shipped in {predecessor}: give --autoencoder-run")
    lines = [line for line in text.splitlines()
             if line.startswith(("- stage 1 autoencoder:", "- decoder fine-tuned alone"))]
    if not lines:
        raise ModelError(f"{card} has no stage-1 line: give --autoencoder-run")
    version = read_model_meta(predecessor).get("model_version", "?")
    # a record carried over before keeps naming the version whose run it came from
    return [line if " (kept from " in line else f"{line} (kept from {predecessor.name} {version})" for line in lines]


def swap_decoder(model: VideoTok4D, weights: Path) -> None:
    """Load the decoder of a stage-1 ``weights`` file into ``model``'s autoencoder, after checking that
    its encoder and latent statistics equal the model's at float16 storage precision (the shipped
    weights are float16 values): the latents the tokenizer was trained on stay exactly what they were."""
    try:
        state = load_file(str(weights))
    except (OSError, SafetensorError, ValueError) as exc:
        raise ModelError(f"--decoder-from: cannot read {weights}: {exc}") from None
    own = model.autoencoder.state_dict()
    if set(state) != set(own):
        raise ModelError(f"--decoder-from {weights}: not an autoencoder of this config")
    for name, value in state.items():
        if value.shape != own[name].shape:
            raise ModelError(f"--decoder-from {weights}: {name} has shape {tuple(value.shape)}, "
                             f"the model's is {tuple(own[name].shape)}")
        if not name.startswith("decoder.") and not torch.equal(value.half().float(), own[name].half().float()):
            raise ModelError(f"--decoder-from {weights}: its {name} differs from the model's: the decoder belongs to "
                             f"another encoder (train it with --decoder-only --init on this model's autoencoder)")
    model.autoencoder.load_state_dict({k: v for k, v in state.items() if k.startswith("decoder.")}, strict=False)


def reconfigure(model: VideoTok4D, overrides: dict) -> VideoTok4D:
    """``model`` under its config with ``overrides``: the same weights, which must fit the new config exactly
    (a field that adds, removes or reshapes weights is refused with ModelError)."""
    new = VideoTok4D(model.config.replace(**overrides)).eval()
    try:
        new.load_state_dict(model.state_dict(), strict=True)
    except RuntimeError as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ModelError(f"--set {overrides}: the trained weights do not fit the changed config ({first})") from None
    new.freeze_autoencoder()
    new.decode_steps, new.default_quality = model.decode_steps, model.default_quality  # settings, not config
    return new


def token_sources_of(model: VideoTok4D, base_name: str) -> list[dict[str, str]]:
    """The ``reads`` record of ``model`` as an update of ``base_name`` that reads its tokens: the base's
    fingerprint, and the earlier models whose tokens the base read (its networks' digests where they differ from
    its own, its own ``reads``). The update may replace the renderer, may add render feedback to an encoder
    without it, and may add to a base's render feedback further passes (``feedback_passes``) and the render's
    gradient (``feedback_gradient``). ModelError unless the model has the base's config (those fields aside) and,
    stored as float16, every tensor of the base outside ``renderer.*`` equal to the base's (new tensors can only
    be the feedback's: the config allows no other) -- the same first-pass encoder, token quantizer and entropy
    tables, so every file of the base holds tokens the model reads as the base did, and its first pass is the
    base's encode."""
    base = from_pretrained(base_name)
    if not base.config.feedback_width:
        plain = model.config.without_feedback()
    else:  # the base's feedback kept; passes and the gradient may be added
        plain = model.config.replace(feedback_passes=base.config.feedback_passes,
                                     feedback_gradient=base.config.feedback_gradient)
    if base.config != plain:
        raise ModelError(f"{base_name}'s config differs from the model's: an update that reads its tokens keeps the "
                         f"config (render feedback, its passes and its gradient aside)")
    ours, theirs = storage_state(model, "float16")[0], base.state_dict()
    differ = sorted(k for k in theirs if not k.startswith("renderer.") and not torch.equal(ours[k], theirs[k]))
    if differ:
        raise ModelError(f"tensors outside renderer.* differ from {base_name}'s ({', '.join(differ[:4])}"
                         f"{', ...' if len(differ) > 4 else ''}): the tokens would not be read the same way")
    fp = base.fingerprint(str(base.model_id), str(base.model_version))
    entries = [{"model_version": str(base.model_version), "config_sha256": fp.config_sha256,
                "weights_sha256": fp.weights_sha256}]
    seen = {(fp.config_sha256, fp.weights_sha256)}
    for pair in ([tuple(base.network_digests)] if base.network_digests else []) + list(base.token_sources):
        if pair not in seen:
            seen.add(pair)
            entries.append({"config_sha256": pair[0], "weights_sha256": pair[1]})
    return entries


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m vt4dcodec.model.train.ship", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, required=True, help="stage-2 run directory (holds model/)")
    parser.add_argument("--autoencoder-run", type=Path, default=None,
                        help="stage-1 run directory; without it the model must keep the autoencoder of the model "
                             "it replaces in --dest, whose card's stage-1 record is carried over")
    parser.add_argument("--id", required=True, help="model id, e.g. vt4d-tiny")
    parser.add_argument("--version", required=True)
    parser.add_argument("--dest", type=Path, default=SHIPPED_DIR, help="directory of shipped models")
    parser.add_argument("--notes", type=Path, help="markdown appended to the generated model card")
    parser.add_argument("--decode-steps", type=int, default=None,
                        help="the codec's default sampler steps for this model (measure: the best-fidelity setting)")
    parser.add_argument("--default-quality", type=int, default=None, metavar="N",
                        help="a model with quality levels: the level the codec stores tokens at when none is asked "
                             "for (chosen by docs/training.md's rate-distortion rule; default: none, then int4)")
    parser.add_argument("--decoder-from", type=Path, default=None,
                        help="stage-1 run of a `--decoder-only` fine-tune: its decoder replaces the model's; its "
                             "encoder and latent statistics must be the model's (the tokens stay valid)")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="config fields to change at ship time that add no weights, e.g. spread_views=true")
    parser.add_argument("--reads", type=str, default=None, metavar="MODEL",
                        help="an update of MODEL (shipped id or directory, e.g. the model it replaces) that replaced its "
                             "renderer or added render feedback (or feedback passes, or the render's gradient) to its "
                             "encoder: checked to have MODEL's config (those fields aside) and every tensor of MODEL "
                             "outside renderer.* (encoder, entropy "
                             "tables), and recorded so MODEL's files, and a prior trained on its tokens, stay readable")
    args = parser.parse_args(argv)
    overrides = parse_overrides(args.set)
    model = from_pretrained(args.run / "model")
    if overrides:
        model = reconfigure(model, overrides)
    if args.decoder_from is not None:
        swap_decoder(model, args.decoder_from / AE_WEIGHTS)
    reads = None
    if args.reads is None:
        model.update_entropy()  # the integer tables the codec reads (a no-op without an entropy model)
    else:  # an update that reads its predecessor's tokens keeps the tables its files were coded with (recomputing
        try:  # them from the float16-stored densities would not give the same integers)
            reads = token_sources_of(model, args.reads)
        except ModelError as exc:
            parser.error(f"--reads: {exc}")
    notes = args.notes.read_text() if args.notes else ""
    stage1 = None if args.autoencoder_run is not None else inherited_stage1_lines(model, args.dest / args.id)
    for stale in (args.dest / args.id).glob("*.onnx"):  # graphs of the old weights never stay
        stale.unlink()
    out = save_pretrained(model, args.dest / args.id, model_id=args.id, model_version=args.version,
                          storage_dtype="float16", decode_steps=args.decode_steps, default_quality=args.default_quality,
                          reads=reads)
    # the encoders for 1 .. 10 cameras and the renderer, so the torch-free codec encodes and decodes with the new
    # weights (save_pretrained rounded model to the stored float16 values the graphs read)
    graphs = export_model(model, out)
    fp = model.fingerprint(args.id, args.version).to_dict()
    (out / "MODEL_CARD.md").write_text(model_card(args.id, args.version, args.run, args.autoencoder_run, fp, notes,
                                                        args.decoder_from, overrides, stage1,
                                                        config=model.config.to_dict(), graphs=[g.name for g in graphs]))
    size, onnx_size = (out / "model.safetensors").stat().st_size, sum(g.stat().st_size for g in graphs)
    print(f"shipped {args.id} {args.version} -> {out} ({size / 1e6:.1f} MB; {len(graphs)} ONNX graphs "
          f"{onnx_size / 1e6:.1f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
