"""The observation stage: per-texel samples of a capture and their SH spectra (docs/method.md#observations to docs/method.md#irradiance).

From the texels and the posed photographs to, per texel and view, the view direction in the
texel's frame, the observed radiance, the band-limited environment in the mirror direction and
the weight; then the irradiance and one regularised SH fit per texel (docs/method.md#conventions, docs/method.md#observations to docs/method.md#irradiance).
Mitsuba traces the shadow rays, through `freqbrdf.render.occluder.Occluder`, and is imported
only when an occluder is made: importing this package does not import it.

Modules
-------
observations
    `Observations` (its samples, spectra, saving and loading) and the stage `observe`.
signals
    The signals a texel's samples are fitted on (`fit_signals`), `mean_over_views`,
    `texel_alpha_bound`.
irradiance
    `texel_irradiance`: the irradiance at the normals from the environment's SH.
occlusion
    `occluded_irradiance`: that irradiance corrected where the object hides its own environment
    (shadow rays to the map's `compact_lights`, cosine rays that see the object's observed
    radiance); `self_occluding` tells the meshes that cannot.
maps
    The coverage and visibility maps of an `Observations` (`write_maps`).
visibility
    `camera_samples`: which surface points a camera without an image would sample.
"""

from freqbrdf.observe.irradiance import texel_irradiance
from freqbrdf.observe.maps import write_maps
from freqbrdf.observe.observations import (
    RAY_OFFSET_OBJECT,
    RAY_OFFSET_TEXELS,
    Observations,
    observe,
)
from freqbrdf.observe.occlusion import CompactLights, compact_lights, occluded_irradiance, self_occluding
from freqbrdf.observe.signals import mean_over_views, texel_alpha_bound
from freqbrdf.observe.visibility import camera_samples

__all__ = [
    "CompactLights",
    "RAY_OFFSET_OBJECT",
    "RAY_OFFSET_TEXELS",
    "Observations",
    "camera_samples",
    "compact_lights",
    "mean_over_views",
    "occluded_irradiance",
    "observe",
    "self_occluding",
    "texel_alpha_bound",
    "texel_irradiance",
    "write_maps",
]
