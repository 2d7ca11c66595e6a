"""Round trips: extract then pack gives back the same keys and bytes, also for keys with '/'; encode
-o into a folder that does not exist yet creates it; the library names a missing folder."""

from __future__ import annotations

import pytest
from cli_helpers import make_scene, vt4d, vt4d_json

from vt4dcodec import ArchiveWriter, dumps, open_archive, save

KEYS = ["cap-1/cam00/000000", "cap-1/cam00/000008", "cap-2/cam03/000000", "flat"]


def test_extract_then_pack_round_trips_keys_with_slashes(tmp_path):
    original = tmp_path / "a.vt4da"
    with ArchiveWriter(original) as w:
        for i, key in enumerate(KEYS):
            w.append(key, dumps(make_scene(kind="encoded", capture=f"cap-{i}")))
        w.commit()
    assert vt4d("extract", original, "-o", tmp_path / "out", "-q").returncode == 0
    assert (tmp_path / "out" / "cap-1" / "cam00" / "000008.vt4d").is_file()
    packed = vt4d_json("pack", tmp_path / "out", "-o", tmp_path / "b.vt4da")
    assert sorted(packed["packed"]) == sorted(KEYS)
    with open_archive(original) as a, open_archive(tmp_path / "b.vt4da") as b:
        assert b.keys() == a.keys()
        assert all(b.read_bytes(k) == a.read_bytes(k) for k in KEYS)


def test_pack_of_an_empty_folder_says_it_searched_recursively(tmp_path):
    (tmp_path / "empty" / "sub").mkdir(parents=True)
    r = vt4d("pack", tmp_path / "empty", "-o", tmp_path / "a.vt4da")
    assert r.returncode == 1 and "recursively" in r.stderr


def test_encode_into_a_new_folder_creates_it(small_model, capture_dir, tmp_path):
    target = tmp_path / "new" / "dir" / "x.vt4d"
    result = vt4d_json("encode", capture_dir, "--model", small_model, "-o", target)
    assert target.is_file() and result["scenes"][0]["file"] == str(target)


def test_save_into_a_missing_folder_names_the_folder_not_a_temp_file(tmp_path):
    target = tmp_path / "nope" / "x.vt4d"
    with pytest.raises(FileNotFoundError) as exc:
        save(make_scene(), target)
    assert str(tmp_path / "nope") in str(exc.value) and ".tmp-" not in str(exc.value)


def test_encode_fit_pad_is_recorded_and_a_bad_fit_names_the_flag(small_model, capture_dir, tmp_path):
    from vt4dcodec import load

    target = tmp_path / "pad.vt4d"
    vt4d_json("encode", capture_dir, "--model", small_model, "--fit", "pad", "-o", target)
    assert load(target).metadata["vt4d"]["fit"] == "pad"
    r = vt4d("encode", capture_dir, "--model", small_model, "--fit", "squash", "-o", target)
    assert r.returncode == 2 and "--fit" in r.stderr and "crop" in r.stderr
