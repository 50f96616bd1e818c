"""The light a lobe reads: the fitted, the environment and the prefiltered light (docs/method.md#forward-model).

A lobe of roughness r reads one of three lights, or a blend:

- the fitted light: the per-texel SH fit of the mirrored samples (degrees <= l*), low-passed by
  the BRDF kernel (`lobe_filtered_light`), as in docs/method.md#forward-model;
- the environment light of rough lobes: the environment map's own SH (world frame, degrees
  <= 5, unoccluded), read through the lobe's exact response to each harmonic
  (`environment_filtered_light`; `tables.environment_response_table`), plus the map's higher
  degrees from prefiltered maps; its share rises from 0 to 1 over
  ``EstimateConfig.environment_blend`` (`environment_weight`);
- the prefiltered light of smooth lobes: the map itself, filtered by the GGX lobe's per-degree
  gains at roughness nodes `tables.PREFILTER_STEP` apart (`prefiltered_environment`), looked up
  at each sample's world mirror direction (`prefiltered_light`). It replaces the fitted light,
  which cannot hold a smooth lobe's sharp reflections at l* = 5.

Burley's diffuse is averaged over the environment's light too (`environment_burley_factor`).
These numpy versions are written independently of the search kernels, which evaluate the same.
"""

from __future__ import annotations

import functools

import numpy as np

from freqbrdf.model import brdf
from freqbrdf.model._kernels import environment_node, environment_share, prefilter_node, project_degrees_kernel
from freqbrdf.model.tables import (
    ENVIRONMENT_LMAX,
    LOBE_TERMS,
    MIN_LAMBERT,
    PREFILTER_STEP,
    TABLE_COS_NODES,
    burley_diffuse_factor,
    burley_response_table,
    environment_pairs,
    environment_response_table,
    ggx_lobe_gains,
)
from freqbrdf.sphere import envmap as envmaps
from freqbrdf.sphere import harmonics as sh


def environment_filtered_light(directions: np.ndarray, weight: np.ndarray, tangent: np.ndarray, normal: np.ndarray,
                               environment_coeffs: np.ndarray, roughness: np.ndarray, term: str = "scale",
                               azimuthal: np.ndarray | None = None) -> np.ndarray:
    """Return the environment light as one term of a lobe reads it.

    The sum over l, m >= 0 of the lobe's responses (`tables.environment_response_table`, linear in
    cos theta_o) times the environment's coefficients in each sample's mirrored view frame
    (`environment_azimuthal`), at the table's roughness nodes on either side of the roughness and
    interpolated linearly between them (as the split-sum albedo is), as the search does. Written
    with numpy, independently of the kernels.

    Parameters
    ----------
    directions : (n, V, 3) array
        Local view directions (z the normal).
    weight : (n, V) array
        The samples' weights; 0 where unsampled.
    tangent, normal : (n, 3) array
        The world frame of each texel.
    environment_coeffs : (K, 3) array
        The world-frame SH of the environment; degrees up to min(l*, 5) are read.
    roughness : (n,) array
        The lobe's roughness per texel.
    term : str, optional
        One of `tables.LOBE_TERMS`.
    azimuthal : (n, V, 3, P) array, optional
        `environment_azimuthal` of these samples, to reuse across calls.

    Returns
    -------
    (n, V, 3) float64
        The light per sample and channel; 0 where the weight is 0.
    """
    directions = np.asarray(directions, np.float64)
    if azimuthal is None:
        azimuthal = environment_azimuthal(directions, weight, tangent, normal, environment_coeffs)
    table = environment_response_table()[LOBE_TERMS.index(term), :, :, :azimuthal.shape[-1]]  # (nodes, cos, P)
    x = np.clip(directions[..., 2], 0.0, 1.0) * (TABLE_COS_NODES - 1)
    row = np.minimum(x.astype(np.int64), TABLE_COS_NODES - 2)
    fx = x[..., None] - row[..., None]
    node, fy = (np.array(part) for part in zip(*[environment_node(r) for r in np.asarray(roughness, np.float64)]))

    def at_node(nodes):  # (n,) roughness node of each texel -> (n, V, 3)
        response = table[nodes[:, None], row] * (1.0 - fx) + table[nodes[:, None], row + 1] * fx  # (n, V, P)
        return np.einsum("nvp,nvcp->nvc", response, azimuthal)

    fy = fy[:, None, None]
    return (1.0 - fy) * at_node(node) + fy * at_node(node + 1)


