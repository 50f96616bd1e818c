"""Principled-BRDF texture sets (base colour, roughness, metallic) and ground-truth generators.

A set is stored as three EXR files in one folder: ``base_color.exr`` (RGB, linear),
``roughness.exr`` and ``metallic.exr`` (one channel each). Textures follow the UV convention of
`freqbrdf.capture.mesh`: row 0 is the top of the texture (v = 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from skimage.transform import resize as resize_image

from freqbrdf.errors import InputError
from freqbrdf.images import REC709_CHROMATICITIES, read_image, write_exr

#: The variance of a map's value uniform on [0, 1]: what is known of a material nothing of which is seen.
UNIFORM_VARIANCE = 1.0 / 12.0
#: The file of each map in a texture-set folder.
MAP_FILES = {
    "base_color": "base_color.exr",
    "roughness": "roughness.exr",
    "metallic": "metallic.exr",
}
#: What each map's EXR says it is (its ``comments`` attribute; see docs/formats.md).
MAP_DESCRIPTIONS = {
    "base_color": "freqbrdf base colour: the Principled BSDF's base colour per texel, linear RGB with the "
                  "Rec.709/sRGB primaries and D65 white (no transfer curve), in [0, 1]. Texture space: "
                  "row 0 is v = 1.",
    "roughness": "freqbrdf roughness: the Principled BSDF's roughness r per texel, in [0, 1]; the GGX "
                 "alpha is r^2 (this map is r, not alpha). Texture space: row 0 is v = 1.",
    "metallic": "freqbrdf metallic: the Principled BSDF's metallic per texel, in [0, 1] (0 dielectric, "
                "1 metal). Texture space: row 0 is v = 1.",
}


@dataclass(frozen=True, eq=False)  # holds arrays: compare fields explicitly
class MaterialMaps:
    """A Principled texture set: base colour, roughness and metallic maps of one resolution.

    Attributes
    ----------
    base_color : (T, T, 3) float32
        Linear RGB in [0, 1].
    roughness : (T, T) float32
        In [0, 1]; alpha = roughness^2.
    metallic : (T, T) float32
        In [0, 1].

    Raises
    ------
    ValueError
        If the maps' shapes disagree.
    """

    base_color: np.ndarray
    roughness: np.ndarray
    metallic: np.ndarray

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
        """T, the maps' side in texels."""
        return self.base_color.shape[0]


def load_material_maps(folder: str | Path) -> MaterialMaps:
    """Read a texture set written by `save_material_maps` (or by hand with the same file names).

    Parameters
    ----------
    folder : str or Path
        The folder holding `MAP_FILES`.

    Returns
    -------
    MaterialMaps
        The maps, float32.

    Raises
    ------
    InputError
        If the folder or a file is missing, a map is not square or not a single channel, values
        exceed 1, or the maps differ in resolution.
    """
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
    """Write the three maps as EXR files (`MAP_FILES`), each atomically.

    Each file's ``comments`` say what it holds (`MAP_DESCRIPTIONS`); base colour carries the
    linear Rec.709 ``chromaticities``.

    Parameters
    ----------
    folder : str or Path
        The folder to write into.
    maps : MaterialMaps
        The maps.
    half : bool, optional
        Store float16 instead of float32.
    """
    folder = Path(folder)
    precision = np.float16 if half else np.float32
    for name, filename in MAP_FILES.items():
        write_exr(folder / filename, getattr(maps, name).astype(precision), comments=MAP_DESCRIPTIONS[name],
                  chromaticities=REC709_CHROMATICITIES if name == "base_color" else None)


def resize(maps: MaterialMaps, resolution: int) -> MaterialMaps:
    """Resample a texture set: bilinear, area-prefiltered when shrinking.

    Base colour is resampled in linear space, where averaging is physically meaningful.

    Parameters
    ----------
    maps : MaterialMaps
        The maps (T x T).
    resolution : int
        The new side.

    Returns
    -------
    MaterialMaps
        The maps at ``resolution`` x ``resolution``, clipped to [0, 1] (``maps`` itself when the
        resolution is already that).
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
