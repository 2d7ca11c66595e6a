"""The ``vt4d`` command.

Each group of subcommands lives in its own module of this package and exposes
``register(subparsers) -> None``; the module adds its subparsers and sets ``func`` on each, a callable
``func(args) -> int`` returning the exit code.  The command modules import the library at module level,
which loads no torch (the codec loads the networks when a command runs them), so ``vt4d info`` never
imports torch and runs on the core install (tests/test_no_torch_import.py, .ci/core_check.py).

Exit codes (stable, for scripts):
    0  success
    1  the input is invalid or failed verification (any vt4dcodec error)
    2  wrong usage (unknown command, bad option)
    3  a file system error (missing file, permission denied)
    130  interrupted

One meaning for the common options, on every command (:func:`add_command` adds them):
    --json       print one JSON document on stdout (the command's result) instead of text
    -q/--quiet   print nothing on stdout but what --json asks for, and no progress; errors still go
                 to stderr
Progress bars (stderr) appear only on a terminal.  Library errors name Python keywords
(``replace=True``); :func:`cli_message` rewrites them into the flag that fixes them (``--overwrite``).
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import errno
import importlib
import json
import os
import re
import sys
import textwrap
import threading
import time
from pathlib import Path
from typing import Any, Iterable, Iterator, NoReturn, Sequence

from ..errors import BadMagicError, FormatError, Vt4dError
from ..format.layout import SCENE_MAGIC
from ..format.reader import open_binary
from ..format.sections import DEFAULT_MAX_DECODED_BYTES
from ..version import __version__

EXIT_OK, EXIT_INVALID, EXIT_USAGE, EXIT_OS, EXIT_INTERRUPTED = 0, 1, 2, 3, 130

# OpenCV's own "[ WARN:0@...] global loadsave.cpp ..." lines would reach a user's terminal beside the command's
# message for the same problem: the commands say what is wrong themselves (read once, when cv2 loads).
os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")

# Command modules, in the order their commands appear in --help.
COMMAND_MODULES = (
    "vt4dcodec.cli.scene_commands",    # info, verify
    "vt4dcodec.cli.codec_commands",    # encode, decode, demo
    "vt4dcodec.cli.archive_commands",  # pack, ls, extract, repair
    "vt4dcodec.cli.capture_commands",  # capture-info, contact-sheet, synth (synth_commands)
    "vt4dcodec.cli.generate_commands", # generate
)


# Packages of the optional extras (pyproject.toml), for the message a core install gets from codec commands.
EXTRA_OF_MODULE = {name: "codec" for name in ("cv2", "skimage", "tqdm", "onnxruntime", "av")} \
    | {name: "train" for name in ("torch", "kornia", "safetensors", "onnx", "matplotlib")} \
    | {"fsspec": "remote", "aiohttp": "remote"}


def trajectory_label(spec: str, index: int) -> str:
    """A file-name stem for the ``index``-th rendered trajectory ``spec``: "source", a trajectory
    file's stem, or the index and the spec with every non-alphanumeric character replaced."""
    if spec == "source":
        return "source"
    if os.path.isfile(spec):
        return Path(spec).stem
    return f"{index:02d}_" + "".join(c if c.isalnum() else "_" for c in spec)[:48]


def plural(n: int, word: str, words: str | None = None) -> str:
    """``n`` and ``word`` in the number that fits: "1 scene", "3 scenes", "0 scenes"."""
    return f"{n} {word if n == 1 else (words or word + 's')}"


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


def add_upscale_option(p: argparse.ArgumentParser, default: int = 1) -> None:
    """``--upscale N``: nearest-neighbour enlargement of mp4 videos for viewing (decode, generate, demo)."""
    from ..media import MAX_UPSCALE

    def parse(text: str) -> int:
        value = int_at_least(1)(text)
        if value > MAX_UPSCALE:
            raise argparse.ArgumentTypeError(f"{text!r} must be at most {MAX_UPSCALE}")
        return value

    parse.__name__ = f"integer in 1..{MAX_UPSCALE}"
    p.add_argument("--upscale", type=parse, default=default, metavar="N",
                   help="enlarge mp4 videos N times by pixel repetition, for viewing small renders (e.g. 4: "
                        f"64x64 -> 256x256); the pixels themselves are unchanged (default {default}; mp4 only)")


def check_upscale(args: argparse.Namespace) -> None:
    """--upscale enlarges videos only: with --format png or npz it is an error (before any work)."""
    if getattr(args, "upscale", 1) != 1 and getattr(args, "format", "mp4") != "mp4":
        raise Vt4dError(f"--upscale applies to --format mp4 only (got --format {args.format}); PNG frames and "
                        "arrays keep the rendered pixels")


