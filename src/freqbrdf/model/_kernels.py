"""numba device functions of the reflection model, shared by the estimators and the light models.

The per-sample pieces of the model of docs/method.md#forward-model as the search kernels evaluate them: the
specular albedo, the BRDF kernel and G1, Burley's factor, the environment light at a roughness
node, the prefiltered light's lookup stencil and nodes. Arrays are written into the ``out``
arguments; the functions compiled with `borrowing_jit` allocate nothing.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from freqbrdf.model.tables import (
    BIAS_PLANE,
    ENVIRONMENT_NODE_STEP,
    MIN_LAMBERT,
    PREFILTER_STEP,
    SCALE_PLANE,
    TABLE_ROUGHNESS_NODES,
    table_lookup,
)
from freqbrdf.sphere import envmap as envmaps
from freqbrdf.sphere import harmonics as sh

# The search's inner functions run many times per texel and take many arrays each. Compiled with
# numba's runtime on, each call would count a reference to every array it takes (an atomic add on
# entry and exit). They allocate nothing and their callers hold the arrays, so they are compiled
# without it.
borrowing_jit = numba.njit(fastmath=True, cache=True, _nrt=False)


@borrowing_jit
def environment_node(roughness):
    """Return the environment light's roughness node below a roughness, and the fraction beyond it.

    The roughness is clipped to [0, 1]; the nodes are every `ENVIRONMENT_NODE_STEP`-th of the
    tables'.
    """
    n_nodes = (TABLE_ROUGHNESS_NODES - 1) // ENVIRONMENT_NODE_STEP + 1
    y = min(max(roughness, 0.0), 1.0) * (n_nodes - 1)
    node = min(int(y), n_nodes - 2)
    return node, y - node


@borrowing_jit
def prefilter_node(roughness, n_nodes):
    """Return the prefiltered maps' node below a roughness, and the fraction beyond it.

    The nodes lie `PREFILTER_STEP` apart from roughness 0; the roughness is clipped to them.
    """
    y = min(max(roughness, 0.0) / PREFILTER_STEP, n_nodes - 1.0)
    node = min(int(y), n_nodes - 2)
    return node, y - node


@borrowing_jit
def cross(a, b, out):
    """Write the cross product a x b of two 3-vectors into out."""
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@borrowing_jit
def mirror_stencil(xyz, n, tangent, normal, bitangent, world_to_local, height, width, corner, stencil_frac):
    """Compute `envmap.lookup`'s bilinear stencil at each sample's world mirror direction.

    For the local view directions xyz[:, s], s < n, in the frame (tangent, bitangent, normal):
    corner (4, n) receives the flat pixel indices row * width + col of (row, col), (row, col + 1),
    (row + 1, col), (row + 1, col + 1), stencil_frac (2, n) the column and row fractions.
    """
    for s in range(n):
        mirror_x, mirror_y, mirror_z = -xyz[0, s], -xyz[1, s], xyz[2, s]
        world_x = mirror_x * tangent[0] + mirror_y * bitangent[0] + mirror_z * normal[0]
        world_y = mirror_x * tangent[1] + mirror_y * bitangent[1] + mirror_z * normal[1]
        world_z = mirror_x * tangent[2] + mirror_y * bitangent[2] + mirror_z * normal[2]
        x, y = envmaps.map_coordinates(world_to_local, world_x, world_y, world_z, height, width)
        row0, col0, col1, fx, fy = envmaps.stencil_at(x, y, height, width)
        corner[0, s], corner[1, s] = row0 * width + col0, row0 * width + col1
        corner[2, s], corner[3, s] = (row0 + 1) * width + col0, (row0 + 1) * width + col1
        stencil_frac[0, s], stencil_frac[1, s] = fx, fy


@numba.njit(inline="always", fastmath=True)
def bilinear(prefiltered, node, c, top_left, top_right, bottom_left, bottom_right, fx, fy):
    """Return channel c of node ``node`` of prefiltered (H W, nodes, 3), bilinear between four pixels."""
    top = (1.0 - fx) * prefiltered[top_left, node, c] + fx * prefiltered[top_right, node, c]
    bottom = (1.0 - fx) * prefiltered[bottom_left, node, c] + fx * prefiltered[bottom_right, node, c]
    return (1.0 - fy) * top + fy * bottom


@borrowing_jit
def prefiltered_node_light(prefiltered, node, n, corner, stencil_frac, out):
    """Look up the light of one prefiltered node at the samples' mirror stencils.

    out[c, s] for samples s < n, bilinear at `mirror_stencil`'s stencil in prefiltered
    (H W, nodes, 3), pixel-major so that a texel's lookups at several nodes share cache lines.
    """
    for s in range(n):
        for c in range(3):
            out[c, s] = bilinear(prefiltered, node, c, corner[0, s], corner[1, s], corner[2, s], corner[3, s],
                                  stencil_frac[0, s], stencil_frac[1, s])


@numba.njit(parallel=True, fastmath=True, cache=True)
def project_degrees_kernel(basis, weight, coeffs, out):
    """Expand SH coefficients by degree at the samples (numba, parallel over texels).

    basis (n, V, K), weight (n, V), coeffs (n, 3, K); out (n, 3, l*+1, V) receives
    sum_m c_c,lm Y_lm(w_v), 0 where the weight is 0 (`light.degree_projections`).
    """
    n_texels, n_views, _ = basis.shape
    n_degrees = out.shape[2]
    for t in numba.prange(n_texels):
        for v in range(n_views):
            sampled = weight[t, v] > 0.0
            for c in range(3):
                for degree in range(n_degrees):
                    acc = np.float32(0.0)
                    if sampled:
                        for k in range(degree * degree, (degree + 1) * (degree + 1)):
                            acc += basis[t, v, k] * coeffs[t, c, k]
                    out[t, c, degree, v] = acc


@numba.njit(fastmath=True, cache=True)
def g1_and_derivative(cos_theta, alpha):
    """Return `brdf.smith_g1_ggx` for one sample (cos_theta > 0) and its derivative in alpha."""
    sin2 = 1.0 - cos_theta * cos_theta
    root = math.sqrt(cos_theta * cos_theta + alpha * alpha * sin2)
    denominator = cos_theta + root
    g1 = 2.0 * cos_theta / denominator
    return g1, -g1 / denominator * alpha * sin2 / root


@numba.njit(fastmath=True, cache=True)
def specular_albedo(cos_theta, roughness, alpha, fresnel, masking, split_sum, table):
    """Return (A, B) of one sample: its specular radiance is (R0 A + B) times the filtered light.

    With ``split_sum`` the table's A and B (`tables.split_sum_terms`); otherwise the angular
    model of docs/method.md#forward-model, F G1 = R0 G1 (1 - F_c) + G1 F_c with F_c = (1 - cos)^5 (G1 = 1 without ``masking``).
    Without ``fresnel``, A + B and 0.
    """
    if split_sum:
        scale = table_lookup(table, SCALE_PLANE, cos_theta, roughness)
        bias = table_lookup(table, BIAS_PLANE, cos_theta, roughness)
    else:
        g1 = g1_and_derivative(cos_theta, alpha)[0] if masking else 1.0
        schlick = (1.0 - cos_theta) ** 5
        scale, bias = g1 * (1.0 - schlick), g1 * schlick
    if not fresnel:
        return scale + bias, 0.0
    return scale, bias


@borrowing_jit
def fill_kernel(alpha, sigma, kernel, kernel_derivative):
    """Fill one texel's BRDF kernel (`brdf.brdf_kernel`) and its derivative in alpha, -2 alpha l^2 k(l)."""
    for degree in range(kernel.shape[0]):
        kernel[degree] = math.exp(-(alpha * alpha - sigma * sigma) * degree * degree)
        kernel_derivative[degree] = -2.0 * alpha * degree * degree * kernel[degree]


