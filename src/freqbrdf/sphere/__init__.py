"""Functions on the sphere: real spherical harmonics and distant environment lighting.

The SH convention, the power spectrum and the environment-map convention of docs/method.md#conventions; the SH
fits (docs/method.md#sh-fit), the band-limit filter (docs/method.md#band-limit) and the irradiance (docs/method.md#irradiance).

Modules
-------
harmonics
    Real SH: evaluation, regularised least-squares fits, power spectra, low-pass filters,
    rotations.
envmap
    `Envmap` in Mitsuba 3's ``envmap`` convention: loading, lookups, SH analysis and synthesis,
    zonal filters, irradiance.
"""

from freqbrdf.sphere.envmap import (
    Envmap,
    clamped_cosine_coeffs,
    downsample,
    envmap_from_sh,
    envmap_sh,
    irradiance,
    load_envmap,
    local_directions,
    lookup,
    lowpass_envmap,
    zonal_filter,
    zonal_filters,
)
from freqbrdf.sphere.harmonics import (
    FIT_EMPTY,
    FIT_OK,
    FIT_UNDERDETERMINED,
    SHFit,
    eval_sh,
    fit_sh,
    gaussian_lowpass,
    lmax_of,
    num_coeffs,
    power_spectrum,
    regulariser_weights,
    rotate_sh,
    rotation_matrix_sh,
    sh_degrees,
    sphere_quadrature,
)

__all__ = [
    "FIT_EMPTY",
    "FIT_OK",
    "FIT_UNDERDETERMINED",
    "Envmap",
    "SHFit",
    "clamped_cosine_coeffs",
    "downsample",
    "envmap_from_sh",
    "envmap_sh",
    "eval_sh",
    "fit_sh",
    "gaussian_lowpass",
    "irradiance",
    "lmax_of",
    "load_envmap",
    "local_directions",
    "lookup",
    "lowpass_envmap",
    "num_coeffs",
    "power_spectrum",
    "regulariser_weights",
    "rotate_sh",
    "rotation_matrix_sh",
    "sh_degrees",
    "sphere_quadrature",
    "zonal_filter",
    "zonal_filters",
]
