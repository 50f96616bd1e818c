#!/usr/bin/env python
"""Regenerate every file under src/freqbrdf/assets/ from the package registries.

    .venv/bin/python scripts/make_assets.py [--out src/freqbrdf/assets]

Sources (all CC0 or public domain, see ATTRIBUTION.md):
- npm ``@pmndrs/assets`` (pinned): Poly Haven HDRIs, 512 x 256 DWAB-compressed EXR inside
  ``hdri/<name>.exr.js`` as base64. The lossy compression rings around bright lights, so negative
  values are clamped to 0. ``park``, ``sunrise`` and ``sky`` are left out: their sun decodes
  to garbage (large negative and single-channel values).
- npm ``bunny`` (pinned): the Stanford bunny as JavaScript arrays ``positions`` and ``cells``.
- ``skimage.data`` photographs for the image-based ground-truth materials.
Needs ``npm`` on the PATH; everything else is the freqbrdf package itself.
"""

from __future__ import annotations

import argparse
import base64
import json
import re
import subprocess
import tarfile
import tempfile
from pathlib import Path

import numpy as np
import skimage.data

from freqbrdf.capture.mesh import (
    Mesh,
    generate_atlas,
    plane_mesh,
    save_obj,
    smooth_normals,
    uv_sphere_mesh,
)
from freqbrdf.images import read_image, write_exr
from freqbrdf.model.materials import save_material_maps
from freqbrdf.synthetic.materials import bands_material, photo_material

PMNDRS_ASSETS = "@pmndrs/assets@1.7.0"
BUNNY = "bunny@1.0.1"

# name -> Poly Haven source; picked for variety of angular frequency content
ENVMAPS = {
    "studio": "studio_small_03",  # softbox and lamps: sharp, very strong highlights
    "lobby": "st_fagans_interior",  # indoor hall, one bright lamp and windows
    "sunset": "venice_sunset",  # outdoor, low sun near the horizon
    "forest": "forest_slope",  # outdoor, sky through trees, mid frequencies
    "apartment": "lebombo",  # indoor, soft window light
    "city": "potsdamer_platz",  # outdoor overcast: soft, low frequency
}
PHOTO_MATERIALS = {  # name -> skimage.data loader
    "astronaut": skimage.data.astronaut,
    "coffee": skimage.data.coffee,
    "chelsea": skimage.data.chelsea,
}
MATERIAL_RESOLUTION = 512


def npm_pack(spec: str, workdir: Path) -> Path:
    """Download one npm package tarball with the npm client and unpack it; returns its folder."""
    result = subprocess.run(
        ["npm", "pack", spec, "--json"], cwd=workdir, check=True, capture_output=True, text=True
    )
    tarball = workdir / json.loads(result.stdout)[0]["filename"]
    target = workdir / tarball.name.removesuffix(".tgz")
    with tarfile.open(tarball) as archive:
        archive.extractall(target, filter="data")
    return target / "package"


def make_envmaps(pmndrs: Path, out: Path, workdir: Path) -> None:
    for name in ENVMAPS:
        module = (pmndrs / "hdri" / f"{name}.exr.js").read_text()
        exr_bytes = base64.b64decode(re.search(r"base64,([A-Za-z0-9+/=]+)", module)[1])
        source = workdir / f"{name}.exr"
        source.write_bytes(exr_bytes)
        radiance = np.maximum(read_image(source), 0.0)  # (256, 512, 3); DWAB ringing < 0
        write_exr(out / "envmaps" / f"{name}.exr", radiance)
        print(f"envmap {name}: {radiance.shape[1]}x{radiance.shape[0]}, max {radiance.max():.1f}")


def make_bunny(bunny: Path, out: Path) -> None:
    module = (bunny / "index.js").read_text()  # exports.positions=[[x,y,z],...] exports.cells=...
    decoder = json.JSONDecoder()
    arrays = {
        match[1]: decoder.raw_decode(module, match.end())[0]
        for match in re.finditer(r"exports\.(\w+)\s*=\s*", module)
    }
    vertices = np.array(arrays["positions"], dtype=np.float64)  # y is already up
    faces = np.array(arrays["cells"], dtype=np.int64)
    # Fit the unit sphere: bounding-box centre to the origin, farthest vertex at distance 1.
    vertices -= (vertices.min(axis=0) + vertices.max(axis=0)) / 2
    vertices /= np.linalg.norm(vertices, axis=1).max()
    normals = smooth_normals(vertices, faces)
    save_obj(out / "meshes" / "bunny.obj", Mesh(*generate_atlas(vertices, faces, normals)),
             comment="Stanford bunny (npm bunny 1.0.1), unit sphere, y up, xatlas UVs")
    print(f"mesh bunny: {len(faces)} faces")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    default_out = Path(__file__).resolve().parents[1] / "src" / "freqbrdf" / "assets"
    parser.add_argument("--out", type=Path, default=default_out, help="assets folder")
    out = parser.parse_args().out
    with tempfile.TemporaryDirectory() as temp:
        workdir = Path(temp)
        make_envmaps(npm_pack(PMNDRS_ASSETS, workdir), out, workdir)
        make_bunny(npm_pack(BUNNY, workdir), out)
    save_obj(out / "meshes" / "plane.obj", plane_mesh(), comment="unit square at y = 0 facing +y")
    save_obj(out / "meshes" / "sphere.obj", uv_sphere_mesh(), comment="unit UV sphere, y up")
    save_material_maps(out / "materials" / "bands", bands_material(MATERIAL_RESOLUTION), half=True)
    for name, photo in PHOTO_MATERIALS.items():
        maps = photo_material(photo(), MATERIAL_RESOLUTION)
        save_material_maps(out / "materials" / name, maps, half=True)
    print(f"meshes plane, sphere; materials bands, {', '.join(PHOTO_MATERIALS)}")


if __name__ == "__main__":
    main()
