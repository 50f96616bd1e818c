"""The capture stage: what was photographed, how, and under which light (docs/method.md#problem, docs/method.md#conventions).

A capture is a triangle mesh with a UV atlas, posed HDR photographs and the distant environment
map they were taken under, optionally with relighting views and ground-truth material maps.

Modules
-------
camera
    Pinhole cameras in the NeRF/Blender convention; reading them from ``transforms.json``.
camera_layouts
    Where cameras go around an object (Fibonacci or random orbits).
layouts
    `Capture` and `Frame`; loading our layout (nerfstudio and NeRF-synthetic files too), writing
    it, summaries.
stanford_orb
    The Stanford-ORB benchmark's layout.
checks
    A loaded capture checked as a whole before any work.
mesh
    Triangle meshes with one UV atlas: loading, xatlas atlases, OBJ output, test meshes.
"""

from freqbrdf.capture.camera import (
    Camera,
    check_rigid,
    focal_length,
    look_at,
    read_cameras,
    rigid_transform_problem,
)
from freqbrdf.capture.camera_layouts import (
    bounding_sphere,
    camera_directions,
    fibonacci_directions,
    orbit_cameras,
    random_directions,
)
from freqbrdf.capture.layouts import (
    Capture,
    Frame,
    describe,
    load,
    read_frame_image,
    read_frame_mask,
)
from freqbrdf.capture.mesh import (
    Mesh,
    generate_atlas,
    load_mesh,
    plane_mesh,
    save_obj,
    smooth_normals,
    unit_or_fallback,
    uv_sphere_mesh,
)
from freqbrdf.capture.stanford_orb import stanford_orb_envmap_to_world
from freqbrdf.capture.transforms_file import write_transforms

__all__ = [
    "Camera",
    "Capture",
    "Frame",
    "Mesh",
    "bounding_sphere",
    "camera_directions",
    "check_rigid",
    "describe",
    "fibonacci_directions",
    "focal_length",
    "generate_atlas",
    "load",
    "load_mesh",
    "look_at",
    "orbit_cameras",
    "plane_mesh",
    "random_directions",
    "read_cameras",
    "read_frame_image",
    "read_frame_mask",
    "rigid_transform_problem",
    "save_obj",
    "smooth_normals",
    "stanford_orb_envmap_to_world",
    "unit_or_fallback",
    "uv_sphere_mesh",
    "write_transforms",
]
