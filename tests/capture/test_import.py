"""`vt4d import` / import_capture: each calibration format from a small fixture written here, checked by
reprojecting known 3-D points through the imported cameras (not only that it parsed)."""

import json

import cv2
import numpy as np
import pytest

from vt4dcodec.cameras import look_at
from vt4dcodec.capture.calibration import decide_units, read_calibration
from vt4dcodec.capture.importer import import_capture
from vt4dcodec.capture.io import read_capture, read_manifest
from vt4dcodec.capture.probe import check_capture
from vt4dcodec.cli import main
from vt4dcodec.errors import CaptureError
from vt4dcodec.media import write_mp4

from capture_helpers import smooth_video

W, H, T = 32, 24, 3
NAMES = ("cam00", "cam01", "cam02")
K_TRUE = {n: np.array([[30.0 + 2 * i, 0.0, 15.2 + i * 0.3], [0.0, 31.0 + i, 11.6 - i * 0.2], [0.0, 0.0, 1.0]])
          for i, n in enumerate(NAMES)}
EYES = {"cam00": [2.0, 0.3, -1.0], "cam01": [-1.5, 0.2, -2.0], "cam02": [0.2, -0.4, -2.5]}
W2C_TRUE = {n: look_at(np.array(e), np.zeros(3), np.array([0.0, -1.0, 0.0])) for n, e in EYES.items()}
POINTS = np.random.default_rng(0).uniform(-0.4, 0.4, size=(20, 3))


def pinhole(K, w2c, X):
    """Ground-truth pixels: x_cam = R X + t, u = fx x / z + s y / z + cx, v = fy y / z + cy."""
    xc = X @ w2c[:3, :3].T + w2c[:3, 3]
    uv = xc[:, :2] / xc[:, 2:]
    return np.stack([K[0, 0] * uv[:, 0] + K[0, 1] * uv[:, 1] + K[0, 2], K[1, 1] * uv[:, 1] + K[1, 2]], -1)


def reprojection_error(manifest, dist_true=None):
    """Max pixel distance between known points projected through the imported and the true cameras."""
    worst = 0.0
    for n in NAMES:
        t = manifest.camera(n).trajectory
        rvec, _ = cv2.Rodrigues(t.w2c[0, :3, :3])
        dist = t.distortion if t.distortion is not None else np.zeros(4)
        got, _ = cv2.projectPoints(POINTS, rvec, t.w2c[0, :3, 3], t.K[0], dist)
        if dist_true is None:
            want = pinhole(K_TRUE[n], W2C_TRUE[n], POINTS)
        else:
            r0, _ = cv2.Rodrigues(W2C_TRUE[n][:3, :3])
            want, _ = cv2.projectPoints(POINTS, r0, W2C_TRUE[n][:3, 3], K_TRUE[n], dist_true)
            want = want[:, 0]
        worst = max(worst, float(np.abs(got[:, 0] - want).max()))
        assert (t.width, t.height) == (W, H)
    return worst


def write_videos(folder, names=NAMES, width=W, height=H, frames=T):
    folder.mkdir(parents=True, exist_ok=True)
    for i, n in enumerate(names):
        write_mp4(folder / f"{n}.mp4", smooth_video(frames, height, width, seed=i), fps=12.0)
    return folder


def write_image_folders(folder, suffix=".png"):
    for i, n in enumerate(NAMES):
        (folder / n).mkdir(parents=True)
        for f, img in enumerate(smooth_video(T, H, W, seed=i)):
            cv2.imwrite(str(folder / n / f"frame_{f + 1}{suffix}"), img[..., ::-1])  # natural order 1, 2, 3
    return folder


def rodrigues_vector(R):
    return cv2.Rodrigues(R)[0].reshape(3)


# --- OpenCV FileStorage ------------------------------------------------------------------------------
DIST = np.array([0.05, -0.02, 0.001, -0.002, 0.003])