@borrowing_jit
def environment_node_lights(response, node, n, table_row, table_frac, azimuthal, out):
    """Evaluate the environment light of the three lobe terms at one roughness node.

    out[k, c, s] for samples s < n: the responses of node ``node`` of response
    (`tables.environment_response_table`), linear in cos theta_o (table_row, table_frac: each
    sample's cos node and fraction), times the environment's coefficients in the sample's mirrored
    view frame, azimuthal (>= n, 3, P) (`light.environment_azimuthal`). The search evaluates it at
    the two nodes around a roughness and interpolates.
    """
    n_pairs = azimuthal.shape[2]
    # The three terms at once: they share each coefficient's load and the nine sums stay in
    # registers.
    for s in range(n):
        row, fx = table_row[s], table_frac[s]
        a0 = a1 = a2 = b0 = b1 = b2 = c0 = c1 = c2 = 0.0
        for pair in range(n_pairs):
            below = response[0, node, row, pair]
            scale = below + fx * (response[0, node, row + 1, pair] - below)
            below = response[1, node, row, pair]
            bias = below + fx * (response[1, node, row + 1, pair] - below)
            below = response[2, node, row, pair]
            dielectric = below + fx * (response[2, node, row + 1, pair] - below)
            red, green, blue = azimuthal[s, 0, pair], azimuthal[s, 1, pair], azimuthal[s, 2, pair]
            a0 += scale * red
            a1 += scale * green
            a2 += scale * blue
            b0 += bias * red
            b1 += bias * green
            b2 += bias * blue
            c0 += dielectric * red
            c1 += dielectric * green
            c2 += dielectric * blue
        out[0, 0, s], out[0, 1, s], out[0, 2, s] = a0, a1, a2
        out[1, 0, s], out[1, 1, s], out[1, 2, s] = b0, b1, b2
        out[2, 0, s], out[2, 1, s], out[2, 2, s] = c0, c1, c2


