"""The evaluation command end to end on random tiny models (2 scenes), metrics and the summary maths."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
import torch

from vt4dcodec.model import VideoTok4D, get_config
from vt4dcodec.eval.command import main
from vt4dcodec.eval.metrics import video_metrics
from vt4dcodec.eval.protocol import EvalSettings
from vt4dcodec.eval.report import format_tables, summarize


def test_every_method_scores_every_view(evaluated):
    results, out = evaluated
    methods = ["ours", "ours_no_static", "ours_no_dynamic", "unified", "nearest_frame", "depth_warp", "mean_colour"]
    assert list(results["summary"]) == methods
    far = [r for r in results["rows"] if r["set"] == "far"]
    assert len(far) == 2 * 2 * len(methods)
    assert {(r["seed"], r["view"]) for r in far} == {(s, v) for s in (0, 1) for v in ("cam01", "cam02")}
    # the default evaluates every set: near has 2 targets, source 1 without the two trivial baselines, the
    # multi-camera sets 5 each without the two single-source baselines
    assert results["sets"] == ["far", "near", "source", "multi-held", "multi-enc"]
    assert len(results["rows"]) == (len(far) + 2 * 2 * len(methods) + 2 * 1 * (len(methods) - 2)
                                    + 2 * 2 * 5 * (len(methods) - 2))
    assert results["summary_by_set"]["far"] == results["summary"]
    for r in results["rows"]:
        assert 0.0 < r["psnr"] < 60.0 and -1.0 <= r["ssim"] <= 1.0
    assert results["settings"] == {**EvalSettings(scenes=2, views=2, steps=2).__dict__}
    assert (out / "eval.png").stat().st_size > 1000


def test_sizes_are_counted_like_tokens(evaluated):
    s = evaluated[0]["summary"]
    assert s["ours"]["floats"] == s["unified"]["floats"] == (64 + 32) * 32
    assert s["nearest_frame"]["floats"] == 8 * 64 * 64 * 3
    assert s["depth_warp"]["floats"] == 8 * 64 * 64 * 4
    assert s["mean_colour"]["floats"] == 3
    # int8 tokens plus header: more than one byte per float, far less than float32
    assert 3072 < s["ours"]["file_bytes"] < 4 * 3072
    assert s["nearest_frame"]["file_bytes"] is None
    assert 0.0 < s["depth_warp"]["hole_fraction"] < 1.0


def test_file_bytes_are_named_for_what_they_are_and_old_results_still_read():
    """Regression: the mean file size was stored as "bytes_int8_vt4d" at every encoding (q9 files included)."""
    from vt4dcodec.eval.report import file_bytes

    assert file_bytes({"file_bytes": 5075.0}) == 5075.0
    assert file_bytes({"bytes_int8_vt4d": 6700.5}) == 6700.5  # a results file written before the rename
    assert file_bytes({"file_bytes": None}) is None and file_bytes({}) is None


def test_token_masking_changes_the_render(evaluated):
    rows = evaluated[0]["rows"]
    psnr = {(r["method"], r["seed"], r["view"]): r["psnr"] for r in rows}
    for masked in ("ours_no_static", "ours_no_dynamic"):
        assert any(psnr[(masked, s, v)] != psnr[("ours", s, v)] for s in (0, 1) for v in ("cam01", "cam02"))


def test_merge_replaces_only_the_given_methods(evaluated, models, tmp_path):
    results, out = evaluated
    path = tmp_path / "eval.json"
    path.write_text(json.dumps(results))
    args = ["--model", models[0], "--scenes", "2", "--views", "2", "--steps", "2", "--out", str(path),
            "--methods", "nearest_frame", "--merge", "--no-progress"]
    assert main(args) == 0
    merged = json.loads(path.read_text())
    assert merged["summary"]["ours"] == results["summary"]["ours"]
    assert merged["summary"]["nearest_frame"]["psnr"] == results["summary"]["nearest_frame"]["psnr"]
    assert len(merged["rows"]) == len(results["rows"])
    # a different protocol is refused (exit code 1, file untouched)
    assert main(args[:4] + ["--views", "1"] + args[6:]) == 1
    assert json.loads(path.read_text()) == merged
    assert "| Unified tokens (ablation) |" in format_tables(merged)


def test_table5_ablations_merge_into_a_results_file_paired_with_ours(evaluated, models, tmp_path, capsys):
    """--no-motion-isolation / --fixed-grid add Table 5's ablations to an existing evaluation (same scenes,
    paired with ours per view), and a model that is not that ablation is refused naming the flag."""
    from eval_models import random_model as _random_model

    results, _ = evaluated
    path = tmp_path / "eval.json"
    path.write_text(json.dumps(results))
    no_motion = _random_model(tmp_path / "nomotion", 2, motion_isolation=False)
    fixed = _random_model(tmp_path / "fixed", 3, track_attention=False)
    common = ["--model", models[0], "--scenes", "2", "--views", "2", "--steps", "2", "--out", str(path), "--merge",
              "--no-progress", "--sets", "far"]
    assert main([*common, "--no-motion-isolation", no_motion, "--fixed-grid", fixed,
                 "--methods", "no_motion_isolation,fixed_grid"]) == 0
    merged = json.loads(path.read_text())
    far = merged["summary_by_set"]["far"]
    for method in ("no_motion_isolation", "fixed_grid"):
        assert far[method]["views"] == far["ours"]["views"] == 4
        assert far[method]["ours_minus_this_psnr"]["n"] == 4
        assert far[method]["floats"] == far["ours"]["floats"]
    assert far["ours"] == results["summary_by_set"]["far"]["ours"]
    tables = format_tables(merged)
    assert "| w/o motion isolation (ablation) |" in tables and "| Fixed-grid temporal attention (ablation) |" in tables
    capsys.readouterr()
    assert main([*common, "--fixed-grid", no_motion, "--methods", "fixed_grid"]) == 1
    assert "--fixed-grid" in capsys.readouterr().err
    assert json.loads(path.read_text()) == merged


def test_video_metrics_of_identical_and_masked_videos():
    rng = np.random.default_rng(0)
    video = rng.integers(0, 256, (2, 16, 16, 3), dtype=np.uint8)
    empty = np.zeros((2, 16, 16), bool)
    m = video_metrics(video, video, empty)
    assert math.isinf(m["psnr"]) and m["ssim"] == pytest.approx(1.0, abs=1e-4)
    assert math.isnan(m["psnr_dynamic"]) and math.isinf(m["psnr_static"])
    noisy = np.clip(video.astype(int) + 10, 0, 255).astype(np.uint8)
    mask = empty.copy()
    mask[:, :4] = True
    m = video_metrics(noisy, video, mask)
    assert 20 < m["psnr"] < 40 and m["psnr_dynamic"] == pytest.approx(m["psnr_dynamic"])


def test_summary_pairs_views_with_ours():
    def row(method, seed, value):
        return {"method": method, "seed": seed, "view": "cam01", "psnr": value, "ssim": 0.5,
                "psnr_dynamic": value - 1, "psnr_static": value + 1, "bytes": None}

    rows = [row("ours", 0, 20.0), row("ours", 1, 22.0), row("nearest_frame", 0, 18.0), row("nearest_frame", 1, 23.0)]
    s = summarize(rows, {"ours": 3072, "nearest_frame": 98304})
    assert s["ours"]["psnr"]["mean"] == 21.0 and s["ours"]["psnr"]["n"] == 2
    assert s["ours"]["psnr"]["se"] == pytest.approx(1.0)
    paired = s["nearest_frame"]["ours_minus_this_psnr"]
    assert paired["mean"] == pytest.approx(0.5) and paired["ours_wins"] == 0.5 and paired["n"] == 2


def test_real_footage_path_on_a_capture_without_depth(models):
    from vt4dcodec.capture.capture import Capture
    from vt4dcodec.model import from_pretrained
    from vt4dcodec.eval.real_footage import best_overlap_pair, evaluate_real
    from vt4dcodec.synth import SynthConfig, generate_scene

    cap = generate_scene(5, split="test", config=SynthConfig(num_cameras=3)).capture
    cap = Capture(cameras=cap.cameras, frames=cap.frames, fps=cap.fps, capture_id=cap.capture_id)  # no depth
    source, target, angle = best_overlap_pair(cap)
    axes = {n: cap.cameras[n].w2c[0, 2, :3] for n in cap.camera_names}
    others = [np.degrees(np.arccos(np.clip(axes[a] @ axes[b], -1, 1))) for a, b in
              (("cam00", "cam01"), ("cam00", "cam02"), ("cam01", "cam02"))]
    assert source != target and angle == pytest.approx(min(others), abs=1e-6)
    rows, clips = evaluate_real(cap, from_pretrained(models[0]), source, target, steps=1)
    assert [r["method"] for r in rows] == ["ours", "nearest_frame", "depth_warp", "mean_colour"]
    assert len(clips) == 1
    assert rows[0]["bytes"] > 3072 and all(0 < r["psnr"] < 60 for r in rows)
    assert clips[0]["ours"].shape == clips[0]["truth"].shape == (8, 64, 64, 3)


def test_a_training_run_directory_evaluates_its_latest_checkpoint(tmp_path):
    from vt4dcodec import codec
    from vt4dcodec.eval.command import load_run_checkpoint, resolve_model
    from vt4dcodec.eval.protocol import EvaluationError
    from vt4dcodec.model.train.common import save_checkpoint

    torch.manual_seed(3)
    cfg = get_config("tiny", patch_size=4)
    net = VideoTok4D(cfg)
    opt = torch.optim.SGD(net.parameters(), lr=0.1)
    with pytest.raises(EvaluationError):  # no complete checkpoint yet
        load_run_checkpoint(tmp_path)
    save_checkpoint(tmp_path / "checkpoint", net, opt, 40, {"config": cfg.to_dict(),
                                                           "args": {"model_id": "m", "model_version": "1"}})
    loaded = resolve_model(str(tmp_path))
    assert loaded.training_step == 40 and codec.model_fingerprint(loaded).model_version == "1+step40"
    for (k, a), b in zip(net.state_dict().items(), loaded.state_dict().values()):
        assert torch.equal(a, b), k


@pytest.mark.parametrize("args, steps", [({"tau_one": 1.0}, 1), ({"tau_one": 0.5}, 8), ({}, 8)])
def test_a_run_checkpoint_decodes_with_the_steps_its_renderer_was_trained_for(tmp_path, args, steps):
    """Regression: a checkpoint records no decode_steps, so evaluations of the from-scratch runs (trained at
    tau = 1 only, --tau-one 1) rendered with 8 Euler steps, asking the renderer about flow times it never
    saw, while the shipped model decodes in one; their curve mixed the two."""
    from vt4dcodec.eval.command import resolve_model
    from vt4dcodec.model.train.common import model_from_run, save_checkpoint

    cfg = get_config("tiny", patch_size=4)
    net = VideoTok4D(cfg)
    save_checkpoint(tmp_path / "checkpoint", net, torch.optim.SGD(net.parameters(), lr=0.1), 5,
                    {"config": cfg.to_dict(), "args": {"model_id": "m", "model_version": "1", **args}})
    assert resolve_model(str(tmp_path)).decode_steps == steps
    assert model_from_run(tmp_path)[0].decode_steps == steps


_json_scalars = st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(allow_nan=False) | st.text(max_size=8)


@given(st.dictionaries(st.text(max_size=6).filter(lambda k: k != "rows"), _json_scalars, max_size=4),
       st.none() | st.lists(st.dictionaries(st.text(max_size=4), _json_scalars, max_size=3), max_size=4))
def test_results_json_round_trips(head, rows):
    import tempfile

    from vt4dcodec.eval.report import write_json

    data = dict(head) if rows is None else {**head, "rows": rows}
    with tempfile.TemporaryDirectory() as d:
        path = write_json(f"{d}/r.json", data)
        assert json.loads(path.read_text()) == data
