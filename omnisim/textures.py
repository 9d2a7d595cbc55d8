"""Texture images made offline: scikit-image's bundled photographs and seeded noise.

Every function returns a float32 ``(H, W, 3)`` array with values in [0, 1]
(linear RGB reflectance), ready to become a Mitsuba bitmap texture.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from .settings import SettingError, check_fields, setting

__all__ = ["BUNDLED_PHOTOS", "PhotoTexture", "NoiseTexture", "TEXTURE_SOURCES", "photo_texture",
           "noise_texture", "texture_image", "texture_side", "linear_texture_from_image"]

# Photographs shipped inside the scikit-image wheel (CC0 or public domain); the
# package fetches others over the network, which is not available here.
BUNDLED_PHOTOS = ("grass", "brick", "gravel", "camera", "astronaut", "coffee", "chelsea",
                  "rocket", "moon", "page", "coins", "clock", "colorwheel", "hubble_deep_field",
                  "immunohistochemistry", "text", "cat", "cell")
# Largest noise texture side, pixels: the noise is summed in a float64 (size, size) array and
# kept as float32 RGB, 512 MiB + 768 MiB at 8192 px (textures here are 256 px).
MAX_NOISE_SIZE = 8192
# Largest gain (brightness times a tint) of a photograph: its darkest non-black 8-bit sRGB level is
# 1 / (255 * 12.92) in linear values, which are clipped to [0, 1]; beyond this gain every non-black
# pixel is white (and gains near float32's range overflowed to NaN texels).
MAX_PHOTO_GAIN = 255 * 12.92


def _as_rgb(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype == bool:
        image = image.astype(np.float32)
    elif np.issubdtype(image.dtype, np.integer):
        image = image.astype(np.float32) / float(np.iinfo(image.dtype).max)
    image = image.astype(np.float32)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    return np.ascontiguousarray(image[..., :3])


def _srgb_to_linear(image: np.ndarray) -> np.ndarray:
    return np.where(image <= 0.04045, image / 12.92, ((image + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_texture_from_image(image) -> np.ndarray:
    """An sRGB-encoded image (8- or 16-bit or float in [0, 1], gray, RGB or RGBA) as linear RGB.

    Parameters
    ----------
    image : (H, W), (H, W, 3) or (H, W, 4) array_like (or a PIL image)
        Rows top to bottom; alpha is dropped.

    Returns
    -------
    (H, W, 3) float32 ndarray
    """
    return _srgb_to_linear(_as_rgb(np.asarray(image)))


def photo_texture(name: str, *, tint=(1.0, 1.0, 1.0), brightness: float = 1.0) -> np.ndarray:
    """A bundled scikit-image photograph as a linear-RGB texture.

    Parameters
    ----------
    name : str
        One of :data:`BUNDLED_PHOTOS`.
    tint : (3,) sequence of float, keyword-only
        Per-channel multiplier (e.g. green for grey grass).
    brightness : float, keyword-only
        Overall multiplier; values are clipped to [0, 1].

    Returns
    -------
    (H, W, 3) float32 ndarray
    """
    import skimage.data

    if name not in BUNDLED_PHOTOS:
        raise ValueError(f"unknown photo texture {name!r}; expected one of {', '.join(BUNDLED_PHOTOS)}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        image = getattr(skimage.data, name)()
    rgb = _srgb_to_linear(_as_rgb(image))
    rgb = rgb * np.asarray(tint, dtype=np.float32)[None, None, :] * float(brightness)
    return np.clip(rgb, 0.0, 1.0).astype(np.float32)


def noise_texture(size: int, *, seed: int, octaves: int = 5, base_cells: int = 4,
                  color_a=(0.2, 0.2, 0.2), color_b=(0.8, 0.8, 0.8)) -> np.ndarray:
    """Seeded, tileable fractal value noise blended between two colours.

    Parameters
    ----------
    size : int
        Texture side in pixels (square).
    seed : int, keyword-only
        Random seed; the same seed gives the same texture.
    octaves : int, keyword-only
        Number of frequency doublings.
    base_cells : int, keyword-only
        Lattice cells across the texture at the lowest frequency.
    color_a, color_b : (3,) sequence of float, keyword-only
        Linear RGB colours at noise values 0 and 1.

    Returns
    -------
    (size, size, 3) float32 ndarray
    """
    if size < 2 or octaves < 1 or base_cells < 1:
        raise ValueError(f"expected size >= 2, octaves >= 1, base_cells >= 1; got {size}, {octaves}, {base_cells}")
    rng = np.random.default_rng(seed)
    coords = np.arange(size) / size
    total = np.zeros((size, size), dtype=np.float64)
    amplitude, weight = 1.0, 0.0
    for octave in range(octaves):
        cells = base_cells * 2 ** octave
        lattice = rng.random((cells, cells))
        t = coords * cells
        i0 = np.floor(t).astype(int) % cells
        i1 = (i0 + 1) % cells
        f = t - np.floor(t)
        f = f * f * (3.0 - 2.0 * f)  # smoothstep between lattice values
        top = lattice[i0][:, i0] * (1 - f)[None, :] + lattice[i0][:, i1] * f[None, :]
        bottom = lattice[i1][:, i0] * (1 - f)[None, :] + lattice[i1][:, i1] * f[None, :]
        total += amplitude * (top * (1 - f)[:, None] + bottom * f[:, None])
        weight += amplitude
        amplitude *= 0.5
    value = (total / weight)[..., None]
    value = (value - value.min()) / max(value.max() - value.min(), 1e-9)
    a = np.asarray(color_a, dtype=np.float64)[None, None, :]
    b = np.asarray(color_b, dtype=np.float64)[None, None, :]
    return (a * (1 - value) + b * value).astype(np.float32)


@dataclass(frozen=True)
class PhotoTexture:
    """``[textures.NAME]`` with ``source = "photo"``: a bundled photograph (see :data:`BUNDLED_PHOTOS`)."""

    name: str = setting(doc="bundled scikit-image photograph", choices=BUNDLED_PHOTOS)
    tint: tuple[float, float, float] = setting((1.0, 1.0, 1.0), "per-channel multiplier", minimum=0.0)
    brightness: float = setting(1.0, "overall multiplier (values are clipped to [0, 1])", minimum=0.0)

    def __post_init__(self):
        check_fields(self)
        gain = self.brightness * max(self.tint)
        if gain > MAX_PHOTO_GAIN:
            raise SettingError("brightness", f"expected brightness times the largest tint <= {MAX_PHOTO_GAIN:g} "
                                             f"(beyond it every non-black pixel is white), got {gain:.4g}")


@dataclass(frozen=True)
class NoiseTexture:
    """``[textures.NAME]`` with ``source = "noise"``: seeded fractal value noise between two colours."""

    size: int = setting(256, "texture side in pixels", minimum=2, maximum=MAX_NOISE_SIZE)
    octaves: int = setting(5, "number of frequency doublings", minimum=1, maximum=16)
    cells: int = setting(4, "lattice cells across the texture at the lowest frequency", minimum=1)
    color_a: tuple[float, float, float] = setting((0.2, 0.2, 0.2), "linear RGB reflectance at noise 0",
                                                  minimum=0.0, maximum=1.0)
    color_b: tuple[float, float, float] = setting((0.8, 0.8, 0.8), "linear RGB reflectance at noise 1",
                                                  minimum=0.0, maximum=1.0)
    seed: int = setting(0, "texture seed, offset by the scene's layout seed", minimum=0)

    def __post_init__(self):
        check_fields(self)
        # The lattice doubles every octave; a (cells, cells) lattice is drawn for each.
        finest = self.cells * 2 ** (self.octaves - 1)
        if finest > self.size:
            raise SettingError("cells", f"expected cells * 2^(octaves - 1) <= size = {self.size} (the finest "
                                        f"lattice no finer than the pixels), got {self.cells} * "
                                        f"2^{self.octaves - 1} = {finest}")


# The classes a texture table's ``source`` key selects.
TEXTURE_SOURCES = {"photo": PhotoTexture, "noise": NoiseTexture}


def texture_image(texture: PhotoTexture | NoiseTexture, *, seed: int) -> np.ndarray:
    """Texture image ``(H, W, 3)`` float32 (linear RGB) of validated texture settings.

    Parameters
    ----------
    texture : PhotoTexture or NoiseTexture
    seed : int, keyword-only
        The scene's layout seed; a noise texture's own seed is offset by it.
    """
    if isinstance(texture, PhotoTexture):
        return photo_texture(texture.name, tint=texture.tint, brightness=texture.brightness)
    return noise_texture(texture.size, seed=texture.seed + seed, octaves=texture.octaves,
                         base_cells=texture.cells, color_a=texture.color_a, color_b=texture.color_b)


def texture_side(texture: PhotoTexture | NoiseTexture) -> int:
    """The larger side in pixels of the image :func:`texture_image` makes (without making a noise image)."""
    if isinstance(texture, PhotoTexture):
        import skimage.data

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return int(max(np.shape(getattr(skimage.data, texture.name)())[:2]))
    return int(texture.size)
