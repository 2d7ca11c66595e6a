"""Issue 13, item 3: every mp4 the project writes is H.264 yuv420p (plays in browsers), written through
PyAV; small renders can be enlarged for viewing (nearest x4); the demo's side-by-side video.  Each test
decodes the written file back with PyAV and checks the codec by name."""

from __future__ import annotations

import av
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vt4dcodec.errors import CaptureError, Vt4dError
from vt4dcodec.media import (MP4_CODEC, read_mp4, mp4_codec_name, psnr, side_by_side, upscale, write_frames,
                             write_mp4)


def smooth(T=8, H=64, W=64, seed=0) -> np.ndarray:
    """A smooth moving gradient: what a video codec is made for, so the round trip is close."""
    y, x = np.mgrid[0:H, 0:W]
    frames = [np.stack([(x * 3 + t * 4 + seed) % 256, (y * 3) % 256, (x + y + 20 * t) % 256], -1)
              for t in range(T)]
    return np.asarray(frames, np.uint8)


def stream_facts(path) -> tuple[str, str, int, int, int]:
    with av.open(str(path)) as c:
        s = c.streams.video[0]
        return s.codec_context.name, s.codec_context.pix_fmt, s.codec_context.width, s.codec_context.height, \
            sum(1 for _ in c.decode(video=0))


def test_write_mp4_is_h264_yuv420p_and_decodes_back_close(tmp_path):
    frames = smooth()
    path = write_mp4(tmp_path / "v.mp4", frames, fps=8)
    assert stream_facts(path) == ("h264", "yuv420p", 64, 64, 8)
    assert mp4_codec_name(path) == MP4_CODEC == "h264"
    back = read_mp4(path)
    assert back.shape == frames.shape and psnr(back, frames) > 35
    with av.open(str(path)) as c:
        assert c.streams.video[0].codec_context.profile == "High"


def test_moov_atom_comes_first_for_streaming(tmp_path):
    """faststart: a browser can start playing before the whole file has arrived."""
    data = write_mp4(tmp_path / "v.mp4", smooth()).read_bytes()
    assert data.index(b"moov") < data.index(b"mdat")


def test_upscale_is_nearest_neighbour_and_the_video_is_that_large(tmp_path):
    frames = smooth(T=3, H=16, W=24)
    big = upscale(frames, 4)
    assert big.shape == (3, 64, 96, 3)
    assert np.array_equal(big[:, ::4, ::4], frames) and np.array_equal(big[:, 3::4, 3::4], frames)
    path = write_mp4(tmp_path / "v.mp4", frames, scale=4)
    assert stream_facts(path)[:5] == ("h264", "yuv420p", 96, 64, 3)
    assert upscale(frames, 1) is frames or np.array_equal(upscale(frames, 1), frames)


@pytest.mark.parametrize("factor", [0, -1, 17, 2.0, True, "4"])
def test_bad_upscale_factor_is_a_typed_error(factor):
    with pytest.raises(Vt4dError, match="upscale"):
        upscale(smooth(T=1, H=4, W=4), factor)


@pytest.mark.parametrize("shape", [(2, 33, 47), (1, 1, 1), (3, 8, 9)])
def test_odd_sides_are_padded_to_even(tmp_path, shape):
    T, H, W = shape
    path = write_mp4(tmp_path / "odd.mp4", smooth(T, H, W))
    name, fmt, w, h, n = stream_facts(path)
    assert (name, fmt, n) == ("h264", "yuv420p", T) and (w, h) == (W + W % 2, H + H % 2)


@pytest.mark.parametrize("bad", [np.zeros((2, 8, 8), np.uint8), np.zeros((2, 8, 8, 3), np.float32),
                                 np.zeros((0, 8, 8, 3), np.uint8), np.zeros((2, 8, 8, 4), np.uint8)])
def test_bad_frames_are_typed_errors(tmp_path, bad):
    with pytest.raises(Vt4dError):
        write_mp4(tmp_path / "x.mp4", bad)


