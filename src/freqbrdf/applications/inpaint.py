"""Inpainting uncertain regions of a fit's material maps (docs/method.md#inpainting, `freqbrdf inpaint`).

**Mask** (`inpaint_mask`). Texels of the mesh's atlas that the fit cannot vouch for: by default
those flagged UNOBSERVED (no sample) or AMBIGUOUS (entropy above the fit's
``uncertainty.ambiguous_entropy``); with ``threshold`` H, UNOBSERVED or entropy >= H. Two flags
are deliberately left out: FEW_SAMPLES (fewer samples than a quarter of the SH coefficients)
already raises the entropy, which counts the samples, and BELOW_BOUND marks shiny texels whose
specular lobe is sharper than the views resolve: their estimate is "very smooth", which a fill
from rougher neighbours would only make worse.

**Charts** (`inpaint_maps`). The atlas is split into connected components (8-connected texels of
the mesh); each is filled from its own confident texels only. Per chart, every texel of its
bounding box that is not a confident texel of the chart (other charts, empty atlas space, the
holes) first takes the value of the nearest confident texel of the chart, so nothing from
elsewhere can leak in; the backend then fills the chart's holes from that picture. A chart
without a single confident texel keeps its values (counted as ``unfilled_texels``). After
filling, the seam padding around the atlas is regrown from the new values
(``texels.fill_texture``).

**Backends.**

- ``biharmonic`` (default, `biharmonic_fill`): scikit-image's ``restoration.inpaint_biharmonic``,
  a smooth continuation of the surrounding values into each hole; no learned prior.
- ``diffusion`` (`load_diffusion_fill`): a diffusers inpainting pipeline in a local folder
  (``--model PATH``, as written by ``save_pretrained``), with the optional extra
  ``pip install 'freqbrdf[diffusion]'``; nothing is downloaded. Each map goes through it as an
  8-bit picture (base colour sRGB-encoded, roughness and metallic as grey), per chart, resized to
  ``size`` pixels square; only the hole texels are taken back.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from scipy import ndimage

from freqbrdf.errors import InputError
from freqbrdf.images import linear_to_srgb, srgb_to_linear
from freqbrdf.model.materials import MaterialMaps
from freqbrdf.texels import fill_texture
from freqbrdf.uncertainty import FLAG_AMBIGUOUS, FLAG_UNOBSERVED

MAP_NAMES = ("base_color", "roughness", "metallic")
MAP_CHANNELS = {"base_color": slice(0, 3), "roughness": slice(3, 4), "metallic": slice(4, 5)}
MASK_PNG = "mask.png"
# Holes are filled on (h, w, C) pictures of one chart: known texels as given, holes (h, w) True.
# One map at a time: (h, w, 3) base colour or (h, w, 1) roughness / metallic.
Fill = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class InpaintSettings:
    """What to inpaint and how (`freqbrdf inpaint`'s options).

    Attributes
    ----------
    threshold : float or None
        Entropy at or above which observed texels are masked; None: the UNOBSERVED and
        AMBIGUOUS flags (module docstring).
    maps : tuple of str
        Which material maps are filled, among `MAP_NAMES`.
    backend : {"biharmonic", "diffusion"}
        The fill (module docstring).
    model : str or None
        diffusion: folder of a diffusers inpainting pipeline.
    prompt : str
        diffusion: the text prompt.
    steps : int
        diffusion: denoising steps.
    size : int
        diffusion: pictures are resized to ``size`` x ``size`` pixels.
    seed : int
        diffusion: noise seed.
    """

    threshold: float | None = None
    maps: tuple[str, ...] = MAP_NAMES
    backend: Literal["biharmonic", "diffusion"] = "biharmonic"
    model: str | None = None
    prompt: str = "seamless physically based material texture, uniform lighting"
    steps: int = 25
    size: int = 512
    seed: int = 0


@dataclass(eq=False)
class Inpainted:
    """The result of `inpaint_maps`.

    Attributes
    ----------
    maps : MaterialMaps
        The (T, T, ...) maps, filled, seam padding regrown.
    mask : (T, T) bool
        The texels that were to be filled.
    atlas : (T, T) bool
        The mesh's texels.
    charts : int
        Connected components of the atlas.
    unfilled_texels : int
        Masked texels in charts without a confident texel (left as they were).
    """

    maps: MaterialMaps
    mask: np.ndarray
    atlas: np.ndarray
    charts: int
    unfilled_texels: int


def inpaint_mask(atlas: np.ndarray, texel_index: np.ndarray, flags: np.ndarray, entropy: np.ndarray,
                 threshold: float | None) -> np.ndarray:
    """Mask the texels to fill (module docstring).

    Parameters
    ----------
    atlas : (T, T) bool
        The mesh's texels.
    texel_index : (N,) int
        Flat row-major indices of the fit's texels into the T x T texture.
    flags : (N,) int
        The uncertainty's flags per texel (``FLAG_*`` of `freqbrdf.uncertainty`).
    entropy : (N,) float
        Normalised entropy per texel.
    threshold : float or None
        Entropy at or above which observed texels are masked; None: the UNOBSERVED and
        AMBIGUOUS flags.

    Returns
    -------
    (T, T) bool
        The texels to fill, within the atlas.
    """
    if threshold is None:
        masked = (flags & (FLAG_UNOBSERVED | FLAG_AMBIGUOUS)) != 0
    else:
        masked = ((flags & FLAG_UNOBSERVED) != 0) | (entropy >= threshold)
    mask = np.zeros(atlas.size, bool)
    mask[texel_index[masked]] = True
    return mask.reshape(atlas.shape) & atlas


def chart_labels(atlas: np.ndarray) -> tuple[np.ndarray, int]:
    """Label the charts of an atlas: its 8-connected components.

    Parameters
    ----------
    atlas : (T, T) bool
        The mesh's texels.

    Returns
    -------
    labels : (T, T) int32
        Chart number per texel, 1 .. count; 0 off the atlas.
    count : int
        The number of charts.
    """
    labels, count = ndimage.label(atlas, structure=np.ones((3, 3), bool))
    return labels.astype(np.int32), int(count)


def inpaint_maps(maps: MaterialMaps, atlas: np.ndarray, mask: np.ndarray, fill: Fill,
                 names: tuple[str, ...] = MAP_NAMES, dilation_px: int = 8) -> Inpainted:
    """Fill the masked texels of some material maps chart by chart (module docstring).

    Parameters
    ----------
    maps : MaterialMaps
        The (T, T, ...) maps.
    atlas : (T, T) bool
        The mesh's texels.
    mask : (T, T) bool
        The texels to fill (`inpaint_mask`); texels off the atlas are ignored.
    fill : Fill
        The backend: (h, w, C) picture and (h, w) bool holes -> (h, w, C) filled picture.
    names : tuple of str
        The maps to fill, among `MAP_NAMES`; the others keep their values.
    dilation_px : int
        Rings of seam padding regrown around the atlas.

    Returns
    -------
    Inpainted
        The maps (float32; filled values clipped to [0, 1]; off the atlas the seam padding
        regrown, `freqbrdf.texels.fill_texture`), the mask and the chart counts.

    Raises
    ------
    ValueError
        If ``names`` is empty or names a map not in `MAP_NAMES`.
    """
    unknown = sorted(set(names) - set(MAP_NAMES))
    if unknown or not names:
        raise ValueError(f"maps to inpaint must be among {', '.join(MAP_NAMES)}; got {', '.join(names) or 'none'}")
    stacked = _stack(maps)  # (T, T, 5)
    labels, n_charts = chart_labels(atlas)
    mask = mask & atlas
    unfilled = 0
    for chart, box in enumerate(ndimage.find_objects(labels), start=1):
        inside = labels[box] == chart
        holes = inside & mask[box]
        known = inside & ~mask[box]
        if not holes.any():
            continue
        if not known.any():
            unfilled += int(holes.sum())
            continue
        # Everything but the chart's confident texels takes the nearest confident texel's value:
        # the backend sees this chart alone, so nothing crosses a seam or comes from empty space.
        nearest = ndimage.distance_transform_edt(~known, return_distances=False, return_indices=True)
        picture = stacked[box][nearest[0], nearest[1]]  # (h, w, 5)
        region = stacked[box]  # a view: writes land in `stacked`
        for name in names:
            channels = MAP_CHANNELS[name]
            filled = np.clip(fill(picture[..., channels], holes), 0.0, 1.0)
            values = region[..., channels]
            values[holes] = filled[holes]
    # Regrow the seam padding from the new atlas values (the maps are hole-free on the atlas).
    off_atlas = np.where(atlas[..., None], stacked, np.nan)
    grown = fill_texture(off_atlas, atlas, dilation_px, fallback=np.nan)
    filled_maps = MaterialMaps(base_color=grown[..., 0:3], roughness=grown[..., 3], metallic=grown[..., 4])
    return Inpainted(filled_maps, mask, atlas, n_charts, unfilled)


def biharmonic_fill(picture: np.ndarray, holes: np.ndarray) -> np.ndarray:
    """Fill holes with scikit-image's biharmonic inpainting (a `Fill`).

    Parameters
    ----------
    picture : (h, w, C) array_like
        The chart's picture.
    holes : (h, w) bool
        The texels to fill.

    Returns
    -------
    (h, w, C) float64
        The picture with its holes filled.
    """
    from skimage.restoration import (
        inpaint_biharmonic,  # its import is slow: only when used
    )

    return inpaint_biharmonic(picture.astype(np.float64), holes, channel_axis=-1)


def diffusion_fill(pipeline, settings: InpaintSettings, generator=None) -> Fill:
    """Make a `Fill` that runs a diffusers inpainting pipeline on each map of a chart.

    Pictures are (h, w, 3) linear base colour (sent sRGB-encoded) or (h, w, 1) grey maps, sent
    as 8-bit RGB pictures resized to ``settings.size`` pixels square, and resized back.

    Parameters
    ----------
    pipeline : callable
        ``pipeline(prompt=, image=, mask_image=, height=, width=, num_inference_steps=,
        generator=)`` must return an object whose ``images[0]`` is a PIL image (diffusers'
        inpainting pipelines do).
    settings : InpaintSettings
        ``prompt``, ``steps`` and ``size``.
    generator : optional
        Passed to the pipeline (e.g. a seeded ``torch.Generator``).

    Returns
    -------
    Fill
        (h, w, C) picture and (h, w) holes -> (h, w, C) float64 picture.
    """
    from PIL import Image

    def fill(picture: np.ndarray, holes: np.ndarray) -> np.ndarray:
        height, width, n_channels = picture.shape
        is_colour = n_channels == 3  # the base colour; otherwise one grey map
        encoded = linear_to_srgb(picture) if is_colour else np.repeat(picture, 3, axis=-1)
        image = Image.fromarray(np.round(np.clip(encoded, 0.0, 1.0) * 255.0).astype(np.uint8), "RGB")
        mask_image = Image.fromarray(np.where(holes, 255, 0).astype(np.uint8), "L")
        size = (settings.size, settings.size)
        result = pipeline(
            prompt=settings.prompt, image=image.resize(size, Image.BILINEAR),
            mask_image=mask_image.resize(size, Image.NEAREST), height=settings.size, width=settings.size,
            num_inference_steps=settings.steps, generator=generator,
        ).images[0]
        result = np.asarray(result.convert("RGB").resize((width, height), Image.BILINEAR), np.float64) / 255.0
        return srgb_to_linear(result) if is_colour else result.mean(axis=-1, keepdims=True)

    return fill


def load_diffusion_fill(settings: InpaintSettings) -> Fill:
    """Load the diffusers pipeline in ``settings.model`` and make its `diffusion_fill`.

    Local files only (a folder written by ``save_pretrained``, e.g. a Stable Diffusion
    inpainting checkpoint); it runs on CUDA when torch sees a GPU, else on the CPU, seeded with
    ``settings.seed``.

    Parameters
    ----------
    settings : InpaintSettings
        ``model`` and the diffusion settings.

    Returns
    -------
    Fill
        The pipeline's fill.

    Raises
    ------
    InputError
        If torch or diffusers is missing (the extra ``freqbrdf[diffusion]``), or ``model`` is not
        a diffusers pipeline folder.
    """
    try:
        import torch
        from diffusers import AutoPipelineForInpainting
    except ImportError as err:
        raise InputError(settings.model, f"the diffusion backend needs torch and diffusers "
                         f"(pip install 'freqbrdf[diffusion]'): {err}") from None
    path = Path(settings.model)
    if not (path / "model_index.json").is_file():
        raise InputError(path, "not a diffusers pipeline folder (no model_index.json)")
    device = "cuda" if torch.cuda.is_available() else "cpu"
    pipeline = AutoPipelineForInpainting.from_pretrained(path, local_files_only=True).to(device)
    pipeline.set_progress_bar_config(disable=True)
    return diffusion_fill(pipeline, settings, torch.Generator(device).manual_seed(settings.seed))


def _stack(maps: MaterialMaps) -> np.ndarray:
    """(T, T, 5) float64: base colour RGB, roughness, metallic."""
    return np.concatenate([maps.base_color, maps.roughness[..., None], maps.metallic[..., None]], axis=-1).astype(
        np.float64)

