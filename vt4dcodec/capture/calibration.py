"""Multi-camera calibration files of common tools, read into the project's camera conventions.

Six families, detected from the file (or forced with ``format=``):

``opencv``  OpenCV FileStorage YAML or JSON (``cv2.FileStorage``): per camera a camera matrix, distortion
            and R (3x3, or a Rodrigues 3-vector) or rvec, and T/tvec, world-to-camera.  Accepted layouts:
            one map per camera (``cam00: {camera_matrix: ..., R: ..., T: ...}``); EasyMocap/ZJU style
            ``names: [...]`` with ``K_<name>``, ``dist_<name>``, ``R_<name>``/``Rot_<name>``, ``T_<name>``
            (a directory holding ``intri.yml`` and ``extri.yml`` is read as one file); or one camera at the
            top level (named after the file).  Image size from ``image_width``/``image_height`` or
            ``size``/``image_size`` when present.
``toml``    the TOML of Pose2Sim, Anipose and caliscope-style tools: tables with ``name``, ``size`` [W, H],
            ``matrix`` 3x3, ``distortions``, ``rotation`` (Rodrigues 3-vector, or 3x3) and ``translation``,
            world-to-camera.  Tables may sit at the top level (``[cam_0]``) or under ``[cameras.N]``.
``colmap``  COLMAP text model, ``cameras.txt`` + ``images.txt`` (a directory holding both, or either file):
            each image is a camera of a static rig (its name without extension, or its first folder when
            images sit in per-camera folders, whose poses must then agree).  COLMAP puts pixel centres at
            half-integers; the principal point moves by -0.5 px into the OpenCV convention here.
``nerf``    NeRF / instant-ngp ``transforms.json``: OpenGL camera-to-world ``transform_matrix`` per frame
            (x right, y up, z backwards), intrinsics from ``fl_x``/``fl_y``/``cx``/``cy`` or
            ``camera_angle_x``, optional ``k1 k2 p1 p2``, globally or per frame; each frame is a camera
            named after its ``file_path`` (without extension).  Poses become OpenCV world-to-camera by
            flipping the camera's y and z axes.
``n3dv``    N3DV / DyNeRF ``poses_bounds.npy`` (LLFF's layout, a directory holding it or the file): N rows of
            17 numbers, a 3x5 matrix ``[R | t | hwf]`` and the near/far depth bounds.  ``[R | t]`` is
            camera-to-world with LLFF's camera axes [down, right, backwards] (LLFF's imgs2poses writes COLMAP's
            [right, down, forwards] columns as ``[c1, c0, -c2]``), so the OpenCV axes are ``x = c1, y = c0,
            z = -c2``; ``hwf`` is the image height, width and the focal length in pixels, the principal point
            the image centre (LLFF keeps only COLMAP's focal length).  Rows are cameras ``cam00``, ``cam01``...
            (the importer pairs row i with the i-th video in name order, as the DyNeRF loaders do); near/far
            are kept per camera.
``multicamvideo``  ReCamMaster's MultiCamVideo ``cameras/camera_extrinsics.json`` (a scene directory holding
            it, or the file): ``frame<i>`` -> ``cam<NN>`` -> an Unreal Engine 4x4 transform written row by row
            (``"[r] [r] [r] [r]"``, row vectors: rows 0-2 the camera's forward, right and up axes, row 3 its
            position in centimetres).  The world becomes metres with Unreal's y axis negated (x forward, y
            left, z up: right-handed), the camera's OpenCV axes are (right, -up, forward), which gives the
            relative poses of ReCamMaster's own loader; one pose per frame.  Intrinsics as the dataset
            documents them: 1280x1280 frames from a 23.76 x 23.76 mm sensor, the focal length in mm taken
            from the folder name ``f<mm>_aperture<N>`` or given, the principal point the image centre.

Translations are returned in the file's own units (MultiCamVideo: metres); :func:`decide_units` tells metres
from millimetres.
"""

from __future__ import annotations

import json
import math
import os
import re
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CameraError, CaptureError

__all__ = ["CameraCalibration", "CALIBRATION_FORMATS", "read_calibration", "detect_format", "decide_units",
           "rodrigues"]

CALIBRATION_FORMATS = ("opencv", "toml", "colmap", "nerf", "n3dv", "multicamvideo")
MAX_CALIBRATION_BYTES = 64 * 1024 * 1024
_GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])  # flips a camera's y and z axes (OpenGL <-> OpenCV)


