"""Captures: posed HDR photographs of a known mesh under a known environment map.

A capture is the input of docs/method.md#problem (mesh, posed HDR photographs, distant environment map),
with cameras in the convention of docs/method.md#conventions and, optionally, the relighting views and ground truth used
to judge results (docs/method.md#evaluation). Three layouts load into the same `Capture` (the format is described for
users in docs/capture-format.md):

- ours: ``transforms.json`` in the NeRF/Blender style plus the keys ``mesh``, ``envmap``,
  ``envmap_to_world`` and ``envmap_scale``; optionally ``transforms_test.json`` (relighting views,
  each under its own environment map or the capture's) and ``gt/`` (ground-truth material maps).
  A nerfstudio file is ours too: its ``applied_transform`` and ``applied_scale`` are undone, so
  the cameras are in the frame of the reconstruction the mesh comes from;
- NeRF-synthetic: ``transforms_{train,test}.json`` with the same keys, the train split fitted,
  the test split relit; RGBA images give their alpha as the mask;
- Stanford-ORB (`freqbrdf.capture.stanford_orb`), recognised by its ground-truth folder.

`write_transforms` is the only writer of the format. Images and masks are read on demand;
every problem with the input raises `InputError` naming the file.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import threading
import warnings
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from freqbrdf.capture.camera import (
    Camera,
    check_rigid,
    frame_lens,
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
from freqbrdf.capture.lens import LensDistortion, undistort_image
from freqbrdf.capture.mesh import Mesh, load_mesh
from freqbrdf.errors import InputError
from freqbrdf.images import IMAGE_SUFFIXES, image_has_alpha, read_image, read_mask_coverage
from freqbrdf.model.materials import MaterialMaps, load_material_maps
from freqbrdf.sphere.envmap import Envmap, load_envmap

TRANSFORMS_FILE = "transforms.json"
TEST_TRANSFORMS_FILE = "transforms_test.json"
# NeRF-synthetic's training split; a folder with it and without transforms.json is that layout.
TRAIN_TRANSFORMS_FILE = "transforms_train.json"
GROUND_TRUTH_FOLDER = "gt"
# Tried in this order when a file_path has no extension, as in NeRF datasets.
IMAGE_SUFFIX_ORDER = (".exr", ".hdr", ".png", ".jpg")



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
    mask_from_alpha : bool
        The mask is the alpha channel of ``mask_path`` (alpha > 0.5), as in NeRF-synthetic's
        RGBA images.
    exposure : (3,) float tuple or None
        The factor per colour channel the image is multiplied by as it is read: the calibration's
        correction of its exposure and white balance (`freqbrdf.calibrate`); None: 1.
    mask_inset_px : float
        Pixels the mask is taken in by as it is read (`read_frame_mask`): where the calibration
        found it drawn wider than the object (a segmentation's halo); 0: as drawn.
    lens : LensDistortion or None
        The lens's distortion (`freqbrdf.capture.lens`): the observations read the photograph
        through it (``as_taken``), other readers get it resampled onto the camera's pinhole image;
        None: a pinhole photograph.
    """

    camera: Camera
    image_path: Path
    mask_path: Path | None = None
    envmap_path: Path | None = None
    envmap_to_world: np.ndarray | None = None
    envmap_scale: float = 1.0
    mask_from_alpha: bool = False
    exposure: tuple[float, float, float] | None = None
    mask_inset_px: float = 0.0
    lens: LensDistortion | None = None


@dataclass(frozen=True)
class Capture:
    """A loaded capture; images and masks are read on demand.

    Attributes
    ----------
    root : Path
        The folder holding the transforms files.
    layout : str
        "freqbrdf", "nerfstudio" (ours, with its applied transform undone), "nerf-synthetic" or
        "stanford-orb".
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
    ground_truth_refused : str or None
        Why the capture's ``gt/`` maps were not loaded (they are in a UV layout the mesh used
        here does not have); None when there are none or they were loaded.
    """

    root: Path
    layout: str
    mesh: Mesh
    envmap: Envmap
    envmap_path: Path
    frames: tuple[Frame, ...]
    test_frames: tuple[Frame, ...]
    ground_truth: MaterialMaps | None
    ground_truth_refused: str | None = None

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
        return load_scaled_envmap(frame.envmap_path, frame.envmap_to_world, frame.envmap_scale)


# ---------------------------------------------------------------------------------------------
# Loading


