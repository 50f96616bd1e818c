"""Image input and output: linear HDR radiance in, EXR / Radiance HDR / PNG out.

Everything inside freqbrdf is linear radiance in float32 arrays ``(H, W, 3)`` with row 0 at the
top of the picture. Readers accept OpenEXR (RGB, RGBA or a single channel such as Y; half or
float), Radiance ``.hdr`` (RGBE, flat or run-length encoded) and, with a warning, 8-bit PNG/JPEG
(decoded from sRGB), 16-bit PNG at full depth. Every writer is atomic: a failed write leaves no
file behind. The codecs no dependency provides (16-bit PNG, Radiance RGBE) are in `freqbrdf._codecs`.

Photographs are the posed HDR images of docs/method.md#problem; environment maps are read by
`freqbrdf.sphere.envmap` through `read_image`.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import warnings
from collections.abc import Iterator
from pathlib import Path

import numba
import numpy as np
import OpenEXR
from PIL import Image, UnidentifiedImageError

from freqbrdf import __version__
from freqbrdf._codecs import _png_header, _read_png16, _read_rgbe
from freqbrdf._codecs import write_hdr as write_hdr  # the Radiance writer, here with the other writers
from freqbrdf.errors import InputError


class CaptureDataWarning(UserWarning):
    """Suspicious but usable input data (8-bit frames, tiny negative HDR values): reported once, aggregated."""


class SrgbImageWarning(CaptureDataWarning):
    """An sRGB-encoded image read as radiance; ``bits`` is its depth (8 or 16)."""

    def __init__(self, message: str, bits: int):
        super().__init__(message)
        self.bits = bits

    def __reduce__(self):  # pickled whole (test workers, Ray), not from its message alone
        return type(self), (str(self), self.bits)


# Negative pixels no deeper than this share of an image's bright level (its 99.9th percentile) are
# noise of an HDR merge or a lossy encoding, clamped to 0; deeper ones mean a broken file.
NEGATIVE_NOISE = 0.01
from freqbrdf.fileio import atomic_path

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
"""Rec. 709 luminance weights of linear RGB."""
HDR_SUFFIXES = (".exr", ".hdr")
LDR_SUFFIXES = (".png", ".jpg", ".jpeg")
IMAGE_SUFFIXES = HDR_SUFFIXES + LDR_SUFFIXES
#: The ``software`` attribute of every EXR written (no date or host: the same image, the same bytes).
EXR_SOFTWARE = f"freqbrdf {__version__}"
#: CIE xy of the red, green and blue primaries and the white point, in OpenEXR's ``chromaticities``
#: order: ITU-R BT.709 (the sRGB primaries) with the D65 white, i.e. linear sRGB.
REC709_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)


# zlib's level for the PNGs `write_png` writes (previews): the fastest within 20 % of the smallest
# (`benchmarks/timing/bench_exr.py`).
PNG_COMPRESS_LEVEL = 3

# A channel within this share of its largest value in an image sits on its ceiling; more than
# CLIPPED_MIN_SHARE of the lit pixels there make the ceiling a clipping plateau (`clipped_channels`).
CLIPPED_TOLERANCE = 1e-4
CLIPPED_MIN_SHARE = 1e-3
CLIPPED_MIN_PIXELS = 4


# --- sRGB transfer function (IEC 61966-2-1), the only definition in the package -------------------


def srgb_to_linear(encoded: np.ndarray) -> np.ndarray:
    """Decode sRGB values to linear values (IEC 61966-2-1).

    Parameters
    ----------
    encoded : array_like
        sRGB values, clipped to [0, 1] first.

    Returns
    -------
    float32 array
        Linear values in [0, 1], same shape.
    """
    encoded = np.clip(np.asarray(encoded, dtype=np.float32), 0.0, 1.0)
    return np.where(
        encoded <= 0.04045, encoded / 12.92, ((encoded + 0.055) / 1.055) ** 2.4
    ).astype(np.float32)


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """Encode linear values to sRGB display values (IEC 61966-2-1).

    Parameters
    ----------
    linear : array_like
        Linear values, clipped to [0, 1] first.

    Returns
    -------
    float32 array
        sRGB values in [0, 1], same shape.
    """
    linear = np.clip(np.asarray(linear, dtype=np.float32), 0.0, 1.0)
    return np.where(
        linear <= 0.0031308, linear * 12.92, 1.055 * linear ** (1.0 / 2.4) - 0.055
    ).astype(np.float32)


# --- reading --------------------------------------------------------------------------------------


def read_image(path: str | Path, validate: bool = False) -> np.ndarray:
    """Read an image as linear radiance.

    Single-channel images are repeated into RGB; an alpha channel is ignored (see `read_mask`).
    PNG/JPEG are decoded from sRGB with a warning: 8-bit images clip highlights, so HDR input is
    preferred.

    Parameters
    ----------
    path : str or Path
        An ``.exr``, ``.hdr``, ``.png``, ``.jpg`` or ``.jpeg`` file.
    validate : bool, optional
        Refuse non-finite pixels and negative ones deeper than noise; clamp the noise to 0
        (`clamp_negative_noise`).

    Returns
    -------
    (H, W, 3) float32
        Linear radiance, row 0 at the top.

    Raises
    ------
    InputError
        If the type is unsupported, the file is missing or unreadable, or (with ``validate``) it
        has non-finite or deeply negative pixels (how many, and where the first one is).
    """
    path = Path(path)
    pixels, srgb_bits = _read_pixels(path, radiance=True)  # (H, W, C)
    channels = pixels.shape[2]
    rgb = pixels[..., :3] if channels >= 3 else np.repeat(pixels[..., :1], 3, axis=2)
    if srgb_bits:
        warnings.warn(SrgbImageWarning(
            f"{path.name}: {srgb_bits}-bit sRGB image linearised as radiance; clipped highlights"
            f"{' and quantisation' if srgb_bits == 8 else ''} bias the result, HDR input (.exr, .hdr) is preferred",
            srgb_bits), stacklevel=2)
        rgb = srgb_to_linear(rgb)
    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    if validate:
        _check_finite_non_negative(path, rgb)
    return rgb


def clamp_negative_noise(path: str | Path, rgb: np.ndarray) -> np.ndarray:
    """Clamp an HDR image's negative noise to 0; refuse negatives deep enough to mean a broken file.

    HDR merges of photographs and lossy encodings leave small negative values near black; those no
    deeper than `NEGATIVE_NOISE` times the image's bright level (its 99.9th percentile) are set to
    0 with a `CaptureDataWarning`.

    Parameters
    ----------
    path : str or Path
        The file the image came from (for the messages).
    rgb : (H, W, 3) float32
        The image, finite.

    Returns
    -------
    (H, W, 3) float32
        The image with its negative noise at 0 (the same array where it had none).

    Raises
    ------
    InputError
        If a pixel is more negative than that (how many, how deep, where the first one is).
    """
    if not rgb.size or not rgb.min() < 0:
        return rgb
    negative = rgb < 0
    bright = float(np.percentile(rgb, 99.9))
    deepest = float(rgb.min())
    if bright <= 0.0 or -deepest > NEGATIVE_NOISE * bright:
        pixel = negative.any(axis=2)
        row, col = np.argwhere(pixel)[0]
        raise InputError(path, f"{int(pixel.sum())} negative pixel(s) down to {deepest:.3g}, first at row {row}, "
                               f"column {col}: deeper than the noise of an HDR merge "
                               f"({NEGATIVE_NOISE:.0%} of the image's bright level {bright:.3g})")
    warnings.warn(f"{Path(path).name}: {int(negative.any(axis=2).sum())} slightly negative pixel(s) (down to "
                  f"{deepest:.2g}) clamped to 0", CaptureDataWarning, stacklevel=2)
    return np.maximum(rgb, 0.0)


def clipped_channels(image: np.ndarray) -> np.ndarray:
    """Find the channels a sensor clipped: where a channel sits on its own ceiling.

    A clipped photograph (8-bit data, a blown highlight) holds a plateau at a channel's largest
    value; such a value says only that the radiance was at least that: a censored measurement
    (docs/method.md#censored-samples). A channel's ceiling counts where `CLIPPED_MIN_SHARE` of the
    lit pixels, and at least `CLIPPED_MIN_PIXELS`, reach it (an HDR image's single brightest pixel
    is no plateau). Each channel has its own ceiling: white balance applied after the sensor
    clipped scales them apart.

    Parameters
    ----------
    image : (H, W, 3) float array
        Linear radiance.

    Returns
    -------
    (H, W, 3) bool
        True where a channel is on its clipping plateau; all False where the image has none.
    """
    image = np.ascontiguousarray(image, dtype=np.float32)
    clipped = np.zeros(image.shape, bool)
    if image.size == 0:
        return clipped
    thresholds = np.empty(image.shape[2], np.float32)
    at_ceiling = np.zeros(image.shape[2], np.int64)
    n_lit = _ceiling_counts(image, 1.0 - CLIPPED_TOLERANCE, thresholds, at_ceiling)
    for channel in range(image.shape[2]):
        if thresholds[channel] > 0.0 and at_ceiling[channel] >= max(CLIPPED_MIN_PIXELS, CLIPPED_MIN_SHARE * n_lit):
            clipped[..., channel] = image[..., channel] >= thresholds[channel]
    return clipped


@numba.njit(cache=True)
def _ceiling_counts(image, keep, thresholds, at_ceiling):
    """Find each channel's ceiling threshold (its largest value times keep, in float32) and count the pixels at or above it (numba).

    Writes thresholds (C,) float32 (not above 0 where the channel's largest value is not above 0)
    and at_ceiling (C,) int64; returns the pixels lit in some channel (largest value above 0).
    """
    height, width, channels = image.shape
    largest = np.full(channels, -np.inf)
    n_lit = 0
    for row in range(height):
        for col in range(width):
            brightest = -np.inf
            for channel in range(channels):
                value = image[row, col, channel]
                if value > largest[channel]:
                    largest[channel] = value
                if value > brightest:
                    brightest = value
            if brightest > 0.0:
                n_lit += 1
    for channel in range(channels):
        thresholds[channel] = np.float32(largest[channel] * keep) if largest[channel] > 0.0 else np.float32(0.0)
        at_ceiling[channel] = 0
    for row in range(height):
        for col in range(width):
            for channel in range(channels):
                if thresholds[channel] > 0.0 and image[row, col, channel] >= thresholds[channel]:
                    at_ceiling[channel] += 1
    return n_lit


def read_mask_coverage(path: str | Path, from_alpha: bool = False) -> np.ndarray:
    """Read an object mask as the share of each pixel the object covers.

    Parameters
    ----------
    path : str or Path
        An image file of a type `read_image` reads; no sRGB decoding (masks are not radiance).
    from_alpha : bool, optional
        Take the alpha channel (NeRF-synthetic's RGBA frames); else the alpha channel where it is
        not constant, otherwise the mean colour.

    Returns
    -------
    (H, W) float32
        Coverage in [0, 1] (of full scale for PNG/JPEG, of 1.0 for HDR files); an anti-aliased
        mask's edge pixels lie between.

    Raises
    ------
    InputError
        If the type is unsupported, the file is missing or unreadable, or ``from_alpha`` and it has
        no alpha channel.
    """
    pixels, _ = _read_pixels(Path(path))  # (H, W, C); no sRGB decoding: masks are not radiance
    channels = pixels.shape[2]
    has_alpha = channels in (2, 4)
    if from_alpha and not has_alpha:
        raise InputError(path, "has no alpha channel to take the object mask from")
    if has_alpha and (from_alpha or np.ptp(pixels[..., -1]) > 0):
        coverage = pixels[..., -1]
    else:
        coverage = (pixels[..., :-1] if has_alpha else pixels).mean(axis=2)
    return np.clip(coverage, 0.0, 1.0).astype(np.float32)


def read_mask(path: str | Path) -> np.ndarray:
    """Read an object mask.

    Parameters
    ----------
    path : str or Path
        An image file of a type `read_image` reads; no sRGB decoding (masks are not radiance).

    Returns
    -------
    (H, W) bool
        alpha > 0.5 when the image has a non-constant alpha channel, otherwise mean colour > 0.5
        (of full scale for PNG/JPEG, of 1.0 for HDR files).

    Raises
    ------
    InputError
        If the type is unsupported or the file is missing or unreadable.
    """
    return read_mask_coverage(path) > 0.5


def read_alpha_mask(path: str | Path) -> np.ndarray:
    """Read an image's alpha channel as an object mask (NeRF-synthetic's RGBA frames).

    Parameters
    ----------
    path : str or Path
        An image file with an alpha channel (see `image_has_alpha`).

    Returns
    -------
    (H, W) bool
        alpha > 0.5 (of full scale for PNG, of 1.0 for EXR).

    Raises
    ------
    InputError
        If the file is unreadable or has no alpha channel.
    """
    return read_mask_coverage(path, from_alpha=True) > 0.5


def image_has_alpha(path: str | Path) -> bool:
    """Whether an image file has an alpha channel, from its header alone.

    Parameters
    ----------
    path : str or Path
        An image file of a type `read_image` reads.

    Returns
    -------
    bool
        True for PNG with alpha or transparency, EXR with an ``A`` channel beside R, G, B.

    Raises
    ------
    InputError
        If the header cannot be read.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".exr":
        try:
            with _native_output_silenced(), OpenEXR.File(str(path), header_only=True) as exr:
                names = {channel.name for channel in exr.header()["channels"]}
        except Exception as err:  # OpenEXR raises RuntimeError or ValueError on damaged files
            raise InputError(path, f"not a readable OpenEXR file ({err})") from None
        return "A" in names and {"R", "G", "B"} <= names
    if suffix in (".png",):
        try:
            with Image.open(path) as image:
                return "A" in image.mode or "transparency" in image.info
        except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as err:
            raise InputError(path, f"not a readable PNG image ({err})") from None
    return False


def _read_pixels(path: Path, radiance: bool = False) -> tuple[np.ndarray, int]:
    """Read all channels of the file ``(H, W, C)`` float32, and the bits of their sRGB encoding (0: linear).

    With ``radiance``, an EXR whose single channel is not a colour (depth ``Z``, alpha ``A``, an
    AOV saved by mistake) is refused.
    """
    suffix = path.suffix.lower()
    if suffix not in IMAGE_SUFFIXES:
        raise InputError(
            path, f"unsupported image type {path.suffix!r} (supported: {', '.join(IMAGE_SUFFIXES)})"
        )
    if not path.exists():
        raise InputError(path, "file does not exist")
    if not path.is_file():
        raise InputError(path, "is not a file")
    if suffix == ".exr":
        return _read_exr(path, radiance), 0
    if suffix == ".hdr":
        return _read_rgbe(path), 0
    if suffix == ".png" and _png_header(path)[0] == 16:
        return _read_png16(path), 16
    return _read_ldr(path), 8


@contextlib.contextmanager
def _native_output_silenced() -> Iterator[None]:
    """Send what C libraries print to the process's stdout and stderr to /dev/null for the block.

    OpenEXR prints its own lines (one of them on stdout, which breaks ``--json``) about a damaged
    file before it raises; the error it raises says the same in one line.
    """
    with _NATIVE_OUTPUT_LOCK:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = [os.dup(1), os.dup(2)]
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(null, 1)
            os.dup2(null, 2)
            yield
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for descriptor in (*saved, null):
                os.close(descriptor)


_NATIVE_OUTPUT_LOCK = threading.Lock()


# A single EXR channel read as a grey photograph must be named as a colour: luminance, grey or one primary.
GREY_CHANNELS = ("Y", "L", "R", "G", "B", "GRAY", "GREY", "LUMINANCE")


def _read_exr(path: Path, radiance: bool = False) -> np.ndarray:
    try:
        with _native_output_silenced(), OpenEXR.File(str(path), separate_channels=True) as exr:
            header = dict(exr.header())  # a copy: the file's header is emptied when it closes
            planes = {name: channel.pixels for name, channel in exr.channels().items()}
    except Exception as err:  # OpenEXR raises RuntimeError or ValueError on damaged files
        raise InputError(path, f"not a readable OpenEXR file ({err})") from None
    if "dataWindow" in header and "displayWindow" in header:
        planes = {name: _in_display_window(plane, header["dataWindow"], header["displayWindow"])
                  for name, plane in planes.items()}
    layer = _colour_layer(path, planes)
    if layer is not None:
        names = [layer + name for name in "RGB"] + ([layer + "A"] if layer + "A" in planes else [])
    elif len(planes) == 1 and (not radiance or next(iter(planes)).split(".")[-1].upper() in GREY_CHANNELS):
        names = list(planes)  # a single channel (Y, or any name) is a grey image
    elif radiance:
        raise InputError(
            path, f"has no colour channels (needs R, G, B or one grey channel such as Y); found "
                  f"{', '.join(sorted(planes))}")
    else:
        raise InputError(
            path, f"needs channels R, G, B or a single channel; found {', '.join(sorted(planes))}"
        )
    return np.stack([planes[name].astype(np.float32) for name in names], axis=2)


def _in_display_window(plane: np.ndarray, data_window, display_window) -> np.ndarray:
    """Return an EXR channel's pixels over its display window, the picture's frame.

    A renderer may store only a part of the frame (the data window: Arnold's and Blender's crops to
    the non-empty pixels) or more (overscan). Pixels outside the data window are 0; those outside
    the display window are dropped. Windows are ((x_min, y_min), (x_max, y_max)), inclusive.
    """
    (data_x, data_y), (data_x_max, data_y_max) = (np.asarray(corner, np.int64) for corner in data_window)
    (frame_x, frame_y), (frame_x_max, frame_y_max) = (np.asarray(corner, np.int64) for corner in display_window)
    if (data_x, data_y, data_x_max, data_y_max) == (frame_x, frame_y, frame_x_max, frame_y_max):
        return plane
    frame = np.zeros((frame_y_max - frame_y + 1, frame_x_max - frame_x + 1), plane.dtype)
    top, left = max(data_y, frame_y), max(data_x, frame_x)
    bottom, right = min(data_y_max, frame_y_max), min(data_x_max, frame_x_max)
    if bottom >= top and right >= left:
        frame[top - frame_y: bottom - frame_y + 1, left - frame_x: right - frame_x + 1] = \
            plane[top - data_y: bottom - data_y + 1, left - data_x: right - data_x + 1]
    return frame


# Of several colour layers in one EXR, the one a renderer's beauty pass is named by (Blender: ViewLayer.Combined).
BEAUTY_LAYERS = ("COMBINED", "BEAUTY", "RGBA", "RGB", "COLOR", "COLOUR")


def _colour_layer(path: Path, planes: dict) -> str | None:
    """Return the prefix of the EXR's R, G, B channels; None where no layer holds all three.

    The prefix is "" for bare channels, "ViewLayer.Combined." in a multi-layer file. Bare channels come first; else the only layer with all three, or among several the beauty pass
    (`BEAUTY_LAYERS`); several others are refused, named.
    """
    if all(name in planes for name in "RGB"):
        return ""
    prefixes = sorted({name[: -1] for name in planes if name.endswith((".R", ".G", ".B"))})
    layers = [prefix for prefix in prefixes if all(prefix + channel in planes for channel in "RGB")]
    if len(layers) <= 1:
        return layers[0] if layers else None
    beauty = [prefix for prefix in layers if prefix.rstrip(".").split(".")[-1].upper() in BEAUTY_LAYERS]
    if len(beauty) == 1:
        return beauty[0]
    raise InputError(path, f"holds {len(layers)} colour layers ({', '.join(prefix.rstrip('.') for prefix in layers)}) "
                           "and none is the beauty pass (Combined): save the photograph's radiance as R, G, B")


def _read_ldr(path: Path) -> np.ndarray:
    try:
        with Image.open(path) as image:
            image.load()
            if image.mode.startswith("I"):  # 16-bit greyscale PNG
                return (np.asarray(image, dtype=np.float32) / 65535.0)[..., None]
            if image.mode not in ("L", "LA", "RGB", "RGBA"):
                has_alpha = "A" in image.mode or "transparency" in image.info
                image = image.convert("RGBA" if has_alpha else "RGB")
            pixels = np.asarray(image, dtype=np.float32) / 255.0
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as err:
        raise InputError(path, f"not a readable {path.suffix[1:].upper()} image ({err})") from None
    return pixels if pixels.ndim == 3 else pixels[..., None]


def _check_finite_non_negative(path: Path, rgb: np.ndarray) -> None:
    if np.isfinite(rgb.sum(dtype=np.float64)):  # one pass: a NaN or an infinity makes the sum non-finite
        rgb[...] = clamp_negative_noise(path, rgb)
        return
    non_finite = ~np.isfinite(rgb).all(axis=2)
    count = int(non_finite.sum())
    if count:
        row, col = np.argwhere(non_finite)[0]
        raise InputError(path, f"{count} non-finite pixel(s), first at row {row}, column {col}")
    rgb[...] = clamp_negative_noise(path, rgb)


# --- writing EXR and PNG --------------------------------------------------------------------------


def write_exr(path: str | Path, image: np.ndarray, comments: str | None = None,
              chromaticities: tuple[float, ...] | None = None) -> None:
    """Write an image as ZIP-compressed OpenEXR, atomically.

    Besides the required attributes the header holds ``software`` (`EXR_SOFTWARE`) and, when
    given, ``comments`` and ``chromaticities``; nothing that changes between runs.

    Parameters
    ----------
    path : str or Path
        The ``.exr`` file.
    image : (H, W), (H, W, 1) or (H, W, 3) array_like
        Channel Y, or R, G, B. A float16 array is stored as half, anything else as float32.
    comments : str, optional
        What the image is, in words (the standard ``comments`` attribute).
    chromaticities : tuple of 8 floats, optional
        CIE xy of the red, green, blue primaries and the white point (e.g.
        `REC709_CHROMATICITIES` for linear sRGB); for colour images only.

    Raises
    ------
    ValueError
        If ``image`` has another shape, or ``chromaticities`` is not 8 numbers.
    """
    pixels = np.asarray(image)
    if pixels.ndim == 3 and pixels.shape[2] == 1:
        pixels = pixels[..., 0]
    pixel_type = np.float16 if pixels.dtype == np.float16 else np.float32
    if pixels.ndim == 2:
        planes = {"Y": np.ascontiguousarray(pixels, dtype=pixel_type)}
    elif pixels.ndim == 3 and pixels.shape[2] == 3:
        planes = {
            name: np.ascontiguousarray(pixels[..., index], dtype=pixel_type)
            for index, name in enumerate("RGB")
        }
    else:
        raise ValueError(f"write_exr needs (H, W), (H, W, 1) or (H, W, 3), got {pixels.shape}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, "software": EXR_SOFTWARE}
    if comments is not None:
        header["comments"] = str(comments)
    if chromaticities is not None:
        values = tuple(float(value) for value in chromaticities)
        if len(values) != 8:
            raise ValueError(f"chromaticities needs 8 numbers (red, green, blue, white x y), got {len(values)}")
        header["chromaticities"] = values  # the bindings take the 8 floats as a tuple
    with atomic_path(path) as tmp:
        with OpenEXR.File(header, planes) as exr:
            exr.write(str(tmp))


def write_png(path: str | Path, image: np.ndarray) -> None:
    """Write display values as an 8-bit PNG, atomically.

    Parameters
    ----------
    path : str or Path
        The ``.png`` file.
    image : (H, W), (H, W, 3) or (H, W, 4) array_like
        Display values in [0, 1], already sRGB-encoded where they are colours (e.g. by
        `linear_to_srgb`); clipped to [0, 1], NaN is black.

    Raises
    ------
    ValueError
        If ``image`` has another shape.
    """
    pixels = np.asarray(image, dtype=np.float32)
    if not (pixels.ndim == 2 or (pixels.ndim == 3 and pixels.shape[2] in (3, 4))):
        raise ValueError(f"write_png needs (H, W), (H, W, 3) or (H, W, 4), got {pixels.shape}")
    quantised = np.round(np.nan_to_num(np.clip(pixels, 0.0, 1.0)) * 255.0).astype(np.uint8)
    with atomic_path(path) as tmp:
        Image.fromarray(quantised).save(tmp, format="PNG", compress_level=PNG_COMPRESS_LEVEL)