@numba.njit(cache=True)
def n_sh_degrees(n_coeffs):
    """Return l* + 1 of (l* + 1)^2 SH coefficients (numba has no math.isqrt)."""
    return int(math.sqrt(n_coeffs) + 0.5)


@borrowing_jit
def texel_environment(environment, tangent, normal, bitangent, quadrature, projection, diag, rec_a, rec_b, world,
                       basis, sh_scratch, values, out):
    """Turn the world-frame environment (K, 3) into a texel's frame (tangent, bitangent, normal).

    As `light.local_environment`, with `light.environment_quadrature`'s directions (Q, 3) and
    projection (K, Q); (diag, rec_a, rec_b) the SH recurrence of `sphere.harmonics._sh_block`;
    scratch world (3, Q), basis (K, Q), sh_scratch (5, Q), values (3, Q); out (K, 3).
    """
    n_points = quadrature.shape[0]
    for q in range(n_points):
        for axis in range(3):
            world[axis, q] = (quadrature[q, 0] * tangent[axis] + quadrature[q, 1] * bitangent[axis]
                              + quadrature[q, 2] * normal[axis])
    sh._sh_block(world[0], world[1], world[2], n_points, n_sh_degrees(environment.shape[0]) - 1, diag, rec_a, rec_b,
                 basis, sh_scratch)
    # Loops innermost over the quadrature points, contiguous in basis, values and projection.
    values[:] = 0.0
    for k in range(environment.shape[0]):
        for c in range(3):
            coefficient = environment[k, c]
            for q in range(n_points):
                values[c, q] += coefficient * basis[k, q]
    for k in range(environment.shape[0]):
        for c in range(3):
            total = 0.0
            for q in range(n_points):
                total += projection[k, q] * values[c, q]
            out[k, c] = total


@borrowing_jit
def azimuthal_coefficients(xyz, n, local, out):
    """Turn a texel's environment into each sample's mirrored view frame.

    out (>= n, 3, P) receives `light.environment_azimuthal` of the local view directions
    xyz (3, >= n) from the texel-frame coefficients local (K, 3).
    """
    n_degrees = n_sh_degrees(local.shape[0])
    for s in range(n):
        mirrored_x, mirrored_y = -xyz[0, s], -xyz[1, s]
        radius = math.sqrt(mirrored_x * mirrored_x + mirrored_y * mirrored_y)
        # At normal incidence the lobe is symmetric (every m > 0 response is 0): any azimuth does.
        cos_beta, sin_beta = (mirrored_x / radius, mirrored_y / radius) if radius > 1e-12 else (1.0, 0.0)
        cos_m, sin_m = 1.0, 0.0
        for order in range(n_degrees):
            if order > 0:
                cos_m, sin_m = cos_m * cos_beta - sin_m * sin_beta, sin_m * cos_beta + cos_m * sin_beta
            for degree in range(order, n_degrees):
                pair = degree * (degree + 1) // 2 + order
                centre = degree * degree + degree
                for c in range(3):
                    if order == 0:
                        out[s, c, pair] = local[centre, c]
                    else:
                        out[s, c, pair] = local[centre + order, c] * cos_m + local[centre - order, c] * sin_m


@borrowing_jit
def prefiltered_nodes_at(roughness, first, count, n, prefiltered, corner, stencil_frac, nodes, cached):
    """Locate a lobe's light among the prefiltered nodes, looking up the nodes it needs.

    Among the nodes first .. first + count - 1 (roughness 0 .. 1 by `PREFILTER_STEP`), for samples
    s < n: returns (lower, upper, fraction), indices into nodes; on a node both are that node and
    the fraction is 0. Each node read is looked up once per texel into nodes (cached).
    """
    node, frac = prefilter_node(roughness, count)
    lower = first + (node if frac < 1.0 else node + 1)
    upper = first + (node + 1 if frac > 0.0 else node)
    for needed in range(lower, upper + 1):
        if not cached[needed]:
            prefiltered_node_light(prefiltered, needed, n, corner, stencil_frac, nodes[needed])
            cached[needed] = True
    return lower, upper, (frac if upper != lower else 0.0)