# --- one overwrite convention ---------------------------------------------------------------------------
# Every command that writes files takes -y/--overwrite to replace what is there; --force is kept for one
# thing only, decoding with a model whose fingerprint differs.  The spellings of earlier versions (--force,
# --replace) still work, hidden from --help, with a note that names the new one.
OVERWRITE_FLAGS = ("-y", "--overwrite")


def add_overwrite_option(p: argparse.ArgumentParser, help: str) -> None:
    """``-y/--overwrite`` (dest ``overwrite``)."""
    p.add_argument(*OVERWRITE_FLAGS, dest="overwrite", action="store_true", help=help)


class DeprecatedFlag(argparse.Action):
    """A hidden flag kept so that scripts written for an earlier version still run: sets ``dest`` to True
    and leaves a note (printed by :func:`main`) naming the flag to use instead."""

    def __init__(self, option_strings: Sequence[str], dest: str, instead: str = "-y/--overwrite",
                 **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=False, help=argparse.SUPPRESS)
        self.instead = instead

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        setattr(namespace, self.dest, True)
        notes = list(getattr(namespace, "deprecated_notes", []))
        notes.append(f"{option_string} is deprecated here; use {self.instead}")
        namespace.deprecated_notes = notes


def add_deprecated_flag(p: argparse.ArgumentParser, flag: str, dest: str, instead: str = "-y/--overwrite") -> None:
    p.add_argument(flag, dest=dest, action=DeprecatedFlag, instead=instead)


def note_replacing(args: argparse.Namespace, paths: Iterable[str | os.PathLike]) -> None:
    """Commands that used to replace their outputs silently still do (scripts keep working), but say so
    unless -y/--overwrite asked for it."""
    if getattr(args, "overwrite", False):
        return
    existing = [str(p) for p in paths if os.path.exists(p)]
    if existing:
        more = f" and {plural(len(existing) - 1, 'other')}" if len(existing) > 1 else ""
        say(args, f"note: replacing {existing[0]}{more} (pass -y/--overwrite to say so; a later version "
                  "will refuse without it)")


# --- output paths, checked before any work -------------------------------------------------------------
def check_output_file(flag: str, path: str | os.PathLike, suffix: str, what: str, hint: str = "") -> None:
    """``path`` (given with ``flag``) names a file ``what`` ending in ``suffix``, that is not a folder, in a
    folder that is one (or can be made) and can be written: refused before any work otherwise."""
    text = os.fspath(path)
    if not text.lower().endswith(suffix):
        found = Path(text).suffix
        raise Vt4dError(f"{flag} {text}: {what} ends in {suffix}, not {found or 'no extension'}"
                        + (f"; {hint}" if hint else f" (e.g. {flag} {Path(text).stem or 'out'}{suffix})"))
    if os.path.isdir(text):
        raise Vt4dError(f"{flag} {text} is a folder; give a file name ending in {suffix}")
    check_output_folder(flag, os.path.dirname(os.path.abspath(text)))


def check_output_folder(flag: str, folder: str | os.PathLike) -> None:
    """The folder outputs go to (made when missing) is not a file and, where it exists, can be written."""
    folder = Path(folder)
    for part in (folder, *folder.parents):
        if part.exists():
            if not part.is_dir():
                raise Vt4dError(f"{flag}: {part} is a file, so no folder can be made there")
            if not os.access(part, os.W_OK | os.X_OK):
                raise PermissionError(errno.EACCES, "Permission denied", str(part))
            return


# --- one shape for every command ----------------------------------------------------------------------
def add_command(subparsers: Any, name: str, *, help: str, description: str, examples: Sequence[str],
                notes: str = "", **kwargs: Any) -> argparse.ArgumentParser:
    """Add subcommand ``name`` with a description, an ``examples:`` section and the common output options
    (``--json``, ``-q/--quiet``), so that every command teaches by ``--help`` and speaks one dialect."""
    epilog = (notes.rstrip() + "\n" if notes else "") + "examples:\n" + "\n".join(f"  {e}" for e in examples)
    p = subparsers.add_parser(name, help=help, description=textwrap.fill(description, 100), epilog=epilog,
                              formatter_class=argparse.RawDescriptionHelpFormatter, **kwargs)
    out = p.add_argument_group("output")
    out.add_argument("--json", action="store_true", help="print one JSON document (the result) on stdout")
    out.add_argument("-q", "--quiet", action="store_true",
                     help="print nothing on stdout (except what --json asks for) and show no progress")
    return p


