"""The video codecs and containers the capture reader accepts (FORMAT.md Part III, "Media"): each one the
installed PyAV can encode is written as a tiny clip and read back through the capture reader, whole and
as a window, and probed by ``capture-info --check``."""

import numpy as np
import pytest

from vt4dcodec.capture import read_capture
from vt4dcodec.capture.probe import check_capture

from capture_helpers import smooth_video, video_capture, write_video

# (what FFmpeg reports decoding it, encoders to try in order, container, suffix)
FORMATS = [
    ({"h264"}, ("libx264",), "mp4", ".mp4"),
    ({"h264"}, ("libx264",), "mov", ".mov"),
    ({"h264"}, ("libx264",), "matroska", ".mkv"),
    ({"hevc"}, ("libx265",), "mp4", ".mp4"),
    ({"vp9", "libvpx-vp9"}, ("libvpx-vp9",), "webm", ".webm"),
    ({"vp8", "libvpx"}, ("libvpx",), "webm", ".webm"),
    ({"av1", "libdav1d", "libaom-av1"}, ("libsvtav1", "libaom-av1", "librav1e"), "matroska", ".mkv"),
    ({"av1", "libdav1d", "libaom-av1"}, ("libsvtav1", "libaom-av1", "librav1e"), "mp4", ".mp4"),
    ({"mpeg4"}, ("mpeg4",), "mp4", ".mp4"),
    ({"mpeg4"}, ("mpeg4",), "avi", ".avi"),
    ({"mjpeg"}, ("mjpeg",), "avi", ".avi"),
]


def _encoder(names):
    import av

    for name in names:
        try:
            av.codec.Codec(name, "w")
            return name
        except (av.FFmpegError, ValueError):
            continue
    return None


@pytest.mark.parametrize("decoded_as,encoders,container,suffix", FORMATS,
                         ids=[f"{e[0]}-{c}" for _, e, c, _ in FORMATS])
def test_each_codec_reads_back_through_the_capture_reader(tmp_path, decoded_as, encoders, container, suffix):
    encoder = _encoder(encoders)
    if encoder is None:
        pytest.skip(f"this PyAV has none of the encoders {encoders}")
    T, H, W = 12, 64, 96
    frames = smooth_video(T, H, W, seed=3)
    write_video(tmp_path / f"cam{suffix}", frames, encoder, container=container, options={"g": "4"})
    video_capture(tmp_path, {"cam": f"cam{suffix}"}, T, W, H)
    [report] = check_capture(tmp_path)
    assert report["problems"] == [] and report["probe"]["num_frames"] == T
    assert report["probe"]["codec"] in decoded_as
    whole = read_capture(tmp_path).frames["cam"]
    assert whole.shape == (T, H, W, 3)
    mse = np.mean((whole.astype(float) - frames) ** 2)
    assert 10 * np.log10(255**2 / max(mse, 1e-9)) > 28  # lossy, but these frames, in this order
    window = read_capture(tmp_path, start=3, num_frames=8).frames["cam"]
    np.testing.assert_array_equal(window, whole[3:11])


def test_png_sequences_are_read_losslessly(tmp_path):
    from vt4dcodec.capture import Capture, write_capture

    from capture_helpers import make_trajectory

    frames = smooth_video(5, 24, 32)
    write_capture(Capture(cameras={"cam": make_trajectory(5, 32, 24)}, frames={"cam": frames}), tmp_path)
    np.testing.assert_array_equal(read_capture(tmp_path, start=1, num_frames=3).frames["cam"], frames[1:4])
