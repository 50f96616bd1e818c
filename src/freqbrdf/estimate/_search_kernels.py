"""The pieces of the global search's numba kernels (docs/method.md#estimation).

The profiled loss of a texel at a roughness, the roughness search, the robust passes' residuals,
the hypotheses' moments and the labels' losses; `freqbrdf.estimate._global_kernels` puts them
together per texel. Target-agnostic numba functions: the CUDA kernels call them too.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from freqbrdf.estimate._profile_kernels import (
    PROBE,
    brent_next,
    brent_seed,
    brent_start,
    metallic_quadratics,
    metallic_terms,
    profile_metallic,
)
from freqbrdf.estimate._records import (
    EnvironmentLight,
    ModelOptions,
    ModelTables,
    PrefilteredLight,
)
from freqbrdf.model._kernels import (
    borrowing_jit,
    environment_node,
    environment_node_lights,
    environment_share,
    fill_kernel,
    prefiltered_nodes_at,
    specular_albedo,
)
from freqbrdf.model.brdf import ALPHA_MIN, DIELECTRIC_F0

# A robust pass scans the roughness nodes within this many cells of the previous optimum.
_ROBUST_NODES = 1
# `global` estimates texels with at least this many samples: 3 n equations for 5 unknowns.
MIN_SAMPLES = 2
# Base colour (3), roughness and metallic: the degrees of freedom a texel's residual loses.
FITTED_PARAMETERS = 5
# The neighbour vote's likelihood-ratio threshold: chi^2 with one degree of freedom at 95 %.
_VOTE_CHI2 = 3.84
# A vote's minimum this close (in grid cells) to its search's bounds lies beyond them: refused.
_VOTE_MARGIN = 0.01
# Texels per parallel work item of the search: amortises the scratch buffers.
_SEARCH_CHUNK = 64
# Brent's absolute tolerance on roughness; its relative part is sqrt(machine eps).
# A grid minimum on the boundary of [0, 1] is kept when the loss rises this far inside, instead of
# letting Brent creep towards the boundary in golden steps.
_BRENT_XTOL = 1e-5
_BRENT_COARSE_XTOL = 1e-3
# Roughness step of the profiled loss's second divided difference (MaterialEstimate.roughness_curvature).
CURVATURE_STEP = 0.05


class Texel(NamedTuple):
    """One texel's n samples of weight > 0, packed (views innermost), and what the search prepared."""

    n: int
    cos_theta: np.ndarray  # (V,) cos theta_o
    omega: np.ndarray  # (V,) each sample's weight in the loss: w^2, or a robust pass's
    proj: np.ndarray  # (3, l*+1, V) the fitted light by degree at the samples (`mirror_projections`)
    values: np.ndarray  # (3, V) the observed radiance
    table_row: np.ndarray  # (V,) int64 each sample's cos theta_o node of the tables
    table_frac: np.ndarray  # (V,) and the fraction towards the next node
    burley_terms: np.ndarray  # (3, 3, V) Burley's factor c0 + r c1 + r^2 c2 per channel
    diffuse_moments: np.ndarray  # (3, 2, 5) `_weighted_sums`
    squared_values: np.ndarray  # (3,) sum omega f^2 per channel
    diffuse_scale: np.ndarray  # (3,) E / pi
    azimuthal: np.ndarray  # (V, 3, P) the environment in each sample's mirrored view frame
    corner: np.ndarray  # (4, V) int64 the prefiltered maps' lookup stencil (`mirror_stencil`)
    stencil_frac: np.ndarray  # (2, V)
    occluded: np.ndarray  # (V,) the share of the sample's mirror lobe that meets the object, not the environment
    surface_light: np.ndarray  # (3, V) the radiance the object shows there
    any_occluded: bool  # some sample is occluded


