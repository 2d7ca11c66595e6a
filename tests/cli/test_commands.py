"""Every command takes --json and -q with one meaning, and its --help teaches
(a description and examples; decode and generate list the trajectory presets with their parameters)."""

from __future__ import annotations

import argparse
import json

import pytest
from cli_helpers import make_scene, vt4d, vt4d_json

from vt4dcodec import ArchiveWriter, save
from vt4dcodec.capture.trajectories import PRESET_PARAMS, SPEC_PRESETS
from vt4dcodec.cli import build_parser


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    (action,) = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(action.choices)


COMMANDS = sorted(_subparsers())


def test_all_commands_are_covered():
    assert set(COMMANDS) == {"info", "verify", "encode", "decode", "demo", "pack", "ls", "extract", "repair",
                             "compact", "import", "capture-info", "contact-sheet", "synth", "generate"}


@pytest.mark.parametrize("name", COMMANDS)
def test_help_has_a_description_examples_and_the_output_options(name):
    r = vt4d(name, "--help")
    assert r.returncode == 0, r.stderr
    text = r.stdout
    assert _subparsers()[name].description and len(_subparsers()[name].description) > 40
    examples = text.split("examples:\n", 1)[1]
    assert f"vt4d {name} " in examples or f"-m vt4dcodec {name} " in examples
    flags = {s for a in _subparsers()[name]._actions for s in a.option_strings}
    assert {"--json", "-q", "--quiet"} <= flags


@pytest.mark.parametrize("name", ["decode", "generate"])
def test_help_lists_every_spec_preset_with_its_parameters(name):
    text = vt4d(name, "--help").stdout
    for preset in SPEC_PRESETS:
        params = ",".join(f"{k}={v:g}" for k, v in PRESET_PARAMS[preset].items())
        assert (f"{preset}:{params}" if params else f"  {preset} ") in text, preset


def test_the_presets_an_error_lists_are_those_the_help_lists(scene_file, tmp_path):
    help_text = vt4d("decode", "--help").stdout
    r = vt4d("decode", scene_file, "-t", "spiral", "-o", tmp_path / "v")
    assert r.returncode == 1
    listed = r.stderr.split("choose one of ")[1].split(" (")[0].split(", ")
    assert listed == list(SPEC_PRESETS) and all(p in help_text for p in listed)
    r = vt4d("decode", scene_file, "-t", "orbit:degress=30", "-o", tmp_path / "v")
    assert r.returncode == 1 and "'degrees', 'distance'" in r.stderr and "degress" in r.stderr


@pytest.fixture()
def workspace(tmp_path, scene_file):
    """A scene, an archive of two scenes and a small synthetic capture, for the torch-free commands."""
    archive = tmp_path / "a.vt4da"
    with ArchiveWriter(archive) as w:
        w.append("cap-1/cam00/000000", scene_file.read_bytes())
        w.append("cap-2/cam00/000000", scene_file.read_bytes())
        w.commit()
    save(make_scene(), tmp_path / "other.vt4d")
    return tmp_path


def _torch_free_runs(ws):
    """(command, arguments) for every command that needs no model, each writing into a fresh place."""
    n = iter(range(100))
    return [
        ("info", [ws / "s.vt4d"]),
        ("verify", [ws / "s.vt4d", ws / "a.vt4da"]),
        ("ls", [ws / "a.vt4da"]),
        ("extract", [ws / "a.vt4da", "-o", lambda: ws / f"x{next(n)}"]),
        ("pack", [ws / "other.vt4d", "-o", lambda: ws / f"p{next(n)}.vt4da"]),
        ("repair", [ws / "a.vt4da", "--dry-run"]),
        ("compact", [ws / "a.vt4da"]),
        ("synth", ["-n", "1", "--cameras", "2", "--frames", "2", "--size", "16", "--workers", "1",
                   "-o", ws / "caps"]),
        ("capture-info", [ws / "caps" / "train-000000"]),
        ("contact-sheet", [ws / "caps" / "train-000000", "-o", lambda: ws / f"sheet{next(n)}.png"]),
    ]


