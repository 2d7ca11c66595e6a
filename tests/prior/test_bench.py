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
                       "--figure", str(figure), "--samplers", "euler:1,heun:2"]) == 0
    out = json.loads(results.read_text())
    assert set(out["quality"]) == {*bench.METHODS, "co4dgen[euler:1]", "co4dgen[heun:2]"}
    assert set(out["gap_closed"]) == {"co4dgen", "co4dgen[euler:1]", "co4dgen[heun:2]"}
    # heun with one step is euler with one step: the headline and the euler:1 row are the same sample
    rows = {(r["method"], r["camera"]): r["psnr"] for r in out["per_video"]}
    assert all(rows[("co4dgen", k)] == rows[("co4dgen[euler:1]", k)] for k in range(3))
    assert set(out["quality"]["co4dgen"]) == {"anchor", "conditioning", "other", "all"}
    assert out["quality"]["co4dgen"]["all"]["videos"] == 3  # every camera of the one event
    t = out["timing"]
    assert len(t["views"]) == 9 and t["speedup_cpu"] > 0 and t["nine_independent_samples_s"]["cpu"] > 0
    assert out["tokenizer"]["model_id"] == "tok-test" and figure.stat().st_size > 1000


def test_bench_prior_refuses_bad_sampler_settings():
    import pytest

    spec = importlib.util.spec_from_file_location("bench_prior", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.parse_samplers("euler:1, heun:16,heun:8:2.5") == [("euler", 1, 1.0), ("heun", 16, 1.0),
                                                                    ("heun", 8, 2.5)]
    assert bench.sampler_name("heun", 8, 2.5) == "co4dgen[heun:8:2.5]" and bench.sampler_name("euler", 1, 1.0) == \
        "co4dgen[euler:1]"
    for bad in ("rk4:2", "euler:0", "heun", "euler:x", "heun:4:x", "heun:4:-1", "heun:4:2:1"):
        with pytest.raises(SystemExit, match="--samplers"):
            bench.parse_samplers(bad)


def test_bench_prior_loads_the_shipped_prior_with_the_shipped_tokenizer():
    """Regression: the benches refused the shipped pair. co4dgen-tiny records vt4d-tiny 1.0.0, the shipped
    vt4d-tiny 2.0.0 adds an entropy model to exactly its networks (same tokens), which ``vt4d generate`` accepts;
    ``load_models`` checked the fingerprint alone and stopped with ModelMismatchError."""
    import pytest

    from vt4dcodec.errors import ModelMismatchError

    spec = importlib.util.spec_from_file_location("bench_prior", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    prior, tokenizer, fp = bench.load_models("co4dgen-tiny", None)
    assert fp.model_id == "vt4d-tiny" and not prior.tokenizer_fingerprint.matches(fp)  # accepted by its networks
    assert tokenizer.network_digests is not None
    # a tokenizer with other networks is still refused
    tokenizer.network_digests = ("0" * 64, "0" * 64)
    with pytest.raises(ModelMismatchError):
        from vt4dcodec.model.prior import check_tokenizer

        check_tokenizer(prior, fp, networks=tokenizer.network_digests)