def load(path: str | Path) -> Capture:
    """Load a capture from its folder or its transforms file.

    The layout is recognised from the files: a folder with ``transforms.json`` (or that file) is
    ours; a folder with ``transforms_train.json`` (or that file) is a Stanford-ORB scene when the
    benchmark's ground-truth folder lies beside it, else a NeRF-synthetic scene.

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

    Examples
    --------
    A tiny synthetic capture (`freqbrdf.synthetic.synthesize`: six 24 x 24 views of a sphere,
    with ground-truth maps), loaded from its folder:

    >>> import tempfile
    >>> from pathlib import Path
    >>> from freqbrdf.capture import load
    >>> from freqbrdf.synthetic import example_capture
    >>> work = tempfile.TemporaryDirectory()
    >>> folder = example_capture(Path(work.name) / "capture")
    >>> sorted(path.name for path in folder.iterdir())
    ['.freqbrdf', 'envmap.exr', 'gt', 'images', 'masks', 'mesh.obj', 'transforms.json']
    >>> capture = load(folder)
    >>> capture.layout, len(capture.frames), len(capture.test_frames)
    ('freqbrdf', 6, 0)
    >>> capture.image(0).shape, capture.image(0).dtype, capture.mask(0).shape  # read on demand
    ((24, 24, 3), dtype('float32'), (24, 24))
    >>> capture.ground_truth.base_color.shape
    (16, 16, 3)
    >>> work.cleanup()
    """
    from freqbrdf.capture import stanford_orb  # it builds on this module

    path = Path(path)
    if not path.exists():
        raise InputError(path, "capture does not exist")
    transforms_path = path if path.is_file() else path / TRANSFORMS_FILE
    if path.is_dir() and not transforms_path.exists() and (path / TRAIN_TRANSFORMS_FILE).is_file():
        transforms_path = path / TRAIN_TRANSFORMS_FILE
    if transforms_path.name == TRAIN_TRANSFORMS_FILE and stanford_orb.is_stanford_orb_scene(transforms_path.parent):
        return stanford_orb.load_stanford_orb(transforms_path.parent)
    return _load_ours(transforms_path)


# Decoded frames kept for the next reader, up to this many bytes (least recently used out first): a
# fit reads each photograph and mask several times (the capture check, calibration, observation),
# then lets them go (`release_decoded_frames`).
DECODED_CACHE_BYTES = 256 << 20


class _DecodedFiles:
    """Arrays decoded from files, keyed by the file's path, inode, size and modification time, read-only.

    The warnings a read raised are kept with its array and raised again on each later hit, so a
    reader sees the same warnings whether the file was decoded for it or before.
    """

    def __init__(self, max_bytes: int):
        self._max_bytes = max_bytes
        self._items: OrderedDict = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self._bytes = 0

    def get(self, path: Path, what: tuple, read: Callable[[], np.ndarray]) -> np.ndarray:
        try:
            status = path.stat()
        except OSError:
            return read()  # the reader names the file and the problem
        key = (str(path.resolve()), status.st_ino, status.st_size, status.st_mtime_ns, what)
        with self._lock:
            item = self._items.get(key)
            if item is not None:
                self._items.move_to_end(key)
        if item is None:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                array = read()
            array.flags.writeable = False
            item = (array, tuple(caught))
            with self._lock:
                if array.nbytes <= self._max_bytes and key not in self._items:
                    self._items[key] = item
                    self._bytes += array.nbytes
                    while self._bytes > self._max_bytes:
                        self._bytes -= self._items.popitem(last=False)[1][0].nbytes
        for warning in item[1]:
            warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
        return item[0]


_DECODED = _DecodedFiles(DECODED_CACHE_BYTES)


def release_decoded_frames() -> None:
    """Forget the decoded photographs and masks kept for later readers (their memory goes)."""
    _DECODED.clear()


def read_frame_image(frame: Frame, as_taken: bool = False) -> np.ndarray:
    """Read a frame's image.

    Parameters
    ----------
    frame : Frame
        The frame.
    as_taken : bool, optional
        Through its lens, as photographed (for a reader that projects through ``frame.lens``
        itself); by default resampled onto the camera's pinhole image.

    Returns
    -------
    (H, W, 3) float32
        Linear radiance, read-only (decoded once and shared by every reader of the frame).

    Raises
    ------
    InputError
        If the image cannot be read, has non-finite or negative pixels, or its size is not its
        camera's.
    """
    lens = None if as_taken else frame.lens
    image = _DECODED.get(frame.image_path, ("image", *_lens_key(frame, lens)),
                         lambda: _pinhole(frame, lens, frame.image_path, read_image(frame.image_path, validate=True)))
    _check_size(frame.image_path, image.shape[:2], frame.camera)
    if frame.exposure is not None:
        image = image * np.asarray(frame.exposure, dtype=np.float32)
        image.flags.writeable = False
    return image


