"""Hypothesis strategies and small builders for format tests."""

from __future__ import annotations

import hashlib
import importlib.util
from dataclasses import replace
from pathlib import Path

import numpy as np
from hypothesis import strategies as st

from vt4dcodec.cameras import Trajectory
from vt4dcodec.format import ENCODINGS, ModelFingerprint, Provenance, Scene

REPO = Path(__file__).resolve().parents[2]


def load_vector_tool():
    """spec/make_vectors.py as a module (the container-surgery helpers live there)."""
    spec = importlib.util.spec_from_file_location("make_vectors", REPO / "spec" / "make_vectors.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def fingerprint(static_shape, dynamic_shape) -> ModelFingerprint:
    return ModelFingerprint("test-model", "0.1", hashlib.sha256(b"c").hexdigest(), hashlib.sha256(b"w").hexdigest(),
                            tuple(static_shape), tuple(dynamic_shape))


def simple_scene(ns=4, nd=3, d=2, frames=2, seed=0, **kw) -> Scene:
    rng = np.random.default_rng(seed)
    K = np.array([[50.0, 0, 16], [0, 50.0, 12], [0, 0, 1]])
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    w2c[:, 2, 3] = np.arange(frames) + 1.0
    cams = Trajectory(np.tile(K, (frames, 1, 1)), w2c, 32, 24)
    return Scene(rng.standard_normal((ns, d)).astype(np.float32), rng.standard_normal((nd, d)).astype(np.float32),
                 cams, fingerprint((ns, d), (nd, d)), **kw)


def camera(rng: np.random.Generator, frames: int, *, static: bool = False, zoom: bool = False,
           size: tuple[int, int] = (32, 24)) -> Trajectory:
    """A random rigid camera (random rotations and translations), constant or zooming K."""
    q = rng.standard_normal((frames, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    w2c[:, :3, :3] = np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
                               np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
                               np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], 1)
    w2c[:, :3, 3] = rng.uniform(-4, 4, (frames, 3))
    if static:
        w2c[:] = w2c[0]
    K = np.tile(np.array([[50.0, 0.0, 16.0], [0.0, 50.0, 12.0], [0.0, 0.0, 1.0]]), (frames, 1, 1))
    if zoom:
        K[:, 0, 0] = K[:, 1, 1] = rng.uniform(30, 90, frames)
    return Trajectory(K, w2c, *size)


def rig_scene(count: int = 2, frames: int = 2, seed: int = 0, *, timestamps: bool = True, **kw) -> Scene:
    """simple_scene with ``count`` extra cameras (alternately moving and static, one zooming)."""
    rng = np.random.default_rng(seed)
    base = simple_scene(frames=frames, seed=seed, **kw)
    cams = base.cameras
    if timestamps:
        cams = replace(cams, timestamps=np.arange(frames) / 30.0)
    extras = [camera(rng, frames, static=i % 2 == 1, zoom=i == 2) for i in range(count)]
    return Scene(base.static_tokens, base.dynamic_tokens, cams, base.fingerprint, base.metadata, base.provenance,
                 base.encoding, extra_cameras=extras)


finite_f32 = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False, width=32)


@st.composite
def token_matrix(draw, rows, cols, elements=finite_f32):
    values = draw(st.lists(elements, min_size=rows * cols, max_size=rows * cols))
    return np.array(values, dtype=np.float32).reshape(rows, cols)


def _rotation(angles) -> np.ndarray:
    a, b, c = angles
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rx = np.array([[1, 0, 0], [0, np.cos(c), -np.sin(c)], [0, np.sin(c), np.cos(c)]])
    return rz @ ry @ rx


@st.composite
def trajectories(draw) -> Trajectory:
    frames = draw(st.integers(1, 5))
    width, height = draw(st.integers(1, 4096)), draw(st.integers(1, 4096))
    angle = st.floats(-3.1, 3.1, allow_nan=False)
    metres = st.floats(-100, 100, allow_nan=False)
    K = np.zeros((frames, 3, 3))
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    for t in range(frames):
        K[t] = [[draw(st.floats(1, 5000)), draw(st.floats(-1, 1)), draw(st.floats(0, width))],
                [0, draw(st.floats(1, 5000)), draw(st.floats(0, height))], [0, 0, 1]]
        w2c[t, :3, :3] = _rotation([draw(angle) for _ in range(3)])
        w2c[t, :3, 3] = [draw(metres) for _ in range(3)]
    n_dist = draw(st.sampled_from([None, 4, 5, 8, 12, 14]))
    dist = None if n_dist is None else np.array(draw(st.lists(st.floats(-1, 1), min_size=n_dist, max_size=n_dist)))
    ts = None
    if draw(st.booleans()):
        ts = np.cumsum(draw(st.lists(st.floats(0, 10), min_size=frames, max_size=frames)))
    return Trajectory(K, w2c, width, height, distortion=dist, timestamps=ts)


json_leaf = st.one_of(st.none(), st.booleans(), st.integers(-(1 << 63), (1 << 63) - 1),
                      st.floats(allow_nan=False, allow_infinity=False), st.text(max_size=20))
metadata = st.dictionaries(st.text(max_size=10), st.recursive(
    json_leaf, lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=5), c, max_size=3),
    max_leaves=10), max_size=5)
provenances = st.none() | st.builds(
    Provenance, st.just("0.1.0"), st.just("2026-03-04T05:06:07Z"), st.none() | st.text("abc-_0123", min_size=1,
                                                                                      max_size=12),
    st.sampled_from(["encoded", "generated"]))


@st.composite
def scenes(draw) -> Scene:
    d = draw(st.integers(1, 9))
    ns, nd = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    enc = draw(st.sampled_from(ENCODINGS))
    elements = st.floats(-60000, 60000, allow_nan=False, width=32) if enc == "float16" else finite_f32
    return Scene(draw(token_matrix(ns, d, elements)), draw(token_matrix(nd, d, elements)), draw(trajectories()),
                 fingerprint((ns, d), (nd, d)), draw(metadata), draw(provenances), enc)
