"""A file a command writes over keeps its permission bits (a private 0600 archive stays private)."""

from __future__ import annotations

import os
import stat

from cli_helpers import StandInCodec

import vt4dcodec.cli as cli
from vt4dcodec import ArchiveWriter


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def test_compact_keeps_the_archives_permission_bits(scene_file, tmp_path):
    archive = tmp_path / "a.vt4da"
    with ArchiveWriter(archive) as w:
        w.append("a", scene_file.read_bytes())
        w.commit()
        w.append("a", scene_file.read_bytes(), replace=True)  # a superseded record for compact to drop
    os.chmod(archive, 0o600)
    assert cli.main(["compact", str(archive), "-q"]) == 0
    assert _mode(archive) == 0o600


def test_encode_over_an_existing_file_keeps_its_permission_bits(small_captures, tmp_path, monkeypatch):
    out = tmp_path / "s.vt4d"
    StandInCodec(monkeypatch)
    assert cli.main(["encode", str(small_captures / "cap-a"), "-o", str(out), "-q"]) == 0
    os.chmod(out, 0o600)
    assert cli.main(["encode", str(small_captures / "cap-a"), "-o", str(out), "-q"]) == 0
    assert _mode(out) == 0o600
    os.chmod(out, 0o640)
    assert cli.main(["encode", str(small_captures / "cap-a"), "-o", str(out), "-q"]) == 0
    assert _mode(out) == 0o640


def test_extract_over_an_existing_file_keeps_its_permission_bits(scene_file, tmp_path):
    archive, out = tmp_path / "a.vt4da", tmp_path / "out"
    with ArchiveWriter(archive) as w:
        w.append("a", scene_file.read_bytes())
    assert cli.main(["extract", str(archive), "-o", str(out), "-q"]) == 0
    os.chmod(out / "a.vt4d", 0o600)
    assert cli.main(["extract", str(archive), "-o", str(out), "-q", "-y"]) == 0
    assert _mode(out / "a.vt4d") == 0o600
