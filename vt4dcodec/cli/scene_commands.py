"""`vt4d info FILE` and `vt4d verify FILE...`: inspect and check .vt4d files without torch (local paths
or fsspec URLs)."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from ..archive import is_archive, open_archive, verify_archive
from ..errors import Vt4dError
from ..format import open_scene, verify
from . import (add_budget_option, add_command, add_storage_option, budget_message, emit, in_words, os_error_message,
               plural, read_head, storage_options)

EXIT_OK, EXIT_INVALID, EXIT_OS = 0, 1, 3


def register(subparsers: argparse._SubParsersAction) -> None:
    info = add_command(subparsers, "info", help="show what a .vt4d scene file (or an archive) holds",
                       description="Print the header of a .vt4d scene: model fingerprint, token shapes, encoding, "
                                   "cameras, provenance and sections.  Reads the header only; no torch.  On an archive (.vt4da): "
                                   "its scene count, and the commands that list, extract and render its scenes.",
                       examples=["vt4d info scene.vt4d",
                                 "vt4d info https://example.org/scene.vt4d --json"])
    info.add_argument("file", help="a .vt4d scene file or a .vt4da archive (path or fsspec URL)")
    add_storage_option(info)
    add_budget_option(info)
    info.set_defaults(func=run_info)
    verify = add_command(subparsers, "verify", help="check .vt4d files (scenes or archives) byte by byte",
                         description="Verify every checksum, size and section of each file. Exit code 0 when all "
                                     "are valid, 1 if any is invalid, 3 if any cannot be read.",
                         examples=["vt4d verify scene.vt4d scenes.vt4da",
                                   "vt4d verify s3://bucket/scenes.vt4da --storage-option anon=true --json"])
    verify.add_argument("files", nargs="+", metavar="FILE", help=".vt4d scene or archive files (paths or URLs)")
    add_storage_option(verify)
    add_budget_option(verify)
    verify.set_defaults(func=run_verify)


def _is_archive(path: str, options: dict[str, str] | None = None) -> bool:
    """True if the file starts with the archive signature."""
    return is_archive(read_head(path, options))


def run_verify(args: argparse.Namespace) -> int:
    options = storage_options(args.storage_option)
    results: list[dict[str, Any]] = []
    for path in args.files:
        result: dict[str, Any] = {"file": path, "ok": True, "kind": "scene", "error": None, "message": None}
        try:
            if _is_archive(path, options):
                result["kind"] = "archive"
                verify_archive(path, max_decoded_bytes=args.max_decoded_bytes, **options)
            else:
                verify(path, max_decoded_bytes=args.max_decoded_bytes, **options)
        except Vt4dError as exc:
            result.update(ok=False, error=type(exc).__name__, message=in_words(budget_message(str(exc))),
                          exit=EXIT_INVALID)
        except OSError as exc:
            result.update(ok=False, error=type(exc).__name__, message=os_error_message(exc), exit=EXIT_OS)
        results.append(result)
        if not args.json:
            if not result["ok"]:
                message = result["message"]  # in words (the error's kind stays in --json's "error")
                print(f"FAIL  {message if message.startswith(path) else f'{path}: {message}'}", file=sys.stderr)
            elif not args.quiet:
                print(f"OK    {path} ({result['kind']})")
    codes = {r.pop("exit", EXIT_OK) for r in results}
    if args.json:
        print(json.dumps(results, indent=2))
    if EXIT_INVALID in codes:
        return EXIT_INVALID
    return EXIT_OS if EXIT_OS in codes else EXIT_OK


def _provenance(summary: dict[str, Any], metadata: dict[str, Any]) -> str:
    """How the tokens came to be, in words: encoded from a capture, or sampled by a prior (and from what)."""
    kind, capture, when = summary["kind"], summary["source_capture_id"], summary["created_utc"] or "unknown time"
    if kind is None:
        return "not recorded"
    text = kind
    if kind == "generated":
        gen = metadata.get("co4dgen") if isinstance(metadata.get("co4dgen"), dict) else {}
        if gen.get("prior_id"):
            text += f" by {gen['prior_id']} {gen.get('prior_version', '')}".rstrip()
            text += f" (seed {gen.get('seed', '-')}, {gen.get('steps', '-')} {gen.get('method', '')} steps)"
        cond = metadata.get("conditioning") if isinstance(metadata.get("conditioning"), dict) else {}
        if capture or cond.get("capture_id"):
            text += f", conditioned on capture {capture or cond.get('capture_id')}"
            text += f" camera {cond['camera']}" if cond.get("camera") else ""
        else:
            text += ", from a video given directly (no capture id recorded)"
    else:
        text += f" from capture {capture}" if capture else " (no source capture recorded)"
    return f"{text}, at {when}"


def _archive_info(args: argparse.Namespace, options: dict[str, str]) -> int:
    """`vt4d info` on an archive: what it is, and the commands that show and get its scenes."""
    with open_archive(args.file, max_decoded_bytes=args.max_decoded_bytes, **options) as reader:  # no record read
        keys = reader.keys()
        summary = {"file": args.file, "kind": "archive", "scenes": len(keys), "generation": reader.generation,
                   "uncommitted_bytes": reader.uncommitted_bytes}
    key = keys[0] if keys else "KEY"
    lines = [f"{args.file}: a .vt4da archive of {plural(len(keys), 'scene')} (generation {summary['generation']})",
             f"  list its scenes:        vt4d ls {args.file}",
             f"  one scene's header:     vt4d extract {args.file} {key} -o out/ && vt4d info out/{key}.vt4d",
             f"  render a scene:         vt4d decode {args.file} --key {key} -o views/",
             f"  check every record:     vt4d verify {args.file}"]
    emit(args, summary, lines)
    return EXIT_OK


def run_info(args: argparse.Namespace) -> int:
    options = storage_options(args.storage_option)
    if _is_archive(args.file, options):
        return _archive_info(args, options)
    scene = open_scene(args.file, max_decoded_bytes=args.max_decoded_bytes, **options)
    summary = scene.summary()
    summary |= {"token_bytes": scene.token_bytes, "non_token_bytes": scene.nbytes - scene.token_bytes,
                "header_bytes": scene.preamble.header_length, "compact_container": scene.compact_container,
                "camera_encoding": scene.camera_encoding(), "extra_cameras": scene.num_extra_cameras,
                "joint_extra_cameras": scene.joint_cameras, "adaptive_rows": scene.adaptive_tokens}
    # bits per pixel of what the file stores: every byte over the encoded cameras' pixels (all frames)
    pixels = (1 + summary["extra_cameras"]) * summary["frames"] * summary["width"] * summary["height"]
    summary["bits_per_pixel"] = round(8 * summary["bytes"] / pixels, 5)
    if args.json or args.quiet:
        emit(args, summary)
        return EXIT_OK
    fp = summary["fingerprint"]
    lines = [
        f"file            {args.file}",
        f"format          .vt4d scene v{summary['format_version']}, {summary['bytes']} bytes "
        f"({summary['token_bytes']} of tokens, {summary['non_token_bytes']} of everything else, "
        f"{summary['header_bytes']} of them the {'compressed ' if summary['compact_container'] else ''}header)",
        f"tokens          Z_s {summary['static_shape'][0]}x{summary['static_shape'][1]}, "
        f"Z_d {summary['dynamic_shape'][0]}x{summary['dynamic_shape'][1]}, encoding {summary['encoding']}"
        + (f" at quality {summary['quality']}" if summary.get("quality") else "")
        + (" (adaptive rows)" if summary["adaptive_rows"] else ""),
        f"rate            {summary['bits_per_pixel']:.4f} bits per pixel of the encoded camera"
        + (f"s ({1 + summary['extra_cameras']})" if summary["extra_cameras"] else "") + " (the whole file)",
        f"cameras         {summary['frames']} frames at {summary['width']}x{summary['height']} px, "
        f"{summary['camera_encoding']}"
        + (f", {summary['extra_cameras']} extra encoded camera{'s' if summary['extra_cameras'] > 1 else ''}"
           + (" (joint layout)" if summary["joint_extra_cameras"] else "") if summary["extra_cameras"] else ""),
        f"model           {fp['model_id']} {fp['model_version']} ({fp['token_dtype']})",
        f"  config sha256 {fp['config_sha256']}",
        f"  weights sha256 {fp['weights_sha256']}",
        f"provenance      {_provenance(summary, scene.metadata)}",
        f"metadata keys   {', '.join(summary['metadata_keys']) or '-'}",
        "sections",
    ]
    for s in summary["sections"]:
        lines.append(f"  {s['type']}  {'critical ' if s['critical'] else 'ancillary'}  {s['compression']:<4}  "
                     f"{s['stored_bytes']:>10} stored  {s['raw_bytes']:>10} raw")
    print("\n".join(lines))
    return EXIT_OK
