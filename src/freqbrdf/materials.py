"""Principled-BRDF texture sets (base colour, roughness, metallic) and ground-truth generators.

A set is stored as three EXR files in one folder: ``base_color.exr`` (RGB, linear),
``roughness.exr`` and ``metallic.exr`` (one channel each). Textures follow the UV convention of
`freqbrdf.mesh`: row 0 is the top of the texture (v = 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage
from skimage.transform import resize as resize_image

from freqbrdf.errors import InputError
from freqbrdf.images import linear_to_srgb, read_image, srgb_to_linear, write_exr

MAP_FILES = {
    "base_color": "base_color.exr",
    "roughness": "roughness.exr",
    "metallic": "metallic.exr",
}


@dataclass(frozen=True, eq=False)  # holds arrays: compare fields explicitly
class MaterialMaps:
    base_color: np.ndarray  # (T, T, 3) float32, linear, in [0, 1]
    roughness: np.ndarray  # (T, T) float32, in [0, 1]; alpha = roughness^2
    metallic: np.ndarray  # (T, T) float32, in [0, 1]

    def __post_init__(self):
        resolution = self.base_color.shape[0]
        expected = {
            "base_color": (resolution, resolution, 3),
            "roughness": (resolution, resolution),
            "metallic": (resolution, resolution),
        }
        for name, shape in expected.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"{name} has shape {getattr(self, name).shape}, expected {shape}")

    @property
    def resolution(self) -> int:
        return self.base_color.shape[0]


def load_material_maps(folder: str | Path) -> MaterialMaps:
    """Read a texture set written by `save_material_maps` (or by hand with the same file names)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, "material folder does not exist")
    maps = {}
    for name, filename in MAP_FILES.items():
        path = folder / filename
        pixels = read_image(path, validate=True)  # (H, W, 3); a one-channel file is repeated
        if name != "base_color":
            if np.ptp(pixels, axis=2).max() > 0:
                raise InputError(path, f"{name} must be a single channel (or grey)")
            pixels = pixels[..., 0]
        if pixels.shape[0] != pixels.shape[1]:
            height, width = pixels.shape[:2]
            raise InputError(path, f"texture must be square, got {width}x{height}")
        above_one = int((pixels > 1.0).sum())
        if above_one:
            raise InputError(path, f"{above_one} values above 1 ({name} lies in [0, 1])")
        maps[name] = np.ascontiguousarray(pixels, dtype=np.float32)
    sizes = {name: pixels.shape[0] for name, pixels in maps.items()}
    if len(set(sizes.values())) > 1:
        raise InputError(folder, f"maps differ in resolution: {sizes}")
    return MaterialMaps(**maps)


def save_material_maps(folder: str | Path, maps: MaterialMaps, half: bool = False) -> None:
    """Write the three maps as EXR (float32, or float16 with ``half``); each file atomically."""
    folder = Path(folder)
    precision = np.float16 if half else np.float32
    for name, filename in MAP_FILES.items():
        write_exr(folder / filename, getattr(maps, name).astype(precision))


def resize(maps: MaterialMaps, resolution: int) -> MaterialMaps:
    """Resample to ``resolution`` x ``resolution``: bilinear, area-prefiltered when shrinking.

    Base colour is resampled in linear space, where averaging is physically meaningful.
    """
    if resolution == maps.resolution:
        return maps

    def resample(texture):
        resized = resize_image(
            texture,
            (resolution, resolution) + texture.shape[2:],
            order=1,
            mode="edge",
            anti_aliasing=resolution < maps.resolution,
            preserve_range=True,
        )
        return np.clip(resized, 0.0, 1.0).astype(np.float32)

    return MaterialMaps(
        resample(maps.base_color), resample(maps.roughness), resample(maps.metallic)
    )


# --- ground-truth generators ----------------------------------------------------------------------

# sRGB display colours of the bands: red, gold, green, blue, light grey, near black (the last
# checks that dark texels are still treated as observed).
BAND_COLOURS_SRGB = np.array(
    [
        [0.80, 0.15, 0.12],
        [0.95, 0.70, 0.25],
        [0.20, 0.60, 0.25],
        [0.15, 0.30, 0.80],
        [0.85, 0.85, 0.85],
        [0.12, 0.12, 0.12],
    ]
)
BAND_METALLIC = (0.0, 0.5, 1.0)  # top, middle, bottom third
BAND_ROUGHNESS = (0.05, 1.0)  # ramp across each colour band, left to right


