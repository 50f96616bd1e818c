"""Where the maps can be trusted: every std a texel has at or below a threshold the user chose.

docs/method.md#trust. The fit's std maps (roughness, metallic and base colour; the per-texel
estimate has only the roughness's) say per texel how far the estimate may be off. A capture/asset
engineer wants one answer per texel: can these maps be used here as they are? `trusted_texels`
gives it for a threshold on every std (``UncertaintyConfig.trust_std``); the fit folder holds it as
``trust.exr`` and the report shows it over the mesh.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from freqbrdf.uncertainty._result import Uncertainty

__all__ = ["trusted_texels", "trust_summary"]


def _std_maps(uncertainty: Uncertainty) -> dict[str, np.ndarray]:
    """Return the std maps the uncertainty holds, per texel: (N,) each (the base colour's mean over RGB)."""
    maps = {}
    if uncertainty.roughness_std is not None:
        maps["roughness"] = np.asarray(uncertainty.roughness_std, np.float64)
    if uncertainty.metallic_std is not None:
        maps["metallic"] = np.asarray(uncertainty.metallic_std, np.float64)
    if uncertainty.base_color_std is not None:
        maps["base_color"] = np.asarray(uncertainty.base_color_std, np.float64).mean(axis=1)
    return maps


def trusted_texels(uncertainty: Uncertainty, threshold: float) -> np.ndarray | None:
    """Mark the texels whose every std is at most ``threshold``.

    Parameters
    ----------
    uncertainty : Uncertainty
        The fit's uncertainty (N texels) with its std maps.
    threshold : float
        The largest std trusted, in the parameters' own units (each in [0, 1]); the base colour's
        is the mean over RGB.

    Returns
    -------
    (N,) bool or None
        True where every std map the uncertainty holds is finite and at most ``threshold``; None
        where it holds none.

    Examples
    --------
    >>> import numpy as np
    >>> from types import SimpleNamespace
    >>> spread = SimpleNamespace(roughness_std=np.array([0.02, 0.2, np.nan]), metallic_std=np.array([0.0, 0.0, 0.0]),
    ...                          base_color_std=None)  # an Uncertainty's std maps
    >>> trusted_texels(spread, 0.1).tolist()
    [True, False, False]
    """
    maps = _std_maps(uncertainty)
    if not maps:
        return None
    trusted = np.ones(len(next(iter(maps.values()))), dtype=bool)
    for values in maps.values():
        trusted &= np.nan_to_num(values, nan=np.inf) <= threshold
    return trusted


def trust_summary(uncertainty: Uncertainty, threshold: float, texels: np.ndarray) -> dict | None:
    """Say how much of the surface is trusted, as summary.json records it.

    Parameters
    ----------
    uncertainty : Uncertainty
        The fit's uncertainty (N texels).
    threshold : float
        The largest std trusted.
    texels : (N,) bool
        The texels that count (those with a value).

    Returns
    -------
    dict or None
        ``threshold``, ``trusted_fraction`` (of ``texels``) and ``by`` (per std map, the fraction at
        most ``threshold``); None where the uncertainty holds no std map.
    """
    trusted = trusted_texels(uncertainty, threshold)
    if trusted is None:
        return None
    count = max(int(np.count_nonzero(texels)), 1)
    by = {name: float(np.count_nonzero((np.nan_to_num(values, nan=np.inf) <= threshold) & texels) / count)
          for name, values in _std_maps(uncertainty).items()}
    return {"threshold": float(threshold), "trusted_fraction": float(np.count_nonzero(trusted & texels) / count),
            "by": by}