def test_opencv_yaml_nested_rvec_millimetres(tmp_path):
    calib = tmp_path / "calib.yml"
    fs = cv2.FileStorage(str(calib), cv2.FILE_STORAGE_WRITE)
    for n in NAMES:
        fs.startWriteStruct(n, cv2.FileNode_MAP)
        fs.write("camera_matrix", K_TRUE[n])
        fs.write("distortion_coefficients", DIST.reshape(1, 5))
        fs.write("rvec", rodrigues_vector(W2C_TRUE[n][:3, :3]).reshape(3, 1))
        fs.write("tvec", (W2C_TRUE[n][:3, 3] * 1000.0).reshape(3, 1))  # millimetres
        fs.write("image_width", W)
        fs.write("image_height", H)
        fs.endWriteStruct()
    fs.release()
    m = import_capture(calib, write_videos(tmp_path / "videos"), tmp_path / "cap")
    assert m.metadata["calibration"]["format"] == "opencv"
    assert m.metadata["calibration"]["units"].startswith("millimetres")
    assert reprojection_error(m, DIST) < 1e-6
    assert m.num_frames == T and m.fps == pytest.approx(12.0)
    assert m.camera("cam01").media_type == "mp4"
    cap = read_capture(tmp_path / "cap")  # the copied H.264 videos decode through the reader
    assert cap.frames["cam02"].shape == (T, H, W, 3)


def test_opencv_json_easymocap_names_metres(tmp_path):
    calib = tmp_path / "calib.json"
    fs = cv2.FileStorage(str(calib), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_JSON)
    fs.startWriteStruct("names", cv2.FileNode_SEQ)
    for n in NAMES:
        fs.write("", n)
    fs.endWriteStruct()
    for n in NAMES:
        fs.write(f"K_{n}", K_TRUE[n])
        fs.write(f"dist_{n}", np.zeros((1, 5)))
        fs.write(f"Rot_{n}", W2C_TRUE[n][:3, :3])
        fs.write(f"T_{n}", W2C_TRUE[n][:3, 3].reshape(3, 1))
    fs.release()
    m = import_capture(calib, write_videos(tmp_path / "videos"), tmp_path / "cap")
    assert m.metadata["calibration"]["units"].startswith("metres")
    assert reprojection_error(m) < 1e-6
    assert m.camera("cam00").trajectory.distortion is None  # all-zero terms: a pinhole camera


# --- TOML (Pose2Sim / Anipose) -----------------------------------------------------------------------
def toml_text(names=NAMES, size=(W, H)):
    """Pose2Sim's Calib.toml for the true cameras, named ``names`` (in NAMES order), calibrated at ``size``."""
    parts = []
    for i, (n, name) in enumerate(zip(NAMES, names)):
        K = K_TRUE[n].tolist()
        r, t = rodrigues_vector(W2C_TRUE[n][:3, :3]).tolist(), W2C_TRUE[n][:3, 3].tolist()
        parts.append(f"[cam_{i}]\nname = \"{name}\"\nsize = [ {size[0]}.0, {size[1]}.0,]\n"
                     f"matrix = [ [ {K[0][0]!r}, 0.0, {K[0][2]!r},], [ 0.0, {K[1][1]!r}, {K[1][2]!r},], [ 0.0, 0.0, 1.0,],]\n"
                     f"distortions = [ 0.0, 0.0, 0.0, 0.0,]\n"
                     f"rotation = [ {r[0]!r}, {r[1]!r}, {r[2]!r},]\ntranslation = [ {t[0]!r}, {t[1]!r}, {t[2]!r},]\n"
                     "fisheye = false\n")
    parts.append("[metadata]\nadjusted = false\nerror = 0.0\n")
    return "\n".join(parts)


