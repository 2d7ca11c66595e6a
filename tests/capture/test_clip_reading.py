"""Clip reading: only the cameras and frames asked for are decoded, videos are seeked rather than decoded
from the start, and the size limit applies to what one read decodes, not to the capture."""

import numpy as np
import pytest

from vt4dcodec.capture import read_capture, write_capture
from vt4dcodec.capture import video as video_mod
from vt4dcodec.capture.io import MAX_READ_PIXELS, read_camera_frames
from vt4dcodec.errors import CaptureError

from capture_helpers import make_capture, numbered_video, video_capture, write_video


def decoded_all(path):
    import av

    with av.open(str(path)) as c:
        return np.stack([f.to_ndarray(format="rgb24") for f in c.decode(video=0)])


@pytest.mark.parametrize("file,codec,container,options", [
    ("h264_gop4.mp4", "libx264", "mp4", {"g": "4", "bf": "2"}),
    ("h264_default.mp4", "libx264", "mp4", {}),
    ("vp9.webm", "libvpx-vp9", "webm", {"g": "5"}),
    ("mpeg4.avi", "mpeg4", "avi", {"g": "6"}),
])
def test_a_window_is_exactly_those_frames_of_the_whole_video(tmp_path, file, codec, container, options):
    T = 30
    write_video(tmp_path / file, numbered_video(T), codec, container=container, options=options)
    manifest = video_capture(tmp_path, {"cam": file}, T, 64, 48)
    whole = decoded_all(tmp_path / file)
    assert len(whole) == T
    np.testing.assert_array_equal(read_camera_frames(manifest, "cam"), whole)
    for start, n in ((0, 8), (1, 8), (13, 8), (22, 8), (29, 1)):
        np.testing.assert_array_equal(read_camera_frames(manifest, "cam", start, n), whole[start:start + n])


def test_seeking_skips_the_frames_before_the_window(tmp_path, monkeypatch):
    T = 64
    write_video(tmp_path / "v.mp4", numbered_video(T), "libx264", container="mp4",
                options={"g": "8", "keyint_min": "8", "sc_threshold": "0"})
    manifest = video_capture(tmp_path, {"cam": "v.mp4"}, T, 64, 48)
    decoded = []
    by_grid = video_mod._frames_by_grid

    def spy(*args):
        for index, frame in by_grid(*args):
            decoded.append(index)
            yield index, frame

    monkeypatch.setattr(video_mod, "_frames_by_grid", spy)
    clip = read_camera_frames(manifest, "cam", 50, 8)
    np.testing.assert_array_equal(clip, decoded_all(tmp_path / "v.mp4")[50:58])
    assert decoded and min(decoded) >= 48 and max(decoded) <= 58  # from the keyframe at 48, not frame 0


def test_variable_frame_rate_is_read_by_counting(tmp_path):
    """Timestamps off the frame-rate grid: frame k is still the k-th frame presented."""
    T = 20
    pts = np.cumsum([0] + [40, 40, 120, 40, 20, 40, 40, 160, 40, 40, 40, 80, 40, 40, 40, 80, 40, 40, 40])
    write_video(tmp_path / "vfr.mkv", numbered_video(T), "libx264", container="matroska", pts=pts)
    manifest = video_capture(tmp_path, {"cam": "vfr.mkv"}, T, 64, 48)
    whole = decoded_all(tmp_path / "vfr.mkv")
    for start, n in ((0, 8), (5, 8), (12, 8)):
        np.testing.assert_array_equal(read_camera_frames(manifest, "cam", start, n), whole[start:start + n])


def test_frame_count_checks_without_a_declared_count(tmp_path):
    """webm declares no frame count: a video longer than the manifest is caught when its last clip is
    read, a shorter one when a clip runs past its end."""
    write_video(tmp_path / "v.webm", numbered_video(12), "libvpx-vp9", container="webm")
    manifest = video_capture(tmp_path, {"cam": "v.webm"}, 10, 64, 48)
    read_camera_frames(manifest, "cam", 0, 8)  # a clip inside the video reads
    with pytest.raises(CaptureError, match="more than the 10 frames"):
        read_camera_frames(manifest, "cam", 2, 8)
    manifest = video_capture(tmp_path, {"cam": "v.webm"}, 16, 64, 48)
    with pytest.raises(CaptureError, match="has 12 frames but frames 8..15"):
        read_camera_frames(manifest, "cam", 8, 8)


