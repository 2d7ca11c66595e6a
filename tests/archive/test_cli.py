"""vt4d pack / ls / extract / repair (and verify on an archive) end to end."""

import json
import os

from vt4dcodec.archive import ArchiveWriter, open_archive
from vt4dcodec.cli import main

from .helpers import scene_record


def _inputs(tmp_path, n=3):
    d = tmp_path / "in"
    d.mkdir()
    for i in range(n):
        (d / f"scene-{i}.vt4d").write_bytes(scene_record(i))
    return d


def test_pack_ls_extract_round_trip(tmp_path, capsys):
    d = _inputs(tmp_path)
    out = str(tmp_path / "a.vt4da")
    assert main(["pack", str(d), "-o", out, "-q"]) == 0
    assert main(["ls", out]) == 0
    text = capsys.readouterr().out
    assert "scene-1" in text and "16x8" in text and "3 scenes, generation 1" in text
    assert main(["ls", "--json", out]) == 0
    info = json.loads(capsys.readouterr().out)
    assert [e["key"] for e in info["entries"]] == ["scene-0", "scene-1", "scene-2"]
    assert main(["extract", out, "scene-2", "-o", str(tmp_path / "x"), "-q"]) == 0
    assert (tmp_path / "x" / "scene-2.vt4d").read_bytes() == scene_record(2)
    assert main(["extract", out, "scene-2", "-o", str(tmp_path / "x"), "-q"]) == 3  # exists, no --force
    assert main(["verify", out]) == 0


def test_pack_errors_and_append(tmp_path, capsys):
    d = _inputs(tmp_path, 2)
    out = str(tmp_path / "a.vt4da")
    assert main(["pack", str(d), "-o", out, "-q"]) == 0
    assert main(["pack", str(d), "-o", out, "-q"]) == 3  # exists
    assert main(["pack", str(d), "-o", out, "--append", "-q"]) == 1  # duplicate keys
    (tmp_path / "junk.vt4d").write_bytes(b"junk")
    assert main(["pack", str(tmp_path / "junk.vt4d"), "-o", out, "--append", "-q"]) == 1
    (tmp_path / "more").mkdir()
    (tmp_path / "more" / "extra.vt4d").write_bytes(scene_record(9))
    assert main(["pack", str(tmp_path / "more"), "-o", out, "--append", "-q"]) == 0
    with open_archive(out) as ar:
        assert ar.keys() == ["extra", "scene-0", "scene-1"]
    assert main(["extract", out, "missing", "-o", str(tmp_path / "y")]) == 1


def test_repair_command(tmp_path, capsys):
    out = tmp_path / "a.vt4da"
    w = ArchiveWriter(out)
    w.append("kept", scene_record(1))
    w.commit()
    w.append("recovered", scene_record(2))
    os.close(w._fd)  # simulate a crash after an append
    w._fd = None
    w._lock.release()
    with open(out, "ab") as f:
        f.write(b"V4AR torn")
    assert main(["verify", str(out)]) == 1  # uncommitted tail
    assert main(["repair", "--dry-run", "--json", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["recovered"] == ["recovered"] and report["discarded_bytes"] == 9
    assert main(["repair", str(out)]) == 0
    assert "recovered 1 scene written after it (recovered), cut 9 torn bytes" in capsys.readouterr().out
    assert main(["verify", str(out)]) == 0
    with open_archive(out) as ar:
        assert ar.read_bytes("recovered") == scene_record(2)
