"""`vt4d import` of the field's datasets and of Pose2Sim's demo layout, each from a fixture written here in
the dataset's own published convention from known cameras, checked by reprojecting known 3-D points:

- N3DV / DyNeRF: ``poses_bounds.npy`` as LLFF's imgs2poses writes it (camera-to-world columns [down, right,
  backwards] = OpenCV's ``[c1, c0, -c2]``, hwf, near/far) beside ``cam00.mp4`` ...;
- MultiCamVideo (ReCamMaster): ``cameras/camera_extrinsics.json`` with Unreal Engine transforms (row
  vectors: forward, right, up axes and the position in cm) per frame and camera, ``videos/cam01.mp4`` ...,
  and the documented lens (f in mm from ``f<mm>_aperture<N>``, a 23.76 mm sensor over 1280 px);
- Pose2Sim's demo: 1080-wide videos under a 1088-wide calibration whose cameras are ``int_camNN_img``.
"""

import json

import numpy as np
import pytest

from vt4dcodec.capture.calibration import read_calibration
from vt4dcodec.capture.importer import CalibrationSizeWarning, camera_number, import_capture
from vt4dcodec.capture.io import read_capture
from vt4dcodec.cli import main
from vt4dcodec.errors import CaptureError

from test_import import H, K_TRUE, NAMES, POINTS, T, W, W2C_TRUE, pinhole, toml_text, write_videos

TOLERANCE_PX = 0.01


def worst_error(manifest, expected, points_for=lambda name: POINTS):
    """Max pixel distance, over cameras and frames, between the imported cameras' projections of known
    points and ``expected[name][t]`` (where the original cameras put them)."""
    worst = 0.0
    for name, per_frame in expected.items():
        traj = manifest.camera(name).trajectory
        assert traj.num_frames == len(per_frame) == manifest.num_frames
        for t, want in enumerate(per_frame):
            worst = max(worst, float(np.abs(pinhole(traj.K[t], traj.w2c[t], points_for(name)) - want).max()))
    return worst


# --- N3DV / DyNeRF: poses_bounds.npy -----------------------------------------------------------------
FOCAL = 29.0
K_LLFF = np.array([[FOCAL, 0.0, (W - 1) / 2], [0.0, FOCAL, (H - 1) / 2], [0.0, 0.0, 1.0]])  # hwf: centred, fx = fy
NEAR_FAR = {n: (0.5 + i, 9.0 + i) for i, n in enumerate(NAMES)}


def llff_row(w2c, near, far):
    """One row of poses_bounds.npy for an OpenCV camera, as LLFF's imgs2poses writes it from COLMAP: the
    camera-to-world columns [r, d, f] become [d, r, -f] ([down, right, backwards]), then [h, w, focal]."""
    c2w = np.linalg.inv(w2c)
    m = np.stack([c2w[:3, 1], c2w[:3, 0], -c2w[:3, 2], c2w[:3, 3], [H, W, FOCAL]], axis=1)
    return np.concatenate([m.ravel(), [near, far]])


def write_n3dv(scene):
    write_videos(scene)  # cam00.mp4 cam01.mp4 cam02.mp4 beside the poses, as N3DV ships them
    np.save(scene / "poses_bounds.npy", np.stack([llff_row(W2C_TRUE[n], *NEAR_FAR[n]) for n in NAMES]))
    return scene


def test_n3dv_poses_bounds_import_and_reproject(tmp_path):
    scene = write_n3dv(tmp_path / "coffee_martini")
    m = import_capture(scene, None, tmp_path / "cap")  # detected; the videos beside the poses are the media
    calib = m.metadata["calibration"]
    assert calib["format"] == "n3dv" and [e.name for e in m.cameras] == list(NAMES)
    expected = {n: [pinhole(K_LLFF, W2C_TRUE[n], POINTS)] * T for n in NAMES}
    assert worst_error(m, expected) < TOLERANCE_PX
    assert calib["near_far"] == {n: list(NEAR_FAR[n]) for n in NAMES}  # near/far kept, in metres
    assert read_capture(tmp_path / "cap").frames["cam01"].shape == (T, H, W, 3)


