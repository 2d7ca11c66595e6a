"""bench/bench_codecs.py: the rate functions give known answers on constructed curves, and the study runs
end to end on a small random model and writes the results it claims."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

BENCH = "bench_codecs"  # the script under test (conftest.py loads it)


def _curve(psnrs, rate_at_20=100.0, decade_db=10.0, factor=1.0):
    """(bytes, psnr) with log10(bytes) linear in PSNR: 10x the bytes per ``decade_db`` dB."""
    return [(factor * rate_at_20 * 10 ** ((p - 20.0) / decade_db), p) for p in psnrs]


def test_bytes_at_psnr_interpolates_in_log_rate(bench):
    pts = [(100.0, 20.0), (1000.0, 30.0)]
    b, bound = bench.bytes_at_psnr(pts, 25.0)
    assert bound == "interpolated" and b == pytest.approx(math.sqrt(100 * 1000))  # halfway in log-rate
    assert bench.bytes_at_psnr(pts, 30.0) == (pytest.approx(1000.0), "interpolated")
    # a log-linear curve is recovered exactly anywhere inside it
    curve = _curve([20, 24, 31, 40])
    for p in (21.0, 27.5, 39.9):
        assert bench.bytes_at_psnr(curve, p)[0] == pytest.approx(100 * 10 ** ((p - 20) / 10))


def test_bytes_at_psnr_bounds_and_pareto(bench):
    pts = [(100.0, 20.0), (1000.0, 30.0)]
    assert bench.bytes_at_psnr(pts, 15.0) == (100.0, "at_most")  # the cheapest point is already better
    assert bench.bytes_at_psnr(pts, 31.0) == (None, "unreachable")
    assert bench.bytes_at_psnr([], 20.0) == (None, "unreachable")
    # a dearer point with a lower PSNR is dominated and ignored
    dominated = pts + [(500.0, 10.0), (2000.0, 25.0)]
    assert bench.pareto(dominated) == pts
    assert bench.bytes_at_psnr(dominated, 25.0)[0] == pytest.approx(math.sqrt(1e5))
    # a falling curve (novel views served another camera's frames) has its cheapest point as its front
    assert bench.pareto([(100.0, 18.0), (1000.0, 17.0)]) == [(100.0, 18.0)]


def test_bd_rate_known_answers(bench):
    anchor = _curve([20, 25, 30, 35, 40])
    assert bench.bd_rate(_curve([22, 28, 33, 38], factor=2.0), anchor) == pytest.approx(100.0)
    assert bench.bd_rate(_curve([20, 30, 40], factor=0.5), anchor) == pytest.approx(-50.0)
    assert bench.bd_rate(anchor, anchor) == pytest.approx(0.0)
    # half the overlap at +100 %, half at +300 % (log-rate offsets log10 2 and log10 4): mean log10 sqrt(8)
    test = [(200.0 * 10 ** 0, 20.0), (200.0 * 10, 30.0), (400.0 * 10, 30.0001), (400.0 * 100, 40.0)]
    assert bench.bd_rate(test, anchor) == pytest.approx((math.sqrt(8) - 1) * 100, rel=1e-3)
    assert bench.bd_rate(_curve([41, 45]), anchor) is None  # no overlap
    assert bench.bd_rate([(100.0, 20.0)], anchor) is None  # one point is no curve


def test_strip_sei_drops_only_sei_nal_units(bench):
    sps, sei, idr = b"\x67\x64\x0a", b"\x06\x05\x10" + b"x" * 20, b"\x65\x88\x84"
    au = b"\x00\x00\x00\x01" + sps + b"\x00\x00\x01" + sei + b"\x00\x00\x01" + idr
    assert bench.strip_sei(au, "h264") == b"\x00\x00\x00\x01" + sps + b"\x00\x00\x01" + idr  # start codes kept
    hevc_sei = bytes([39 << 1, 1]) + b"y" * 9
    assert bench.strip_sei(b"\x00\x00\x01" + hevc_sei, "h265") == b""
    assert bench.strip_sei(au, "av1") == au


def test_study_runs_end_to_end_and_writes_json_figure_and_table(bench, tmp_path):
    from vt4dcodec import codec
    from vt4dcodec.model import VideoTok4D, get_config, save_pretrained

    torch.manual_seed(0)
    torch.set_num_threads(1)
    cfg = get_config("tiny", width=64, heads=2, renderer_layers=1, spatial_layers=1, static_query_layers=1,
                     track_layers=1, dynamic_spatial_layers=1, n_tracks=16)
    model = save_pretrained(VideoTok4D(cfg), tmp_path / "m", model_id="test-codecs", model_version="0.0")
    doc = tmp_path / "codecs.md"
    doc.write_text(f"intro\n{bench.TABLE_BEGIN}\nold\n{bench.TABLE_END}\nafter\n")
    out, fig = tmp_path / "codecs.json", tmp_path / "codecs.png"
    assert bench.main(["--model", str(model), "--quick", "--scenes", "1", "--cameras", "3", "--real-clips", "0",
                       "--encodings", f"{codec.DEFAULT_ENCODING},int8", "--out", str(out), "--figure", str(fig),
                       "--doc", str(doc)]) == 0
    r = json.loads(out.read_text())
    assert r["model"]["id"] == "test-codecs" and r["reference_encoding"] == codec.DEFAULT_ENCODING
    assert set(r["codecs"]) <= {"h264", "h265", "av1"} and {"h264", "h265"} <= set(r["codecs"])
    s = r["datasets"]["synthetic"]["summary"]
    assert list(s) == [row for row, _, _ in bench.SETTINGS]
    assert [(s[row]["stored_cameras"], s[row]["views"]) for row in s] == [(1, 1), (1, 2), (3, 3), (2, 2), (2, 1)]
    assert s["half/novel"]["novel_served_by_nearest_stored_camera"] and s["single/novel"]["angle_deg_mean"] > 0
    for row in s.values():
        assert set(row["vt4d"]) == {codec.DEFAULT_ENCODING, "int8"}
        for c in row["codecs"].values():
            assert all(p["bytes"] > 0 and 5 < p["psnr"] < 60 and -1 <= p["ssim"] <= 1 for p in c["curve"])
            assert {p["scale"] for p in c["low_rate"]} == {4}
            eq = c["equal_quality"]
            assert eq["bound"] in ("interpolated", "at_most", "unreachable")
            if eq["codec_bytes"] is not None:
                assert eq["rate_ratio"] == pytest.approx(row["vt4d"][codec.DEFAULT_ENCODING]["bytes"] / eq["codec_bytes"], rel=1e-3)
    # the whole-capture file is one token set: about the size of one camera's, far below 3 separate files
    assert s["all/captured"]["vt4d"]["int8"]["bytes"] < 1.5 * s["single/captured"]["vt4d"]["int8"]["bytes"]
    # each stored camera's bytes are summed for the codecs: all cameras cost more than one
    h264 = {row: min(p["bytes"] for p in s[row]["codecs"]["h264"]["curve"]) for row in ("single/captured", "all/captured")}
    assert h264["all/captured"] > 2 * h264["single/captured"]
    clip = r["datasets"]["synthetic"]["per_clip"][0]
    assert len(clip["settings"]["all/captured"]["codecs"]["h264"]) == len(r["codecs"]["h264"]["sweep"])
    assert set(r["headline"]) == {"captured", "novel"}
    text = doc.read_text()
    assert text.startswith("intro\n") and text.endswith("after\n") and "old" not in text and "| all/captured |" in text
    assert fig.stat().st_size > 1000


def test_decoded_frames_are_what_is_scored(bench):
    rng = np.random.default_rng(0)
    frames = np.repeat(rng.integers(0, 255, (1, 16, 16, 3), dtype=np.uint8), 4, axis=0)
    codecs = bench.available_codecs(["h264"])
    size, decoded = bench.video_roundtrip(frames, "h264", codecs["h264"], 21)
    assert decoded.shape == frames.shape and decoded.dtype == np.uint8 and 0 < size < frames.nbytes
    size2, decoded2 = bench.video_roundtrip(frames, "h264", codecs["h264"], 51)
    assert size2 < size
    from vt4dcodec.media import psnr

    assert psnr(decoded, frames) > psnr(decoded2, frames)


def test_per_clip_ratios_mean_se_and_bounds(bench):
    def clip(vt4d_bytes, vt4d_psnr):
        return {"vt4d": {"q1": {"bytes": vt4d_bytes, "psnr": vt4d_psnr}},
                "codecs": {"h265": [{"bytes": 100.0, "psnr": 20.0}, {"bytes": 1000.0, "psnr": 30.0}]}}
    # 25 dB needs sqrt(1e5) B of the codec: ratios 1x and 2x; one clip below its cheapest point, one above its best
    rs = [clip(math.sqrt(1e5), 25.0), clip(2 * math.sqrt(1e5), 25.0), clip(300.0, 15.0), clip(300.0, 35.0)]
    got = bench.per_clip_ratios(rs, "h265")["q1"]
    assert got["mean"] == pytest.approx(1.5) and got["se"] == pytest.approx(0.5)
    assert (got["clips"], got["at_most"], got["unreachable"]) == (2, 1, 1)
    assert bench._se([1.0]) is None


def test_a_capture_directory_is_measured_clip_by_clip(bench, tmp_path):
    """--capture takes a capture directory (as `vt4d synth` / `vt4d import` write them): consecutive clips,
    cropped to the model's square, reported with bits per pixel and standard errors."""
    from vt4dcodec.model import VideoTok4D, get_config, save_pretrained
    from vt4dcodec.synth import SynthConfig, write_dataset

    torch.manual_seed(0)
    torch.set_num_threads(1)
    cfg = get_config("tiny", width=64, heads=2, renderer_layers=1, spatial_layers=1, static_query_layers=1,
                     track_layers=1, dynamic_spatial_layers=1, n_tracks=16)
    model = save_pretrained(VideoTok4D(cfg), tmp_path / "m", model_id="test-codecs", model_version="0.0")
    captures = write_dataset(tmp_path / "caps", num_scenes=1, split="test", seed=7, workers=1,
                             config=SynthConfig(num_cameras=2, num_frames=16, height=80, width=96))
    out = tmp_path / "capture.json"
    assert bench.main(["--model", str(model), "--quick", "--scenes", "0", "--capture", str(captures[0]),
                       "--codecs", "h265", "--encodings", "int8", "--out", str(out), "--figure", "none",
                       "--doc", "none"]) == 0
    r = json.loads(out.read_text())
    data = r["datasets"]["capture"]
    assert data["clips"] == 2 and data["cameras"] == 2
    row = data["summary"]["all/captured"]
    assert row["vt4d"]["int8"]["bpp"] == pytest.approx(8 * row["vt4d"]["int8"]["bytes"] / (2 * 8 * 64 * 64), abs=1e-4)
    assert row["vt4d_se"]["int8"]["psnr"] is not None
    assert set(row["codecs"]["h265"]["rate_ratio_per_clip"]["int8"]) == {"mean", "se", "clips", "at_most",
                                                                            "unreachable"}


