"""Issue 52, bounded reading, on the command line: every command that decodes a stored scene (a .vt4d file or an
archive record) takes --max-decoded-bytes, the library's ``max_decoded_bytes`` (FORMAT.md I.7: default 64 MiB,
``none`` for no budget).  A scene over the budget is refused with the flag that reads it named, never the Python
keyword; the library's own message stays as API users read it.

Most checks call the command in this process (``vt4dcodec.cli.main``; decode with the stand-in renderer of
cli_helpers); one runs `vt4d` as a user does, for the exit codes."""

from __future__ import annotations

import argparse
import inspect
import json

import pytest
from cli_helpers import StandInDecoder, vt4d

import vt4dcodec.cli as cli
from vt4dcodec import ArchiveWriter
from vt4dcodec.archive import open_archive, verify_archive
from vt4dcodec.errors import LimitExceededError
from vt4dcodec.format import load, open_scene, verify
from vt4dcodec.format.sections import DEFAULT_MAX_DECODED_BYTES, check_decoded_budget, decoded_budget

FLAG = "--max-decoded-bytes"
# the commands that decode stored scenes: info (a scene's cameras), verify, decode, pack (it verifies each scene)
READERS = ("info", "verify", "decode", "pack")


@pytest.fixture()
def sources(scene_file, tmp_path):
    """The small scene as a file and as record "s" of an archive, and the bytes it decodes to."""
    archive = tmp_path / "a.vt4da"
    with ArchiveWriter(archive, "x", durable=False) as writer:
        writer.append("s", scene_file.read_bytes())
    return {"scene": scene_file, "archive": archive, "size": open_scene(scene_file)._decoded_bytes}


