"""bench/bench_render_batch.py: one small run writes what docs/benchmarks/render_batch.md reads, and the
batched views are the single renders' views."""

from __future__ import annotations

import json

import pytest

BENCH = "bench_render_batch"  # the script under test (conftest.py loads it)


def test_a_small_run_writes_both_sides_and_their_agreement(bench, tmp_path):
    from vt4dcodec import codec

    before = codec.RENDER_BATCH
    out = tmp_path / "render_batch.json"
    try:
        assert bench.main(["--views", "3", "--repeats", "1", "--threads", "1", "--stages", "--out", str(out)]) == 0
    finally:
        codec.RENDER_BATCH = before
    result = json.loads(out.read_text())
    (run,) = result["runs"]
    assert result["views"] == 3 and run["threads"] == 1
    for key in ("single_wall_s_per_view", "batch_wall_s_per_view", "single_cpu_s_per_view", "batch_cpu_s_per_view"):
        assert run[key] > 0, key
    assert run["speedup_wall"] == run["single_wall_s_per_view"] / run["batch_wall_s_per_view"]
    assert run["max_grey_level_difference"] <= 1 and run["max_float_difference"] <= 1e-5
    assert set(run["stages_batch_n"]) == {"sampler_cpu_s_per_view", "decoder_cpu_s_per_view"}


def test_the_onnx_runtime_is_measured_the_same_way(bench, tmp_path):
    pytest.importorskip("onnxruntime")
    from vt4dcodec import codec

    before = codec.RENDER_BATCH
    out = tmp_path / "render_batch_onnx.json"
    try:
        assert bench.main(["--runtime", "onnx", "--views", "2", "--repeats", "1", "--out", str(out)]) == 0
    finally:
        codec.RENDER_BATCH = before
    result = json.loads(out.read_text())
    (run,) = result["runs"]
    assert result["runtime"] == "onnx" and run["threads"] is None and run["max_float_difference"] is None
    assert run["batch_cpu_s_per_view"] > 0 and run["max_grey_level_difference"] <= 1