def environment_azimuthal(directions: np.ndarray, weight: np.ndarray, tangent: np.ndarray, normal: np.ndarray,
                          environment_coeffs: np.ndarray) -> np.ndarray:
    """Turn the environment's SH into each sample's mirrored view frame.

    The texel's frame (`local_environment`) turned about the normal by the azimuth beta of the
    mirrored view direction (-x, -y): c_lm cos(m beta) + c_l,-m sin(m beta), for degrees
    l <= min(l*, 5) and orders m >= 0.

    Parameters
    ----------
    directions : (n, V, 3) array
        Local view directions (z the normal).
    weight : (n, V) array
        The samples' weights; 0 where unsampled.
    tangent, normal : (n, 3) array
        The world frame of each texel.
    environment_coeffs : (K, 3) array
        The world-frame SH of the environment.

    Returns
    -------
    (n, V, 3, P) float64
        The coefficients, P = `tables.environment_pairs`; 0 where the weight is 0.
    """
    directions = np.asarray(directions, np.float64)
    degrees = min(sh.lmax_of(environment_coeffs.shape[0]), ENVIRONMENT_LMAX)
    local = local_environment(environment_coeffs, tangent, normal, degrees)  # (n, K, 3)
    beta = np.arctan2(-directions[..., 1], -directions[..., 0])[..., None]  # (n, V, 1)
    out = np.empty(directions.shape[:2] + (3, environment_pairs(degrees)))
    pair = 0
    for degree in range(degrees + 1):
        for order in range(degree + 1):
            centre = degree * degree + degree
            out[..., pair] = local[:, None, centre]
            if order > 0:
                out[..., pair] = (local[:, None, centre + order] * np.cos(order * beta)
                                  + local[:, None, centre - order] * np.sin(order * beta))
            pair += 1
    return np.where(np.asarray(weight)[:, :, None, None] > 0.0, out, 0.0)


def local_environment(environment_coeffs: np.ndarray, tangent: np.ndarray, normal: np.ndarray,
                      lmax: int) -> np.ndarray:
    """Turn world-frame SH coefficients into each texel's frame.

    The frame is x tangent, y normal x tangent, z normal; projected with a quadrature exact for
    products of two such harmonics, so exact to rounding.

    Parameters
    ----------
    environment_coeffs : (K, 3) array
        The world-frame SH (at least (lmax + 1)^2 coefficients).
    tangent, normal : (n, 3) array
        Each texel's frame.
    lmax : int
        The highest degree turned.

    Returns
    -------
    (n, (lmax + 1)^2, 3) float64
        The coefficients in each texel's frame.
    """
    directions, weights = sh.sphere_quadrature(2 * lmax)
    tangent, normal = np.asarray(tangent, np.float64), np.asarray(normal, np.float64)
    frames = np.stack([tangent, np.cross(normal, tangent), normal], axis=1)  # (n, 3, 3) rows
    world = np.einsum("qi,nij->nqj", directions, frames)
    values = sh.eval_sh(world, lmax) @ np.asarray(environment_coeffs, np.float64)[: sh.num_coeffs(lmax)]
    return np.einsum("qk,q,nqc->nkc", sh.eval_sh(directions, lmax), weights, values)


@functools.cache
def environment_quadrature(lmax: int) -> tuple[np.ndarray, np.ndarray]:
    """Return `local_environment`'s quadrature, for the kernels.

    Local coefficients = projection @ (the environment at the directions turned to the world).

    Parameters
    ----------
    lmax : int
        The highest degree.

    Returns
    -------
    directions : (Q, 3) float64
        The quadrature's directions.
    projection : ((lmax + 1)^2, Q) float64
        The SH basis times the weights, transposed.
    """
    directions, weights = sh.sphere_quadrature(2 * lmax)
    return np.ascontiguousarray(directions), np.ascontiguousarray((sh.eval_sh(directions, lmax) * weights[:, None]).T)


