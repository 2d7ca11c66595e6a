"""The codec's depth reference on the shipped model: a capture whose world origin sits at the encoded camera is
encoded and rendered in the frame moved to a reference point (vt4dcodec.reference), and that equals encoding the
capture expressed in that frame in the first place."""

from __future__ import annotations

import dataclasses
from unittest import mock

import numpy as np
import pytest

from vt4dcodec import codec, reference
from vt4dcodec.errors import FormatError
from vt4dcodec.format import dumps, load


@pytest.fixture(scope="module")
def shipped():
    from vt4dcodec.model import from_pretrained, shipped_model_ids

    if "vt4d-tiny" not in shipped_model_ids():
        pytest.skip("the shipped vt4d-tiny weights are not in this checkout")
    return from_pretrained("vt4d-tiny").eval()


def moved(capture, point):
    return dataclasses.replace(capture, cameras={k: dataclasses.replace(v, w2c=reference.move_origin(v.w2c, point))
                                                 for k, v in capture.cameras.items()})


def test_an_origin_at_the_camera_renders_as_the_moved_frame(synth_scene, shipped):
    cap = synth_scene.capture
    w0 = np.asarray(cap.cameras["cam00"].w2c, np.float64)[0]
    at_camera = moved(cap, -w0[:3, :3].T @ w0[:3, 3])  # the world origin at cam00's centre at frame 0
    scene = load(dumps(codec.encode(at_camera, shipped, camera="cam00", quality=9)))
    stored = scene.metadata["vt4d"][reference.CENTRE_KEY]
    centre = np.asarray(stored, np.float64) / 1000.0
    depth = np.asarray(at_camera.cameras["cam00"].w2c)[:, 2, :3] @ centre + np.asarray(at_camera.cameras["cam00"].w2c)[:, 2, 3]
    assert np.all(np.abs(depth - reference.DEFAULT_REFERENCE_DEPTH) < 0.5)  # a moving camera: ~4 m ahead of it
    # the same capture in the frame whose origin is that point: nothing to move, the same tokens
    same = moved(at_camera, centre)
    plain = load(dumps(codec.encode(same, shipped, camera="cam00", quality=9)))
    assert reference.CENTRE_KEY not in plain.metadata["vt4d"]
    np.testing.assert_allclose(scene.static_tokens, plain.static_tokens, atol=1e-5)
    np.testing.assert_allclose(scene.dynamic_tokens, plain.dynamic_tokens, atol=1e-5)
    # and the same pictures, at the encoded camera and at another one (stored cameras differ by their rounding)
    a = codec.SceneDecoder.open(scene, model=shipped).render_many(["source", at_camera.cameras["cam01"]])
    b = codec.SceneDecoder.open(plain, model=shipped).render_many(["source", same.cameras["cam01"]])
    for x, y in zip(a, b):
        assert np.abs(x.astype(int) - y.astype(int)).max() <= 2
    # the codec before the reference moved: this moving camera's own view fell apart (its tokens within 0.74 m
    # of the lens); with the move it is the picture of the generator's own frame
    truth = cap.frames["cam00"].astype(float)
    original = codec.SceneDecoder.open(dumps(codec.encode(cap, shipped, camera="cam00", quality=9)),
                                       model=shipped).render("source")
    with mock.patch.object(codec, "model_centre", lambda frame, trajectories: None):
        unmoved = codec.encode(at_camera, shipped, camera="cam00", quality=9)
    broken = codec.SceneDecoder.open(dumps(unmoved), model=shipped).render("source")

    def error(video):
        return float(np.abs(video - truth).mean())

    assert error(a[0]) < 1.5 * error(original) and error(broken) > 1.4 * error(a[0])


def test_an_origin_in_front_is_left_alone(synth_scene, shipped):
    scene = codec.encode(synth_scene.capture, shipped, camera="cam00", quality=9)
    assert reference.CENTRE_KEY not in scene.metadata["vt4d"]
    assert codec.SceneDecoder.open(dumps(scene), model=shipped).centre() is None


def test_a_malformed_reference_point_is_refused_on_open(synth_scene, shipped):
    scene = codec.encode(synth_scene.capture, shipped, camera="cam00", quality=9)
    bad = dataclasses.replace(scene, metadata={"vt4d": {**scene.metadata["vt4d"], reference.CENTRE_KEY: [1, 2]}})
    with pytest.raises(FormatError, match="centre_mm"):
        codec.SceneDecoder.open(dumps(bad), model=shipped)


def test_a_model_trained_in_the_cameras_frame_always_records_it(tmp_path, small_config, synth_scene):
    """config.reference_frame = "cameras": every encode works in the frame moved to the encoded cameras' point,
    whatever the capture's origin, so the same capture in two world frames gives the same tokens."""
    import torch

    from vt4dcodec.model import VideoTok4D, save_pretrained

    torch.manual_seed(0)
    directory = save_pretrained(VideoTok4D(small_config.replace(reference_frame="cameras")), tmp_path / "m",
                                model_id="test-model", model_version="0.0")
    cap = synth_scene.capture
    scene = codec.encode(cap, directory, cameras=["cam00", "cam01"], seed=0)
    assert reference.CENTRE_KEY in scene.metadata["vt4d"]
    aside = codec.encode(moved(cap, np.array([2.0, -1.0, 0.5])), directory, cameras=["cam00", "cam01"], seed=0)
    np.testing.assert_allclose(aside.static_tokens, scene.static_tokens, atol=1e-4)
    centre = np.asarray(scene.metadata["vt4d"][reference.CENTRE_KEY]) / 1000.0
    np.testing.assert_allclose(np.asarray(aside.metadata["vt4d"][reference.CENTRE_KEY]) / 1000.0,
                               centre - [2.0, -1.0, 0.5], atol=1.5e-3)
