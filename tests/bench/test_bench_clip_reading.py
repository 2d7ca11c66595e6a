"""bench/bench_clip_reading.py: the synthetic capture it makes is a valid capture of the size asked for, and
one case runs in a child process and reports what the results table needs."""

from __future__ import annotations


import numpy as np

BENCH = "bench_clip_reading"  # the script under test (conftest.py loads it)



def test_small_capture_and_one_clip_case(bench, tmp_path):
    from vt4dcodec.capture.io import read_capture
    from vt4dcodec.capture.probe import check_capture

    info = bench.make_capture(tmp_path / "cap", cameras=2, frames=12, width=96, height=64, fps=60.0, gop=4)
    assert info["frames"] == 12 and info["bytes"] > 0
    assert all(not r["problems"] for r in check_capture(tmp_path / "cap"))
    clip = read_capture(tmp_path / "cap", cameras=["cam01"], start=4, num_frames=8)
    assert clip.frames["cam01"].shape == (8, 64, 96, 3)
    r = bench.run_case("api_clip", tmp_path / "cap", 4, "vt4d-tiny", tmp_path)
    assert r["case"] == "api_clip" and r["start"] == 4
    assert 0 < r["encode_s"] < r["wall_s"] and r["peak_rss_mb"] >= r["peak_private_mb"] > 0
    assert r["runtime"] == "OnnxEncoder" and not r["torch_imported"]  # the default runtime needs no torch
    tokens = np.load(tmp_path / "api_clip_4.npz")
    assert tokens["static"].ndim == 2 and np.isfinite(tokens["static"]).all()
    t = bench.run_case("api_clip_torch", tmp_path / "cap", 4, "vt4d-tiny", tmp_path)
    assert t["runtime"] == "VideoTok4D" and t["torch_imported"]
    torch_tokens = np.load(tmp_path / "api_clip_torch_4.npz")
    assert np.abs(torch_tokens["static"] - tokens["static"]).max() < 1e-5