class Probe(NamedTuple):
    """What a probe of the profiled loss writes: its model terms, scratch and caches per texel."""

    column: np.ndarray  # (3, cos nodes) the split-sum table at the probe's roughness
    kernel: np.ndarray  # (l*+1,) the BRDF kernel
    kernel_derivative: np.ndarray  # (l*+1,)
    albedo: np.ndarray  # (3, V) A, B, E
    diffuse_factor: np.ndarray  # (3, V) D per channel
    own_filtered: np.ndarray  # (V,) the lobe's own light of one channel
    filtered: np.ndarray  # (3, 3, V) per channel X, Y, Z
    moments: np.ndarray  # (3, 14) `metallic_quadratics`' weighted sums
    quadratics: np.ndarray  # (3, 3, 3)
    state: np.ndarray  # (4,) the probe's base colour and metallic
    environment_nodes: np.ndarray  # (environment nodes, 3, 3, V) the environment light per node
    environment_cached: np.ndarray  # (environment nodes,) bool
    prefiltered_nodes: np.ndarray  # (maps, 3, V) the prefiltered light per map node
    prefiltered_cached: np.ndarray  # (maps,) bool
    high_filtered: np.ndarray  # (V,) the degrees above the environment light's, one channel


class Objective(NamedTuple):
    """The profiled loss of one texel as a function of its roughness (`_roughness_objective`)."""

    texel: Texel
    probe: Probe
    options: ModelOptions
    tables: ModelTables
    environment: EnvironmentLight
    prefiltered: PrefilteredLight
    metallic_grid: int


class SearchBuffers(NamedTuple):
    """A chunk's buffers for the roughness search."""

    roughness_grid: int
    best_state: np.ndarray  # (4,) the best probe's base colour and metallic
    brent: np.ndarray  # (13,) Brent's state
    node_loss: np.ndarray  # (roughness_grid,) the loss at the grid's nodes
    sample_weight: np.ndarray  # (V,) w of each packed sample


