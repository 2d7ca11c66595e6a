"""`vt4d encode DIR --archive A` keeps what it finished: it commits as it goes, commits on Ctrl-C and says
how many scenes it kept, and `--skip-existing` resumes where it stopped.

The codec is replaced by a stand-in (what is tested is the command's bookkeeping, not the networks), so
these run in-process and fast; a stand-in encode raises KeyboardInterrupt as Ctrl-C would."""

from __future__ import annotations

import json
import shutil
from types import SimpleNamespace

import pytest

from cli_helpers import make_scene

import vt4dcodec.cli as cli
import vt4dcodec.cli.codec_commands as codec_commands
from vt4dcodec import codec, open_archive


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """A folder of three small one-camera captures (cap-a, cap-b, cap-c)."""
    from vt4dcodec.capture.io import write_capture
    from vt4dcodec.synth import SynthConfig, generate_scene

    root = tmp_path_factory.mktemp("captures")
    first = root / "cap-a"
    write_capture(generate_scene(3, split="test", config=SynthConfig(num_cameras=1, height=16, width=16)).capture,
                  first)
    for name in ("cap-b", "cap-c"):
        shutil.copytree(first, root / name)
        manifest = json.loads((root / name / "capture.json").read_text())
        manifest["capture_id"] = name
        (root / name / "capture.json").write_text(json.dumps(manifest))
    manifest = json.loads((first / "capture.json").read_text())
    manifest["capture_id"] = "cap-a"
    (first / "capture.json").write_text(json.dumps(manifest))
    return root


class StandInCodec:
    """codec.encode's stand-in: a small scene per call, Ctrl-C (KeyboardInterrupt) at call ``interrupt_at``."""

    def __init__(self, monkeypatch, interrupt_at=None, on_call=None):
        self.calls: list[str] = []
        self.interrupt_at, self.on_call = interrupt_at, on_call
        fp = make_scene().fingerprint
        monkeypatch.setattr(codec, "load_encoder", lambda *a, **k: SimpleNamespace(config=SimpleNamespace(frames=8)))
        monkeypatch.setattr(codec, "model_fingerprint", lambda model: fp)
        monkeypatch.setattr(codec, "encode", self.encode)

    def encode(self, cap, model, encoding, *, camera=None, cameras=None, start=0, seed=0, fit="crop"):
        self.calls.append(cap.capture_id)
        if self.on_call is not None:
            self.on_call(len(self.calls))
        if len(self.calls) == self.interrupt_at:
            raise KeyboardInterrupt
        return make_scene(kind="encoded", metadata={"vt4d": {"source_camera": cap.camera_names[0],
                                                             "clip_start": start}})


def _keys(archive) -> list[str]:
    with open_archive(archive) as reader:
        return sorted(reader.keys())


def test_ctrl_c_keeps_the_scenes_finished_and_skip_existing_resumes(captures, tmp_path, monkeypatch, capsys):
    archive = tmp_path / "a.vt4da"
    stand_in = StandInCodec(monkeypatch, interrupt_at=3)
    code = cli.main(["encode", str(captures), "--archive", str(archive), "-q"])
    err = capsys.readouterr().err
    assert code == cli.EXIT_INTERRUPTED
    assert _keys(archive) == ["cap-a/cam00/000000", "cap-b/cam00/000000"]  # the two finished before Ctrl-C
    assert "kept the 2 scenes" in err and "--skip-existing" in err, err

    stand_in = StandInCodec(monkeypatch)
    code = cli.main(["encode", str(captures), "--archive", str(archive), "--skip-existing", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and stand_in.calls == ["cap-c"]  # the finished captures are not encoded again
    assert [s["key"] for s in out["scenes"]] == ["cap-c/cam00/000000"]
    assert out["skipped"] == ["cap-a/cam00/000000", "cap-b/cam00/000000"]
    assert _keys(archive) == ["cap-a/cam00/000000", "cap-b/cam00/000000", "cap-c/cam00/000000"]


def test_encode_commits_as_it_goes(captures, tmp_path, monkeypatch):
    """With the commit interval passed, scenes are committed between captures: a run killed outright (no
    chance to commit on the way out) keeps them too."""
    archive = tmp_path / "a.vt4da"
    seen: dict[int, list[str]] = {}

    def look(n):
        if n > 1:
            seen[n] = _keys(archive)

    monkeypatch.setattr(codec_commands, "COMMIT_SECONDS", 0.0)
    StandInCodec(monkeypatch, on_call=look)
    assert cli.main(["encode", str(captures), "--archive", str(archive), "-q"]) == 0
    assert seen == {2: ["cap-a/cam00/000000"], 3: ["cap-a/cam00/000000", "cap-b/cam00/000000"]}


def test_skip_existing_needs_an_archive_and_excludes_replace(captures, tmp_path, capsys):
    assert cli.main(["encode", str(captures / "cap-a"), "-o", str(tmp_path / "s.vt4d"), "--skip-existing"]) == 1
    assert cli.main(["encode", str(captures), "--archive", str(tmp_path / "a.vt4da"), "--skip-existing",
                     "--replace"]) == 1
    assert "--skip-existing" in capsys.readouterr().err