@numba.njit(inline="always")
def prefiltered_between(nodes, c, s, lower, upper, frac):
    """Return channel c of sample s's light between the nodes `prefiltered_nodes_at` returned."""
    value = nodes[lower, c, s]
    return value + frac * (nodes[upper, c, s] - value) if frac > 0.0 else value


@borrowing_jit
def environment_share(roughness, blend):
    """Return `light.environment_weight` for one roughness; blend (start, end)."""
    ramp = min(max((roughness - blend[0]) / max(blend[1] - blend[0], 1e-12), 0.0), 1.0)
    return ramp * ramp * (3.0 - 2.0 * ramp)


@borrowing_jit
def burley_polynomial(cos_theta, out):
    """Write (c0, c1, c2) with `tables.burley_diffuse_factor` (cos_theta, r) = c0 + r c1 + r^2 c2 into out."""
    schlick_view = (1.0 - cos_theta) ** 5
    retro_fresnel = 1.0 / 21.0 + cos_theta / 84.0
    out[0] = (1.0 - 0.5 * schlick_view) * (1.0 - 0.5 / 21.0)
    out[1] = schlick_view * (1.0 + 2.0 * cos_theta / 3.0) + retro_fresnel - schlick_view * retro_fresnel
    out[2] = schlick_view * (1.0 / 21.0 + cos_theta / 42.0 + 11.0 * (1.0 - cos_theta * cos_theta) / 504.0
                             + cos_theta * cos_theta / 252.0)


@borrowing_jit
def uniform_burley_terms(cos_theta, burley, out):
    """Write every channel's (c0, c1, c2) of Burley's uniform-light factor into out (3, 3).

    `burley_polynomial`, or Lambert's (1, 0, 0) without ``burley``.
    """
    if burley:
        burley_polynomial(cos_theta, out[0])
    else:
        out[0, 0], out[0, 1], out[0, 2] = 1.0, 0.0, 0.0
    for c in range(1, 3):
        for power in range(3):
            out[c, power] = out[0, power]


@borrowing_jit
def environment_burley_terms(n, table_row, table_frac, azimuthal, burley_response, out):
    """Write Burley's factor under the environment's own light per channel into out (3, 3, >= n).

    c0 + r c1 + r^2 c2 (`light.environment_burley_factor`) from burley_response (4, cos nodes, >= P)
    (`tables.burley_response_table`) and the samples' azimuthal (>= n, 3, P) coefficients; channels
    whose Lambert response is not above `MIN_LAMBERT` times their DC keep what out holds.
    """
    n_pairs = min(azimuthal.shape[2], burley_response.shape[2])
    for s in range(n):
        row, fx = table_row[s], table_frac[s]
        # All rows and channels in one pass over the harmonics, the twelve sums in registers (as
        # `environment_node_lights`).
        f0r = f0g = f0b = f1r = f1g = f1b = f2r = f2g = f2b = lr = lg = lb = 0.0
        for pair in range(n_pairs):
            red, green, blue = azimuthal[s, 0, pair], azimuthal[s, 1, pair], azimuthal[s, 2, pair]
            below = burley_response[0, row, pair]
            power0 = below + fx * (burley_response[0, row + 1, pair] - below)
            below = burley_response[1, row, pair]
            power1 = below + fx * (burley_response[1, row + 1, pair] - below)
            below = burley_response[2, row, pair]
            power2 = below + fx * (burley_response[2, row + 1, pair] - below)
            below = burley_response[3, row, pair]
            lambert = below + fx * (burley_response[3, row + 1, pair] - below)
            f0r += power0 * red
            f0g += power0 * green
            f0b += power0 * blue
            f1r += power1 * red
            f1g += power1 * green
            f1b += power1 * blue
            f2r += power2 * red
            f2g += power2 * green
            f2b += power2 * blue
            lr += lambert * red
            lg += lambert * green
            lb += lambert * blue
        for c, (power0, power1, power2, lambert) in enumerate(((f0r, f1r, f2r, lr), (f0g, f1g, f2g, lg),
                                                               (f0b, f1b, f2b, lb))):
            if lambert > MIN_LAMBERT * abs(azimuthal[s, c, 0]):
                out[c, 0, s] = power0 / lambert
                out[c, 1, s] = power1 / lambert
                out[c, 2, s] = power2 / lambert
