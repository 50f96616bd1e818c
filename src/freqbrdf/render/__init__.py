"""Rendering with Mitsuba 3: scenes, path-traced views and ray tests (docs/method.md#conventions, docs/method.md#observations, docs/method.md#evaluation).

The only package that imports ``mitsuba`` or ``drjit``, and only when a function needs them:
importing it is cheap.

Modules
-------
scenes
    Mitsuba scene dicts built from our meshes, material maps, environment maps and cameras;
    variant selection; rendering views.
occluder
    `Occluder`: batched ray tests against a mesh (visibility and self-occlusion).
inverse
    The Mitsuba inverse-rendering baseline (`freqbrdf.render.inverse.mitsuba_inverse`); not
    re-exported here, because it imports the capture and texel stages.
"""

from freqbrdf.render.occluder import Occluder
from freqbrdf.render.scenes import (
    RenderedView,
    build_scene,
    envmap_emitter,
    mesh_shape,
    mitsuba,
    mitsuba_to_world,
    path_integrator,
    perspective_sensor,
    principled_bsdf,
    render_view,
    render_views,
    restored_floating_point,
    view_seed,
)

__all__ = [
    "Occluder",
    "RenderedView",
    "build_scene",
    "envmap_emitter",
    "mesh_shape",
    "mitsuba",
    "mitsuba_to_world",
    "path_integrator",
    "perspective_sensor",
    "principled_bsdf",
    "render_view",
    "render_views",
    "restored_floating_point",
    "view_seed",
]