@dataclass(frozen=True)
class CameraCalibration:
    """One calibrated camera as read from a file, in the project's conventions but the file's units.

    Attributes:
        name: the camera's name in the calibration (media are matched to it).
        K: (3, 3) intrinsics in pixels, pixel centres at integer coordinates.
        w2c: (4, 4) world-to-camera pose, or (T, 4, 4) one per frame; translation in the calibration's units.
        width, height: image size the intrinsics refer to, or None when the file does not say.
        distortion: OpenCV distortion terms or None.
        near_far: the scene's depth bounds seen from the camera (LLFF's), in the calibration's units, or None.
    """

    name: str
    K: np.ndarray
    w2c: np.ndarray
    width: int | None = None
    height: int | None = None
    distortion: np.ndarray | None = None
    near_far: tuple[float, float] | None = None


def rodrigues(r: Any, where: str) -> np.ndarray:
    """A rotation given as a 3x3 matrix or a Rodrigues (axis-angle) 3-vector, as a 3x3 matrix."""
    arr = _floats(r, where)
    if arr.shape == (3, 3):
        return arr
    if arr.size != 3:
        raise CameraError(f"{where}: rotation must be a 3x3 matrix or a Rodrigues 3-vector, got shape {arr.shape}")
    v = arr.reshape(3)
    theta = float(np.linalg.norm(v))
    if theta < 1e-12:
        return np.eye(3)
    k = v / theta
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(theta) * kx + (1.0 - math.cos(theta)) * (kx @ kx)