def test_toml_pose2sim_rodrigues(tmp_path):
    calib = tmp_path / "Calib_scene.toml"
    calib.write_text(toml_text())
    m = import_capture(calib, write_image_folders(tmp_path / "frames"), tmp_path / "cap", fps=25)
    assert m.metadata["calibration"]["format"] == "toml" and m.fps == 25.0
    assert reprojection_error(m) < 1e-6
    assert m.camera("cam00").media_type == "png"
    # image folders in natural order: frame_1, frame_2, frame_3 -> 000000.png ... lossless
    cap = read_capture(tmp_path / "cap")
    np.testing.assert_array_equal(cap.frames["cam01"], smooth_video(T, H, W, seed=1))


def test_toml_fisheye_is_refused(tmp_path):
    calib = tmp_path / "c.toml"
    calib.write_text(toml_text().replace("fisheye = false", "fisheye = true"))
    with pytest.raises(Exception, match="fisheye"):
        read_calibration(calib)


# --- COLMAP text -------------------------------------------------------------------------------------
def quaternion(R):
    w = np.sqrt(max(0.0, 1 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = np.copysign(np.sqrt(max(0.0, 1 + R[0, 0] - R[1, 1] - R[2, 2])) / 2, R[2, 1] - R[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1 - R[0, 0] + R[1, 1] - R[2, 2])) / 2, R[0, 2] - R[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1 - R[0, 0] - R[1, 1] + R[2, 2])) / 2, R[1, 0] - R[0, 1])
    return w, x, y, z


def write_colmap(folder, moved=False):
    folder.mkdir()
    cams = ["# Camera list with one line of data per camera:"]
    imgs = ["# Image list with two lines of data per image:"]
    image_id = 1
    for i, n in enumerate(NAMES):
        K = K_TRUE[n].tolist()  # COLMAP puts pixel centres at +0.5: its principal point is ours + 0.5
        cams.append(f"{i + 1} PINHOLE {W} {H} {K[0][0]!r} {K[1][1]!r} {K[0][2] + 0.5!r} {K[1][2] + 0.5!r}")
        for f in range(2):  # a static rig: each camera's frames share one pose
            t = W2C_TRUE[n][:3, 3] + (0.1 if moved and f else 0.0)
            q = quaternion(W2C_TRUE[n][:3, :3])
            imgs.append(f"{image_id} {' '.join(repr(float(v)) for v in (*q, *t))} {i + 1} {n}/{f:06d}.jpg")
            imgs.append("" if f else "10.0 12.0 -1 11.0 13.0 5")
            image_id += 1
    (folder / "cameras.txt").write_text("\n".join(cams) + "\n")
    (folder / "images.txt").write_text("\n".join(imgs) + "\n")
    return folder


def test_colmap_text_static_rig(tmp_path):
    sparse = write_colmap(tmp_path / "sparse")
    m = import_capture(sparse, write_image_folders(tmp_path / "images", ".jpg"), tmp_path / "cap", fps=30)
    assert m.metadata["calibration"]["format"] == "colmap"
    assert reprojection_error(m) < 1e-6
    assert read_capture(tmp_path / "cap").frames["cam00"].shape == (T, H, W, 3)


def test_colmap_moving_camera_is_refused(tmp_path):
    with pytest.raises(CaptureError, match="static rigs"):
        read_calibration(write_colmap(tmp_path / "sparse", moved=True))


# --- NeRF transforms.json ----------------------------------------------------------------------------
def test_nerf_transforms_opengl_to_opencv(tmp_path):
    frames = []
    for n in NAMES:
        c2w_cv = np.linalg.inv(W2C_TRUE[n])
        c2w_gl = c2w_cv @ np.diag([1.0, -1.0, -1.0, 1.0])
        K = K_TRUE[n]
        frames.append({"file_path": f"./images/{n}.png", "transform_matrix": c2w_gl.tolist(),
                       "fl_x": K[0, 0], "fl_y": K[1, 1], "cx": K[0, 2] + 0.5, "cy": K[1, 2] + 0.5})
    (tmp_path / "scene").mkdir()
    (tmp_path / "scene" / "transforms.json").write_text(json.dumps({"w": W, "h": H, "frames": frames}))
    m = import_capture(tmp_path / "scene" / "transforms.json", write_videos(tmp_path / "videos"), tmp_path / "cap")
    assert m.metadata["calibration"]["format"] == "nerf"
    assert reprojection_error(m) < 1e-6


