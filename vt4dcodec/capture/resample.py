"""Fit captures to a model's resolution and clip length: undistort, resize, centre-crop or pad (numpy + OpenCV).

The mapping, per camera (one camera = one ``K``, optional distortion):

1. **Undistort** (only when the camera has distortion terms) to the ideal pinhole camera with the
   *same* ``K``; pixels that map outside the source image become black / unknown depth (0).
   The distortion is then dropped from the calibration.
2. **Resize** by one factor ``s``, new size ``round(W s) x round(H s)``; the intrinsics follow the
   pixel-centre mapping ``u' = (u + 0.5) * sx - 0.5`` with the exact per-axis ratios.  ``fit="crop"``
   (the default): ``s = max(height / H, width / W)``, the image covers ``height`` x ``width`` (the
   shorter side fits).  ``fit="pad"``: ``s = min(height / H, width / W)``, the whole image fits inside
   (the longer side fits).
3. **Centre** it in ``height`` x ``width``: offset ``x0 = (W' - width) // 2``, ``y0 = (H' - height) // 2``
   and ``cx -= x0``, ``cy -= y0``.  With ``crop`` the offsets are >= 0 and the overhang is cut away
   (a portrait 1080x1920 frame loses 44 % of its pixels); with ``pad`` they are <= 0 and the image is
   letterboxed: the bars are black RGB and unknown depth (0), and the whole field of view is kept.

How pixels are resampled (:class:`FrameFitter`): without distortion, an area-average resize when
shrinking (bilinear when enlarging) and a crop or pad.  With distortion, one ``cv2.remap`` straight
from the source to the output pixels (map from ``cv2.initUndistortRectifyMap``; output pixels that
fall outside the source, bars included, are black); when shrinking, the source is first area-averaged
to the resized size (a low-pass that prevents aliasing; the lens model is applied at that scale with
the scaled ``K``, which is geometrically exact).  RGB is bilinear, depth nearest (never blends depths
across edges).

Frames ``[start, start + num_frames)`` are kept and the rest dropped (``num_frames=None`` keeps all
from ``start``); poses and timestamps are sliced the same way.  :class:`FitPlan` applies the same
mapping to pixel coordinates, so observations (e.g. detected corners) can follow the images.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..cameras import Trajectory
from ..errors import CaptureError
from .capture import Capture

__all__ = [
    "FitPlan",
    "plan_fit",
    "FrameFitter",
    "undistort_pixels",
    "fit_image",
    "fit_trajectory",
    "fit_capture",
    "select_frames",
    "FITS",
    "check_fit",
]

FITS = ("crop", "pad")  # how a frame of another aspect ratio becomes the output size

# Tight criteria so point undistortion converges even for strongly distorted webcams (k1 ~ -0.34).
_UNDISTORT_CRITERIA = (3, 200, 1e-12)  # cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS


def _cv2():
    import cv2

    return cv2


@dataclass(frozen=True)
class FitPlan:
    """How an ``in_width`` x ``in_height`` image becomes ``out_width`` x ``out_height``: a resize to
    ``scaled_width`` x ``scaled_height``, then the output window starts at pixel ``(x0, y0)`` of the
    resized image: a crop where the offsets are >= 0, black bars (letterbox) where they are < 0."""

    in_width: int
    in_height: int
    scaled_width: int
    scaled_height: int
    x0: int
    y0: int
    out_width: int
    out_height: int

    @property
    def sx(self) -> float:
        return self.scaled_width / self.in_width

    @property
    def sy(self) -> float:
        return self.scaled_height / self.in_height

    def intrinsics(self, K: np.ndarray) -> np.ndarray:
        """(..., 3, 3) intrinsics of the fitted image (pixel-centre resize, then crop offset)."""
        K = np.array(K, dtype=np.float64)
        out = K.copy()
        out[..., 0, :] *= self.sx
        out[..., 1, :] *= self.sy
        out[..., 0, 2] = (K[..., 0, 2] + 0.5) * self.sx - 0.5 - self.x0
        out[..., 1, 2] = (K[..., 1, 2] + 0.5) * self.sy - 0.5 - self.y0
        return out

    def points(self, uv: np.ndarray) -> np.ndarray:
        """(..., 2) pixel coordinates of the (undistorted) input image -> fitted image coordinates."""
        uv = np.asarray(uv, dtype=np.float64)
        return np.stack([
            (uv[..., 0] + 0.5) * self.sx - 0.5 - self.x0,
            (uv[..., 1] + 0.5) * self.sy - 0.5 - self.y0,
        ], axis=-1)


def check_fit(fit: str) -> str:
    """``fit`` itself when it is one of :data:`FITS`; CaptureError otherwise."""
    if fit not in FITS:
        raise CaptureError(f"fit must be 'crop' (centre-crop to the square) or 'pad' (letterbox: keep the whole "
                           f"picture), got {fit!r}")
    return fit


def plan_fit(width: int, height: int, *, out_height: int, out_width: int, fit: str = "crop") -> FitPlan:
    """The plan that fits ``width`` x ``height`` to ``out_width`` x ``out_height``: resize, then centre-crop
    (``fit="crop"``) or centre on black bars (``fit="pad"``)."""
    for label, v in (("width", width), ("height", height), ("out_width", out_width), ("out_height", out_height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
            raise CaptureError(f"{label} must be a positive integer number of pixels, got {v!r}")
    if check_fit(fit) == "crop":
        s = max(out_height / height, out_width / width)
        sw = max(out_width, int(round(width * s)))
        sh = max(out_height, int(round(height * s)))
    else:
        s = min(out_height / height, out_width / width)
        sw = min(out_width, max(1, int(round(width * s))))
        sh = min(out_height, max(1, int(round(height * s))))
    return FitPlan(int(width), int(height), sw, sh, (sw - out_width) // 2, (sh - out_height) // 2,
                   int(out_width), int(out_height))


class FrameFitter:
    """Fits every frame of one camera (``K``, OpenCV ``dist`` or None, image size of ``plan``) to the
    output of ``plan``: undistort + resize + centre-crop.  Build once per camera; maps are reused."""

    def __init__(self, K: np.ndarray, dist: np.ndarray | None, plan: FitPlan) -> None:
        cv2 = _cv2()
        self.plan = plan
        self.prefilter = plan.sx < 1 and plan.sy < 1 and dist is not None
        self.maps = None
        if dist is not None:
            K = np.asarray(K, dtype=np.float64)
            K_src = K
            if self.prefilter:  # the intrinsics of the area-averaged, uncropped source
                K_src = plan.intrinsics(K)
                K_src[0, 2] += plan.x0
                K_src[1, 2] += plan.y0
            self.maps = cv2.initUndistortRectifyMap(
                K_src, np.asarray(dist, dtype=np.float64), None, plan.intrinsics(K),
                (plan.out_width, plan.out_height), cv2.CV_32FC1,
            )

    def _check(self, image: np.ndarray) -> None:
        if image.shape[:2] != (self.plan.in_height, self.plan.in_width):
            raise CaptureError(f"image is {image.shape[1]}x{image.shape[0]}, the camera is "
                               f"{self.plan.in_width}x{self.plan.in_height}")

    def _remap(self, image: np.ndarray, *, depth: bool) -> np.ndarray:
        cv2 = _cv2()
        if self.prefilter:
            size = (self.plan.scaled_width, self.plan.scaled_height)
            image = cv2.resize(image, size, interpolation=cv2.INTER_NEAREST_EXACT if depth else cv2.INTER_AREA)
        return cv2.remap(image, *self.maps, cv2.INTER_NEAREST if depth else cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    def image(self, image: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 source frame -> (out_height, out_width, 3) uint8."""
        self._check(image)
        return fit_image(image, self.plan) if self.maps is None else self._remap(image, depth=False)

    def depth(self, depth: np.ndarray) -> np.ndarray:
        """(H, W) float32 depth (metres, 0 = unknown) -> (out_height, out_width) float32."""
        self._check(depth)
        depth = np.asarray(depth, dtype=np.float32)
        return fit_image(depth, self.plan, depth=True) if self.maps is None else self._remap(depth, depth=True)