@borrowing_jit
def _roughness_objective(roughness, objective):
    """Profiled loss at this roughness: min over base colour and metallic (written to state).

    Per sample, only the specular albedo (A, B, E) and the diffuse factor D depend on the roughness
    besides the kernel; their roughness-free parts were prepared per texel
    (`global_search_kernel`).
    """
    texel, probe, options, tables = objective.texel, objective.probe, objective.options, objective.tables
    n, cos_theta, omega, proj, values = texel.n, texel.cos_theta, texel.omega, texel.proj, texel.values
    table_row, table_frac, burley_terms = texel.table_row, texel.table_frac, texel.burley_terms
    diffuse_moments, squared_values, diffuse_scale = texel.diffuse_moments, texel.squared_values, texel.diffuse_scale
    azimuthal, corner, stencil_frac = texel.azimuthal, texel.corner, texel.stencil_frac
    occluded, surface_light, any_occluded = texel.occluded, texel.surface_light, texel.any_occluded
    column, kernel, kernel_derivative, albedo = probe.column, probe.kernel, probe.kernel_derivative, probe.albedo
    diffuse_factor, own_filtered, filtered = probe.diffuse_factor, probe.own_filtered, probe.filtered
    moments, quadratics, state = probe.moments, probe.quadratics, probe.state
    environment_nodes, environment_cached = probe.environment_nodes, probe.environment_cached
    prefiltered_nodes, prefiltered_cached, high_filtered = (probe.prefiltered_nodes, probe.prefiltered_cached,
                                                            probe.high_filtered)
    sigma, fresnel, masking = options.sigma, options.fresnel, options.masking
    split_sum, exact_dielectric = options.split_sum, options.exact_dielectric
    table, table_rows, response = tables.split_sum, tables.split_sum_rows, tables.environment_response
    environment_blend = objective.environment.blend
    prefiltered, n_full = objective.prefiltered.maps, objective.prefiltered.n_full
    metallic_grid = objective.metallic_grid
    # Without the environment (environment light off) the lobes read their own light alone.
    share = environment_share(roughness, environment_blend) if azimuthal.shape[2] > 0 else 0.0
    # Terms with a light of their own: A and B, and E with the exact dielectric (else Z = 0.04 X + Y).
    n_terms = 3 if exact_dielectric else 2
    alpha = max(roughness * roughness, ALPHA_MIN)
    if split_sum:  # the table's column at this roughness, linear in it (from its rows, `split_sum_rows`)
        y = min(max(roughness, 0.0), 1.0) * (table_rows.shape[1] - 1)
        j = min(int(y), table_rows.shape[1] - 2)
        fy = y - j
        for term in range(n_terms):
            for i in range(table_rows.shape[2]):
                column[term, i] = table_rows[term, j, i] * (1.0 - fy) + table_rows[term, j + 1, i] * fy
        if share > 0.0:
            # The environment light at its roughness nodes on either side, each computed once per
            # texel (the search visits few, most of them many times); on a node (the grid's nodes
            # are nodes of the table) the other one is not needed.
            node, node_frac = environment_node(roughness)
            lower_node = node if node_frac < 1.0 else node + 1
            upper_node = node + 1 if node_frac > 0.0 else node
            for needed in range(lower_node, upper_node + 1):
                if not environment_cached[needed]:
                    environment_node_lights(response, needed, n, table_row, table_frac, azimuthal,
                                             environment_nodes[needed])
                    environment_cached[needed] = True
        for s in range(n):
            row, fx = table_row[s], table_frac[s]
            for term in range(n_terms):
                albedo[term, s] = column[term, row] + fx * (column[term, row + 1] - column[term, row])
    else:
        for s in range(n):
            albedo[0, s], albedo[1, s] = specular_albedo(cos_theta[s], roughness, alpha, fresnel, masking, False,
                                                          table)
    if split_sum and not fresnel:
        for s in range(n):
            albedo[0, s] += albedo[1, s]
            albedo[1, s] = 0.0
    # Burley's factor is c0 + r c1 + r^2 c2 per channel and sample (`burley_polynomial`,
    # `environment_burley_terms`); Lambert's is 1.
    for c in range(3):
        for s in range(n):
            diffuse_factor[c, s] = burley_terms[c, 0, s] + roughness * (burley_terms[c, 1, s]
                                                                        + roughness * burley_terms[c, 2, s])
    # The lobe's own light (contiguous, vectorised loops): the fitted light filtered by the kernel,
    # or the prefiltered light. A lobe that reads the environment light alone (share 1) needs none.
    own_light = share < 1.0
    # The prefiltered light replaces the fitted one: its nodes around this roughness, each looked
    # up once per texel.
    use_prefiltered = own_light and n_full > 0
    use_fitted = own_light and n_full == 0
    lower_map = upper_map = lower_high = upper_high = 0
    map_frac = high_frac = 0.0
    if use_prefiltered:
        lower_map, upper_map, map_frac = prefiltered_nodes_at(roughness, 0, n_full, n, prefiltered, corner,
                                                               stencil_frac, prefiltered_nodes, prefiltered_cached)
    # The degrees the environment light leaves out, from the prefiltered maps' last nodes.
    n_high = prefiltered.shape[1] - n_full
    use_high = share > 0.0 and n_high > 0
    if use_high:
        lower_high, upper_high, high_frac = prefiltered_nodes_at(roughness, n_full, n_high, n, prefiltered,
                                                                  corner, stencil_frac, prefiltered_nodes,
                                                                  prefiltered_cached)
    if use_fitted:
        fill_kernel(alpha, sigma, kernel, kernel_derivative)
    # Below, whole indices rather than row views (see `metallic_quadratics`).
    for c in range(3):
        if use_prefiltered:
            for s in range(n):
                lower = prefiltered_nodes[lower_map, c, s]
                own_filtered[s] = lower + map_frac * (prefiltered_nodes[upper_map, c, s] - lower)
        if use_high:
            for s in range(n):
                lower = prefiltered_nodes[lower_high, c, s]
                high_filtered[s] = lower + high_frac * (prefiltered_nodes[upper_high, c, s] - lower)
        if use_fitted:
            k0 = kernel[0]
            for s in range(n):
                own_filtered[s] = k0 * proj[c, 0, s]
            for degree in range(1, kernel.shape[0]):
                k = kernel[degree]
                for s in range(n):
                    own_filtered[s] += k * proj[c, degree, s]
        if own_light and any_occluded:  # the object in the mirror lobe: what it shows there
            for s in range(n):
                own_filtered[s] += occluded[s] * (surface_light[c, s] - own_filtered[s])
        model = filtered
        for term in range(n_terms):
            if own_light:
                for s in range(n):
                    model[c, term, s] = albedo[term, s] * own_filtered[s]
            if share > 0.0:
                frac = node_frac if upper_node != lower_node else 0.0
                keep = 1.0 - share
                for s in range(n):
                    lower = environment_nodes[lower_node, term, c, s]
                    light = lower + frac * (environment_nodes[upper_node, term, c, s] - lower)
                    if use_high:
                        light += high_filtered[s]
                    light *= albedo[term, s]
                    model[c, term, s] = keep * model[c, term, s] + share * light if own_light else light
        if not exact_dielectric:
            for s in range(n):
                model[c, 2, s] = DIELECTRIC_F0 * model[c, 0, s] + model[c, 1, s]
        s_xd = s_yd = s_zd = s_xx = s_xy = s_xz = s_xf = s_yy = s_yz = s_yf = s_zz = s_zf = 0.0
        for s in range(n):
            x, y, z = model[c, 0, s], model[c, 1, s], model[c, 2, s]  # X = A S_A, Y = B S_B, Z = E S_E
            f = values[c, s]
            d = diffuse_factor[c, s]
            wx = omega[s] * x
            wy = omega[s] * y
            wz = omega[s] * z
            s_xd += wx * d
            s_yd += wy * d
            s_zd += wz * d
            s_xx += wx * x
            s_xy += wx * y
            s_xz += wx * z
            s_xf += wx * f
            s_yy += wy * y
            s_yz += wy * z
            s_yf += wy * f
            s_zz += wz * z
            s_zf += wz * f
        s_dd = 0.0
        for power in range(4, -1, -1):
            s_dd = s_dd * roughness + diffuse_moments[c, 0, power]
        s_fd = diffuse_moments[c, 1, 0] + roughness * (diffuse_moments[c, 1, 1] + roughness * diffuse_moments[c, 1, 2])
        for index, total in enumerate((s_xd, s_yd, s_zd, s_xx, s_xy, s_xz, s_xf, s_yy, s_yz, s_yf, s_zz, s_zf, s_dd,
                                       s_fd)):
            moments[c, index] = total
    metallic_quadratics(moments, squared_values, diffuse_scale, quadratics)
    return profile_metallic(quadratics, state, metallic_grid)


