"""Ray-primitive intersections land on the surfaces; motion laws are rigid and behave as documented."""

from __future__ import annotations

import numpy as np
from hypothesis import given, strategies as st

from vt4dcodec.synth.motion import MOTION_KINDS, sample_motion
from vt4dcodec.synth.raycast import intersect_box, intersect_card, intersect_plane_z, intersect_sphere

finite = st.floats(-3, 3, allow_nan=False)
vec = st.tuples(finite, finite, finite).map(np.array)


def _rays(origin, target):
    d = target - origin
    n = np.linalg.norm(d)
    return origin[None], (d / max(n, 1e-12))[None], n


@given(origin=vec, target=vec, r=st.floats(0.1, 1.0))
def test_sphere_hits_lie_on_the_sphere_and_are_first(origin, target, r):
    o, d, n = _rays(origin * 3, target * 0.2)
    if n < 1e-3:
        return
    s, normal = intersect_sphere(o, d, r)
    if np.isfinite(s[0]):
        hit = o[0] + s[0] * d[0]
        assert abs(np.linalg.norm(hit) - r) < 1e-6
        assert np.dot(normal[0], d[0]) <= 1e-9          # entering: normal faces the ray
    elif np.linalg.norm(origin * 3) > r:
        # a miss: the ray's closest approach stays outside (or the sphere is behind)
        closest = o[0] - np.dot(o[0], d[0]) * d[0]
        assert np.linalg.norm(closest) >= r - 1e-9 or np.dot(o[0], d[0]) > 0


@given(origin=vec, target=vec, half=st.tuples(*[st.floats(0.1, 1.0)] * 3).map(np.array))
def test_box_hits_lie_on_the_boundary(origin, target, half):
    o, d, n = _rays(origin * 3, target * 0.1)
    if n < 1e-3:
        return
    s, normal = intersect_box(o, d, half)
    inside = np.all(np.abs(o[0]) < half)
    if np.isfinite(s[0]):
        hit = o[0] + s[0] * d[0]
        assert np.all(np.abs(hit) <= half + 1e-6)
        assert np.isclose(np.max(np.abs(hit) / half), 1.0, atol=1e-6)
        assert np.dot(normal[0], d[0]) <= 1e-9
    elif not inside and np.all(np.abs(target * 0.1) < half):
        raise AssertionError("a ray aimed at a point inside the box must hit it")


def test_box_ray_parallel_to_a_slab_outside_it_misses():
    """Regression: a ray parallel to the z slab but above the box was reported as hitting it."""
    o = np.array([[0.0, 3.0, 0.3], [0.0, 3.0, 0.1]])
    d = np.array([[0.0, -1.0, 0.0], [0.0, -1.0, 0.0]])
    s, normal = intersect_box(o, d, np.array([1.0, 1.0, 0.25]))
    assert np.isinf(s[0])
    assert s[1] == 2.0 and np.array_equal(normal[1], [0.0, 1.0, 0.0])


def test_card_and_plane():
    o = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 2.0], [5.0, 0.0, 2.0]])
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    s, normal = intersect_card(o, d, 1.0, 0.5)
    assert s[0] == 2.0 and np.isinf(s[1]) and np.isinf(s[2])
    assert normal[0, 2] == 1.0
    assert np.array_equal(intersect_plane_z(o, d, 0.0), [2.0, np.inf, 2.0])


@given(seed=st.integers(0, 2**31), kind=st.sampled_from(MOTION_KINDS + ("static",)), upright=st.booleans())
def test_motion_laws_are_rigid_and_stay_above_ground(seed, kind, upright):
    rng = np.random.default_rng(seed)
    law = sample_motion(rng, kind, start=np.array([0.3, -0.2]), rest_height=0.4, upright=upright)
    t = np.linspace(0, 2, 17)
    R, p = law.pose(t)
    assert R.shape == (17, 3, 3) and p.shape == (17, 3)
    assert np.allclose(np.swapaxes(R, 1, 2) @ R, np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.all(p[:, 2] >= 0.4 - 1e-9)                 # never sinks below its resting height
    assert np.allclose(p[0, :2], [0.3, -0.2])             # starts where it was placed
    moved = np.abs(R - R[0]).max() + np.abs(p - p[0]).max()
    assert (moved > 1e-3) == law.moves
    if upright:                                            # upright objects only turn about z
        assert np.allclose(R[:, 2, :], R[0, 2, :], atol=1e-9) or kind == "static"
    if kind == "circular":
        centre = law.p0
        assert np.allclose(np.linalg.norm(p[:, :2] - centre[:2], axis=1), law.params["radius"])
