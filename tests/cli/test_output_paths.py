"""Output paths are checked before any work: a wrong extension, a folder where a file goes or a file
where a folder goes is refused (exit 1) before a capture is read or a model loaded, and nothing is
written."""

from __future__ import annotations

import pytest

from cli_helpers import StandInCodec, StandInDecoder

import vt4dcodec.cli as cli


@pytest.mark.parametrize("output, says", [
    ("out.mp4", "-o out.mp4: a scene file ends in .vt4d, not .mp4; videos are rendered from it by `vt4d decode`"),
    ("a.vt4da", "-o a.vt4da: a scene file ends in .vt4d, not .vt4da; --archive FILE.vt4da writes an archive"),
    ("scene", "-o scene: a scene file ends in .vt4d, not no extension (e.g. -o scene.vt4d)"),
])
def test_encode_refuses_an_output_that_is_not_a_scene_file(output, says, small_captures, tmp_path, monkeypatch,
                                                            capsys):
    monkeypatch.chdir(tmp_path)
    stand_in = StandInCodec(monkeypatch)
    assert cli.main(["encode", str(small_captures / "cap-a"), "-o", output]) == 1
    assert capsys.readouterr().err.strip() == f"vt4d encode: error: {says}"
    assert stand_in.calls == [] and not stand_in.loaded and list(tmp_path.iterdir()) == []


def test_encode_checks_the_output_folder_before_the_model_loads(small_captures, tmp_path, monkeypatch, capsys):
    stand_in = StandInCodec(monkeypatch)
    (tmp_path / "s.vt4d").mkdir()
    (tmp_path / "afile").write_text("")
    assert cli.main(["encode", str(small_captures / "cap-a"), "-o", str(tmp_path / "s.vt4d")]) == 1
    assert "is a folder; give a file name ending in .vt4d" in capsys.readouterr().err
    assert cli.main(["encode", str(small_captures / "cap-a"), "-o", str(tmp_path / "afile" / "s.vt4d")]) == 1
    assert "afile is a file, so no folder can be made there" in capsys.readouterr().err
    assert cli.main(["encode", str(small_captures), "--archive", str(tmp_path / "a.vt4d")]) == 1
    assert "an archive ends in .vt4da, not .vt4d; -o FILE.vt4d writes one scene" in capsys.readouterr().err
    assert stand_in.calls == [] and not stand_in.loaded


def test_pack_refuses_a_scene_file_name(scene_file, tmp_path, capsys):
    assert cli.main(["pack", str(scene_file), "-o", str(tmp_path / "a.vt4d")]) == 1
    assert "an archive ends in .vt4da, not .vt4d; a .vt4d file holds one scene" in capsys.readouterr().err
    assert not (tmp_path / "a.vt4d").exists() and not (tmp_path / "a.vt4d.lock").exists()


def test_decode_and_contact_sheet_check_their_outputs_first(scene_file, small_captures, tmp_path, monkeypatch,
                                                            capsys):
    decoder = StandInDecoder(monkeypatch)
    (tmp_path / "afile").write_text("")
    assert cli.main(["decode", str(scene_file), "-o", str(tmp_path / "afile" / "views")]) == 1
    assert "afile is a file, so no folder can be made there" in capsys.readouterr().err
    assert decoder.opened == []
    assert cli.main(["contact-sheet", str(small_captures / "cap-a"), "-o", str(tmp_path / "sheet.jpg")]) == 1
    assert "a contact sheet ends in .png, not .jpg" in capsys.readouterr().err


def test_pack_makes_the_archives_folder_as_encode_does(scene_file, tmp_path):
    archive = tmp_path / "new" / "dir" / "a.vt4da"
    assert cli.main(["pack", str(scene_file), "-o", str(archive), "-q"]) == 0
    assert archive.is_file()
