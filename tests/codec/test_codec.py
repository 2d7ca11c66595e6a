"""The codec API: encode -> save -> load -> decode, fingerprints, determinism and clear errors."""

import numpy as np
import pytest

from vt4dcodec import codec
from vt4dcodec.cameras import Trajectory
from vt4dcodec.capture import Capture
from vt4dcodec.errors import CaptureError, ModelMismatchError, ModelNotFoundError, TrajectoryError, Vt4dError
from vt4dcodec.format import dumps, load, open_scene, save
from vt4dcodec.format.compact_cameras import REPROJECTION_TOLERANCE_PX, reprojection_change


def test_encode_save_load_decode_round_trip(tmp_path, encoded, model_dir, synth_scene):
    path = tmp_path / "s.vt4d"
    nbytes = save(encoded, path)
    assert nbytes == path.stat().st_size
    loaded = load(path)
    assert loaded.fingerprint.matches(encoded.fingerprint)
    assert loaded.provenance.kind == "encoded" and loaded.provenance.source_capture_id == synth_scene.capture.capture_id
    assert loaded.metadata["vt4d"]["source_camera"] == synth_scene.capture.camera_names[0]
    source = synth_scene.capture.cameras[synth_scene.capture.camera_names[0]]
    # compact cameras (format 1.2, the default): float32 within 0.01 px; cameras="exact" keeps float64
    assert reprojection_change(source, loaded.cameras) <= REPROJECTION_TOLERANCE_PX
    save(encoded, path, cameras="exact")
    assert load(path).cameras.equals(source, atol=1e-9)
    frames = codec.decode(path, "source", steps=2, seed=3, model=model_dir)
    cfg = codec.load_model(model_dir).config
    assert frames.dtype == np.uint8 and frames.shape == (cfg.frames, cfg.image_size, cfg.image_size, 3)


def test_decode_is_deterministic_for_file_trajectory_and_seed(tmp_path, encoded, model_dir):
    path = tmp_path / "s.vt4d"
    save(encoded, path)
    a = codec.decode(path, "orbit:degrees=20", steps=2, seed=5, model=model_dir)
    b = codec.decode(path, "orbit:degrees=20", steps=2, seed=5, model=model_dir)
    c = codec.decode(path, "orbit:degrees=20", steps=2, seed=6, model=model_dir)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_render_many_reuses_one_token_state(encoded, model_dir, synth_scene, monkeypatch):
    decoder = codec.SceneDecoder.open(encoded, model=model_dir)
    calls = []
    monkeypatch.setattr(decoder.model, "encode", lambda *a, **k: calls.append(1))
    other = synth_scene.capture.cameras[synth_scene.capture.camera_names[1]]
    views = decoder.render_many(["source", other, "dolly_in:metres=0.3"], steps=1)
    assert len(views) == 3 and not calls
    assert np.array_equal(views[0], decoder.render("source", steps=1))


def test_render_many_batches_views_and_each_equals_its_render_alone(tmp_path, synth_scene, small_config,
                                                                    monkeypatch):
    """Views of one frame count are rendered in one forward pass (RENDER_BATCH at a time), in the order
    given; the renderer gives every item the same seeded noise, so each view equals its render alone."""
    import torch

    from vt4dcodec.model import VideoTok4D, save_pretrained

    torch.manual_seed(3)
    net = VideoTok4D(small_config).eval()
    with torch.no_grad():  # a zero-initialised output layer would render every view alike
        for p in net.renderer.parameters():
            p.add_(0.05 * torch.randn_like(p))
    directory = save_pretrained(net, tmp_path / "live", model_id="batch-test", model_version="0")
    decoder = codec.SceneDecoder.open(codec.encode(synth_scene.capture, model=directory, seed=0), model=directory)
    monkeypatch.setattr(codec, "RENDER_BATCH", 2)
    short = decoder.trajectory("source")[:3]
    other = synth_scene.capture.cameras[synth_scene.capture.camera_names[1]]
    views = ["source", other, short, "orbit:degrees=15", "pan:degrees=10"]
    many = decoder.render_many(views, steps=2, seed=4)
    alone = [decoder.render(v, steps=2, seed=4) for v in views]
    assert [v.shape[0] for v in many] == [8, 8, 3, 8, 8]
    for a, b in zip(many, alone):
        assert np.abs(a.astype(int) - b.astype(int)).max() <= 1  # float summation order only
    assert not np.array_equal(many[0], many[1]) and not np.array_equal(many[3], many[4])


