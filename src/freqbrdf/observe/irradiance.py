"""Irradiance at the texels' normals from the environment's SH (docs/method.md#irradiance).

E(n) = integral of L(w) max(0, n.w) dw is the clamped-cosine kernel applied to the environment's
spherical harmonics. Irradiance is smooth, so it is synthesised once on a lat-long grid of
`IRRADIANCE_MAP_HEIGHT` rows and read bilinearly at the normals (`texel_irradiance`), rather than
evaluating every SH at every texel. `freqbrdf.observe.observations.observe` stores it per texel
as ``Observations.irradiance``.
"""

from __future__ import annotations

import numpy as np

from freqbrdf.sphere import envmap as envmaps
from freqbrdf.sphere import harmonics as sh

# Irradiance is smooth (its SH decay like l^-5/2), so it is synthesised once on a lat-long grid
# of this height and interpolated bilinearly at the normals, rather than evaluating every SH at
# every texel (docs/results.md has the error and the cost of both).
IRRADIANCE_MAP_HEIGHT = 256


def texel_irradiance(envmap: envmaps.Envmap, normals: np.ndarray) -> np.ndarray:
    """Compute the irradiance E(n) = integral of L(w) max(0, n.w) dw at world normals.

    The clamped-cosine kernel applied to the map's SH (`freqbrdf.sphere.envmap.irradiance`'s
    method, up to ``IRRADIANCE_LMAX`` of `freqbrdf.sphere.envmap` or what the map resolves),
    synthesised on a lat-long grid of ``IRRADIANCE_MAP_HEIGHT`` rows and read bilinearly
    (docs/method.md#irradiance).

    Parameters
    ----------
    envmap : Envmap
        The environment, unfiltered.
    normals : (N, 3) array_like
        Unit world normals.

    Returns
    -------
    (N, 3) float32
        Irradiance per normal and channel.
    """
    return envmaps.lookup(irradiance_map(envmap), normals)


def irradiance_map(envmap: envmaps.Envmap) -> envmaps.Envmap:
    """Return the irradiance E(n) of the map as a world-frame map of `IRRADIANCE_MAP_HEIGHT` rows.

    Read at a normal n (`freqbrdf.sphere.envmap.lookup`) it gives `texel_irradiance`; read at
    R^T n, the irradiance under the map turned by R.

    Parameters
    ----------
    envmap : Envmap
        The environment, unfiltered.

    Returns
    -------
    Envmap
        (H, 2 H, 3), its to_world the identity.
    """
    height, width = envmap.radiance.shape[:2]
    lmax = min(envmaps.IRRADIANCE_LMAX, height - 2, (width - 1) // 2)
    kernel = envmaps.clamped_cosine_coeffs(lmax)[sh.sh_degrees(lmax)]  # (K,)
    irradiance_coeffs = envmaps.envmap_sh(envmap, lmax) * kernel[:, None]  # (K, 3), world frame
    return envmaps.envmap_from_sh(irradiance_coeffs, max(IRRADIANCE_MAP_HEIGHT, lmax + 2))
