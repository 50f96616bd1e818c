"""Inpainting uncertain regions of a fit's material maps (METHOD.md §4, `freqbrdf inpaint`).

**Mask.** Texels of the mesh's atlas that the fit cannot vouch for: by default those flagged
UNOBSERVED (no sample) or AMBIGUOUS (entropy above the fit's ``uncertainty.ambiguous_entropy``,
0.7 by default); with ``threshold`` H, UNOBSERVED or entropy >= H. Two flags are deliberately
left out: FEW_SAMPLES (fewer samples than a quarter of the SH coefficients) already raises the
entropy, which counts the samples, and BELOW_BOUND marks shiny texels whose specular lobe is
sharper than the views resolve: their estimate is "very smooth", which a fill from rougher
neighbours would only make worse.

**Charts.** The atlas is split into connected components (8-connected texels of the mesh); each
is filled from its own confident texels only. Per chart, its bounding box is prepared so that
nothing from elsewhere can leak in: every texel that is not a confident texel of the chart
(other charts, empty atlas space, the holes) first takes the value of the nearest confident
texel of the chart; the backend then fills the chart's holes from that picture. A chart without
a single confident texel keeps its values (counted as ``unfilled_texels``). After filling, the
seam padding around the atlas is regrown from the new values (``texels.fill_texture``).

**Backends.**

- ``biharmonic`` (default): scikit-image's ``restoration.inpaint_biharmonic``, a smooth
  (biharmonic) continuation of the surrounding values into each hole; no learned prior.
- ``diffusion``: a diffusers inpainting pipeline loaded from a local folder (``--model PATH``,
  as written by ``save_pretrained``: e.g. a Stable Diffusion inpainting checkpoint). It needs the
  optional extra ``pip install 'freqbrdf[diffusion]'`` (torch, diffusers, transformers) and the
  model's files on disk; nothing is downloaded. Each map goes through it as an 8-bit picture
  (base colour sRGB-encoded, roughness and metallic as grey), per chart, resized to ``size``
  pixels square; only the hole texels are taken back.
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
    threshold: float | None = None  # entropy at or above which observed texels are masked; None: the flags
    maps: tuple[str, ...] = MAP_NAMES  # which material maps are filled
    backend: Literal["biharmonic", "diffusion"] = "biharmonic"
    model: str | None = None  # diffusion: folder of a diffusers inpainting pipeline
    prompt: str = "seamless physically based material texture, uniform lighting"
    steps: int = 25  # diffusion: denoising steps
    size: int = 512  # diffusion: pictures are resized to size x size
    seed: int = 0  # diffusion: noise seed


@dataclass(eq=False)
class Inpainted:
    maps: MaterialMaps  # (T, T, ·) filled, seam padding regrown
    mask: np.ndarray  # (T, T) bool: the texels that were to be filled
    atlas: np.ndarray  # (T, T) bool: the mesh's texels
    charts: int  # connected components of the atlas
    unfilled_texels: int  # masked texels in charts without a confident texel (left as they were)


def inpaint_mask(atlas: np.ndarray, texel_index: np.ndarray, flags: np.ndarray, entropy: np.ndarray,
                 threshold: float | None) -> np.ndarray:
    """(T, T) bool mask of the texels to fill (module docstring); per-texel flags and entropy (N,)."""
    if threshold is None:
        masked = (flags & (FLAG_UNOBSERVED | FLAG_AMBIGUOUS)) != 0
    else:
        masked = ((flags & FLAG_UNOBSERVED) != 0) | (entropy >= threshold)
    mask = np.zeros(atlas.size, bool)
    mask[texel_index[masked]] = True
    return mask.reshape(atlas.shape) & atlas


def chart_labels(atlas: np.ndarray) -> tuple[np.ndarray, int]:
    """(T, T) int32 chart number per texel (0 off the atlas) and the number of charts (8-connected)."""
    labels, count = ndimage.label(atlas, structure=np.ones((3, 3), bool))
    return labels.astype(np.int32), int(count)


def inpaint_maps(maps: MaterialMaps, atlas: np.ndarray, mask: np.ndarray, fill: Fill,
                 names: tuple[str, ...] = MAP_NAMES, dilation_px: int = 8) -> Inpainted:
    """Fill the ``mask`` (T, T) texels of the maps ``names`` chart by chart with ``fill``."""
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
    """scikit-image's biharmonic inpainting of ``holes`` (h, w) in ``picture`` (h, w, C)."""
    from skimage.restoration import (
        inpaint_biharmonic,  # its import costs ~0.5 s: only when used
    )

    return inpaint_biharmonic(picture.astype(np.float64), holes, channel_axis=-1)


def diffusion_fill(pipeline, settings: InpaintSettings, generator=None) -> Fill:
    """A `Fill` running a diffusers inpainting ``pipeline`` on each map of a chart (module docstring).

    ``pipeline(prompt=, image=, mask_image=, height=, width=, num_inference_steps=, generator=)``
    must return an object whose ``images[0]`` is a PIL image (diffusers' inpainting pipelines do).
    Pictures are (h, w, 3) linear base colour (sent sRGB-encoded) or (h, w, 1) grey maps.
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
    """`diffusion_fill` with the pipeline in ``settings.model`` (local files only, CPU or CUDA)."""
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