def _floats(value: Any, where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise CameraError(f"{where}: expected numbers, got {str(value)[:60]!r}") from None
    if not np.all(np.isfinite(arr)):
        raise CameraError(f"{where}: holds non-finite numbers")
    return arr


def _pose(R: Any, t: Any, where: str) -> np.ndarray:
    w2c = np.eye(4)
    w2c[:3, :3] = rodrigues(R, f"{where}: rotation")
    tt = _floats(t, f"{where}: translation").reshape(-1)
    if tt.shape != (3,):
        raise CameraError(f"{where}: translation must be 3 numbers, got {tt.size}")
    w2c[:3, 3] = tt
    return w2c


def _camera(name: str, K: Any, w2c: np.ndarray, size: Any, dist: Any, where: str) -> CameraCalibration:
    KK = _floats(K, f"{where}: camera matrix")
    if KK.shape != (3, 3):
        raise CameraError(f"{where}: camera matrix must be 3x3, got shape {KK.shape}")
    d = None if dist is None else _floats(dist, f"{where}: distortion").reshape(-1)
    if d is not None and not np.any(d):
        d = None
    width = height = None
    if size is not None:
        s = _floats(size, f"{where}: image size").reshape(-1)
        if s.shape != (2,) or np.any(s < 1) or np.any(s != np.round(s)):
            raise CameraError(f"{where}: image size must be two positive integers [width, height], got {size!r}")
        width, height = int(s[0]), int(s[1])
    return CameraCalibration(name=str(name), K=KK, w2c=w2c, width=width, height=height, distortion=d)


def _check_file(path: Path) -> None:
    if not path.is_file():
        raise CaptureError(f"{path}: calibration file not found")
    if path.stat().st_size > MAX_CALIBRATION_BYTES:
        raise CaptureError(f"{path}: larger than {MAX_CALIBRATION_BYTES} bytes; not a calibration file")


def _read_text(path: Path) -> str:
    _check_file(path)
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise CaptureError(f"{path}: not UTF-8 text; not a calibration file") from None


# --- detection ---------------------------------------------------------------------------------------
def detect_format(path: str | os.PathLike) -> str:
    """The calibration family of ``path`` (one of :data:`CALIBRATION_FORMATS`), from names and contents."""
    path = Path(path)
    if path.is_dir():
        names = {p.name for p in path.iterdir()}
        if {"cameras.txt", "images.txt"} <= names:
            return "colmap"
        if "transforms.json" in names:
            return "nerf"
        if {"intri.yml", "extri.yml"} <= names:
            return "opencv"
        if N3DV_FILE in names:
            return "n3dv"
        if MULTICAMVIDEO_FILE in names or (path / "cameras" / MULTICAMVIDEO_FILE).is_file():
            return "multicamvideo"
        raise CaptureError(f"{path}: a directory without cameras.txt + images.txt (COLMAP), transforms.json "
                           f"(NeRF), intri.yml + extri.yml (OpenCV), {N3DV_FILE} (N3DV/DyNeRF) or "
                           f"cameras/{MULTICAMVIDEO_FILE} (MultiCamVideo); give the calibration file itself")
    suffix = path.suffix.lower()
    if path.name in ("cameras.txt", "images.txt"):
        return "colmap"
    if suffix == ".npy":
        return "n3dv"
    if suffix == ".toml":
        return "toml"
    if suffix in (".yml", ".yaml", ".xml"):
        return "opencv"
    text = _read_text(path)
    if suffix == ".json":
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise CaptureError(f"{path}: not valid JSON ({exc})") from None
        if isinstance(doc, dict) and isinstance(doc.get("frames"), list):
            return "nerf"
        if isinstance(doc, dict) and isinstance(doc.get("frame0"), dict):
            return "multicamvideo"
        return "opencv"
    if text.lstrip().startswith("%YAML"):
        return "opencv"
    raise CaptureError(f"{path}: cannot tell the calibration format (none of OpenCV YAML/JSON, TOML, COLMAP text or "
                       f"NeRF transforms.json); name it with --format {'|'.join(CALIBRATION_FORMATS)} (in Python: "
                       "format=NAME)")


def read_calibration(path: str | os.PathLike, format: str = "auto", *,
                     focal_mm: float | None = None) -> tuple[str, list[CameraCalibration]]:
    """Read a calibration: (the format read, its cameras in file order).  ``format`` is ``"auto"`` or one
    of :data:`CALIBRATION_FORMATS`; ``focal_mm`` is MultiCamVideo's lens (default: from the scene's folder
    name).  Problems raise CaptureError (files) or CameraError (numbers)."""
    path = Path(path)
    if not path.exists():
        raise CaptureError(f"{path}: calibration not found")
    fmt = detect_format(path) if format == "auto" else format
    if fmt not in CALIBRATION_FORMATS:
        raise CaptureError(f"calibration format must be 'auto' or one of {CALIBRATION_FORMATS}, got {format!r}")
    if focal_mm is not None and fmt != "multicamvideo":
        raise CaptureError(f"focal_mm (--focal-mm) is MultiCamVideo's lens; a {fmt} calibration holds its own "
                           "intrinsics")
    if fmt == "multicamvideo":
        cams = _read_multicamvideo(path, focal_mm)
    else:
        reader = {"opencv": _read_opencv, "toml": _read_toml, "colmap": _read_colmap, "nerf": _read_nerf,
                  "n3dv": _read_n3dv}[fmt]
        cams = reader(path)
    if not cams:
        raise CaptureError(f"{path}: no cameras found in the {fmt} calibration")
    names = [c.name for c in cams]
    if len(set(names)) != len(names):
        raise CaptureError(f"{path}: camera names repeat in the calibration: {names}")
    return fmt, cams


# --- OpenCV FileStorage ------------------------------------------------------------------------------
_K_KEYS = ("camera_matrix", "cameraMatrix", "K", "M", "intrinsic", "intrinsics", "intrinsic_matrix", "mtx")
_D_KEYS = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "dist", "D", "distortion", "dist_coeff")
_R_KEYS = ("R", "Rot", "rotation", "rotation_matrix", "rvec", "rvecs", "r")
_T_KEYS = ("T", "t", "tvec", "tvecs", "translation")


