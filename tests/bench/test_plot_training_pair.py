"""bench/plot_training_pair.py: evaluations at checkpoints become one curve only when they share a protocol;
the points, differences and training-log means it writes are the ones it was given."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

BENCH = "plot_training_pair"  # the script under test (conftest.py loads it)


def _metric(mean, se=0.5):
    return {"mean": mean, "se": se, "n": 8}


def _eval(step, source, held, *, scenes=8, decode_steps=1, unified_step=None):
    """An evaluation JSON shaped like python -m vt4dcodec.eval's, with ours and unified on two sets."""
    def summary(value):
        return {"ours": {"psnr": _metric(value), "ssim": _metric(0.6, 0.02), "psnr_dynamic": _metric(value - 4)},
                "unified": {"psnr": _metric(value - 0.2), "ssim": _metric(0.59, 0.02),
                            "psnr_dynamic": _metric(value - 4.1),
                            "ours_minus_this_psnr": {"mean": 0.2, "se": 0.05, "ours_wins": 0.9, "n": 8}}}
    return {"settings": {"scenes": scenes, "first_seed": 0, "views": 3, "num_cameras": 4, "frames": 8,
                         "image_size": 64},
            "summary_by_set": {"multi-held": summary(held), "source": summary(source)},
            "models": {"main": {"training_step": step, "steps": decode_steps, "fingerprint": f"m@1.0.0+step{step} (x)"},
                       "unified": {"training_step": unified_step or step, "steps": decode_steps}},
            "token_health": {"models": {"main": {"static_spread": 0.8, "dynamic_spread": 0.6,
                                                 "dynamic_saturation": 0.1, "swap_drop_db": 9.0}}}}


def _write(tmp_path, name, data):
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


def test_points_sorted_by_step_with_sets_in_protocol_order(bench, tmp_path):
    late = _write(tmp_path, "e2000.json", _eval(2000, 25.0, 22.0, unified_step=2100))
    early = _write(tmp_path, "e500.json", _eval(500, 22.3, 20.2))
    result = bench.build([late, early], None, [])
    assert [p["step"] for p in result["points"]] == [500, 2000]
    assert result["points"][1]["step_unified"] == 2100
    assert result["protocol"]["sets"] == ["source", "multi-held"]
    assert result["points"][0]["sets"]["source"]["ours"]["psnr"]["mean"] == 22.3
    assert result["points"][1]["sets"]["multi-held"]["unified"]["ours_minus_this_psnr"]["mean"] == 0.2
    assert result["points"][1]["token_health"]["main"]["swap_drop_db"] == 9.0


@pytest.mark.parametrize("change", [{"scenes": 50}, {"decode_steps": 8}])
def test_refuses_evaluations_of_another_protocol(bench, tmp_path, change):
    a = _write(tmp_path, "a.json", _eval(500, 22.0, 20.0))
    b = _write(tmp_path, "b.json", _eval(1000, 23.0, 21.0, **change))
    with pytest.raises(bench.CurveError, match="another protocol"):
        bench.build([a, b], None, [])
    assert bench.main(["--eval", str(a), "--eval", str(b), "--out", str(tmp_path / "c.json")]) == 2
    assert not (tmp_path / "c.json").exists()


def test_refuses_a_reference_on_other_scenes_and_files_that_are_no_evaluation(bench, tmp_path):
    a = _write(tmp_path, "a.json", _eval(500, 22.0, 20.0))
    ref = _write(tmp_path, "ref.json", _eval(None, 28.0, 23.0, scenes=50))
    with pytest.raises(bench.CurveError, match="other scenes"):
        bench.build([a], ref, [])
    junk = _write(tmp_path, "junk.json", {"rows": []})
    with pytest.raises(bench.CurveError, match="not an evaluation JSON"):
        bench.build([junk], None, [])
    with pytest.raises(bench.CurveError, match="at least one"):
        bench.build([], None, [])


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(0.0, 2.0), min_size=1, max_size=60), st.integers(1, 7))
def test_training_curve_means_each_window(bench, tmp_path_factory, values, every):
    records = [{"step": every * (i + 1), "x0": v, "loss": 1.0} for i, v in enumerate(values)]
    log = tmp_path_factory.mktemp("run") / "log.jsonl"
    log.write_text("\n".join(json.dumps(r) for r in records) + "\n" + json.dumps({"event": "resume"}) + "\n")
    curve = bench.training_curve(log, window=10)
    for end, mean in curve:
        chunk = [r["x0"] for r in records if end - 10 < r["step"] <= end]
        assert mean == pytest.approx(sum(chunk) / len(chunk))
    last = records[-1]["step"]
    assert [end for end, _ in curve] == [end for end in range(10, last + 1, 10)
                                         if any(end - 10 < r["step"] <= end for r in records)]


