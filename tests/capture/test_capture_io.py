"""Capture directories: write/read round trips and clear errors for broken directories."""

import json
import shutil

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vt4dcodec.capture import Capture, read_capture, write_capture
from vt4dcodec.capture.io import MANIFEST_NAME, read_manifest
from vt4dcodec.errors import CameraError, CaptureError

from capture_helpers import make_capture, make_trajectory, smooth_video


def assert_same(a: Capture, b: Capture, *, depth_atol=0.0):
    assert list(a.cameras) == list(b.cameras)
    assert a.fps == b.fps and a.capture_id == b.capture_id and a.metadata == b.metadata
    for n in a.cameras:
        assert a.cameras[n].equals(b.cameras[n])
        np.testing.assert_array_equal(a.frames[n], b.frames[n])
        assert a.has_depth(n) == b.has_depth(n)
        if a.has_depth(n):
            np.testing.assert_allclose(a.depth[n], b.depth[n], atol=depth_atol, rtol=0)


@given(T=st.integers(1, 3), W=st.integers(1, 9), H=st.integers(1, 7), ncam=st.integers(1, 3),
       seed=st.integers(0, 2**31 - 1), depth=st.booleans())
@settings(max_examples=15)
def test_png_round_trip_is_lossless(tmp_path_factory, T, W, H, ncam, seed, depth):
    cap = make_capture(T, W, H, cameras=tuple(f"c{i}" for i in range(ncam)), depth=depth, seed=seed)
    d = tmp_path_factory.mktemp("cap")
    write_capture(cap, d)
    assert_same(cap, read_capture(d))


def test_png16_depth_round_trips_to_a_millimetre(tmp_path):
    cap = make_capture()
    name = next(iter(cap.depth))
    cap.depth[name][0, 0, 0] = 0.0  # unknown stays unknown
    cap.depth[name][0, 0, 1] = np.nan
    write_capture(cap, tmp_path, depth="png16")
    back = read_capture(tmp_path)
    known = np.isfinite(cap.depth[name]) & (cap.depth[name] > 0)
    np.testing.assert_allclose(back.depth[name][known], cap.depth[name][known], atol=5e-4 + 1e-6, rtol=0)
    assert back.depth[name][0, 0, 0] == 0 and back.depth[name][0, 0, 1] == 0
    assert back.depth[name].dtype == np.float32


def test_png16_depth_refuses_far_depth(tmp_path):
    cap = make_capture()
    next(iter(cap.depth.values()))[0, 0, 0] = 70.0
    with pytest.raises(CaptureError, match="65.535"):
        write_capture(cap, tmp_path, depth="png16")


def test_mp4_round_trip_is_close(tmp_path):
    T, H, W = 4, 48, 64
    frames = {"cam_a": smooth_video(T, H, W, 1), "cam_b": smooth_video(T, H, W, 2)}
    cap = make_capture(T, W, H, frames=frames)
    write_capture(cap, tmp_path, media="mp4")
    assert (tmp_path / "cam_a" / "rgb.mp4").is_file()
    back = read_capture(tmp_path)
    for n in frames:
        assert back.frames[n].shape == frames[n].shape
        err = np.abs(back.frames[n].astype(np.int16) - frames[n]).mean()
        assert err < 6.0, f"{n}: mean abs error {err:.2f} of 255"
        assert back.cameras[n].equals(cap.cameras[n])


def test_static_camera_and_constant_K_are_stored_once(tmp_path):
    traj = make_trajectory(4, moving=False)
    cap = Capture(cameras={"c": traj}, frames={"c": np.zeros((4, 24, 32, 3), np.uint8)})
    write_capture(cap, tmp_path)
    doc = json.loads((tmp_path / MANIFEST_NAME).read_text())
    assert np.asarray(doc["cameras"][0]["w2c"]).shape == (4, 4)
    assert np.asarray(doc["cameras"][0]["K"]).shape == (3, 3)
    assert read_capture(tmp_path).cameras["c"].equals(traj)