def emit(args: argparse.Namespace, result: Any, lines: Sequence[str] = ()) -> None:
    """Print a command's result: JSON with --json, else the text ``lines`` unless --quiet."""
    if getattr(args, "json", False):
        print(json.dumps(result, indent=2, sort_keys=True, default=str))
    elif not getattr(args, "quiet", False) and lines:
        print("\n".join(lines))


def say(args: argparse.Namespace, line: str) -> None:
    """A progress line for people (stderr), silent with --quiet or --json."""
    if not (getattr(args, "quiet", False) or getattr(args, "json", False)):
        print(line, file=sys.stderr, flush=True)


def show_progress(args: argparse.Namespace) -> bool:
    """Progress bars are drawn on a terminal (stderr), never with --quiet."""
    return not getattr(args, "quiet", False) and sys.stderr.isatty()


def progress(args: argparse.Namespace, iterable: Iterable, total: int | None, desc: str, unit: str) -> Iterable:
    """``iterable`` with a tqdm bar on stderr when :func:`show_progress` (tqdm is optional: the core
    install has none, and then no bar is drawn)."""
    if not show_progress(args):
        return iterable
    try:
        from tqdm import tqdm
    except ImportError:
        return iterable
    return tqdm(iterable, total=total, desc=desc, unit=unit, file=sys.stderr)


@contextlib.contextmanager
def working(args: argparse.Namespace, desc: str, interval: float = 0.5) -> Iterator[None]:
    """Show ``desc`` with a running clock on stderr while the block runs (work with no steps to count,
    e.g. sampling the prior or loading a model); nothing off a terminal or with --quiet."""
    if not show_progress(args):
        yield
        return
    started, done = time.perf_counter(), threading.Event()

    def tick() -> None:
        while not done.wait(interval):
            print(f"\r{desc} ... {time.perf_counter() - started:.0f} s", end="", file=sys.stderr, flush=True)

    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()
        print(f"\r{desc} ... done in {time.perf_counter() - started:.1f} s", file=sys.stderr, flush=True)


# --- where the networks run ----------------------------------------------------------------------------
DEVICE_CHOICES = ("auto", "cpu", "cuda")  # codec.DEVICES (the codec module loads on first use, not here)


def add_device_option(parser: argparse.ArgumentParser, what: str) -> None:
    """``--device cpu|cuda|auto`` for a command that runs ``what``."""
    parser.add_argument("--device", choices=DEVICE_CHOICES, default="cpu",
                        help=f"where {what} runs: cpu (default), cuda (an NVIDIA GPU, through torch or onnxruntime's "
                             "CUDA provider; an error where none is seen) or auto (a GPU where one is seen, else the CPU)")


# --- sources: local paths and fsspec URLs --------------------------------------------------------------
def add_storage_option(parser: argparse.ArgumentParser) -> None:
    """``--storage-option KEY=VALUE`` (repeatable), read back with :func:`storage_options`."""
    parser.add_argument("--storage-option", action="append", metavar="KEY=VALUE",
                        help="fsspec storage option for a URL (repeatable)")


def storage_options(pairs: list[str] | None) -> dict[str, str]:
    """``--storage-option KEY=VALUE`` (repeatable) as fsspec keyword arguments."""
    out = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise FormatError(f"--storage-option wants KEY=VALUE, got {pair!r}")
        out[key] = value
    return out


def read_head(source: str, options: dict[str, str] | None = None, n: int = 16) -> bytes:
    """The first ``n`` bytes of a local file or a URL (to tell a scene from an archive)."""
    with open_binary(source, **(options or {})) as fh:
        return fh.read(n)


