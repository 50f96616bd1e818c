"""Fit outputs: hole-free textures, scalar maps, the glTF binary's conventions, the output folder."""

from __future__ import annotations

import io
import json
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from matplotlib import colormaps
from PIL import Image

from freqbrdf import __version__
from freqbrdf.capture.mesh import plane_mesh, uv_sphere_mesh
from freqbrdf.config import Config, TexelConfig
from freqbrdf.estimate import MaterialEstimate
from freqbrdf.fileio import OUTPUT_MARKER, write_json
from freqbrdf.images import REC709_CHROMATICITIES, read_image
from freqbrdf.model.materials import MaterialMaps, load_material_maps
from freqbrdf.outputs import export, gltf, report
from freqbrdf.texels import fill_texture, rasterise
from freqbrdf.uncertainty import FLAG_UNOBSERVED, Uncertainty, hypothesis_grid


def test_fill_texture_nearest_inside_atlas_dilation_outside_and_mean_beyond():
    size = 16
    atlas = np.zeros((size, size), bool)
    atlas[2:5, 1:11] = True  # one chart: rows 2-4, columns 1-10
    texture = np.full((size, size), np.nan, np.float32)
    texture[2:5, 1] = 1.0  # known at its left edge ...
    texture[2:5, 10] = 5.0  # ... and right edge; the middle of the chart was never seen
    filled = fill_texture(texture, atlas, dilation_px=2, fallback=-1.0)

    assert np.isfinite(filled).all()
    assert np.all(filled[2:5, 1] == 1.0) and np.all(filled[2:5, 10] == 5.0)  # known texels kept
    assert np.all(filled[2:5, 2:6] == 1.0) and np.all(filled[2:5, 6:10] == 5.0)  # nearest known
    assert filled[1, 1] == 1.0 and filled[3, 11] == 5.0  # first dilation ring: its neighbours
    assert filled[0, 0] == pytest.approx(1.0)  # second ring
    atlas_mean = filled[atlas].mean()
    assert filled[10, 10] == pytest.approx(atlas_mean)  # beyond the dilation: the atlas mean
    # A texel outside the atlas never counts as known, whatever it holds.
    texture[12, 12] = 100.0
    assert fill_texture(texture, atlas, 2, -1.0)[12, 12] == pytest.approx(atlas_mean)
    # Nothing known: the fallback everywhere; channels are filled alike.
    assert np.all(fill_texture(np.full((4, 4, 3), np.nan), np.ones((4, 4), bool), 2, 0.25) == 0.25)


def test_write_scalar_map_grey_colormap_and_exr(tmp_path):
    texture = np.array([[0.0, 0.5], [1.0, 2.0]], np.float32)
    export.write_scalar_map(tmp_path / "map.exr", texture)
    np.testing.assert_array_equal(read_image(tmp_path / "map.exr")[..., 0], texture)
    export.write_scalar_map(tmp_path / "grey.png", texture)
    assert np.array_equal(np.asarray(Image.open(tmp_path / "grey.png")), [[0, 128], [255, 255]])
    export.write_scalar_map(tmp_path / "viridis.png", texture, "viridis", (0.0, 2.0))
    pixels = np.asarray(Image.open(tmp_path / "viridis.png"))
    expected = np.round(colormaps["viridis"](texture / 2.0)[..., :3] * 255)
    assert np.abs(pixels.astype(int) - expected).max() <= 1
    with pytest.raises(ValueError):
        export.write_scalar_map(tmp_path / "map.jpg", texture)


def exr_header(path):
    with OpenEXR.File(str(path), header_only=True) as exr:
        return dict(exr.parts[0].header)


def read_glb(path):
    """(JSON document, binary chunk) of a GLB file, by the container layout of glTF 2.0 §4.4."""
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF" and version == 2 and length == len(data)
    json_length, json_type = struct.unpack_from("<I4s", data, 12)
    assert json_type == b"JSON"
    document = json.loads(data[20 : 20 + json_length])
    offset = 20 + json_length
    bin_length, bin_type = struct.unpack_from("<I4s", data, offset)
    assert bin_type == b"BIN\x00"
    return document, data[offset + 8 : offset + 8 + bin_length]


