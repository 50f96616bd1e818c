"""Outputs of a fit: hole-free textures, EXR/PNG maps, the fit folder and ``summary.json``.

These are the outputs of docs/method.md#outputs. Per-texel estimates become T x T textures in two fill steps, so that renderers and texture
filtering never see holes or dark seams:

1. Texels of the mesh's atlas without an estimate (no sample) take the value of the nearest
   estimated texel in texture space (Euclidean distance transform).
2. The atlas is grown ``config.texels.dilation_px`` rings into the empty texture space by
   `texels.dilate` (mean of filled neighbours), so bilinear and mip-mapped lookups across chart
   seams blend surface values. Texels farther from every chart take the mean over the atlas
  (`freqbrdf.texels.fill_texture`).

The glTF binary is `freqbrdf.outputs.gltf`'s.
"""

from __future__ import annotations

import math
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numba
import numpy as np
from matplotlib import colormaps

from freqbrdf.capture.mesh import Mesh
from freqbrdf.config import Config
from freqbrdf.estimate import MaterialEstimate
from freqbrdf.fileio import atomic_directory, atomic_path, write_json
from freqbrdf.images import linear_to_srgb, write_exr, write_png
from freqbrdf.model.materials import MaterialMaps, save_material_maps
from freqbrdf.observe.observations import Observations
from freqbrdf.outputs.gltf import write_gltf
from freqbrdf.texels import Texels, fill_texture
from freqbrdf.uncertainty import (
    FLAG_AMBIGUOUS,
    FLAG_BELOW_BOUND,
    FLAG_FEW_SAMPLES,
    FLAG_UNOBSERVED,
    PRIOR_ROUGHNESS_VARIANCE,
    Uncertainty,
)
from freqbrdf.uncertainty import (
    summary as uncertainty_summary,
)
from freqbrdf.uncertainty.trust import trust_summary, trusted_texels

# Values of a texture without a single estimated texel: mid grey, mid roughness, dielectric.
FALLBACK_BASE_COLOR = 0.5
FALLBACK_ROUGHNESS = 0.5
FALLBACK_METALLIC = 0.0
ENTROPY_RANGE = (0.0, 1.0)  # normalised entropy; the PNG maps this range onto the colour map
ENTROPY_COLORMAP = "viridis"
# Roughness std of a texel without an estimate: the prior's, roughness uniform on [0, 1] (sqrt(1/12)
# ~ 0.29), as the entropy of an unobserved texel is 1: nothing is known there.
UNESTIMATED_ROUGHNESS_STD = math.sqrt(PRIOR_ROUGHNESS_VARIANCE)
# The PNG's range, in roughness units. The top, 0.3, is about the prior's std: brighter means no
# better than knowing nothing; the few estimated texels above it are clipped to it (their spread
# on the default fits: docs/results.md).
ROUGHNESS_STD_RANGE = (0.0, 0.3)
ROUGHNESS_STD_COLORMAP = "magma"  # not viridis: a different quantity and unit than the entropy
# The metallic std's PNG range: 0.5 is a coin toss between dielectric and metal.
METALLIC_STD_RANGE = (0.0, 0.5)
# The base colour std's PNG range (the mean over RGB), in linear base-colour units.
BASE_COLOR_STD_RANGE = (0.0, 0.3)
# Files of a fit folder written at once (see write_fit_outputs); more threads than jobs idle.
WRITER_THREADS = 4

FILES = {
    "base_color": "base_color.exr",
    "roughness": "roughness.exr",
    "metallic": "metallic.exr",
    "base_color_png": "base_color.png",
    "roughness_png": "roughness.png",
    "metallic_png": "metallic.png",
    "entropy": "entropy.exr",
    "entropy_png": "entropy.png",
    "roughness_std": "roughness_std.exr",
    "roughness_std_png": "roughness_std.png",
    "metallic_std": "metallic_std.exr",
    "metallic_std_png": "metallic_std.png",
    "base_color_std": "base_color_std.exr",
    "base_color_std_png": "base_color_std.png",
    "flags_png": "flags.png",
    "trust": "trust.exr",
    "trust_png": "trust.png",
    "gltf": "material.glb",
    "spectra": "spectra.npz",
    "uncertainty": "uncertainty.npz",
    "summary": "summary.json",
}


# ---------------------------------------------------------------------------------------------
# From per-texel values to textures