# --- the decoded-size budget of reading (FORMAT.md I.7) ------------------------------------------------
# Every command that decodes a stored scene (a .vt4d file or an archive record) takes --max-decoded-bytes,
# the library's max_decoded_bytes: the default is the library's, `none` sets no budget.
BUDGET_FLAG = "--max-decoded-bytes"
BINARY_UNITS = (("TiB", 1 << 40), ("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10))
_BYTE_COUNT = re.compile(r"(\d+)\s*([A-Za-z]*)")


def in_binary_units(n: int) -> str:
    """``n`` bytes in the largest binary unit that divides it: 67108864 -> "64MiB"."""
    return next((f"{n // size}{unit}" for unit, size in BINARY_UNITS if n and n % size == 0), str(n))


def decoded_budget_arg(text: str) -> int | None:
    """An argparse type: ``none`` (no budget) or a byte count, 0 or more as the library's ``max_decoded_bytes``
    allows, with an optional binary suffix (``256MiB``, ``1GiB``); anything else is a usage error (exit code 2)
    that names the flag."""
    if text.strip().lower() == "none":
        return None
    match = _BYTE_COUNT.fullmatch(text.strip())
    units = {unit.lower(): size for unit, size in BINARY_UNITS} | {"": 1, "b": 1}
    if match is None or match.group(2).lower() not in units:
        wrong = "must be 0 or more" if text.strip().startswith("-") else "is not a byte count"
        raise argparse.ArgumentTypeError(f"{text!r} {wrong}: give N bytes, N with a binary suffix KiB, MiB, GiB "
                                         "or TiB (e.g. 256MiB), or none for no budget")
    return int(match.group(1)) * units[match.group(2).lower()]


def add_budget_option(parser: argparse.ArgumentParser) -> None:
    """``--max-decoded-bytes N|none`` (dest ``max_decoded_bytes``), the library's default budget unless given."""
    default = DEFAULT_MAX_DECODED_BYTES
    parser.add_argument(BUDGET_FLAG, dest="max_decoded_bytes", type=decoded_budget_arg, default=default,
                        metavar="N|none",
                        help="the most bytes one scene may decode to (sections, float32 tokens, cameras; FORMAT.md "
                             "I.7): a scene over it is refused before anything is decompressed.  N bytes, with an "
                             "optional binary suffix (256MiB, 1GiB), or none for no budget; raise it for files you "
                             f"trust (default {in_binary_units(default)} = {default:,} bytes)")


_BUDGET_HINT = re.compile(r"pass max_decoded_bytes=(\d+) \(or None\)")
_READER_BUDGET = re.compile(r"the reader's budget of ([\d,]+)")


def budget_message(message: str) -> str:
    """A library message about the decoded-size budget (LimitExceededError) in the words of the command line:
    the budget and the flag that raises it, ``--max-decoded-bytes N (or none)``, for ``max_decoded_bytes=N``."""
    message = _READER_BUDGET.sub(r"the decoded-size budget of \1 bytes", message) if _BUDGET_HINT.search(message) \
        else message
    return _BUDGET_HINT.sub(rf"rerun with {BUDGET_FLAG} \1 (or none)", message)


# --- errors in the words of the command line -----------------------------------------------------------
# The library's messages name the Python keyword that fixes a problem; on the command line the fix is a
# flag.  KEYWORD_FLAGS maps each such keyword hint to its flag (tests/cli/test_errors.py checks that every
# hint in the library's messages is listed here).
KEYWORD_FLAGS: dict[str, str] = {
    "replace=True": "--overwrite",
    "overwrite=True": "--overwrite",
    "force=True": "--force",
    "allow_truncated=True": "--allow-truncated",
    "scale_intrinsics=True": "--scale-intrinsics",
    "units='m'": "--units m",
    "units='mm'": "--units mm",
    "capture=DIR": "--capture DIR",
    "model=<path to the model directory>": "--model PATH",
    "on_uncommitted='recover'": "--recover",
    "on_uncommitted='discard'": "--discard-uncommitted",
    "runtime='torch'": "--runtime torch",
    "runtime='onnx'": "--runtime onnx",
    "device='cpu'": "--device cpu",
    "device='cuda'": "--device cuda",
    "device='auto'": "--device auto",
}
_HINT = re.compile("|".join(re.escape(k) for k in sorted(KEYWORD_FLAGS, key=len, reverse=True)))
_ALREADY = re.compile(r" \((?:CLI: )?--[a-z][a-z-]*\)")  # "force=True (--force)": the flag is named already


def cli_message(message: str, flags: set[str]) -> str:
    """``message`` with every keyword hint replaced by its flag (``max_decoded_bytes=N`` by
    :func:`budget_message`).  A parenthesised hint whose flag the command lacks is an API-only alternative and
    is dropped; any other one stays as it is."""

    def flag_of(hint: str) -> str | None:
        flag = KEYWORD_FLAGS[hint]
        return flag if flag.split()[0] in flags else None

    def drop_api_only(m: re.Match) -> str:
        hints = _HINT.findall(m.group(0))
        return "" if hints and all(flag_of(h) is None for h in hints) else m.group(0)

    if BUDGET_FLAG in flags:
        message = budget_message(message)
    message = re.sub(r" \([^()]*\)", drop_api_only, message)
    message = re.sub("(" + _HINT.pattern + ")" + _ALREADY.pattern, lambda m: m.group(1), message)
    return _HINT.sub(lambda m: flag_of(m.group(0)) or m.group(0), message)


def _command_flags(parser: argparse.ArgumentParser, command: str | None) -> set[str]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and command in action.choices:
            return {s for a in action.choices[command]._actions for s in a.option_strings}
    return set()


class Parser(argparse.ArgumentParser):
    """argparse, with a usage error said in one line first (the usage itself is `--help`'s)."""

    def error(self, message: str) -> NoReturn:  # type: ignore[override]
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n(`{self.prog} --help` lists the options)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="vt4d",
        description=(
            "vt4dcodec: compress multi-camera captures into small .vt4d token files, keep them in "
            "archives, and render any camera view back.  Run `vt4d COMMAND --help` for each command."
        ),
        epilog="Exit codes: 0 ok, 1 invalid input or failed verification, 2 usage, 3 file system error "
               "(a missing input, a folder that cannot be written), 130 interrupted.",
    )

    parser.add_argument("--version", action="version", version=f"vt4dcodec {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")  # subcommands are Parsers too
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


# The inputs (argument dests) of each command that must exist, checked before any work: a missing one is a
# file system error (exit 3) on every command.  URLs are left to the command.
INPUTS: dict[str, tuple[str, ...]] = {
    "info": ("file",), "encode": ("captures",), "decode": ("source", "capture"), "pack": ("files",),
    "ls": ("archive",), "extract": ("archive",), "repair": ("archive",), "compact": ("archive",),
    "import": ("calibration", "media_dir"), "capture-info": ("directory",), "contact-sheet": ("directory",),
    "generate": ("capture",),
}
_URL = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*://")


def _missing_input(args: argparse.Namespace) -> str | None:
    for dest in INPUTS.get(args.command, ()):
        values = getattr(args, dest, None)
        for value in values if isinstance(values, list) else [values]:
            if value is None or _URL.match(str(value)):
                continue
            path = str(value).split("::", 1)[0] if dest == "source" else str(value)
            if not os.path.exists(path):
                if args.command in ARCHIVE_COMMANDS:
                    return f"{path}: no such archive (no file at that path)"
                return f"{path}: no such file or directory"
    return None


def _url_reason(exc: OSError) -> str:
    """Why a URL could not be read, in words (fsspec raises FileNotFoundError(url) from the HTTP client's error)."""
    cause = exc.__cause__ or exc.__context__
    status = getattr(cause, "status", None)
    if isinstance(status, int):
        return f"the server answered {status} {getattr(cause, 'message', '') or ''}".rstrip()
    host = getattr(cause, "host", None)
    if host is not None:
        os_error = getattr(cause, "os_error", None)
        code = getattr(os_error, "errno", None)
        reason = os.strerror(code) if isinstance(code, int) else "connection failed"
        return f"cannot connect to {host}:{getattr(cause, 'port', '')} ({reason.lower()})"
    if cause is not None and str(cause):
        return str(cause)
    return "no such file there" if isinstance(exc, FileNotFoundError) else "it cannot be read"


ARCHIVE_COMMANDS = ("ls", "extract", "repair", "compact")


def _wrong_kind(args: argparse.Namespace) -> str | None:
    """An archive command given a single scene file: say what it is and what to run instead."""
    path = getattr(args, "archive", None) if args.command in ARCHIVE_COMMANDS else None
    if path is None or _URL.match(str(path)) or not os.path.isfile(path):
        return None
    with open(path, "rb") as fh:
        if not fh.read(len(SCENE_MAGIC)).startswith(SCENE_MAGIC[:5]):
            return None
    return (f"{path} is a single .vt4d scene, not an archive (.vt4da): `vt4d info {path}` shows it, "
            f"`vt4d pack {path} -o NAME.vt4da` puts it in an archive")


def os_error_message(exc: OSError) -> str:
    """An OSError in words: the path and what is wrong with it, without ``[Errno N]``; a writer's lock file
    is named as the archive's folder it lives in."""
    if exc.errno is None or exc.strerror is None:
        url = str(exc.args[0]) if exc.args else ""
        return f"cannot read {url}: {_url_reason(exc)}" if _URL.match(url) else str(exc)
    path = exc.filename
    what = {errno.ENOENT: "no such file or directory", errno.EACCES: "permission denied",
            errno.EPERM: "operation not permitted", errno.EEXIST: "already exists (pass -y/--overwrite to replace it)",
            errno.EISDIR: "is a folder, not a file", errno.ENOTDIR: "a part of this path is a file, not a folder",
            errno.ENOSPC: "no space left on the device", errno.EROFS: "the file system is read-only"
            }.get(exc.errno, exc.strerror[:1].lower() + exc.strerror[1:])
    if path is None:
        return what
    path = os.fspath(path)
    if isinstance(path, bytes):
        path = path.decode(errors="replace")
    folder = os.path.dirname(path) or "."
    if path.endswith(".lock") and exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOENT):
        if exc.errno == errno.ENOENT:
            return f"cannot write {path[:-5]}: folder {folder} does not exist"
        return (f"cannot write {path[:-5]}: {what} in folder {folder} (a writer keeps a lock file beside the "
                "archive)")
    temporary = re.search(r"\.(?:tmp|compact)-\d+$", path)  # the file a command writes, then renames
    if temporary and exc.errno == errno.ENOENT:
        return f"cannot write {path[:temporary.start()]}: folder {folder} does not exist"
    if temporary:
        return f"cannot write {path[:temporary.start()]}: {what}"
    return f"{path}: {what}"