def _fs_node(node: Any) -> Any:
    """A cv2.FileNode as plain Python: maps -> dict, sequences -> list, matrices -> ndarray."""
    if node.isMap():
        keys = set(node.keys())
        if {"rows", "cols", "dt", "data"} <= keys:  # an opencv-matrix
            return np.asarray(node.mat(), dtype=np.float64)
        return {k: _fs_node(node.getNode(k)) for k in node.keys()}
    if node.isSeq():
        return [_fs_node(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    return None


def _read_filestorage(path: Path) -> dict[str, Any]:
    import cv2

    _read_text(path)  # size and encoding checks
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_FORMAT_AUTO)
    except cv2.error as exc:
        raise CaptureError(f"{path}: OpenCV cannot read it as FileStorage YAML/JSON/XML ({str(exc).strip()[:200]})"
                           " (a YAML file must start with %YAML:1.0)") from None
    try:
        if not fs.isOpened():
            raise CaptureError(f"{path}: OpenCV cannot open it as FileStorage YAML/JSON/XML")
        doc = _fs_node(fs.root())
    finally:
        fs.release()
    if not isinstance(doc, dict):
        raise CaptureError(f"{path}: the top level must be a map")
    return doc


def _first(doc: dict[str, Any], keys: tuple[str, ...], suffix: str = "") -> Any:
    for k in keys:
        if k + suffix in doc:
            return doc[k + suffix]
    return None


def _size_of(doc: dict[str, Any], suffix: str = "") -> Any:
    w, h = doc.get("image_width" + suffix, doc.get("width" + suffix)), doc.get("image_height" + suffix,
                                                                               doc.get("height" + suffix))
    if w is not None and h is not None:
        return [w, h]
    return _first(doc, ("image_size", "imageSize", "size", "resolution"), suffix)


def _opencv_camera(name: str, doc: dict[str, Any], suffix: str, where: str) -> CameraCalibration:
    K = _first(doc, _K_KEYS, suffix)
    if K is None:
        raise CaptureError(f"{where}: no camera matrix (one of {', '.join(_K_KEYS)})")
    R, T = _first(doc, _R_KEYS, suffix), _first(doc, _T_KEYS, suffix)
    if (R is None) != (T is None):
        raise CaptureError(f"{where}: has {'a rotation' if T is None else 'a translation'} but no "
                           f"{'translation (T or tvec)' if T is None else 'rotation (R or rvec)'}")
    if R is None:
        R, T = np.eye(3), np.zeros(3)
    return _camera(name, K, _pose(R, T, where), _size_of(doc, suffix), _first(doc, _D_KEYS, suffix), where)


def _read_opencv(path: Path) -> list[CameraCalibration]:
    if path.is_dir():
        doc = {**_read_filestorage(path / "intri.yml"), **_read_filestorage(path / "extri.yml")}
    else:
        doc = _read_filestorage(path)
    if isinstance(doc.get("names"), list):  # EasyMocap / ZJU-Mocap: names + K_<name>, R_<name>/Rot_<name> ...
        cams = []
        for name in doc["names"]:
            if not isinstance(name, (str, int)):
                raise CaptureError(f"{path}: names must be strings")
            sub = {k: v for k, v in doc.items() if k.endswith(f"_{name}")}
            sub = {k[: -len(f"_{name}")]: v for k, v in sub.items()}
            if "Rot" in sub:  # EasyMocap writes both: Rot is the matrix, R the Rodrigues vector
                sub["R"] = sub["Rot"]
            cams.append(_opencv_camera(str(name), sub, "", f"{path.name} camera {name!r}"))
        return cams
    if _first(doc, _K_KEYS) is not None:
        return [_opencv_camera(path.stem, doc, "", path.name)]
    return [_opencv_camera(str(k), v, "", f"{path.name} [{k}]") for k, v in doc.items()
            if isinstance(v, dict) and _first(v, _K_KEYS) is not None]


# --- TOML (Pose2Sim, Anipose, caliscope) -------------------------------------------------------------
def _read_toml(path: Path) -> list[CameraCalibration]:
    try:
        doc = tomllib.loads(_read_text(path))
    except tomllib.TOMLDecodeError as exc:
        raise CaptureError(f"{path}: not valid TOML ({exc})") from None
    tables = doc["cameras"] if isinstance(doc.get("cameras"), dict) else doc
    cams = []
    for key, cam in tables.items():
        if not isinstance(cam, dict) or "matrix" not in cam:
            continue  # [metadata] and other tables
        where = f"{path.name} [{key}]"
        if cam.get("ignore") is True:
            continue
        if cam.get("fisheye") is True:
            raise CameraError(f"{where}: fisheye calibrations are not supported (OpenCV pinhole with "
                              "k1 k2 p1 p2 [k3] only); recalibrate with the pinhole model")
        missing = [k for k in ("rotation", "translation") if k not in cam]
        if missing:
            raise CaptureError(f"{where}: missing {missing}")
        name = cam.get("name", f"cam_{cam['cam_id']}" if "cam_id" in cam else key)
        cams.append(_camera(str(name), cam["matrix"], _pose(cam["rotation"], cam["translation"], where),
                            cam.get("size"), cam.get("distortions"), where))
    return cams


# --- COLMAP text -------------------------------------------------------------------------------------
_COLMAP_MODELS = {  # model -> (number of parameters, (fx, fy, cx, cy) indices, distortion builder)
    "SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8, "FULL_OPENCV": 12,
}


def _colmap_intrinsics(model: str, p: list[float], where: str) -> tuple[np.ndarray, np.ndarray | None]:
    if model not in _COLMAP_MODELS:
        raise CameraError(f"{where}: COLMAP camera model {model} is not supported (use one of "
                          f"{', '.join(_COLMAP_MODELS)}; undistort fisheye models with colmap image_undistorter)")
    if len(p) != _COLMAP_MODELS[model]:
        raise CameraError(f"{where}: {model} takes {_COLMAP_MODELS[model]} parameters, got {len(p)}")
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy, rest = p[1], p[2], p[3:]
    else:
        fx, fy, cx, cy, rest = p[0], p[1], p[2], p[3], p[4:]
    dist: list[float] | None
    if model == "SIMPLE_RADIAL":
        dist = [rest[0], 0.0, 0.0, 0.0]
    elif model == "RADIAL":
        dist = [rest[0], rest[1], 0.0, 0.0]
    elif model in ("OPENCV", "FULL_OPENCV"):
        dist = list(rest)  # k1 k2 p1 p2 [k3 k4 k5 k6]: OpenCV's order
    else:
        dist = None
    K = np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])  # COLMAP pixel centres at +0.5
    return K, None if dist is None else np.asarray(dist, dtype=np.float64)