def material_textures(estimate: MaterialEstimate, dilation_px: int) -> MaterialMaps:
    """Make hole-free textures of an estimate (see the module docstring).

    Parameters
    ----------
    estimate : MaterialEstimate
        The per-texel estimate (N texels of a T x T texture); its texels are the atlas.
    dilation_px : int
        Rings of dilation beyond the atlas.

    Returns
    -------
    MaterialMaps
        Base colour (T, T, 3), roughness and metallic (T, T), float32; textures without any
        estimated texel take ``FALLBACK_*``.
    """
    atlas = _atlas_mask(estimate)
    maps = estimate.textures()  # NaN off the estimated texels
    return MaterialMaps(
        base_color=fill_texture(maps["base_color"], atlas, dilation_px, FALLBACK_BASE_COLOR),
        roughness=fill_texture(maps["roughness"], atlas, dilation_px, FALLBACK_ROUGHNESS),
        metallic=fill_texture(maps["metallic"], atlas, dilation_px, FALLBACK_METALLIC),
    )


def entropy_texture(uncertainty: Uncertainty, estimate: MaterialEstimate | Observations,
                    dilation_px: int) -> np.ndarray:
    """Make the normalised-entropy texture, dilated across seams like the material maps.

    Parameters
    ----------
    uncertainty : Uncertainty
        The uncertainty (N texels).
    estimate : MaterialEstimate or Observations
        Gives the texel layout; from the same Observations as ``uncertainty`` (same texel order).
    dilation_px : int
        Rings of dilation beyond the atlas.

    Returns
    -------
    (T, T) float32
        Entropy in [0, 1]; 1 (nothing known) where no texel is.
    """
    values = estimate.to_texture(uncertainty.entropy.astype(np.float32), fill=np.nan)
    return fill_texture(values, _atlas_mask(estimate), dilation_px, fallback=ENTROPY_RANGE[1])


def roughness_std_values(roughness_std: np.ndarray) -> np.ndarray:
    """Return the per-texel roughness std as exported and evaluated.

    Parameters
    ----------
    roughness_std : (N,) float array
        The posterior std of the roughness, NaN where not estimated.

    Returns
    -------
    (N,) float32
        The std; texels without an estimate take ``UNESTIMATED_ROUGHNESS_STD`` (the prior's).
    """
    values = np.asarray(roughness_std, np.float32)
    return np.where(np.isfinite(values), values, np.float32(UNESTIMATED_ROUGHNESS_STD))


def roughness_std_texture(uncertainty: Uncertainty, estimate: MaterialEstimate, dilation_px: int) -> np.ndarray:
    """Make the roughness-std texture, dilated across seams like the material maps.

    Parameters
    ----------
    uncertainty : Uncertainty
        The uncertainty; its ``roughness_std`` must have been computed.
    estimate : MaterialEstimate
        Gives the texel layout (same texel order).
    dilation_px : int
        Rings of dilation beyond the atlas.

    Returns
    -------
    (T, T) float32
        ``roughness_std_values(uncertainty.roughness_std)`` as a texture.
    """
    values = estimate.to_texture(roughness_std_values(uncertainty.roughness_std), fill=np.nan)
    return fill_texture(values, _atlas_mask(estimate), dilation_px, fallback=UNESTIMATED_ROUGHNESS_STD)


# ---------------------------------------------------------------------------------------------
# Writers (each atomic)


def entropy_description(mode: str) -> str:
    """Say what an entropy map is, for its EXR's ``comments``.

    Parameters
    ----------
    mode : str
        The uncertainty's mode (``Uncertainty.mode``: "calibrated", "paper" or "angular").

    Returns
    -------
    str
        One paragraph: the quantity, its range and that it is normalised.
    """
    return (f"freqbrdf entropy ({mode} mode): the normalised entropy of the likelihood over the specular "
            "hypotheses (GGX alpha = roughness^2, specular k_s) per texel, in [0, 1]: 0 = the data pin the "
            "material down, 1 = every hypothesis fits equally (a uniform likelihood; also unobserved texels). "
            "Normalised by the entropy of the uniform likelihood, not in bits; the minimum over RGB. "
            "Texture space: row 0 is v = 1.")