def environment_weight(roughness: np.ndarray, blend: tuple[float, float]) -> np.ndarray:
    """Return the environment light's share of the light a lobe reads.

    0 up to blend[0], 1 from blend[1], smoothstep between (``EstimateConfig.environment_blend``).

    Parameters
    ----------
    roughness : array
        The lobe's roughness, any shape.
    blend : (float, float)
        Where the share starts to rise and where it reaches 1.

    Returns
    -------
    float64 array
        The share, the shape of ``roughness``.
    """
    roughness = np.asarray(roughness, np.float64)
    return np.array([environment_share(r, blend) for r in roughness.ravel()]).reshape(roughness.shape)


# Larger maps are resampled to this height (degrees up to 510): bounds the memory of the
# prefiltered stack and its transforms.
PREFILTER_MAX_HEIGHT = 512
# A prefiltered map holds the degrees up to the last whose lobe gain is at least this share of the
# largest: beyond it the GGX gains are their table's noise, and the synthesis stops there.
PREFILTER_GAIN_FLOOR = 1e-3


def prefiltered_environment(envmap, n_nodes: int, skip_degrees: int = 0) -> np.ndarray:
    """Filter an environment map by the GGX lobe's gains at the prefiltered roughness nodes.

    The map is filtered by `tables.ggx_lobe_gains` at roughness j `tables.PREFILTER_STEP`, every
    degree the map holds (at most `PREFILTER_MAX_HEIGHT` rows) from ``skip_degrees`` on (the
    environment light holds the degrees below) whose gain is at least `PREFILTER_GAIN_FLOOR` of the
    largest. Node 0, a mirror, is the map itself (averaged in
    pixel space to the stack's size, `envmap.downsample`): cut at the map's band limit it would ring
    around bright lights (Gibbs). The next nodes' lobes are filtered in SH as the rest: read raw as
    well, roughness between them would mix a sharp map into a blurred one.

    Parameters
    ----------
    envmap : Envmap
        The environment map (`freqbrdf.sphere.envmap.Envmap`).
    n_nodes : int
        The number of roughness nodes.
    skip_degrees : int, optional
        Leave out the degrees below this.

    Returns
    -------
    (n_nodes, H, W, 3) float32
        The filtered maps, H at most `PREFILTER_MAX_HEIGHT`, W = 2 H.
    """
    height, width = envmap.radiance.shape[:2]
    out_height = min(height, PREFILTER_MAX_HEIGHT, (width + 1) // 2)
    lmax = min(height - 2, (width - 1) // 2, out_height - 2)
    gains = np.stack([ggx_lobe_gains(node * PREFILTER_STEP, lmax) for node in range(n_nodes)])
    magnitude = np.abs(gains)
    held = magnitude >= PREFILTER_GAIN_FLOOR * magnitude.max(axis=1, keepdims=True)
    last = lmax - np.argmax(held[:, ::-1], axis=1)  # (n_nodes,) the last degree held
    gains[np.arange(lmax + 1)[None, :] > last[:, None]] = 0.0
    gains[:, :skip_degrees] = 0.0
    resample = out_height if out_height != height else None
    maps = np.empty((n_nodes, out_height, 2 * out_height, 3), np.float32)
    if n_nodes > 1:
        maps[1:] = envmaps.zonal_filters(envmap, gains[1:], resample)
    maps[0] = envmaps.downsample(envmap.radiance, out_height)
    if skip_degrees > 0:  # less the degrees below skip_degrees: smooth, so exact in SH
        low_pass = (np.arange(lmax + 1) < skip_degrees).astype(np.float64)[None]
        maps[0] -= envmaps.zonal_filters(envmap, low_pass, resample)[0]
    return maps


def prefiltered_light(directions: np.ndarray, tangent: np.ndarray, normal: np.ndarray, prefiltered: np.ndarray,
                      rotation: np.ndarray, roughness: np.ndarray) -> np.ndarray:
    """Return the prefiltered light a lobe reads, as the search reads it.

    Looked up bilinearly at the world mirror directions and linear in roughness between the maps'
    nodes. Written with numpy, independently of the kernels.

    Parameters
    ----------
    directions : (n, V, 3) array
        Local view directions (z the normal).
    tangent, normal : (n, 3) array
        The world frame of each texel.
    prefiltered : (nodes, H, W, 3) array
        `prefiltered_environment` of the map.
    rotation : (3, 3) array
        The map's emitter-to-world rotation.
    roughness : (n,) array
        The lobe's roughness per texel.

    Returns
    -------
    (n, V, 3) float64
        The light per sample and channel.
    """
    directions = np.asarray(directions, np.float64)
    tangent, normal = np.asarray(tangent, np.float64), np.asarray(normal, np.float64)
    bitangent = np.cross(normal, tangent)
    mirror = directions * np.array([-1.0, -1.0, 1.0])
    world = (mirror[..., :1] * tangent[:, None] + mirror[..., 1:2] * bitangent[:, None]
             + mirror[..., 2:] * normal[:, None])
    cos_theta = np.clip(mirror[..., 2], 0.0, 1.0)
    n_nodes, height, width = prefiltered.shape[:3]

    def texel_coordinates(where: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # as envmap.map_coordinates
        local = where @ np.asarray(rotation, np.float64)
        u = np.arctan2(local[..., 0], -local[..., 2]) / (2.0 * np.pi)
        return (u - np.floor(u)) * width - 0.5, np.arccos(np.clip(local[..., 1], -1.0, 1.0)) / np.pi * (height - 1)

    def bilinear(nodes: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:  # as envmap.stencil_at
        column = np.floor(x)
        col0 = column.astype(np.int64) % width
        col1, fx = (col0 + 1) % width, (x - column)[..., None]
        y = np.clip(y, 0.0, height - 1.0)
        row0 = np.minimum(y.astype(np.int64), height - 2)
        fy = (y - row0)[..., None]

        def texel(row, col):
            return prefiltered[nodes, row, col].astype(np.float64)

        top = (1.0 - fx) * texel(row0, col0) + fx * texel(row0, col1)
        bottom = (1.0 - fx) * texel(row0 + 1, col0) + fx * texel(row0 + 1, col1)
        return (1.0 - fy) * top + fy * bottom

    x, y = texel_coordinates(world)  # of the mirror direction
    roughness = np.broadcast_to(np.asarray(roughness, np.float64)[:, None], cos_theta.shape)
    node, frac = np.vectorize(lambda r: prefilter_node(r, n_nodes), otypes=[np.int64, np.float64])(roughness)
    lower, upper = bilinear(node, x, y), bilinear(node + 1, x, y)
    return lower + frac[..., None] * (upper - lower)


def lobe_filtered_light(directions: np.ndarray, weight: np.ndarray, light_coeffs: np.ndarray, lmax: int,
                        sigma: float, roughness: np.ndarray) -> np.ndarray:
    """Return the fitted light as the split-sum model filters it for a lobe.

    The SH fit of the mirrored light, low-passed by the BRDF kernel (`brdf.brdf_kernel`) and read
    in the mirror direction.

    Parameters
    ----------
    directions : (n, V, 3) array
        Local view directions (z the normal).
    weight : (n, V) array
        The samples' weights; 0 where unsampled.
    light_coeffs : (n, 3, K) array
        The SH fit of the mirrored light.
    lmax : int
        l*.
    sigma : float
        The band limit's width (`brdf.band_limit_sigma`).
    roughness : (n,) array
        The lobe's roughness per texel.

    Returns
    -------
    (n, V, 3) float64
        The light per sample and channel; 0 where the weight is 0.
    """
    alpha = brdf.alpha_from_roughness(np.asarray(roughness, np.float64))
    kernel = brdf.brdf_kernel(alpha, lmax, sigma)  # (n, l*+1)
    return np.einsum("nl,nclv->nvc", kernel, mirror_projections(directions, weight, light_coeffs, lmax))


def mirror_projections(directions, weight, coeffs, lmax) -> np.ndarray:
    """Expand the light by degree at the view directions, normalised in float64 as the search does.

    Parameters
    ----------
    directions : (n, V, 3) array
        View directions; unsampled ones may be (0, 0, 0).
    weight : (n, V) array
        The samples' weights; 0 where unsampled.
    coeffs : (n, 3, K) array
        The light's SH fit.
    lmax : int
        l*.

    Returns
    -------
    (n, 3, l*+1, V) float32
        `degree_projections` at the unit directions.
    """
    directions = np.asarray(directions, dtype=np.float64)
    unit = directions / np.maximum(np.linalg.norm(directions, axis=-1, keepdims=True), 1e-12)  # unsampled: (0, 0, 0)
    return degree_projections(unit, weight, coeffs, lmax)


def degree_projections(directions: np.ndarray, weight: np.ndarray, coeffs: np.ndarray, lmax: int) -> np.ndarray:
    """Expand SH coefficients by degree at the samples: P_c,l(w_v) = sum_m c_c,lm Y_lm(w_v).

    Parameters
    ----------
    directions : (n, V, 3) array
        Unit directions.
    weight : (n, V) array
        The samples' weights; samples of weight 0 are skipped (no estimator reads them).
    coeffs : (n, 3, K) array
        The SH coefficients per texel and channel.
    lmax : int
        l*.

    Returns
    -------
    (n, 3, l*+1, V) float32
        The projections; 0 where the weight is 0.
    """
    basis = sh.eval_sh(np.ascontiguousarray(directions, dtype=np.float32), lmax)  # (n, V, K)
    out = np.empty((directions.shape[0], 3, lmax + 1, directions.shape[1]), dtype=np.float32)
    project_degrees_kernel(basis, weight, np.ascontiguousarray(coeffs, dtype=np.float32), out)
    return out


def environment_burley_factor(directions: np.ndarray, weight: np.ndarray, tangent: np.ndarray, normal: np.ndarray,
                              environment_coeffs: np.ndarray, roughness: np.ndarray,
                              azimuthal: np.ndarray | None = None) -> np.ndarray:
    """Return Burley's diffuse relative to Lambert's under the environment's own light.

    Degrees <= min(l*, 3) of the light (`tables.burley_response_table`, linear in cos theta_o), per
    channel: what `tables.burley_diffuse_factor` gives under uniform light. Where a channel's
    Lambert response is not positive (a map with no light there), the uniform-light factor. Written
    with numpy, independently of the kernels.

    Parameters
    ----------
    directions : (n, V, 3) array
        Local view directions (z the normal).
    weight : (n, V) array
        The samples' weights; 0 where unsampled.
    tangent, normal : (n, 3) array
        The world frame of each texel.
    environment_coeffs : (K, 3) array
        The world-frame SH of the environment.
    roughness : (n,) array
        The roughness per texel.
    azimuthal : (n, V, 3, P) array, optional
        `environment_azimuthal` of these samples, to reuse across calls.

    Returns
    -------
    (n, V, 3) float64
        The factor per sample and channel; 0 where the weight is 0.
    """
    directions = np.asarray(directions, np.float64)
    if azimuthal is None:
        azimuthal = environment_azimuthal(directions, weight, tangent, normal, environment_coeffs)
    table = burley_response_table()
    pairs = min(table.shape[-1], azimuthal.shape[-1])
    table, azimuthal = table[..., :pairs], azimuthal[..., :pairs]
    x = np.clip(directions[..., 2], 0.0, 1.0) * (TABLE_COS_NODES - 1)
    row = np.minimum(x.astype(np.int64), TABLE_COS_NODES - 2)
    fx = (x - row)[..., None]
    response = table[:, row] * (1.0 - fx) + table[:, row + 1] * fx  # (4, n, V, P)
    parts = np.einsum("jnvp,nvcp->jnvc", response, azimuthal)
    roughness = np.asarray(roughness, np.float64)[:, None, None]
    lambert = parts[3]
    burley = parts[0] + roughness * (parts[1] + roughness * parts[2])
    uniform = burley_diffuse_factor(directions[..., 2], roughness[..., 0])[..., None]
    factor = np.where(lambert > MIN_LAMBERT * np.abs(azimuthal[..., 0]), burley / np.where(lambert > 0.0, lambert,
                                                                                               1.0), uniform)
    return np.where(np.asarray(weight)[:, :, None] > 0.0, factor, 0.0)
