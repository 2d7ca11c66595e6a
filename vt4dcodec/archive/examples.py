"""Deterministic example scenes for tests, benchmarks and the archive's golden vectors.

The tokens are seeded random numbers (not a model's output); everything else - cameras, fingerprint,
provenance - is a valid, fully specified scene, so records built from them exercise the real
container end to end.
"""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np

from ..cameras import Trajectory
from ..format import ModelFingerprint, Provenance, Scene, dumps

__all__ = ["example_scene", "example_record"]


def example_scene(seed: int, *, static_shape: tuple[int, int] = (96, 64),
                  dynamic_shape: tuple[int, int] = (48, 64), frames: int = 4, encoding: str = "int8",
                  capture_id: str | None = None) -> Scene:
    """A valid ``vt4dcodec.format.Scene`` whose content is a pure function of the arguments.

    Tokens are float32 N(0, 1) draws; the camera moves 5 cm per frame along +x (w2c in metres,
    K in pixels for a 64x48 image).
    """
    rng = np.random.default_rng(seed)
    static = rng.standard_normal(static_shape).astype(np.float32)
    dynamic = rng.standard_normal(dynamic_shape).astype(np.float32)
    K = np.tile(np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]]), (frames, 1, 1))
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    w2c[:, 0, 3] = -0.05 * np.arange(frames)
    fingerprint = ModelFingerprint(
        model_id="vt4d-example", model_version="1.0",
        config_sha256=hashlib.sha256(b"example-config").hexdigest(),
        weights_sha256=hashlib.sha256(b"example-weights").hexdigest(),
        static_shape=(static_shape[0], static_shape[1]), dynamic_shape=(dynamic_shape[0], dynamic_shape[1]),
    )
    provenance = Provenance(library_version="0.1.0", created_utc="2026-01-01T00:00:00Z",
                            source_capture_id=capture_id or f"example-{seed}", kind="encoded")
    return Scene(static, dynamic, Trajectory(K, w2c, 64, 48), fingerprint, metadata={"seed": int(seed)},
                 provenance=provenance, encoding=encoding)


def example_record(seed: int, **kwargs: Any) -> bytes:
    """``.vt4d`` bytes of :func:`example_scene` (deterministic).  The 1.0 cameras section: the archive
    vectors made from these records are kept byte for byte (FORMAT.md, versioning rules)."""
    return dumps(example_scene(seed, **kwargs), cameras="legacy", header="legacy")