def read_frame_mask(frame: Frame, as_taken: bool = False) -> np.ndarray:
    """Read a frame's object mask.

    Parameters
    ----------
    frame : Frame
        The frame.
    as_taken : bool, optional
        Through its lens (see `read_frame_image`).

    Returns
    -------
    (H, W) bool
        The mask; all True when the frame has none. Taken in by ``frame.mask_inset_px``: the
        pixels whose centre lies within that and half a pixel of its edge are left out.

    Raises
    ------
    InputError
        If the mask cannot be read or its size is not its camera's.
    """
    mask = read_frame_mask_coverage(frame, as_taken) > 0.5
    if frame.mask_inset_px > 0.0 and frame.mask_path is not None:
        # A pixel whose footprint reaches the rim (its centre within the inset and half a pixel) is left out.
        mask = ndimage.distance_transform_edt(mask) > frame.mask_inset_px + 0.5
    return mask


def read_frame_mask_coverage(frame: Frame, as_taken: bool = False) -> np.ndarray:
    """Read a frame's object mask as coverage (an anti-aliased mask's edge pixels between 0 and 1).

    Parameters
    ----------
    frame : Frame
        The frame.
    as_taken : bool, optional
        Through its lens (see `read_frame_image`).

    Returns
    -------
    (H, W) float32
        The share of each pixel the object covers; all 1 when the frame has none; read-only.

    Raises
    ------
    InputError
        If the mask cannot be read or its size is not its camera's.
    """
    lens = None if as_taken else frame.lens
    whole = np.ones((frame.camera.height, frame.camera.width), dtype=np.float32)
    if frame.mask_path is None and lens is None:
        return whole
    if frame.mask_path is None:  # through a lens: the pixels it saw
        return _DECODED.get(frame.image_path, ("lens coverage", *_lens_key(frame, lens)),
                            lambda: _pinhole(frame, lens, frame.image_path, whole, coverage=True))
    coverage = _DECODED.get(frame.mask_path, ("mask", frame.mask_from_alpha, *_lens_key(frame, lens)),
                            lambda: _pinhole(frame, lens, frame.mask_path, read_mask_coverage(
                                frame.mask_path, from_alpha=frame.mask_from_alpha), coverage=True))
    _check_size(frame.mask_path, coverage.shape, frame.camera)
    return coverage


def _lens_key(frame: Frame, lens: LensDistortion | None) -> tuple:
    """Return what a decoded file's resampling depends on: the lens and the camera's intrinsics (none for a pinhole)."""
    if lens is None:
        return ()
    camera = frame.camera
    return (lens, camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)


def _pinhole(frame: Frame, lens: LensDistortion | None, path: Path, pixels: np.ndarray,
             coverage: bool = False) -> np.ndarray:
    """Return a decoded image or mask of ``frame`` resampled through ``lens`` onto its pinhole image (None: as read).

    A mask's ``coverage`` stays at most 1 (the resampling rings at its edge).
    """
    if lens is None:
        return pixels
    _check_size(path, pixels.shape[:2], frame.camera)
    found = undistort_image(pixels, frame.camera, lens)
    return np.minimum(found, np.float32(1.0), out=found) if coverage else found