def test_n3dv_axes_agree_with_the_dynerf_loaders(tmp_path):
    """The DyNeRF loaders (nerf's load_llff, 4DGaussians, K-Planes) turn LLFF's [down, right, back] into
    OpenGL's [right, up, back] as ``[c1, -c0, c2]``: the imported OpenCV camera is that with y and z flipped."""
    rows = np.load(write_n3dv(tmp_path / "s") / "poses_bounds.npy")
    _, cams = read_calibration(tmp_path / "s" / "poses_bounds.npy")
    for row, cam in zip(rows, cams):
        m = row[:15].reshape(3, 5)
        c2w_gl = np.stack([m[:, 1], -m[:, 0], m[:, 2], m[:, 3]], axis=1)
        c2w_cv = np.linalg.inv(cam.w2c)[:3]
        np.testing.assert_allclose(c2w_cv @ np.diag([1.0, -1.0, -1.0, 1.0]), c2w_gl, atol=1e-12)
        assert (cam.width, cam.height) == (W, H) and cam.K[0, 0] == FOCAL


def test_n3dv_rows_pair_with_the_videos_in_name_order(tmp_path):
    scene = write_n3dv(tmp_path / "s")
    (scene / "cam02.mp4").rename(scene / "cam07.mp4")  # a gap in the numbers: row 2 is still the third video
    m = import_capture(scene / "poses_bounds.npy", scene, tmp_path / "cap")
    assert [e.name for e in m.cameras] == ["cam00", "cam01", "cam07"]
    write_videos(scene, names=("cam09",))
    with pytest.raises(CaptureError, match=r"3 camera rows but .* holds 4 videos"):
        import_capture(scene, None, tmp_path / "cap2")
    with pytest.raises(CaptureError, match=r"--map\) does not apply to N3DV"):
        import_capture(scene, None, tmp_path / "cap2", camera_map={"cam00": "cam09.mp4"})


def test_n3dv_refuses_a_malformed_array(tmp_path):
    np.save(tmp_path / "poses_bounds.npy", np.zeros((3, 15)))
    with pytest.raises(CaptureError, match="N x 17"):
        read_calibration(tmp_path / "poses_bounds.npy")


# --- MultiCamVideo (ReCamMaster): cameras/camera_extrinsics.json -------------------------------------
FOCAL_MM, SIDE = 18.0, 32  # the fixture's videos are 32 x 32: the dataset's 1280 x 1280, rescaled
F_PX = FOCAL_MM / 23.76 * SIDE
UNREAL_POINTS = np.random.default_rng(1).uniform(-40.0, 40.0, size=(20, 3)) + [0.0, 0.0, 100.0]  # cm
MCV_NAMES = ("cam01", "cam02", "cam03")


def unreal_camera(i, t):
    """Camera i at frame t in Unreal terms: its forward, right and up axes (rows) and position in cm.
    Unreal is left-handed (x forward, y right, z up); the cameras circle the points and roll a little."""
    angle = 0.6 * i + 0.05 * t
    position = np.array([-400.0 * np.cos(angle), -400.0 * np.sin(angle), 150.0 + 10.0 * t])
    forward = np.array([0.0, 0.0, 100.0]) - position
    forward /= np.linalg.norm(forward)
    right = np.cross([0.0, 0.0, 1.0], forward)  # in Unreal's coordinates: z x forward points right
    right /= np.linalg.norm(right)
    up = np.cross(forward, right)
    roll = 0.1 * (i - 1)
    right, up = np.cos(roll) * right + np.sin(roll) * up, -np.sin(roll) * right + np.cos(roll) * up
    return np.stack([forward, right, up]), position


def unreal_pixels(i, t):
    """Where an Unreal camera sees UNREAL_POINTS: image right is the camera's +y (right), image up its +z."""
    axes, position = unreal_camera(i, t)
    d = (UNREAL_POINTS - position) @ axes.T  # (forward, right, up) coordinates
    c = (SIDE - 1) / 2
    return np.stack([c + F_PX * d[:, 1] / d[:, 0], c - F_PX * d[:, 2] / d[:, 0]], axis=-1)


def unreal_matrix_text(i, t, rows_of=4):
    axes, position = unreal_camera(i, t)
    rows = [[*axes[k], 0.0] for k in range(3)] + [[*position, 1.0]]
    return " ".join("[" + " ".join(repr(float(v)) for v in row[:rows_of]) + "]" for row in rows)


def write_multicamvideo(scene, frames=T, rows_of=4):
    """A scene as the dataset ships it: videos/camNN.mp4 and cameras/camera_extrinsics.json."""
    write_videos(scene / "videos", names=MCV_NAMES, width=SIDE, height=SIDE)
    doc = {f"frame{t}": {n: unreal_matrix_text(i, t, rows_of) for i, n in enumerate(MCV_NAMES)}
           for t in range(frames)}
    (scene / "cameras").mkdir(parents=True)
    (scene / "cameras" / "camera_extrinsics.json").write_text(json.dumps(doc, indent=2))
    return scene