def test_size_is_checked_before_decoding(tmp_path):
    write_video(tmp_path / "v.mp4", numbered_video(4), "libx264", container="mp4")
    manifest = video_capture(tmp_path, {"cam": "v.mp4"}, 4, 32, 48)
    with pytest.raises(CaptureError, match="64x48, manifest says 32x48"):
        read_camera_frames(manifest, "cam", 0, 2)


@pytest.mark.parametrize("media,depth", [("png", "npy"), ("png", "png16"), ("mp4", "npy")])
def test_read_capture_takes_a_window_of_some_cameras(tmp_path, media, depth):
    T, W, H = 6, 32, 24
    cap = make_capture(T, W, H, cameras=("cam_a", "cam_b", "cam_c"), depth=True)
    cap.depth = {"cam_b": cap.depth.pop("cam_a")}
    write_capture(cap, tmp_path, media=media, depth=depth)
    whole = read_capture(tmp_path)
    part = read_capture(tmp_path, cameras=["cam_c", "cam_b"], start=2, num_frames=3)
    assert part.camera_names == ["cam_c", "cam_b"] and part.num_frames == 3
    for name in part.camera_names:
        np.testing.assert_array_equal(part.frames[name], whole.frames[name][2:5])
        assert part.cameras[name].equals(whole.cameras[name][2:5])
    np.testing.assert_array_equal(part.depth["cam_b"], whole.depth["cam_b"][2:5])
    assert not part.has_depth("cam_c")


@pytest.mark.parametrize("kwargs,match", [
    ({"start": 6}, "start frame 6 outside"),
    ({"start": -1}, "start frame -1 outside"),
    ({"start": 2, "num_frames": 5}, "4 frames from frame 2"),
    ({"num_frames": 0}, "num_frames 0"),
    ({"cameras": ["cam_a", "cam_a"]}, "distinct cameras"),
    ({"cameras": ["nope"]}, "no camera 'nope'"),
])
def test_bad_windows_are_refused(tmp_path, kwargs, match):
    write_capture(make_capture(6, 8, 6, depth=False), tmp_path)
    with pytest.raises(CaptureError, match=match):
        read_capture(tmp_path, **kwargs)


def test_limits_apply_to_what_is_read(tmp_path):
    """10 minutes of 8 cameras at 4K60 is a valid capture; reading it whole is refused, a clip is not."""
    T, W, H = 36_000, 3840, 2160
    manifest = video_capture(tmp_path, {f"cam{i}": f"cam{i}.mp4" for i in range(8)}, T, W, H, fps=60.0)
    assert manifest.num_frames == T and len(manifest.cameras) == 8
    assert 8 * T * W * H > MAX_READ_PIXELS
    with pytest.raises(CaptureError, match="over the limit .* read a clip at a time"):
        read_capture(tmp_path)
    with pytest.raises(CaptureError, match="over the limit"):
        read_camera_frames(manifest, "cam3")
    with pytest.raises(CaptureError, match="missing video"):  # the limit passes; only the media are missing
        read_capture(tmp_path, cameras=["cam3"], start=20_000, num_frames=8)


def test_a_contact_sheet_reads_only_the_frames_it_shows(tmp_path):
    from vt4dcodec.capture.contact_sheet import contact_sheet, read_sheet_frames

    T = 30
    write_video(tmp_path / "a.mp4", numbered_video(T), "libx264", container="mp4", options={"g": "5"})
    write_video(tmp_path / "b.webm", numbered_video(T)[::-1].copy(), "libvpx-vp9", container="webm")
    video_capture(tmp_path, {"a": "a.mp4", "b": "b.webm"}, T, 64, 48)
    shown, numbers = read_sheet_frames(tmp_path, 4)
    assert numbers == [0, 10, 19, 29] and shown.num_frames == 4
    whole = read_capture(tmp_path)
    for name in ("a", "b"):
        np.testing.assert_array_equal(shown.frames[name], whole.frames[name][numbers])
    np.testing.assert_array_equal(contact_sheet(shown, frame_numbers=numbers), contact_sheet(whole, max_frames=4))
