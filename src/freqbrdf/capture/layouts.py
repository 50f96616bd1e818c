"""Captures: posed HDR photographs of a known mesh under a known environment map.

A capture is the input of METHOD.md §1 (mesh, posed HDR photographs, distant environment map),
with cameras in the convention of §2 and, optionally, the relighting views and ground truth used
to judge results (§5). Two layouts load into the same `Capture` (the format is described for
users in docs/capture-format.md):

- ours: ``transforms.json`` in the NeRF/Blender style plus the keys ``mesh``, ``envmap``,
  ``envmap_to_world`` and ``envmap_scale``; optionally ``transforms_test.json`` (relighting views,
  each with its own environment map) and ``gt/`` (ground-truth material maps);
- Stanford-ORB: ``blender_HDR/<scene>/transforms_{train,test,novel}.json`` with
  ``ground_truth/<scene>/{env_map,mesh_blender}``.

`write_transforms` is the only writer of the format. Images and masks are read on demand;
every problem with the input raises `InputError` naming the file.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from freqbrdf.capture.camera import (
    Camera,
    check_rigid,
    required_key,
)
from freqbrdf.capture.camera import (
    frame_camera as _camera,
)
from freqbrdf.capture.camera import (
    frame_entries as _frame_entries,
)
from freqbrdf.capture.camera import (
    positive_number as _number,
)
from freqbrdf.capture.camera import (
    read_json_object as _read_json,
)
from freqbrdf.capture.mesh import Mesh, load_mesh, smooth_normals
from freqbrdf.errors import InputError
from freqbrdf.fileio import atomic_path
from freqbrdf.images import IMAGE_SUFFIXES, read_image, read_mask
from freqbrdf.model.materials import MaterialMaps, load_material_maps
from freqbrdf.sphere.envmap import Envmap, load_envmap

TRANSFORMS_FILE = "transforms.json"
TEST_TRANSFORMS_FILE = "transforms_test.json"
GROUND_TRUTH_FOLDER = "gt"
# Tried in this order when a file_path has no extension, as in NeRF datasets.
IMAGE_SUFFIX_ORDER = (".exr", ".hdr", ".png", ".jpg")

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


@dataclass(frozen=True)
class Frame:
    """One posed photograph of a capture.

    Attributes
    ----------
    camera : Camera
        The camera it was taken with.
    image_path : Path
        The linear HDR image.
    mask_path : Path or None
        The object mask; None means every pixel may show the object.
    envmap_path : Path or None
        Test (relighting) frames only: the environment map this photograph was taken under.
    envmap_to_world : (4, 4) float64 or None
        Test frames only: that map's Mitsuba envmap to_world.
    envmap_scale : float
        Test frames only: the factor applied to that map's radiance.
    """

    camera: Camera
    image_path: Path
    mask_path: Path | None = None
    envmap_path: Path | None = None
    envmap_to_world: np.ndarray | None = None
    envmap_scale: float = 1.0


@dataclass(frozen=True)
class Capture:
    """A loaded capture; images and masks are read on demand.

    Attributes
    ----------
    root : Path
        The folder holding the transforms files.
    layout : str
        "freqbrdf" or "stanford-orb".
    mesh : Mesh
        The object's geometry, with a UV atlas.
    envmap : Envmap
        The lighting of `frames`, in world space, envmap_scale applied.
    envmap_path : Path
        The file ``envmap`` was read from.
    frames : tuple of Frame
        The views to fit (V of them).
    test_frames : tuple of Frame
        Relighting views, each under its own environment map (may be empty).
    ground_truth : MaterialMaps or None
        Ground-truth material maps in texture space, when the capture has them.
    """

    root: Path
    layout: str
    mesh: Mesh
    envmap: Envmap
    envmap_path: Path
    frames: tuple[Frame, ...]
    test_frames: tuple[Frame, ...]
    ground_truth: MaterialMaps | None

    def image(self, index: int) -> np.ndarray:
        """Read the image of a frame.

        Parameters
        ----------
        index : int
            Index into `frames`.

        Returns
        -------
        (H, W, 3) float32
            Linear radiance, validated (see `read_frame_image`).
        """
        return read_frame_image(self.frames[index])

    def mask(self, index: int) -> np.ndarray:
        """Read the object mask of a frame.

        Parameters
        ----------
        index : int
            Index into `frames`.

        Returns
        -------
        (H, W) bool
            The mask; all True when the frame has none.
        """
        return read_frame_mask(self.frames[index])

    def test_image(self, index: int) -> np.ndarray:
        """Read the image of a test frame.

        Parameters
        ----------
        index : int
            Index into `test_frames`.

        Returns
        -------
        (H, W, 3) float32
            Linear radiance, validated (see `read_frame_image`).
        """
        return read_frame_image(self.test_frames[index])

    def test_mask(self, index: int) -> np.ndarray:
        """Read the object mask of a test frame.

        Parameters
        ----------
        index : int
            Index into `test_frames`.

        Returns
        -------
        (H, W) bool
            The mask; all True when the frame has none.
        """
        return read_frame_mask(self.test_frames[index])

    def test_envmap(self, index: int) -> Envmap:
        """Load the environment map a test frame was taken under.

        Parameters
        ----------
        index : int
            Index into `test_frames`.

        Returns
        -------
        Envmap
            The map in world space, its scale applied.
        """
        frame = self.test_frames[index]
        return _load_scaled_envmap(frame.envmap_path, frame.envmap_to_world, frame.envmap_scale)


# ---------------------------------------------------------------------------------------------
# Loading


def load(path: str | Path) -> Capture:
    """Load a capture from its folder or its transforms file.

    The layout is recognised from the files: a folder with ``transforms.json`` (or that file) is
    ours; a folder with ``transforms_train.json`` (or that file) is a Stanford-ORB scene.

    Parameters
    ----------
    path : str or Path
        The capture folder or its transforms file.

    Returns
    -------
    Capture
        The capture, its mesh and environment map loaded, its images not yet read.

    Raises
    ------
    InputError
        Naming the file, for anything missing or malformed.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(path, "capture does not exist")
    transforms_path = path if path.is_file() else path / TRANSFORMS_FILE
    folder = transforms_path.parent
    is_orb = transforms_path.name == ORB_TRAIN_FILE or (
        path.is_dir() and not transforms_path.exists() and (folder / ORB_TRAIN_FILE).is_file()
    )
    if is_orb:
        return _load_stanford_orb(folder)
    return _load_ours(transforms_path)