def metric_points(name):
    """UNREAL_POINTS in the imported world: metres, Unreal's y axis negated."""
    return UNREAL_POINTS * [0.01, -0.01, 0.01]


def test_multicamvideo_import_and_reproject(tmp_path):
    scene = write_multicamvideo(tmp_path / "MultiCamVideo-Dataset" / "train" / "f18_aperture10" / "scene1")
    m = import_capture(scene, None, tmp_path / "cap", scale_intrinsics=True)  # 1280 px calibration -> 32 px
    calib = m.metadata["calibration"]
    assert calib["format"] == "multicamvideo" and calib["focal_mm"] == pytest.approx(FOCAL_MM)
    assert calib["units"].startswith("metres")
    expected = {n: [unreal_pixels(i, t) for t in range(T)] for i, n in enumerate(MCV_NAMES)}
    assert worst_error(m, expected, metric_points) < TOLERANCE_PX
    assert not np.all(m.camera("cam02").trajectory.w2c == m.camera("cam02").trajectory.w2c[0])  # moving cameras


def test_multicamvideo_relative_poses_match_recammasters_loader(tmp_path):
    """ReCamMaster's loader: transpose the matrix, take columns [1, 2, 0, 3], negate column 1, divide the
    translation by 100; only relative poses are used.  The imported cameras give the same ones."""
    scene = write_multicamvideo(tmp_path / "f24_aperture5" / "scene7")
    _, cams = read_calibration(scene / "cameras" / "camera_extrinsics.json")
    doc = json.loads((scene / "cameras" / "camera_extrinsics.json").read_text())
    for i, cam in enumerate(cams):
        loader = []
        for t in range(T):
            rows = [[float(v) for v in r.split()] for r in doc[f"frame{t}"][cam.name].strip("[] ").split("] [")]
            c2w = np.array(rows).T[:, [1, 2, 0, 3]]
            c2w[:3, 1] *= -1.0
            c2w[:3, 3] /= 100.0
            loader.append(c2w)
        ours = np.linalg.inv(cam.w2c)
        for t in range(1, T):
            np.testing.assert_allclose(np.linalg.inv(ours[0]) @ ours[t], np.linalg.inv(loader[0]) @ loader[t],
                                       atol=1e-9)
        assert np.linalg.det(cam.w2c[0, :3, :3]) > 0  # a proper rotation, where the loader's has det -1
    assert cams[0].K[0, 0] == pytest.approx(24.0 / 23.76 * 1280) and cams[0].K[0, 2] == 639.5


def test_multicamvideo_focal_from_the_flag_and_rows_of_three(tmp_path, capsys):
    scene = write_multicamvideo(tmp_path / "val" / "10basic_trajectories", rows_of=3)  # no f<mm>_ folder
    with pytest.raises(CaptureError, match=r"--focal-mm F"):
        import_capture(scene, None, tmp_path / "cap", scale_intrinsics=True)
    assert main(["import", str(scene), "-o", str(tmp_path / "cap")]) == 1
    assert "--focal-mm" in capsys.readouterr().err
    args = ["import", str(scene), "-o", str(tmp_path / "cap"), "--focal-mm", "18", "--scale-intrinsics", "--json"]
    assert main(args) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["calibration"]["format"] == "multicamvideo" and info["num_cameras"] == 3
    from vt4dcodec.capture.io import read_manifest

    expected = {n: [unreal_pixels(i, t) for t in range(T)] for i, n in enumerate(MCV_NAMES)}
    assert worst_error(read_manifest(tmp_path / "cap"), expected, metric_points) < TOLERANCE_PX


def test_multicamvideo_more_poses_than_frames_names_frames(tmp_path):
    scene = write_multicamvideo(tmp_path / "f35_aperture2.4" / "scene2", frames=T + 2)
    with pytest.raises(CaptureError, match=rf"poses for {T + 2} frames and its media {T}.*--frames {T}"):
        import_capture(scene, None, tmp_path / "cap", scale_intrinsics=True)
    m = import_capture(scene, None, tmp_path / "cap", scale_intrinsics=True, frames=T)
    assert m.num_frames == T and m.camera("cam01").trajectory.num_frames == T


# --- Pose2Sim's demo layout: padded calibration, int_camNN_img names ---------------------------------
POSE2SIM_NAMES = ("int_cam01_img", "int_cam02_img", "int_cam03_img")


