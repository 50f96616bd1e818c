"""The ``synth`` job: a synthetic capture of a known object, path traced with Mitsuba 3.

A capture is what a real acquisition would give (HDR photographs, masks, camera poses, the mesh
and the environment map; docs/method.md#problem) plus what only a synthetic one can: the ground-truth
material maps (``gt/``) and test views under other environment maps with their reference renders,
which results are judged on (docs/method.md#evaluation). It is written in our layout or Stanford-ORB's
(`freqbrdf.capture.layouts`).

World axes are Mitsuba's and OBJ's: +y is up (the zenith of an environment map with identity
to_world, and the normal of the bundled plane). Cameras sit on a sphere around the object's
bounding sphere, looking at its centre, far enough that the bounding sphere fills
``FRAME_FILL`` of the field of view (`freqbrdf.capture.camera_layouts`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeRemainingColumn,
)

from freqbrdf import assets
from freqbrdf.capture.camera import Camera, check_rigid
from freqbrdf.capture.camera_layouts import (
    bounding_sphere,
    camera_directions,
    orbit_cameras,
    random_directions,
)
from freqbrdf.capture.layouts import (
    GROUND_TRUTH_FOLDER,
    TEST_TRANSFORMS_FILE,
    TRANSFORMS_FILE,
    Frame,
)
from freqbrdf.capture.mesh import Mesh, load_mesh, save_obj
from freqbrdf.capture.stanford_orb import ORB_NORMAL_FIXES, ORB_NOVEL_FILE, stanford_orb_envmap_to_world
from freqbrdf.capture.transforms_file import write_transforms
from freqbrdf.errors import InputError
from freqbrdf.fileio import atomic_directory
from freqbrdf.images import write_exr, write_png
from freqbrdf.model.materials import (
    MaterialMaps,
    load_material_maps,
    resize,
    save_material_maps,
)
from freqbrdf.render.scenes import (
    DEFAULT_MAX_DEPTH,
    RenderedView,
    build_scene,
    principled_bsdf,
    render_views,
)
from freqbrdf.sphere.envmap import Envmap, load_envmap, local_directions, lookup

CameraLayout = Literal["hemisphere", "sphere", "random", "side"]
CaptureFormat = Literal["ours", "orb"]
CAMERA_LAYOUTS: tuple[str, ...] = ("hemisphere", "sphere", "random", "side")
CAPTURE_FORMATS: tuple[str, ...] = ("ours", "orb")


@dataclass(frozen=True)
class SynthSettings:
    """What a synthetic capture is rendered from, and how.

    Attributes
    ----------
    mesh : str
        A bundled mesh's name or a mesh file.
    envmap : str
        A bundled environment map's name or an EXR/HDR file; lights the training views.
    materials : str
        A bundled material's name or a folder written by ``save_material_maps``.
    views : int
        Number of training views.
    resolution : int
        Images are resolution x resolution pixels.
    spp : int
        Samples per pixel.
    texture_res : int
        The ground-truth maps are resampled to texture_res x texture_res.
    cameras : {"hemisphere", "sphere", "random", "side"}
        The training views' layout (`freqbrdf.capture.camera_layouts.camera_directions`); the
        test views are random on the sphere for "sphere", on the upper hemisphere otherwise.
    seed : int
        Camera placement (random layouts), the choice of test maps and Monte Carlo noise.
    test_envmaps : tuple of str, or int
        Environment maps of the test views: names or paths, or a count of bundled maps other
        than ``envmap`` chosen with ``seed``.
    test_views : int
        Number of test (relighting) views, randomly placed; may be 0 for our layout.
    format : {"ours", "orb"}
        Our layout or Stanford-ORB's.
    max_depth : int
        Maximum path length of the renders.
    envmap_to_world : (4, 4) nested tuple of float, or None
        The training light's Mitsuba to_world (a rotation), recorded in the capture's
        ``envmap_to_world``; None for the identity. The test views' maps keep the identity.
    """

    mesh: str = "bunny"
    envmap: str = "forest"
    materials: str = "bands"
    views: int = 32
    resolution: int = 256
    spp: int = 64
    texture_res: int = 512
    cameras: CameraLayout = "hemisphere"
    seed: int = 0
    test_envmaps: tuple[str, ...] | int = 2
    test_views: int = 8
    format: CaptureFormat = "ours"
    max_depth: int = DEFAULT_MAX_DEPTH
    envmap_to_world: tuple[tuple[float, ...], ...] | None = None


# --- the job -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class SynthScene:
    """Everything a capture is rendered from, resolved from the settings.

    Attributes
    ----------
    mesh : Mesh
        The object.
    envmap : Envmap
        The training views' light.
    envmap_path : Path
        Its file.
    materials : MaterialMaps
        The ground-truth maps, T x T.
    cameras : list of Camera
        The training views.
    test_cameras : list of Camera
        The test views.
    test_envmap_paths : list of Path
        One environment map per test view.
    """

    mesh: Mesh
    envmap: Envmap
    envmap_path: Path
    materials: MaterialMaps
    cameras: list[Camera]
    test_cameras: list[Camera]
    test_envmap_paths: list[Path]


def synthesize(out: str | Path, settings: SynthSettings = SynthSettings(), progress: bool = True) -> Path:
    """Render a synthetic capture into a folder, replacing it as a whole, atomically.

    Parameters
    ----------
    out : str or Path
        The capture folder.
    settings : SynthSettings, optional
        What to render.
    progress : bool, optional
        Show a progress bar.

    Returns
    -------
    Path
        What `freqbrdf.capture.layouts.load` takes: ``out`` itself, or for the Stanford-ORB layout
        its scene folder ``out/blender_HDR/synth``.

    Raises
    ------
    InputError
        If the settings are invalid (see `prepare`), or the Stanford-ORB layout has no test view.
    """
    scene = prepare(settings)
    out = Path(out)
    with atomic_directory(out) as folder:
        _render_and_write(folder, scene, settings, progress)
    return out if settings.format == "ours" else out / "blender_HDR" / ORB_SCENE


#: The smallest capture worth fitting: six 24 x 24 views of the bundled sphere, rendered in about a
#: second (`example_capture`).
EXAMPLE_SETTINGS = SynthSettings(mesh="sphere", views=6, resolution=24, spp=1, texture_res=16, test_views=0)


def example_capture(out: str | Path, **changes) -> Path:
    """Render the tiny capture the documentation's examples fit (`EXAMPLE_SETTINGS`).

    Parameters
    ----------
    out : str or Path
        The capture folder to write (replaced if it exists).
    **changes
        `SynthSettings` fields to change, e.g. ``test_views=1``.

    Returns
    -------
    Path
        The capture folder.
    """
    return synthesize(out, replace(EXAMPLE_SETTINGS, **changes), progress=False)


def prepare(settings: SynthSettings) -> SynthScene:
    """Validate the settings, load the assets and place the cameras, deterministically in the seed.

    Parameters
    ----------
    settings : SynthSettings
        What to render.

    Returns
    -------
    SynthScene
        The mesh, lights, ground-truth maps and cameras.

    Raises
    ------
    InputError
        If a count is not positive, a layout or format is unknown, ``test_envmaps`` is empty or
        asks for more bundled maps than there are, or an asset cannot be loaded.
    """
    _check_settings(settings)
    mesh = load_mesh(_asset(settings.mesh, assets.list_meshes(), assets.mesh_path))
    envmap_path = _asset(settings.envmap, assets.list_envmaps(), assets.envmap_path)
    envmap = load_envmap(envmap_path, np.eye(4) if settings.envmap_to_world is None
                         else np.asarray(settings.envmap_to_world, np.float64))
    materials = resize(
        load_material_maps(_asset(settings.materials, assets.list_materials(), assets.material_dir)),
        settings.texture_res,
    )
    # Independent streams, so that e.g. adding test views does not move the training cameras.
    camera_rng, test_rng, envmap_rng = (
        np.random.default_rng(stream) for stream in np.random.SeedSequence(settings.seed).spawn(3)
    )
    centre, radius = bounding_sphere(mesh.vertices)
    cameras = orbit_cameras(
        camera_directions(settings.cameras, settings.views, camera_rng), centre, radius,
        settings.resolution,
    )
    test_directions = random_directions(
        settings.test_views, hemisphere=settings.cameras != "sphere", rng=test_rng
    )
    test_cameras = orbit_cameras(test_directions, centre, radius, settings.resolution)
    test_envmaps = _test_envmap_paths(settings, envmap_path, envmap_rng)
    return SynthScene(
        mesh=mesh,
        envmap=envmap,
        envmap_path=envmap_path,
        materials=materials,
        cameras=cameras,
        test_cameras=test_cameras,
        test_envmap_paths=[test_envmaps[k % len(test_envmaps)] for k in range(settings.test_views)],
    )


def _render_and_write(folder: Path, scene: SynthScene, settings: SynthSettings, progress: bool) -> None:
    n_test = len(scene.test_cameras)
    with Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
        disable=not progress,
    ) as bar:
        # The Stanford-ORB layout renders the test cameras twice: under the training light (its
        # test split) and under their own light (its novel-scene split).
        n_test_renders = n_test if settings.format == "ours" else 2 * n_test
        task = bar.add_task("rendering views", total=len(scene.cameras) + n_test_renders)

        def render(cameras, envmap, first_index):
            """Render under ``envmap``; seeds continue across batches so no two views share one."""
            # A fresh BSDF dict per scene: Mitsuba takes over the tensors of the one it loads.
            bsdf = principled_bsdf(scene.materials)
            views = render_views(
                build_scene(scene.mesh, bsdf, envmap, settings.max_depth), cameras, settings.spp,
                settings.seed, first_index,
            )
            for view in views:
                bar.advance(task)
                yield view

        if settings.format == "ours":
            _write_ours(folder, scene, render)
        else:
            _write_stanford_orb(folder, scene, render)


def _write_view(image_path: Path, mask_path: Path, view: RenderedView) -> None:
    write_exr(image_path, view.radiance)
    write_png(mask_path, view.coverage)  # 8-bit coverage; read_mask thresholds it at 0.5


def _write_ours(folder: Path, scene: SynthScene, render) -> None:
    """Write ``transforms.json``, images/, masks/, mesh.obj, envmap.exr, gt/, and the test set."""
    save_obj(folder / "mesh.obj", scene.mesh)
    write_exr(folder / "envmap.exr", scene.envmap.radiance)
    save_material_maps(folder / GROUND_TRUTH_FOLDER, scene.materials)
    frames = []
    for index, view in enumerate(render(scene.cameras, scene.envmap, 0)):
        frame = Frame(scene.cameras[index], folder / "images" / f"{index:04d}.exr",
                      folder / "masks" / f"{index:04d}.png")
        _write_view(frame.image_path, frame.mask_path, view)
        frames.append(frame)
    write_transforms(folder / TRANSFORMS_FILE, frames, mesh=folder / "mesh.obj",
                     envmap=folder / "envmap.exr", envmap_to_world=scene.envmap.to_world,
                     envmap_scale=1.0)
    if not scene.test_cameras:
        return
    test_frames: list[Frame | None] = [None] * len(scene.test_cameras)
    first_index = len(scene.cameras)
    for light, source in enumerate(dict.fromkeys(scene.test_envmap_paths)):
        envmap = load_envmap(source, np.eye(4))
        envmap_file = folder / "test_envmaps" / f"{light}_{source.stem}.exr"
        write_exr(envmap_file, envmap.radiance)
        indices = [k for k, path in enumerate(scene.test_envmap_paths) if path == source]
        cameras = [scene.test_cameras[k] for k in indices]
        for k, view in zip(indices, render(cameras, envmap, first_index)):
            frame = Frame(scene.test_cameras[k], folder / "test" / f"{k:04d}.exr",
                          folder / "test_masks" / f"{k:04d}.png", envmap_file, envmap.to_world, 1.0)
            _write_view(frame.image_path, frame.mask_path, view)
            test_frames[k] = frame
        first_index += len(indices)
    write_transforms(folder / TEST_TRANSFORMS_FILE, test_frames)


ORB_SCENE = "synth"


def _write_stanford_orb(folder: Path, scene: SynthScene, render) -> None:
    """Write ``blender_HDR/synth`` and ``ground_truth/synth`` as Stanford-ORB lays them out.

    Stanford-ORB has no map for its training views: a scene's light is the map of its first test
    photograph, stored in that camera's frame. So the test split here is the test cameras under
    the training light, and every map is resampled (bilinearly, once) into its camera's frame.
    The whole capture is rendered under the resampled map of test view 0, exactly the light the
    loader reconstructs. The relighting views under the other maps form ORB's novel-scene split:
    each distinct map is one more scene ``synth_light<k>`` holding its test images and maps, and
    ``transforms_novel.json`` names that scene per frame. Each novel view is rendered under its own
    stored map, so the light the loader places is exactly the light that was rendered.
    """
    if not scene.test_cameras:
        raise InputError(Path("synth settings"), "the Stanford-ORB layout needs test_views >= 1")
    images = folder / "blender_HDR" / ORB_SCENE
    truth = folder / "ground_truth" / ORB_SCENE
    stored = []  # maps in each test camera's frame, as written
    for index, camera in enumerate(scene.test_cameras):
        to_world = stanford_orb_envmap_to_world(camera.camera_to_world)
        stored.append(resample_envmap(scene.envmap, to_world))
        write_exr(truth / "env_map" / f"{index:04d}.exr", stored[-1].radiance)
    light = stored[0]
    # ORB's OBJ normals are in Blender's Z-up axes, (x, y, z) -> (x, -z, y); the loader undoes it.
    blender_normals = scene.mesh.normals @ ORB_NORMAL_FIXES[1]
    save_obj(truth / "mesh_blender" / "mesh.obj", replace(scene.mesh, normals=blender_normals))
    save_material_maps(truth / GROUND_TRUTH_FOLDER, scene.materials)
    for split, cameras, first_index in (("train", scene.cameras, 0),
                                        ("test", scene.test_cameras, len(scene.cameras))):
        frames = []
        for index, view in enumerate(render(cameras, light, first_index)):
            image_path = images / split / f"{index:04d}.exr"
            _write_view(image_path, images / f"{split}_mask" / f"{index:04d}.png", view)
            frames.append(Frame(cameras[index], image_path))
        write_transforms(images / f"transforms_{split}.json", frames)

    first_index = len(scene.cameras) + len(scene.test_cameras)
    light_scene = {source: f"{ORB_SCENE}_light{light}"
                   for light, source in enumerate(dict.fromkeys(scene.test_envmap_paths))}
    novel_frames, novel_fields = [], []
    for index, (camera, source) in enumerate(zip(scene.test_cameras, scene.test_envmap_paths)):
        other = light_scene[source]
        stored_map = resample_envmap(load_envmap(source, np.eye(4)),
                                     stanford_orb_envmap_to_world(camera.camera_to_world))
        write_exr(folder / "ground_truth" / other / "env_map" / f"{index:04d}.exr", stored_map.radiance)
        image_path = folder / "blender_HDR" / other / "test" / f"{index:04d}.exr"
        (view,) = render([camera], stored_map, first_index + index)
        _write_view(image_path, image_path.parent.with_name("test_mask") / f"{index:04d}.png", view)
        novel_frames.append(Frame(camera, image_path))
        novel_fields.append({"scene_name": other, "file_path": f"test/{index:04d}.exr"})
    write_transforms(images / ORB_NOVEL_FILE, novel_frames, frame_fields=novel_fields)


def resample_envmap(envmap: Envmap, to_world: np.ndarray) -> Envmap:
    """Store the same light in another frame.

    Each texel of the new map is looked up (bilinearly) in ``envmap`` in the direction it stands
    for.

    Parameters
    ----------
    envmap : Envmap
        The light, radiance (H, W, 3).
    to_world : (4, 4) array_like
        The new map's Mitsuba to_world.

    Returns
    -------
    Envmap
        The map with that to_world, (H, W, 3) float32.
    """
    height, width = envmap.radiance.shape[:2]
    # Mitsuba's texel centres: u = (j + 0.5) / W from -z towards +x, v = i / (H - 1) from +y.
    local = local_directions(np.pi * np.arange(height) / (height - 1), 2.0 * np.pi * (np.arange(width) + 0.5) / width)
    world = local @ np.asarray(to_world, np.float64)[:3, :3].T
    radiance = lookup(envmap, world.reshape(-1, 3)).reshape(height, width, 3)
    return Envmap(radiance.astype(np.float32), np.asarray(to_world, np.float64))


def _check_settings(settings: SynthSettings) -> None:
    where = Path("synth settings")
    positive = {
        "views": settings.views, "resolution": settings.resolution, "spp": settings.spp,
        "texture_res": settings.texture_res, "max_depth": settings.max_depth,
    }
    for name, value in positive.items():
        if not (isinstance(value, int) and value >= 1):
            raise InputError(where, f"{name} must be a positive integer, got {value!r}")
    if settings.test_views < 0:
        raise InputError(where, f"test_views must be >= 0, got {settings.test_views}")
    if settings.cameras not in CAMERA_LAYOUTS:
        raise InputError(where, f"cameras must be one of {', '.join(CAMERA_LAYOUTS)}, got {settings.cameras!r}")
    if settings.format not in CAPTURE_FORMATS:
        raise InputError(where, f"format must be one of {', '.join(CAPTURE_FORMATS)}, got {settings.format!r}")
    if settings.envmap_to_world is not None:
        check_rigid(settings.envmap_to_world, where, "envmap_to_world")


def _asset(name: str, bundled: list[str], bundled_path) -> Path:
    """Resolve a bundled asset by name, otherwise ``name`` as a path (its loader reports if it is bad)."""
    return bundled_path(name) if name in bundled else Path(name)


def _test_envmap_paths(settings: SynthSettings, training: Path, rng: np.random.Generator) -> list[Path]:
    if settings.test_views == 0:
        return []
    if isinstance(settings.test_envmaps, int):
        others = [name for name in assets.list_envmaps() if assets.envmap_path(name) != training]
        if not 1 <= settings.test_envmaps <= len(others):
            raise InputError(
                Path("synth settings"),
                f"test_envmaps must be between 1 and {len(others)} (bundled maps other than the "
                f"training one), got {settings.test_envmaps}",
            )
        chosen = rng.choice(len(others), size=settings.test_envmaps, replace=False)
        return [assets.envmap_path(others[k]) for k in sorted(chosen)]
    if not settings.test_envmaps:
        raise InputError(Path("synth settings"), "test_envmaps is empty")
    if any(not str(name).strip() for name in settings.test_envmaps):
        raise InputError(Path("synth settings"), f"test_envmaps has an empty name: {list(settings.test_envmaps)}")
    return [_asset(name, assets.list_envmaps(), assets.envmap_path) for name in settings.test_envmaps]