def read_frame_image(frame: Frame) -> np.ndarray:
    """Read a frame's image.

    Parameters
    ----------
    frame : Frame
        The frame.

    Returns
    -------
    (H, W, 3) float32
        Linear radiance.

    Raises
    ------
    InputError
        If the image cannot be read, has non-finite or negative pixels, or its size is not its
        camera's.
    """
    image = read_image(frame.image_path, validate=True)
    _check_size(frame.image_path, image.shape[:2], frame.camera)
    return image


def read_frame_mask(frame: Frame) -> np.ndarray:
    """Read a frame's object mask.

    Parameters
    ----------
    frame : Frame
        The frame.

    Returns
    -------
    (H, W) bool
        The mask; all True when the frame has none.

    Raises
    ------
    InputError
        If the mask cannot be read or its size is not its camera's.
    """
    if frame.mask_path is None:
        return np.ones((frame.camera.height, frame.camera.width), dtype=bool)
    mask = read_mask(frame.mask_path)
    _check_size(frame.mask_path, mask.shape, frame.camera)
    return mask


def _load_ours(transforms_path: Path) -> Capture:
    root = transforms_path.parent
    document = _read_json(transforms_path)
    frames = _parse_frames(transforms_path, document, with_envmaps=False)
    mesh_path = root / _string(transforms_path, "", document, "mesh")
    envmap_path = root / _string(transforms_path, "", document, "envmap")
    envmap_to_world = check_rigid(
        document.get("envmap_to_world", np.eye(4)), transforms_path, "envmap_to_world"
    )
    envmap_scale = _number(transforms_path, "", "envmap_scale", document.get("envmap_scale", 1.0))
    mesh = load_mesh(mesh_path, atlas_cache=_atlas_cache(mesh_path))
    envmap = _load_scaled_envmap(envmap_path, envmap_to_world, envmap_scale)

    test_path = root / TEST_TRANSFORMS_FILE
    test_frames = ()
    if test_path.exists():
        test_frames = _parse_frames(test_path, _read_json(test_path), with_envmaps=True)
    ground_truth_folder = root / GROUND_TRUTH_FOLDER
    ground_truth = load_material_maps(ground_truth_folder) if ground_truth_folder.is_dir() else None
    return Capture(
        root, "freqbrdf", mesh, envmap, envmap_path, frames, test_frames, ground_truth
    )