def accessor_array(document, binary, index):
    accessor = document["accessors"][index]
    view = document["bufferViews"][accessor["bufferView"]]
    assert accessor["componentType"] == 5126  # float32
    width = {"VEC2": 2, "VEC3": 3}[accessor["type"]]
    start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    return np.frombuffer(binary, np.float32, accessor["count"] * width, start).reshape(-1, width)


def texture_pixels(document, binary, texture_info):
    image = document["images"][document["textures"][texture_info["index"]]["source"]]
    assert image["mimeType"] == "image/png"
    view = document["bufferViews"][image["bufferView"]]
    start = view.get("byteOffset", 0)
    return np.asarray(Image.open(io.BytesIO(binary[start : start + view["byteLength"]])))


def test_gltf_follows_the_pbr_texture_and_uv_conventions(tmp_path):
    mesh = plane_mesh()
    size = 8
    rng = np.random.default_rng(0)
    maps = MaterialMaps(
        rng.random((size, size, 3)).astype(np.float32),
        rng.random((size, size)).astype(np.float32),
        rng.random((size, size)).astype(np.float32),
    )
    gltf.write_gltf(tmp_path / "material.glb", mesh, maps)
    document, binary = read_glb(tmp_path / "material.glb")

    material = document["materials"][0]["pbrMetallicRoughness"]
    assert material["metallicFactor"] == 1.0 and material["roughnessFactor"] == 1.0
    # Base colour: sRGB-encoded 8-bit of the linear map, rows in image order (row 0 on top).
    encoded = np.where(maps.base_color <= 0.0031308, 12.92 * maps.base_color,
                       1.055 * maps.base_color ** (1 / 2.4) - 0.055)
    base = texture_pixels(document, binary, material["baseColorTexture"])
    assert np.abs(base.astype(int) - np.round(encoded * 255)).max() <= 1
    # Metallic-roughness: linear, R = 255 (unused), G = roughness, B = metallic.
    packed = texture_pixels(document, binary, material["metallicRoughnessTexture"])
    assert np.all(packed[..., 0] == 255)
    assert np.array_equal(packed[..., 1], np.round(maps.roughness * 255))
    assert np.array_equal(packed[..., 2], np.round(maps.metallic * 255))

    primitive = document["meshes"][0]["primitives"][0]
    uv = accessor_array(document, binary, primitive["attributes"]["TEXCOORD_0"])
    normals = accessor_array(document, binary, primitive["attributes"]["NORMAL"])
    positions = accessor_array(document, binary, primitive["attributes"]["POSITION"])
    np.testing.assert_allclose(positions, mesh.vertices, atol=1e-7)
    # glTF's UV origin is the image's top-left: v flips, so our v = 1 (texture row 0) is glTF v = 0.
    np.testing.assert_allclose(uv, np.stack([mesh.uv[:, 0], 1.0 - mesh.uv[:, 1]], axis=1), atol=1e-7)
    np.testing.assert_allclose(normals, mesh.normals, atol=1e-7)
    sampler = document["samplers"][0]
    assert sampler["wrapS"] == sampler["wrapT"] == 33071  # CLAMP_TO_EDGE
    assert all(texture["sampler"] == 0 for texture in document["textures"])


def test_gltf_names_its_parts_and_targets_its_buffer_views(tmp_path):
    mesh = uv_sphere_mesh(16, 8)
    maps = MaterialMaps(np.full((8, 8, 3), 0.25, np.float32), np.full((8, 8), 0.5, np.float32),
                        np.zeros((8, 8), np.float32))
    gltf.write_gltf(tmp_path / "material.glb", mesh, maps)
    document, _ = read_glb(tmp_path / "material.glb")
    assert document["asset"] == {"version": "2.0", "generator": f"freqbrdf {__version__}"}
    assert [image["name"] for image in document["images"]] == ["base_color", "metallic_roughness"]
    assert [texture["name"] for texture in document["textures"]] == ["base_color", "metallic_roughness"]
    assert document["materials"][0]["name"] == "freqbrdf"
    primitive = document["meshes"][0]["primitives"][0]
    views = document["bufferViews"]
    for accessor in primitive["attributes"].values():
        assert views[document["accessors"][accessor]["bufferView"]]["target"] == 34962  # ARRAY_BUFFER
    assert views[document["accessors"][primitive["indices"]]["bufferView"]]["target"] == 34963  # ELEMENT_ARRAY_BUFFER
    # One bufferView per accessor: on a unit sphere the normals equal the positions, and a shared
    # view would need a byteStride.
    used = [document["accessors"][index]["bufferView"] for index in [*primitive["attributes"].values(), primitive["indices"]]]
    assert len(set(used)) == len(used)
    # Deterministic: the same input gives the same bytes (no timestamp anywhere).
    gltf.write_gltf(tmp_path / "again.glb", mesh, maps)
    assert (tmp_path / "again.glb").read_bytes() == (tmp_path / "material.glb").read_bytes()