@borrowing_jit
def _weighted_sums(n, omega, values, burley_terms, diffuse_moments, squared_values):
    """Compute the roughness-free weighted sums of a texel's samples for `_roughness_objective`.

    Per channel c: sum w^2 D_c^2 as a quartic in r (diffuse_moments[c, 0]) and sum w^2 f_c D_c as
    a quadratic (diffuse_moments[c, 1, :3]) (Burley's D_c = c0 + r c1 + r^2 c2, burley_terms
    (3, 3, n)), and sum w^2 f_c^2 (squared_values). Returns sum w^2.
    """
    diffuse_moments[:] = 0.0
    total_weight = 0.0
    for s in range(n):
        total_weight += omega[s]
    for c in range(3):
        quartic, quadratic = diffuse_moments[c, 0], diffuse_moments[c, 1]
        squared_values[c] = 0.0
        for s in range(n):
            c0, c1, c2 = burley_terms[c, 0, s], burley_terms[c, 1, s], burley_terms[c, 2, s]
            o = omega[s]
            quartic[0] += o * c0 * c0
            quartic[1] += 2.0 * o * c0 * c1
            quartic[2] += o * (c1 * c1 + 2.0 * c0 * c2)
            quartic[3] += 2.0 * o * c1 * c2
            quartic[4] += o * c2 * c2
            of = o * values[c, s]
            quadratic[0] += of * c0
            quadratic[1] += of * c1
            quadratic[2] += of * c2
            squared_values[c] += of * values[c, s]
    return total_weight


