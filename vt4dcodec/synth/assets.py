"""Textures for the synthetic scenes, with asset-disjoint train/test pools (numpy only).

A texture is a 128x128 RGB image in [0, 1], either a photo that scikit-image ships (loaded offline,
centre-cropped to a square and resized) or a procedural pattern (checker, stripes, smooth noise,
gradient bands, dots) made from a fixed seed.  Every texture belongs to exactly ONE split: the test
pool holds photos and procedural patterns that no training scene ever uses.  Objects are
(shape, texture) pairs, so objects are split-disjoint through their textures.

Textures are sampled with mirror-repeat addressing and a mip pyramid (2x2 box filtered levels
128, 64, ..., 4 texels), so distant or grazing surfaces are prefiltered instead of aliasing.
:class:`TextureBank` packs all levels of all textures into one flat atlas for vectorized lookups.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..errors import Vt4dError

__all__ = [
    "TEXTURE_SIZE", "MIP_LEVELS", "SPLITS", "PHOTO_TEXTURES", "PROCEDURAL_KINDS",
    "texture_names", "texture_split", "photo_image", "check_split", "load_texture", "TextureBank", "texture_bank",
    "SynthError", "hsv_rgb",
]

TEXTURE_SIZE = 128          # texels along each side of mip level 0
MIP_LEVELS = 6              # 128, 64, 32, 16, 8, 4 texels
SPLITS = ("train", "test")

# name -> split.  Whole photos are assigned to one split (never crops of the same photo in both).
PHOTO_TEXTURES: dict[str, str] = {
    "astronaut": "train", "coffee": "train", "chelsea": "train", "camera": "train",
    "brick": "train", "grass": "train", "moon": "train", "page": "train", "text": "train",
    "hubble_deep_field": "train", "immunohistochemistry": "train", "colorwheel": "train",
    "cell": "train", "logo": "train", "motorcycle_left": "train", "motorcycle_right": "train",
    "rocket": "test", "coins": "test", "gravel": "test", "clock": "test", "retina": "test",
}
PROCEDURAL_KINDS = ("checker", "stripes", "noise", "gradient", "dots")
NUM_PROCEDURAL = 48          # procedural textures proc_00 .. proc_47; proc_i is of kind i % 5
PROCEDURAL_TEST_EVERY = 6    # proc_i with i % 6 == 5 is a test texture (8 test, 40 train); as 6 and 5
                             # are coprime, both pools hold every procedural kind


class SynthError(Vt4dError, ValueError):
    """A synthetic-scene request is invalid (unknown split or texture, impossible configuration)."""


def check_split(split: str) -> str:
    if split not in SPLITS:
        raise SynthError(f"split must be one of {SPLITS}, got {split!r}")
    return split


def _procedural_split(index: int) -> str:
    return "test" if index % PROCEDURAL_TEST_EVERY == PROCEDURAL_TEST_EVERY - 1 else "train"


def texture_names(split: str) -> list[str]:
    """Names of the textures in the ``split`` pool ("train" or "test"), in a fixed order."""
    check_split(split)
    photos = [n for n, s in PHOTO_TEXTURES.items() if s == split]
    procs = [f"proc_{i:02d}" for i in range(NUM_PROCEDURAL) if _procedural_split(i) == split]
    return photos + procs


# --- photos --------------------------------------------------------------------------------------
def _photo_array(name: str) -> np.ndarray:
    import skimage.data as skdata

    if name in ("motorcycle_left", "motorcycle_right"):
        left, right, _ = skdata.stereo_motorcycle()
        return left if name == "motorcycle_left" else right
    return getattr(skdata, name)()


def _tint(gray: np.ndarray, name: str) -> np.ndarray:
    """Colour a grayscale photo with a fixed, name-derived tint so it is not plain gray."""
    rng = np.random.default_rng(sum(map(ord, name)))
    tint = 0.55 + 0.45 * rng.random(3)
    return gray[..., None] * tint / tint.max()


def _resize_square(img: np.ndarray, size: int) -> np.ndarray:
    """Centre-crop ``img`` (H, W, C) float to a square and area-resample it to ``size`` x ``size``."""
    import cv2  # area resampling is ~100x faster than skimage's anti-aliased resize

    h, w = img.shape[:2]
    s = min(h, w)
    y0, x0 = (h - s) // 2, (w - s) // 2
    sq = np.ascontiguousarray(img[y0:y0 + s, x0:x0 + s], dtype=np.float32)
    return cv2.resize(sq, (size, size), interpolation=cv2.INTER_AREA).reshape(size, size, -1)


@functools.lru_cache(maxsize=None)
def photo_image(name: str) -> np.ndarray:
    """Photo texture ``name`` at the resolution scikit-image ships it: (H, W, 3) float32 in [0, 1],
    RGBA composited over light gray, grayscale tinted as in the textures. Read-only (cached)."""
    if name not in PHOTO_TEXTURES:
        raise SynthError(f"unknown photo {name!r}; choose one of {sorted(PHOTO_TEXTURES)}")
    img = np.asarray(_photo_array(name))
    if img.dtype == bool:
        img = img.astype(np.float32)
    else:
        img = img.astype(np.float32) / (255.0 if img.dtype == np.uint8 else max(float(img.max()), 1e-6))
    if img.ndim == 3 and img.shape[2] == 4:          # RGBA logo: composite over light gray
        img = img[..., :3] * img[..., 3:] + 0.8 * (1.0 - img[..., 3:])
    if img.ndim == 2:
        img = _tint(img, name)
    img = np.ascontiguousarray(np.clip(img, 0.0, 1.0), dtype=np.float32)
    img.setflags(write=False)
    return img


def _photo_texture(name: str) -> np.ndarray:
    return np.clip(_resize_square(photo_image(name), TEXTURE_SIZE), 0.0, 1.0)


# --- procedural patterns -------------------------------------------------------------------------
def _colours(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` distinct saturated-ish RGB colours (n, 3) in [0.05, 0.95]."""
    hues = (rng.random() + np.arange(n) / n + 0.1 * rng.random(n)) % 1.0
    sat = 0.35 + 0.55 * rng.random(n)
    val = 0.35 + 0.6 * rng.random(n)
    return np.clip(hsv_rgb(hues, sat, val), 0.05, 0.95)