REPOSITORY = Path(__file__).resolve().parents[2]
GLTF_VALIDATOR = REPOSITORY / ".cache" / "node" / "node_modules" / "gltf-validator"
VALIDATE_SCRIPT = REPOSITORY / "tests" / "node" / "validate_gltf.cjs"


def khronos_validator_reports(paths: list[Path]) -> list[dict]:
    """Run the Khronos glTF validator (tests/node/validate_gltf.cjs) on GLB files; one report per file."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("needs Node.js (`node`) for the Khronos glTF validator; `make test` installs it when run as root")
    if not (GLTF_VALIDATOR / "package.json").is_file():
        pytest.skip("needs the npm package gltf-validator in .cache/node: run `bash scripts/ensure_test_tools.sh` "
                    "(part of `make test`)")
    result = subprocess.run([node, str(VALIDATE_SCRIPT), str(GLTF_VALIDATOR), *map(str, paths)],
                            capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def test_gltf_files_pass_the_khronos_validator_without_any_message(tmp_path):
    mesh, texels, estimate = sphere_fit()
    n_texels = texels.n_texels
    uncertainty = Uncertainty(
        entropy=np.linspace(0, 1, n_texels).astype(np.float32),
        flags=np.zeros(n_texels, np.uint8), likelihood=None,
        best_alpha=np.zeros(n_texels, np.float32), best_ks=np.zeros(n_texels, np.float32),
        channel=np.zeros(n_texels, np.int8), mode="calibrated", grid=hypothesis_grid(8),
    )
    config = Config(texels=TexelConfig(texture_res=32, dilation_px=3))
    out = export.write_fit_outputs(tmp_path / "fit", mesh, texels, estimate, uncertainty, config)
    # The report's entropy overlay: the same writer, on the entropy colour map.
    (tmp_path / "entropy.glb").write_bytes(report._entropy_glb(mesh, read_image(out / "entropy.exr")[..., 0]))
    (tmp_path / "plane.glb").write_bytes(gltf.gltf_bytes(plane_mesh(), load_material_maps(out)))
    files = [out / "material.glb", tmp_path / "entropy.glb", tmp_path / "plane.glb"]
    reports = khronos_validator_reports(files)
    assert len(reports) == len(files)
    for path, result in zip(files, reports):
        counts = {key: result[key] for key in ("numErrors", "numWarnings", "numInfos", "numHints")}
        assert counts == dict.fromkeys(counts, 0), (path.name, result["messages"])
        assert result["generator"] == f"freqbrdf {__version__}"


def sphere_fit(texture_res: int = 32, seed: int = 0):
    """A sphere's texels and an estimate on them with a third of the texels unobserved."""
    mesh = uv_sphere_mesh(16, 8)
    texels = rasterise(mesh, texture_res)
    n_texels = texels.n_texels
    rng = np.random.default_rng(seed)
    estimated = rng.random(n_texels) > 0.33
    nan_off = lambda values: np.where(estimated.reshape((-1,) + (1,) * (values.ndim - 1)), values, np.nan)
    estimate = MaterialEstimate(
        texture_res=texture_res,
        texel_index=texels.texel_index,
        base_color=nan_off(rng.random((n_texels, 3))),
        roughness=nan_off(rng.random(n_texels)),
        metallic=nan_off(rng.random(n_texels)),
        estimated=estimated,
        loss=nan_off(rng.random(n_texels)),
        method="global",
    )
    return mesh, texels, estimate


