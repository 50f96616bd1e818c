"""Mitsuba 3 scenes built from our arrays, and rendering helpers.

Mitsuba renders the synthetic captures and the relighting views that results are judged on
(docs/method.md#evaluation); its ``envmap`` convention is the one our environment maps follow (docs/method.md#conventions). Mitsuba
itself is imported only when a function here needs it (`mitsuba`). Scenes are Python dicts in
Mitsuba's own style; only the mesh is built as an ``mi.Mesh`` object because its buffers come
from our arrays. The conventions that join our data to Mitsuba's are each proved by a test in
tests/test_synth.py:

- UVs: ours are OBJ's (origin bottom-left: texel row i, column j is centred at
  uv = ((j + 0.5)/T, 1 - (i + 0.5)/T)); Mitsuba's ``bitmap`` reads texel row floor(v T), row 0
  at v = 0. The mesh is therefore given texcoords (u, 1 - v), which is what Mitsuba's own OBJ
  loader does, and texture arrays are passed unflipped.
- Cameras: ours use OpenGL axes (x right, y up, looking down -z). Mitsuba's perspective camera
  looks down +z with +y up, so its +x points to the image's left: to_world = c2w diag(-1, 1, -1, 1),
  a half turn about the camera's y axis. Its principal point offset, in film-size units, moves
  the optical axis to film coordinate 0.5 - offset, hence offset = 0.5 - c/size.
- Environment maps: our ``Envmap`` is defined in Mitsuba's ``envmap`` convention, so it is handed
  over as it is (radiance bitmap and to_world).

Pixels are reconstructed with a ``box`` filter: each pixel is then the unbiased average of the
radiance over its own footprint, which is what the observation stage assumes when it samples an
image; a Gaussian filter would blend neighbouring pixels and widen silhouettes in the masks.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import glob
import os
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # only attributes are used, so importing render stays cheap
    from freqbrdf.capture.camera import Camera
    from freqbrdf.capture.mesh import Mesh
    from freqbrdf.model.materials import MaterialMaps
    from freqbrdf.sphere.envmap import Envmap

MITSUBA_VARIANT = "llvm_ad_rgb"
DEFAULT_MAX_DEPTH = 8  # path length 8: seven bounces, enough for interreflections on a convex-ish object
MIN_LLVM_VERSION = 17  # Dr.Jit's LLVM backend aborts with libLLVM 14-16
_LIBLLVM_PATTERNS = (  # where Dr.Jit itself looks on Linux
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/libLLVM*.so*",
)

# OpenGL camera axes -> Mitsuba camera axes (x and z flip; see the module docstring).
_GL_TO_MITSUBA_CAMERA = np.diag([-1.0, 1.0, -1.0, 1.0])


def _newest_libllvm() -> tuple[int, str] | None:
    """Find (major version, path) of the newest system libLLVM, or None if none is found."""
    found = []
    for pattern in _LIBLLVM_PATTERNS:
        for path in glob.glob(pattern):
            match = re.search(r"libLLVM[-.](?:so\.)?(\d+)", os.path.basename(path))
            if match:
                found.append((int(match.group(1)), path))
    return max(found) if found else None


_LIBM = ctypes.CDLL(ctypes.util.find_library("m"))


@contextlib.contextmanager
def restored_floating_point() -> Iterator[None]:
    """Restore the calling thread's floating-point environment after Mitsuba has run on it.

    Mitsuba's tracing (Embree, Dr.Jit's thread pool) may leave flush-to-zero and
    denormals-are-zero set on the calling thread, and only on some runs. numba's kernels would
    then compute differently on this thread than on their own workers, and a fit's maps would
    change in their last digits from one run to the next.

    Yields
    ------
    None
        Control, inside the saved environment; it is restored on exit, also on an exception.
    """
    environment = ctypes.create_string_buffer(64)  # fenv_t: 32 bytes on x86-64 glibc
    _LIBM.fegetenv(environment)
    try:
        yield
    finally:
        _LIBM.fesetenv(environment)


def mitsuba() -> ModuleType:
    """Import Mitsuba with the CPU variant ``llvm_ad_rgb`` set, or fail with what to install.

    Dr.Jit picks the first libLLVM it finds; with several installed that may be an old one that
    aborts the process, so unless DRJIT_LIBLLVM_PATH is set it is pointed at the newest.

    Returns
    -------
    module
        The ``mitsuba`` module, variant set.

    Raises
    ------
    RuntimeError
        If only a libLLVM older than ``MIN_LLVM_VERSION`` is found or the variant cannot be set.
    """
    if "DRJIT_LIBLLVM_PATH" not in os.environ:
        newest = _newest_libllvm()
        if newest is not None and newest[0] >= MIN_LLVM_VERSION:
            os.environ["DRJIT_LIBLLVM_PATH"] = newest[1]
        elif newest is not None:
            raise RuntimeError(
                f"Mitsuba's CPU renderer needs libLLVM >= {MIN_LLVM_VERSION}, found only "
                f"{newest[1]}; install it with: sudo apt-get install libllvm19"
            )
    import mitsuba as mi

    if mi.variant() != MITSUBA_VARIANT:
        try:
            mi.set_variant(MITSUBA_VARIANT)
        except ImportError as err:
            raise RuntimeError(
                f"Mitsuba's {MITSUBA_VARIANT} variant needs libLLVM >= {MIN_LLVM_VERSION} "
                "(install it with: sudo apt-get install libllvm19, or set DRJIT_LIBLLVM_PATH): "
                f"{err}"
            ) from err
    return mi


# ---------------------------------------------------------------------------------------------
# Scene pieces, as Mitsuba dicts


def principled_bsdf(materials: MaterialMaps) -> dict:
    """Make a ``principled`` BSDF whose base colour, roughness and metallic are texture maps.

    Base colour is linear RGB, so no sRGB decoding is wanted (Mitsuba applies none to float
    tensors in RGB variants); roughness and metallic are data, hence ``raw``. Filtering is
    bilinear between texel centres, which is where our texels hold their values; ``clamp``
    wrapping keeps the edges of the UV square from bleeding into each other.

    Parameters
    ----------
    materials : MaterialMaps
        The maps: base colour (T, T, 3), roughness and metallic (T, T), float.

    Returns
    -------
    dict
        A Mitsuba BSDF dict holding the maps as float32 bitmap tensors.
    """
    mi = mitsuba()

    def texture(values: np.ndarray, raw: bool) -> dict:
        if values.ndim == 2:
            values = values[..., None]
        return {
            "type": "bitmap",
            "data": mi.TensorXf(np.ascontiguousarray(values, dtype=np.float32)),
            "raw": raw,
            "filter_type": "bilinear",
            "wrap_mode": "clamp",
        }

    return {
        "type": "principled",
        "base_color": texture(materials.base_color, raw=False),
        "roughness": texture(materials.roughness, raw=True),
        "metallic": texture(materials.metallic, raw=True),
    }


def mesh_shape(mesh: Mesh, bsdf: dict, name: str = "mesh"):
    """Build an ``mi.Mesh`` holding our vertex positions, faces, normals and UVs.

    Parameters
    ----------
    mesh : Mesh
        The mesh.
    bsdf : dict
        Its BSDF, as a Mitsuba dict. It is used up: Mitsuba takes over the tensors of bitmap
        textures when it loads them.
    name : str, optional
        The shape's name in the scene.

    Returns
    -------
    mitsuba.Mesh
        The shape, texcoords (u, 1 - v) as Mitsuba's bitmaps expect.
    """
    mi = mitsuba()
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    shape = mi.Mesh(
        name,
        vertex_count=len(mesh.vertices),
        face_count=len(mesh.faces),
        props=props,
        has_vertex_normals=True,
        has_vertex_texcoords=True,
    )
    # Mitsuba's bitmap puts v = 0 at the top row; ours (OBJ) at the bottom row.
    texcoords = np.stack([mesh.uv[:, 0], 1.0 - mesh.uv[:, 1]], axis=-1)
    params = mi.traverse(shape)
    params["vertex_positions"] = mi.Float(np.asarray(mesh.vertices, np.float32).ravel())
    params["faces"] = mi.UInt32(np.asarray(mesh.faces, np.uint32).ravel())
    params["vertex_normals"] = mi.Float(np.asarray(mesh.normals, np.float32).ravel())
    params["vertex_texcoords"] = mi.Float(texcoords.astype(np.float32).ravel())
    params.update()
    return shape


def envmap_emitter(envmap: Envmap) -> dict:
    """Make an ``envmap`` emitter showing our environment map (same convention, no conversion).

    Parameters
    ----------
    envmap : Envmap
        The map: radiance (H, W, 3) float32 and its to_world.

    Returns
    -------
    dict
        A Mitsuba emitter dict.
    """
    mi = mitsuba()
    return {
        "type": "envmap",
        # A writeable array (Mitsuba takes no read-only one; a transformed map's radiance is read-only).
        "bitmap": mi.Bitmap(np.require(envmap.radiance, np.float32, ["C", "W"])),
        "to_world": mi.ScalarTransform4f(np.asarray(envmap.to_world, np.float64)),
    }


def mitsuba_to_world(camera: Camera) -> np.ndarray:
    """Convert a camera's OpenGL camera-to-world matrix to Mitsuba's sensor to_world.

    Parameters
    ----------
    camera : Camera
        The camera.

    Returns
    -------
    (4, 4) float64
        camera_to_world diag(-1, 1, -1, 1): a half turn about the camera's y axis.
    """
    return np.asarray(camera.camera_to_world, np.float64) @ _GL_TO_MITSUBA_CAMERA


def perspective_sensor(camera: Camera, spp: int) -> dict:
    """Make a pinhole ``perspective`` sensor reproducing a camera exactly.

    The film is float32 RGBA with a box reconstruction filter (see the module docstring).

    Parameters
    ----------
    camera : Camera
        The camera; its pixels must be square (fx = fy).
    spp : int
        Samples per pixel of the sensor's sampler.

    Returns
    -------
    dict
        A Mitsuba sensor dict.

    Raises
    ------
    ValueError
        If fx and fy differ.
    """
    mi = mitsuba()
    if not np.isclose(camera.fx, camera.fy, rtol=1e-6):
        raise ValueError(
            f"Mitsuba's perspective camera has square pixels; got fx={camera.fx}, fy={camera.fy}"
        )
    fov_x = np.degrees(2.0 * np.arctan(0.5 * camera.width / camera.fx))
    return {
        "type": "perspective",
        "fov": float(fov_x),
        "fov_axis": "x",
        "principal_point_offset_x": float(0.5 - camera.cx / camera.width),
        "principal_point_offset_y": float(0.5 - camera.cy / camera.height),
        "to_world": mi.ScalarTransform4f(mitsuba_to_world(camera)),
        "film": {
            "type": "hdrfilm",
            "width": int(camera.width),
            "height": int(camera.height),
            "pixel_format": "rgba",
            "component_format": "float32",
            "rfilter": {"type": "box"},
        },
        "sampler": {"type": "independent", "sample_count": int(spp)},
    }


def path_integrator(max_depth: int = DEFAULT_MAX_DEPTH) -> dict:
    """Make a unidirectional path tracer; the environment stays visible behind the object.

    Parameters
    ----------
    max_depth : int, optional
        Maximum path length (Mitsuba's ``max_depth``).

    Returns
    -------
    dict
        A Mitsuba integrator dict.
    """
    return {"type": "path", "max_depth": int(max_depth), "hide_emitters": False}


def build_scene(mesh: Mesh, bsdf: dict, envmap: Envmap, max_depth: int = DEFAULT_MAX_DEPTH):
    """Build the scene: a mesh with a BSDF under an environment map, path traced.

    Sensors are given per view (`render_view`).

    Parameters
    ----------
    mesh : Mesh
        The object, named "object" in the scene.
    bsdf : dict
        Its BSDF as a Mitsuba dict (used up, see `mesh_shape`).
    envmap : Envmap
        The lighting.
    max_depth : int, optional
        Maximum path length.

    Returns
    -------
    mitsuba.Scene
        The loaded scene.
    """
    mi = mitsuba()
    with restored_floating_point():  # building the scene traces nothing but builds Embree's BVH
        return mi.load_dict(
            {
                "type": "scene",
                "integrator": path_integrator(max_depth),
                "object": mesh_shape(mesh, bsdf),
                "environment": envmap_emitter(envmap),
            }
        )


# ---------------------------------------------------------------------------------------------
# Rendering


@dataclass(frozen=True)
class RenderedView:
    """One rendered view.

    Attributes
    ----------
    radiance : (H, W, 3) float32
        Linear radiance: box-filtered pixel averages, the environment visible behind the object.
    coverage : (H, W) float32
        Fraction of each pixel covered by the scene's shapes, in [0, 1].
    """

    radiance: np.ndarray
    coverage: np.ndarray


def view_seed(seed: int, view_index: int) -> int:
    """Derive a view's render seed, distinct across views and across runs' seeds.

    Parameters
    ----------
    seed : int
        The run's seed.
    view_index : int
        The view's index.

    Returns
    -------
    int
        A 32-bit seed.
    """
    return int(np.random.SeedSequence([seed, view_index]).generate_state(1)[0])


def render_view(scene, camera: Camera, spp: int, seed: int) -> RenderedView:
    """Path-trace one view and measure the object's pixel coverage with a primary-ray pass.

    Parameters
    ----------
    scene : mitsuba.Scene
        A scene from `build_scene`.
    camera : Camera
        The view (square pixels).
    spp : int
        Samples per pixel.
    seed : int
        The render seed.

    Returns
    -------
    RenderedView
        Radiance and coverage of the view.
    """
    mi = mitsuba()
    with restored_floating_point():
        sensor = mi.load_dict(perspective_sensor(camera, spp))
        rgba = np.array(mi.render(scene, sensor=sensor, spp=spp, seed=seed))
        # The path tracer's alpha is 1 wherever the visible envmap is hit; the depth integrator's
        # alpha is exactly "the camera ray hit a surface", averaged over the pixel's samples.
        coverage_integrator = mi.load_dict({"type": "depth"})
        depth_alpha = np.array(
            mi.render(scene, sensor=sensor, spp=spp, seed=seed, integrator=coverage_integrator)
        )
    return RenderedView(
        radiance=np.ascontiguousarray(rgba[..., :3], dtype=np.float32),
        coverage=np.ascontiguousarray(np.clip(depth_alpha[..., 3], 0.0, 1.0), dtype=np.float32),
    )


def render_views(
    scene, cameras: Sequence[Camera], spp: int, seed: int, first_index: int = 0
) -> Iterator[RenderedView]:
    """Render views one after another.

    The scene is built once; each view only adds a sensor, and Dr.Jit reuses the compiled
    kernels because a sensor's transform and intrinsics are not baked into them.

    Parameters
    ----------
    scene : mitsuba.Scene
        A scene from `build_scene`.
    cameras : sequence of Camera
        The views.
    spp : int
        Samples per pixel.
    seed : int
        The run's seed; view k gets ``view_seed(seed, first_index + k)``.
    first_index : int, optional
        The index of the first camera among all the run's views.

    Yields
    ------
    RenderedView
        One per camera, in order.
    """
    for index, camera in enumerate(cameras, start=first_index):
        yield render_view(scene, camera, spp, view_seed(seed, index))
