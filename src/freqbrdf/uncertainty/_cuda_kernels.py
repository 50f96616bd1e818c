"""The CUDA kernels of the entropy (docs/method.md#entropy), for `freqbrdf.uncertainty.spectral` and `.angular`.

Each thread runs the CPU kernels' own per-texel (or per-block) functions on scratch of its own, so
both backends do the same arithmetic in the same order:

- `grid_entropy_on_cuda`: one thread per block of ``_LANES`` texels, `grid_entropy_block` (the
  spectral modes);
- `moment_entropy_on_cuda`: one thread per texel, `_moment_entropy_texel` (the angular mode).

The kernels take named records only (see `freqbrdf.devices`). Imported only when the CUDA
backend runs.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import cuda

from freqbrdf import devices
from freqbrdf.uncertainty._kernels import (
    _LANES,
    EntropyOutputs,
    GridScratch,
    MomentInputs,
    SpectraInputs,
    SpectralOptions,
    _moment_entropy_texel,
    grid_entropy_block,
    grid_entropy_scratch,
)


@numba.njit(cache=True)
def _slot_grid_scratch(scratch, slot):
    """Return thread slot's `GridScratch`: row slot of each (threads, ...) array of scratch."""
    return GridScratch(
        scratch.specular[slot],
        scratch.steps32[slot],
        scratch.filter_sq[slot],
        scratch.light_lanes[slot],
        scratch.observed_lanes[slot],
        scratch.light_sq[slot],
        scratch.light_observed[slot],
        scratch.constant[slot],
        scratch.light_dc[slot],
        scratch.observed_dc[slot],
        scratch.to_temperature[slot],
        scratch.quad[slot],
        scratch.linear[slot],
        scratch.lowest[slot],
        scratch.sums[slot],
        scratch.rows[slot],
        scratch.cell[slot],
        scratch.cell_sums[slot],
        scratch.weights[slot],
        scratch.channel_sums[slot],
        scratch.choice[slot],
        scratch.light_power[slot],
    )


@cuda.jit
def _grid_entropy_cuda_kernel(arguments, outputs, scratch):
    """Score blocks of texels, one thread each: arguments (SpectraInputs, SpectralOptions)."""
    spectra, options = arguments
    slot = cuda.grid(1)
    if slot >= scratch.light_lanes.shape[0]:
        return
    own = _slot_grid_scratch(scratch, slot)
    n_blocks = (spectra.light.shape[0] + _LANES - 1) // _LANES
    for block in range(slot, n_blocks, cuda.gridsize(1)):
        grid_entropy_block(block, spectra, options, outputs, own)


@cuda.jit
def _moment_entropy_cuda_kernel(arguments, outputs, scratch):
    """Score texels, one thread each: arguments (MomentInputs,), scratch (misfit, cell weights, norm, light)."""
    inputs = arguments[0]
    misfit, cell_weight, norm, light_mean_square = scratch
    slot = cuda.grid(1)
    if slot >= misfit.shape[0]:
        return
    for t in range(slot, inputs.moments.shape[0], cuda.gridsize(1)):
        _moment_entropy_texel(t, inputs, outputs, misfit[slot], cell_weight[slot], norm[slot], light_mean_square[slot])


def grid_entropy_on_cuda(spectra: SpectraInputs, options: SpectralOptions, outputs: EntropyOutputs) -> None:
    """Run `grid_entropy_kernel`'s work on the CUDA device, writing outputs.

    Parameters
    ----------
    spectra : SpectraInputs
        The spectra (N, 3, L), their scale, the rows' filter and alpha.
    options : SpectralOptions
        How to score.
    outputs : EntropyOutputs
        Written per texel (N of them).
    """
    template = grid_entropy_scratch(spectra, options)
    n_blocks = (spectra.light.shape[0] + _LANES - 1) // _LANES
    blocks, threads = devices.launch_size(n_blocks, devices.record_bytes(template))
    arguments = devices.to_device((spectra, options))
    device_outputs = devices.to_device(outputs)
    _grid_entropy_cuda_kernel[blocks, threads](arguments, device_outputs,
                                               devices.slot_scratch(template, blocks * threads))
    devices.copy_to_host(device_outputs, outputs)


def moment_entropy_on_cuda(inputs: MomentInputs, outputs: EntropyOutputs) -> None:
    """Run `moment_entropy_kernel`'s work on the CUDA device, writing outputs.

    Parameters
    ----------
    inputs : MomentInputs
        The moments (N, R, 3, 8), the samples' weights and mirrored light, the grid.
    outputs : EntropyOutputs
        Written per texel (N of them).
    """
    resolution = inputs.moments.shape[1]
    template = (np.empty((resolution, resolution)), np.empty((3, resolution, resolution), np.float32), np.empty(3),
                np.empty(3))
    blocks, threads = devices.launch_size(inputs.moments.shape[0], devices.record_bytes(template))
    arguments = devices.to_device((inputs,))
    device_outputs = devices.to_device(outputs)
    _moment_entropy_cuda_kernel[blocks, threads](arguments, device_outputs,
                                                 devices.slot_scratch(template, blocks * threads))
    devices.copy_to_host(device_outputs, outputs)
