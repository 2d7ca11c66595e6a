"""`vt4d decode -t camera:NAME --capture DIR` and render_many(["camera:NAME"], capture=...)."""

from cli_helpers import vt4d, vt4d_json

import numpy as np


def test_decode_camera_target_from_cli_and_api(small_model, capture_dir, tmp_path):
    from vt4dcodec.capture.io import read_manifest
    from vt4dcodec.codec import SceneDecoder

    names = [e.name for e in read_manifest(capture_dir).cameras]
    assert vt4d("encode", capture_dir, "--model", small_model, "-o", tmp_path / "s.vt4d", "-q").returncode == 0
    result = vt4d_json("decode", tmp_path / "s.vt4d", "--model", small_model, "--steps", "1", "-o", tmp_path / "v",
                       "--capture", capture_dir, "-t", f"camera:{names[1]}")
    assert [o["trajectory"] for o in result["outputs"]] == [f"camera:{names[1]}"]
    r = vt4d("decode", tmp_path / "s.vt4d", "--model", small_model, "-o", tmp_path / "w", "-t", f"camera:{names[1]}")
    assert r.returncode == 1 and "pass --capture DIR" in r.stderr, r.stderr
    r = vt4d("decode", tmp_path / "s.vt4d", "--model", small_model, "-o", tmp_path / "w", "-t", "camera:")
    assert r.returncode == 1 and "name of a capture camera" in r.stderr, r.stderr

    decoder = SceneDecoder.open(tmp_path / "s.vt4d", model=small_model)
    by_name, by_traj = decoder.render_many([f"camera:{names[1]}", read_manifest(capture_dir).camera(names[1]).trajectory],
                                           steps=1, capture=capture_dir)
    np.testing.assert_array_equal(by_name, by_traj)
