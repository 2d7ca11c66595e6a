"""``vt4d pack``, ``vt4d ls``, ``vt4d extract``, ``vt4d repair``: multi-scene archives.

(``vt4d verify`` on an archive lives with the container commands and calls
:func:`vt4dcodec.archive.verify_archive`.)  Nothing here imports torch.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any, Iterable

from ..errors import ArchiveError

__all__ = ["register"]


def _progress(iterable: Iterable, total: int, desc: str, quiet: bool) -> Iterable:
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, unit="scene", disable=quiet or not sys.stderr.isatty(),
                file=sys.stderr)


def _storage_options(pairs: list[str] | None) -> dict[str, str]:
    out = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise ArchiveError(f"--storage-option wants KEY=VALUE, got {pair!r}")
        out[key] = value
    return out


def _scene_files(inputs: list[str]) -> list[str]:
    files: list[str] = []
    for item in inputs:
        if os.path.isdir(item):
            files.extend(sorted(os.path.join(item, n) for n in os.listdir(item) if n.endswith(".vt4d")))
        else:
            files.append(item)
    return files


def _key_for(path: str) -> str:
    name = os.path.basename(path)
    return name[: -len(".vt4d")] if name.endswith(".vt4d") else name


def cmd_pack(args: argparse.Namespace) -> int:
    from ..archive import ArchiveWriter

    files = _scene_files(args.files)
    if not files:
        raise ArchiveError("no .vt4d files to pack")
    keys = [_key_for(f) for f in files]
    seen: dict[str, str] = {}
    for key, path in zip(keys, files):
        if key in seen:
            raise ArchiveError(f"two inputs map to key {key!r}: {seen[key]} and {path}")
        seen[key] = path
    mode = "a" if args.append else "x"
    if args.force and not args.append:
        mode = "w"
    policy = "recover" if args.recover else "error"
    with ArchiveWriter(args.output, mode, on_uncommitted=policy) as writer:
        for n, (key, path) in enumerate(_progress(zip(keys, files), len(files), "pack", args.quiet), 1):
            with open(path, "rb") as f:
                writer.append(key, f.read(), replace=args.replace)
            if args.commit_every and n % args.commit_every == 0:
                writer.commit()
        writer.commit()
        total, generation = len(writer), writer.generation
    if not args.quiet:
        print(f"{args.output}: packed {len(files)} scenes ({total} in archive, generation {generation})")
    return 0


def _ls_row(key: str, s: dict[str, Any]) -> list[str]:
    fp = s.get("fingerprint") or {}
    shape = lambda v: "x".join(str(x) for x in v) if isinstance(v, list) else "-"  # noqa: E731
    model = f"{fp.get('model_id', '-')}@{fp.get('model_version', '-')}" if fp else "-"
    return [key, str(s.get("frames", "-")), shape(s.get("static_shape")), shape(s.get("dynamic_shape")),
            str(s.get("encoding", "-")), model, str(s.get("bytes", "-"))]


def cmd_ls(args: argparse.Namespace) -> int:
    from ..archive import open_archive

    with open_archive(args.archive, allow_truncated=args.allow_truncated,
                      **_storage_options(args.storage_option)) as reader:
        rows = [(e.key, e.summary, e.length, e.offset) for e in reader.entries()]
        info = {"archive": reader.name, "generation": reader.generation, "scenes": len(reader),
                "uncommitted_bytes": reader.uncommitted_bytes}
    if args.json:
        info["entries"] = [{"key": k, "offset": off, "length": n, "summary": s} for k, s, n, off in rows]
        json.dump(info, sys.stdout, indent=1)
        print()
        return 0
    table = [["KEY", "FRAMES", "Z_s", "Z_d", "ENCODING", "MODEL", "BYTES"]]
    table += [_ls_row(k, {**s, "bytes": s.get("bytes", n)}) for k, s, n, _ in rows]
    widths = [max(len(r[i]) for r in table) for i in range(len(table[0]))]
    for r in table:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
    tail = f" ({info['uncommitted_bytes']} uncommitted bytes: run `vt4d repair`)" if info["uncommitted_bytes"] else ""
    print(f"{info['scenes']} scenes, generation {info['generation']}{tail}")
    return 0


def cmd_extract(args: argparse.Namespace) -> int:
    from ..archive import open_archive

    with open_archive(args.archive, allow_truncated=args.allow_truncated,
                      **_storage_options(args.storage_option)) as reader:
        keys = args.keys or reader.keys()
        entries = [reader.entry(k) for k in keys]  # SceneNotFoundError before anything is written
        targets = [os.path.join(args.output, *e.key.split("/")) + ".vt4d" for e in entries]
        if not args.force:
            clash = [t for t in targets if os.path.exists(t)]
            if clash:
                raise FileExistsError(f"{clash[0]} exists (use --force to overwrite)")
        for entry, target in _progress(zip(entries, targets), len(entries), "extract", args.quiet):
            os.makedirs(os.path.dirname(target), exist_ok=True)
            data = reader.read_entry(entry)
            tmp = f"{target}.tmp-{os.getpid()}"
            with open(tmp, "wb") as f:
                f.write(data)
            os.replace(tmp, target)
    if not args.quiet:
        print(f"extracted {len(entries)} scenes to {args.output}")
    return 0


def cmd_repair(args: argparse.Namespace) -> int:
    from ..archive import repair_archive

    report = repair_archive(args.archive, full_scan=args.full_scan, dry_run=args.dry_run)
    status = 0 if report.complete else 1  # never report success when committed scenes were lost
    if args.json:
        json.dump(report.to_dict(), sys.stdout, indent=1)
        print()
        return status
    if report.last_generation is None:
        start = "no commit verifies; a full scan of the record frames"
    else:
        start = f"generation {report.last_generation} ({report.committed} scenes)"
        if report.full_scan:
            start += ", every record checked"
    recover, cut, copy = ("would recover", "would cut", "would copy") if args.dry_run else ("recovered", "cut", "copied")
    lines = [f"{args.archive}: from {start}: {recover} {len(report.recovered)} scenes written after it"
             f"{' (' + ', '.join(report.recovered) + ')' if report.recovered else ''}, {cut} "
             f"{report.discarded_bytes} torn bytes after the last valid record"]
    if report.damaged_bytes:
        lines.append(f"skipped {report.damaged_bytes} damaged bytes between valid records (left in place)")
    if report.copied:
        lines.append(f"{copy} {len(report.copied)} records whose frame header is damaged but whose "
                     f"payload verifies into fresh frames: {', '.join(report.copied)}")
    if report.lost_generation is not None:
        lines.append(f"the file was truncated: commit generation {report.lost_generation} "
                     f"({report.lost_scenes} scenes) was cut off its end; its records still in the file are kept")
    if report.new_generation is not None:
        lines.append(f"committed generation {report.new_generation} ({report.scenes} scenes)")
    elif args.dry_run:
        lines.append(f"dry run: nothing written; the repaired archive would hold {report.scenes} scenes")
    else:
        lines.append("nothing to repair")
    print("\n".join(lines))
    if report.unrecoverable:
        print(f"{args.archive}: error: {len(report.unrecoverable)} committed scenes could not be recovered "
              f"(their records fail their checksum): {', '.join(report.unrecoverable)}", file=sys.stderr)
    elif not report.complete:
        print(f"{args.archive}: error: the truncated commit held {report.lost_scenes} scenes, "
              f"{report.scenes} could be recovered", file=sys.stderr)
    return status


def cmd_compact(args: argparse.Namespace) -> int:
    from ..archive import compact_archive

    major, _, minor = args.format_version.partition(".")
    report = compact_archive(args.archive, version=(int(major), int(minor or 0)))
    if args.json:
        json.dump(report.to_dict(), sys.stdout, indent=1)
        print()
    else:
        print(f"{args.archive}: {report.scenes} scenes, {report.bytes_before} -> {report.bytes_after} bytes, "
              f"generation {report.generation}, format {report.version[0]}.{report.version[1]}")
    return 0


TRUNC_HELP = ("read the last intact commit of an archive whose newest commit was cut off the end "
              "(truncated file); without it such an archive is an error")


def register(subparsers: Any) -> None:
    so = dict(action="append", metavar="KEY=VALUE", help="fsspec storage option (repeatable)")

    p = subparsers.add_parser("pack", help="pack .vt4d files into an archive (.vt4da)",
                              description="Pack .vt4d scene files (or directories of them) into an archive; "
                              "each scene's key is its file name without .vt4d.")
    p.add_argument("files", nargs="+", help=".vt4d files or directories")
    p.add_argument("-o", "--output", required=True, help="archive path (.vt4da)")
    p.add_argument("--append", action="store_true", help="add to an existing archive")
    p.add_argument("--force", action="store_true", help="replace an existing archive")
    p.add_argument("--replace", action="store_true", help="replace scenes whose key exists")
    p.add_argument("--recover", action="store_true", help="first recover records a crashed writer left")
    p.add_argument("--commit-every", type=int, default=0, metavar="N", help="commit after every N scenes")
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(func=cmd_pack)

    p = subparsers.add_parser("ls", help="list the scenes of an archive")
    p.add_argument("archive", help="archive path or fsspec URL")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--storage-option", **so)
    p.add_argument("--allow-truncated", action="store_true", help=TRUNC_HELP)
    p.set_defaults(func=cmd_ls)

    p = subparsers.add_parser("extract", help="extract scenes from an archive as standalone .vt4d files")
    p.add_argument("archive", help="archive path or fsspec URL")
    p.add_argument("keys", nargs="*", help="scene keys (default: all)")
    p.add_argument("-o", "--output", default=".", help="output directory (default: .)")
    p.add_argument("--force", action="store_true", help="overwrite existing files")
    p.add_argument("--storage-option", **so)
    p.add_argument("--allow-truncated", action="store_true", help=TRUNC_HELP)
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(func=cmd_extract)

    p = subparsers.add_parser("repair", help="recover an archive after a crashed writer or damage",
                              description="Keep the last commit, add complete checksum-valid records written "
                              "after it (skipping damaged bytes), cut off torn bytes after the last valid record, "
                              "and commit.  A truncated archive, or one without a usable commit, gets a full "
                              "scan.  Never drops a record that verifies; exits 1 if committed scenes could not "
                              "be recovered (they are listed).")
    p.add_argument("archive", help="local archive path")
    p.add_argument("--full-scan", action="store_true",
                   help="also check every record of the newest commit whose index verifies, and walk the whole "
                   "file for records written after it")
    p.add_argument("--dry-run", action="store_true", help="print the plan; change nothing")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_repair)

    p = subparsers.add_parser("compact", help="rewrite an archive with only its live records (atomic)",
                              description="Copy every live record (CRC-checked) into a new file with one index, "
                              "then rename it over the archive: replaced records and old indexes are reclaimed. "
                              "Holds the writer lock; readers see the old or the new file, never a mix.")
    p.add_argument("archive", help="local archive path")
    p.add_argument("--format-version", default="1.1", choices=["1.0", "1.1"],
                   help="1.1 (default: segmented indexes) or 1.0 (readable by 1.0 readers)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_compact)
