"""One overwrite convention: every command that writes files takes -y/--overwrite; --force is kept for
the model-mismatch override of decode alone; the spellings of earlier versions (--force, --replace) still
work, hidden from --help, with a note naming -y/--overwrite."""

from __future__ import annotations

import argparse

from cli_helpers import StandInCodec

import vt4dcodec.cli as cli
from vt4dcodec import ArchiveWriter, open_archive

WRITERS = {"encode", "decode", "demo", "pack", "extract", "import", "contact-sheet", "synth", "generate"}


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = cli.build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def test_every_command_that_writes_takes_y_overwrite_and_force_is_decodes_alone():
    commands = _subparsers()
    assert WRITERS <= set(commands)
    for name, p in commands.items():
        flags = {s for a in p._actions for s in a.option_strings}
        shown = p.format_help()
        if name in WRITERS:
            assert {"-y", "--overwrite"} <= flags and "-y, --overwrite" in shown, name
        assert "--replace" not in shown, name
        assert ("--force" in shown) == (name == "decode"), name


def _archive(path, scene_file, keys=("a",)):
    with ArchiveWriter(path) as w:
        for key in keys:
            w.append(key, scene_file.read_bytes())


def _keys(path):
    with open_archive(path) as reader:
        return sorted(reader.keys())


def test_pack_y_replaces_the_archive_or_with_append_its_scenes(scene_file, tmp_path, capsys):
    archive = tmp_path / "a.vt4da"
    _archive(archive, scene_file, keys=("old",))
    assert cli.main(["pack", str(scene_file), "-o", str(archive), "-q"]) == cli.EXIT_OS  # refused without -y
    assert "-y/--overwrite" in capsys.readouterr().err
    assert cli.main(["pack", str(scene_file), "-o", str(archive), "-y", "-q"]) == 0
    assert _keys(archive) == ["s"]
    assert cli.main(["pack", str(scene_file), "-o", str(archive), "--append", "-q"]) == 1  # key s is there
    assert "--overwrite" in capsys.readouterr().err
    assert cli.main(["pack", str(scene_file), "-o", str(archive), "--append", "--overwrite", "-q"]) == 0


def test_the_earlier_spellings_still_work_with_a_note(scene_file, tmp_path, capsys):
    archive, out = tmp_path / "a.vt4da", tmp_path / "out"
    _archive(archive, scene_file, keys=("old",))
    assert cli.main(["pack", str(scene_file), "-o", str(archive), "--force"]) == 0
    assert _keys(archive) == ["s"]
    assert "--force is deprecated here; use -y/--overwrite" in capsys.readouterr().err
    assert cli.main(["pack", str(scene_file), "-o", str(archive), "--append", "--replace"]) == 0
    assert "--replace is deprecated here; use -y/--overwrite" in capsys.readouterr().err
    assert cli.main(["extract", str(archive), "-o", str(out), "-q"]) == 0
    assert cli.main(["extract", str(archive), "-o", str(out), "-q"]) == cli.EXIT_OS
    assert "-y/--overwrite" in capsys.readouterr().err
    assert cli.main(["extract", str(archive), "-o", str(out), "--force"]) == 0
    assert cli.main(["extract", str(archive), "-o", str(out), "-y"]) == 0


def test_encode_over_an_existing_file_says_so_unless_y(small_captures, tmp_path, monkeypatch, capsys):
    out = tmp_path / "s.vt4d"
    StandInCodec(monkeypatch)
    assert cli.main(["encode", str(small_captures / "cap-a"), "-o", str(out)]) == 0
    assert "replacing" not in capsys.readouterr().err
    assert cli.main(["encode", str(small_captures / "cap-a"), "-o", str(out)]) == 0  # scripts keep working
    assert f"note: replacing {out} (pass -y/--overwrite" in capsys.readouterr().err
    assert cli.main(["encode", str(small_captures / "cap-a"), "-o", str(out), "-y"]) == 0
    assert "replacing" not in capsys.readouterr().err
