"""Where `vt4d decode` writes, and at what frame rate: `-o v.mp4` with one trajectory is that file, and
videos play at the capture's frame rate, which `vt4d encode` records in the scene.

The renderer is a stand-in (cli_helpers.StandInDecoder): what is tested is the command's outputs."""

from __future__ import annotations

import dataclasses
import json
from fractions import Fraction
from pathlib import Path
from types import SimpleNamespace

import av
import numpy as np
import pytest

from cli_helpers import StandInCodec, StandInDecoder, make_scene

import vt4dcodec.cli as cli
from vt4dcodec import load, save
from vt4dcodec.media import scene_fps


def _rate(path) -> Fraction:
    with av.open(str(path)) as container:
        return Fraction(container.streams.video[0].average_rate)


def test_decode_to_a_mp4_name_writes_that_file(scene_file, tmp_path, monkeypatch, capsys):
    StandInDecoder(monkeypatch)
    out = tmp_path / "views" / "v.mp4"
    assert cli.main(["decode", str(scene_file), "-o", str(out), "-q"]) == 0
    assert out.is_file() and list(out.parent.iterdir()) == [out]
    assert cli.main(["decode", str(scene_file), "-o", str(tmp_path / "v.npz"), "-q"]) == 0
    assert (tmp_path / "v.npz").is_file()


def test_decode_refuses_a_file_name_for_several_outputs_before_any_work(scene_file, tmp_path, monkeypatch, capsys):
    decoder = StandInDecoder(monkeypatch)
    code = cli.main(["decode", str(scene_file), "-t", "source", "-t", "pan", "-o", str(tmp_path / "v.mp4")])
    assert code == 1 and "2 trajectories" in capsys.readouterr().err
    code = cli.main(["decode", str(scene_file), "--format", "png", "-o", str(tmp_path / "v.mp4")])
    assert code == 1 and "--format png" in capsys.readouterr().err
    assert decoder.opened == [] and sorted(p.name for p in tmp_path.iterdir()) == ["s.vt4d"]


@pytest.mark.parametrize("fps", [30.0, 12.5])
def test_decoded_videos_play_at_the_captures_frame_rate(tmp_path, monkeypatch, fps):
    scene = tmp_path / "s.vt4d"
    save(make_scene(metadata={"capture": {"fps": fps}}), scene)
    StandInDecoder(monkeypatch)
    assert cli.main(["decode", str(scene), "-o", str(tmp_path / "v"), "-q"]) == 0
    (video,) = (tmp_path / "v").iterdir()
    assert _rate(video) == Fraction(fps)


def test_encode_records_the_captures_frame_rate(small_captures, tmp_path, monkeypatch):
    manifest = json.loads((small_captures / "cap-a" / "capture.json").read_text())
    StandInCodec(monkeypatch)
    out = tmp_path / "s.vt4d"
    assert cli.main(["encode", str(small_captures / "cap-a"), "-o", str(out), "-q"]) == 0
    assert load(out).metadata["capture"] == {"fps": manifest["fps"]}
    assert scene_fps(load(out)) == manifest["fps"]


def test_frame_rate_from_timestamps_without_a_recorded_one():
    scene = make_scene()
    assert scene_fps(scene) == 8.0  # nothing recorded: the default
    timed = SimpleNamespace(metadata={}, cameras=dataclasses.replace(scene.cameras, timestamps=np.array([0, 0.04, 0.08])))
    assert scene_fps(timed) == pytest.approx(25.0)


def test_several_trajectories_render_as_batches(scene_file, tmp_path, monkeypatch, capsys):
    """`vt4d decode` renders its trajectories RENDER_BATCH at a time, not one forward pass each (issue 51.2);
    every output is still written, in order."""
    from vt4dcodec import codec

    decoder = StandInDecoder(monkeypatch)
    monkeypatch.setattr(codec, "RENDER_BATCH", 4)
    specs = ["source", "pan", "orbit", "dolly_in", "pan:degrees=5", "orbit:degrees=5"]
    argv = ["decode", str(scene_file), "-o", str(tmp_path / "v"), "--format", "npz", "--json"]
    assert cli.main([*argv, *[a for s in specs for a in ("-t", s)]]) == 0
    assert decoder.batches == [4, 2]
    outputs = json.loads(capsys.readouterr().out)["outputs"]
    assert [o["trajectory"] for o in outputs] == specs and all((tmp_path / "v" / o["path"]).exists() or
                                                             Path(o["path"]).exists() for o in outputs)
