"""Bundled data: environment maps, meshes and ground-truth material sets (see ATTRIBUTION.md).

Everything here is regenerated from the package registries (docs/method.md#data) by
``scripts/make_assets.py``.
"""

from __future__ import annotations

from pathlib import Path

from freqbrdf.errors import InputError

ASSETS_DIR = Path(__file__).resolve().parent
ENVMAPS_DIR = ASSETS_DIR / "envmaps"  # <name>.exr, 512 x 256 lat-long, linear radiance
MESHES_DIR = ASSETS_DIR / "meshes"  # <name>.obj with UVs and normals
MATERIALS_DIR = ASSETS_DIR / "materials"  # <name>/{base_color,roughness,metallic}.exr


def list_envmaps() -> list[str]:
    """List the bundled environment maps.

    Returns
    -------
    list of str
        Their names, sorted.
    """
    return sorted(path.stem for path in ENVMAPS_DIR.glob("*.exr"))


def list_meshes() -> list[str]:
    """List the bundled meshes.

    Returns
    -------
    list of str
        Their names, sorted.
    """
    return sorted(path.stem for path in MESHES_DIR.glob("*.obj"))


def list_materials() -> list[str]:
    """List the bundled material sets.

    Returns
    -------
    list of str
        Their names, sorted.
    """
    return sorted(path.name for path in MATERIALS_DIR.iterdir() if path.is_dir())


def envmap_path(name: str) -> Path:
    """Return the path of a bundled environment map.

    Parameters
    ----------
    name : str
        Its name (e.g. ``"studio"``; see `list_envmaps`).

    Returns
    -------
    Path
        The ``.exr`` file.

    Raises
    ------
    InputError
        If no bundled map has that name.
    """
    return _bundled(ENVMAPS_DIR / f"{name}.exr", name, "environment map", list_envmaps())


def mesh_path(name: str) -> Path:
    """Return the path of a bundled mesh.

    Parameters
    ----------
    name : str
        Its name (``"bunny"``, ``"plane"``, ``"sphere"``; see `list_meshes`).

    Returns
    -------
    Path
        The ``.obj`` file.

    Raises
    ------
    InputError
        If no bundled mesh has that name.
    """
    return _bundled(MESHES_DIR / f"{name}.obj", name, "mesh", list_meshes())


def material_dir(name: str) -> Path:
    """Return the folder of a bundled material set.

    Parameters
    ----------
    name : str
        Its name (see `list_materials`).

    Returns
    -------
    Path
        The folder, for `freqbrdf.model.materials.load_material_maps`.

    Raises
    ------
    InputError
        If no bundled set has that name.
    """
    return _bundled(MATERIALS_DIR / name, name, "material set", list_materials())


def _bundled(path: Path, name: str, kind: str, names: list[str]) -> Path:
    if name not in names:
        problem = f"no bundled {kind} {name!r}; choose one of: {', '.join(names)}"
        raise InputError(path.parent, problem)
    return path
