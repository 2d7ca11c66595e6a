"""Target sets (far / near / source), sampler steps from the model, token health, old results files and
real footage on the source camera: random tiny models only, never a quality assertion."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from vt4dcodec.eval.command import main
from vt4dcodec.eval.protocol import (HEALTH_THRESHOLDS, RIG_CAMERAS, EvalSettings, EvaluationError, axis_angles_deg,
                                     make_scene, nearest_cameras, parse_sets, set_sources, set_targets,
                                     token_health_report)
from vt4dcodec.eval.report import format_tables
from vt4dcodec.model import VideoTok4D, from_pretrained, get_config, save_pretrained


HEALTH_KEYS = {"static_spread", "dynamic_spread", "static_rank", "dynamic_rank", "static_saturation",
               "dynamic_saturation", "scenes", "spread_pass", "psnr_own_db", "psnr_swapped_db", "swap_drop_db",
               "swap_drop_se_db", "swap_pass"}


def _yaw(degrees: float) -> np.ndarray:
    """A world-to-camera matrix turned by ``degrees`` about the world y axis (one frame)."""
    a = np.radians(degrees)
    w2c = np.eye(4)
    w2c[:3, :3] = [[np.cos(a), 0, -np.sin(a)], [0, 1, 0], [np.sin(a), 0, np.cos(a)]]
    return w2c[None]


def test_nearest_cameras_by_optical_axis_on_constructed_cameras():
    yaws = {"cam00": 0.0, "cam01": 90.0, "cam02": 10.0, "cam03": -5.0, "cam04": 170.0, "cam05": 30.0}
    cap = SimpleNamespace(camera_names=list(yaws), cameras={n: SimpleNamespace(w2c=_yaw(y)) for n, y in yaws.items()})
    near = nearest_cameras(cap, "cam00", 2)
    assert [n for n, _ in near] == ["cam03", "cam02"]
    assert [a for _, a in near] == pytest.approx([5.0, 10.0])
    assert [n for n, _ in nearest_cameras(cap, "cam01", 1)] == ["cam05"]  # 60 degrees, nearer than cam02's 80
    angles = axis_angles_deg(np.stack([cap.cameras[n].w2c for n in yaws]))
    np.testing.assert_allclose(angles, angles.T)
    assert angles[0, 4] == pytest.approx(170.0)
    with pytest.raises(EvaluationError):
        nearest_cameras(cap, "cam00", 6)


def test_targets_of_each_set():
    settings = EvalSettings(scenes=1, views=3)
    far = make_scene(0, settings)
    assert len(far.capture.camera_names) == 4
    assert set_targets(far, settings, "far") == ("cam00", ["cam01", "cam02", "cam03"])
    rig = make_scene(0, settings, "near")
    names = rig.capture.camera_names
    assert len(names) == RIG_CAMERAS
    source, near = set_targets(rig, settings, "near")
    angles = axis_angles_deg(np.stack([rig.capture.cameras[n].w2c for n in names]))[0]
    assert source == "cam00" and len(near) == 2 and "cam00" not in near
    assert max(angles[names.index(n)] for n in near) <= min(angles[i] for i in range(1, len(names))
                                                           if names[i] not in near)
    assert set_targets(rig, settings, "source") == ("cam00", ["cam00"])
    encoded = ["cam00", "cam02", "cam04", "cam06", "cam08"]
    assert set_sources(rig, "multi-held") == set_sources(rig, "multi-enc") == encoded
    assert set_sources(rig, "near") == ["cam00"]
    assert set_targets(rig, settings, "multi-held") == ("cam00", ["cam01", "cam03", "cam05", "cam07", "cam09"])
    assert set_targets(rig, settings, "multi-enc") == ("cam00", encoded)
    with pytest.raises(EvaluationError):
        set_targets(rig, settings, "sideways")


def test_parse_sets():
    assert parse_sets("source,far") == ("far", "source")
    assert parse_sets(["near", "near"]) == ("near",)
    for bad in ("", "far,nearby"):
        with pytest.raises(EvaluationError):
            parse_sets(bad)


def test_steps_none_means_the_models_recorded_decode_steps():
    net = VideoTok4D(get_config("tiny", patch_size=4))
    net.decode_steps = 3
    assert EvalSettings().steps is None
    assert EvalSettings().steps_for(net) == 3 and EvalSettings(steps=5).steps_for(net) == 5
    with pytest.raises(EvaluationError):
        EvalSettings(steps=0)


def test_rows_sets_figures_and_tables(evaluated):
    results, out = evaluated
    assert {r["set"] for r in results["rows"]} == {"far", "near", "source", "multi-held", "multi-enc"}
    source_rows = [r for r in results["rows"] if r["set"] == "source"]
    assert {r["view"] for r in source_rows} == {"cam00"}
    assert not {"nearest_frame", "depth_warp"} & {r["method"] for r in source_rows}
    held = [r for r in results["rows"] if r["set"] == "multi-held"]
    enc = [r for r in results["rows"] if r["set"] == "multi-enc"]
    assert {r["view"] for r in held} == {"cam01", "cam03", "cam05", "cam07", "cam09"}
    assert {r["view"] for r in enc} == {"cam00", "cam02", "cam04", "cam06", "cam08"}
    assert not {"nearest_frame", "depth_warp"} & {r["method"] for r in held + enc}
    # one token set per scene from five cameras: the same stored bytes for every target of a scene
    ours = [r for r in held + enc if r["method"] == "ours"]
    assert len({(r["seed"], r["bytes"]) for r in ours}) == len({r["seed"] for r in ours})
    assert {r["view"] for r in results["rows"] if r["set"] == "near"} <= {f"cam{i:02d}" for i in range(1, 10)}
    assert results["models"]["main"]["steps"] == 2  # forced with --steps 2
    assert "decode_steps" in results["models"]["main"]
    for name in ("eval.png", "eval_near.png", "eval_source.png"):
        assert (out / name).stat().st_size > 1000
    tables = format_tables(results)
    for text in ("### Far views", "### Near views", "### Source view", "skipped: the target is the source camera",
                 "Flat mean-colour reference", "### Token health", "token-swap drop", "### Multi-camera, held-out",
                 "### Multi-camera, encoded", "skipped: a single-source baseline"):
        assert text in tables
    assert tables.count("Flat mean-colour reference") == 5


def test_token_health_block(evaluated):
    health = evaluated[0]["token_health"]
    assert health["set"] == "source" and health["thresholds"] == HEALTH_THRESHOLDS
    assert set(health["models"]) == {"main", "unified"}
    for entry in health["models"].values():
        assert set(entry) == HEALTH_KEYS and entry["scenes"] == 2
        assert entry["swap_drop_db"] == pytest.approx(entry["psnr_own_db"] - entry["psnr_swapped_db"], abs=2e-4)
        assert isinstance(entry["spread_pass"], bool) and isinstance(entry["swap_pass"], bool)
    # the own-token PSNR is the source set's "ours" PSNR (the same render)
    ours = [r["psnr"] for r in evaluated[0]["rows"] if r["set"] == "source" and r["method"] == "ours"]
    assert health["models"]["main"]["psnr_own_db"] == pytest.approx(float(np.mean(ours)), abs=1e-3)


def test_swap_pairs_each_scene_with_the_next_one():
    """Stub decoders render a flat value that names whose tokens drew it: the swap uses the next scene's."""
    class Decoder:
        def __init__(self, value: int):
            self.value = value
            self.scene = SimpleNamespace(static_tokens=np.random.default_rng(value).normal(size=(4, 2)),
                                         dynamic_tokens=np.random.default_rng(value + 9).normal(size=(3, 2)))

        def render(self, trajectory, steps=None, seed=0):
            return np.full((2, 4, 4, 3), self.value, np.uint8)

    values = [100, 110, 140]
    items = {"main": [{"seed": i, "decoder": Decoder(v), "trajectory": None, "truth": np.full((2, 4, 4, 3), v, np.uint8),
                       "own": None} for i, v in enumerate(values)]}
    entry = token_health_report(items, EvalSettings(), "source")["models"]["main"]
    assert entry["psnr_own_db"] == pytest.approx(100.0)  # exact renders: the PSNR floor of psnr_db
    swapped = [10 * np.log10(255 ** 2 / (b - a) ** 2) for a, b in zip(values, values[1:] + values[:1])]
    assert entry["psnr_swapped_db"] == pytest.approx(np.mean(swapped), abs=1e-3)
    assert entry["swap_pass"] is True