# --- units, sizes, names: the checks and their messages ----------------------------------------------
def test_units_decision():
    _, cams = 0, [type("C", (), {"w2c": W2C_TRUE[n]})() for n in NAMES]
    assert decide_units(cams)[0] == 1.0
    mm = []
    for n in NAMES:
        w2c = W2C_TRUE[n].copy()
        w2c[:3, 3] *= 1000
        mm.append(type("C", (), {"w2c": w2c})())
    assert decide_units(mm)[0] == 1e-3 and decide_units(mm, "m")[0] == 1.0


def test_media_size_mismatch_names_the_fix(tmp_path):
    calib = tmp_path / "c.toml"
    calib.write_text(toml_text())
    with pytest.raises(CaptureError, match=r"is 64x48 but the calibration is for 32x24.*--scale-intrinsics"):
        import_capture(calib, write_videos(tmp_path / "big", width=64, height=48), tmp_path / "cap")
    m = import_capture(calib, tmp_path / "big", tmp_path / "cap", scale_intrinsics=True)
    t = m.camera("cam00").trajectory
    assert (t.width, t.height) == (64, 48) and t.K[0, 0, 0] == pytest.approx(2 * K_TRUE["cam00"][0, 0])
    assert t.K[0, 0, 2] == pytest.approx((K_TRUE["cam00"][0, 2] + 0.5) * 2 - 0.5)
    with pytest.raises(CaptureError, match="rotated against the calibration"):
        import_capture(calib, write_videos(tmp_path / "portrait", width=H, height=W), tmp_path / "cap2")


def test_missing_media_and_frame_counts(tmp_path):
    calib = tmp_path / "c.toml"
    calib.write_text(toml_text())
    write_videos(tmp_path / "two", names=NAMES[:2])
    with pytest.raises(CaptureError, match=r"no video or image folder for calibrated cameras \['cam02'\]"):
        import_capture(calib, tmp_path / "two", tmp_path / "cap")
    vids = write_videos(tmp_path / "uneven")
    write_mp4(vids / "cam01.mp4", smooth_video(T + 2, H, W), fps=12.0)
    with pytest.raises(CaptureError, match="different frame counts"):
        import_capture(calib, vids, tmp_path / "cap")
    m = import_capture(calib, vids, tmp_path / "cap", frames=T, media="png")
    assert m.num_frames == T and m.camera("cam01").media_type == "png"
    with pytest.raises(CaptureError, match="already holds a capture"):
        import_capture(calib, vids, tmp_path / "cap", frames=T, media="png")


# --- the command, and capture-info --check -----------------------------------------------------------
def test_import_command_and_check(tmp_path, capsys):
    calib = tmp_path / "c.toml"
    calib.write_text(toml_text())
    vids = write_videos(tmp_path / "videos")
    out = tmp_path / "cap"
    assert main(["import", str(calib), str(vids), "-o", str(out), "--format", "toml", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["num_cameras"] == 3 and info["calibration"]["format"] == "toml"
    assert main(["capture-info", str(out), "--check", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["check"]["ok"] and report["check"]["cameras"][0]["probe"]["codec"] == "h264"
    # a manifest claiming the wrong width fails the check, naming the camera and the fix
    doc = json.loads((out / "capture.json").read_text())
    doc["cameras"][1]["width"] = 40
    (out / "capture.json").write_text(json.dumps(doc))
    assert main(["capture-info", str(out), "--check"]) == 1
    err = capsys.readouterr().err
    assert "camera 'cam01'" in err and "is 32x24 but the manifest says 40x24" in err
    assert check_capture(read_manifest(out))[0]["problems"] == []
    # an existing capture needs --overwrite; the CLI names the flag
    assert main(["import", str(calib), str(vids), "-o", str(out)]) == 1
    assert "--overwrite" in capsys.readouterr().err
