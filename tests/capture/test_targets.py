"""Capture cameras as render targets: "camera:NAME" over the scene's clip, full-length trajectories cut
to the scene's window, and errors that say the fix (no model needed: resolve_trajectory is pure)."""

import numpy as np
import pytest

from vt4dcodec.capture import write_capture
from vt4dcodec.capture.targets import camera_target, cut_to_clip
from vt4dcodec.codec import resolve_trajectory
from vt4dcodec.errors import TrajectoryError

from capture_helpers import make_capture

CLIP = {"vt4d": {"clip_start": 5, "clip_frames": 8}}


@pytest.fixture
def capture():
    cap = make_capture(T=20, width=32, height=24, depth=False)
    dist = np.array([0.1, -0.05, 0.0, 0.0])
    cap.cameras["cam_b"] = type(cap.cameras["cam_b"])(
        K=cap.cameras["cam_b"].K, w2c=cap.cameras["cam_b"].w2c, width=32, height=24, distortion=dist,
        timestamps=cap.cameras["cam_b"].timestamps)
    return cap


def test_camera_spec_takes_the_scenes_frames_as_a_pinhole_camera(capture, tmp_path):
    write_capture(capture, tmp_path / "cap")
    for source in (capture, tmp_path / "cap"):  # a Capture, or a directory (manifest only)
        traj = resolve_trajectory("camera:cam_b", capture.cameras["cam_a"][:8], size=32, max_frames=8,
                                  metadata=CLIP, capture=source, source_capture_id="test")
        np.testing.assert_allclose(traj.w2c, capture.cameras["cam_b"].w2c[5:13])
        assert traj.distortion is None and traj.num_frames == 8
        assert np.allclose(traj.timestamps, capture.cameras["cam_b"].timestamps[5:13])


def test_full_length_trajectory_is_cut_to_the_clip(capture):
    full = capture.cameras["cam_a"]
    traj = resolve_trajectory(full, full[:8], size=32, max_frames=8, metadata=CLIP)
    np.testing.assert_allclose(traj.w2c, full.w2c[5:13])
    assert cut_to_clip(full[:8], None, 8).num_frames == 8  # fits already: unchanged
    with pytest.raises(TrajectoryError, match=r"records no clip window.*trajectory\[start:start \+ 8\]"):
        resolve_trajectory(full, full[:8], size=32, max_frames=8, metadata={})


def test_camera_target_errors_say_the_fix(capture):
    with pytest.raises(TrajectoryError, match=r"needs the capture the scene was encoded from \('test'\): pass capture=DIR"):
        camera_target("camera:cam_a", None, CLIP, "test", 8)
    with pytest.raises(TrajectoryError, match=r"encoded from capture 'other' but capture 'test'.*pass the capture"):
        camera_target("camera:cam_a", capture, CLIP, "other", 8)
    with pytest.raises(TrajectoryError, match=r"has no camera 'cam_z'; it has \['cam_a', 'cam_b'\]"):
        camera_target("camera:cam_z", capture, CLIP, "test", 8)
    with pytest.raises(TrajectoryError, match="name of a capture camera"):
        camera_target("camera:", capture, CLIP, "test", 8)
    with pytest.raises(TrajectoryError, match="records no clip"):
        camera_target("camera:cam_a", capture, {}, "test", 8)
    short = {"vt4d": {"clip_start": 15, "clip_frames": 8}}
    with pytest.raises(TrajectoryError, match="clip is frames 15..22"):
        camera_target("camera:cam_a", capture, short, "test", 8)


def test_distorted_trajectory_error_names_the_fix(capture):
    with pytest.raises(TrajectoryError, match=r"replace\(trajectory, distortion=None\) or 'camera:NAME'"):
        resolve_trajectory(capture.cameras["cam_b"][:8], capture.cameras["cam_a"][:8], size=32, max_frames=8)
