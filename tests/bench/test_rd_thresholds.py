"""bench/rd_thresholds.py reports a study's levels against the codec's thresholds, from the results file."""

from __future__ import annotations

import json
from pathlib import Path

BENCH = "rd_thresholds"  # the script under test (conftest.py loads it)
RESULTS = Path(__file__).resolve().parents[2] / "bench" / "results" / "codecs_rd.json"


def test_report_of_a_committed_study(bench, tmp_path):
    result = json.loads(RESULTS.read_text())
    text = bench.report(result)
    levels = [e for e in result["encodings"] if e.startswith("q")]
    for enc in result["encodings"]:
        assert f"| {enc} |" in text
    own = [result["datasets"]["synthetic"]["summary"]["single/captured"]["vt4d"][e]["psnr"] for e in levels]
    assert f"{max(own) - min(own):.2f} dB" in text
    assert "whole capture <= 1.0x" in text and "caliscope <= 2.0x" in text
    out = tmp_path / "r.md"
    assert bench.main([str(RESULTS), "--out", str(out)]) == 0 and out.read_text() == text