@borrowing_jit
def _keep_state(state, best_state):
    """Copy state into best_state element by element.

    A slice assignment may allocate, and these functions run without numba's runtime.
    """
    for i in range(state.shape[0]):
        best_state[i] = state[i]


@borrowing_jit
def _search_roughness(objective, buffers, first_node, last_node, xtol, node_rows, node_moments, node_sums):
    """Search the roughness: scan the grid's nodes first_node..last_node, then Brent in the best cell.

    Brent (to xtol) runs unless the loss rises inwards from a boundary node, and starts from the
    parabola through the best node and its neighbours when the scan holds them. The best evaluation
    seen wins: returns (roughness, loss), its base colour and metallic in buffers.best_state
    (`_roughness_objective` leaves each probe's in objective.probe.state). A node whose node_rows
    entry (`_node_rows`; (0,): none) is a row i >= 0 records its hypothesis moments into
    node_moments[i] (R, 3, 8), with the samples' weights buffers.sample_weight (n,). Where
    node_sums (G, 3, 16) has a row per node (else (0, 3, 16)), each node i writes the weighted sums
    its labels' losses come from into row i (`record_label_sums`).
    """
    state, roughness_grid, best_state = objective.probe.state, buffers.roughness_grid, buffers.best_state
    roughness_brent, node_loss, sample_weight = buffers.brent, buffers.node_loss, buffers.sample_weight
    cell = 1.0 / (roughness_grid - 1)
    best_node, best_r, best_f = first_node, 0.0, np.inf
    for i in range(first_node, last_node + 1):
        r = i / (roughness_grid - 1)
        node_loss[i] = _roughness_objective(r, objective)
        if node_rows.shape[0] > 0 and node_rows[i] >= 0:
            _record_hypothesis(objective, sample_weight, node_moments[node_rows[i]])
        if node_sums.shape[0] > 0:
            record_label_sums(objective, node_sums[i])
        if node_loss[i] < best_f:
            best_node, best_r, best_f = i, r, node_loss[i]
            _keep_state(state, best_state)
    node_r, node_f = best_r, best_f
    on_boundary = best_node == 0 or best_node == roughness_grid - 1
    bracketed = first_node < best_node < last_node
    if bracketed:
        lower_f, upper_f = node_loss[best_node - 1], node_loss[best_node + 1]
        lower_r, upper_r = node_r - cell, node_r + cell
        if lower_f <= upper_f:
            search = brent_seed(roughness_brent, lower_r, upper_r, xtol, node_r, node_f, lower_r, lower_f, upper_r,
                                 upper_f)
        else:
            search = brent_seed(roughness_brent, lower_r, upper_r, xtol, node_r, node_f, upper_r, upper_f, lower_r,
                                 lower_f)
    else:
        search = not on_boundary
        if on_boundary:
            probe = node_r + (_BRENT_XTOL if node_r == 0.0 else -_BRENT_XTOL)
            f = _roughness_objective(probe, objective)
            search = f < node_f
            if f < best_f:
                best_r, best_f = probe, f
                _keep_state(state, best_state)
        if search:
            brent_start(roughness_brent, max(node_r - cell, 0.0), min(node_r + cell, 1.0), xtol)
    return _brent_run(objective, buffers, best_r, best_f, search)


@borrowing_jit
def record_label_sums(objective, out):
    """Write per channel the last probe's 14 `metallic_quadratics` sums, sum w^2 f^2 and the diffuse scale into out (3, 16)."""
    moments, squared_values, scale = objective.probe.moments, objective.texel.squared_values, objective.texel.diffuse_scale
    for c in range(3):
        for index in range(14):
            out[c, index] = moments[c, index]
        out[c, 14] = squared_values[c]
        out[c, 15] = scale[c]


@borrowing_jit
def _brent_run(objective, buffers, best_r, best_f, search):
    """Run Brent's search as started in buffers.brent (if ``search``) on the profiled loss.

    Returns the best (roughness, loss) of it and of (best_r, best_f), its base colour and metallic
    in buffers.best_state.
    """
    state, best_state, roughness_brent = objective.probe.state, buffers.best_state, buffers.brent
    while search:
        f = _roughness_objective(roughness_brent[PROBE], objective)
        if f < best_f:
            best_r, best_f = roughness_brent[PROBE], f
            _keep_state(state, best_state)
        search = brent_next(roughness_brent, f)
    return best_r, best_f


