"""The CUDA kernel of the per-texel SH least squares (docs/method.md#sh-fit), for `harmonics.fit_sh`.

One thread per texel, in a grid-stride loop: each thread builds its texel's normal equations and
solves them with the CPU kernel's own per-texel functions (`freqbrdf.sphere._fit_kernels`), on a
one-lane `FitScratch` of its own, so both backends do the same arithmetic in the same order. The
kernel takes named records only (see `freqbrdf.devices`). Imported only when the CUDA backend runs.
"""

from __future__ import annotations

import numpy as np
from numba import cuda

from freqbrdf import devices
from freqbrdf.sphere._fit_kernels import FitScratch, fit_scratch, solve_lanes, texel_normal_equations


@cuda.jit
def _fit_cuda_kernel(arguments, outputs, scratch):
    """Fit texel after texel, one thread each: arguments as `_fit_kernel`'s, outputs (coeffs, n_samples, solved)."""
    directions, weights, values, lmax, diag, rec_a, rec_b, reg, reg_lambda, scale_by_weight = arguments
    coeffs, n_samples, solved = outputs
    slot = cuda.grid(1)
    if slot >= scratch.upper.shape[0]:
        return
    own = FitScratch(scratch.xyz[slot], scratch.sample_weights[slot], scratch.sh_scratch[slot],
                     scratch.augmented[slot], scratch.upper[slot], scratch.gram_diagonal[slot],
                     scratch.inv_diagonal[slot], scratch.solution[slot], scratch.lane_ok[slot])
    for t in range(slot, weights.shape[0], cuda.gridsize(1)):
        texel_normal_equations(t, directions, weights, values, lmax, diag, rec_a, rec_b, reg, reg_lambda,
                               scale_by_weight, 0, own, n_samples)
        solve_lanes(t, 1, own, coeffs, n_samples, solved)


def fit_on_cuda(directions: np.ndarray, weights: np.ndarray, values: np.ndarray, lmax: int, tables: tuple,
                reg: np.ndarray, reg_lambda: float, scale_by_weight: bool, coeffs: np.ndarray,
                n_samples: np.ndarray, solved: np.ndarray) -> None:
    """Run the fit on the CUDA device, writing coeffs (N, C, K), n_samples (N,) and solved (N,).

    directions (N, V, 3), weights (N, V), values (N, V, C), float32 or float64; tables the SH
    recurrence (`harmonics._legendre_tables`); reg (K,) the regulariser's weights.
    """
    n_texels, n_views = weights.shape
    template = fit_scratch(n_views, reg.shape[0], values.shape[2], 1)
    blocks, threads = devices.launch_size(n_texels, devices.record_bytes(template))
    arguments = devices.to_device((directions, weights, values, np.int64(lmax), *tables, reg, np.float64(reg_lambda),
                                   np.bool_(scale_by_weight)))
    outputs = (coeffs, n_samples, solved)
    device_outputs = devices.to_device(outputs)
    _fit_cuda_kernel[blocks, threads](arguments, device_outputs, devices.slot_scratch(template, blocks * threads))
    devices.copy_to_host(device_outputs, outputs)
