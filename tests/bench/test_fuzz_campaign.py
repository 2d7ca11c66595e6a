"""The fuzz campaign (bench/fuzz_campaign.py): a short run of the default CI finds no crash, numeric warning,
hang or silent wrong read; its mutators change their seeds; its oracle catches a reader that reads wrong."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

BENCH = "fuzz_campaign"


def test_a_short_campaign_finds_nothing(bench, tmp_path):
    # run as a user runs it, in a fresh interpreter: no other test's global state (warning filters, table
    # resolvers, patched modules) reaches the readers, and the campaign's own does not reach other tests
    out = tmp_path / "fuzz.json"
    run = subprocess.run([sys.executable, str(bench.ROOT / "bench" / "fuzz_campaign.py"), "--inputs", "3000",
                          "--workers", "1", "--save", str(tmp_path / "findings"), "--out", str(out)],
                         capture_output=True, text=True, timeout=600)
    result = json.loads(out.read_text())
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    assert result["crashes"] == result["warnings"] == result["hangs"] == result["silent_wrong_reads"] == 0, \
        result["findings"][:5]
    counts = result["counts"]
    # both readers see accepted and rejected inputs, so mutations reach past the checksums into the decoders
    assert counts.get("scene:accepted", 0) > 30 and counts.get("scene:rejected", 0) > 1000
    assert counts.get("archive:rejected", 0) > 300
    assert result["by_mutator"].get("scene:structured", 0) > 500
    assert result["max_rss_mb"] < 300


def test_mutators_change_their_seed(bench):
    rng = np.random.default_rng(0)
    seeds = bench.load_seeds()
    data = seeds["scene"][0]
    for name, mutate in bench.SCENE_MUTATORS.items():
        outs = {mutate(rng, data, seeds["scene"]) for _ in range(20)}
        assert any(out != data for out in outs), name


def test_the_oracle_flags_tokens_the_independent_reader_reads_otherwise(bench):
    from vt4dcodec.format import load

    data = (bench.VECTORS / "valid" / "float32_raw_minimal.vt4d").read_bytes()
    scene = load(data)
    assert bench.scene_disagreement(data, scene) is None
    scene.static_tokens = scene.static_tokens + np.float32(1.0)  # a reader that returned other tokens
    assert bench.scene_disagreement(data, scene) == "static tokens differ"