def _load_ours(transforms_path: Path) -> Capture:
    root = transforms_path.parent
    document = _read_json(transforms_path)
    layout = "nerf-synthetic" if transforms_path.name == TRAIN_TRANSFORMS_FILE else "freqbrdf"
    for key, what in (("mesh", "the object's mesh"), ("envmap", "the environment map it was photographed under")):
        if key not in document:
            raise InputError(transforms_path, f"missing required key {key!r}: freqbrdf needs {what}; add "
                             f'"{key}": "<path relative to this file>" (docs/capture-format.md)')
    mesh_path = root / string_key(transforms_path, "", document, "mesh")
    envmap_path = root / string_key(transforms_path, "", document, "envmap")
    envmap_to_world = check_rigid(
        document.get("envmap_to_world", np.eye(4)), transforms_path, "envmap_to_world"
    )
    envmap_scale = _number(transforms_path, "", "envmap_scale", document.get("envmap_scale", 1.0))
    reconstruction = reconstruction_from_transforms(transforms_path, document)
    if reconstruction is not None:
        layout = "nerfstudio"
    frames = _parse_frames(transforms_path, document, reconstruction=reconstruction)
    mesh = load_mesh(mesh_path, atlas_cache=atlas_cache_path(mesh_path))
    envmap = load_scaled_envmap(envmap_path, envmap_to_world, envmap_scale)

    test_path = root / TEST_TRANSFORMS_FILE
    test_frames = ()
    if test_path.exists():
        test_frames = _parse_frames(test_path, _read_json(test_path), reconstruction=reconstruction,
                                    light=(envmap_path, envmap_to_world, envmap_scale))
    ground_truth_folder = root / GROUND_TRUTH_FOLDER
    ground_truth, refused = None, None
    if ground_truth_folder.is_dir() and mesh.atlas_generated:
        refused = (f"its maps are in a UV layout of their own, but {mesh_path.name} has no usable UVs (freqbrdf "
                   "made an atlas for it), so they cannot be compared; give the mesh with the UVs the maps were made "
                   "for")
    elif ground_truth_folder.is_dir():
        ground_truth = load_material_maps(ground_truth_folder)
    return Capture(
        root, layout, mesh, envmap, envmap_path, frames, test_frames, ground_truth, refused
    )