def test_old_results_files_read_as_far_and_merge(evaluated, models, tmp_path):
    results, _ = evaluated
    old = {k: v for k, v in results.items() if k not in ("sets", "summary_by_set", "token_health")}
    old["rows"] = [{k: v for k, v in r.items() if k != "set"} for r in results["rows"] if r["set"] == "far"]
    tables = format_tables(old)
    assert "### Far views" in tables and "Near views" not in tables and "Token health" not in tables
    path = tmp_path / "old.json"
    path.write_text(json.dumps(old))
    assert main(["--tables", str(path)]) == 0
    base = ["--model", models[0], "--scenes", "2", "--views", "2", "--steps", "2", "--out", str(path), "--merge",
            "--no-progress"]
    assert main(base + ["--methods", "mean_colour", "--sets", "far"]) == 0
    merged = json.loads(path.read_text())
    assert len(merged["rows"]) == len(old["rows"]) and all(r["set"] == "far" for r in merged["rows"])
    assert merged["summary"]["ours"] == results["summary"]["ours"]
    assert merged["summary"]["mean_colour"]["psnr"] == results["summary"]["mean_colour"]["psnr"]
    # another set is added next to the far rows, which stay
    assert main(base + ["--methods", "ours,mean_colour", "--sets", "source"]) == 0
    merged = json.loads(path.read_text())
    assert merged["sets"] == ["far", "source"]
    assert sum(r["set"] == "far" for r in merged["rows"]) == len(old["rows"])
    assert sum(r["set"] == "source" for r in merged["rows"]) == 2 * 2
    assert set(merged["token_health"]["models"]) == {"main"}
    assert "### Source view" in format_tables(merged)