def test_write_fit_outputs_writes_a_complete_hole_free_folder(tmp_path):
    mesh, texels, estimate = sphere_fit()
    n_texels = texels.n_texels
    grid = hypothesis_grid(8)
    entropy = np.where(estimate.estimated, np.linspace(0, 1, n_texels), 1.0).astype(np.float32)
    spread = np.where(estimate.estimated, np.linspace(0, 0.4, n_texels), np.nan).astype(np.float32)
    uncertainty = Uncertainty(
        entropy=entropy,
        flags=np.where(estimate.estimated, 0, FLAG_UNOBSERVED).astype(np.uint8),
        likelihood=None,
        best_alpha=np.zeros(n_texels, np.float32),
        best_ks=np.zeros(n_texels, np.float32),
        channel=np.zeros(n_texels, np.int8),
        mode="calibrated",
        grid=grid,
        roughness_std=spread,
    )
    config = Config(texels=TexelConfig(texture_res=32, dilation_px=3))
    out = export.write_fit_outputs(tmp_path / "fit", mesh, texels, estimate, uncertainty, config,
                                   timings={"estimate": 1.5})

    summary = json.loads((out / "summary.json").read_text())
    assert sorted(summary["files"]) == sorted(path.name for path in out.iterdir() if path.name != OUTPUT_MARKER)
    assert summary["settings"]["texels"]["dilation_px"] == 3
    assert summary["timings"] == {"estimate": 1.5}
    assert summary["coverage"]["texels"] == n_texels
    assert summary["coverage"]["observed_fraction"] == pytest.approx(estimate.estimated.mean())
    assert summary["uncertainty"]["observed_texels"] == int(estimate.estimated.sum())

    maps = load_material_maps(out)
    for name in ("base_color", "roughness", "metallic"):
        texture = getattr(maps, name)
        assert np.isfinite(texture).all()
        per_texel = texture.reshape(32 * 32, *texture.shape[2:])[texels.texel_index]
        np.testing.assert_allclose(per_texel[estimate.estimated], getattr(estimate, name)[estimate.estimated],
                                   rtol=1e-6)
    saved_entropy = read_image(out / "entropy.exr")[..., 0].reshape(-1)[texels.texel_index]
    np.testing.assert_allclose(saved_entropy, entropy, atol=1e-7)
    assert Image.open(out / "entropy.png").size == (32, 32)
    assert Image.open(out / "base_color.png").mode == "RGB"

    # roughness_std: the per-texel array where estimated, the prior's std elsewhere, dilated like
    # the maps; the PNG in the colour map and range summary.json states; the array in the npz.
    spread_texture = read_image(out / "roughness_std.exr")[..., 0]
    assert np.isfinite(spread_texture).all()
    saved_spread = spread_texture.reshape(-1)[texels.texel_index]
    np.testing.assert_allclose(saved_spread[estimate.estimated], spread[estimate.estimated], atol=1e-7)
    np.testing.assert_allclose(saved_spread[~estimate.estimated], np.sqrt(1 / 12), atol=1e-6)
    assert summary["roughness_std_png"]["colormap"] == "magma" and summary["roughness_std_png"]["range"] == [0.0, 0.3]
    low, high = summary["roughness_std_png"]["range"]
    pixels = np.asarray(Image.open(out / "roughness_std.png")).reshape(-1, 3)[texels.texel_index]
    expected = np.round(colormaps["magma"](np.clip((saved_spread - low) / (high - low), 0, 1))[:, :3] * 255)
    assert np.abs(pixels.astype(int) - expected).max() <= 1
    with np.load(out / "uncertainty.npz") as arrays:
        np.testing.assert_array_equal(arrays["roughness_std"], spread)  # NaN where not estimated
    assert summary["uncertainty"]["roughness_std_mean"] == pytest.approx(np.nanmean(spread), rel=1e-5)

    # Every EXR says what it is; base colour also its primaries; none holds a time (same bytes again).
    headers = {name: exr_header(out / name) for name in
               ("base_color.exr", "roughness.exr", "metallic.exr", "entropy.exr", "roughness_std.exr")}
    assert all(header["software"] == f"freqbrdf {__version__}" for header in headers.values())
    np.testing.assert_allclose(headers["base_color.exr"]["chromaticities"], REC709_CHROMATICITIES, rtol=1e-6)
    assert all("chromaticities" not in headers[name] for name in headers if name != "base_color.exr")
    assert "linear RGB" in headers["base_color.exr"]["comments"]
    assert "D65" in headers["base_color.exr"]["comments"]
    assert "roughness r" in headers["roughness.exr"]["comments"]
    assert "alpha is r^2" in headers["roughness.exr"]["comments"]
    assert "metallic" in headers["metallic.exr"]["comments"] and "[0, 1]" in headers["metallic.exr"]["comments"]
    assert "normalised entropy" in headers["entropy.exr"]["comments"]
    assert "(calibrated mode)" in headers["entropy.exr"]["comments"]
    assert "standard deviation" in headers["roughness_std.exr"]["comments"]
    again = export.write_fit_outputs(tmp_path / "again", mesh, texels, estimate, uncertainty, config,
                                     timings={"estimate": 1.5})
    for name in (*headers, "material.glb"):
        assert (again / name).read_bytes() == (out / name).read_bytes(), name

    # Without roughness_std (turned off): neither its maps nor its array.
    uncertainty.roughness_std = None
    out = export.write_fit_outputs(tmp_path / "fit", mesh, texels, estimate, uncertainty, config)
    assert not list(out.glob("roughness_std.*")) and "roughness_std_png" not in json.loads((out / "summary.json").read_text())
    with np.load(out / "uncertainty.npz") as arrays:
        assert "roughness_std" not in arrays.files