def reconstruction_from_transforms(source: Path, document: dict) -> np.ndarray | None:
    """Return what undoes nerfstudio's ``applied_transform`` and ``applied_scale``, if given.

    nerfstudio's data processing writes poses as ``applied_scale * (applied_transform @ pose)``
    (positions scaled) of the reconstruction it read; a mesh of that reconstruction is in its
    original frame, where this brings the cameras back.

    Parameters
    ----------
    source : Path
        The transforms file (for messages).
    document : dict
        Its parsed content.

    Returns
    -------
    (4, 4) float64 or None
        A similarity transform mapping the file's world frame to the reconstruction's: applied to
        positions; None when the file has neither key.

    Raises
    ------
    InputError
        If ``applied_transform`` is not a rigid 3x4 or 4x4 matrix or ``applied_scale`` not a
        positive number.
    """
    if "applied_transform" not in document and "applied_scale" not in document:
        return None
    applied = np.eye(4)
    if "applied_transform" in document:
        matrix = document["applied_transform"]
        try:
            matrix = np.asarray(matrix, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(source, "'applied_transform' must be a 3x4 or 4x4 matrix of numbers") from None
        if matrix.shape == (3, 4):
            matrix = np.vstack([matrix, [0.0, 0.0, 0.0, 1.0]])
        if matrix.shape != (4, 4):
            raise InputError(source, f"'applied_transform' must be 3x4 or 4x4, got shape {matrix.shape}")
        applied = check_rigid(matrix, source, "applied_transform")
    scale = _number(source, "", "applied_scale", document.get("applied_scale", 1.0))
    undo = np.linalg.inv(applied)
    undo[:3, :3] /= scale
    return undo


def _parse_frames(source: Path, document: dict, reconstruction: np.ndarray | None = None,
                  light: tuple[Path, np.ndarray, float] | None = None) -> tuple[Frame, ...]:
    """Parse the frames of one transforms file of ours; paths are relative to its folder.

    Any per-frame key may also be given at the top level, as the default for every frame. Without
    masks, images with an alpha channel give it as their mask. ``reconstruction`` (see
    `reconstruction_from_transforms`) moves the cameras; with ``light`` (the capture's map, its
    to_world and scale) the frames are test frames, each under its own ``envmap`` or that light.
    """
    root = source.parent
    entries = _frame_entries(source, document)
    image_paths, mask_paths = [], []
    for index, entry in enumerate(entries):
        where = f"frame {index}: "
        image = root / string_key(source, where, entry, "file_path")
        image_paths.append(resolve_image(source, f"image of frame {index}", image))
        if "mask_path" in entry:
            mask = root / string_key(source, where, entry, "mask_path")
            mask_paths.append(resolve_image(source, f"mask of frame {index}", mask))
        else:
            mask_paths.append(None)
    _check_masks_for_all(source, mask_paths)
    from_alpha = not any(mask_paths) and _alpha_for_all(source, image_paths)
    if from_alpha:
        mask_paths = list(image_paths)
    size_of_first = functools.cache(lambda: read_image(image_paths[0]).shape[:2])
    frames = []
    for index, (entry, image_path, mask_path) in enumerate(zip(entries, image_paths, mask_paths)):
        camera = _camera(source, index, entry, document, size_of_first)
        if reconstruction is not None:
            pose = np.array(camera.camera_to_world)
            pose[:3, :3] = reconstruction[:3, :3] @ pose[:3, :3] / np.cbrt(np.linalg.det(reconstruction[:3, :3]))
            pose[:3, 3] = reconstruction[:3, :3] @ pose[:3, 3] + reconstruction[:3, 3]
            camera = dataclasses.replace(camera, camera_to_world=pose)
        frame = Frame(camera, image_path, mask_path, mask_from_alpha=from_alpha,
                      lens=frame_lens(source, index, entry, document, camera))
        if light is not None:
            frame = dataclasses.replace(frame, **_test_light(source, index, {**document, **entry}, light))
        frames.append(frame)
    return tuple(frames)


def _test_light(source: Path, index: int, keys: dict, light: tuple[Path, np.ndarray, float]) -> dict:
    """Return a test frame's light: its ``envmap`` (with to_world and scale), else the capture's."""
    if "envmap" not in keys:
        envmap_path, envmap_to_world, envmap_scale = light
        return dict(envmap_path=envmap_path, envmap_to_world=envmap_to_world, envmap_scale=envmap_scale)
    where = f"frame {index}: "
    envmap_path = source.parent / string_key(source, where, keys, "envmap")
    if not envmap_path.is_file():  # read only when that view is relit: said now, before any work
        raise InputError(envmap_path, f"environment map of frame {index} in {source.name} does not exist")
    return dict(
        envmap_path=envmap_path,
        envmap_to_world=check_rigid(keys.get("envmap_to_world", np.eye(4)), source, f"{where}envmap_to_world"),
        envmap_scale=_number(source, where, "envmap_scale", keys.get("envmap_scale", 1.0)),
    )


def _alpha_for_all(source: Path, image_paths: Sequence[Path]) -> bool:
    """Whether every image has an alpha channel (NeRF-synthetic's mask); refuse some having it."""
    has_alpha = [image_has_alpha(path) for path in image_paths]
    if all(has_alpha):
        return True
    if any(has_alpha):
        first = has_alpha.index(False)
        raise InputError(source, f"{sum(has_alpha)} of {len(has_alpha)} images have an alpha channel, taken as the "
                                 f"object mask (first without one: frame {first}); give it on every image, or "
                                 "mask_path for every frame")
    return False


def _check_masks_for_all(source: Path, mask_paths: Sequence[Path | None]) -> None:
    """Masks come for every frame or for none: a partial list is almost surely a mistake."""
    missing = [index for index, mask in enumerate(mask_paths) if mask is None]
    if 0 < len(missing) < len(mask_paths):
        raise InputError(
            source,
            f"mask_path given for {len(mask_paths) - len(missing)} of {len(mask_paths)} frames "
            f"(first frame without one: {missing[0]}); give it for every frame or for none",
        )


# --- shared parsing helpers --------------------------------------------------------------------


def string_key(source: Path, where: str, mapping: dict, key: str) -> str:
    """Return ``mapping[key]``, a non-empty string (a path); `InputError` naming ``source`` if not.

    Windows separators (a backslash, as tools on Windows write paths) are read as ``/``.
    """
    value = required_key(source, where, mapping, key)
    if not isinstance(value, str) or not value:
        raise InputError(source, f"{where}{key!r} must be a non-empty string (a path)")
    return value.replace("\\", "/") if os.sep == "/" else value


def resolve_image(source: Path, what: str, path: Path) -> Path:
    """``path`` itself, or with the first of IMAGE_SUFFIX_ORDER that exists when it has none.

    ``what`` names the file for the error message, e.g. "image of frame 3".
    """
    if path.is_dir():
        raise InputError(path, f"{what} in {source.name} is a folder, not an image")
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


def load_scaled_envmap(path: Path, to_world: np.ndarray, scale: float) -> Envmap:
    """Load an environment map placed by ``to_world`` (4, 4), its radiance times ``scale``."""
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


def atlas_cache_path(mesh_path: Path) -> Path:
    """Name the atlas cache file of a mesh by its content (in `atlas_cache_folder`)."""
    if not Path(mesh_path).is_file():  # `load_mesh` names the missing file
        return atlas_cache_folder() / f"{mesh_path.stem}.obj"
    digest = hashlib.sha256(Path(mesh_path).read_bytes()).hexdigest()[:32]
    return atlas_cache_folder() / f"{mesh_path.stem}-{digest}.obj"


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
