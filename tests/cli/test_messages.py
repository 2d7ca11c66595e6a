"""Errors a new user meets say the problem in words: a missing input is exit 3 on every command, a usage
error starts with the one useful line, and no message shows `[Errno N]`, an exception class, magic bytes,
a `.lock` path or OpenCV's `[ WARN` lines; `vt4d info` on an archive says what it is and what to run."""

from __future__ import annotations

import errno
import subprocess
import sys

import pytest

from cli_helpers import ROOT

import vt4dcodec.cli as cli
from vt4dcodec import ArchiveWriter

RAW = ("[Errno", "Error:", "\\x89", "b'", ".lock", "[ WARN", "Traceback")


def _clean(text: str) -> bool:
    return not any(r in text for r in RAW)


# each command with its inputs missing (the other arguments valid)
MISSING = {
    "info": ["info", "nope.vt4d"],
    "encode": ["encode", "nope", "-o", "s.vt4d"],
    "decode": ["decode", "nope.vt4d", "-o", "v"],
    "decode --capture": ["decode", "SCENE", "--capture", "nope", "-o", "v"],
    "pack": ["pack", "nope.vt4d", "-o", "a.vt4da"],
    "ls": ["ls", "nope.vt4da"],
    "extract": ["extract", "nope.vt4da", "-o", "x"],
    "repair": ["repair", "nope.vt4da"],
    "compact": ["compact", "nope.vt4da"],
    "import": ["import", "nope.toml", "nope", "-o", "c"],
    "capture-info": ["capture-info", "nope"],
    "contact-sheet": ["contact-sheet", "nope", "-o", "s.png"],
    "generate": ["generate", "nope", "-o", "g"],
}


@pytest.mark.parametrize("name", sorted(MISSING))
def test_a_missing_input_is_exit_3_in_words_on_every_command(name, scene_file, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    argv = [str(scene_file) if a == "SCENE" else a for a in MISSING[name]]
    assert cli.main(argv) == cli.EXIT_OS
    err = capsys.readouterr().err
    wanted = "no such archive" if name in cli.ARCHIVE_COMMANDS else "no such file or directory"
    assert "nope" in err and wanted in err and _clean(err), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.vt4d"]  # nothing written


def test_every_command_with_inputs_is_checked():
    assert set(cli.INPUTS) == {name.split()[0] for name in MISSING}


def test_a_usage_error_starts_with_the_useful_line(capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main(["encode"])
    assert stop.value.code == cli.EXIT_USAGE
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "vt4d encode: error: the following arguments are required: captures", lines
    assert len(lines) <= 2 and "--help" in lines[-1]


def test_wrong_files_are_named_in_words(scene_file, tmp_path, capsys):
    text = tmp_path / "notes.md"
    text.write_text("# not a scene\n")
    assert cli.main(["info", str(text)]) == 1
    err = capsys.readouterr().err
    assert "notes.md: not a .vt4d scene" in err and _clean(err), err
    assert cli.main(["verify", str(text), str(tmp_path / "nope.vt4d")]) == 1
    err = capsys.readouterr().err
    assert "notes.md: not a .vt4d scene" in err and "nope.vt4d: no such file or directory" in err, err
    assert _clean(err) and "BadMagicError" not in err and "FileNotFoundError" not in err, err
    assert cli.main(["ls", str(scene_file)]) == 1
    err = capsys.readouterr().err
    assert "is a single .vt4d scene, not an archive" in err and f"vt4d info {scene_file}" in err and _clean(err), err


def test_an_unreachable_url_says_why(capsys):
    assert cli.main(["info", "http://127.0.0.1:1/scene.vt4d"]) == cli.EXIT_OS
    err = capsys.readouterr().err
    assert "cannot read http://127.0.0.1:1/scene.vt4d: cannot connect to 127.0.0.1:1 (connection refused)" in err, err


def test_os_errors_in_words_without_lock_or_temporary_paths():
    denied = cli.os_error_message(PermissionError(errno.EACCES, "Permission denied", "data/a.vt4da.lock"))
    assert denied.startswith("cannot write data/a.vt4da: permission denied in folder data") and _clean(denied)
    gone = cli.os_error_message(FileNotFoundError(errno.ENOENT, "No such file", "out/s.vt4d.tmp-11904"))
    assert gone == "cannot write out/s.vt4d: folder out does not exist"
    gone = cli.os_error_message(FileNotFoundError(errno.ENOENT, "No such file", "out/a.vt4da.lock"))
    assert gone == "cannot write out/a.vt4da: folder out does not exist"
    assert cli.os_error_message(IsADirectoryError(errno.EISDIR, "Is a directory", "v")) == "v: is a folder, not a file"
    full = cli.os_error_message(OSError(errno.ENOSPC, "No space left on device", "out/a.vt4da.compact-77"))
    assert full == "cannot write out/a.vt4da: no space left on the device"
    denied = cli.os_error_message(PermissionError(errno.EACCES, "Permission denied", "out/s.vt4d.tmp-11904"))
    assert denied == "cannot write out/s.vt4d: permission denied"


def test_no_opencv_warning_lines():
    code = "import vt4dcodec.cli, cv2; cv2.imread('missing.png')"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0 and "[ WARN" not in r.stderr, r.stderr


def test_info_on_an_archive_says_what_it_is_and_what_to_run(scene_file, tmp_path, capsys):
    archive = tmp_path / "a.vt4da"
    with ArchiveWriter(archive) as w:
        w.append("cap/cam00/000000", scene_file.read_bytes())
    assert cli.main(["info", str(archive)]) == 0
    out = capsys.readouterr().out
    assert f"{archive}: a .vt4da archive of 1 scene" in out, out
    assert f"vt4d ls {archive}" in out and f"vt4d decode {archive} --key cap/cam00/000000" in out, out


def test_the_readme_states_the_exit_codes_the_commands_return():
    text = " ".join((ROOT / "README.md").read_text().split())
    assert (f"Exit codes are {cli.EXIT_OK} ok, {cli.EXIT_INVALID} invalid input or failed verification, "
            f"{cli.EXIT_USAGE} usage, {cli.EXIT_OS} file system error (a missing input, on every command), "
            f"{cli.EXIT_INTERRUPTED} interrupted.") in text


def test_an_unknown_option_is_said_by_its_command_with_the_nearest_one(capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main(["encode", "cap", "--ovewrite"])
    assert stop.value.code == cli.EXIT_USAGE
    first = capsys.readouterr().err.splitlines()[0]
    assert first == "vt4d encode: error: unrecognized arguments: --ovewrite (did you mean --overwrite?)", first


def test_an_unknown_calibration_format_names_the_flag_and_its_values(small_captures, tmp_path, capsys):
    calibration = tmp_path / "calib.txt"
    calibration.write_text("fx fy cx cy\n")
    assert cli.main(["import", str(calibration), str(small_captures / "cap-a"), "-o", str(tmp_path / "c")]) == 1
    err = capsys.readouterr().err
    assert "cannot tell the calibration format" in err and "--format opencv|toml|colmap|nerf" in err, err
    assert "format= one of" not in err and "('opencv'" not in err, err


def test_an_unknown_camera_lists_the_cameras_in_words(small_captures, tmp_path, capsys):
    assert cli.main(["encode", str(small_captures / "cap-a"), "--camera", "cam9", "-o", str(tmp_path / "s.vt4d")]) == 1
    err = capsys.readouterr().err
    assert err.rstrip().endswith("has no camera 'cam9' (--camera); it has cam00"), err