@pytest.mark.parametrize("fps", [0, -1, float("nan"), float("inf")])
def test_bad_fps_is_a_typed_error(tmp_path, fps):
    with pytest.raises(Vt4dError, match="fps"):
        write_mp4(tmp_path / "x.mp4", smooth(T=1, H=8, W=8), fps=fps)


def test_unwritable_path_is_an_os_error(tmp_path):
    with pytest.raises(OSError):
        write_mp4(tmp_path / "no" / "such" / "dir.mp4", smooth(T=1, H=8, W=8))


def test_reading_a_non_video_is_a_typed_error(tmp_path):
    (tmp_path / "x.mp4").write_bytes(b"not a video at all")
    with pytest.raises(Vt4dError):
        read_mp4(tmp_path / "x.mp4")


def test_side_by_side_puts_truth_left_and_decoded_right():
    a, b = smooth(T=2, H=8, W=8, seed=0), smooth(T=2, H=8, W=8, seed=99)
    both = side_by_side(a, b, gap=2)
    assert both.shape == (2, 8, 18, 3)
    assert np.array_equal(both[:, :, :8], a) and np.array_equal(both[:, :, 10:], b)
    assert (both[:, :, 8:10] == 255).all()
    with pytest.raises(Vt4dError):
        side_by_side(a, smooth(T=3, H=8, W=8))
    with pytest.raises(Vt4dError):
        side_by_side()


def test_write_frames_upscales_mp4_only(tmp_path):
    frames = smooth(T=2, H=8, W=8)
    path = write_frames(tmp_path / "v", frames, "mp4", scale=2)
    assert stream_facts(path)[:4] == ("h264", "yuv420p", 16, 16)
    for fmt in ("png", "npz"):
        with pytest.raises(Vt4dError, match="mp4"):
            write_frames(tmp_path / fmt, frames, fmt, scale=2)
    assert np.load(write_frames(tmp_path / "a", frames, "npz"))["frames"].shape == frames.shape


@settings(max_examples=15, deadline=None)
@given(T=st.integers(1, 4), H=st.integers(1, 20), W=st.integers(1, 20), scale=st.integers(1, 3))
def test_any_small_clip_writes_a_decodable_h264_of_the_right_size(tmp_path_factory, T, H, W, scale):
    path = tmp_path_factory.mktemp("v") / "v.mp4"
    write_mp4(path, smooth(T, H, W), scale=scale)
    name, fmt, w, h, n = stream_facts(path)
    assert (name, fmt, n) == ("h264", "yuv420p", T)
    assert (w, h) == (W * scale + (W * scale) % 2, H * scale + (H * scale) % 2)


def test_capture_mp4_media_is_h264_and_odd_sides_are_refused(tmp_path):
    from vt4dcodec.capture import Capture
    from vt4dcodec.capture.io import read_capture, write_capture
    from vt4dcodec.cameras import Trajectory

    K = np.array([[30.0, 0, 16], [0, 30, 12], [0, 0, 1]])
    traj = Trajectory(K=np.repeat(K[None], 4, 0), w2c=np.repeat(np.eye(4)[None], 4, 0), width=32, height=24)
    cap = Capture(cameras={"c": traj}, frames={"c": smooth(4, 24, 32)})
    write_capture(cap, tmp_path / "cap", media="mp4")
    assert mp4_codec_name(tmp_path / "cap" / "c" / "rgb.mp4") == "h264"
    assert psnr(read_capture(tmp_path / "cap").frames["c"], cap.frames["c"]) > 30
    odd = Trajectory(K=np.repeat(K[None], 4, 0), w2c=np.repeat(np.eye(4)[None], 4, 0), width=33, height=24)
    with pytest.raises(CaptureError, match="even"):
        write_capture(Capture(cameras={"c": odd}, frames={"c": smooth(4, 24, 33)}), tmp_path / "odd", media="mp4")
