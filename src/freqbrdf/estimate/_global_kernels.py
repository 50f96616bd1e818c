"""The global search's kernel entry points (docs/method.md#estimation): per texel, and on the CPU in parallel.

`search_texel` does one texel's whole search with the scratch of a `SearchScratch`
(`new_search_scratch`): the CPU's `global_search_kernel` runs it texel by texel in parallel chunks,
the CUDA kernel (`freqbrdf.estimate._cuda_kernels`) one thread per texel. The pieces it calls
(the profiled loss, the roughness search, the robust passes, the neighbour vote) are in
`freqbrdf.estimate._search_kernels`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from freqbrdf.estimate._profile_kernels import brent_start, metallic_terms
from freqbrdf.estimate._search_kernels import (
    _BRENT_COARSE_XTOL,
    _BRENT_XTOL,
    _ROBUST_NODES,
    _SEARCH_CHUNK,
    _VOTE_CHI2,
    _VOTE_MARGIN,
    FITTED_PARAMETERS,
    MIN_SAMPLES,
    Objective,
    Probe,
    SearchBuffers,
    Texel,
    _brent_run,
    _keep_state,
    _loss_curvature,
    _record_hypothesis,
    _record_labels,
    _residual_magnitudes,
    _roughness_objective,
    _search_roughness,
    _weighted_sums,
    record_label_sums,
)
from freqbrdf.model._kernels import (
    azimuthal_coefficients,
    cross,
    environment_burley_terms,
    mirror_stencil,
    n_sh_degrees,
    texel_environment,
    uniform_burley_terms,
)
from freqbrdf.model.tables import ENVIRONMENT_NODES
from freqbrdf.sphere import harmonics as sh


class SearchScratch(NamedTuple):
    """One thread's scratch arrays of the search (`new_search_scratch`); the views innermost."""

    xyz: np.ndarray
    unit: np.ndarray
    basis: np.ndarray
    sh_scratch: np.ndarray
    packed_cos: np.ndarray
    omega: np.ndarray  # w^2
    packed_proj: np.ndarray
    values: np.ndarray
    table_row: np.ndarray
    table_frac: np.ndarray
    burley_terms: np.ndarray  # per channel, power of r and sample
    diffuse_moments: np.ndarray  # per channel: sum w^2 D^2 (quartic in r), sum w^2 f D (quadratic)
    column: np.ndarray
    albedo: np.ndarray  # A, B, E
    diffuse_factor: np.ndarray
    own_filtered: np.ndarray  # the lobe's own light of one channel
    filtered: np.ndarray  # per channel X, Y, Z
    sample_weight: np.ndarray  # w
    residual: np.ndarray
    kernel: np.ndarray
    kernel_derivative: np.ndarray
    moments: np.ndarray  # `metallic_quadratics`' weighted sums
    quadratics: np.ndarray
    squared_values: np.ndarray  # sum_v w^2 f^2 per channel
    scale: np.ndarray
    state: np.ndarray
    best_state: np.ndarray
    label_state: np.ndarray
    roughness_brent: np.ndarray
    node_loss: np.ndarray
    scanned: np.ndarray
    no_rows: np.ndarray
    no_moments: np.ndarray
    no_sums: np.ndarray
    local_environment: np.ndarray
    quadrature_world: np.ndarray
    quadrature_basis: np.ndarray
    quadrature_scratch: np.ndarray
    quadrature_values: np.ndarray
    azimuthal: np.ndarray
    environment_nodes: np.ndarray
    environment_cached: np.ndarray
    bitangent: np.ndarray
    prefiltered_nodes: np.ndarray
    prefiltered_cached: np.ndarray
    corner: np.ndarray
    stencil_frac: np.ndarray
    high_filtered: np.ndarray
    occluded: np.ndarray
    surface_light: np.ndarray


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
    (m = 0) and as a metal (m = 1) at the estimated roughness, and where estimates.label_moments
    has rows the weighted sums those losses come from (for `freqbrdf.calibrate.gains`); others are
    left untouched.
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


@numba.njit(fastmath=True, cache=True)
def _global_search_chunk(chunk, samples, light, recurrence, options, tables, environment_light, prefiltered_light,
                         settings, hypotheses, candidate, estimates):
    """Do `global_search_kernel`'s work for the texels of one chunk, with one set of scratch arrays.

    A function of its own, so that numba's parallel passes see a small loop (on the whole body they
    take much of the kernel's compile time).
    """
    scratch = _new_search_scratch_inline(samples.weight.shape[1], recurrence.lmax, tables, environment_light,
                                         prefiltered_light, settings, hypotheses)
    for t in range(chunk * _SEARCH_CHUNK, min((chunk + 1) * _SEARCH_CHUNK, samples.weight.shape[0])):
        _search_texel_inline(t, samples, light, recurrence, options, tables, environment_light, prefiltered_light, settings,
                     hypotheses, candidate, estimates, scratch)


