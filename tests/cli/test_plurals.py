"""Counts of one read as one: "1 scene", "1 camera", "rendered 1 trajectory" (not "1 scenes", "trajectory(ies)")."""

from __future__ import annotations

from cli_helpers import StandInDecoder

import vt4dcodec.cli as cli


def test_one_of_a_kind_is_singular(scene_file, small_captures, tmp_path, monkeypatch, capsys):
    archive = tmp_path / "a.vt4da"
    runs = [
        (["pack", str(scene_file), "-o", str(archive)], "packed 1 scene (1 in the archive"),
        (["ls", str(archive)], "1 scene, generation 1"),
        (["extract", str(archive), "-o", str(tmp_path / "out")], "extracted 1 scene to"),
        (["compact", str(archive)], ": 1 scene, "),
        (["capture-info", str(small_captures / "cap-a")], "1 camera, 8 frames at 8.000 fps"),
        (["decode", str(scene_file), "-o", str(tmp_path / "v")], "rendered 1 trajectory in"),
    ]
    StandInDecoder(monkeypatch)
    for argv, says in runs:
        assert cli.main(argv) == 0, argv
        out = capsys.readouterr().out
        assert says in out, (argv, out)
        assert "(s)" not in out and "(ies)" not in out and " 1 scenes" not in out and " 1 cameras" not in out, out
    assert cli.main(["decode", str(scene_file), "-t", "source", "-t", "pan", "-o", str(tmp_path / "w")]) == 0
    assert "rendered 2 trajectories in" in capsys.readouterr().out
