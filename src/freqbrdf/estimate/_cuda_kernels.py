"""The CUDA kernel of the global search (docs/method.md#estimation), for `freqbrdf.estimate.search`.

One thread per texel, in a grid-stride loop: each thread runs the CPU kernel's own per-texel
search (`freqbrdf.estimate._global_kernels.search_texel`) on a `SearchScratch` of its own, so both
backends do the same arithmetic in the same order. The kernel takes named records only (see
`freqbrdf.devices`). Imported only when the CUDA backend runs.
"""

from __future__ import annotations

import numba
from numba import cuda

from freqbrdf import devices
from freqbrdf.estimate._global_kernels import SearchScratch, new_search_scratch, search_texel
from freqbrdf.estimate._records import Hypotheses


@numba.njit(cache=True)
def _slot_scratch(scratch, slot):
    """Return thread slot's `SearchScratch`: row slot of each (threads, ...) array of scratch."""
    return SearchScratch(
        scratch.xyz[slot],
        scratch.unit[slot],
        scratch.basis[slot],
        scratch.sh_scratch[slot],
        scratch.packed_cos[slot],
        scratch.omega[slot],
        scratch.packed_proj[slot],
        scratch.values[slot],
        scratch.table_row[slot],
        scratch.table_frac[slot],
        scratch.burley_terms[slot],
        scratch.diffuse_moments[slot],
        scratch.column[slot],
        scratch.albedo[slot],
        scratch.diffuse_factor[slot],
        scratch.own_filtered[slot],
        scratch.filtered[slot],
        scratch.sample_weight[slot],
        scratch.residual[slot],
        scratch.kernel[slot],
        scratch.kernel_derivative[slot],
        scratch.moments[slot],
        scratch.quadratics[slot],
        scratch.squared_values[slot],
        scratch.scale[slot],
        scratch.state[slot],
        scratch.best_state[slot],
        scratch.label_state[slot],
        scratch.roughness_brent[slot],
        scratch.node_loss[slot],
        scratch.scanned[slot],
        scratch.no_rows[slot],
        scratch.no_moments[slot],
        scratch.no_sums[slot],
        scratch.local_environment[slot],
        scratch.quadrature_world[slot],
        scratch.quadrature_basis[slot],
        scratch.quadrature_scratch[slot],
        scratch.quadrature_values[slot],
        scratch.azimuthal[slot],
        scratch.environment_nodes[slot],
        scratch.environment_cached[slot],
        scratch.bitangent[slot],
        scratch.prefiltered_nodes[slot],
        scratch.prefiltered_cached[slot],
        scratch.corner[slot],
        scratch.stencil_frac[slot],
        scratch.high_filtered[slot],
        scratch.occluded[slot],
        scratch.surface_light[slot],
    )


@cuda.jit
def _global_search_cuda_kernel(arguments, estimates, moments, scratch):
    """Search texel after texel, one thread each.

    arguments: `global_search_kernel`'s inputs (samples, light, recurrence, options, tables,
    environment, prefiltered, settings, hypothesis roughness and node rows, candidate); estimates
    and moments (the hypotheses' moments) are written; scratch holds one `SearchScratch` per thread.
    """
    (samples, light, recurrence, options, tables, environment, prefiltered, settings, hypothesis_roughness,
     node_rows, candidate) = arguments
    hypotheses = Hypotheses(hypothesis_roughness, moments[0], node_rows)
    slot = cuda.grid(1)
    if slot >= scratch.xyz.shape[0]:
        return
    own = _slot_scratch(scratch, slot)
    for t in range(slot, samples.weight.shape[0], cuda.gridsize(1)):
        search_texel(t, samples, light, recurrence, options, tables, environment, prefiltered, settings,
                     hypotheses, candidate, estimates, own)


def global_search_on_cuda(samples, light, recurrence, options, tables, environment, prefiltered, settings,
                          hypotheses, candidate, estimates) -> None:
    """Run `global_search_kernel`'s work on the CUDA device: the same records, estimates written.

    Parameters are the records of `freqbrdf.estimate._records` (and candidate (n, 2) float64), as
    `global_search_kernel` takes them; estimates and hypotheses.moments receive the results.
    """
    n_texels, n_views = samples.weight.shape
    template = new_search_scratch(n_views, recurrence.lmax, tables, environment, prefiltered, settings, hypotheses)
    blocks, threads = devices.launch_size(n_texels, devices.record_bytes(template))
    arguments = devices.to_device((samples, light, recurrence, options, tables, environment, prefiltered, settings,
                                   hypotheses.roughness, hypotheses.node_rows, candidate))
    outputs = (estimates, (hypotheses.moments,))
    device_outputs = devices.to_device(outputs)
    _global_search_cuda_kernel[blocks, threads](arguments, *device_outputs,
                                                devices.slot_scratch(template, blocks * threads))
    devices.copy_to_host(device_outputs, outputs)