def _colmap_lines(path: Path) -> list[str]:
    return [line for line in _read_text(path).splitlines() if not line.startswith("#")]


def _quat_to_R(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _read_colmap(path: Path) -> list[CameraCalibration]:
    folder = path if path.is_dir() else path.parent
    cams_path, imgs_path = folder / "cameras.txt", folder / "images.txt"
    intrinsics: dict[int, tuple[np.ndarray, np.ndarray | None, int, int]] = {}
    for n, line in enumerate(_colmap_lines(cams_path), start=1):
        tok = line.split()
        if not tok:
            continue
        where = f"{cams_path.name} camera line {n}"
        try:
            cam_id, model, width, height = int(tok[0]), tok[1], int(tok[2]), int(tok[3])
            params = [float(v) for v in tok[4:]]
        except (IndexError, ValueError):
            raise CaptureError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS...") from None
        K, dist = _colmap_intrinsics(model, params, where)
        intrinsics[cam_id] = (K, dist, width, height)
    lines = _colmap_lines(imgs_path)
    poses: dict[str, tuple[np.ndarray, int, str]] = {}
    order: list[str] = []
    for i in range(0, len(lines), 2):  # an image line, then its 2-D points line (possibly empty)
        tok = lines[i].split()
        if not tok:
            continue
        where = f"{imgs_path.name} image {tok[0]}"
        try:
            q = np.array([float(v) for v in tok[1:5]])
            t = np.array([float(v) for v in tok[5:8]])
            cam_id, image_name = int(tok[8]), " ".join(tok[9:])
        except (IndexError, ValueError):
            raise CaptureError(f"{where}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME") from None
        if not image_name:
            raise CaptureError(f"{where}: no image name")
        if cam_id not in intrinsics:
            raise CaptureError(f"{where}: camera {cam_id} is not in {cams_path.name}")
        parts = Path(image_name).parts
        name = parts[0] if len(parts) > 1 else Path(image_name).stem
        w2c = _pose(_quat_to_R(q), t, where)
        if name in poses:
            other, other_id, other_image = poses[name]
            if other_id != cam_id or np.abs(other - w2c).max() > 1e-6:
                raise CaptureError(f"{where}: {image_name} and {other_image} belong to camera {name!r} but differ in "
                                   "pose or intrinsics; import handles static rigs (one pose per camera) only")
            continue
        poses[name] = (w2c, cam_id, image_name)
        order.append(name)
    out = []
    for name in order:
        w2c, cam_id, _ = poses[name]
        K, dist, width, height = intrinsics[cam_id]
        out.append(_camera(name, K, w2c, [width, height], dist, f"{imgs_path.name} camera {name!r}"))
    return out


# --- NeRF transforms.json ----------------------------------------------------------------------------
def _nerf_intrinsics(doc: dict[str, Any], frame: dict[str, Any], where: str) -> tuple[np.ndarray, Any, Any]:
    def get(key: str) -> Any:
        return frame.get(key, doc.get(key))

    w, h = get("w"), get("h")
    fx, fy = get("fl_x"), get("fl_y")
    if fx is None and get("camera_angle_x") is not None:
        if w is None:
            raise CaptureError(f"{where}: camera_angle_x without the image width w")
        fx = 0.5 * float(w) / math.tan(0.5 * float(get("camera_angle_x")))
    if fy is None and get("camera_angle_y") is not None and h is not None:
        fy = 0.5 * float(h) / math.tan(0.5 * float(get("camera_angle_y")))
    if fx is None:
        raise CaptureError(f"{where}: no focal length (fl_x or camera_angle_x)")
    fy = fx if fy is None else fy
    cx, cy = get("cx"), get("cy")
    if cx is None or cy is None:
        if w is None or h is None:
            raise CaptureError(f"{where}: no principal point (cx, cy) and no image size (w, h) to centre it")
        cx, cy = float(w) / 2, float(h) / 2
    # NeRF tools follow COLMAP's pixel centres at +0.5 (cx = w/2 is the image centre): same shift.
    K = np.array([[float(fx), 0.0, float(cx) - 0.5], [0.0, float(fy), float(cy) - 0.5], [0.0, 0.0, 1.0]])
    terms = [get(k) or 0.0 for k in ("k1", "k2", "p1", "p2")]
    k3 = get("k3")
    dist = terms + ([k3] if k3 else [])
    size = None if w is None or h is None else [w, h]
    return K, size, dist


def _read_nerf(path: Path) -> list[CameraCalibration]:
    file = path / "transforms.json" if path.is_dir() else path
    try:
        doc = json.loads(_read_text(file))
    except json.JSONDecodeError as exc:
        raise CaptureError(f"{file}: not valid JSON ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("frames"), list):
        raise CaptureError(f"{file}: a NeRF transforms.json holds a 'frames' list")
    cams = []
    for i, frame in enumerate(doc["frames"]):
        where = f"{file.name} frame {i}"
        if not isinstance(frame, dict) or "transform_matrix" not in frame or "file_path" not in frame:
            raise CaptureError(f"{where}: needs file_path and transform_matrix")
        c2w_gl = _floats(frame["transform_matrix"], f"{where}: transform_matrix")
        if c2w_gl.shape == (3, 4):
            c2w_gl = np.vstack([c2w_gl, [0.0, 0.0, 0.0, 1.0]])
        if c2w_gl.shape != (4, 4):
            raise CameraError(f"{where}: transform_matrix must be 4x4, got {c2w_gl.shape}")
        c2w_cv = c2w_gl @ _GL_TO_CV
        R = c2w_cv[:3, :3].T
        w2c = np.eye(4)
        w2c[:3, :3], w2c[:3, 3] = R, -R @ c2w_cv[:3, 3]
        K, size, dist = _nerf_intrinsics(doc, frame, where)
        name = Path(str(frame["file_path"])).stem
        cams.append(_camera(name, K, w2c, size, dist, where))
    return cams


# --- N3DV / DyNeRF poses_bounds.npy (LLFF) ------------------------------------------------------------
N3DV_FILE = "poses_bounds.npy"


def n3dv_file(path: Path) -> Path:
    """The ``poses_bounds.npy`` that ``path`` (the file or its directory) names."""
    return path / N3DV_FILE if path.is_dir() else path


def _read_n3dv(path: Path) -> list[CameraCalibration]:
    file = n3dv_file(path)
    _check_file(file)
    try:
        rows = np.load(file, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise CaptureError(f"{file}: not a NumPy .npy array ({str(exc)[:120]})") from None
    if rows.ndim != 2 or rows.shape[1] != 17 or rows.shape[0] < 1 or rows.dtype.kind not in "fiu":
        raise CaptureError(f"{file}: an N3DV/LLFF {N3DV_FILE} is an N x 17 array of numbers (a 3x5 pose-and-hwf "
                           f"matrix and near, far per camera), got {rows.dtype} {rows.shape}")
    cams = []
    for i, row in enumerate(_floats(rows, file.name)):
        where, name = f"{file.name} row {i}", f"cam{i:02d}"
        m = row[:15].reshape(3, 5)
        h, w, f = m[:, 4]
        if not (h >= 1 and w >= 1 and h == round(h) and w == round(w) and f > 0):
            raise CameraError(f"{where}: hwf must be the image height and width in pixels and a positive focal "
                              f"length, got {[float(h), float(w), float(f)]}")
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([m[:, 1], m[:, 0], -m[:, 2]], axis=1)  # LLFF [down, right, back] -> OpenCV
        c2w[:3, 3] = m[:, 3]
        R = c2w[:3, :3].T
        w2c = np.eye(4)
        w2c[:3, :3], w2c[:3, 3] = R, -R @ c2w[:3, 3]
        K = [[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]]  # principal point: the image centre
        near, far = float(row[15]), float(row[16])
        cam = _camera(name, K, w2c, [w, h], None, where)
        cams.append(replace(cam, near_far=(near, far)))
    return cams


# --- MultiCamVideo (ReCamMaster) cameras/camera_extrinsics.json -------------------------------------------
MULTICAMVIDEO_FILE = "camera_extrinsics.json"
MULTICAMVIDEO_SIZE = 1280          # the dataset's frames are 1280 x 1280
MULTICAMVIDEO_SENSOR_MM = 23.76    # ... from a 23.76 mm x 23.76 mm sensor
_FOCAL_FOLDER = re.compile(r"^f(\d+(?:\.\d+)?)_aperture", re.IGNORECASE)  # train/f18_aperture10/scene1
_UNREAL_AXES = np.diag([1.0, -1.0, 1.0])  # Unreal's left-handed world with y negated: right-handed
_UNREAL_UNIT = 0.01                         # Unreal's centimetres, in metres


def multicamvideo_file(path: Path) -> Path:
    """The ``camera_extrinsics.json`` that ``path`` (the file, its scene directory or ``cameras/``) names."""
    if not path.is_dir():
        return path
    return path / MULTICAMVIDEO_FILE if (path / MULTICAMVIDEO_FILE).is_file() else path / "cameras" / MULTICAMVIDEO_FILE


def multicamvideo_scene(path: Path) -> Path:
    """The scene directory of a MultiCamVideo calibration (it holds ``cameras/`` and ``videos/``)."""
    file = multicamvideo_file(path)
    return file.parent.parent if file.parent.name == "cameras" else file.parent


def _focal_from_folders(scene: Path) -> float | None:
    for folder in (scene, *scene.resolve().parents):
        m = _FOCAL_FOLDER.match(folder.name)
        if m:
            return float(m.group(1))
    return None


def _unreal_matrix(text: Any, where: str) -> np.ndarray:
    """An Unreal transform written as bracketed rows (``"[1 0 0 0] [0 1 0 0] [0 0 1 0] [x y z 1]"``; rows of
    three are read with the implied last column 0 0 0 1)."""
    if not isinstance(text, str):
        raise CaptureError(f"{where}: expected a matrix string \"[r00 r01 r02 0] ... [x y z 1]\"")
    rows = re.findall(r"\[([^\[\]]*)\]", text)
    try:
        values = [[float(v) for v in row.split()] for row in rows]
    except ValueError:
        raise CaptureError(f"{where}: expected numbers in {text[:80]!r}") from None
    if len(values) != 4 or {len(r) for r in values} not in ({3}, {4}):
        raise CaptureError(f"{where}: expected four bracketed rows of 4 (or 3) numbers, got {text[:80]!r}")
    if len(values[0]) == 3:
        values = [r + [float(i == 3)] for i, r in enumerate(values)]
    m = _floats(values, where)
    if np.abs(m[:, 3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-6:
        raise CameraError(f"{where}: the last column must be 0 0 0 1 (row vectors: the position is the last row)")
    return m


def _read_multicamvideo(path: Path, focal_mm: float | None) -> list[CameraCalibration]:
    file = multicamvideo_file(path)
    try:
        doc = json.loads(_read_text(file))
    except json.JSONDecodeError as exc:
        raise CaptureError(f"{file}: not valid JSON ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("frame0"), dict) or not doc["frame0"]:
        raise CaptureError(f"{file}: a MultiCamVideo {MULTICAMVIDEO_FILE} maps frame0, frame1, ... to the "
                           "cameras' matrices")
    frames = [f"frame{i}" for i in range(len(doc))]
    missing = [k for k in frames if not isinstance(doc.get(k), dict)]
    if missing:
        raise CaptureError(f"{file}: frames must be frame0..frame{len(doc) - 1} without gaps; {missing[0]} is missing")
    names = sorted(doc["frame0"], key=natural_key)
    if focal_mm is None:
        focal_mm = _focal_from_folders(multicamvideo_scene(path))
    if focal_mm is None:
        raise CaptureError(f"{file}: the focal length is not in a folder name f<mm>_aperture<N> (the dataset's "
                           "train/f18_aperture10/scene1/ layout); pass it in millimetres with focal_mm=F "
                           "(--focal-mm F)")
    if not (np.isfinite(focal_mm) and focal_mm > 0):
        raise CaptureError(f"focal_mm (--focal-mm) must be a positive number of millimetres, got {focal_mm!r}")
    f = focal_mm / MULTICAMVIDEO_SENSOR_MM * MULTICAMVIDEO_SIZE
    c = (MULTICAMVIDEO_SIZE - 1) / 2
    K = [[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]]
    cams = []
    for name in names:
        w2c = np.empty((len(frames), 4, 4))
        for t, key in enumerate(frames):
            where = f"{file.name} {key} {name}"
            if name not in doc[key]:
                raise CaptureError(f"{where}: camera {name} is missing from {key} (every frame lists every camera)")
            m = _unreal_matrix(doc[key][name], where)
            forward, right, up, position = m[0, :3], m[1, :3], m[2, :3], m[3, :3]
            c2w = np.eye(4)  # OpenCV camera axes (right, down, forward) in the metric right-handed world
            c2w[:3, :3] = _UNREAL_AXES @ np.stack([right, -up, forward], axis=1)
            c2w[:3, 3] = _UNREAL_AXES @ position * _UNREAL_UNIT
            R = c2w[:3, :3].T
            w2c[t] = np.eye(4)
            w2c[t, :3, :3], w2c[t, :3, 3] = R, -R @ c2w[:3, 3]
        cams.append(_camera(name, K, w2c, [MULTICAMVIDEO_SIZE, MULTICAMVIDEO_SIZE], None, f"{file.name} {name}"))
    return cams


# --- units -------------------------------------------------------------------------------------------
MM_THRESHOLD = 50.0  # a median camera spacing above this many units is millimetres, not metres


def decide_units(cams: list[CameraCalibration], units: str = "auto") -> tuple[float, str]:
    """(scale to metres, reason): ``units`` "m" or "mm" as given; "auto" takes millimetres when the
    median distance between camera centres (one camera: its distance from the world origin) exceeds
    :data:`MM_THRESHOLD` -- real rigs span centimetres to tens of metres, so 50 "metres" between cameras
    is a rig measured in millimetres."""
    if units == "m":
        return 1.0, "metres (given)"
    if units == "mm":
        return 1e-3, "millimetres (given)"
    if units != "auto":
        raise CaptureError(f"units must be 'auto', 'm' or 'mm', got {units!r}")
    first = [c.w2c.reshape(-1, 4, 4)[0] for c in cams]  # a moving camera: where it starts
    centres = np.array([-w2c[:3, :3].T @ w2c[:3, 3] for w2c in first])
    if len(centres) > 1:
        d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)[np.triu_indices(len(centres), 1)]
        spread, what = float(np.median(d)), "median camera spacing"
    else:
        spread, what = float(np.linalg.norm(centres[0])), "camera distance from the origin"
    if spread > MM_THRESHOLD:
        return 1e-3, f"millimetres ({what} {spread:.4g} units > {MM_THRESHOLD:g}; units='m' to override)"
    return 1.0, f"metres ({what} {spread:.4g} units <= {MM_THRESHOLD:g}; units='mm' to override)"


def scaled(cam: CameraCalibration, scale: float) -> CameraCalibration:
    """``cam`` with its translations (and near/far) multiplied by ``scale`` (units to metres)."""
    w2c = cam.w2c.copy()
    w2c[..., :3, 3] *= scale
    near_far = None if cam.near_far is None else (cam.near_far[0] * scale, cam.near_far[1] * scale)
    return replace(cam, w2c=w2c, near_far=near_far)


def natural_key(name: str) -> list[Any]:
    """Sort key of names in natural order: cam2 before cam10."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


_SAFE = re.compile(r"[^A-Za-z0-9_.-]")


def safe_name(name: str) -> str:
    """A calibration camera name as a capture camera name (FORMAT.md Part III): other characters -> '_'."""
    out = _SAFE.sub("_", name)[:64]
    return "_" + out[1:] if out.startswith((".", "-")) else out or "_"