def undistort_pixels(uv: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Distorted pixel coordinates (N, 2) -> pixels of the ideal pinhole camera with the same ``K``."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 1, 2)
    K = np.asarray(K, dtype=np.float64)
    out = _cv2().undistortPoints(uv, K, np.asarray(dist, dtype=np.float64), None, K, criteria=_UNDISTORT_CRITERIA)
    return out.reshape(-1, 2)


def fit_image(image: np.ndarray, plan: FitPlan, *, depth: bool = False) -> np.ndarray:
    """Resize and centre-crop or pad one (H, W, 3) uint8 image or (H, W) float32 depth map by ``plan``
    (bars: black, depth 0)."""
    cv2 = _cv2()
    if image.shape[:2] != (plan.in_height, plan.in_width):
        raise CaptureError(f"image is {image.shape[1]}x{image.shape[0]}, the plan is for {plan.in_width}x{plan.in_height}")
    size = (plan.scaled_width, plan.scaled_height)
    if size != (plan.in_width, plan.in_height):
        if depth:
            interp = cv2.INTER_NEAREST_EXACT
        elif plan.sx <= 1 and plan.sy <= 1:
            interp = cv2.INTER_AREA
        else:
            interp = cv2.INTER_LINEAR
        image = cv2.resize(image, size, interpolation=interp)
    if plan.x0 >= 0 and plan.y0 >= 0:
        return np.ascontiguousarray(image[plan.y0:plan.y0 + plan.out_height, plan.x0:plan.x0 + plan.out_width])
    out = np.zeros((plan.out_height, plan.out_width) + image.shape[2:], dtype=image.dtype)
    sx, sy, dx, dy = max(plan.x0, 0), max(plan.y0, 0), max(-plan.x0, 0), max(-plan.y0, 0)
    w = min(plan.scaled_width - sx, plan.out_width - dx)
    h = min(plan.scaled_height - sy, plan.out_height - dy)
    out[dy:dy + h, dx:dx + w] = image[sy:sy + h, sx:sx + w]
    return out


def fit_trajectory(traj: Trajectory, plan: FitPlan) -> Trajectory:
    """The calibration of the fitted images: intrinsics mapped by ``plan``, distortion dropped."""
    return Trajectory(K=plan.intrinsics(traj.K), w2c=traj.w2c, width=plan.out_width, height=plan.out_height,
                      timestamps=traj.timestamps)


def select_frames(total: int, *, num_frames: int | None, start: int = 0) -> range:
    """Frame indices ``[start, start + num_frames)`` of a ``total``-frame clip (checked)."""
    if isinstance(start, bool) or not isinstance(start, (int, np.integer)) or not 0 <= start < total:
        raise CaptureError(f"start frame {start!r} outside the capture's 0..{total - 1}")
    available = total - start
    if num_frames is None:
        num_frames = available
    if isinstance(num_frames, bool) or not isinstance(num_frames, (int, np.integer)) or not 1 <= num_frames <= available:
        raise CaptureError(f"num_frames {num_frames!r}: only {available} frames from frame {start} on")
    return range(int(start), int(start + num_frames))


def _fitted_camera(traj: Trajectory, frames: np.ndarray, depth: np.ndarray | None, plan: FitPlan,
                   sel: range) -> tuple[Trajectory, np.ndarray, np.ndarray | None]:
    fitters: dict[bytes, FrameFitter] = {}  # one per distinct K (usually one per camera)
    out_rgb = np.empty((len(sel), plan.out_height, plan.out_width, 3), dtype=np.uint8)
    out_depth = None if depth is None else np.empty((len(sel), plan.out_height, plan.out_width), dtype=np.float32)
    for j, i in enumerate(sel):
        key = traj.K[i].tobytes()
        if key not in fitters:
            fitters[key] = FrameFitter(traj.K[i], traj.distortion, plan)
        out_rgb[j] = fitters[key].image(frames[i])
        if depth is not None:
            out_depth[j] = fitters[key].depth(depth[i])
    return fit_trajectory(traj[sel.start:sel.stop], plan), out_rgb, out_depth


def fit_capture(capture: Capture, *, height: int, width: int, num_frames: int | None = None,
                start: int = 0, fit: str = "crop") -> Capture:
    """A copy of ``capture`` undistorted, resized and centre-cropped (``fit="crop"``: the shorter side
    fits) or letterboxed (``fit="pad"``: the whole picture, black bars) to ``height`` x ``width`` with
    intrinsics updated, keeping frames ``[start, start + num_frames)``.

    The result has no distortion terms; metadata records the fit under ``"fit"``.
    """
    sel = select_frames(capture.num_frames, num_frames=num_frames, start=start)
    check_fit(fit)
    cameras, frames, depth = {}, {}, {}
    for name, traj in capture.cameras.items():
        plan = plan_fit(traj.width, traj.height, out_height=height, out_width=width, fit=fit)
        d = capture.depth[name] if capture.has_depth(name) else None
        cameras[name], frames[name], dd = _fitted_camera(traj, capture.frames[name], d, plan, sel)
        if dd is not None:
            depth[name] = dd
    metadata = dict(capture.metadata)
    metadata["fit"] = {"height": height, "width": width, "start": sel.start, "num_frames": len(sel), "mode": fit}
    return Capture(cameras=cameras, frames=frames, depth=depth or None, fps=capture.fps,
                   capture_id=capture.capture_id, metadata=metadata)
