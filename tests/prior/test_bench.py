"""bench/bench_prior.py runs end to end on the small fixtures and reports what it claims."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

BENCH = Path(__file__).resolve().parents[2] / "bench" / "bench_prior.py"


def test_bench_prior_reports_quality_of_every_method_and_the_nine_view_timing(shards, trained_prior, tokenizer_dir,
                                                                               monkeypatch, tmp_path):
    monkeypatch.setenv("VT4D_MODEL_PATH", str(tokenizer_dir.parent))
    spec = importlib.util.spec_from_file_location("bench_prior", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    results, figure = tmp_path / "prior.json", tmp_path / "co4dgen.png"
    assert bench.main(["--shards", str(shards), "--prior", str(trained_prior / "prior"), "--events", "1",
                       "--prior-steps", "1", "--render-steps", "1", "--repeats", "1", "--results", str(results),
                       "--figure", str(figure)]) == 0
    out = json.loads(results.read_text())
    assert set(out["quality"]) == set(bench.METHODS)
    assert set(out["quality"]["co4dgen"]) == {"anchor", "conditioning", "other", "all"}
    assert out["quality"]["co4dgen"]["all"]["videos"] == 3  # every camera of the one event
    t = out["timing"]
    assert len(t["views"]) == 9 and t["speedup_cpu"] > 0 and t["nine_independent_samples_s"]["cpu"] > 0
    assert out["tokenizer"]["model_id"] == "tok-test" and figure.stat().st_size > 1000
