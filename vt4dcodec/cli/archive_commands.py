"""``vt4d pack``, ``vt4d ls``, ``vt4d extract``, ``vt4d repair``: multi-scene archives.

(``vt4d verify`` on an archive lives with the container commands and calls
:func:`vt4dcodec.archive.verify_archive`.)  Nothing here imports torch.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
import threading
from typing import Any, Iterator

from ..archive import ArchiveWriter, check_key, compact_archive, open_archive, repair_archive
from ..errors import ArchiveError, FormatError
from . import (EXIT_INTERRUPTED, add_budget_option, add_command, add_deprecated_flag, add_overwrite_option, add_storage_option,
               check_output_file, check_output_folder, emit, plural, positive_int, progress, storage_options,
               working)

__all__ = ["register"]


def _strip_vt4d(name: str) -> str:
    return name[: -len(".vt4d")] if name.endswith(".vt4d") else name


def _scene_files(inputs: list[str]) -> list[tuple[str, str]]:
    """(key, path) of every input: a file's key is its name without .vt4d; a directory is walked and each
    .vt4d file below it gets its path relative to the directory, '/'-separated, as key -- the inverse of
    ``vt4d extract``, which writes key a/b/c as a/b/c.vt4d."""
    pairs: list[tuple[str, str]] = []
    for item in inputs:
        if os.path.isdir(item):
            found = []
            for root, dirs, names in os.walk(item):
                dirs.sort()
                found += [os.path.join(root, n) for n in names if n.endswith(".vt4d")]
            for path in sorted(found):
                rel = os.path.relpath(path, item).replace(os.sep, "/")
                pairs.append((_strip_vt4d(rel), path))
        else:
            pairs.append((_strip_vt4d(os.path.basename(item)), item))
    return pairs


@contextlib.contextmanager
def _interruptible(caught: list[int]) -> Iterator[None]:
    """While the block runs, SIGTERM raises KeyboardInterrupt as Ctrl-C (SIGINT) does, so an ArchiveWriter
    leaving the block commits every scene whose append returned; the signal's number goes to ``caught``.
    A signal the parent set to be ignored stays ignored; off the main thread nothing changes."""
    def interrupt(signum: int, frame: Any) -> None:
        caught.append(signum)
        raise KeyboardInterrupt(signal.Signals(signum).name)

    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(sig) in (signal.default_int_handler, signal.SIG_DFL):
                previous[sig] = signal.signal(sig, interrupt)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def cmd_pack(args: argparse.Namespace) -> int:
    check_output_file("-o", args.output, ".vt4da", "an archive",
                      "a .vt4d file holds one scene" if args.output.lower().endswith(".vt4d") else "")
    pairs = _scene_files(args.files)
    if not pairs:
        raise ArchiveError(f"no .vt4d files to pack in {', '.join(args.files)} (directories are searched recursively)")
    seen: dict[str, str] = {}
    for key, path in pairs:
        check_key(key)  # every key checked before the archive is touched
        if key in seen:
            raise ArchiveError(f"two inputs map to key {key!r}: {seen[key]} and {path}")
        seen[key] = path
    mode = "a" if args.append else "x"
    if (args.force or args.overwrite) and not args.append:
        mode = "w"
    replace = args.replace or (args.overwrite and args.append)
    if mode == "x" and os.path.exists(args.output):
        raise FileExistsError(f"{args.output} exists: pass -y/--overwrite to replace it, or --append to add to it")
    policy = "recover" if args.recover else "discard" if args.discard_uncommitted else "error"
    os.makedirs(os.path.dirname(os.path.abspath(args.output)), exist_ok=True)  # as encode --archive: made
    writer, finished = None, 0
    caught: list[int] = []
    try:
        # Ctrl-C or SIGTERM: the writer commits every scene packed so far as it leaves the block
        with _interruptible(caught), ArchiveWriter(args.output, mode, on_uncommitted=policy) as writer:
            try:
                for n, (key, path) in enumerate(progress(args, pairs, len(pairs), "pack", "scene"), 1):
                    with open(path, "rb") as f:
                        data = f.read()
                    try:  # every scene is verified as it goes in, within the decoded-size budget
                        writer.append(key, data, replace=replace, max_decoded_bytes=args.max_decoded_bytes)
                    except ArchiveError:
                        raise
                    except FormatError as exc:  # the container's error: name the file, keep the class
                        raise type(exc)(f"{path}: {exc}") from exc
                    finished = n
                    if args.commit_every and n % args.commit_every == 0:
                        writer.commit()
                writer.commit()
            except KeyboardInterrupt:  # it may have come after the append returned, before ``finished`` counted it
                finished += finished < len(pairs) and pairs[finished][0] in writer.pending_keys
                raise
            total, generation = len(writer), writer.generation
    except KeyboardInterrupt:
        name = signal.Signals(caught[0]).name if caught else "SIGINT"
        if writer is None or not finished:
            print(f"vt4d pack: interrupted ({name}) before any scene was packed", file=sys.stderr)
        else:
            print(f"vt4d pack: interrupted ({name}): {args.output} keeps the {plural(finished, 'scene')} packed "
                  f"before it, committed ({plural(len(writer), 'scene')} in the archive, generation "
                  f"{writer.generation}); {plural(len(pairs) - finished, 'input')} not packed: run the command again "
                  "with --append -y to pack them (replacing the scenes packed already)", file=sys.stderr)
        return EXIT_INTERRUPTED if not caught or caught[0] == signal.SIGINT else 128 + caught[0]
    emit(args, {"archive": args.output, "packed": [k for k, _ in pairs], "scenes": total, "generation": generation},
         [f"{args.output}: packed {plural(len(pairs), 'scene')} ({total} in the archive, generation {generation})"])
    return 0


def _ls_row(key: str, s: dict[str, Any]) -> list[str]:
    fp = s.get("fingerprint") or {}
    shape = lambda v: "x".join(str(x) for x in v) if isinstance(v, list) else "-"  # noqa: E731
    model = f"{fp.get('model_id', '-')}@{fp.get('model_version', '-')}" if fp else "-"
    return [key, str(s.get("frames", "-")), shape(s.get("static_shape")), shape(s.get("dynamic_shape")),
            str(s.get("encoding", "-")), model, str(s.get("bytes", "-"))]


def cmd_ls(args: argparse.Namespace) -> int:
    with open_archive(args.archive, allow_truncated=args.allow_truncated,
                      **storage_options(args.storage_option)) as reader:
        rows = [(e.key, reader.entry_summary(e), e.length, e.offset) for e in reader.entries()]
        info = {"archive": reader.name, "generation": reader.generation, "scenes": len(reader),
                "uncommitted_bytes": reader.uncommitted_bytes}
    if args.json:
        info["entries"] = [{"key": k, "offset": off, "length": n, "summary": s} for k, s, n, off in rows]
        json.dump(info, sys.stdout, indent=1)
        print()
        return 0
    if args.quiet:
        return 0
    table = [["KEY", "FRAMES", "Z_s", "Z_d", "ENCODING", "MODEL", "BYTES"]]
    table += [_ls_row(k, {**s, "bytes": s.get("bytes", n)}) for k, s, n, _ in rows]
    widths = [max(len(r[i]) for r in table) for i in range(len(table[0]))]
    for r in table:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
    tail = f" ({info['uncommitted_bytes']} uncommitted bytes: run `vt4d repair`)" if info["uncommitted_bytes"] else ""
    print(f"{plural(info['scenes'], 'scene')}, generation {info['generation']}{tail}")
    return 0


def cmd_extract(args: argparse.Namespace) -> int:
    with open_archive(args.archive, allow_truncated=args.allow_truncated,
                      **storage_options(args.storage_option)) as reader:
        keys = args.keys or reader.keys()
        entries = [reader.entry(k) for k in keys]  # SceneNotFoundError before anything is written
        targets = [os.path.join(args.output, *e.key.split("/")) + ".vt4d" for e in entries]
        if os.path.isfile(args.output):
            raise ArchiveError(f"-o {args.output} is a file; give the folder the scenes go to")
        check_output_folder("-o", args.output)
        if not (args.force or args.overwrite):
            clash = [t for t in targets if os.path.exists(t)]
            if clash:
                raise FileExistsError(f"{clash[0]} exists (pass -y/--overwrite to replace it)")
        for entry, target in progress(args, list(zip(entries, targets)), len(entries), "extract", "scene"):
            os.makedirs(os.path.dirname(target), exist_ok=True)
            data = reader.read_entry(entry)
            tmp = f"{target}.tmp-{os.getpid()}"
            with open(tmp, "wb") as f:
                f.write(data)
            if os.path.exists(target):  # a file written over keeps its permission bits
                os.chmod(tmp, os.stat(target).st_mode & 0o7777)
            os.replace(tmp, target)
    emit(args, {"output": args.output, "files": [{"key": e.key, "path": t} for e, t in zip(entries, targets)]},
         [f"extracted {plural(len(entries), 'scene')} to {args.output} (key a/b/c -> a/b/c.vt4d; `vt4d pack "
          f"{args.output} -o NEW.vt4da` packs them back under the same keys)"])
    return 0


def cmd_repair(args: argparse.Namespace) -> int:
    with working(args, f"repairing {args.archive}"):  # no steps to count: a running clock on a terminal
        report = repair_archive(args.archive, full_scan=args.full_scan, dry_run=args.dry_run)
    status = 0 if report.complete else 1  # 0 only when nothing committed was lost
    if args.json:
        json.dump(report.to_dict(), sys.stdout, indent=1)
        print()
        return status
    if args.quiet:
        _repair_errors(args, report)
        return status
    if report.last_generation is None:
        start = "no commit verifies; a full scan of the record frames"
    else:
        start = f"generation {report.last_generation} ({plural(report.committed, 'scene')}), every record checked"
    recover, cut, copy = ("would recover", "would cut", "would copy") if args.dry_run else ("recovered", "cut", "copied")
    lines = [f"{args.archive}: full scan: {report.scan_reason}"] if report.scan_reason else []
    lines.append(f"{args.archive}: from {start}: {recover} {plural(len(report.recovered), 'scene')} written after it"
                 f"{' (' + ', '.join(report.recovered) + ')' if report.recovered else ''}, {cut} "
                 f"{plural(report.discarded_bytes, 'torn byte')} after the last valid record")
    if report.damaged_bytes:
        lines.append(f"skipped {plural(report.damaged_bytes, 'damaged byte')} between valid records (left in place)")
    if report.copied:
        lines.append(f"{copy} {plural(len(report.copied), 'record')} whose frame header is damaged but whose "
                     f"payload verifies into fresh frames: {', '.join(report.copied)}")
    if report.reindexed:
        lines.append(f"{'would re-index' if args.dry_run else 're-indexed'} {plural(len(report.reindexed), 'record')} "
                     f"whose index entry pointed at other bytes: {', '.join(report.reindexed)}")
    if report.lost_generation is not None:
        lines.append(f"the newest commit, generation {report.lost_generation} "
                     f"({plural(report.lost_scenes or 0, 'scene')}), was cut off the end of the file or damaged; its "
                     "records still in the file are kept")
    if report.rewritten:
        lines.append(f"the generation counter is spent: the repaired archive {'would be' if args.dry_run else 'was'} "
                     "written as a new file, from generation 1")
    if report.new_generation is not None:
        lines.append(f"committed generation {report.new_generation} ({plural(report.scenes, 'scene')})")
    elif args.dry_run:
        lines.append(f"dry run: nothing written; the repaired archive would hold {plural(report.scenes, 'scene')}")
    else:
        lines.append("nothing to repair")
    print("\n".join(lines))
    _repair_errors(args, report)
    return status


def _repair_errors(args: argparse.Namespace, report: Any) -> None:
    verb = "would lose" if args.dry_run else "lost"
    if report.lost:
        print(f"{args.archive}: error: {plural(len(report.lost), 'committed scene')} could not be recovered (record "
              f"damaged or missing; the repair {verb} {'it' if len(report.lost) == 1 else 'them'}): "
              f"{', '.join(report.lost)}", file=sys.stderr)
    if report.lost_unnamed:
        more = "more " if report.lost else ""
        print(f"{args.archive}: error: {plural(report.lost_unnamed, more + 'committed scene')} could not be recovered "
              "and cannot be named (the index that listed them is damaged or cut off)", file=sys.stderr)
    if report.uncertain and report.scenes:
        print(f"{args.archive}: error: commit generation {report.lost_generation} lost its index and records written "
              "for it are damaged or cut off: a scene kept may be in an older version than the one it committed",
              file=sys.stderr)
    elif report.uncertain and not report.lost_unnamed:
        print(f"{args.archive}: error: commit generation {report.lost_generation} lost its index and the records "
              "written for it", file=sys.stderr)


def cmd_compact(args: argparse.Namespace) -> int:
    major, _, minor = args.format_version.partition(".")
    with working(args, f"compacting {args.archive}"):
        report = compact_archive(args.archive, version=(int(major), int(minor or 0)))
    emit(args, report.to_dict(),
         [f"{args.archive}: {plural(report.scenes, 'scene')}, {report.bytes_before} -> {report.bytes_after} bytes, "
          f"generation {report.generation}, format {report.version[0]}.{report.version[1]}"])
    return 0


TRUNC_HELP = ("read the last intact commit of an archive whose newest commit was cut off the end "
              "(truncated file); without it such an archive is an error")


def register(subparsers: Any) -> None:
    p = add_command(subparsers, "pack", help="pack .vt4d files into an archive (.vt4da)",
                    description="Pack .vt4d scene files (or directories of them, searched recursively) into an "
                    "archive.  A file's key is its name without .vt4d; below a directory, its path relative to "
                    "that directory (a/b/c.vt4d -> key a/b/c), so `vt4d extract` output packs back unchanged.  "
                    "Ctrl-C or SIGTERM commits the scenes packed so far and exits 130 or 143 (the same command "
                    "with --append -y then packs the rest).",
                    examples=["vt4d pack scenes/ -o scenes.vt4da",
                              "vt4d extract old.vt4da -o out/ && vt4d pack out/ -o new.vt4da    same keys",
                              "vt4d pack more/*.vt4d -o scenes.vt4da --append -y    replacing scenes of the same key",
                              "vt4d pack scenes/ -o scenes.vt4da -y                 replace the archive"])
    p.add_argument("files", nargs="+", help=".vt4d files or directories")
    p.add_argument("-o", "--output", required=True, help="archive path (.vt4da); its folder is created")
    p.add_argument("--append", action="store_true", help="add to an existing archive")
    add_overwrite_option(p, "replace an existing archive; with --append, replace the scenes whose key is there")
    add_deprecated_flag(p, "--force", "force")      # earlier spellings: replace the archive,
    add_deprecated_flag(p, "--replace", "replace")  # and replace scenes whose key exists
    uncommitted = p.add_mutually_exclusive_group()
    uncommitted.add_argument("--recover", action="store_true",
                             help="first keep the complete records a crashed writer left after the last commit")
    uncommitted.add_argument("--discard-uncommitted", action="store_true",
                             help="first drop the bytes a crashed writer left after the last commit")
    p.add_argument("--commit-every", type=positive_int, default=0, metavar="N", help="commit after every N scenes")
    add_budget_option(p)
    p.set_defaults(func=cmd_pack)

    p = add_command(subparsers, "ls", help="list the scenes of an archive",
                    description="List an archive's committed scenes: key, frames, token shapes, encoding, model "
                    "and size.  Reads the footer and index only (local path or fsspec URL).",
                    examples=["vt4d ls scenes.vt4da",
                              "vt4d ls https://example.org/scenes.vt4da --json",
                              "vt4d ls s3://bucket/scenes.vt4da --storage-option anon=true"])
    p.add_argument("archive", help="archive path or fsspec URL")
    add_storage_option(p)
    p.add_argument("--allow-truncated", action="store_true", help=TRUNC_HELP)
    p.set_defaults(func=cmd_ls)

    p = add_command(subparsers, "extract", help="extract scenes from an archive as standalone .vt4d files",
                    description="Write scenes of an archive as standalone .vt4d files: key a/b/c becomes "
                    "OUTPUT/a/b/c.vt4d.  Every key is checked, and no file overwritten without -y/--overwrite, before "
                    "anything is written.",
                    examples=["vt4d extract scenes.vt4da -o out/                 every scene",
                              "vt4d extract scenes.vt4da cap-3/cam00/000000 -o out/",
                              "vt4d extract https://example.org/scenes.vt4da -o out/ --json"])
    p.add_argument("archive", help="archive path or fsspec URL")
    p.add_argument("keys", nargs="*", help="scene keys (default: all)")
    p.add_argument("-o", "--output", default=".", help="output directory (default: .)")
    add_overwrite_option(p, "replace files that exist")
    add_deprecated_flag(p, "--force", "force")
    add_storage_option(p)
    p.add_argument("--allow-truncated", action="store_true", help=TRUNC_HELP)
    p.set_defaults(func=cmd_extract)

    p = add_command(subparsers, "repair", help="recover an archive after a crashed writer or damage",
                    description="Check every record of the last commit, add complete checksum-valid records "
                    "written after it (skipping damaged bytes), cut off torn bytes after the last valid record, "
                    "and commit.  A truncated archive, one without a usable commit, or one whose committed "
                    "records fail their checks gets a full scan.  Never drops a record that verifies; exits 0 "
                    "only when nothing committed was lost, 1 otherwise, naming every lost scene.",
                    examples=["vt4d repair scenes.vt4da --dry-run     print the plan, write nothing",
                              "vt4d repair scenes.vt4da --full-scan   walk the whole file whatever the last commit",
                              "vt4d repair scenes.vt4da --json        the lost keys under \"lost\""])
    p.add_argument("archive", help="local archive path")
    p.add_argument("--full-scan", action="store_true",
                   help="walk the whole file even when the last commit and its records verify: the newest commit "
                   "whose index verifies is the base, and records anywhere after it are recovered")
    p.add_argument("--dry-run", action="store_true", help="print the plan; change nothing")
    p.set_defaults(func=cmd_repair)

    p = add_command(subparsers, "compact", help="rewrite an archive with only its live records (atomic)",
                    description="Copy every live record (CRC-checked) into a new file with one index, "
                    "then rename it over the archive: replaced records and old indexes are reclaimed. "
                    "Holds the writer lock; readers see the old or the new file, never a mix.",
                    examples=["vt4d compact scenes.vt4da",
                              "vt4d compact scenes.vt4da --format-version 1.0   readable by 1.0 readers"])
    p.add_argument("archive", help="local archive path")
    p.add_argument("--format-version", default="1.2", choices=["1.0", "1.1", "1.2"],
                   help="1.2 (default: light commits, compressed segments), 1.1 (segmented indexes, readable by "
                   "1.1 readers) or 1.0 (readable by 1.0 readers)")
    p.set_defaults(func=cmd_compact)
