"""Asset pools: disjoint train/test textures and objects, sane textures, exact mirror-repeat sampling."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from vt4dcodec.synth import SynthError, texture_names, texture_split
from vt4dcodec.synth.assets import PHOTO_TEXTURES, PROCEDURAL_KINDS, TEXTURE_SIZE, load_texture, texture_bank

from .helpers import scene


def test_texture_pools_are_disjoint_and_cover_both_kinds():
    train, test = set(texture_names("train")), set(texture_names("test"))
    assert not train & test
    assert len(train) >= 40 and len(test) >= 10
    for pool in (train, test):
        assert any(n in PHOTO_TEXTURES for n in pool) and any(n.startswith("proc_") for n in pool)
    kinds = {pool_name: {PROCEDURAL_KINDS[int(n[5:]) % len(PROCEDURAL_KINDS)] for n in pool if n.startswith("proc_")}
             for pool_name, pool in (("train", train), ("test", test))}
    assert kinds["train"] == kinds["test"] == set(PROCEDURAL_KINDS)   # same kinds, different instances
    assert all(texture_split(n) == "train" for n in train)
    assert all(texture_split(n) == "test" for n in test)


@settings(max_examples=6)
@given(seed=st.integers(0, 200))
def test_generated_scenes_use_only_their_split_pool(seed):
    """Test scenes use textures (and so textured objects) no training scene can use, and vice versa."""
    for split in ("train", "test"):
        sc = scene(seed, split)
        pool = set(texture_names(split))
        assert set(sc.textures) <= pool
        assert {o["texture"] for o in sc.objects} <= pool
        assert sc.capture.metadata["split"] == split


def test_object_combinations_disjoint_over_many_scenes():
    train_objects = {(o["shape"], o["texture"]) for s in range(12) for o in scene(s, "train").objects}
    test_objects = {(o["shape"], o["texture"]) for s in range(12) for o in scene(s, "test").objects}
    assert train_objects and test_objects and not train_objects & test_objects


@pytest.mark.parametrize("name", texture_names("train")[:4] + texture_names("test")[:4] + ["proc_01", "proc_03"])
def test_textures_are_rgb_in_range_and_not_flat(name):
    tex = load_texture(name)
    assert tex.shape == (TEXTURE_SIZE, TEXTURE_SIZE, 3) and tex.dtype == np.float32
    assert tex.min() >= 0.0 and tex.max() <= 1.0
    assert tex.std() > 0.02


def test_unknown_texture_and_split_are_errors():
    for bad in ("nope", "proc_48", "proc_x", "proc_"):
        with pytest.raises(SynthError):
            load_texture(bad)
        with pytest.raises(SynthError):
            texture_split(bad)
    with pytest.raises(SynthError):
        texture_names("validation")


@given(i=st.integers(-600, 600), j=st.integers(-600, 600), k=st.integers(0, 12))
def test_level0_sampling_at_texel_centres_is_the_mirrored_texel(i, j, k):
    bank = texture_bank("test")
    k = k % len(bank.names)

    def mirror(a):
        m = a % (2 * TEXTURE_SIZE)
        return m if m < TEXTURE_SIZE else 2 * TEXTURE_SIZE - 1 - m

    got = bank.sample(np.array([k]), np.array([i + 0.5]), np.array([j + 0.5]), np.array([0.0]))[0]
    want = load_texture(bank.names[k])[mirror(j), mirror(i)]
    assert np.allclose(got, want, atol=1e-6)


@given(u=st.floats(-1e3, 1e3), v=st.floats(-1e3, 1e3), level=st.floats(-2, 9))
def test_sampling_is_bounded_and_finite(u, v, level):
    bank = texture_bank("train")
    rgb = bank.sample(np.array([3]), np.array([u]), np.array([v]), np.array([level]))
    assert rgb.shape == (1, 3) and np.all(np.isfinite(rgb)) and rgb.min() >= 0 and rgb.max() <= 1 + 1e-6