def test_distortion_round_trips(tmp_path):
    traj = make_trajectory(2, distortion=np.array([-0.1, 0.01, 0.001, -0.001, 0.0]))
    cap = Capture(cameras={"c": traj}, frames={"c": np.zeros((2, 24, 32, 3), np.uint8)})
    write_capture(cap, tmp_path)
    assert read_capture(tmp_path).cameras["c"].equals(traj)


def test_refuses_to_overwrite_without_flag(tmp_path):
    cap = make_capture()
    write_capture(cap, tmp_path)
    with pytest.raises(CaptureError, match="already holds"):
        write_capture(cap, tmp_path)
    write_capture(cap, tmp_path, overwrite=True)
    assert_same(cap, read_capture(tmp_path))


# --- broken directories ------------------------------------------------------------------------------
@pytest.fixture
def written(tmp_path):
    cap = make_capture(3)
    write_capture(cap, tmp_path)
    return tmp_path


def edit_manifest(directory, change):
    path = directory / MANIFEST_NAME
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


def test_missing_manifest(tmp_path):
    with pytest.raises(CaptureError, match="no capture.json"):
        read_capture(tmp_path)
    with pytest.raises(CaptureError, match="not a directory"):
        read_capture(tmp_path / "nope")


def test_missing_frame_file(written):
    (written / "cam_a" / "rgb" / "000001.png").unlink()
    with pytest.raises(CaptureError, match="missing.*000001.png"):
        read_capture(written)


def test_mismatched_frame_count(written):
    shutil.copy(written / "cam_b" / "rgb" / "000000.png", written / "cam_b" / "rgb" / "000003.png")
    with pytest.raises(CaptureError, match="manifest says 3 frames"):
        read_capture(written)


def test_missing_depth_file(written):
    (written / "cam_a" / "depth.npy").unlink()
    with pytest.raises(CaptureError, match="missing depth"):
        read_capture(written)


def test_wrong_depth_shape(written):
    np.save(written / "cam_a" / "depth.npy", np.zeros((2, 24, 32), np.float32))
    with pytest.raises(CaptureError, match="float32"):
        read_capture(written)