_SCENE_MAGIC_TEXT = re.compile(r"the file starts with b(['\"]).*?(?<!\\)\1, expected b(['\"]).*?(?<!\\)\2")
_SIGNATURE_TEXT = re.compile(r" \(signature b(['\"]).*?(?<!\\)\1\)")


def in_words(message: str) -> str:
    """A library message without magic bytes: what the file is not, in words."""
    message = _SCENE_MAGIC_TEXT.sub("it does not start with the .vt4d signature", message)
    message = _SIGNATURE_TEXT.sub("", message)
    return message.replace("not a vt4d archive (bad magic; expected \\x89V4A\\r\\n\\x1a\\n)",
                           "not a .vt4da archive (it does not start with the archive signature)")


def _first_input(args: argparse.Namespace) -> str | None:
    dests = INPUTS.get(args.command, ())
    values = getattr(args, dests[0], None) if dests else None
    if isinstance(values, list):
        return values[0] if len(values) == 1 else None
    return values


def _unknown_options(parser: argparse.ArgumentParser, command: str | None, extra: list[str]) -> NoReturn:
    """Unrecognized arguments, said by the command they were given to, with the nearest option it has."""
    sub = next((a.choices[command] for a in parser._actions
                if isinstance(a, argparse._SubParsersAction) and command in a.choices), parser)
    known = [s for a in sub._actions if a.help != argparse.SUPPRESS for s in a.option_strings]
    near = difflib.get_close_matches(extra[0].split("=")[0], known, n=1) if extra[0].startswith("-") else []
    sub.error(f"unrecognized arguments: {' '.join(extra)}" + (f" (did you mean {near[0]}?)" if near else ""))


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:
        _unknown_options(parser, getattr(args, "command", None), extra)
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_USAGE
    for note in getattr(args, "deprecated_notes", []):
        say(args, f"vt4d {args.command}: note: {note}")
    missing = _missing_input(args)
    if missing is not None:
        print(f"vt4d {args.command}: error: {missing}", file=sys.stderr)
        return EXIT_OS
    wrong = _wrong_kind(args)
    if wrong is not None:
        print(f"vt4d {args.command}: error: {wrong}", file=sys.stderr)
        return EXIT_INVALID
    try:
        return int(args.func(args) or 0)
    except Vt4dError as exc:
        message = in_words(cli_message(str(exc), _command_flags(parser, args.command)))
        source = _first_input(args)
        if isinstance(exc, BadMagicError) and source and not message.startswith(str(source)):
            message = f"{source}: {message}"
        print(f"vt4d {args.command}: error: {message}", file=sys.stderr)
        return EXIT_INVALID
    except OSError as exc:
        print(f"vt4d {args.command}: error: {os_error_message(exc)}", file=sys.stderr)
        return EXIT_OS
    except ModuleNotFoundError as exc:  # a command of the codec on the core install
        extra = EXTRA_OF_MODULE.get((exc.name or "").split(".")[0])
        if extra is None:
            raise
        print(f"vt4d {args.command}: error: this command needs {exc.name}, which the core install leaves out: "
              f'pip install "vt4dcodec[{extra}]" (from a clone: pip install -e ".[{extra}]")', file=sys.stderr)
        return EXIT_INVALID
    except KeyboardInterrupt:
        print(f"vt4d {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
