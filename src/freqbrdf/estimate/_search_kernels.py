"""The global search's numba kernels (METHOD.md §3.7).

The profiled loss of a texel at a roughness, the roughness search, the robust passes, the
neighbour vote and the hypotheses' moments, and the model's squared residual.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
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
    azimuthal_coefficients,
    borrowing_jit,
    cross,
    environment_burley_terms,
    environment_node,
    environment_node_lights,
    environment_share,
    fill_kernel,
    mirror_stencil,
    n_sh_degrees,
    prefiltered_nodes_at,
    specular_albedo,
    texel_environment,
    uniform_burley_terms,
)
from freqbrdf.model.brdf import ALPHA_MIN, DIELECTRIC_F0
from freqbrdf.model.tables import (
    ENVIRONMENT_NODES,
)
from freqbrdf.sphere import harmonics as sh

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
def _search_roughness(objective, buffers, first_node, last_node, xtol, node_rows, node_moments):
    """Search the roughness: scan the grid's nodes first_node..last_node, then Brent in the best cell.

    Brent (to xtol) runs unless the loss rises inwards from a boundary node, and starts from the
    parabola through the best node and its neighbours when the scan holds them. The best evaluation
    seen wins: returns (roughness, loss), its base colour and metallic in buffers.best_state
    (`_roughness_objective` leaves each probe's in objective.probe.state). A node whose node_rows
    entry (`_node_rows`; (0,): none) is a row i >= 0 records its hypothesis moments into
    node_moments[i] (R, 3, 8), with the samples' weights buffers.sample_weight (n,).
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


@numba.njit(parallel=True, fastmath=True, cache=True)
def global_search_kernel(samples, light, recurrence, options, tables, environment, prefiltered, settings, hypotheses,
                         candidate, estimates):
    """Find per texel the (base colour, roughness, metallic) of least weighted squared residual (numba).

    samples (`Samples`, n texels): the local view directions, weights, observations, E / pi and
    frames; light (n, 3, K) float32 the incoming light's SH fit, expanded by degree at the samples
    with recurrence (`ShRecurrence`) unless prefiltered maps replace it; options and tables
    (`ModelOptions`, `ModelTables`) the model. With an environment (`EnvironmentLight`, K > 0) the
    environment light is blended in over its blend, and with a Burley response of P > 0 harmonics
    Burley's diffuse is averaged over that light. With prefiltered maps (`PrefilteredLight`), smooth
    lobes read them at the world mirror directions. Then the roughness is searched if
    settings.search (`SearchSettings`). With hypotheses (`Hypotheses`, R > 0): their moments
    (`estimate.hypothesis_moments`) into hypotheses.moments, those on the grid's nodes (node_rows)
    recorded by the search's first scan, the others probed before it. With candidate (n, 2)
    (roughness, metallic) instead of a search, the neighbour vote (``EstimateConfig.neighbour_vote``)
    on the estimate in estimates.params. Writes estimates (`Estimates`): params (n, 5) [b_rgb, r, m],
    loss (n,) (divided by sum_v w^2) and the profiled loss's curvature in roughness (n,)
    (`MaterialEstimate.roughness_curvature`) for texels with at least `MIN_SAMPLES` samples, and
    after a search, where estimates.label_loss has rows, the loss and base colour as a dielectric
    (m = 0) and as a metal (m = 1) at the estimated roughness; others are left untouched.
    """
    n_chunks = (samples.weight.shape[0] + _SEARCH_CHUNK - 1) // _SEARCH_CHUNK
    # numba hands each thread a contiguous run of items: where the texels the cameras see lie in
    # one half of the texture, the other thread would wait: the chunks are taken scattered.
    stride = scattering_stride(n_chunks)
    for item in numba.prange(n_chunks):
        # np.int64: the loop index is unsigned in numba's parallel code and signed when typed: one
        # signature, not two (each compiles the whole search).
        chunk = (np.int64(item) * stride) % n_chunks
        _global_search_chunk(chunk, samples, light, recurrence, options, tables, environment, prefiltered, settings,
                             hypotheses, candidate, estimates)


@numba.njit(cache=True)
def scattering_stride(n_items):
    """Return a stride coprime to n_items near the golden section of it (numba).

    Item i -> (i stride) mod n_items visits every item once and spreads any contiguous run of i over
    the whole range: parallel work items taken in this order give every thread a share of each part
    of the texture.

    Parameters
    ----------
    n_items : int
        The number of items, at least 1.

    Returns
    -------
    int64
        The stride.
    """
    stride = max(int(n_items * 0.6180339887), 1)
    while math.gcd(stride, n_items) != 1:
        stride += 1
    return np.int64(stride)


@borrowing_jit
def _record_labels(roughness, objective, quadratics, label_state, total_weight, label_loss, label_base_color):
    """Write the loss and base colour of a dielectric (m = 0) and a metal (m = 1) at a roughness.

    Base colour re-fitted (`metallic_terms`): what the samples say about the metal label
    (`freqbrdf.estimate.surface`). Probes the roughness, so the probe's state changes.
    """
    _roughness_objective(roughness, objective)
    for label in range(2):
        label_f = metallic_terms(np.float64(label), quadratics, label_state)[0]
        label_loss[label] = max(label_f, 0.0) / total_weight
        for c in range(3):
            label_base_color[label, c] = label_state[c]


@numba.njit(fastmath=True, cache=True)
def _global_search_chunk(chunk, samples, light, recurrence, options, tables, environment_light, prefiltered_light,
                         settings, hypotheses, candidate, estimates):
    """Do `global_search_kernel`'s work for the texels of one chunk.

    A function of its own, so that numba's parallel passes see a small loop (on the whole body they
    take much of the kernel's compile time).
    """
    directions, weight, observed = samples.view_direction, samples.weight, samples.observed
    diffuse_scale, tangent, normal = samples.diffuse_scale, samples.tangent, samples.normal
    lmax, diag, rec_a, rec_b = recurrence.lmax, recurrence.diag, recurrence.rec_a, recurrence.rec_b
    burley = options.burley
    table, burley_response = tables.split_sum, tables.burley_response
    environment = environment_light.coeffs
    quadrature, quadrature_projection = environment_light.quadrature, environment_light.projection
    prefiltered, n_full = prefiltered_light.maps, prefiltered_light.n_full
    world_to_local, map_height, map_width = prefiltered_light.world_to_local, prefiltered_light.height, prefiltered_light.width
    roughness_grid, metallic_grid = settings.roughness_grid, settings.metallic_grid
    robust_passes, search = settings.robust_passes, settings.search
    hypothesis_roughness, hypothesis_moments, node_rows = hypotheses.roughness, hypotheses.moments, hypotheses.node_rows
    params, loss, curvature = estimates.params, estimates.loss, estimates.curvature
    label_loss, label_base_color = estimates.label_loss, estimates.label_base_color
    n_texels, n_views = weight.shape
    n_degrees = lmax + 1
    n_coeffs = n_degrees * n_degrees
    # The texel's samples with w > 0, packed and with the views innermost (vectorised loops).
    xyz = np.empty((3, n_views))
    unit = np.empty((3, n_views))
    basis = np.empty((n_coeffs, n_views))
    sh_scratch = np.empty((5, n_views))
    packed_cos = np.empty(n_views)
    omega = np.empty(n_views)  # w^2
    packed_proj = np.empty((3, n_degrees, n_views))
    values = np.empty((3, n_views))
    table_row = np.empty(n_views, dtype=np.int64)
    table_frac = np.empty(n_views)
    burley_terms = np.empty((3, 3, n_views))  # per channel, power of r and sample
    diffuse_moments = np.empty((3, 2, 5))  # per channel: sum w^2 D^2 (quartic in r), sum w^2 f D (quadratic)
    column = np.empty((table.shape[0], table.shape[1]))
    albedo = np.empty((3, n_views))  # A, B, E
    diffuse_factor = np.empty((3, n_views))
    own_filtered = np.empty(n_views)  # the lobe's own light of one channel
    filtered = np.empty((3, 3, n_views))  # per channel X, Y, Z
    sample_weight = np.empty(n_views)  # w
    residual = np.empty(n_views)
    kernel = np.empty(n_degrees)
    kernel_derivative = np.empty(n_degrees)
    moments = np.empty((3, 14))  # `metallic_quadratics`' weighted sums
    quadratics = np.empty((3, 3, 3))
    squared_values = np.empty(3)  # sum_v w^2 f^2 per channel
    scale = np.empty(3)
    state = np.empty(4)
    best_state = np.empty(4)
    label_state = np.empty(4)
    roughness_brent = np.empty(13)
    node_loss = np.empty(roughness_grid)
    # The hypotheses the first scan records: the others are probed before the search.
    scanned = np.zeros(hypothesis_roughness.shape[0], dtype=np.bool_)
    for node in range(node_rows.shape[0]):
        if node_rows[node] >= 0:
            scanned[node_rows[node]] = True
    no_rows = np.full(0, -1, dtype=np.int64)
    no_moments = np.zeros((0, 3, 8))
    # The environment in the texel's frame, then in each sample's mirrored view frame.
    n_points = quadrature.shape[0]
    local_environment = np.empty((environment.shape[0], 3))
    quadrature_world = np.empty((3, n_points))
    quadrature_basis = np.empty((environment.shape[0], n_points))
    quadrature_scratch = np.empty((5, n_points))
    quadrature_values = np.empty((3, n_points))
    n_environment_degrees = n_sh_degrees(environment.shape[0])
    azimuthal = np.zeros((n_views, 3, n_environment_degrees * (n_environment_degrees + 1) // 2))
    # The environment light per roughness node, lobe term, channel and sample.
    environment_nodes = np.empty((ENVIRONMENT_NODES, 3, 3, n_views))
    environment_cached = np.zeros(ENVIRONMENT_NODES, dtype=np.bool_)
    bitangent = np.empty(3)
    # The prefiltered light per map node, channel and sample, and each sample's lookup stencil.
    n_prefiltered = prefiltered.shape[1]
    prefiltered_nodes = np.empty((n_prefiltered, 3, n_views))
    prefiltered_cached = np.zeros(n_prefiltered, dtype=np.bool_)
    corner = np.empty((4, n_views), dtype=np.int64)
    stencil_frac = np.empty((2, n_views))
    high_filtered = np.empty(n_views)
    probe = Probe(column, kernel, kernel_derivative, albedo, diffuse_factor, own_filtered, filtered, moments,
                  quadratics, state, environment_nodes, environment_cached, prefiltered_nodes, prefiltered_cached,
                  high_filtered)
    buffers = SearchBuffers(roughness_grid, best_state, roughness_brent, node_loss, sample_weight)
    for t in range(chunk * _SEARCH_CHUNK, min((chunk + 1) * _SEARCH_CHUNK, n_texels)):
        # np.int64, np.bool_ and below: a literal constant where a variable goes (here into a record)
        # makes numba compile the callee once more for the literal's type.
        n = np.int64(0)
        for v in range(n_views):
            w = np.float64(weight[t, v])
            if w <= 0.0:
                continue
            for axis in range(3):
                xyz[axis, n] = directions[t, v, axis]
            packed_cos[n] = xyz[2, n]
            omega[n] = w * w
            sample_weight[n] = w
            for c in range(3):
                values[c, n] = observed[t, v, c]
            n += 1
        if n < MIN_SAMPLES:
            continue
        # The neighbour vote (below) concerns only texels whose candidate roughness or metallic
        # lies more than a grid cell away: the others skip the preparation too.
        voting = candidate.shape[0] > 0
        far_roughness = voting and abs(candidate[t, 0] - params[t, 3]) * (roughness_grid - 1) > 1.0
        far_metallic = voting and abs(candidate[t, 1] - params[t, 4]) * (metallic_grid - 1) > 1.0
        if voting and not ((far_roughness or far_metallic) and 3 * n > FITTED_PARAMETERS):
            continue
        cross(normal[t], tangent[t], bitangent)
        prefiltered_cached[:] = False
        if n_full > 0:
            mirror_stencil(xyz, n, tangent[t], normal[t], bitangent, world_to_local, map_height, map_width,
                            corner, stencil_frac)
        if n_full == 0:  # the fitted light, expanded by degree at the (normalised) view directions
            for s in range(n):
                norm = math.sqrt(xyz[0, s] ** 2 + xyz[1, s] ** 2 + xyz[2, s] ** 2)
                for axis in range(3):
                    unit[axis, s] = xyz[axis, s] / norm
            sh._sh_block(unit[0], unit[1], unit[2], n, lmax, diag, rec_a, rec_b, basis, sh_scratch)
            for c in range(3):
                for degree in range(n_degrees):
                    for s in range(n):
                        packed_proj[c, degree, s] = 0.0
                    for k in range(degree * degree, (degree + 1) * (degree + 1)):
                        coefficient = np.float64(light[t, c, k])
                        for s in range(n):
                            packed_proj[c, degree, s] += coefficient * basis[k, s]
        environment_cached[:] = False
        if environment.shape[0] > 0:
            texel_environment(environment, tangent[t], normal[t], bitangent, quadrature, quadrature_projection,
                               diag, rec_a, rec_b, quadrature_world, quadrature_basis, quadrature_scratch,
                               quadrature_values, local_environment)
            azimuthal_coefficients(xyz, n, local_environment, azimuthal)
        for s in range(n):
            x = min(max(packed_cos[s], 0.0), 1.0) * (table.shape[1] - 1)
            table_row[s] = min(int(x), table.shape[1] - 2)
            table_frac[s] = x - table_row[s]
            uniform_burley_terms(packed_cos[s], burley, burley_terms[:, :, s])
        if burley and burley_response.shape[2] > 0 and environment.shape[0] > 0:
            environment_burley_terms(n, table_row, table_frac, azimuthal, burley_response, burley_terms)
        total_weight = _weighted_sums(n, omega, values, burley_terms, diffuse_moments, squared_values)
        for c in range(3):
            scale[c] = diffuse_scale[t, c]
        texel = Texel(n, packed_cos, omega, packed_proj, values, table_row, table_frac, burley_terms, diffuse_moments,
                      squared_values, scale, azimuthal, corner, stencil_frac)
        objective = Objective(texel, probe, options, tables, environment_light, prefiltered_light, metallic_grid)
        for i in range(hypothesis_roughness.shape[0]):
            if not scanned[i]:
                _roughness_objective(hypothesis_roughness[i], objective)
                _record_hypothesis(objective, sample_weight, hypothesis_moments[t, i])
        if voting:
            # The neighbour vote. A likelihood-ratio test bounds what it may cost: the profiled
            # least-squares loss may exceed the estimate's by _VOTE_CHI2 times the noise variance
            # (the residual over its 3n - FITTED_PARAMETERS degrees of freedom). Roughness: a
            # local minimum within a grid cell of the candidate (Brent, not at its bounds, over a
            # cell from the estimate: another minimum). Then metallic: the candidate's, base
            # colour profiled, at the roughness kept.
            estimate_r = params[t, 3]
            estimate_f = _roughness_objective(estimate_r, objective)
            limit = estimate_f + _VOTE_CHI2 * estimate_f / (3 * n - FITTED_PARAMETERS)
            voted_r = estimate_r
            if far_roughness:
                cell = 1.0 / (roughness_grid - 1)
                lower, upper = max(candidate[t, 0] - cell, 0.0), min(candidate[t, 0] + cell, 1.0)
                brent_start(roughness_brent, lower, upper, _BRENT_XTOL)
                local_r, local_f = _brent_run(objective, buffers, 0.0, np.inf, np.bool_(True))
                margin = _VOTE_MARGIN * cell
                interior = ((local_r - lower > margin or lower == 0.0)
                            and (upper - local_r > margin or upper == 1.0))
                if interior and abs(local_r - estimate_r) > cell and local_f <= limit:
                    voted_r = local_r
            profiled_f = _roughness_objective(voted_r, objective)  # state: its base colour, metallic
            voted_f = profiled_f
            metallic_voted = False
            if abs(candidate[t, 1] - state[3]) * (metallic_grid - 1) > 1.0:
                # Into best_state, so that state keeps the profiled fit if the test refuses it.
                fixed_f = metallic_terms(candidate[t, 1], quadratics, best_state)[0]
                if fixed_f <= limit:
                    voted_f = fixed_f
                    _keep_state(best_state, state)
                    metallic_voted = True
            if voted_r == estimate_r and not metallic_voted:
                continue  # the estimate stands
            params[t, 0], params[t, 1], params[t, 2] = state[0], state[1], state[2]
            params[t, 3], params[t, 4] = voted_r, state[3]
            loss[t] = max(voted_f, 0.0) / total_weight
            curvature[t] = _loss_curvature(voted_r, profiled_f, objective) / total_weight
            if label_loss.shape[0] > 0 and voted_r != estimate_r:
                _record_labels(voted_r, objective, quadratics, label_state, total_weight, label_loss[t],
                               label_base_color[t])
            continue
        if not search:
            continue
        # A robust pass refines the roughness to _BRENT_XTOL: this search need only find its cell.
        first_xtol = _BRENT_COARSE_XTOL if robust_passes > 0 else _BRENT_XTOL
        best_r, best_f = _search_roughness(objective, buffers, np.int64(0), roughness_grid - 1, first_xtol, node_rows,
                                           hypothesis_moments[t] if node_rows.shape[0] > 0 else no_moments)
        if robust_passes > 0:
            # Towards the paper's L1 loss sum_v w |r_v| (IRLS): weight each sample by
            # w / max(|r|, delta), delta a tenth of the texel's mean |r| so that near-exact
            # samples do not take over, and search again.
            for _ in range(robust_passes):
                best_f = _roughness_objective(best_r, objective)
                best_state[:] = state
                _residual_magnitudes(n, values, filtered, diffuse_factor, scale, best_state, residual)
                weighted_residual = weight_sum = 0.0
                for s in range(n):
                    weighted_residual += sample_weight[s] * residual[s]
                    weight_sum += sample_weight[s]
                floor = 0.1 * weighted_residual / weight_sum
                if not floor > 0.0:
                    break  # an exact fit: nothing to re-weight
                for s in range(n):
                    omega[s] = sample_weight[s] / max(residual[s], floor)
                _weighted_sums(n, omega, values, burley_terms, diffuse_moments, squared_values)
                # Re-weighting moves the optimum locally: scan the nodes within one cell of it.
                node = int(round(best_r * (roughness_grid - 1)))
                best_r, best_f = _search_roughness(objective, buffers, max(node - _ROBUST_NODES, 0),
                                                   min(node + _ROBUST_NODES, roughness_grid - 1), _BRENT_XTOL,
                                                   no_rows, no_moments)
            for s in range(n):  # back to least squares for the curvature
                omega[s] = sample_weight[s] * sample_weight[s]
            _weighted_sums(n, omega, values, burley_terms, diffuse_moments, squared_values)
            # The profiled least-squares loss at the optimum for the curvature (the robust
            # pass's best_f is not profiled). The model terms this probe leaves in filtered do
            # not depend on the weights, so they also give the reported loss: the weighted
            # squared residual of the robust estimate (best_state), `MaterialEstimate.loss`.
            centre_f = _roughness_objective(best_r, objective)
            _residual_magnitudes(n, values, filtered, diffuse_factor, scale, best_state, residual)
            best_f = 0.0
            for s in range(n):
                best_f += sample_weight[s] * sample_weight[s] * residual[s] * residual[s]
        else:
            centre_f = best_f
        curvature[t] = _loss_curvature(best_r, centre_f, objective) / total_weight
        params[t, 0], params[t, 1], params[t, 2] = best_state[0], best_state[1], best_state[2]
        params[t, 3], params[t, 4] = best_r, best_state[3]
        loss[t] = max(best_f, 0.0) / total_weight
        if label_loss.shape[0] > 0:
            _record_labels(best_r, objective, quadratics, label_state, total_weight, label_loss[t],
                           label_base_color[t])