#: What roughness_std.exr is (its ``comments``).
ROUGHNESS_STD_DESCRIPTION = (
    "freqbrdf roughness std: the posterior standard deviation of the estimated Principled roughness r "
    "per texel, in roughness units (r, not GGX alpha = r^2), >= 0; texels without an estimate hold the "
    "prior's sqrt(1/12) (roughness uniform on [0, 1]). Texture space: row 0 is v = 1.")



def write_scalar_map(path: str | Path, texture: np.ndarray, colormap: str | None = None,
                     value_range: tuple[float, float] = (0.0, 1.0), description: str | None = None) -> None:
    """Write a scalar texture: ``.exr`` as float values, ``.png`` as an 8-bit picture.

    Parameters
    ----------
    path : str or Path
        The file; its suffix (``.exr`` or ``.png``) chooses the format.
    texture : (T, T) float array
        The values.
    colormap : str, optional
        A matplotlib colour map for the PNG (e.g. "viridis", "magma"); None: grey.
    value_range : (float, float), optional
        The values mapped linearly onto the PNG's range; values outside are clipped, NaN is
        black.
    description : str, optional
        What the map is, stored in the EXR's ``comments`` (e.g. `entropy_description`); unused for
        PNG.

    Raises
    ------
    ValueError
        If ``texture`` is not 2-D or the suffix is neither ``.exr`` nor ``.png``.
    """
    path = Path(path)
    texture = np.asarray(texture, np.float32)
    if texture.ndim != 2:
        raise ValueError(f"write_scalar_map needs a (T, T) texture, got shape {texture.shape}")
    if path.suffix.lower() == ".exr":
        write_exr(path, texture, comments=description)
        return
    if path.suffix.lower() != ".png":
        raise ValueError(f"write_scalar_map writes .exr or .png, not {path.name}")
    low, high = value_range
    normalised = np.clip((texture - low) / (high - low), 0.0, 1.0)
    if colormap is None:
        write_png(path, normalised)
        return
    rgb = colormaps[colormap](np.nan_to_num(normalised))[..., :3]
    rgb[~np.isfinite(texture)] = 0.0
    write_png(path, rgb)


def write_material_previews(folder: str | Path, maps: MaterialMaps) -> None:
    """Write ``base_color.png`` (sRGB-encoded), ``roughness.png`` and ``metallic.png`` (grey, linear).

    Parameters
    ----------
    folder : str or Path
        The folder to write into.
    maps : MaterialMaps
        The textures.
    """
    folder = Path(folder)
    write_png(folder / FILES["base_color_png"], linear_to_srgb(maps.base_color))
    write_scalar_map(folder / FILES["roughness_png"], maps.roughness)
    write_scalar_map(folder / FILES["metallic_png"], maps.metallic)


def coverage(source: Texels | Observations, estimate: MaterialEstimate) -> dict:
    """Compute coverage statistics for ``summary.json``.

    Parameters
    ----------
    source : Texels or Observations
        What the estimate was made on; only Observations know views.
    estimate : MaterialEstimate
        The estimate (N texels).

    Returns
    -------
    dict
        ``texture_res``, ``texels``, ``estimated_fraction`` and ``observed_fraction`` (with
        Texels alone: the estimated fraction); with Observations also ``views``,
        ``mean_views_per_texel`` and ``mean_views_per_observed_texel``.
    """
    n_texels = estimate.n_texels
    stats = {
        "texture_res": estimate.texture_res,
        "texels": n_texels,
        "estimated_fraction": float(np.mean(estimate.estimated)) if n_texels else 0.0,
    }
    if isinstance(source, Observations):
        samples = source.n_samples.astype(np.float64)
        stats.update(
            views=source.n_views,
            observed_fraction=float(np.mean(samples > 0)) if n_texels else 0.0,
            mean_views_per_texel=float(samples.mean()) if n_texels else 0.0,
            mean_views_per_observed_texel=float(samples[samples > 0].mean()) if (samples > 0).any() else 0.0,
        )
    else:  # texels alone say nothing about views; "observed" means "has an estimate"
        stats["observed_fraction"] = stats["estimated_fraction"]
    return stats