def test_pickled_depth_is_refused(written):
    np.save(written / "cam_a" / "depth.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)  # pickle-check: writes a hostile file the reader must refuse
    with pytest.raises(CaptureError):
        read_capture(written)


def test_wrong_image_size(written):
    edit_manifest(written, lambda d: d["cameras"][0].update(width=31))
    with pytest.raises(CaptureError, match="manifest says 31x24"):
        read_capture(written)


@pytest.mark.parametrize("change, error, match", [
    (lambda d: d["cameras"][0]["K"].__setitem__(0, [float("nan"), 0, 1]), CameraError, "non-finite"),
    (lambda d: d["cameras"][0]["K"].__setitem__(0, [-5.0, 0, 1]), CameraError, "focal"),
    (lambda d: d["cameras"][0]["K"].__setitem__(0, [0.0, 0, 1]), CameraError, "focal"),
    (lambda d: d["cameras"][0]["w2c"][1].__setitem__(0, [1.0, 0.5, 0, 0]), CameraError, "orthonormal"),
    (lambda d: d["cameras"][0]["w2c"][1].__setitem__(0, [-1.0, 0, 0, 0]), CameraError, "reflection"),
    (lambda d: d["cameras"][0].update(w2c=[[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]] * 2),
     CameraError, "one per frame"),
    (lambda d: d["cameras"][0].update(timestamps=[0.0, 0.2, 0.1]), CameraError, "non-decreasing"),
    (lambda d: d["cameras"][0].update(distortion=[0.1, 0.2, 0.3]), CameraError, "distortion"),
    (lambda d: d.update(num_frames=2), CameraError, "one per frame"),
    (lambda d: d.update(num_frames=10**9), CaptureError, "num_frames"),
    (lambda d: d.update(fps=0), CaptureError, "fps"),
    (lambda d: d.update(version=2), CaptureError, "version"),
    (lambda d: d.update(format="other"), CaptureError, "format"),
    (lambda d: d.update(cameras=[]), CaptureError, "cameras"),
    (lambda d: d["cameras"][1].update(name="cam_a"), CaptureError, "unique"),
    (lambda d: d["cameras"][0].update(name="../x"), CaptureError, "name"),
    (lambda d: d["cameras"][0]["media"].update(path="../../etc"), CaptureError, "inside"),
    (lambda d: d["cameras"][0]["media"].update(path="/etc"), CaptureError, "inside"),
    (lambda d: d["cameras"][0]["media"].update(type="avi"), CaptureError, "media type"),
    (lambda d: d["cameras"][0].update(width=10**6), CaptureError, "image size"),
    (lambda d: d["cameras"][0].update(width=True), CaptureError, "wrong type"),
    (lambda d: d["cameras"][0].pop("K"), CaptureError, "missing 'K'"),
])
def test_bad_manifest_is_reported(written, change, error, match):
    edit_manifest(written, change)
    with pytest.raises(error, match=match):
        read_manifest(written)


def test_manifest_not_json(written):
    (written / MANIFEST_NAME).write_bytes(b"\xff\x00{")
    with pytest.raises(CaptureError, match="JSON"):
        read_capture(written)


def test_mp4_with_wrong_frame_count(tmp_path):
    T, H, W = 3, 24, 32
    cap = make_capture(T, W, H, frames={n: smooth_video(T, H, W) for n in ("cam_a", "cam_b")}, depth=False)
    write_capture(cap, tmp_path, media="mp4")

    def claim(n):
        def change(doc):
            doc["num_frames"] = n
            for cam in doc["cameras"]:
                if np.asarray(cam["w2c"]).ndim == 3:
                    cam["w2c"] = cam["w2c"][0]  # one static pose fits any length
                cam["timestamps"] = None
        return change

    for n, expected in ((2, "declares 3 frames but the manifest says 2"), (5, "declares 3 frames but the manifest says 5")):
        edit_manifest(tmp_path, claim(n))
        with pytest.raises(CaptureError, match=expected):
            read_capture(tmp_path)


def test_png_of_the_wrong_size_is_refused_before_decoding(written):
    import cv2

    cv2.imwrite(str(written / "cam_b" / "rgb" / "000002.png"), np.zeros((2000, 3000, 3), np.uint8))
    with pytest.raises(CaptureError, match="3000x2000, manifest says 32x24"):
        read_capture(written)
    (written / "cam_b" / "rgb" / "000002.png").write_bytes(b"GIF89a not a png at all....")
    with pytest.raises(CaptureError, match="not a PNG"):
        read_capture(written)


def test_symlink_out_of_the_directory_is_refused(written, tmp_path_factory):
    outside = tmp_path_factory.mktemp("outside")
    shutil.move(str(written / "cam_b" / "rgb"), str(outside / "rgb"))
    (written / "cam_b" / "rgb").symlink_to(outside / "rgb", target_is_directory=True)
    with pytest.raises(CaptureError, match="leaves the capture directory"):
        read_capture(written)


def test_strings_and_booleans_are_not_numbers(written):
    edit_manifest(written, lambda d: d["cameras"][0]["K"].__setitem__(0, ["40", 0, 1]))
    with pytest.raises(CameraError, match="list of numbers"):
        read_manifest(written)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**20, 10**20) | st.floats() | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=5), inner, max_size=3),
    max_leaves=10,
)


def _paths(doc, prefix=()):
    """Every (container, key) location in a JSON document."""
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for k, v in items:
        yield prefix + (k,)
        yield from _paths(v, prefix + (k,))


@given(data=st.data())
@settings(max_examples=60)
def test_fuzzed_manifests_fail_cleanly(tmp_path_factory, data):
    """Replacing any value of a valid manifest by arbitrary JSON gives a capture or a Vt4dError,
    never another exception."""
    from vt4dcodec.errors import Vt4dError

    d = tmp_path_factory.mktemp("fuzz")
    write_capture(make_capture(2, 6, 4), d)
    doc = json.loads((d / MANIFEST_NAME).read_text())
    locations = sorted(_paths(doc), key=repr)
    where = data.draw(st.sampled_from(locations))
    target = doc
    for k in where[:-1]:
        target = target[k]
    target[where[-1]] = data.draw(json_values)
    (d / MANIFEST_NAME).write_text(json.dumps(doc))
    try:
        read_capture(d)
    except Vt4dError:
        pass