def test_json_and_quiet_mean_the_same_on_every_torch_free_command(workspace):
    for name, args in _torch_free_runs(workspace):
        def argv():
            return [a() if callable(a) else a for a in args]
        r = vt4d(name, *argv())
        assert r.returncode == 0 and r.stdout.strip(), (name, r.stderr)  # text by default
        result = vt4d_json(name, *argv())  # --json: one JSON document
        assert isinstance(result, (dict, list)) and result, name
        r = vt4d(name, *argv(), "-q")  # -q: nothing on stdout
        assert r.returncode == 0 and r.stdout == "", (name, r.stdout, r.stderr)
        r = vt4d(name, *argv(), "-q", "--json")  # -q never hides what --json asks for
        assert r.returncode == 0 and json.loads(r.stdout), name


def test_json_and_quiet_on_encode_and_decode(small_model, capture_dir, tmp_path):
    r = vt4d("encode", capture_dir, "--model", small_model, "-o", tmp_path / "s.vt4d", "-q")
    assert r.returncode == 0 and r.stdout == "", r.stderr
    result = vt4d_json("encode", capture_dir, "--model", small_model, "-o", tmp_path / "s.vt4d")
    assert result["scenes"][0]["bytes"] == (tmp_path / "s.vt4d").stat().st_size
    r = vt4d("decode", tmp_path / "s.vt4d", "--model", small_model, "--steps", "1", "-o", tmp_path / "v", "-q")
    assert r.returncode == 0 and r.stdout == "", r.stderr
    result = vt4d_json("decode", tmp_path / "s.vt4d", "--model", small_model, "--steps", "1", "-o", tmp_path / "v")
    assert [o["trajectory"] for o in result["outputs"]] == ["source"]


def test_a_failing_verify_reports_on_stderr_even_when_quiet(tmp_path):
    bad = tmp_path / "bad.vt4d"
    bad.write_bytes(b"not a scene")
    r = vt4d("verify", bad, "-q")
    assert r.returncode == 1 and r.stdout == "" and "FAIL" in r.stderr


def test_decode_writes_h264_and_upscales_for_viewing(small_model, capture_dir, tmp_path):
    """Issue 13: the mp4s `vt4d decode` writes are H.264 yuv420p (browsers play them), ``--upscale 4``
    enlarges them by pixel repetition."""
    from vt4dcodec.media import read_mp4

    assert vt4d("encode", capture_dir, "--model", small_model, "-o", tmp_path / "s.vt4d", "-q").returncode == 0
    plain = vt4d_json("decode", tmp_path / "s.vt4d", "--model", small_model, "--steps", "1", "-o", tmp_path / "a")
    big = vt4d_json("decode", tmp_path / "s.vt4d", "--model", small_model, "--steps", "1", "-o", tmp_path / "b",
                    "--upscale", "4")
    import av
    small_frames = read_mp4(plain["outputs"][0]["path"])
    for result, factor in ((plain, 1), (big, 4)):
        with av.open(result["outputs"][0]["path"]) as c:
            ctx = c.streams.video[0].codec_context
            assert (ctx.name, ctx.pix_fmt) == ("h264", "yuv420p")
            assert (ctx.height, ctx.width) == (small_frames.shape[1] * factor, small_frames.shape[2] * factor)


def test_upscale_is_checked_before_work(scene_file, tmp_path):
    r = vt4d("decode", scene_file, "--format", "png", "--upscale", "4", "-o", tmp_path / "v")
    assert r.returncode == 1 and "--upscale" in r.stderr and "model" not in r.stderr.lower(), r.stderr
    r = vt4d("decode", scene_file, "--upscale", "17", "-o", tmp_path / "v")
    assert r.returncode == 2 and "--upscale" in r.stderr, r.stderr
    assert not (tmp_path / "v").exists()