def _parse_frames(source: Path, document: dict, with_envmaps: bool) -> tuple[Frame, ...]:
    """Parse the frames of one transforms file of ours; paths are relative to its folder.

    Any per-frame key may also be given at the top level, as the default for every frame.
    """
    root = source.parent
    entries = _frame_entries(source, document)
    image_paths, mask_paths = [], []
    for index, entry in enumerate(entries):
        where = f"frame {index}: "
        image = root / _string(source, where, entry, "file_path")
        image_paths.append(_resolve_image(source, f"image of frame {index}", image))
        if "mask_path" in entry:
            mask = root / _string(source, where, entry, "mask_path")
            mask_paths.append(_resolve_image(source, f"mask of frame {index}", mask))
        else:
            mask_paths.append(None)
    _check_masks_for_all(source, mask_paths)
    size_of_first = functools.cache(lambda: read_image(image_paths[0]).shape[:2])
    frames = []
    for index, (entry, image_path, mask_path) in enumerate(zip(entries, image_paths, mask_paths)):
        camera = _camera(source, index, entry, document, size_of_first)
        if not with_envmaps:
            frames.append(Frame(camera, image_path, mask_path))
            continue
        where = f"frame {index}: "
        defaults = {**document, **entry}
        envmap_to_world = defaults.get("envmap_to_world", np.eye(4))
        envmap_scale = defaults.get("envmap_scale", 1.0)
        frames.append(
            Frame(
                camera,
                image_path,
                mask_path,
                envmap_path=root / _string(source, where, defaults, "envmap"),
                envmap_to_world=check_rigid(envmap_to_world, source, f"{where}envmap_to_world"),
                envmap_scale=_number(source, where, "envmap_scale", envmap_scale),
            )
        )
    return tuple(frames)


def _check_masks_for_all(source: Path, mask_paths: Sequence[Path | None]) -> None:
    """Masks come for every frame or for none: a partial list is almost surely a mistake."""
    missing = [index for index, mask in enumerate(mask_paths) if mask is None]
    if 0 < len(missing) < len(mask_paths):
        raise InputError(
            source,
            f"mask_path given for {len(mask_paths) - len(missing)} of {len(mask_paths)} frames "
            f"(first frame without one: {missing[0]}); give it for every frame or for none",
        )


# --- Stanford-ORB --------------------------------------------------------------------------------


def _load_stanford_orb(scene_folder: Path) -> Capture:
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
    envmap = _load_scaled_envmap(envmap_path, stanford_orb_envmap_to_world(light_pose), 1.0)

    novel_path = scene_folder / ORB_NOVEL_FILE
    test_frames = ()
    if novel_path.exists():
        # Novel-scene views live in the other scene's folders; their poses are already aligned.
        def other_scene(entry: dict) -> str:
            return _string(novel_path, "", entry, "scene_name")

        test_frames = _parse_orb_frames(
            novel_path,
            lambda entry: scene_folder.parent / other_scene(entry),
            lambda entry: ground_truth_root / other_scene(entry),
        )

    mesh_folder = scene_truth / "mesh_blender"
    meshes = sorted(mesh_folder.glob("*.obj"))
    if len(meshes) != 1:
        raise InputError(mesh_folder, f"needs exactly one .obj mesh, found {len(meshes)}")
    mesh = _orb_normals(load_mesh(meshes[0], atlas_cache=_atlas_cache(meshes[0])))
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
        image = image_folder(entry) / _string(source, f"frame {index}: ", entry, "file_path")
        image_paths.append(_resolve_image(source, f"image of frame {index}", image))
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
    photo = Path(_string(source, f"frame {index}: ", entry, "file_path"))
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