def write_fit_outputs(
    out_dir: str | Path,
    mesh: Mesh,
    source: Texels | Observations,
    estimate: MaterialEstimate,
    uncertainty: Uncertainty | None = None,
    config: Config = Config(),
    timings: dict | None = None,
    extra_summary: dict | None = None,
    maps: MaterialMaps | None = None,
) -> Path:
    """Write the whole output folder of a fit, replacing it as a whole, atomically.

    Files: see ``FILES``; the entropy maps, ``flags.png`` and ``uncertainty.npz`` only with
    ``uncertainty``, the roughness_std maps only when it holds them, ``spectra.npz`` only when
    ``source`` is Observations.

    Parameters
    ----------
    out_dir : str or Path
        The output folder.
    mesh : Mesh
        The mesh, for the glTF.
    source : Texels or Observations
        What the estimate was made on (same texel order).
    estimate : MaterialEstimate
        The estimate.
    uncertainty : Uncertainty, optional
        The uncertainty of the same texels.
    config : Config, optional
        The settings; recorded in ``summary.json``, and ``config.texels.dilation_px`` dilates the
        textures.
    timings : dict, optional
        Seconds per stage, recorded in ``summary.json``.
    extra_summary : dict, optional
        Merged into ``summary.json`` (e.g. the capture's path).
    maps : MaterialMaps, optional
        The estimate's textures when already made
        (``material_textures(estimate, config.texels.dilation_px)``).

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    ValueError
        If the estimate was not made on ``source``'s texels.

    Examples
    --------
    The per-texel estimate and entropy of a tiny synthetic capture written as a fit folder
    (`freqbrdf.pipeline.write_fit` writes a whole `freqbrdf.pipeline.fit` this way), and read back:

    >>> import json
    >>> import tempfile
    >>> from pathlib import Path
    >>> from freqbrdf.capture import load
    >>> from freqbrdf.config import Config, TexelConfig
    >>> from freqbrdf.estimate import estimate
    >>> from freqbrdf.observe import observe
    >>> from freqbrdf.outputs import load_fit, write_fit_outputs
    >>> from freqbrdf.synthetic import example_capture
    >>> from freqbrdf.uncertainty import entropy_map
    >>> work = tempfile.TemporaryDirectory()
    >>> capture = load(example_capture(Path(work.name) / "capture"))
    >>> config = Config(texels=TexelConfig(texture_res=32))
    >>> observations = observe(capture, config)
    >>> materials = estimate(observations, config)
    >>> folder = write_fit_outputs(Path(work.name) / "fit", capture.mesh, observations, materials,
    ...                            entropy_map(observations), config)
    >>> json.loads((folder / "summary.json").read_text())["files"]
    ['base_color.exr', 'roughness.exr', 'metallic.exr', 'base_color.png', 'roughness.png', 'metallic.png',
     'material.glb', 'entropy.exr', 'entropy.png', 'flags.png', 'uncertainty.npz', 'spectra.npz', 'summary.json']
    >>> fit = load_fit(folder)
    >>> fit.maps.base_color.shape, fit.maps.roughness.shape
    ((32, 32, 3), (32, 32))
    >>> work.cleanup()
    """
    if not np.array_equal(source.texel_index, estimate.texel_index):
        raise ValueError("the estimate was not made on these texels (texel_index differs)")
    dilation = config.texels.dilation_px
    if maps is None:
        maps = material_textures(estimate, dilation)
    out_dir = Path(out_dir)
    written = ["base_color", "roughness", "metallic", "base_color_png", "roughness_png", "metallic_png", "gltf"]
    summary = {
        "settings": config.to_dict(),
        "timings": dict(timings or {}),
        "coverage": coverage(source, estimate),
        "estimate": {
            "method": estimate.method,
            "base_color_mean": _masked_mean(estimate.base_color, estimate.estimated),
            "roughness_mean": _masked_mean(estimate.roughness, estimate.estimated),
            "metallic_mean": _masked_mean(estimate.metallic, estimate.estimated),
        },
    }
    # The files are independent and their costly parts (deflate, PNG encoding, numpy) release the
    # GIL, so they are written by a few threads at once. The pool is closed (every write finished
    # or failed) before the folder is renamed into place or removed.
    with atomic_directory(out_dir) as folder, ThreadPoolExecutor(WRITER_THREADS) as pool:
        jobs = []  # the longest first: uncertainty.npz deflates the likelihood grids
        if uncertainty is not None:
            jobs += [
                pool.submit(_save_uncertainty, folder / FILES["uncertainty"], uncertainty, estimate.texel_index),
                pool.submit(_write_uncertainty_maps, folder, uncertainty, estimate, dilation),
            ]
            summary["uncertainty"] = uncertainty_summary(uncertainty)
            summary["entropy_png"] = {"colormap": ENTROPY_COLORMAP, "range": list(ENTROPY_RANGE)}
            written += ["entropy", "entropy_png", "flags_png", "uncertainty"]
            if uncertainty.metallic_std is not None and uncertainty.base_color_std is not None:
                jobs.append(pool.submit(_write_posterior_std_maps, folder, uncertainty, estimate, dilation))
                summary["metallic_std_png"] = {"colormap": ROUGHNESS_STD_COLORMAP, "range": list(METALLIC_STD_RANGE)}
                summary["base_color_std_png"] = {"colormap": ROUGHNESS_STD_COLORMAP, "range": list(BASE_COLOR_STD_RANGE),
                                                 "of": "the mean over RGB"}
                written += ["metallic_std", "metallic_std_png", "base_color_std", "base_color_std_png"]
            trust = trust_summary(uncertainty, config.uncertainty.trust_std, np.ones(estimate.n_texels, bool))
            if trust is not None:
                jobs.append(pool.submit(_write_trust_maps, folder, uncertainty, estimate, config.uncertainty.trust_std))
                summary["trust"] = trust
                written += ["trust", "trust_png"]
            if uncertainty.roughness_std is not None:
                jobs.append(pool.submit(_write_roughness_std_maps, folder, uncertainty, estimate, dilation))
                summary["roughness_std_png"] = {"colormap": ROUGHNESS_STD_COLORMAP, "range": list(ROUGHNESS_STD_RANGE),
                                                "unestimated": UNESTIMATED_ROUGHNESS_STD}
                written += ["roughness_std", "roughness_std_png"]
        if isinstance(source, Observations):
            jobs.append(pool.submit(_save_spectra, folder / FILES["spectra"], source))
            written.append("spectra")
        jobs += [
            pool.submit(save_material_maps, folder, maps),
            pool.submit(write_material_previews, folder, maps),
            pool.submit(write_gltf, folder / FILES["gltf"], mesh, maps),
        ]
        summary.update(extra_summary or {})
        summary["files"] = [FILES[key] for key in written] + [FILES["summary"]]
        write_json(folder / FILES["summary"], summary)
        for job in jobs:
            job.result()  # re-raises the first failure; the folder is then discarded
    return out_dir


