"""The Stanford-ORB benchmark's layout, read into a `Capture` (docs/method.md#problem, docs/method.md#evaluation).

``blender_HDR/<scene>/transforms_{train,test,novel}.json`` with
``ground_truth/<scene>/{env_map,mesh_blender}``: the training views are the frames, the
novel-scene test views the relighting frames, and the scene's light is the environment map of its
first test photograph. A folder is read as Stanford-ORB only with its ground-truth folder beside
(`is_stanford_orb_scene`); a bare ``transforms_train.json`` is a NeRF-synthetic split
(`freqbrdf.capture.layouts`). The format for users: docs/capture-format.md.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from pathlib import Path

import numpy as np

from freqbrdf.capture.camera import check_rigid, required_key
from freqbrdf.capture.camera import frame_camera as _camera
from freqbrdf.capture.camera import frame_entries as _frame_entries
from freqbrdf.capture.camera import read_json_object as _read_json
from freqbrdf.capture.layouts import (
    GROUND_TRUTH_FOLDER,
    Capture,
    Frame,
    atlas_cache_path,
    load_scaled_envmap,
    resolve_image,
    string_key,
)
from freqbrdf.capture.mesh import Mesh, load_mesh, smooth_normals
from freqbrdf.errors import InputError
from freqbrdf.images import IMAGE_SUFFIXES, read_image
from freqbrdf.model.materials import load_material_maps

ORB_TRAIN_FILE = "transforms_train.json"
ORB_TEST_FILE = "transforms_test.json"
ORB_NOVEL_FILE = "transforms_novel.json"
# Stanford-ORB stores each environment map in the camera frame of the test photograph it belongs
# to, with longitude u = 0 at +z and u = 1/4 at -x (its orb/utils/env_map.py); Mitsuba's envmap
# has u = 0 at -z and u = 1/4 at +x. The two differ by a half turn about y.
ORB_ENVMAP_TO_MITSUBA = np.diag([-1.0, 1.0, -1.0])
# Its OBJ normals are in another axis convention than its vertices: y and z are exchanged, with
# or without a sign. The candidate that agrees with the surface is chosen (see _orb_normals).
ORB_NORMAL_FIXES = (
    np.eye(3),  # a release with consistent normals
    np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),  # (x, y, z) -> (x, z, -y): Blender Z-up -> Y-up
    np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),  # (x, y, z) -> (x, -z, y)
    np.array([[1.0, 0, 0], [0, 0, 1], [0, 1, 0]]),  # (x, y, z) -> (x, z, y)
)


def is_stanford_orb_scene(scene_folder: Path) -> bool:
    """Whether a folder is a Stanford-ORB scene: its train split, and its ground truth beside.

    Parameters
    ----------
    scene_folder : Path
        A folder holding ``transforms_train.json``.

    Returns
    -------
    bool
        True when ``../../ground_truth/<scene>`` exists, the benchmark's own marker.
    """
    scene_folder = Path(scene_folder)
    return (scene_folder / ORB_TRAIN_FILE).is_file() and (
        scene_folder.parent.parent / "ground_truth" / scene_folder.name).is_dir()


def load_stanford_orb(scene_folder: Path) -> Capture:
    """``blender_HDR/<scene>``: train views as frames, novel-scene test views as test frames.

    The scene's light is the environment map of its first test photograph (Stanford-ORB has one
    per test photograph, none for the training views), placed by that test camera's pose.
    """
    scene = scene_folder.name
    ground_truth_root = scene_folder.parent.parent / "ground_truth"
    scene_truth = ground_truth_root / scene
    if not scene_truth.is_dir():
        raise InputError(
            scene_truth,
            f"Stanford-ORB layout ({ORB_TRAIN_FILE} found) needs this ground-truth folder",
        )
    train_path = scene_folder / ORB_TRAIN_FILE
    frames = _parse_orb_frames(train_path, lambda entry: scene_folder, lambda entry: None)

    test_path = scene_folder / ORB_TEST_FILE
    test_entries = _frame_entries(test_path, _read_json(test_path))
    light_pose = check_rigid(
        required_key(test_path, "frame 0: ", test_entries[0], "transform_matrix"),
        test_path,
        "frame 0: transform_matrix",
    )
    envmap_path = _orb_envmap_path(test_path, 0, test_entries[0], scene_truth)
    envmap = load_scaled_envmap(envmap_path, stanford_orb_envmap_to_world(light_pose), 1.0)

    novel_path = scene_folder / ORB_NOVEL_FILE
    test_frames = ()
    if novel_path.exists():
        # Novel-scene views live in the other scene's folders; their poses are already aligned.
        def other_scene(entry: dict) -> str:
            return string_key(novel_path, "", entry, "scene_name")

        test_frames = _parse_orb_frames(
            novel_path,
            lambda entry: scene_folder.parent / other_scene(entry),
            lambda entry: ground_truth_root / other_scene(entry),
        )

    mesh_folder = scene_truth / "mesh_blender"
    meshes = sorted(mesh_folder.glob("*.obj"))
    if len(meshes) != 1:
        raise InputError(mesh_folder, f"needs exactly one .obj mesh, found {len(meshes)}")
    mesh = _orb_normals(load_mesh(meshes[0], atlas_cache=atlas_cache_path(meshes[0])))
    # Stanford-ORB has no texture-space ground truth; synthetic captures in its layout add gt/.
    truth_maps = scene_truth / GROUND_TRUTH_FOLDER
    ground_truth = load_material_maps(truth_maps) if truth_maps.is_dir() else None
    return Capture(
        scene_folder, "stanford-orb", mesh, envmap, envmap_path, frames, test_frames, ground_truth
    )


def _parse_orb_frames(
    source: Path,
    image_folder: Callable[[dict], Path],
    truth_folder: Callable[[dict], Path | None],
) -> tuple[Frame, ...]:
    """Parse the frames of a Stanford-ORB transforms file.

    Masks are ``<images>_mask/<name>.png``; with a ``truth_folder`` each frame gets its
    environment map, placed by its camera.
    """
    document = _read_json(source)
    entries = _frame_entries(source, document)
    image_paths = []
    for index, entry in enumerate(entries):
        image = image_folder(entry) / string_key(source, f"frame {index}: ", entry, "file_path")
        image_paths.append(resolve_image(source, f"image of frame {index}", image))
    mask_paths = [
        image.parent.with_name(image.parent.name + "_mask") / f"{image.stem}.png"
        for image in image_paths
    ]
    missing = [mask for mask in mask_paths if not mask.is_file()]
    if len(missing) == len(mask_paths):
        mask_paths = [None] * len(image_paths)
    elif missing:
        raise InputError(
            missing[0].parent,
            f"has no mask for {len(missing)} of {len(mask_paths)} frames of {source.name} "
            f"(first missing: {missing[0].name})",
        )
    size_of_first = functools.cache(lambda: read_image(image_paths[0]).shape[:2])
    frames = []
    for index, (entry, image_path, mask_path) in enumerate(zip(entries, image_paths, mask_paths)):
        camera = _camera(source, index, entry, document, size_of_first)
        truth = truth_folder(entry)
        if truth is None:
            frames.append(Frame(camera, image_path, mask_path))
            continue
        envmap_path = _orb_envmap_path(source, index, entry, truth)
        envmap_to_world = stanford_orb_envmap_to_world(camera.camera_to_world)
        frames.append(Frame(camera, image_path, mask_path, envmap_path, envmap_to_world))
    return tuple(frames)


def _orb_envmap_path(source: Path, index: int, entry: dict, scene_truth: Path) -> Path:
    """``env_map/<name>.exr``, named after the test photograph; it must exist."""
    photo = Path(string_key(source, f"frame {index}: ", entry, "file_path"))
    name = photo.stem if photo.suffix.lower() in IMAGE_SUFFIXES else photo.name
    envmap_path = scene_truth / "env_map" / f"{name}.exr"
    if not envmap_path.is_file():
        raise InputError(
            envmap_path, f"environment map of frame {index} in {source.name} does not exist"
        )
    return envmap_path


def stanford_orb_envmap_to_world(camera_to_world: np.ndarray) -> np.ndarray:
    """Place a Stanford-ORB environment map, stored in a camera's frame, in world space.

    Parameters
    ----------
    camera_to_world : (4, 4) array_like
        The pose of the camera whose frame the map is stored in.

    Returns
    -------
    (4, 4) float64
        The map's Mitsuba envmap to_world (a rotation).
    """
    to_world = np.eye(4)
    to_world[:3, :3] = np.asarray(camera_to_world)[:3, :3] @ ORB_ENVMAP_TO_MITSUBA
    return to_world


def _orb_normals(mesh: Mesh) -> Mesh:
    """Undo the axis exchange of Stanford-ORB's normals.

    Keeps the candidate in ORB_NORMAL_FIXES that agrees best with the area-weighted normals of
    the triangles themselves.
    """
    geometric = smooth_normals(mesh.vertices, mesh.faces)  # (V, 3)
    agreement = [
        np.mean(np.sum((mesh.normals @ fix.T) * geometric, axis=1)) for fix in ORB_NORMAL_FIXES
    ]
    best = ORB_NORMAL_FIXES[int(np.argmax(agreement))]
    return dataclasses.replace(mesh, normals=mesh.normals @ best.T)
