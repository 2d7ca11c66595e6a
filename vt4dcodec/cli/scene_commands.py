"""`vt4d info FILE` and `vt4d verify FILE...`: inspect and check .vt4d files without torch."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from ..errors import Vt4dError

EXIT_OK, EXIT_INVALID, EXIT_OS = 0, 1, 3
ARCHIVES_UNSUPPORTED = "archives not supported by this build"


def register(subparsers: argparse._SubParsersAction) -> None:
    info = subparsers.add_parser("info", help="show what a .vt4d scene file holds",
                                 description="Print the header of a .vt4d scene: model fingerprint, token "
                                             "shapes, encoding, cameras, provenance and sections.")
    info.add_argument("file", help="a .vt4d scene file")
    info.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    info.set_defaults(func=run_info)
    verify = subparsers.add_parser("verify", help="check .vt4d files (scenes or archives) byte by byte",
                                   description="Verify every checksum, size and section of each file. Exit "
                                               "code 0 when all are valid, 1 if any is invalid, 3 if any "
                                               "cannot be read.")
    verify.add_argument("files", nargs="+", metavar="FILE", help=".vt4d scene or archive files")
    verify.add_argument("--json", action="store_true", help="print a JSON list of per-file results")
    verify.set_defaults(func=run_verify)


def _is_archive(path: str) -> bool:
    """True if the file starts with the archive signature (known only when the archive module exists)."""
    from ..format import SCENE_MAGIC

    with open(path, "rb") as fh:
        head = fh.read(16)
    if head.startswith(SCENE_MAGIC):
        return False
    try:
        from ..archive import ARCHIVE_MAGIC  # type: ignore[attr-defined]
    except ImportError:
        # No archive support in this build: anything with the vt4d family prefix that is not a scene is
        # treated as an archive so the user gets a clear message.
        return head.startswith((b"\x89V4", b"\x89VT4"))
    return head.startswith(ARCHIVE_MAGIC)


def _verify_archive(path: str) -> None:
    try:
        from ..archive import verify_archive  # type: ignore[attr-defined]
    except ImportError:
        from ..errors import UnsupportedFeatureError

        raise UnsupportedFeatureError(f"{path}: {ARCHIVES_UNSUPPORTED}") from None
    verify_archive(path)


def run_verify(args: argparse.Namespace) -> int:
    from ..format import verify

    results: list[dict[str, Any]] = []
    for path in args.files:
        result: dict[str, Any] = {"file": path, "ok": True, "kind": "scene", "error": None, "message": None}
        try:
            if _is_archive(path):
                result["kind"] = "archive"
                _verify_archive(path)
            else:
                verify(path)
        except Vt4dError as exc:
            result.update(ok=False, error=type(exc).__name__, message=str(exc), exit=EXIT_INVALID)
        except OSError as exc:
            result.update(ok=False, error=type(exc).__name__, message=str(exc), exit=EXIT_OS)
        results.append(result)
        if not args.json:
            if result["ok"]:
                print(f"OK    {path} ({result['kind']})")
            else:
                print(f"FAIL  {path}: {result['error']}: {result['message']}", file=sys.stderr)
    codes = {r.pop("exit", EXIT_OK) for r in results}
    if args.json:
        print(json.dumps(results, indent=2))
    if EXIT_INVALID in codes:
        return EXIT_INVALID
    return EXIT_OS if EXIT_OS in codes else EXIT_OK


def run_info(args: argparse.Namespace) -> int:
    from ..format import open_scene

    if _is_archive(args.file):
        print(f"{args.file} is an archive; list its scenes with `vt4d ls {args.file}`", file=sys.stderr)
        return EXIT_INVALID
    summary = open_scene(args.file).summary()
    if args.json:
        print(json.dumps(summary, indent=2))
        return EXIT_OK
    fp = summary["fingerprint"]
    lines = [
        f"file            {args.file}",
        f"format          .vt4d scene v{summary['format_version']}, {summary['bytes']} bytes",
        f"tokens          Z_s {summary['static_shape'][0]}x{summary['static_shape'][1]}, "
        f"Z_d {summary['dynamic_shape'][0]}x{summary['dynamic_shape'][1]}, encoding {summary['encoding']}",
        f"cameras         {summary['frames']} frames at {summary['width']}x{summary['height']} px",
        f"model           {fp['model_id']} {fp['model_version']} ({fp['token_dtype']})",
        f"  config sha256 {fp['config_sha256']}",
        f"  weights sha256 {fp['weights_sha256']}",
        f"provenance      {summary['kind'] or '-'} from capture {summary['source_capture_id'] or '-'} "
        f"at {summary['created_utc'] or '-'}",
        f"metadata keys   {', '.join(summary['metadata_keys']) or '-'}",
        "sections",
    ]
    for s in summary["sections"]:
        lines.append(f"  {s['type']}  {'critical ' if s['critical'] else 'ancillary'}  {s['compression']:<4}  "
                     f"{s['stored_bytes']:>10} stored  {s['raw_bytes']:>10} raw")
    print("\n".join(lines))
    return EXIT_OK