@numba.njit(cache=True)
def new_search_scratch(n_views, lmax, tables, environment_light, prefiltered_light, settings, hypotheses):
    """Allocate one thread's `SearchScratch` for V = n_views views and SH degree lmax.

    The other arguments are `global_search_kernel`'s records; the hypotheses the first scan
    records are marked in ``scanned`` (the others are probed before the search).
    """
    table = tables.split_sum
    environment = environment_light.coeffs
    quadrature = environment_light.quadrature
    prefiltered = prefiltered_light.maps
    roughness_grid = settings.roughness_grid
    hypothesis_roughness, node_rows = hypotheses.roughness, hypotheses.node_rows
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
    no_sums = np.zeros((0, 3, 16))
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
    # Per sample: the share of its mirror lobe on the object, and the radiance the object shows there.
    occluded = np.zeros(n_views)
    surface_light = np.zeros((3, n_views))
    return SearchScratch(
        xyz, unit, basis, sh_scratch, packed_cos, omega, packed_proj, values, table_row, table_frac,
        burley_terms, diffuse_moments, column, albedo, diffuse_factor, own_filtered, filtered, sample_weight,
        residual, kernel, kernel_derivative, moments, quadratics, squared_values, scale, state, best_state,
        label_state, roughness_brent, node_loss, scanned, no_rows, no_moments, no_sums, local_environment,
        quadrature_world, quadrature_basis, quadrature_scratch, quadrature_values, azimuthal, environment_nodes,
        environment_cached, bitangent, prefiltered_nodes, prefiltered_cached, corner, stencil_frac,
        high_filtered, occluded, surface_light,
    )


