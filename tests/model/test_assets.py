"""Bundled assets (envmaps, meshes, material sets) and the material-map module."""

import numpy as np
import pytest
import skimage.data
import trimesh

from freqbrdf import assets
from freqbrdf.capture.mesh import load_mesh
from freqbrdf.errors import InputError
from freqbrdf.images import read_image, srgb_to_linear, write_exr
from freqbrdf.model.materials import (
    MaterialMaps,
    load_material_maps,
    resize,
    save_material_maps,
)
from freqbrdf.synthetic.materials import (
    BAND_COLOURS_SRGB,
    bands_material,
    photo_material,
)

# --- environment maps -----------------------------------------------------------------------------


def test_bundled_envmaps_are_valid_lat_long_radiance():
    names = assets.list_envmaps()
    assert len(names) >= 5 and {"studio", "city", "apartment"} <= set(names)
    for name in names:
        radiance = read_image(assets.envmap_path(name), validate=True)  # finite, non-negative
        assert radiance.shape == (256, 512, 3), name
        assert radiance.mean() > 0.01, name


def test_envmaps_span_sharp_and_soft_lighting():
    """The set must contain both a highlight-dominated and a low-frequency environment."""
    def peak_to_mean(name):
        luminance = read_image(assets.envmap_path(name)).mean(axis=2)
        return luminance.max() / luminance.mean()

    assert peak_to_mean("studio") > 500  # a few very bright lights
    assert peak_to_mean("city") < 30  # overcast sky


def test_unknown_asset_names_list_the_valid_ones():
    with pytest.raises(InputError, match=r"no bundled environment map 'moon'.*city.*studio"):
        assets.envmap_path("moon")
    with pytest.raises(InputError, match=r"no bundled mesh 'teapot'.*bunny"):
        assets.mesh_path("teapot")
    with pytest.raises(InputError, match=r"no bundled material set 'wood'.*bands"):
        assets.material_dir("wood")


# --- meshes ---------------------------------------------------------------------------------------


def test_bundled_bunny():
    bunny = load_mesh(assets.mesh_path("bunny"))
    assert len(bunny.faces) == 3674
    assert bunny.uv.min() >= 0 and bunny.uv.max() <= 1
    radius = np.linalg.norm(bunny.vertices, axis=1)
    assert radius.max() == pytest.approx(1.0, abs=1e-12)  # fits the unit sphere, touching it
    centre = (bunny.vertices.min(axis=0) + bunny.vertices.max(axis=0)) / 2
    np.testing.assert_allclose(centre, 0.0, atol=1e-12)
    extent = np.ptp(bunny.vertices, axis=0)
    assert extent[1] > 0.9 * extent.max()  # y up: the bunny is about as tall as it is long
    welded = trimesh.Trimesh(bunny.vertices, bunny.faces)  # merges the atlas seam copies
    assert welded.is_watertight and welded.volume > 0  # closed, outward winding
    np.testing.assert_allclose(np.linalg.norm(bunny.normals, axis=1), 1.0, atol=1e-12)
    # Smooth vertex normals agree with the faces around them.
    face_normals_at_corners = np.repeat(welded.face_normals, 3, axis=0)
    corner_normals = bunny.normals[bunny.faces.reshape(-1)]
    assert np.mean(np.einsum("ij,ij->i", face_normals_at_corners, corner_normals)) > 0.9


def test_bundled_plane_and_sphere():
    assert {"bunny", "plane", "sphere"} <= set(assets.list_meshes())
    plane = load_mesh(assets.mesh_path("plane"))
    np.testing.assert_array_equal(plane.normals[:, 1], 1.0)
    sphere = load_mesh(assets.mesh_path("sphere"))
    assert trimesh.Trimesh(sphere.vertices, sphere.faces).is_watertight
    assert sphere.uv.min() == 0 and sphere.uv.max() == 1


# --- material sets --------------------------------------------------------------------------------


def test_bundled_material_sets_load_in_range_and_vary():
    names = assets.list_materials()
    assert {"bands", "astronaut", "coffee", "chelsea"} <= set(names)
    for name in names:
        maps = load_material_maps(assets.material_dir(name))
        assert maps.resolution == 512, name
        for channel in (maps.base_color, maps.roughness, maps.metallic):
            assert channel.dtype == np.float32
            assert np.isfinite(channel).all() and channel.min() >= 0 and channel.max() <= 1
        assert maps.roughness.std() > 0.05, name
        assert maps.base_color.std(axis=(0, 1)).min() > 0.02, name
        assert maps.roughness.min() >= 0.05, name  # no perfect mirrors in the ground truth


def test_bundled_materials_match_their_generators():
    """The files are what make_assets writes: the generators' output stored as half floats, to one
    half-float step (scipy's and numpy's float64 filters round differently from one version to the
    next, which moves a value lying near the middle of two half floats to the other one)."""
    expected = {"bands": bands_material(512), "astronaut": photo_material(skimage.data.astronaut())}
    for name, generated in expected.items():
        stored = load_material_maps(assets.material_dir(name))
        for field in ("base_color", "roughness", "metallic"):
            half = getattr(generated, field).astype(np.float16)
            difference = np.abs(getattr(stored, field) - half.astype(np.float32))
            step = np.spacing(np.abs(half)).astype(np.float32)
            assert np.all(difference <= step), f"{name}.{field}: {np.count_nonzero(difference > step)} texels"
            assert np.mean(difference > 0) < 1e-3, f"{name}.{field}: {np.count_nonzero(difference)} texels differ"


