"""What a candidate view would tell the whole-surface estimate, before it is taken (docs/method.md#guidance).

Capture guidance (`freqbrdf.applications.guidance`) scores cameras by what their samples would
add to each texel: the Fisher information on roughness (with the specular and diffuse scales as
nuisances: `roughness_information`) and the evidence between the metal and dielectric labels
(`view_information`). Both come from the texel's current estimate, the environment's SH in the
mirror direction and the camera's visibility (`freqbrdf.applications.candidates.view_samples`),
so no photograph is needed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from freqbrdf.applications.candidates import view_samples
from freqbrdf.capture.camera import Camera
from freqbrdf.capture.layouts import Capture
from freqbrdf.estimate.search import lambert_scale
from freqbrdf.model.brdf import ALPHA_MIN, alpha_from_roughness
from freqbrdf.sphere import envmap as envmaps
from freqbrdf.sphere import harmonics as sh
from freqbrdf.texels import Texels

if TYPE_CHECKING:
    from freqbrdf.applications.guidance import SurfaceFit

LIGHT_LMAX = 16  # SH degree of the environment in the Fisher information and the metal evidence
DIELECTRIC_F0 = 0.04  # specular reflectance of a dielectric at normal incidence
# Entries of the symmetric 3 x 3 Fisher information on (roughness, specular scale, diffuse scale).
_FISHER_PAIRS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
FISHER_ENTRIES = len(_FISHER_PAIRS)
# Ridge on the nuisance block, relative to its trace: a texel seen once cannot separate them.
_NUISANCE_RIDGE = 1e-6


@dataclass(frozen=True)
class ViewInformation:
    """What one camera adds to the m scored texels it samples.

    Attributes
    ----------
    texel : (m,) int64
        Rows of the scored texels, ascending.
    fisher : (m, 6) float64
        The samples' Fisher information on (roughness, specular scale, diffuse scale), the entries
        rr, rk, rd, kk, kd, dd of sum over RGB of w^2 J J^T (`FISHER_ENTRIES`).
    metal_evidence : (m,) float64
        w^2 |f_metal - f_dielectric|^2 summed over RGB.
    """

    texel: np.ndarray
    fisher: np.ndarray
    metal_evidence: np.ndarray


def view_information(capture: Capture, texels: Texels, fit: SurfaceFit, rows: np.ndarray,
                     cameras: Sequence[Camera], sigma: float) -> list[ViewInformation]:
    """Find what each camera adds to the scored texels: Fisher information and metal evidence.

    At each texel the camera samples (`view_samples`: visibility as `freqbrdf.observe.observe`,
    weight w = cos(theta_o)), the specular light in the mirror direction w_r for the texel's
    estimated GGX width alpha is L_alpha = sum_l exp(-(alpha^2 + sigma^2) l^2) L_l(w_r), L_l the
    degree-l part of the environment's SH (`LIGHT_LMAX`). The Fisher information is that of
    f = k s L_alpha + d b (1 - m) E / pi in (roughness, k, d) at k = d = 1, s = 0.04 (1 - m) + b m,
    per channel, summed over RGB, times w^2; the metal evidence
    w^2 |b_metal L_alpha - (b_dielectric E / pi + 0.04 L_alpha)|^2, b the labels' base colours of
    the per-texel estimate (the whole-surface one where a texel has none), E the irradiance.

    Parameters
    ----------
    capture : Capture
        The mesh and the light.
    texels : Texels
        The n scored texels (`subset_texels` of the fit's).
    fit : SurfaceFit
        The fit whose estimate sets alpha, k and the base colours.
    rows : (n,) int64
        The scored texels' rows in the fit.
    cameras : sequence of Camera
        The cameras.
    sigma : float
        The band limit.

    Returns
    -------
    list of ViewInformation
        One per camera, in order.
    """
    solved, per_texel = fit.estimate, fit.per_texel
    roughness = np.clip(np.nan_to_num(solved.roughness[rows], nan=0.5), 0.0, 1.0)
    metallic = np.clip(np.nan_to_num(solved.metallic[rows]), 0.0, 1.0)
    base = np.clip(np.nan_to_num(solved.base_color[rows], nan=0.5), 0.0, 1.0)
    specular = DIELECTRIC_F0 * (1.0 - metallic)[:, None] + base * metallic[:, None]
    diffuse = base * (1.0 - metallic)[:, None]
    if per_texel.label_base_color is not None:
        labels = np.nan_to_num(per_texel.label_base_color[rows], nan=0.5)
        own = per_texel.estimated[rows, None]
        metal_color, dielectric_color = np.where(own, labels[:, 1], base), np.where(own, labels[:, 0], base)
    else:
        metal_color = dielectric_color = base
    lambert = lambert_scale(fit.observations)[rows]
    alpha = alpha_from_roughness(roughness)
    alpha_slope = 2.0 * np.maximum(roughness, np.sqrt(ALPHA_MIN))  # d alpha / d roughness (above the floor)
    degrees = np.arange(LIGHT_LMAX + 1, dtype=np.float64)
    lobe = np.exp(-(alpha[:, None] ** 2 + sigma ** 2) * degrees ** 2)  # (n, L + 1)
    lobe_slope = -2.0 * alpha[:, None] * degrees ** 2 * lobe * alpha_slope[:, None]
    environment = envmaps.envmap_sh(capture.envmap, LIGHT_LMAX)  # (K, 3) world
    bounds = np.concatenate([[0], np.cumsum(2 * degrees.astype(np.int64) + 1)])[:-1]
    result = []
    for texel, cos_theta, mirror in view_samples(capture, texels, cameras):
        basis = sh.eval_sh(mirror, LIGHT_LMAX)  # (m, K)
        by_degree = np.add.reduceat(basis[:, :, None] * environment[None], bounds, axis=1)  # (m, L + 1, 3)
        light = np.einsum("ml,mlc->mc", lobe[texel], by_degree)
        slope = np.einsum("ml,mlc->mc", lobe_slope[texel], by_degree)
        weight_sq = cos_theta ** 2
        # d f / d (roughness, specular scale, diffuse scale) per channel: (m, 3, 3) [parameter, channel]
        jacobian = np.stack([specular[texel] * slope, specular[texel] * light, diffuse[texel] * lambert[texel]], axis=1)
        fisher = weight_sq[:, None] * np.stack(
            [np.einsum("mc,mc->m", jacobian[:, i], jacobian[:, j]) for i, j in _FISHER_PAIRS], axis=1)
        difference = metal_color[texel] * light - (dielectric_color[texel] * lambert[texel] + DIELECTRIC_F0 * light)
        evidence = weight_sq * np.sum(difference ** 2, axis=1)
        result.append(ViewInformation(texel, fisher, evidence))
    return result


def roughness_information(fisher: np.ndarray) -> np.ndarray:
    """Return the information on roughness left once the specular and diffuse scales are fitted.

    The Schur complement I_rr - I_r,n I_nn^-1 I_n,r of the Fisher information on (roughness,
    specular scale k, diffuse scale d): what the samples say about roughness that a brighter lobe
    or a brighter diffuse term cannot also explain, as the estimate's loss (base colour
    re-fitted at each roughness) sees it. Samples from one direction add little of it; samples
    across the lobe do.

    Parameters
    ----------
    fisher : (n, 6) float64
        Entries rr, rk, rd, kk, kd, dd (`ViewInformation`).

    Returns
    -------
    (n,) float64
        The roughness information, >= 0.
    """
    rr, rk, rd, kk, kd, dd = np.moveaxis(np.asarray(fisher, np.float64), -1, 0)
    ridge = _NUISANCE_RIDGE * (kk + dd)
    kk, dd = kk + ridge, dd + ridge
    determinant = kk * dd - kd * kd
    numerator = dd * rk * rk - 2.0 * kd * rk * rd + kk * rd * rd
    explained = np.divide(numerator, determinant, out=np.zeros_like(numerator), where=determinant > 0)
    return np.maximum(rr - explained, 0.0)