# --- shared parsing helpers --------------------------------------------------------------------


def _string(source: Path, where: str, mapping: dict, key: str) -> str:
    value = required_key(source, where, mapping, key)
    if not isinstance(value, str) or not value:
        raise InputError(source, f"{where}{key!r} must be a non-empty string (a path)")
    return value


def _resolve_image(source: Path, what: str, path: Path) -> Path:
    """``path`` itself, or with the first of IMAGE_SUFFIX_ORDER that exists when it has none.

    ``what`` names the file for the error message, e.g. "image of frame 3".
    """
    if path.suffix.lower() in IMAGE_SUFFIXES:
        candidates = [path]
    else:
        candidates = [path.with_name(path.name + suffix) for suffix in IMAGE_SUFFIX_ORDER]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    tried = "" if len(candidates) == 1 else f" (tried {', '.join(IMAGE_SUFFIX_ORDER)})"
    raise InputError(path, f"{what} in {source.name} does not exist{tried}")


def _check_size(path: Path, shape: tuple[int, ...], camera: Camera) -> None:
    height, width = shape
    if (height, width) != (camera.height, camera.width):
        raise InputError(
            path, f"is {width}x{height} pixels but its camera is {camera.width}x{camera.height}"
        )


def _load_scaled_envmap(path: Path, to_world: np.ndarray, scale: float) -> Envmap:
    envmap = load_envmap(path, to_world)
    if scale == 1.0:
        return envmap
    return dataclasses.replace(envmap, radiance=envmap.radiance * np.float32(scale))


def atlas_cache_folder() -> Path:
    """Return where the xatlas atlases of meshes without UVs are kept, outside every capture.

    ``$FREQBRDF_CACHE/atlas``, else ``$XDG_CACHE_HOME/freqbrdf/atlas``, else
    ``~/.cache/freqbrdf/atlas``: a capture folder is never written to (it may be read-only, and a
    batch hashes its files).

    Returns
    -------
    Path
        The folder (not created here).
    """
    base = os.environ.get("FREQBRDF_CACHE")
    if base:
        return Path(base) / "atlas"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "freqbrdf" / "atlas"


def _atlas_cache(mesh_path: Path) -> Path:
    """Name the atlas cache file of a mesh by its content (in `atlas_cache_folder`)."""
    if not Path(mesh_path).is_file():  # `load_mesh` names the missing file
        return atlas_cache_folder() / f"{mesh_path.stem}.obj"
    digest = hashlib.sha256(Path(mesh_path).read_bytes()).hexdigest()[:32]
    return atlas_cache_folder() / f"{mesh_path.stem}-{digest}.obj"


# ---------------------------------------------------------------------------------------------
# Writing