def hsv_rgb(hue: np.ndarray, sat: np.ndarray, val: np.ndarray) -> np.ndarray:
    """(n,) hues in [0, 1), saturations and values -> (n, 3) RGB (the HSV cone, piecewise linear in hue)."""
    k = (np.array([5.0, 3.0, 1.0])[None] + np.asarray(hue, np.float64)[:, None] * 6.0) % 6.0
    val, sat = np.asarray(val, np.float64)[:, None], np.asarray(sat, np.float64)[:, None]
    return val - val * sat * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)


def _periodic_noise(rng: np.random.Generator, size: int, cutoff: float) -> np.ndarray:
    """Tileable smooth noise in [0, 1] of shape (size, size): white noise low-passed in Fourier space."""
    spec = np.fft.fft2(rng.standard_normal((size, size)))
    f = np.fft.fftfreq(size)
    r = np.sqrt(f[:, None] ** 2 + f[None, :] ** 2)
    field = np.real(np.fft.ifft2(spec * np.exp(-(r / cutoff) ** 2)))
    field -= field.min()
    return field / max(field.max(), 1e-9)


def _procedural_texture(index: int) -> np.ndarray:
    rng = np.random.default_rng(10_007 * (index + 1))
    kind = PROCEDURAL_KINDS[index % len(PROCEDURAL_KINDS)]
    n = TEXTURE_SIZE
    yy, xx = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5, indexing="ij")
    c = _colours(rng, 4)
    if kind == "checker":
        period = n / int(rng.choice([2, 4, 8]))
        cell = (np.floor(xx / period) + np.floor(yy / period)) % 2
        img = c[0] * (1 - cell[..., None]) + c[1] * cell[..., None]
        img *= (0.85 + 0.15 * _periodic_noise(rng, n, 0.08))[..., None]
    elif kind == "stripes":
        freq = int(rng.integers(2, 9))
        ang = int(rng.integers(0, 3))           # 0 vertical, 1 horizontal, 2 diagonal (all tileable)
        coord = [xx, yy, xx + yy][ang] / n
        w = 0.5 + 0.5 * np.sin(2 * np.pi * freq * coord)
        img = c[0] * w[..., None] + c[1] * (1 - w[..., None])
    elif kind == "noise":
        w1 = _periodic_noise(rng, n, float(rng.uniform(0.03, 0.12)))
        w2 = _periodic_noise(rng, n, float(rng.uniform(0.1, 0.25)))
        img = c[0] * w1[..., None] + c[1] * (1 - w1[..., None])
        img = 0.75 * img + 0.25 * c[2] * w2[..., None]
    elif kind == "gradient":
        freq = int(rng.integers(1, 4))
        u = 0.5 + 0.5 * np.cos(2 * np.pi * freq * xx / n)
        v = 0.5 + 0.5 * np.cos(2 * np.pi * freq * yy / n)
        img = (c[0] * u[..., None] + c[1] * (1 - u[..., None])) * 0.6 + c[2] * v[..., None] * 0.4
    else:  # dots on a noisy ground
        period = n / int(rng.choice([4, 8]))
        dx = (xx % period) - period / 2
        dy = (yy % period) - period / 2
        radius = period * rng.uniform(0.2, 0.4)
        dot = np.clip(radius + 0.5 - np.sqrt(dx ** 2 + dy ** 2), 0.0, 1.0)
        base = c[0] * (0.8 + 0.2 * _periodic_noise(rng, n, 0.1))[..., None]
        img = base * (1 - dot[..., None]) + c[1] * dot[..., None]
    return np.clip(img, 0.0, 1.0).astype(np.float32)