@borrowing_jit
def _record_hypothesis(objective, sample_weight, out):
    """Write per channel the `_specular_moments` of the last probe's metal terms into out (3, 8).

    The terms are those `_roughness_objective` left in objective.probe.filtered; sample_weight (n,).
    """
    n, values, filtered = objective.texel.n, objective.texel.values, objective.probe.filtered
    for c in range(3):
        _specular_moments(n, sample_weight, values[c], filtered[c, 0], filtered[c, 1], out[c])


@borrowing_jit
def _specular_moments(n, sample_weight, values, scale_terms, bias_terms, out):
    """Write [sum w, sum w u, sum w X, sum w u^2, sum w u X, sum w X^2, sum w f, sum w f^2] into out.

    Over samples s < n, with w the sample weight, f the observed radiance, u = f - Y and X, Y a
    metal's specular terms (scale_terms, bias_terms: specular = k X + Y for base colour k).
    """
    out[:] = 0.0
    for s in range(n):
        w = sample_weight[s]
        f = values[s]
        u = f - bias_terms[s]
        x = scale_terms[s]
        out[0] += w
        out[1] += w * u
        out[2] += w * x
        out[3] += w * u * u
        out[4] += w * u * x
        out[5] += w * x * x
        out[6] += w * f
        out[7] += w * f * f


@borrowing_jit
def _residual_magnitudes(n, values, filtered, diffuse_factor, diffuse_scale, params, out):
    """Write |L(w_s) - f_s| over the channels for params [b_rgb, m] into out[s].

    With the per-channel model terms `_roughness_objective` left in filtered (3, 3, n) and
    diffuse_factor at their roughness.
    """
    m = params[3]
    for s in range(n):
        total = 0.0
        for c in range(3):
            x, y, z = filtered[c, 0, s], filtered[c, 1, s], filtered[c, 2, s]
            b = params[c]
            residual = (b * (m * x + (1.0 - m) * diffuse_scale[c] * diffuse_factor[c, s]) + m * y + (1.0 - m) * z
                        - values[c, s])
            total += residual * residual
        out[s] = math.sqrt(total)


@borrowing_jit
def _loss_curvature(best_r, centre_f, objective):
    """Return the profiled loss's second divided difference in roughness.

    Through its value centre_f at best_r and two probes `CURVATURE_STEP` apart on the side within
    [0, 1].
    """
    first_r = best_r + CURVATURE_STEP if best_r < CURVATURE_STEP else best_r - CURVATURE_STEP
    if best_r < CURVATURE_STEP:
        second_r = best_r + 2.0 * CURVATURE_STEP
    elif best_r > 1.0 - CURVATURE_STEP:
        second_r = best_r - 2.0 * CURVATURE_STEP
    else:
        second_r = best_r + CURVATURE_STEP
    first_f = _roughness_objective(first_r, objective)
    second_f = _roughness_objective(second_r, objective)
    return 2.0 * ((first_f - centre_f) / (first_r - best_r) - (second_f - centre_f) / (second_r - best_r)) / (
        first_r - second_r)


@borrowing_jit
def _record_labels(roughness, objective, quadratics, label_state, total_weight, label_loss, label_base_color, probe):
    """Write the loss and base colour of a dielectric (m = 0) and a metal (m = 1) at a roughness.

    Base colour re-fitted (`metallic_terms`): what the samples say about the metal label
    (`freqbrdf.estimate.surface`). With ``probe`` the roughness is probed first (the probe's state
    changes); without, quadratics must hold the last probe's, at that roughness.
    """
    if probe:
        _roughness_objective(roughness, objective)
    for label in range(2):
        label_f = metallic_terms(np.float64(label), quadratics, label_state)[0]
        label_loss[label] = max(label_f, 0.0) / total_weight
        for c in range(3):
            label_base_color[label, c] = label_state[c]
