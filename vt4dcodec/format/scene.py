"""The in-memory scene: what one ``.vt4d`` file holds."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..cameras import Trajectory
from ..errors import FormatError, LimitExceededError
from .encodings import ALL_ENCODINGS
from .fingerprint import ModelFingerprint, Provenance
from .limits import MAX_EXTRA_CAMERAS, MAX_FRAMES, MAX_IMAGE_SIDE
from .metadata import normalize_metadata

__all__ = ["Scene", "normalize_extra_cameras"]


def _tokens(value: Any, what: str) -> np.ndarray:
    arr = np.asarray(value)
    if arr.ndim != 2:
        raise FormatError(f"{what} must be a 2-D (N, d) array, got shape {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise FormatError(f"{what} must hold real numbers, got dtype {arr.dtype}")
    arr = arr.astype(np.float32, copy=False)
    if not np.all(np.isfinite(arr)):
        raise FormatError(f"{what} holds NaN or inf (or values beyond float32's range)")
    return arr


def normalize_extra_cameras(cameras: Trajectory, extras: Any) -> tuple[Trajectory, ...]:
    """``extras`` (a tuple or list of trajectories) checked against ``cameras`` as the extra cameras section
    can store them (FORMAT.md I.5.3): at most 63, each a Trajectory with ``cameras``' frame count and image
    size, no distortion, and timestamps that are absent or ``cameras``' own.  Returned as a tuple in which
    every trajectory carries ``cameras``' timestamps (the ones a reader gives back: the cameras are synchronized,
    their frames are the same instants)."""
    if not isinstance(extras, (tuple, list)):
        raise FormatError(f"extra_cameras must be a tuple (or list) of Trajectory, got {type(extras).__name__}")
    if len(extras) > MAX_EXTRA_CAMERAS:
        raise LimitExceededError(f"{len(extras)} extra cameras exceed the limit of {MAX_EXTRA_CAMERAS}")
    shared = cameras.timestamps
    out = []
    for i, traj in enumerate(extras):
        if not isinstance(traj, Trajectory):
            raise FormatError(f"extra_cameras[{i}] must be a vt4dcodec.cameras.Trajectory, got {type(traj).__name__}")
        if traj.num_frames != cameras.num_frames:
            raise FormatError(f"extra_cameras[{i}] has {traj.num_frames} frames but cameras has {cameras.num_frames}: "
                              "every encoded camera covers the same frames")
        if (traj.width, traj.height) != (cameras.width, cameras.height):
            raise FormatError(f"extra_cameras[{i}] is {traj.width}x{traj.height} px but cameras is "
                              f"{cameras.width}x{cameras.height}: every encoded camera has the same image size")
        if traj.distortion is not None:
            raise FormatError(f"extra_cameras[{i}] has distortion terms; extra cameras are stored as pinhole "
                              "cameras (K and w2c only): undistort, then dataclasses.replace(traj, distortion=None)")
        if traj.timestamps is not None and (shared is None or not np.array_equal(traj.timestamps, shared)):
            raise FormatError(f"extra_cameras[{i}] has timestamps other than cameras': the scene stores one set of "
                              "frame times for every encoded camera; use dataclasses.replace(traj, timestamps=None)")
        out.append(traj if traj.timestamps is shared else replace(traj, timestamps=shared))
    return tuple(out)


@dataclass(eq=False)
class Scene:
    """One encoded scene.

    Attributes:
        static_tokens: (N_s, d) float32 static tokens Z_s.
        dynamic_tokens: (N_d, d) float32 dynamic tokens Z_d.
        cameras: the source camera trajectory the tokens were encoded from (one pose per frame).
        fingerprint: the model that made the tokens; its shapes must equal the token shapes.
        metadata: bounded user key/values (see FORMAT.md, "Metadata").
        provenance: where the tokens came from, or None.
        encoding: the token encoding used by :func:`save` unless overridden
            ("float32" | "float16" | "int8" | "int4" | "int2-rans" .. "int8-rans"); a loaded scene carries
            its file's encoding.
        extra_cameras: the trajectories of the further encoded cameras of a multi-camera encode, in encoding
            order (the first encoded camera is ``cameras``); at most 63, a list is stored as a tuple.  Each has
            ``cameras``' frame count and image size and no distortion; they share ``cameras``' timestamps (one
            given without timestamps takes them).  Stored in the extra cameras section (format 1.4), each as
            ``cameras`` is stored (FORMAT.md I.5.3): bit for bit with ``cameras="exact"`` or ``"legacy"``, by
            default within 0.01 px of reprojection.
        quality: the quality level (1 = the coarsest) of a ``learned-rans`` scene, whose tokens are then exactly
            that level's quantized values; None for the other encodings (and a scene to be saved with another).
    """

    static_tokens: np.ndarray
    dynamic_tokens: np.ndarray
    cameras: Trajectory
    fingerprint: ModelFingerprint
    metadata: dict[str, Any] = field(default_factory=dict)
    provenance: Provenance | None = None
    encoding: str = "int8"
    extra_cameras: tuple[Trajectory, ...] = ()
    quality: int | None = None

    def __post_init__(self) -> None:
        self.static_tokens = _tokens(self.static_tokens, "static_tokens")
        self.dynamic_tokens = _tokens(self.dynamic_tokens, "dynamic_tokens")
        if not isinstance(self.cameras, Trajectory):
            raise FormatError(f"cameras must be a vt4dcodec.cameras.Trajectory, got {type(self.cameras).__name__}")
        if not isinstance(self.fingerprint, ModelFingerprint):
            raise FormatError("fingerprint must be a ModelFingerprint")
        if self.provenance is not None and not isinstance(self.provenance, Provenance):
            raise FormatError("provenance must be a Provenance or None")
        if self.encoding not in ALL_ENCODINGS:
            raise FormatError(f"encoding must be one of {ALL_ENCODINGS}, got {self.encoding!r}")
        if self.static_tokens.shape != self.fingerprint.static_shape:
            raise FormatError(f"static_tokens have shape {self.static_tokens.shape} but the model fingerprint "
                              f"says {self.fingerprint.static_shape}")
        if self.dynamic_tokens.shape != self.fingerprint.dynamic_shape:
            raise FormatError(f"dynamic_tokens have shape {self.dynamic_tokens.shape} but the model fingerprint "
                              f"says {self.fingerprint.dynamic_shape}")
        if self.static_tokens.shape[1] != self.dynamic_tokens.shape[1]:
            raise FormatError("static and dynamic tokens must have the same width d")
        if self.cameras.num_frames > MAX_FRAMES:
            raise LimitExceededError(f"{self.cameras.num_frames} frames exceed the limit of {MAX_FRAMES}")
        if max(self.cameras.width, self.cameras.height) > MAX_IMAGE_SIDE:
            raise LimitExceededError(f"image size exceeds {MAX_IMAGE_SIDE} pixels per side")
        if self.quality is not None and (isinstance(self.quality, bool) or not isinstance(self.quality, int)
                                         or not 1 <= self.quality <= 16):
            raise FormatError(f"quality must be None or a level from 1 to 16, got {self.quality!r}")
        self.extra_cameras = normalize_extra_cameras(self.cameras, self.extra_cameras)
        self.metadata = normalize_metadata(self.metadata)

    @classmethod
    def _from_verified(cls, **fields: Any) -> "Scene":
        """Build from parts a reader has already validated (skips re-checking every token)."""
        scene = cls.__new__(cls)
        for name, value in fields.items():
            setattr(scene, name, value)
        return scene

    @property
    def num_frames(self) -> int:
        return self.cameras.num_frames

    @property
    def num_cameras(self) -> int:
        """How many encoded cameras the scene records: ``cameras`` and the ``extra_cameras``."""
        return 1 + len(self.extra_cameras)

    @property
    def static_shape(self) -> tuple[int, int]:
        return tuple(self.static_tokens.shape)

    @property
    def dynamic_shape(self) -> tuple[int, int]:
        return tuple(self.dynamic_tokens.shape)

    def __eq__(self, other: object) -> bool:
        """Equal when every field is equal (tokens and cameras exactly).  Defining ``__eq__`` leaves the class
        unhashable (``__hash__`` is None): a scene is mutable."""
        if not isinstance(other, Scene):
            return NotImplemented
        return (self.encoding == other.encoding and self.quality == other.quality and self.fingerprint == other.fingerprint
                and self.provenance == other.provenance and self.metadata == other.metadata
                and self.cameras.equals(other.cameras)
                and len(self.extra_cameras) == len(other.extra_cameras)
                and all(a.equals(b) for a, b in zip(self.extra_cameras, other.extra_cameras))
                and np.array_equal(self.static_tokens, other.static_tokens)
                and np.array_equal(self.dynamic_tokens, other.dynamic_tokens))

    def __repr__(self) -> str:
        return (f"Scene(Z_s {self.static_shape[0]}x{self.static_shape[1]}, Z_d {self.dynamic_shape[0]}x"
                f"{self.dynamic_shape[1]}, {self.num_frames} frames {self.cameras.width}x{self.cameras.height}"
                f"{f', {len(self.extra_cameras)} extra cameras' if self.extra_cameras else ''}"
                f", encoding={self.encoding}{'' if self.quality is None else f' quality {self.quality}'}, model={self.fingerprint.short()})")
