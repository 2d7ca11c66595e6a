"""python -m vt4dcodec.eval.real_footage on any capture directory: here the caliscope sample imported with
`vt4d import`, one clip, a random tiny model, every camera rendered and compared."""

from __future__ import annotations

import json

import pytest

from vt4dcodec.eval.real_footage import main as real_main


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    from vt4dcodec.capture.caliscope import find_sample_capture
    from vt4dcodec.capture.importer import import_capture

    sample = find_sample_capture()
    if sample is None:
        pytest.skip("caliscope_4cam sample not found")
    out = tmp_path_factory.mktemp("imported") / "caliscope"
    import_capture(sample / "camera_array.toml", sample / "videos", out)
    return out


def test_every_camera_of_an_imported_capture(models, imported, tmp_path):
    out, sheet = tmp_path / "real.json", tmp_path / "sheet.png"
    assert real_main(["--model", models[0], "--capture", str(imported), "--source", "cam_0", "--target", "all",
                      "--max-clips", "1", "--steps", "1", "--out", str(out), "--sheet", str(sheet)]) == 0
    results = json.loads(out.read_text())
    cams = ["cam_0", "cam_1", "cam_2", "cam_3"]
    assert results["targets"] == cams and results["sources"] == ["cam_0"] and results["clips"] == 1
    assert list(results["summary_by_camera"]) == cams
    methods = {c: [r["method"] for r in results["rows"] if r["camera"] == c] for c in cams}
    assert methods["cam_0"] == ["ours", "mean_colour"]  # the references are exact on the encoded camera
    assert all(methods[c] == ["ours", "nearest_frame", "depth_warp", "mean_colour"] for c in cams[1:])
    assert all(0 < r["psnr"] < 60 and r["clip_start"] == 0 for r in results["rows"])
    assert set(results["summary_by_camera"]["cam_1"]) == {"ours", "nearest_frame", "depth_warp", "mean_colour",
                                                          "ours_minus_flat"}
    import cv2

    image = cv2.imread(str(sheet))
    assert image is not None and image.shape[0] > 8 * 64  # two rows (real, render) per camera


def test_several_encoded_cameras_and_one_target(models, imported, tmp_path):
    out = tmp_path / "real.json"
    assert real_main(["--model", models[0], "--capture", str(imported), "--source", "cam_0,cam_2", "--target",
                      "cam_1", "--max-clips", "1", "--steps", "1", "--fit", "pad", "--out", str(out)]) == 0
    results = json.loads(out.read_text())
    assert results["sources"] == ["cam_0", "cam_2"] and results["target"] == "cam_1" and results["fit"] == "pad"
    assert [r["method"] for r in results["rows"]] == ["ours", "nearest_frame", "depth_warp", "mean_colour"]


@pytest.mark.parametrize("args,message", [
    (["--source", "nope"], "--source: the capture has no camera 'nope'"),
    (["--source", "cam_1", "--target", "cam_1"], "--target CAM"),
    (["--max-clips", "0"], "--max-clips must be at least 1"),
    (["--frame-step", "2"], "--frame-step applies to caliscope recordings"),
    (["--quality", "3"], "--quality must be int8 (the model has no quality levels), got '3'"),
])
def test_bad_arguments_name_the_flag(models, imported, tmp_path, capsys, args, message):
    assert real_main(["--model", models[0], "--capture", str(imported), *args, "--out", str(tmp_path / "r.json")]) == 1
    assert message in capsys.readouterr().err


def test_a_folder_that_is_no_capture_says_how_to_make_one(models, tmp_path, capsys):
    assert real_main(["--model", models[0], "--capture", str(tmp_path), "--out", str(tmp_path / "r.json")]) == 1
    assert "vt4d import" in capsys.readouterr().err


def test_tokens_are_stored_at_the_codec_default_level_unless_asked(imported, tmp_path, capsys):
    """The report measures what `vt4d encode` stores: the model's default quality level; --quality N or int8
    asks for another, and a level the model lacks names the flag."""
    import torch

    from vt4dcodec.model import VideoTok4D, get_config, save_pretrained

    torch.manual_seed(0)
    net = VideoTok4D(get_config("tiny", patch_size=4, entropy_levels=2)).eval()
    net.update_entropy()
    model = save_pretrained(net, tmp_path / "levels", model_id="test-levels", model_version="0", default_quality=1)
    common = ["--model", str(model), "--capture", str(imported), "--target", "source", "--max-clips", "1",
              "--steps", "1"]
    for extra, encoding in (([], "learned-rans q1"), (["--quality", "2"], "learned-rans q2"),
                            (["--quality", "int8"], "int8")):
        out = tmp_path / f"r{len(extra)}{encoding[-1]}.json"
        assert real_main([*common, *extra, "--out", str(out)]) == 0
        assert json.loads(out.read_text())["encoding"] == encoding
    assert real_main([*common, "--quality", "3", "--out", str(tmp_path / "bad.json")]) == 1
    assert "--quality must be a level 1 .. 2 or int8, got '3'" in capsys.readouterr().err
