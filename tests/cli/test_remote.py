"""Decode, info, verify and open_scene read scenes at URLs (fsspec) as the archive
commands read archives; a server without Range support gets that message."""

from __future__ import annotations

import shutil

import fsspec
from cli_helpers import serve_folder, vt4d, vt4d_json

import vt4dcodec
from vt4dcodec import ArchiveWriter


def test_scene_commands_and_open_scene_read_urls(tmp_path, scene_file, encoded_file, small_model):
    shutil.copy(encoded_file, tmp_path / "enc.vt4d")
    with serve_folder(tmp_path) as root:
        url = root + "s.vt4d"
        assert vt4d_json("info", url)["fingerprint"]["model_id"] == "m"
        assert vt4d_json("verify", url)[0]["ok"]
        assert vt4dcodec.open_scene(url).static_shape == (4, 8)
        assert vt4dcodec.load(url).provenance.source_capture_id == "cap-1"
        result = vt4d_json("decode", root + "enc.vt4d", "--model", small_model, "--steps", "1", "-o", tmp_path / "v")
        assert result["outputs"][0]["frames"] == 8
        r = vt4d("info", root + "missing.vt4d")
        assert r.returncode == 3, r.stderr


def test_memory_urls_and_storage_options(scene_file):
    fs = fsspec.filesystem("memory")
    fs.pipe("/vt4d-cli-test/s.vt4d", scene_file.read_bytes())
    try:
        assert vt4dcodec.open_scene("memory://vt4d-cli-test/s.vt4d").summary()["kind"] == "encoded"
        vt4dcodec.verify("memory://vt4d-cli-test/s.vt4d")
    finally:
        fs.rm("/vt4d-cli-test", recursive=True)


def test_an_archive_on_a_server_without_range_support_says_so(tmp_path, scene_file):
    with ArchiveWriter(tmp_path / "a.vt4da") as w:
        w.append("k", scene_file.read_bytes())
        w.commit()
    with serve_folder(tmp_path) as root:  # Python's file server ignores Range and sends the whole file
        for cmd in (["ls", root + "a.vt4da"], ["extract", root + "a.vt4da", "-o", tmp_path / "x"],
                    ["verify", root + "a.vt4da"]):
            r = vt4d(*cmd)
            assert r.returncode == 1 and "Range" in r.stderr + r.stdout, (cmd, r.stderr)
            assert "shrank" not in r.stderr