def test_encode_is_deterministic(synth_scene, model_dir, encoded):
    again = codec.encode(synth_scene.capture, model=model_dir, seed=0)
    assert np.array_equal(again.static_tokens, encoded.static_tokens)
    assert np.array_equal(again.dynamic_tokens, encoded.dynamic_tokens)


def test_source_date_epoch_makes_encoded_files_byte_identical(synth_scene, model_dir, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1767225600")
    a = dumps(codec.encode(synth_scene.capture, model=model_dir, seed=0))
    b = dumps(codec.encode(synth_scene.capture, model=model_dir, seed=0))
    assert a == b and open_scene(a).provenance.created_utc == "2026-01-01T00:00:00Z"


def test_model_mismatch_is_refused_naming_both_fingerprints(tmp_path, encoded, other_model_dir):
    path = tmp_path / "s.vt4d"
    save(encoded, path)
    with pytest.raises(ModelMismatchError) as err:
        codec.decode(path, "source", steps=1, model=other_model_dir)
    message = str(err.value)
    other = codec.model_fingerprint(codec.load_model(other_model_dir))
    assert encoded.fingerprint.weights_sha256[:8] in message and other.weights_sha256[:8] in message
    frames = codec.decode(path, "source", steps=1, model=other_model_dir, force=True)
    assert frames.dtype == np.uint8


def test_unknown_model_id_is_a_clear_error(encoded):
    from dataclasses import replace

    from vt4dcodec.format import Scene

    fp = replace(encoded.fingerprint, model_id="no-such-model")
    scene = Scene(encoded.static_tokens, encoded.dynamic_tokens, encoded.cameras, fp)
    with pytest.raises(ModelNotFoundError, match="no-such-model"):
        codec.SceneDecoder.open(scene)


def test_user_model_found_through_model_path(monkeypatch, encoded, model_dir):
    monkeypatch.setenv("VT4D_MODEL_PATH", str(model_dir.parent))
    decoder = codec.SceneDecoder.open(encoded)  # the fingerprint's id names the directory
    assert decoder.model.config == codec.load_model(model_dir).config


@pytest.mark.parametrize("spec, message", [
    ("warp:speed=3", "unknown trajectory preset"),
    ("orbit:degrees=abc", "not a number"),
    (42, "a trajectory must be"),
])
def test_bad_trajectories_give_clear_errors(encoded, model_dir, spec, message):
    decoder = codec.SceneDecoder.open(encoded, model=model_dir)
    with pytest.raises(TrajectoryError, match=message):
        decoder.render(spec, steps=1)


def test_full_length_trajectory_is_cut_to_the_clip_and_distorted_is_refused(encoded, model_dir):
    """A capture camera's whole trajectory is cut to the scene's clip window (metadata clip_start /
    clip_frames); it used to be refused with "a scene covers 8 frames"."""
    decoder = codec.SceneDecoder.open(encoded, model=model_dir)
    src = encoded.cameras
    long = Trajectory(K=np.concatenate([src.K, src.K]), w2c=np.concatenate([src.w2c, src.w2c]),
                      width=src.width, height=src.height)
    np.testing.assert_array_equal(decoder.render(long, steps=1), decoder.render("source", steps=1))
    distorted = Trajectory(K=src.K, w2c=src.w2c, width=src.width, height=src.height,
                           distortion=np.array([0.1, 0, 0, 0]))
    with pytest.raises(TrajectoryError, match="pinhole"):
        decoder.render(distorted, steps=1)


def test_trajectory_for_another_image_size_is_fitted(encoded, model_dir):
    decoder = codec.SceneDecoder.open(encoded, model=model_dir)
    src = encoded.cameras
    big = Trajectory(K=src.K * np.array([[4, 1, 4], [1, 4, 4], [1, 1, 1]]) + np.array([[0, 0, 1.5], [0, 0, 1.5], [0, 0, 0]]),
                     w2c=src.w2c, width=src.width * 4, height=src.height * 4)
    fitted = decoder.trajectory(big)
    assert (fitted.width, fitted.height) == (src.width, src.height)
    assert np.allclose(fitted.K, src.K, atol=1e-9)


def test_clip_policy(synth_scene, model_dir):
    cap = synth_scene.capture
    T = cap.num_frames
    with pytest.raises(CaptureError, match="does not fit"):
        codec.encode(cap, model=model_dir, start=1)
    with pytest.raises(CaptureError, match="no camera"):
        codec.encode(cap, model=model_dir, camera="nope")
    # a capture twice as long splits into two clips; a shorter one is rejected
    names = cap.camera_names
    long = Capture(cameras={n: Trajectory(K=np.concatenate([cap.cameras[n].K] * 2),
                                          w2c=np.concatenate([cap.cameras[n].w2c] * 2),
                                          width=cap.cameras[n].width, height=cap.cameras[n].height) for n in names},
                   frames={n: np.concatenate([cap.frames[n]] * 2) for n in names}, fps=cap.fps, capture_id="long")
    clips = codec.encode_clips(long, model=model_dir)
    assert [c.metadata["vt4d"]["clip_start"] for c in clips] == [0, T]
    short = Capture(cameras={n: cap.cameras[n][: T - 1] for n in names},
                    frames={n: cap.frames[n][: T - 1] for n in names}, fps=cap.fps, capture_id="short")
    with pytest.raises(CaptureError, match="frames"):
        codec.encode(short, model=model_dir)


def test_encode_fits_larger_frames_with_updated_intrinsics(synth_scene, model_dir):
    import cv2

    cap = synth_scene.capture
    name = cap.camera_names[0]
    traj = cap.cameras[name]
    s = 2
    K2 = traj.K.copy()
    K2[:, :2, :2] *= s
    K2[:, :2, 2] = (traj.K[:, :2, 2] + 0.5) * s - 0.5
    big = Capture(cameras={name: Trajectory(K=K2, w2c=traj.w2c, width=traj.width * s, height=traj.height * s)},
                  frames={name: np.stack([cv2.resize(f, None, fx=s, fy=s, interpolation=cv2.INTER_CUBIC)
                                          for f in cap.frames[name]])}, fps=cap.fps, capture_id="big")
    scene = codec.encode(big, model=model_dir)
    assert (scene.cameras.width, scene.cameras.height) == (traj.width, traj.height)
    assert np.allclose(scene.cameras.K, traj.K, atol=1e-6)


def test_bad_capture_directory_is_a_vt4d_error(tmp_path, model_dir):
    (tmp_path / "capture.json").write_text("{not json")
    with pytest.raises(Vt4dError):
        codec.encode(tmp_path, model=model_dir)


def test_encoding_a_directory_reads_only_the_clip_of_the_encoded_cameras(tmp_path, synth_scene, model_dir,
                                                                       monkeypatch):
    """From a capture directory, encode decodes the clip's frames of the encoded cameras and nothing else
    (one seeked read per camera), and gives the tokens the in-memory capture gives."""
    from vt4dcodec.capture import io as capture_io
    from vt4dcodec.capture import read_capture, write_capture

    cap = synth_scene.capture
    names = cap.camera_names
    T = cap.num_frames
    long = Capture(cameras={n: Trajectory(K=np.concatenate([cap.cameras[n].K] * 3),
                                          w2c=np.concatenate([cap.cameras[n].w2c] * 3),
                                          width=cap.cameras[n].width, height=cap.cameras[n].height) for n in names},
                   frames={n: np.concatenate([cap.frames[n]] * 3) for n in names}, fps=cap.fps, capture_id="long")
    write_capture(long, tmp_path, media="mp4")
    reads = []
    real = capture_io.read_video_window

    def spy(path, start, count, **kwargs):
        reads.append((str(path.relative_to(tmp_path)), start, count))
        return real(path, start, count, **kwargs)

    monkeypatch.setattr(capture_io, "read_video_window", spy)
    scene = codec.encode(tmp_path, model=model_dir, camera=names[1], start=T)
    assert reads == [(f"{names[1]}/rgb.mp4", T, T)]
    assert scene.metadata["vt4d"]["clip_start"] == T
    reference = codec.encode(read_capture(tmp_path), model=model_dir, camera=names[1], start=T)
    np.testing.assert_array_equal(scene.static_tokens, reference.static_tokens)
    np.testing.assert_array_equal(scene.dynamic_tokens, reference.dynamic_tokens)
    reads.clear()
    clips = codec.encode_clips(tmp_path, model=model_dir, cameras=[names[2], names[0]])
    assert [c.metadata["vt4d"]["clip_start"] for c in clips] == [0, T, 2 * T]
    assert reads == [(f"{n}/rgb.mp4", s, T) for s in (0, T, 2 * T) for n in (names[2], names[0])]
    with pytest.raises(CaptureError, match="does not fit"):
        codec.encode(tmp_path, model=model_dir, start=2 * T + 1)


def _portrait(cap, name, extra=48):
    """``cap``'s camera ``name`` as a portrait camera: ``extra`` rows of grey above and below its frames."""
    traj = cap.cameras[name]
    half = extra // 2
    frames = np.pad(cap.frames[name], ((0, 0), (half, half), (0, 0), (0, 0)), constant_values=128)
    K = traj.K.copy()
    K[:, 1, 2] += half
    return Capture(cameras={name: Trajectory(K=K, w2c=traj.w2c, width=traj.width, height=traj.height + extra)},
                   frames={name: frames}, fps=cap.fps, capture_id="portrait")


def test_fit_pad_keeps_the_whole_portrait_frame_and_renders_capture_cameras_alike(synth_scene, model_dir):
    from vt4dcodec.capture.resample import plan_fit

    name = synth_scene.capture.camera_names[0]
    portrait = _portrait(synth_scene.capture, name)  # 64 x 112
    size = synth_scene.capture.cameras[name].width
    padded = codec.encode(portrait, model=model_dir, fit="pad")
    cropped = codec.encode(portrait, model=model_dir)
    assert padded.metadata["vt4d"]["fit"] == "pad" and "fit" not in cropped.metadata["vt4d"]
    plan = plan_fit(size, size + 48, out_height=size, out_width=size, fit="pad")
    assert plan.scaled_height == size and plan.scaled_width < size and plan.x0 < 0
    np.testing.assert_allclose(padded.cameras.K, plan.intrinsics(portrait.cameras[name].K), atol=1e-9)
    assert not np.allclose(padded.cameras.K, cropped.cameras.K)
    # a capture camera (and any capture-size trajectory) is fitted the way the scene was
    for scene in (padded, cropped):
        decoder = codec.SceneDecoder.open(scene, model=model_dir)
        np.testing.assert_allclose(decoder.trajectory(f"camera:{name}", capture=portrait).K, scene.cameras.K,
                                   atol=1e-9)
        np.testing.assert_allclose(decoder.trajectory(portrait.cameras[name]).K, scene.cameras.K, atol=1e-9)
    with pytest.raises(CaptureError, match="fit must be 'crop'.*or 'pad'"):
        codec.encode(portrait, model="no-such-model", fit="squash")  # refused before the model is looked up