@functools.lru_cache(maxsize=None)
def load_texture(name: str) -> np.ndarray:
    """The (128, 128, 3) float32 texture ``name`` in [0, 1] (cached per process; read-only)."""
    if name in PHOTO_TEXTURES:
        tex = _photo_texture(name)
    elif name.startswith("proc_") and name[5:].isdigit() and int(name[5:]) < NUM_PROCEDURAL:
        tex = _procedural_texture(int(name[5:]))
    else:
        raise SynthError(f"unknown texture {name!r}")
    tex.setflags(write=False)
    return tex


def texture_split(name: str) -> str:
    """The split ("train" or "test") that texture ``name`` belongs to."""
    if name in PHOTO_TEXTURES:
        return PHOTO_TEXTURES[name]
    if name.startswith("proc_") and name[5:].isdigit() and int(name[5:]) < NUM_PROCEDURAL:
        return _procedural_split(int(name[5:]))
    raise SynthError(f"unknown texture {name!r}")


# --- the mip-mapped atlas ------------------------------------------------------------------------
def _mip_pyramid(tex: np.ndarray) -> list[np.ndarray]:
    levels = [tex]
    for _ in range(MIP_LEVELS - 1):
        t = levels[-1]
        levels.append(0.25 * (t[0::2, 0::2] + t[1::2, 0::2] + t[0::2, 1::2] + t[1::2, 1::2]))
    return levels