@numba.njit(fastmath=True, cache=True)
def search_texel(t, samples, light, recurrence, options, tables, environment_light, prefiltered_light, settings,
                 hypotheses, candidate, estimates, scratch):
    """Do `global_search_kernel`'s work for texel t, with one thread's `SearchScratch`."""
    directions, weight, observed = samples.view_direction, samples.weight, samples.observed
    diffuse_scale, tangent, normal = samples.diffuse_scale, samples.tangent, samples.normal
    lmax, diag, rec_a, rec_b = recurrence.lmax, recurrence.diag, recurrence.rec_a, recurrence.rec_b
    burley = options.burley
    table, burley_response = tables.split_sum, tables.burley_response
    environment = environment_light.coeffs
    quadrature, quadrature_projection = environment_light.quadrature, environment_light.projection
    n_full = prefiltered_light.n_full
    world_to_local, map_height, map_width = prefiltered_light.world_to_local, prefiltered_light.height, prefiltered_light.width
    roughness_grid, metallic_grid = settings.roughness_grid, settings.metallic_grid
    robust_passes, search = settings.robust_passes, settings.search
    hypothesis_roughness, hypothesis_moments, node_rows = hypotheses.roughness, hypotheses.moments, hypotheses.node_rows
    params, loss, curvature = estimates.params, estimates.loss, estimates.curvature
    label_loss, label_base_color = estimates.label_loss, estimates.label_base_color
    n_views = weight.shape[1]
    n_degrees = lmax + 1
    (
        xyz, unit, basis, sh_scratch, packed_cos, omega, packed_proj, values, table_row, table_frac,
        burley_terms, diffuse_moments, column, albedo, diffuse_factor, own_filtered, filtered, sample_weight,
        residual, kernel, kernel_derivative, moments, quadratics, squared_values, scale, state, best_state,
        label_state, roughness_brent, node_loss, scanned, no_rows, no_moments, no_sums, local_environment,
        quadrature_world, quadrature_basis, quadrature_scratch, quadrature_values, azimuthal, environment_nodes,
        environment_cached, bitangent, prefiltered_nodes, prefiltered_cached, corner, stencil_frac,
        high_filtered, occluded, surface_light,
    ) = scratch
    probe = Probe(column, kernel, kernel_derivative, albedo, diffuse_factor, own_filtered, filtered, moments,
                  quadratics, state, environment_nodes, environment_cached, prefiltered_nodes, prefiltered_cached,
                  high_filtered)
    buffers = SearchBuffers(roughness_grid, best_state, roughness_brent, node_loss, sample_weight)
    # np.int64, np.bool_ and below: a literal constant where a variable goes (here into a record)
    # makes numba compile the callee once more for the literal's type.
    # The neighbour vote (below) concerns only texels whose candidate roughness or metallic
    # lies more than a grid cell away: the others skip the preparation too.
    voting = candidate.shape[0] > 0
    far_roughness = voting and abs(candidate[t, 0] - params[t, 3]) * (roughness_grid - 1) > 1.0
    far_metallic = voting and abs(candidate[t, 1] - params[t, 4]) * (metallic_grid - 1) > 1.0
    if voting and not (far_roughness or far_metallic):
        return
    traced = samples.mirror_occluded.shape[1] > 0
    any_occluded = False
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
        occluded[n] = samples.mirror_occluded[t, v] if traced else 0.0
        if occluded[n] > 0.0:
            any_occluded = True
            for c in range(3):
                surface_light[c, n] = samples.mirror_surface[t, v, c]
        n += 1
    if n < MIN_SAMPLES:
        return
    if voting and 3 * n <= FITTED_PARAMETERS:
        return
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
                  squared_values, scale, azimuthal, corner, stencil_frac, occluded, surface_light, any_occluded)
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
            return  # the estimate stands
        params[t, 0], params[t, 1], params[t, 2] = state[0], state[1], state[2]
        params[t, 3], params[t, 4] = voted_r, state[3]
        loss[t] = max(voted_f, 0.0) / total_weight
        curvature[t] = _loss_curvature(voted_r, profiled_f, objective) / total_weight
        if label_loss.shape[0] > 0 and voted_r != estimate_r:
            _record_labels(voted_r, objective, quadratics, label_state, total_weight, label_loss[t],
                           label_base_color[t], np.bool_(True))
        return
    if not search:
        return
    # A robust pass refines the roughness to _BRENT_XTOL: this search need only find its cell.
    first_xtol = _BRENT_COARSE_XTOL if robust_passes > 0 else _BRENT_XTOL
    # Where label_moments' roughness slots are the grid's nodes, the scan (at the least-squares
    # weights) records their sums: the nodes are not probed again below.
    n_slots = estimates.label_moments.shape[1]
    slots_scanned = estimates.label_moments.shape[0] > 0 and n_slots - 2 == roughness_grid - 1
    best_r, best_f = _search_roughness(objective, buffers, np.int64(0), roughness_grid - 1, first_xtol, node_rows,
                                       hypothesis_moments[t] if node_rows.shape[0] > 0 else no_moments,
                                       estimates.label_moments[t, 1:] if slots_scanned else no_sums)
    if robust_passes > 0:
        # Towards the paper's L1 loss sum_v w |r_v| (IRLS): weight each sample by
        # w / max(|r|, delta), delta a tenth of the texel's mean |r| so that near-exact
        # samples do not take over, and search again.
        for _ in range(robust_passes):
            best_f = _roughness_objective(best_r, objective)
            _keep_state(state, best_state)
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
                                               no_rows, no_moments, no_sums)
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
    if label_loss.shape[0] > 0:
        # After a robust pass the last probe was at best_r (centre_f): its quadratics give the labels.
        _record_labels(best_r, objective, quadratics, label_state, total_weight, label_loss[t],
                       label_base_color[t], np.bool_(robust_passes == 0))
        # The sums at the estimate (the probe at best_r left them in moments), then at the
        # roughness nodes label_moments has room for, evenly on [0, 1] (where the scan did not).
        recorded_slots = 1 if slots_scanned else n_slots
        for slot in range(recorded_slots if estimates.label_moments.shape[0] > 0 else 0):
            if slot > 0:
                _roughness_objective((slot - 1) / max(n_slots - 2, 1), objective)
            record_label_sums(objective, estimates.label_moments[t, slot])
    curvature[t] = _loss_curvature(best_r, centre_f, objective) / total_weight
    params[t, 0], params[t, 1], params[t, 2] = best_state[0], best_state[1], best_state[2]
    params[t, 3], params[t, 4] = best_r, best_state[3]
    loss[t] = max(best_f, 0.0) / total_weight


# The CPU chunk's copies of `new_search_scratch` and `search_texel`, inlined into it (numba IR), so that
# LLVM sees the scratch arrays as the chunk's own allocations, of known shapes, as in one function.
_new_search_scratch_inline = numba.njit(cache=True, inline="always")(new_search_scratch.py_func)
_search_texel_inline = numba.njit(fastmath=True, cache=True, inline="always")(search_texel.py_func)