def write_transforms(
    path: str | Path,
    frames: Sequence[Frame],
    *,
    mesh: str | Path | None = None,
    envmap: str | Path | None = None,
    envmap_to_world: np.ndarray | None = None,
    envmap_scale: float | None = None,
    frame_fields: Sequence[dict[str, Any]] | None = None,
) -> None:
    """Write a transforms file of our format, atomically; `load` reads back identical cameras.

    Paths are stored relative to the file's folder. Intrinsics shared by all frames go to the top
    level. Frames with an ``envmap_path`` (test frames) get their own ``envmap``, to_world and
    scale.

    Parameters
    ----------
    path : str or Path
        The file to write (``transforms.json`` or ``transforms_test.json``).
    frames : sequence of Frame
        The frames, at least one.
    mesh, envmap : str or Path, optional
        The mesh and environment map; they belong in ``transforms.json``.
    envmap_to_world : (4, 4) array_like, optional
        The environment map's Mitsuba to_world.
    envmap_scale : float, optional
        The factor applied to the environment map's radiance.
    frame_fields : sequence of dict, optional
        One dict per frame, adding or overriding keys of its entry, e.g. Stanford-ORB's
        ``scene_name`` with a ``file_path`` relative to that scene's folder.

    Raises
    ------
    ValueError
        If ``frames`` is empty or ``frame_fields`` does not have one entry per frame.
    """
    path = Path(path)
    if not frames:
        raise ValueError("write_transforms needs at least one frame")
    if frame_fields is not None and len(frame_fields) != len(frames):
        raise ValueError(f"frame_fields has {len(frame_fields)} entries for {len(frames)} frames")
    folder = path.parent

    def relative(file: str | Path) -> str:
        return Path(os.path.relpath(Path(file).absolute(), folder.absolute())).as_posix()

    document: dict[str, Any] = {}
    if mesh is not None:
        document["mesh"] = relative(mesh)
    if envmap is not None:
        document["envmap"] = relative(envmap)
    if envmap_to_world is not None:
        document["envmap_to_world"] = np.asarray(envmap_to_world, dtype=np.float64).tolist()
    if envmap_scale is not None:
        document["envmap_scale"] = float(envmap_scale)

    intrinsics = [_intrinsics(frame.camera) for frame in frames]
    shared = all(values == intrinsics[0] for values in intrinsics)
    if shared:
        document.update(intrinsics[0])
    entries = []
    for frame, values in zip(frames, intrinsics):
        entry: dict[str, Any] = {"file_path": relative(frame.image_path)}
        if frame.mask_path is not None:
            entry["mask_path"] = relative(frame.mask_path)
        entry["transform_matrix"] = frame.camera.camera_to_world.tolist()
        if not shared:
            entry.update(values)
        if frame.envmap_path is not None:
            entry["envmap"] = relative(frame.envmap_path)
            to_world = np.eye(4) if frame.envmap_to_world is None else frame.envmap_to_world
            entry["envmap_to_world"] = np.asarray(to_world, dtype=np.float64).tolist()
            entry["envmap_scale"] = float(frame.envmap_scale)
        if frame_fields is not None:
            entry.update(frame_fields[len(entries)])
        entries.append(entry)
    document["frames"] = entries
    with atomic_path(path) as tmp:
        # json writes floats in shortest round-trip form, so cameras load back bit for bit.
        tmp.write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")


def _intrinsics(camera: Camera) -> dict[str, float | int]:
    return {
        "fl_x": float(camera.fx),
        "fl_y": float(camera.fy),
        "cx": float(camera.cx),
        "cy": float(camera.cy),
        "w": int(camera.width),
        "h": int(camera.height),
    }


# ---------------------------------------------------------------------------------------------
# Summary


def describe(capture: Capture) -> list[tuple[str, str]]:
    """Summarise a capture without reading its images.

    Parameters
    ----------
    capture : Capture
        The capture.

    Returns
    -------
    list of (str, str)
        (topic, text) lines: the capture, frames, resolution, mesh, environment map, test set and
        ground truth.
    """
    sizes = sorted({(frame.camera.width, frame.camera.height) for frame in capture.frames})
    masked = sum(frame.mask_path is not None for frame in capture.frames)
    mesh = capture.mesh
    extent = mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)
    radiance = capture.envmap.radiance
    lines = [
        ("capture", f"{capture.root} ({capture.layout} layout)"),
        ("frames", f"{len(capture.frames)} views, {masked} with masks"),
        ("resolution", ", ".join(f"{width}x{height}" for width, height in sizes)),
        (
            "mesh",
            f"{mesh.path}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces, "
            f"extent {extent[0]:.3g} x {extent[1]:.3g} x {extent[2]:.3g}",
        ),
        (
            "envmap",
            f"{capture.envmap_path}: {radiance.shape[1]}x{radiance.shape[0]}, "
            f"mean radiance {radiance.mean():.3g}, max {radiance.max():.3g}",
        ),
    ]
    if capture.test_frames:
        lights = len({frame.envmap_path for frame in capture.test_frames})
        lines.append(
            ("test set", f"{len(capture.test_frames)} views under {lights} environment maps")
        )
    else:
        lines.append(("test set", "none"))
    truth = capture.ground_truth
    maps = "none" if truth is None else f"material maps {truth.resolution}x{truth.resolution}"
    lines.append(("ground truth", maps))
    return lines
