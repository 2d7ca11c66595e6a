"""The ``vt4d`` command.

Each group of subcommands lives in its own module of this package and exposes
``register(subparsers) -> None``; the module adds its subparsers and sets ``func`` on each, a callable
``func(args) -> int`` returning the exit code.  Modules are imported lazily so that ``vt4d info`` never
imports torch.

Exit codes (stable, for scripts):
    0  success
    1  the input is invalid or failed verification (any vt4dcodec error)
    2  wrong usage (unknown command, bad option)
    3  a file system error (missing file, permission denied)
    130  interrupted
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from pathlib import Path
from typing import Sequence

from ..errors import Vt4dError

EXIT_OK, EXIT_INVALID, EXIT_USAGE, EXIT_OS, EXIT_INTERRUPTED = 0, 1, 2, 3, 130

# Command modules, in the order their commands appear in --help.
COMMAND_MODULES = (
    "vt4dcodec.cli.scene_commands",    # info, verify
    "vt4dcodec.cli.codec_commands",    # encode, decode, demo
    "vt4dcodec.cli.archive_commands",  # pack, ls, extract, repair
    "vt4dcodec.cli.capture_commands",  # capture-info, contact-sheet, synth (synth_commands)
    "vt4dcodec.cli.generate_commands", # generate
)


def trajectory_label(spec: str, index: int) -> str:
    """A file-name stem for the ``index``-th rendered trajectory ``spec``: "source", a trajectory
    file's stem, or the index and the spec with every non-alphanumeric character replaced."""
    if spec == "source":
        return "source"
    if os.path.isfile(spec):
        return Path(spec).stem
    return f"{index:02d}_" + "".join(c if c.isalnum() else "_" for c in spec)[:48]


def int_at_least(minimum: int):
    """An argparse type: an integer >= ``minimum`` (a usage error, exit code 2, otherwise)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{text!r} must be at least {minimum}")
        return value

    parse.__name__ = f"integer>={minimum}"
    return parse


positive_int = int_at_least(1)
nonneg_int = int_at_least(0)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vt4d",
        description=(
            "vt4dcodec: compress multi-camera captures into small .vt4d token files, keep them in "
            "archives, and render any camera view back.  Run `vt4d COMMAND --help` for each command."
        ),
        epilog="Exit codes: 0 ok, 1 invalid input or failed verification, 2 usage, 3 file system error.",
    )
    from ..version import __version__

    parser.add_argument("--version", action="version", version=f"vt4dcodec {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_USAGE
    try:
        return int(args.func(args) or 0)
    except Vt4dError as exc:
        print(f"vt4d {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_INVALID
    except OSError as exc:
        print(f"vt4d {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_OS
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