def _write_uncertainty_maps(folder: Path, uncertainty: Uncertainty, estimate: MaterialEstimate,
                            dilation_px: int) -> None:
    """Write entropy.exr, entropy.png and flags.png."""
    entropy = entropy_texture(uncertainty, estimate, dilation_px)
    write_scalar_map(folder / FILES["entropy"], entropy, description=entropy_description(uncertainty.mode))
    write_scalar_map(folder / FILES["entropy_png"], entropy, ENTROPY_COLORMAP, ENTROPY_RANGE)
    write_png(folder / FILES["flags_png"],
              flags_picture(estimate.to_texture(uncertainty.flags, fill=0), _atlas_mask(estimate)))


#: What trust.exr is (its ``comments``).
TRUST_DESCRIPTION = (
    "freqbrdf trust mask: 1 where every std of the texel (roughness, metallic, the base colour's mean over RGB) is at "
    "most the threshold in summary.json trust.threshold, else 0 (and 0 off the atlas). Texture space: row 0 is v = 1.")


def _write_trust_maps(folder: Path, uncertainty: Uncertainty, estimate: MaterialEstimate, threshold: float) -> None:
    """Write trust.exr (1 trusted, 0 not or off the atlas) and trust.png (white trusted)."""
    mask = estimate.to_texture(trusted_texels(uncertainty, threshold).astype(np.float32), fill=0.0).astype(np.float32)
    write_scalar_map(folder / FILES["trust"], mask, description=TRUST_DESCRIPTION)
    write_scalar_map(folder / FILES["trust_png"], mask)


def _write_roughness_std_maps(folder: Path, uncertainty: Uncertainty, estimate: MaterialEstimate,
                              dilation_px: int) -> None:
    """Write roughness_std.exr and roughness_std.png."""
    spread = roughness_std_texture(uncertainty, estimate, dilation_px)
    write_scalar_map(folder / FILES["roughness_std"], spread, description=ROUGHNESS_STD_DESCRIPTION)
    write_scalar_map(folder / FILES["roughness_std_png"], spread, ROUGHNESS_STD_COLORMAP, ROUGHNESS_STD_RANGE)