@dataclass(frozen=True)
class TextureBank:
    """All textures of one split, mip-mapped and packed for vectorized trilinear sampling.

    Attributes:
        names: texture names; a texture is addressed by its index in this list.
        atlas: (num_textures, texels, 4) float32 RGB plus a zero pad channel (4-float rows gather
            fastest), every mip level of a texture flattened row-major one after the other.
        level_offset: (MIP_LEVELS,) int64 start of each level inside a texture's row of ``atlas``.
    """

    names: tuple[str, ...]
    atlas: np.ndarray
    level_offset: np.ndarray

    def sample(self, tex: np.ndarray, u: np.ndarray, v: np.ndarray, level: np.ndarray) -> np.ndarray:
        """Trilinear, mirror-repeat lookup.

        Args:
            tex: (N,) int texture indices into :attr:`names`.
            u, v: (N,) float texel coordinates at level 0 (texel centres at i + 0.5; any real value,
                the texture mirror-repeats with period 2 * 128).
            level: (N,) float mip level (0 = full resolution), clipped to [0, MIP_LEVELS - 1].
        Returns:
            (N, 3) float32 RGB in [0, 1].
        """
        level = np.clip(level, 0.0, MIP_LEVELS - 1.0)
        l0 = np.minimum(np.floor(level).astype(np.int32), MIP_LEVELS - 2)
        wl = (level - l0).astype(np.float32)[:, None]
        tex = tex.astype(np.int32)
        a = self._bilinear(tex, u, v, l0)
        b = self._bilinear(tex, u, v, l0 + 1)
        return (a + (b - a) * wl)[:, :3]

    def _bilinear(self, tex: np.ndarray, u: np.ndarray, v: np.ndarray, lev: np.ndarray) -> np.ndarray:
        shift = (TEXTURE_SIZE.bit_length() - 1) - lev           # log2 of this level's size
        size = (1 << shift).astype(np.int32)
        period_mask = 2 * size - 1                              # mirror-repeat period is 2 * size
        scale = (1.0 / size.astype(np.float32)) * np.float32(TEXTURE_SIZE)
        x = u.astype(np.float32) / scale - np.float32(0.5)
        y = v.astype(np.float32) / scale - np.float32(0.5)
        x0 = np.floor(x)
        y0 = np.floor(y)
        fx = (x - x0)[:, None]
        fy = (y - y0)[:, None]
        x0 = x0.astype(np.int32)
        y0 = y0.astype(np.int32)
        row = tex * np.int32(self.atlas.shape[1]) + self.level_offset[lev].astype(np.int32)
        flat = self.atlas.reshape(-1, 4)

        def mirror(i):
            # i mod 2s, then reflect the upper half: for m in [s, 2s), 2s - 1 - m == m XOR (2s - 1)
            m = i & period_mask
            return m ^ ((m >> shift) * period_mask)

        xa, xb = mirror(x0), mirror(x0 + 1)
        ya, yb = mirror(y0) * size + row, mirror(y0 + 1) * size + row
        take = np.take
        p00, p01 = take(flat, ya + xa, axis=0), take(flat, ya + xb, axis=0)
        p10, p11 = take(flat, yb + xa, axis=0), take(flat, yb + xb, axis=0)
        top = p00 + (p01 - p00) * fx
        bot = p10 + (p11 - p10) * fx
        return top + (bot - top) * fy


@functools.lru_cache(maxsize=None)
def texture_bank(split: str) -> TextureBank:
    """The :class:`TextureBank` of the ``split`` pool (built once per process)."""
    names = tuple(texture_names(split))
    rows, offsets, pos = [], [], 0
    for lev in range(MIP_LEVELS):
        offsets.append(pos)
        pos += (TEXTURE_SIZE >> lev) ** 2
    for name in names:
        rgb = np.concatenate([lv.reshape(-1, 3) for lv in _mip_pyramid(load_texture(name))])
        rows.append(np.concatenate([rgb, np.zeros((len(rgb), 1), np.float32)], axis=1))  # pad to RGBx
    atlas = np.ascontiguousarray(np.stack(rows).astype(np.float32))
    atlas.setflags(write=False)
    return TextureBank(names=names, atlas=atlas, level_offset=np.asarray(offsets, dtype=np.int64))