def test_the_figure_names_the_codecs_the_study_ran(bench):
    """Regression: the figure's title said "vs H.264 / H.265 / AV1" for an H.265-only study."""
    assert bench.figure_codecs({"codecs": {"h265": {}}}) == "H.265"
    assert bench.figure_codecs({"codecs": {"h264": {}, "h265": {}, "av1": {}}}) == "H.264 / H.265 / AV1"
    assert bench.figure_codecs({"codecs": {}}) == "no codec"


def test_each_level_is_measured_from_the_tokens_vt4d_encode_stores_at_it(bench, tmp_path, monkeypatch):
    """Regression: the study encoded each stored set once and wrote every level from those tokens, so a model with
    render feedback from level 2 up (``feedback_quality``) was measured at q1 with the feedback's tokens where
    ``vt4d encode --quality 1`` stores the first pass. Each level's file now has the bytes of the codec's file.
    One creation time for every file: the stamp's seconds are zstd-compressed with the header, so two files
    written across a second's turn could differ in length by a byte (a CI run saw 446 against 445)."""
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1767225600")
    from vt4dcodec import codec
    from vt4dcodec.format import dumps
    from vt4dcodec.model import VideoTok4D, get_config, save_pretrained
    from vt4dcodec.synth import SynthConfig, generate_scene

    torch.manual_seed(0)
    torch.set_num_threads(1)
    cfg = get_config("tiny", frames=4, image_size=32, width=32, heads=2, ae_width=8, spatial_layers=1,
                     static_query_layers=1, track_layers=1, renderer_layers=1, n_static=32, n_dynamic=4,
                     token_dim=8, n_tracks=8, patch_size=2, locality_sigma=0.35, query_from_grid=True,
                     project_anchors=True, prediction="x0", anchor_views=True, token_splat=True,
                     token_from_cell=True, frame_copies=True, pixel_splat=True, dynamic_splat=2,
                     dynamic_from_patch=True, entropy_levels=2, feedback_width=16, feedback_quality=2)
    net = VideoTok4D(cfg).eval()
    for layer in (net.feedback.static[2], net.feedback.dynamic[2]):
        torch.nn.init.normal_(layer.weight, std=0.3)  # a feedback that moves the tokens
    net.update_entropy()
    net.decode_steps = 1
    model = codec.load_model(save_pretrained(net, tmp_path / "m", model_id="test-fb", model_version="0"))
    capture = generate_scene(3, split="test", config=SynthConfig(num_cameras=3, num_frames=4, height=32,
                                                                 width=32)).capture
    got = bench.evaluate_clip(capture, 0, model, {}, ["q1", "q2"], quick=True)["settings"]["single/captured"]
    stored = got["stored"]
    for level in (1, 2):
        want = len(dumps(codec.encode(capture, model, cameras=stored, quality=level)))
        assert got["vt4d"][f"q{level}"]["bytes"] == want
    first, fed = (codec.encode(capture, model, cameras=stored, quality=q) for q in (1, 2))
    assert not np.array_equal(first.static_tokens, fed.static_tokens)  # the two levels' tokens differ