#: What metallic_std.exr is (its ``comments``).
METALLIC_STD_DESCRIPTION = (
    "freqbrdf metallic std: the whole-surface posterior's standard deviation of the metallic per texel, "
    "sqrt(p (1 - p) + v) for the probability p of the metal label and the variance v of p over the texel's "
    "neighbourhood (a border between metal and dielectric), in [0, 0.5]. Texture space: row 0 is v = 1.")
#: What base_color_std.exr is (its ``comments``).
BASE_COLOR_STD_DESCRIPTION = (
    "freqbrdf base colour std: the whole-surface posterior's standard deviation of each linear base-colour "
    "channel (R, G, B) per texel, >= 0. Texture space: row 0 is v = 1.")


def _write_posterior_std_maps(folder: Path, uncertainty: Uncertainty, estimate: MaterialEstimate,
                              dilation_px: int) -> None:
    """Write metallic_std.exr/.png and base_color_std.exr/.png (the whole-surface posterior's)."""
    atlas = _atlas_mask(estimate)
    metallic = fill_texture(estimate.to_texture(np.asarray(uncertainty.metallic_std, np.float32), fill=np.nan), atlas,
                            dilation_px, fallback=METALLIC_STD_RANGE[1])
    write_scalar_map(folder / FILES["metallic_std"], metallic, description=METALLIC_STD_DESCRIPTION)
    write_scalar_map(folder / FILES["metallic_std_png"], metallic, ROUGHNESS_STD_COLORMAP, METALLIC_STD_RANGE)
    color = estimate.to_texture(np.asarray(uncertainty.base_color_std, np.float32), fill=np.nan)
    color = np.stack([fill_texture(color[..., c], atlas, dilation_px, fallback=BASE_COLOR_STD_RANGE[1])
                      for c in range(3)], axis=-1).astype(np.float32)
    write_exr(folder / FILES["base_color_std"], color, comments=BASE_COLOR_STD_DESCRIPTION)
    write_scalar_map(folder / FILES["base_color_std_png"], color.mean(axis=-1), ROUGHNESS_STD_COLORMAP,
                     BASE_COLOR_STD_RANGE)


def _save_uncertainty(path: Path, uncertainty: Uncertainty, texel_index: np.ndarray) -> None:
    """Write uncertainty.npz, deflated (the float16 likelihood grids compress well).

    roughness_std is stored as computed (NaN where not estimated).
    """
    optional = {"likelihood": None if uncertainty.likelihood is None else to_float16(uncertainty.likelihood),
                "roughness_std": uncertainty.roughness_std, "metallic_std": uncertainty.metallic_std,
                "base_color_std": uncertainty.base_color_std}
    _save_npz(path, True, texel_index=texel_index, entropy=uncertainty.entropy, flags=uncertainty.flags,
              best_alpha=uncertainty.best_alpha, best_ks=uncertainty.best_ks,
              **{name: values for name, values in optional.items() if values is not None})


def _save_spectra(path: Path, source: Observations) -> None:
    """Write spectra.npz, stored: deflating costs time and barely shrinks the spectra."""
    _save_npz(path, False, texel_index=source.texel_index,
              observed_spectrum=source.observed_spectrum.astype(np.float32),
              mirrored_spectrum=source.mirrored_spectrum.astype(np.float32),
              n_samples=source.n_samples, sigma=np.float64(source.sigma),
              alpha_bound=source.alpha_bound.astype(np.float32))


# Colours of flags.png, one per FLAG_* bit in priority order (the first set bit wins); texels
# without a flag are white and texels off the atlas black.
FLAG_COLOURS = {
    FLAG_UNOBSERVED: (0.35, 0.35, 0.35),
    FLAG_FEW_SAMPLES: (0.95, 0.55, 0.10),
    FLAG_BELOW_BOUND: (0.20, 0.45, 0.90),
    FLAG_AMBIGUOUS: (0.85, 0.15, 0.15),
}


