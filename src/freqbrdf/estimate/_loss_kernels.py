"""The model's weighted squared residual of given parameters, for `freqbrdf.estimate.angular_loss`.

The residual of the ``global`` estimator's model (docs/method.md#forward-model) with its light, written as the
search kernels evaluate it (`freqbrdf.estimate._search_kernels`), per texel over its samples.
"""

from __future__ import annotations

import numba
import numpy as np

from freqbrdf.model._kernels import (
    cross,
    environment_burley_terms,
    environment_node,
    environment_node_lights,
    environment_share,
    fill_kernel,
    mirror_stencil,
    prefiltered_between,
    prefiltered_nodes_at,
    specular_albedo,
    uniform_burley_terms,
)
from freqbrdf.model.brdf import ALPHA_MIN, DIELECTRIC_F0
from freqbrdf.model.tables import DIELECTRIC_PLANE, LOBE_TERMS, table_lookup


@numba.njit(parallel=True, fastmath=True, cache=True)
def squared_residual_kernel(proj, samples, base_color, metallic, roughness, options, tables, environment, azimuthal,
                            prefiltered_light, out, predicted):
    """Write each texel's weighted mean squared residual, sum_v,c w^2 (L - f)^2 / sum_v w^2 (numba, parallel).

    Where predicted (n, V, 3) has views (else (n, 0, 3)), also the model's radiance L of every
    sample with a positive weight.

    proj (n, 3, l*+1, V) is `model.light.mirror_projections` of the fitted light; base_color (n, 3),
    metallic and roughness (n,) the parameters; out (n,) receives the loss (0 without samples). The
    specular is m (b X + Y) + (1 - m) Z with X = A S_A, Y = B S_B (S_k: the light filtered for term
    k, `model.light.lobe_filtered_light`) and Z = E S_E with the exact dielectric, else Schlick's
    0.04 X + Y. With azimuthal (n, V, 3, P > 0) (`model.light.environment_azimuthal`) each S_k is
    blended towards the environment light (`model.light.environment_filtered_light`) over
    environment.blend, and with a Burley response of P > 0 harmonics Burley's diffuse is averaged
    over that light (`model.light.environment_burley_factor`). With prefiltered maps the lobes read
    `model.light.prefiltered_light` instead of proj. The records: `Samples`, `ModelOptions`,
    `ModelTables`, `EnvironmentLight`, `PrefilteredLight` (`freqbrdf.estimate._records`).
    """
    directions, weight, observed = samples.view_direction, samples.weight, samples.observed
    diffuse_scale, tangent, normal = samples.diffuse_scale, samples.tangent, samples.normal
    sigma, fresnel, masking = options.sigma, options.fresnel, options.masking
    split_sum, exact_dielectric, burley = options.split_sum, options.exact_dielectric, options.burley
    table, response, burley_response = tables.split_sum, tables.environment_response, tables.burley_response
    environment_blend = environment.blend
    prefiltered, n_full = prefiltered_light.maps, prefiltered_light.n_full
    world_to_local, map_height, map_width = prefiltered_light.world_to_local, prefiltered_light.height, prefiltered_light.width
    n_texels, n_views = weight.shape
    traced = samples.mirror_occluded.shape[1] > 0
    predicting = predicted.shape[1] > 0
    n_degrees = proj.shape[2]
    n_terms = len(LOBE_TERMS)
    for t in numba.prange(n_texels):
        alpha = max(roughness[t] * roughness[t], ALPHA_MIN)
        kernel = np.empty(n_degrees)
        fill_kernel(alpha, sigma, kernel, np.empty(n_degrees))
        filtered = np.empty(n_terms)
        share = environment_share(roughness[t], environment_blend) if azimuthal.shape[3] > 0 else 0.0
        # The environment light at the roughness nodes on either side, per term, channel and view.
        environment_light = np.zeros((2, 3, 3, n_views))  # all three terms, used or not
        # Burley's factor c0 + r c1 + r^2 c2 per channel and view: under uniform light, or the
        # environment's.
        burley_terms = np.empty((3, 3, n_views))
        for v in range(n_views):
            uniform_burley_terms(np.float64(directions[t, v, 2]), burley, burley_terms[:, :, v])
        environment_burley = burley and burley_response.shape[2] > 0 and azimuthal.shape[3] > 0
        table_row = np.empty(n_views, dtype=np.int64)
        table_frac = np.empty(n_views)
        if share > 0.0 or environment_burley:
            for v in range(n_views):
                x = min(max(np.float64(directions[t, v, 2]), 0.0), 1.0) * (table.shape[1] - 1)
                table_row[v] = min(int(x), table.shape[1] - 2)
                table_frac[v] = x - table_row[v]
        if environment_burley:
            environment_burley_terms(n_views, table_row, table_frac, azimuthal[t], burley_response, burley_terms)
        if share > 0.0:
            node, node_frac = environment_node(roughness[t])
            for side in range(2):
                environment_node_lights(response, node + side, n_views, table_row, table_frac, azimuthal[t],
                                         environment_light[side])
        # The prefiltered light at its nodes on either side, per channel and view.
        use_prefiltered = n_full > 0 and share < 1.0
        n_high = prefiltered.shape[1] - n_full
        use_high = n_high > 0 and share > 0.0
        nodes = np.empty((prefiltered.shape[1], 3, n_views))
        cached = np.zeros(prefiltered.shape[1], dtype=np.bool_)
        lower_map = upper_map = lower_high = upper_high = 0  # the full and the high nodes
        map_frac = high_frac = 0.0
        corner = np.zeros((4, n_views), dtype=np.int64)
        stencil_frac = np.zeros((2, n_views))
        if use_prefiltered or use_high:
            xyz = np.empty((3, n_views))
            for v in range(n_views):
                for axis in range(3):
                    xyz[axis, v] = directions[t, v, axis]
            bitangent = np.empty(3)
            cross(normal[t], tangent[t], bitangent)
            mirror_stencil(xyz, n_views, tangent[t], normal[t], bitangent, world_to_local, map_height, map_width,
                            corner, stencil_frac)
        if use_prefiltered:
            lower_map, upper_map, map_frac = prefiltered_nodes_at(roughness[t], 0, n_full, n_views, prefiltered,
                                                                   corner, stencil_frac, nodes, cached)
        if use_high:
            lower_high, upper_high, high_frac = prefiltered_nodes_at(roughness[t], n_full, n_high, n_views,
                                                                      prefiltered, corner, stencil_frac, nodes, cached)
        # Without the environment light every term reads the same light; Schlick's dielectric needs
        # no light of its own.
        distinct = share > 0.0
        distinct_terms = (n_terms if exact_dielectric else n_terms - 1) if distinct else 1
        total = 0.0
        weight_sq = 0.0
        for v in range(n_views):
            w = np.float64(weight[t, v])
            if w > 0.0:
                cos_v = np.float64(directions[t, v, 2])
                scale, bias = specular_albedo(cos_v, roughness[t], alpha, fresnel, masking, split_sum, table)
                dielectric = table_lookup(table, DIELECTRIC_PLANE, cos_v, roughness[t]) if exact_dielectric else 0.0
                for c in range(3):
                    for term in range(distinct_terms):
                        filtered[term] = 0.0
                        if use_prefiltered:
                            filtered[term] = prefiltered_between(nodes, c, v, lower_map, upper_map, map_frac)
                        else:
                            for degree in range(n_degrees):
                                filtered[term] += kernel[degree] * proj[t, c, degree, v]
                        if traced:  # the share of the mirror lobe on the object: what it shows there
                            occluded = np.float64(samples.mirror_occluded[t, v])
                            filtered[term] += occluded * (samples.mirror_surface[t, v, c] - filtered[term])
                        if share > 0.0:
                            lower = environment_light[0, term, c, v]
                            light = lower + node_frac * (environment_light[1, term, c, v] - lower)
                            if use_high:
                                light += prefiltered_between(nodes, c, v, lower_high, upper_high, high_frac)
                            filtered[term] = (1.0 - share) * filtered[term] + share * light
                    for term in range(distinct_terms, n_terms):
                        filtered[term] = filtered[0]
                    x, y = scale * filtered[0], bias * filtered[1]
                    z = dielectric * filtered[2] if exact_dielectric else DIELECTRIC_F0 * x + y
                    m, b = metallic[t], base_color[t, c]
                    terms = burley_terms[c, :, v]
                    diffuse_factor = terms[0] + roughness[t] * (terms[1] + roughness[t] * terms[2])
                    residual = (m * (b * x + y) + (1.0 - m) * z
                                + (1.0 - m) * b * diffuse_scale[t, c] * diffuse_factor - observed[t, v, c])
                    total += w * w * residual * residual
                    if predicting:
                        predicted[t, v, c] = residual + observed[t, v, c]
                weight_sq += w * w
        out[t] = total / weight_sq if weight_sq > 0.0 else 0.0