def test_pose2sim_demo_layout_imports_without_hand_edits(tmp_path):
    calib = tmp_path / "Calib_scene.toml"
    calib.write_text(toml_text(POSE2SIM_NAMES, size=(W + 8, H)))  # calibrated 8 px wider (1088 for 1080 videos)
    videos = write_videos(tmp_path / "videos", names=("cam01", "cam02", "cam03"))
    with pytest.warns(CalibrationSizeWarning) as caught:
        m = import_capture(calib, videos, tmp_path / "cap")
    assert len(caught) == 3 and str(caught[0].message) == (
        f"camera 'int_cam01_img': cam01.mp4 is {W}x{H}, 8 px narrower than the calibrated {W + 8}x{H}: taken as "
        "encoder padding cut off the right and bottom, K unchanged")
    assert [e.name for e in m.cameras] == list(POSE2SIM_NAMES)
    expected = {p: [pinhole(K_TRUE[n], W2C_TRUE[n], POINTS)] * T for p, n in zip(POSE2SIM_NAMES, NAMES)}
    assert worst_error(m, expected) < TOLERANCE_PX
    traj = m.camera("int_cam02_img").trajectory
    assert (traj.width, traj.height) == (W, H) and np.array_equal(traj.K[0], K_TRUE["cam01"])
    media = m.metadata["media"]["int_cam03_img"]
    assert media["matched_by"] == "number" and media["calibrated_size"] == [W + 8, H]
    assert media["source"].endswith("cam03.mp4")


def test_pose2sim_layout_on_the_command_line(tmp_path, capsys):
    calib = tmp_path / "Calib_scene.toml"
    calib.write_text(toml_text(POSE2SIM_NAMES, size=(W + 8, H + 8)))
    videos = write_videos(tmp_path / "videos", names=("cam01", "cam02", "cam03"))
    assert main(["import", str(calib), str(videos), "-o", str(tmp_path / "cap")]) == 0
    out, err = capsys.readouterr()
    assert "int_cam01_img <- " in out and "by camera number" in out
    assert err.count("vt4d import: warning:") == 3 and "8 px narrower and 8 px shorter" in err


def test_padding_beyond_16_pixels_or_larger_media_is_refused(tmp_path):
    calib = tmp_path / "c.toml"
    calib.write_text(toml_text(size=(W + 17, H)))
    videos = write_videos(tmp_path / "videos")
    with pytest.raises(CaptureError, match=rf"is {W}x{H} but the calibration is for {W + 17}x{H}"):
        import_capture(calib, videos, tmp_path / "cap")
    calib.write_text(toml_text(size=(W - 4, H)))  # media larger than the calibration: not padding
    with pytest.raises(CaptureError, match=rf"is {W}x{H} but the calibration is for {W - 4}x{H}"):
        import_capture(calib, videos, tmp_path / "cap")


def test_camera_numbers():
    assert [camera_number(n) for n in ("int_cam01_img", "cam01", "cam_1", "Camera 12", "rig2_cam03", "left")] == \
        [1, 1, 1, 12, 3, None]


def test_explicit_map_for_media_named_otherwise(tmp_path, capsys):
    calib = tmp_path / "c.toml"
    calib.write_text(toml_text(("left", "centre", "right")))
    videos = write_videos(tmp_path / "videos", names=("a", "b", "c"))
    with pytest.raises(CaptureError, match=r"--map NAME=FILE"):
        import_capture(calib, videos, tmp_path / "cap")
    with pytest.raises(CaptureError, match=r"names camera 'middle', which the calibration does not have"):
        import_capture(calib, videos, tmp_path / "cap", camera_map={"middle": "b.mp4"})
    m = import_capture(calib, videos, tmp_path / "cap",
                       camera_map={"left": "a.mp4", "centre": "b.mp4", "right": str(videos / "c.mp4")})
    expected = {p: [pinhole(K_TRUE[n], W2C_TRUE[n], POINTS)] * T for p, n in zip(("left", "centre", "right"), NAMES)}
    assert worst_error(m, expected) < TOLERANCE_PX
    assert m.metadata["media"]["centre"]["matched_by"] == "map"
    cli = ["import", str(calib), str(videos), "-o", str(tmp_path / "cap2"), "--map", "left=a.mp4",
           "--map", "centre=b.mp4", "--map", "right=c.mp4"]
    assert main(cli) == 0
    capsys.readouterr()
    with pytest.raises(SystemExit) as usage:
        main(["import", str(calib), str(videos), "-o", str(tmp_path / "cap3"), "--map", "left"])
    assert usage.value.code == 2 and "'left' is not NAME=FILE" in capsys.readouterr().err
    assert main(["import", str(calib), str(videos), "-o", str(tmp_path / "cap3"), "--map", "left=x.mp4"]) == 1
    assert "--map left=x.mp4" in capsys.readouterr().err