def test_main_writes_the_curve_and_the_figure(bench, tmp_path):
    evals = [_write(tmp_path, f"e{s}.json", _eval(s, 20 + s / 500, 19 + s / 1000)) for s in (500, 1000, 2000)]
    ref = _write(tmp_path, "ref.json", _eval(None, 28.2, 22.96))
    log = tmp_path / "run" / "log.jsonl"
    log.parent.mkdir()
    log.write_text("".join(json.dumps({"step": s, "x0": 1.0 / s}) + "\n" for s in range(25, 2001, 25)))
    out, png = tmp_path / "curve.json", tmp_path / "curve.png"
    args = [a for e in evals for a in ("--eval", str(e))] + ["--reference", str(ref), "--log", str(log),
                                                             "--out", str(out), "--figure", str(png)]
    assert bench.main(args) == 0
    result = json.loads(out.read_text())
    assert [p["step"] for p in result["points"]] == [500, 1000, 2000]
    assert result["reference"]["sets"]["source"]["ours"]["psnr"]["mean"] == 28.2
    assert len(result["training_x0"][str(log)]) == 8  # 2,000 steps in windows of 250
    assert result["command"].startswith("python bench/plot_training_pair.py --eval")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_extend_adds_points_to_an_earlier_curve_and_keeps_its_reference(bench, tmp_path):
    """Evaluation files of earlier sessions do not travel: the curve they made is the input."""
    early = [_write(tmp_path, f"e{s}.json", _eval(s, 20 + s / 500, 19 + s / 1000)) for s in (500, 2000)]
    ref = _write(tmp_path, "ref.json", _eval(None, 28.2, 22.96))
    curve = tmp_path / "curve.json"
    assert bench.main([*("--eval", str(early[0]), "--eval", str(early[1])), "--reference", str(ref),
                       "--out", str(curve)]) == 0
    again = _write(tmp_path, "e2000b.json", _eval(2000, 25.5, 21.5))  # a re-evaluation of step 2,000
    later = _write(tmp_path, "e4000.json", _eval(4000, 26.2, 22.5, unified_step=4000))
    result = bench.build([later, again], None, [], extend=curve)
    assert [p["step"] for p in result["points"]] == [500, 2000, 4000]
    assert result["points"][1]["sets"]["source"]["ours"]["psnr"]["mean"] == 25.5
    assert result["points"][0]["sets"]["source"]["ours"]["psnr"]["mean"] == 21.0
    assert result["reference"]["sets"]["source"]["ours"]["psnr"]["mean"] == 28.2
    assert result["evaluations"] == [str(early[0]), str(early[1]), str(later), str(again)]
    assert bench.build([], None, [], extend=curve)["points"] == json.loads(curve.read_text())["points"]


def test_extend_refuses_another_protocol_and_files_that_are_no_curve(bench, tmp_path):
    curve = tmp_path / "curve.json"
    assert bench.main(["--eval", str(_write(tmp_path, "a.json", _eval(500, 22.0, 20.0))), "--out", str(curve)]) == 0
    other = _write(tmp_path, "b.json", _eval(1000, 23.0, 21.0, scenes=50))
    with pytest.raises(bench.CurveError, match="another protocol than the curve"):
        bench.build([other], None, [], extend=curve)
    evaluation = _write(tmp_path, "c.json", _eval(1000, 23.0, 21.0))  # an evaluation, not a curve
    with pytest.raises(bench.CurveError, match="not a curve JSON"):
        bench.build([], None, [], extend=evaluation)
    out = tmp_path / "d.json"
    assert bench.main(["--extend", str(tmp_path / "missing.json"), "--out", str(out)]) == 2
    assert not out.exists()