def _command(command: str, kind: str, sources, tmp_path) -> list[str]:
    if command == "decode":
        key = ["--key", "s"] if kind == "archive" else []
        return ["decode", str(sources[kind]), *key, "-o", str(tmp_path / "v.npz"), "-y", "-q"]
    if command == "pack":
        return ["pack", str(sources["scene"]), "-o", str(tmp_path / "packed.vt4da"), "-y", "-q"]
    return [command, str(sources[kind]), "-q"]


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    (action,) = [a for a in cli.build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(action.choices)


READS = [("info", "scene"), ("verify", "scene"), ("verify", "archive"), ("decode", "scene"), ("decode", "archive"),
         ("pack", "scene")]


@pytest.mark.parametrize("command,kind", READS)
def test_a_scene_just_over_the_budget_is_refused_naming_the_flag_and_read_with_it_raised(
        command, kind, sources, tmp_path, monkeypatch, capsys):
    decoder = StandInDecoder(monkeypatch)
    size, args = sources["size"], _command(command, kind, sources, tmp_path)
    assert cli.main([*args, FLAG, str(size - 1)]) == 1  # invalid input, as any refused file
    err = capsys.readouterr().err
    assert f"over the decoded-size budget of {size - 1:,} bytes" in err, err
    assert f"if you trust the file, rerun with {FLAG} {size} (or none)" in err, err
    assert "max_decoded_bytes" not in err and "None" not in err, err
    assert decoder.opened == []  # refused before a model was looked for
    for budget in (str(size), "none"):
        assert cli.main([*args, FLAG, budget]) == 0, capsys.readouterr().err
    assert len(decoder.opened) == (2 if command == "decode" else 0)


def test_info_on_an_archive_reads_no_record_so_any_budget_serves(sources, capsys):
    assert cli.main(["info", str(sources["archive"]), FLAG, "0", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["scenes"] == 1


def test_verify_json_keeps_its_error_shape_and_names_the_flag(sources, capsys):
    size = sources["size"]
    code = cli.main(["verify", str(sources["scene"]), str(sources["archive"]), FLAG, f"{size - 1}", "--json"])
    assert code == 1
    results = json.loads(capsys.readouterr().out)
    assert [set(r) for r in results] == [{"file", "ok", "kind", "error", "message"}] * 2
    assert [(r["kind"], r["ok"], r["error"]) for r in results] == [("scene", False, "LimitExceededError"),
                                                                 ("archive", False, "LimitExceededError")]
    assert results[1]["message"].startswith("record 's': the scene decodes to")
    for r in results:
        assert r["message"].endswith(f"rerun with {FLAG} {size} (or none)"), r["message"]


def test_pack_append_names_the_file_over_the_budget(sources, tmp_path, capsys):
    size, archive = sources["size"], sources["archive"]
    args = ["pack", str(sources["scene"]), "-o", str(archive), "--append", "-y"]
    assert cli.main([*args, FLAG, str(size - 1)]) == 1
    err = capsys.readouterr().err
    assert f"{sources['scene']}: the scene decodes to" in err and f"{FLAG} {size} (or none)" in err, err
    assert cli.main([*args, FLAG, "2KiB", "-q"]) == 0  # 2,048 bytes: more than the small scene decodes to


@pytest.mark.parametrize("text,value", [("123", 123), ("0", 0), ("256MiB", 256 << 20), ("1GiB", 1 << 30),
                                        ("2kib", 2048), ("1 TiB", 1 << 40), ("64B", 64), ("none", None),
                                        ("None", None)])
def test_budget_values(text, value):
    """N bytes with an optional binary suffix, or none.  0 is allowed, as the library's decoded_budget allows it:
    no scene is decoded then (info on an archive still runs)."""
    parsed = cli.decoded_budget_arg(text)
    assert parsed == value and decoded_budget(parsed) == value


@pytest.mark.parametrize("bad", ["-1", "abc", "1.5", "64MB", "1e6", "", "0x10", "12 apples"])
@pytest.mark.parametrize("command", READERS)
def test_a_bad_budget_is_a_usage_error_naming_the_flag(command, bad, sources, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main([*_command(command, "scene", sources, tmp_path), f"{FLAG}={bad}"])
    assert exit_.value.code == cli.EXIT_USAGE
    err = capsys.readouterr().err
    assert f"argument {FLAG}: {bad!r}" in err and "KiB, MiB, GiB or TiB" in err, err


def test_the_commands_that_decode_stored_scenes_have_the_flag_and_the_default_is_the_librarys():
    with_flag = {name for name, p in _subcommands().items() for a in p._actions if FLAG in a.option_strings}
    assert with_flag == set(READERS)
    for name in READERS:
        assert _subcommands()[name].get_default("max_decoded_bytes") == DEFAULT_MAX_DECODED_BYTES == 64 << 20
    for reader in (open_scene, load, verify, open_archive, verify_archive, ArchiveWriter.append):
        assert inspect.signature(reader).parameters["max_decoded_bytes"].default == DEFAULT_MAX_DECODED_BYTES
    assert "default 64MiB = 67,108,864 bytes" in " ".join(_subcommands()["verify"].format_help().split())


def test_the_librarys_message_stays_and_the_commands_say_the_flag():
    with pytest.raises(LimitExceededError) as error:
        check_decoded_budget(123_456_789, DEFAULT_MAX_DECODED_BYTES)
    message = str(error.value)
    assert message.endswith("over the reader's budget of 67,108,864; if you trust the file, pass "
                            "max_decoded_bytes=123456789 (or None)")  # the API's words
    assert cli.cli_message(message, {FLAG}).endswith(
        "over the decoded-size budget of 67,108,864 bytes; if you trust the file, rerun with --max-decoded-bytes "
        "123456789 (or none)")
    assert cli.cli_message(message, set()) == message  # a command without the flag has no other words for it


def test_exit_codes_as_a_user_sees_them(sources):
    size = sources["size"]
    r = vt4d("verify", sources["scene"], sources["archive"], FLAG, size - 1)
    assert r.returncode == 1 and r.stderr.count(f"rerun with {FLAG} {size} (or none)") == 2, r.stderr
    assert vt4d("verify", sources["scene"], sources["archive"], FLAG, size, "-q").returncode == 0
    r = vt4d("info", sources["scene"], FLAG, "-1")
    assert r.returncode == 2 and f"argument {FLAG}: '-1' must be 0 or more" in r.stderr, r.stderr


def test_encode_archive_never_refuses_its_own_output_by_the_reading_budget(small_captures, tmp_path, monkeypatch):
    """Regression: `encode --archive` validated the scenes it had just encoded against the default reading budget,
    which has no flag there: a large enough encode would have been refused with the Python keyword's message."""
    from cli_helpers import StandInCodec

    import vt4dcodec.format.reader as reader

    StandInCodec(monkeypatch)
    # the library's default budget made tiny: every scene read under it is over it
    monkeypatch.setattr(reader, "check_decoded_budget", lambda size, budget: check_decoded_budget(
        size, 1 if budget == DEFAULT_MAX_DECODED_BYTES else budget))
    with pytest.raises(LimitExceededError):
        reader.check_decoded_budget(10, DEFAULT_MAX_DECODED_BYTES)
    archive = tmp_path / "a.vt4da"
    assert cli.main(["encode", str(small_captures / "cap-a"), "--archive", str(archive), "-q"]) == 0
    with open_archive(archive) as ar:
        assert len(ar) == 1