def test_default_steps_are_the_models_recorded_decode_steps(tmp_path):
    torch.manual_seed(4)
    net = VideoTok4D(get_config("tiny", patch_size=4)).eval()
    model_dir = save_pretrained(net, tmp_path / "m", model_id="test-steps", model_version="0", decode_steps=1)
    args = ["--model", str(model_dir), "--scenes", "2", "--sets", "source", "--methods", "ours", "--no-progress"]
    assert main(args + ["--out", str(tmp_path / "default.json")]) == 0
    assert main(args + ["--steps", "1", "--out", str(tmp_path / "forced.json")]) == 0
    default, forced = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("default", "forced"))
    assert default["settings"]["steps"] is None and forced["settings"]["steps"] == 1
    assert default["models"]["main"]["steps"] == forced["models"]["main"]["steps"] == 1
    assert default["models"]["main"]["decode_steps"] == 1
    assert [r["psnr"] for r in default["rows"]] == [r["psnr"] for r in forced["rows"]]


def test_real_footage_source_target_skips_the_trivial_baselines(models):
    from vt4dcodec.capture.capture import Capture
    from vt4dcodec.eval.real_footage import evaluate_real, summarize_real
    from vt4dcodec.synth import SynthConfig, generate_scene

    cap = generate_scene(6, split="test", config=SynthConfig(num_cameras=2)).capture
    cap = Capture(cameras=cap.cameras, frames=cap.frames, fps=cap.fps, capture_id=cap.capture_id)  # no depth
    rows, clips = evaluate_real(cap, from_pretrained(models[0]), "cam00", "cam00", steps=1)
    assert [r["method"] for r in rows] == ["ours", "mean_colour"]
    summary = summarize_real(rows)
    assert set(summary) == {"ours", "mean_colour", "ours_minus_flat"}
    assert summary["ours_minus_flat"]["psnr_mean"] == pytest.approx(rows[0]["psnr"] - rows[1]["psnr"], abs=1e-3)
    assert "nearest_frame" not in clips[0]


def test_real_footage_command_on_the_source_camera(models, tmp_path):
    from vt4dcodec.capture.caliscope import find_sample_capture
    from vt4dcodec.eval.real_footage import main as real_main

    capture = find_sample_capture()
    if capture is None:
        pytest.skip("caliscope_4cam sample not found")
    out = tmp_path / "real.json"
    assert real_main(["--model", models[0], "--capture", str(capture), "--target", "source", "--frame-step", "6",
                      "--steps", "1", "--out", str(out), "--figure", str(tmp_path / "real.png")]) == 0
    results = json.loads(out.read_text())
    assert results["source"] == results["target"] and results["target_mode"] == "source"
    assert set(results["summary"]) == {"ours", "mean_colour", "ours_minus_flat"}
    assert results["steps"] == 1 and (tmp_path / "real.png").is_file()


def test_quality_stores_the_main_model_at_that_level_and_the_ablation_as_int8(models, tmp_path):
    """--quality N: a model with quality levels is evaluated from learned-rans files at level N (smaller
    files at a lower level); a model without levels (here the unified ablation) stays int8."""
    torch.manual_seed(5)
    net = VideoTok4D(get_config("tiny", patch_size=4, entropy_levels=3)).eval()
    net.update_entropy()
    model_dir = save_pretrained(net, tmp_path / "levels", model_id="test-levels", model_version="0", decode_steps=1)
    args = ["--model", str(model_dir), "--unified", models[1], "--scenes", "1", "--sets", "source",
            "--methods", "ours,unified", "--no-progress"]
    sizes = {}
    for quality in ("1", "3"):
        out = tmp_path / f"q{quality}.json"
        assert main(args + ["--quality", quality, "--out", str(out)]) == 0
        result = json.loads(out.read_text())
        assert result["settings"]["quality"] == int(quality)
        assert result["models"]["main"]["encoding"] == f"learned-rans q{quality}"
        assert result["models"]["unified"]["encoding"] == "int8"
        assert f"learned-rans q{quality} .vt4d bytes" in format_tables(result)  # the tables say how it was stored
        sizes[quality] = {r["method"]: r["bytes"] for r in result["rows"]}
    assert sizes["1"]["ours"] < sizes["3"]["ours"] and sizes["1"]["unified"] == sizes["3"]["unified"]
    with pytest.raises(EvaluationError):
        EvalSettings(quality=0)