def test_bands_layout():
    resolution = 96
    maps = bands_material(resolution)
    # Metallic: 0, 0.5, 1 in horizontal thirds, constant along each row.
    np.testing.assert_array_equal(maps.metallic[:32], 0.0)
    np.testing.assert_array_equal(maps.metallic[32:64], 0.5)
    np.testing.assert_array_equal(maps.metallic[64:], 1.0)
    # Six vertical colour bands of 16 columns, each with a roughness ramp 0.05 -> 1.
    band_width = resolution // len(BAND_COLOURS_SRGB)
    for band, colour in enumerate(srgb_to_linear(BAND_COLOURS_SRGB)):
        columns = slice(band * band_width, (band + 1) * band_width)
        expected = np.broadcast_to(colour, (resolution, band_width, 3))
        np.testing.assert_allclose(maps.base_color[:, columns], expected)
        ramp = maps.roughness[0, columns]
        assert np.all(np.diff(ramp) > 0)
        assert ramp[0] == pytest.approx(0.05 + 0.95 / 32, abs=1e-6)  # texel centres
        assert ramp[-1] == pytest.approx(1.0 - 0.95 / 32, abs=1e-6)
    assert np.all(maps.roughness == maps.roughness[:1])  # roughness is constant down columns


def test_photo_material_is_deterministic_and_plausible():
    photo = skimage.data.coffee()
    maps = photo_material(photo, 128)
    again = photo_material(photo, 128)
    np.testing.assert_array_equal(maps.roughness, again.roughness)
    assert 0.03 - 1e-6 <= maps.base_color.min() and maps.base_color.max() <= 0.93 + 1e-6
    assert 0.1 - 1e-6 <= maps.roughness.min() and maps.roughness.max() <= 0.95 + 1e-6
    # The white porcelain rim is metal somewhere, the dark-red saucer and coffee are not.
    assert 0.01 < (maps.metallic > 0.5).mean() < 0.3
    # Base colour follows the photo: red dominates on average (cup and saucer).
    mean_colour = maps.base_color.mean(axis=(0, 1))
    assert mean_colour[0] > mean_colour[1] and mean_colour[0] > mean_colour[2]


# --- materials module -----------------------------------------------------------------------------


def test_material_maps_round_trip(tmp_path):
    maps = photo_material(skimage.data.chelsea(), 64)
    save_material_maps(tmp_path / "m", maps)
    back = load_material_maps(tmp_path / "m")
    for field in ("base_color", "roughness", "metallic"):
        np.testing.assert_array_equal(getattr(back, field), getattr(maps, field))
    save_material_maps(tmp_path / "h", maps, half=True)
    np.testing.assert_allclose(load_material_maps(tmp_path / "h").roughness, maps.roughness,
                               atol=1e-3)


def test_resize_preserves_averages_and_range():
    maps = bands_material(128)
    smaller, larger = resize(maps, 32), resize(maps, 200)
    assert smaller.resolution == 32 and larger.resolution == 200
    for resized in (smaller, larger):
        assert resized.metallic.min() >= 0 and resized.metallic.max() <= 1
        # Area-weighted means survive resampling (linear base colour, metallic).
        np.testing.assert_allclose(resized.base_color.mean(axis=(0, 1)),
                                   maps.base_color.mean(axis=(0, 1)), rtol=0.03)
        assert resized.metallic.mean() == pytest.approx(maps.metallic.mean(), abs=0.02)
    assert resize(maps, 128) is maps


def test_material_loading_errors(tmp_path):
    with pytest.raises(InputError, match="material folder does not exist"):
        load_material_maps(tmp_path / "none")
    maps = bands_material(16)
    save_material_maps(tmp_path / "m", maps)
    (tmp_path / "m" / "metallic.exr").unlink()
    with pytest.raises(InputError, match=r"metallic\.exr: file does not exist"):
        load_material_maps(tmp_path / "m")
    save_material_maps(tmp_path / "m", maps)
    write_exr(tmp_path / "m" / "roughness.exr", np.full((16, 16), 1.5, np.float32))
    with pytest.raises(InputError, match=r"roughness\.exr: 256 values above 1"):
        load_material_maps(tmp_path / "m")
    write_exr(tmp_path / "m" / "roughness.exr", np.full((8, 8), 0.5, np.float32))
    with pytest.raises(InputError, match="maps differ in resolution"):
        load_material_maps(tmp_path / "m")
    write_exr(tmp_path / "m" / "roughness.exr", np.random.default_rng(0).random((16, 16, 3)))
    with pytest.raises(InputError, match="single channel"):
        load_material_maps(tmp_path / "m")
    with pytest.raises(ValueError, match="roughness has shape"):
        MaterialMaps(maps.base_color, maps.roughness[:8], maps.metallic)
