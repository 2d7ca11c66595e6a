"""`vt4d encode DIR --archive A` keeps what it finished: it commits as it goes, commits on Ctrl-C and says
how many scenes it kept, and `--skip-existing` resumes where it stopped.

The codec is replaced by a stand-in (what is tested is the command's bookkeeping, not the networks), so
these run in-process and fast; a stand-in encode raises KeyboardInterrupt as Ctrl-C would."""

from __future__ import annotations

import json

from cli_helpers import StandInCodec

import vt4dcodec.cli as cli
import vt4dcodec.cli.codec_commands as codec_commands
from vt4dcodec import open_archive


def _keys(archive) -> list[str]:
    with open_archive(archive) as reader:
        return sorted(reader.keys())


def test_ctrl_c_keeps_the_scenes_finished_and_skip_existing_resumes(small_captures, tmp_path, monkeypatch, capsys):
    archive = tmp_path / "a.vt4da"
    stand_in = StandInCodec(monkeypatch, interrupt_at=3)
    code = cli.main(["encode", str(small_captures), "--archive", str(archive), "-q"])
    err = capsys.readouterr().err
    assert code == cli.EXIT_INTERRUPTED
    assert _keys(archive) == ["cap-a/cam00/000000", "cap-b/cam00/000000"]  # the two finished before Ctrl-C
    assert "kept the 2 scenes" in err and "--skip-existing" in err, err

    stand_in = StandInCodec(monkeypatch)
    code = cli.main(["encode", str(small_captures), "--archive", str(archive), "--skip-existing", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and stand_in.calls == ["cap-c"]  # the finished small_captures are not encoded again
    assert [s["key"] for s in out["scenes"]] == ["cap-c/cam00/000000"]
    assert out["skipped"] == ["cap-a/cam00/000000", "cap-b/cam00/000000"]
    assert _keys(archive) == ["cap-a/cam00/000000", "cap-b/cam00/000000", "cap-c/cam00/000000"]


def test_encode_commits_as_it_goes(small_captures, tmp_path, monkeypatch):
    """With the commit interval passed, scenes are committed between small_captures: a run killed outright (no
    chance to commit on the way out) keeps them too."""
    archive = tmp_path / "a.vt4da"
    seen: dict[int, list[str]] = {}

    def look(n):
        if n > 1:
            seen[n] = _keys(archive)

    monkeypatch.setattr(codec_commands, "COMMIT_SECONDS", 0.0)
    StandInCodec(monkeypatch, on_call=look)
    assert cli.main(["encode", str(small_captures), "--archive", str(archive), "-q"]) == 0
    assert seen == {2: ["cap-a/cam00/000000"], 3: ["cap-a/cam00/000000", "cap-b/cam00/000000"]}


def test_skip_existing_needs_an_archive_and_excludes_replace(small_captures, tmp_path, capsys):
    assert cli.main(["encode", str(small_captures / "cap-a"), "-o", str(tmp_path / "s.vt4d"), "--skip-existing"]) == 1
    assert cli.main(["encode", str(small_captures), "--archive", str(tmp_path / "a.vt4da"), "--skip-existing",
                     "--replace"]) == 1
    assert "--skip-existing" in capsys.readouterr().err


def test_keys_already_there_are_refused_before_the_model_loads(small_captures, tmp_path, monkeypatch, capsys):
    archive = tmp_path / "a.vt4da"
    StandInCodec(monkeypatch)
    assert cli.main(["encode", str(small_captures / "cap-b"), "--archive", str(archive), "-q"]) == 0
    stand_in = StandInCodec(monkeypatch)
    assert cli.main(["encode", str(small_captures), "--archive", str(archive)]) == 1
    err = capsys.readouterr().err
    assert "scene 'cap-b/cam00/000000' is already in" in err and "-y/--overwrite" in err and "--skip-existing" in err
    assert not stand_in.loaded and stand_in.calls == []  # refused before the model loaded or anything encoded
    assert _keys(archive) == ["cap-b/cam00/000000"]


def test_a_real_sigint_keeps_the_finished_scenes(small_captures, tmp_path):
    """The same through the operating system's Ctrl-C: the process signals itself (SIGINT) while encoding
    its third capture, and exits 130 with the two finished scenes committed."""
    import os
    import signal
    import subprocess
    import sys

    from cli_helpers import ROOT

    archive = tmp_path / "a.vt4da"
    driver = f"""
import os, signal, sys
sys.path.insert(0, {str(ROOT / "tests" / "cli")!r})
import pytest
from cli_helpers import StandInCodec
import vt4dcodec.cli as cli
patch = pytest.MonkeyPatch()
StandInCodec(patch, on_call=lambda n: n == 3 and os.kill(os.getpid(), signal.SIGINT))
sys.exit(cli.main(["encode", {str(small_captures)!r}, "--archive", {str(archive)!r}]))
"""
    r = subprocess.run([sys.executable, "-c", driver], capture_output=True, text=True, cwd=ROOT, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(ROOT)},
                       # SIGINT at its default in the child, even where the tests run as a background job (whose
                       # shell ignores SIGINT for what it starts): else Python never raises KeyboardInterrupt
                       preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert r.returncode == 130, r.stderr
    assert "interrupted: kept the 2 scenes this run encoded" in r.stderr, r.stderr
    assert _keys(archive) == ["cap-a/cam00/000000", "cap-b/cam00/000000"]
