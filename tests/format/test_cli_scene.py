"""`vt4d info` and `vt4d verify` on scenes, damaged files and (unsupported or supported) archives."""

from __future__ import annotations

import json

from format_strategies import rig_scene, simple_scene
from vt4dcodec.cli import main
from vt4dcodec.format import save


def test_info_text_and_json(tmp_path, capsys):
    path = tmp_path / "s.vt4d"
    save(simple_scene(metadata={"who": "me"}), path)
    assert main(["info", str(path)]) == 0
    text = capsys.readouterr().out
    assert "Z_s 4x2" in text and "test-model" in text and "ZSTA" in text
    assert main(["info", "--json", str(path)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["static_shape"] == [4, 2] and summary["metadata_keys"] == ["who"]


def test_info_and_verify_read_both_layouts(tmp_path, capsys):
    """Format 1.3 (the default compact container) and the 1.2 layout: `vt4d info --json` says the version
    and what is not tokens (file bytes minus token sections), `vt4d verify` passes both and names a
    damaged compressed header."""
    scene = simple_scene(metadata={"who": "me"})
    for header, version in (("compact", "1.3"), ("legacy", "1.2")):
        path = tmp_path / f"{header}.vt4d"
        save(scene, path, header=header)
        assert main(["info", "--json", str(path)]) == 0
        summary = json.loads(capsys.readouterr().out)
        assert summary["format_version"] == version and summary["compact_container"] == (header == "compact")
        assert summary["non_token_bytes"] == summary["bytes"] - summary["token_bytes"]
        assert summary["header_bytes"] < summary["non_token_bytes"] and summary["metadata_keys"] == ["who"]
        assert main(["info", str(path)]) == 0
        assert ("compressed header" in capsys.readouterr().out) == (header == "compact")
        assert main(["verify", str(path)]) == 0
        assert "OK" in capsys.readouterr().out
    data = bytearray((tmp_path / "compact.vt4d").read_bytes())
    data[70] ^= 0x01  # inside the zstd frame of the header
    (tmp_path / "bad.vt4d").write_bytes(bytes(data))
    capsys.readouterr()
    assert main(["verify", "--json", str(tmp_path / "bad.vt4d")]) == 1
    assert json.loads(capsys.readouterr().out)[0]["error"] == "ChecksumError"


def test_info_counts_the_extra_encoded_cameras(tmp_path, capsys):
    """Format 1.4: `vt4d info` says how many further encoded cameras the file holds (0 for a single camera)."""
    for count, name in ((0, "one.vt4d"), (1, "two.vt4d"), (3, "four.vt4d")):
        save(rig_scene(count), tmp_path / name)
        assert main(["info", "--json", str(tmp_path / name)]) == 0
        summary = json.loads(capsys.readouterr().out)
        assert summary["extra_cameras"] == count and summary["format_version"] == ("1.4" if count else "1.3")
        assert main(["info", str(tmp_path / name)]) == 0
        cams = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("cameras"))
        assert cams.endswith({0: "quaternion", 1: ", 1 extra encoded camera", 3: ", 3 extra encoded cameras"}[count])


def test_verify_exit_codes(tmp_path, capsys):
    good, bad = tmp_path / "good.vt4d", tmp_path / "bad.vt4d"
    save(simple_scene(), good)
    data = bytearray(good.read_bytes())
    data[-1] ^= 0xFF
    bad.write_bytes(bytes(data))
    assert main(["verify", str(good)]) == 0
    assert main(["verify", str(good), str(bad)]) == 1
    assert main(["verify", str(tmp_path / "missing.vt4d")]) == 3
    capsys.readouterr()
    assert main(["verify", "--json", str(good), str(bad)]) == 1
    results = json.loads(capsys.readouterr().out)
    assert [r["ok"] for r in results] == [True, False]
    assert results[1]["error"] == "ChecksumError"


def test_info_on_a_damaged_file_is_exit_code_1(tmp_path, capsys):
    path = tmp_path / "x.vt4d"
    path.write_bytes(b"hello world, not a scene")
    assert main(["info", str(path)]) == 1
    assert "not a .vt4d scene" in capsys.readouterr().err


def test_verify_routes_archive_signatures_to_the_archive_module(tmp_path, capsys):
    path = tmp_path / "a.vt4d"
    try:
        from vt4dcodec.archive import ARCHIVE_MAGIC, verify_archive  # noqa: F401
    except ImportError:
        path.write_bytes(b"\x89VT4A\r\n\x1a\n" + b"\0" * 64)
        assert main(["verify", str(path)]) == 1
        assert "archives not supported by this build" in capsys.readouterr().err
        return
    path.write_bytes(ARCHIVE_MAGIC + b"\0" * 64)  # a broken archive: the archive verifier must reject it
    assert main(["verify", "--json", str(path)]) == 1
    result = json.loads(capsys.readouterr().out)[0]
    assert result["kind"] == "archive" and not result["ok"]


def test_info_and_verify_of_a_learned_file_need_no_model(capsys):
    """Format 1.6: `vt4d info` says the quality level and the bits per pixel of a learned-rans file, and
    `vt4d verify` checks it, without the model whose tables code its tokens (the spec vector's test model)."""
    from format_strategies import REPO

    path = REPO / "spec" / "vectors" / "valid" / "learned_rans_one_camera.vt4d"
    assert main(["info", "--json", str(path)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["encoding"] == "learned-rans" and summary["quality"] == 1
    assert summary["bits_per_pixel"] == round(8 * path.stat().st_size / (2 * 64 * 48), 5)
    assert main(["info", str(path)]) == 0
    text = capsys.readouterr().out
    assert "at quality 1" in text and "bits per pixel" in text
    assert main(["verify", str(path)]) == 0


def test_info_names_the_joint_extra_cameras_layout(capsys):
    """Format 1.6, required flag bit 9: `vt4d info` says the extra cameras are in the joint layout (I.5.5) and
    counts them from the section's count byte; `vt4d verify` decodes them."""
    from format_strategies import REPO

    vectors = REPO / "spec" / "vectors" / "valid"
    for name, joint in (("learned_rans_joint_cameras", True), ("learned_rans_camera_dictionary", False)):
        assert main(["info", "--json", str(vectors / f"{name}.vt4d")]) == 0
        summary = json.loads(capsys.readouterr().out)
        assert summary["joint_extra_cameras"] is joint and summary["extra_cameras"] == 2
        assert main(["info", str(vectors / f"{name}.vt4d")]) == 0
        cams = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("cameras"))
        assert cams.endswith("2 extra encoded cameras (joint layout)" if joint else "2 extra encoded cameras")
        assert main(["verify", str(vectors / f"{name}.vt4d")]) == 0
        capsys.readouterr()


def test_info_names_adaptive_rows(capsys):
    """Format 1.6, required flag bit 10: `vt4d info` says the token streams use adaptive rows (I.6.2)."""
    from format_strategies import REPO

    vectors = REPO / "spec" / "vectors" / "valid"
    for name, adaptive in (("learned_rans_adaptive", True), ("learned_rans_one_camera", False)):
        assert main(["info", "--json", str(vectors / f"{name}.vt4d")]) == 0
        assert json.loads(capsys.readouterr().out)["adaptive_rows"] is adaptive
        assert main(["info", str(vectors / f"{name}.vt4d")]) == 0
        tokens = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("tokens"))
        assert tokens.endswith("at quality 1 (adaptive rows)" if adaptive else "at quality 1")