def test_write_fit_outputs_is_atomic_and_checks_the_texels(tmp_path, monkeypatch):
    mesh, texels, estimate = sphere_fit()
    out = tmp_path / "fit"
    export.write_fit_outputs(out, mesh, texels, estimate)
    before = sorted(path.name for path in out.iterdir())

    def failing_gltf(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(export, "write_gltf", failing_gltf)
    with pytest.raises(RuntimeError):
        export.write_fit_outputs(out, mesh, texels, estimate)
    assert sorted(path.name for path in out.iterdir()) == before  # the old folder is untouched
    assert sorted(path.name for path in tmp_path.iterdir()) == ["fit"]  # no temporary left behind
    _, other_texels, _ = sphere_fit(texture_res=16)
    with pytest.raises(ValueError, match="texel_index"):
        export.write_fit_outputs(out, mesh, other_texels, estimate)


def test_write_json_is_strict_json(tmp_path):
    write_json(tmp_path / "doc.json", {"a": np.float32(np.nan), "b": [np.inf, np.int64(3)], "c": np.ones(2)})
    assert json.loads((tmp_path / "doc.json").read_text()) == {"a": None, "b": [None, 3], "c": [1.0, 1.0]}


def test_to_float16_matches_numpys_cast_bit_for_bit():
    # Bit patterns across every exponent (both signs, subnormals, inf, nan) and, densely, around the
    # float16 boundaries: smallest subnormal (2**-24), half of it (2**-25), smallest normal (2**-14)
    # and the largest finite value (65504) with its rounding neighbours.
    patterns = [np.arange(0, 2**32 - 1, 4099, dtype=np.uint64).astype(np.uint32)]
    for boundary in (2.0**-25, 2.0**-24, 2.0**-14, 65504.0, 65520.0):
        centre = int(np.array(boundary, np.float32).view(np.uint32))
        patterns.append(np.arange(centre - 3000, centre + 3000, dtype=np.uint32))
        patterns.append(patterns[-1] | np.uint32(1 << 31))
    values = np.concatenate(patterns).view(np.float32)
    values = values[: len(values) // 21 * 21].reshape(-1, 7, 3)[:, ::2]  # not contiguous
    with np.errstate(over="ignore", invalid="ignore"):
        expected = values.astype(np.float16)
    result = export.to_float16(values)
    assert result.dtype == np.float16 and result.shape == values.shape
    finite_or_inf = ~np.isnan(values)
    np.testing.assert_array_equal(result.view(np.uint16)[finite_or_inf], expected.view(np.uint16)[finite_or_inf])
    assert np.isnan(result[~finite_or_inf]).all()