def flags_picture(flags: np.ndarray, atlas: np.ndarray) -> np.ndarray:
    """Paint a flag texture as a picture, one colour per flag (``FLAG_COLOURS``).

    Parameters
    ----------
    flags : (T, T) uint8
        Bit fields of ``FLAG_*``; the first set bit in priority order gives the colour.
    atlas : (T, T) bool
        The mesh's texels: white where no flag is set; texels off the atlas are black.

    Returns
    -------
    (T, T, 3) float32
        The picture, RGB in [0, 1].
    """
    picture = np.zeros(flags.shape + (3,), np.float32)
    picture[atlas] = 1.0
    for bit, colour in reversed(FLAG_COLOURS.items()):  # reversed: higher priority painted last
        picture[(flags & bit) != 0] = colour
    return picture


# ---------------------------------------------------------------------------------------------
# Helpers


def _save_npz(path: Path, compress: bool, **arrays) -> None:
    """Write an .npz that np.load reads, atomically; deflated at level 1 when ``compress``, else stored.

    Level 1 rather than numpy's default level: the higher level costs much more time for little
    gain on these arrays.
    """
    with atomic_path(path) as tmp:
        compression = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
        with zipfile.ZipFile(tmp, "w", compression=compression, compresslevel=1 if compress else None) as archive:
            for name, array in arrays.items():
                with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, np.asanyarray(array), allow_pickle=False)


def to_float16(values: np.ndarray) -> np.ndarray:
    """Cast to float16 like ``values.astype(np.float16)``, bit for bit, in one pass.

    numpy's cast is slow on likelihood grids: most of their values are tiny, and a float16 result
    below 2**-14 (subnormal) costs the processor a slow assist each. Serial on purpose: it runs in
    a writer thread (`write_fit_outputs`), beside other writes.

    Parameters
    ----------
    values : float array
        Any shape; cast to float32 first.

    Returns
    -------
    float16 array
        Same shape, rounded to nearest even.
    """
    values = np.ascontiguousarray(values, dtype=np.float32)
    bits = np.empty(values.shape, np.uint16)
    _float16_bits(values.reshape(-1).view(np.uint32), bits.reshape(-1))
    return bits.view(np.float16)


@numba.njit(cache=True)
def _float16_bits(float_bits, half_bits):
    """Convert IEEE binary32 to binary16 bits, round to nearest even (what numpy's cast does)."""
    for i in range(float_bits.shape[0]):
        f = float_bits[i]
        sign = np.uint16((f >> 16) & 0x8000)
        exponent = (f >> 23) & 0xFF
        mantissa = f & 0x7FFFFF
        if exponent == 0xFF:  # inf, or nan (quiet, keeping the payload's top bits)
            half_bits[i] = sign | 0x7C00 | (np.uint16(0x200 | (mantissa >> 13)) if mantissa else 0)
        elif exponent >= 143:  # |x| >= 2**16: beyond float16's range
            half_bits[i] = sign | 0x7C00
        elif exponent >= 113:  # normal float16: keep 10 mantissa bits, round half to even
            half = np.uint32(((exponent - 112) << 10) | (mantissa >> 13))
            rest = mantissa & 0x1FFF
            if rest > 0x1000 or (rest == 0x1000 and (half & 1)):
                half += 1  # a carry into the exponent is right (up to 0x7C00, inf)
            half_bits[i] = sign | np.uint16(half)
        elif exponent >= 102:  # subnormal float16 (or 2**-14 after rounding): steps of 2**-24
            significand = mantissa | 0x800000  # value = significand * 2**(exponent - 150)
            shift = 126 - exponent  # 2**-24 steps: significand >> (126 - exponent), 13 < shift <= 24
            half = significand >> shift
            rest = significand & ((np.uint32(1) << shift) - 1)
            halfway = np.uint32(1) << (shift - 1)
            if rest > halfway or (rest == halfway and (half & 1)):
                half += 1
            half_bits[i] = sign | np.uint16(half)
        else:  # below half the smallest subnormal: a signed zero
            half_bits[i] = sign


def _atlas_mask(estimate: MaterialEstimate | Observations) -> np.ndarray:
    """Return the (T, T) bool mask of the mesh's texels (estimated or not)."""
    return estimate.to_texture(np.ones(estimate.n_texels, bool), fill=False)


def _masked_mean(values: np.ndarray, keep: np.ndarray):
    if not keep.any():
        return None
    mean = np.asarray(values)[keep].mean(axis=0)
    return mean.tolist() if np.ndim(mean) else float(mean)