def bands_material(resolution: int = 512) -> MaterialMaps:
    """Factorial test pattern in the spirit of the paper's plane scene.

    Six vertical colour bands; inside each band roughness ramps linearly from 0.05 (left edge)
    to 1 (right edge); three horizontal strips with metallic 0, 0.5 and 1 from top to bottom.
    Every colour thus appears with every roughness and metallic level.
    """
    n_bands = len(BAND_COLOURS_SRGB)
    column = (np.arange(resolution) + 0.5) / resolution * n_bands  # band coordinate per column
    band = np.minimum(column.astype(int), n_bands - 1)  # (T,)
    within_band = column - band  # position inside its band, in [0, 1)
    row_strip = np.minimum((np.arange(resolution) * len(BAND_METALLIC)) // resolution, 2)
    low, high = BAND_ROUGHNESS
    roughness_row = low + (high - low) * within_band  # (T,)
    colours = srgb_to_linear(BAND_COLOURS_SRGB)  # (6, 3)
    base_color = np.broadcast_to(colours[band], (resolution, resolution, 3))
    roughness = np.broadcast_to(roughness_row, (resolution, resolution))
    metallic = np.broadcast_to(
        np.asarray(BAND_METALLIC)[row_strip][:, None], (resolution, resolution)
    )
    return MaterialMaps(
        np.ascontiguousarray(base_color, dtype=np.float32),
        np.ascontiguousarray(roughness, dtype=np.float32),
        np.ascontiguousarray(metallic, dtype=np.float32),
    )


def photo_material(photo_srgb: np.ndarray, resolution: int = 512) -> MaterialMaps:
    """Ground-truth maps from an 8-bit sRGB photograph ``(H, W, 3)`` uint8, deterministically.

    - The central square crop is resized to ``resolution`` (in linear space).
    - base colour: the linear image mapped into [0.03, 0.93], the range of real albedos.
    - roughness: 0.1 + 0.85 * e, where e is the local detail of the sRGB luminance (Sobel
      gradient magnitude, Gaussian-blurred over resolution / 128 texels, divided by its 95th
      percentile, clipped to 1): busy regions (hair, fabric) are rough, smooth ones glossy.
    - metallic: bright, unsaturated regions are metal (HSV value ramps 0.5 -> 0.75 times
      (1 - saturation ramp 0.1 -> 0.25), blurred over one texel): mostly 0 or 1, soft borders.
    """
    height, width = photo_srgb.shape[:2]
    side = min(height, width)
    top, left = (height - side) // 2, (width - side) // 2
    crop = photo_srgb[top : top + side, left : left + side, :3].astype(np.float64) / 255.0
    linear = resize_image(
        srgb_to_linear(crop).astype(np.float64),
        (resolution, resolution, 3),
        order=1,
        anti_aliasing=resolution < side,
        preserve_range=True,
    )
    linear = np.clip(linear, 0.0, 1.0)
    base_color = 0.03 + 0.9 * linear
    display = linear_to_srgb(linear).astype(np.float64)  # (T, T, 3) sRGB of the resized image

    luminance = display @ np.array([0.2126, 0.7152, 0.0722])
    gradient = np.hypot(ndimage.sobel(luminance, axis=0), ndimage.sobel(luminance, axis=1))
    detail = ndimage.gaussian_filter(gradient, sigma=resolution / 128)
    detail = np.clip(detail / np.percentile(detail, 95), 0.0, 1.0)
    roughness = 0.1 + 0.85 * detail

    value = display.max(axis=2)
    saturation = np.where(value > 0, np.ptp(display, axis=2) / np.maximum(value, 1e-6), 0.0)
    metallic = _smoothstep(0.5, 0.75, value) * (1.0 - _smoothstep(0.1, 0.25, saturation))
    metallic = np.clip(ndimage.gaussian_filter(metallic, sigma=1.0), 0.0, 1.0)
    return MaterialMaps(
        base_color.astype(np.float32), roughness.astype(np.float32), metallic.astype(np.float32)
    )


def _smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)
