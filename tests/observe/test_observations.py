"""Observations, checked against Mitsuba's own renders (never against our forward model).

Three tiny captures are path traced once per test run with freqbrdf.synthetic.synth:

- a smooth conductor sphere (base colour 1, metallic 1, roughness 0): a mirror, so the observed
  radiance must be the environment in the mirror direction;
- a white Lambertian sphere (a plain ``diffuse`` BSDF, reflectance 1): the observed radiance must
  be E / pi. Mitsuba's ``principled`` is no Lambertian even at roughness 1 (Disney diffuse with a
  retro-reflection term, plus a specular lobe), so synth's BSDF is swapped for ``diffuse`` here;
- the bunny with a checkerboard of black and bright texels: visibility against Mitsuba's depth,
  and dark texels weighted like bright ones.

The sphere is convex: no self-occlusion and no interreflection, so what is left between our
samples and Mitsuba's pixels is Monte Carlo noise and the pixel footprint.
"""

import json
import sys
from dataclasses import replace
from unittest import mock

import numpy as np
import pytest
from scipy import ndimage

from freqbrdf.assets import envmap_path
from freqbrdf.capture.layouts import load
from freqbrdf.capture.mesh import Mesh
from freqbrdf.cli import main
from freqbrdf.config import Config, FitConfig, ObserveConfig, TexelConfig
from freqbrdf.errors import InputError
from freqbrdf.images import write_exr
from freqbrdf.model.materials import MaterialMaps, save_material_maps
from freqbrdf.observe._kernels import _sample_bilinear
from freqbrdf.observe.irradiance import texel_irradiance
from freqbrdf.observe.observations import Observations, observe
from freqbrdf.render import scenes as render
from freqbrdf.render.occluder import Occluder
from freqbrdf.sphere import harmonics as sh
from freqbrdf.sphere.envmap import Envmap, load_envmap, lookup
from freqbrdf.synthetic.synth import SynthSettings, synthesize
from freqbrdf.texels import rasterise

TEXTURE_RES = 64


def constant_materials(folder, base_color, roughness, metallic, resolution=8):
    maps = MaterialMaps(
        np.full((resolution, resolution, 3), base_color, np.float32),
        np.full((resolution, resolution), roughness, np.float32),
        np.full((resolution, resolution), metallic, np.float32),
    )
    save_material_maps(folder, maps)
    return folder


def render_capture(folder, settings, bsdf=None):
    """synthesize, optionally with every principled BSDF replaced by the dict ``bsdf``."""
    if bsdf is None:
        return load(synthesize(folder, settings, progress=False))
    with mock.patch("freqbrdf.synthetic.synth.principled_bsdf", lambda materials: dict(bsdf)):
        return load(synthesize(folder, settings, progress=False))


def sphere_settings(materials, views, resolution, spp):
    return SynthSettings(mesh="sphere", envmap="forest", materials=str(materials), views=views,
                         resolution=resolution, spp=spp, texture_res=8, cameras="sphere",
                         test_views=0, seed=3)


@pytest.fixture(scope="session")
def mirror_sphere(tmp_path_factory):
    """A mirror sphere under a smoothed forest map (Gaussian blur, 8 texels = 5.6 degrees): pixels
    of 128 x 128 images then span less than the map's detail, so that a pixel (the map averaged
    over its footprint) may be compared with a point lookup. With the full map the footprint
    alone makes 20 % errors."""
    folder = tmp_path_factory.mktemp("mirror")
    materials = constant_materials(folder / "materials", 1.0, 0.0, 1.0)
    radiance = load_envmap(envmap_path("forest")).radiance
    smooth = ndimage.gaussian_filter(radiance, sigma=(8, 8, 0), mode=("nearest", "wrap", "nearest"))
    write_exr(folder / "smooth_forest.exr", smooth)
    settings = replace(sphere_settings(materials, 6, 128, 16), envmap=str(folder / "smooth_forest.exr"))
    capture = render_capture(folder / "capture", settings)
    # Compared with the capture's own (unblurred) map: no band limit.
    config = Config(texels=TexelConfig(texture_res=TEXTURE_RES), fit=FitConfig(band_limit=False))
    return capture, observe(capture, config)


@pytest.fixture(scope="session")
def lambertian_sphere(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lambert")
    materials = constant_materials(folder / "materials", 1.0, 1.0, 0.0)
    diffuse = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}
    capture = render_capture(folder / "capture", sphere_settings(materials, 10, 64, 256), diffuse)
    return capture, observe(capture, Config(texels=TexelConfig(texture_res=TEXTURE_RES)))


@pytest.fixture(scope="session")
def checker_bunny(tmp_path_factory):
    """The bunny with base colour 0 and 0.8 in 8 x 8 texel squares (roughness 0.5, dielectric)."""
    folder = tmp_path_factory.mktemp("bunny")
    rows, cols = np.indices((TEXTURE_RES, TEXTURE_RES))
    dark = ((rows // 8 + cols // 8) % 2).astype(bool)
    maps = MaterialMaps(
        np.where(dark[..., None], 0.0, 0.8).astype(np.float32) * np.ones(3, np.float32),
        np.full((TEXTURE_RES, TEXTURE_RES), 0.5, np.float32),
        np.zeros((TEXTURE_RES, TEXTURE_RES), np.float32),
    )
    save_material_maps(folder / "materials", maps)
    settings = SynthSettings(mesh="bunny", envmap="forest", materials=str(folder / "materials"),
                             views=5, resolution=96, spp=4, texture_res=TEXTURE_RES, test_views=0)
    capture = render_capture(folder / "capture", settings)
    return capture, observe(capture, Config(texels=TexelConfig(texture_res=TEXTURE_RES))), dark


# --- the bilinear sampler -----------------------------------------------------------------------


def test_bilinear_sampler_matches_scipy_with_pixel_centres_at_half_integers():
    """Pixel (i, j) is centred at (x, y) = (j + 0.5, i + 0.5): scipy's map_coordinates of order 1
    at (y - 0.5, x - 0.5), edges clamped ('nearest'), is the same interpolation."""
    rng = np.random.default_rng(0)
    image = rng.uniform(0.0, 5.0, size=(7, 9, 3)).astype(np.float32)
    height, width = image.shape[:2]
    inside = rng.uniform([0.0, 0.0], [width, height], size=(500, 2))
    centres = np.stack(np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5), -1).reshape(-1, 2)
    border = np.array([[0.0, 0.0], [width, height], [0.2, height], [width, 3.7], [4.0, 0.1]])
    pixels = np.concatenate([inside, centres, border])
    ours = np.empty((len(pixels), 3), np.float32)
    _sample_bilinear(image, pixels, ours)
    expected = np.stack(
        [ndimage.map_coordinates(image[..., c].astype(np.float64), [pixels[:, 1] - 0.5, pixels[:, 0] - 0.5],
                                 order=1, mode="nearest") for c in range(3)], axis=-1)
    np.testing.assert_allclose(ours, expected, rtol=1e-5, atol=1e-5)
    # At a pixel centre the sample is that pixel, exactly.
    np.testing.assert_array_equal(ours[500:500 + len(centres)], image.reshape(-1, 3))


# --- irradiance -----------------------------------------------------------------------------------


def test_irradiance_matches_quadrature_of_mitsubas_envmap():
    """E(n) against brute force: the map as Mitsuba evaluates it (bilinear, `lookup`) integrated
    with max(0, n.w) on a fine lat-long grid. The SH route (degree 20) is within 0.6 %."""
    to_world = np.eye(4)
    to_world[:3, :3] = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # zenith moved
    envmap = load_envmap(envmap_path("forest"), to_world)
    rows, cols = 1024, 2048
    polar = (np.arange(rows) + 0.5) / rows * np.pi
    azimuth = (np.arange(cols) + 0.5) / cols * 2.0 * np.pi
    directions = np.stack(np.broadcast_arrays(
        np.sin(polar)[:, None] * np.cos(azimuth), np.cos(polar)[:, None], np.sin(polar)[:, None] * np.sin(azimuth)
    ), -1).reshape(-1, 3)
    solid_angle = np.repeat(np.sin(polar) * (np.pi / rows) * (2.0 * np.pi / cols), cols)
    weighted = lookup(envmap, directions) * solid_angle[:, None]  # (P, 3)
    normals = np.random.default_rng(1).normal(size=(12, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    expected = np.maximum(directions @ normals.T, 0.0).T @ weighted  # (12, 3)
    np.testing.assert_allclose(texel_irradiance(envmap, normals), expected, rtol=6e-3)


# --- acceptance on Mitsuba renders ------------------------------------------------------------------

@pytest.mark.slow
def test_observed_radiance_is_the_pixel_the_texel_projects_to(mirror_sphere):
    """Every sample is the photograph, bilinearly interpolated (scipy, half-pixel convention)
    where the camera model puts the texel; a texel within 0.1 px of a pixel centre reads that
    pixel, up to the neighbours' bilinear weights (< 20 %) times their spread."""
    capture, observations = mirror_sphere
    texels = rasterise(capture.mesh, TEXTURE_RES)
    near_centre_errors = []
    for view in range(len(capture.frames)):
        image = capture.image(view)
        pixels, _ = capture.frames[view].camera.project(texels.position)
        sampled = observations.visible[:, view]
        expected = np.stack([
            ndimage.map_coordinates(image[..., c], [pixels[sampled, 1] - 0.5, pixels[sampled, 0] - 0.5],
                                    order=1, mode="nearest") for c in range(3)], axis=-1)
        np.testing.assert_allclose(observations.observed[sampled, view], expected, rtol=1e-4, atol=1e-6)

        offset = pixels - (np.floor(pixels) + 0.5)
        near_centre = sampled & (np.abs(offset) < 0.1).all(axis=1)
        rows, cols = np.floor(pixels[near_centre, 1]).astype(int), np.floor(pixels[near_centre, 0]).astype(int)
        spread = ndimage.maximum_filter(image, size=(3, 3, 1)) - ndimage.minimum_filter(image, size=(3, 3, 1))
        difference = np.abs(observations.observed[near_centre, view] - image[rows, cols])
        assert (difference <= 0.2 * spread[rows, cols] + 1e-6).all()
        near_centre_errors.append(difference / image[rows, cols])
    near_centre_errors = np.concatenate(near_centre_errors)
    assert len(near_centre_errors) > 200 and np.median(near_centre_errors) < 0.015  # measured: 0.9 %


@pytest.mark.slow
def test_mirror_conductor_observes_the_environment_in_the_mirror_direction(mirror_sphere):
    """The observed radiance of a perfect mirror is the environment in the mirror direction
    (median relative error a few %: a pixel averages the map over its footprint, which on a
    curved mirror spans several environment texels, while the lookup is a point)."""
    capture, observations = mirror_sphere
    assert observations.sigma == 0.0
    sampled = observations.weight > 0.3  # away from grazing, where the footprint stretches
    observed, mirrored = observations.observed[sampled], observations.mirrored[sampled]
    assert sampled.sum() > 2000
    assert np.median(np.abs(observed - mirrored) / mirrored) < 0.02  # measured: 0.8 %

    # Control: the same mirror directions, rebuilt from the local view directions, looked up in
    # the map turned half round the zenith (a plausible convention slip) miss by far more.
    texels = rasterise(capture.mesh, TEXTURE_RES)
    frame = np.stack([texels.tangent, texels.bitangent, texels.normal], axis=1)  # (N, 3, 3) rows
    mirror_local = observations.view_direction * np.array([-1.0, -1.0, 1.0], np.float32)
    mirror_world = np.einsum("nvi,nij->nvj", mirror_local, frame)[sampled]
    np.testing.assert_allclose(lookup(capture.envmap, mirror_world), mirrored, rtol=1e-4, atol=1e-6)
    turned = Envmap(capture.envmap.radiance, np.diag([-1.0, 1.0, -1.0, 1.0]))
    assert np.median(np.abs(observed - lookup(turned, mirror_world)) / mirrored) > 0.1


@pytest.mark.slow
def test_white_lambertian_observes_irradiance_over_pi(lambertian_sphere):
    """Per texel the mean observed radiance over its views is E / pi (diffuse reflectance 1).

    Each pixel is a 128-sample estimate (a few % noise), averaged over the texel's views; the
    median must be within 1.5 % and 90 % of texels within 6 %. Our E is exact up to 0.6 %
    (test_irradiance_matches_quadrature...); the sphere mesh is faceted, but shading normals
    are interpolated identically in Mitsuba and in our texels.
    """
    _, observations = lambertian_sphere
    sampled = observations.n_samples >= 2
    mean_observed = (observations.observed * (observations.weight > 0)[..., None]).sum(axis=1)
    mean_observed = mean_observed[sampled] / observations.n_samples[sampled, None]
    ratio = mean_observed / (observations.irradiance[sampled] / np.pi)
    assert sampled.sum() > 1000
    assert abs(np.median(ratio) - 1.0) < 0.015
    assert np.quantile(np.abs(ratio - 1.0), 0.9) < 0.06


@pytest.mark.slow
def test_visibility_agrees_with_mitsubas_depth(checker_bunny):
    """Texels are sampled in a view exactly when Mitsuba's depth at their pixel says the camera
    sees them: their distance to the camera matches the depth (within 2 % of the object's size,
    about two pixel footprints) rather than exceeding it. Pixels on silhouettes or depth steps
    (partly covered, or 3 x 3 depth range above 5 % of the size) are left out."""
    capture, observations, _ = checker_bunny
    mi = render.mitsuba()
    scene = mi.load_dict({"type": "scene", "object": render.mesh_shape(capture.mesh, {"type": "diffuse"})})
    texels = rasterise(capture.mesh, TEXTURE_RES)
    extent = np.linalg.norm(np.ptp(capture.mesh.vertices, axis=0))
    compared = 0
    for view in (0, 3):
        camera = capture.frames[view].camera
        sensor = mi.load_dict(render.perspective_sensor(camera, 16))
        rendered = np.array(mi.render(scene, sensor=sensor, spp=16, seed=view,
                                      integrator=mi.load_dict({"type": "depth"})))
        depth, coverage = rendered[..., 0], rendered[..., 3]  # ray distance; hit fraction
        pixels, _ = camera.project(texels.position)
        in_frame = ((pixels >= 0) & (pixels < [camera.width, camera.height])).all(axis=1)
        rows = np.clip(np.floor(pixels[:, 1]), 0, camera.height - 1).astype(int)
        cols = np.clip(np.floor(pixels[:, 0]), 0, camera.width - 1).astype(int)
        depth_range = ndimage.maximum_filter(depth, 3) - ndimage.minimum_filter(depth, 3)
        interior = (ndimage.minimum_filter(coverage, 3) >= 1.0) & (depth_range < 0.05 * extent)
        judged = in_frame & interior[rows, cols]
        behind = np.linalg.norm(texels.position - camera.center, axis=1) - depth[rows, cols]
        seen_by_depth = np.abs(behind) <= 0.02 * extent
        sampled = observations.visible[:, view]
        assert np.mean(sampled[judged] == seen_by_depth[judged]) > 0.98
        assert not (sampled & judged & (behind > 0.1 * extent)).any()  # clearly hidden: never sampled
        assert 0.2 < seen_by_depth[judged].mean() < 0.8  # both kinds are present
        compared += judged.sum()
    assert compared > 1500


@pytest.mark.slow
def test_dark_texels_are_weighted_like_bright_ones(checker_bunny):
    """Base colour 0 and 0.8 alternate in 8 x 8 texel squares, so both see the same geometry:
    their sample counts and weights must agree, although the dark ones reflect little light."""
    _, observations, dark_texture = checker_bunny
    dark = dark_texture.reshape(-1)[observations.texel_index]
    sampled = observations.weight > 0
    brightness = observations.observed.mean(axis=2)
    assert np.median(brightness[sampled & dark[:, None]]) < 0.2 * np.median(brightness[sampled & ~dark[:, None]])
    # Samples per texel, total weight, and the share of texels seen at all.
    for statistic in (observations.n_samples, observations.weight.sum(axis=1), observations.n_samples > 0):
        dark_mean, bright_mean = statistic[dark].mean(), statistic[~dark].mean()
        assert abs(dark_mean - bright_mean) < 0.05 * bright_mean


@pytest.mark.slow
def test_observations_round_trip_through_npz(checker_bunny, tmp_path):
    _, observations, _ = checker_bunny
    path = tmp_path / "observations.npz"
    observations.save(path)
    loaded = Observations.load(path)
    assert observations.texels is not None and loaded.texels is None  # the texels are the mesh's, not saved
    for name, value in vars(observations).items():
        if name == "texels":
            continue
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(getattr(loaded, name), value, err_msg=name)
            assert getattr(loaded, name).dtype == value.dtype, name
        else:
            assert getattr(loaded, name) == value and type(getattr(loaded, name)) is type(value), name
    np.testing.assert_array_equal(loaded.observed_spectrum, observations.observed_spectrum)
    # The texel frame and the environment the estimator's environment light reads travel along;
    # a file from before they did loads without them (the estimator then uses the fitted light).
    assert abs(np.sum(loaded.tangent * loaded.normal, axis=1)).max() < 1e-5
    assert loaded.environment_coeffs.shape == (sh.num_coeffs(observations.lmax), 3)
    assert loaded.environment_coeffs[0, 0] > 0.0  # the DC of a real map
    # So does the map the prefiltered light reads, with its frame.
    environment = loaded.environment()
    assert environment.radiance.shape == observations.environment_radiance.shape
    np.testing.assert_array_equal(environment.rotation, observations.environment_rotation)
    older = dict(np.load(path))
    del older["tangent"], older["environment_coeffs"], older["environment_radiance"], older["environment_rotation"]
    np.savez(tmp_path / "older.npz", **older)
    assert Observations.load(tmp_path / "older.npz").tangent is None
    assert Observations.load(tmp_path / "older.npz").environment() is None

    with pytest.raises(InputError, match="does not exist"):
        Observations.load(tmp_path / "missing.npz")
    np.savez(tmp_path / "other.npz", something=np.zeros(3))
    with pytest.raises(InputError, match="not a freqbrdf observations file"):
        Observations.load(tmp_path / "other.npz")


def test_with_views_is_what_observing_only_those_views_gives(checker_bunny):
    """Dropping views from the observations and refitting equals observing a capture of only
    those views (without the band limit, which depends on the view count)."""
    capture = checker_bunny[0]
    config = Config(texels=TexelConfig(texture_res=TEXTURE_RES), fit=FitConfig(band_limit=False))
    keep = np.arange(len(capture.frames)) % 2 == 0
    whole = observe(capture, config)
    dropped = whole.with_views(keep, config)
    alone = observe(replace(capture, frames=tuple(f for f, k in zip(capture.frames, keep) if k)), config)
    assert dropped.n_views == len(capture.frames) and alone.n_views == keep.sum()
    assert np.all(dropped.weight[:, ~keep] == 0) and not dropped.visible[:, ~keep].any()
    for name in ("weight", "visible", "observed", "mirrored"):
        np.testing.assert_array_equal(getattr(dropped, name)[:, keep], getattr(alone, name), err_msg=name)
    for name in ("n_samples", "fit_status", "alpha_bound"):
        np.testing.assert_array_equal(getattr(dropped, name), getattr(alone, name), err_msg=name)
    assert (alone.n_samples > 0).mean() > 0.3  # the bunny is seen, with fewer samples than before
    assert (dropped.n_samples < whole.n_samples).any()
    for name in ("observed_coeffs", "mirrored_coeffs", "constant_coeffs"):
        np.testing.assert_allclose(getattr(dropped, name), getattr(alone, name), rtol=1e-5, atol=1e-6, err_msg=name)
    with pytest.raises(ValueError, match="keep must be"):
        dropped.with_views(keep[:-1], config)


def test_at_most_views_keeps_each_texels_samples_evenly_over_its_views(checker_bunny):
    """A texel with more samples than asked keeps that many, its first and last view among them and
    each kept sample as observed; one with fewer keeps them all; the per-texel fits are kept."""
    whole = observe(checker_bunny[0], Config(texels=TexelConfig(texture_res=TEXTURE_RES)))
    counts = np.count_nonzero(whole.weight > 0, axis=1)
    most = 3
    assert counts.max() > most and (counts[counts > 0] <= most).any()  # both kinds of texel
    thinned = whole.at_most_views(most)
    assert thinned.n_views == most and thinned.n_texels == whole.n_texels
    np.testing.assert_array_equal(thinned.n_samples, np.minimum(counts, most))
    np.testing.assert_array_equal(thinned.observed_coeffs, whole.observed_coeffs)
    for texel in np.flatnonzero(counts > 0):
        views = np.flatnonzero(whole.weight[texel] > 0)
        kept = thinned.weight[texel] > 0
        expected = views[np.rint(np.linspace(0, len(views) - 1, most)).astype(int)] if len(views) > most else views
        for name in ("weight", "observed", "view_direction", "mirrored"):
            np.testing.assert_array_equal(getattr(thinned, name)[texel][kept], getattr(whole, name)[texel][expected],
                                          err_msg=name)
    assert whole.at_most_views(whole.n_views) is whole


@pytest.mark.slow
def test_observe_command_writes_observations_and_maps(checker_bunny, tmp_path, monkeypatch, capsys):
    capture, observations, _ = checker_bunny
    out = tmp_path / "observed"
    monkeypatch.setattr(sys, "argv", ["freqbrdf", "observe", str(capture.root), "--out", str(out),
                                      "--texture-res", str(TEXTURE_RES), "--lmax", "3", "--quiet"])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code in (None, 0)
    written = Observations.load(out / "observations.npz")
    assert written.lmax == 3 and written.observed_coeffs.shape[-1] == 16
    np.testing.assert_array_equal(written.weight, observations.weight)  # same samples as the API
    summary = json.loads((out / "observations.json").read_text())
    assert summary["texels"] == observations.n_texels and summary["views"] == 5
    from PIL import Image

    for name in ("coverage.png", "visibility.png"):
        with Image.open(out / name) as image:
            assert min(image.size) >= TEXTURE_RES  # the texture at one pixel per texel or more
    assert capsys.readouterr().err == ""  # --quiet: no progress bars

    monkeypatch.setattr(sys, "argv", ["freqbrdf", "observe", str(tmp_path / "nowhere"), "--out", str(out)])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2
    error = capsys.readouterr().err
    assert "nowhere" in error and len(error.strip().splitlines()) == 1


@pytest.mark.skipif(__import__("platform").machine() != "x86_64", reason="reads glibc's x86-64 fenv_t layout")
def test_ray_tests_leave_the_floating_point_environment_as_they_found_it():
    # Mitsuba's tracing may set flush-to-zero on the calling thread on some runs only, and numba's
    # kernels then compute differently there than on their workers: fits changed in their last
    # digits between runs. The guard restores the environment; fesetround is a change we can see.
    import ctypes
    import ctypes.util

    libm = ctypes.CDLL(ctypes.util.find_library("m"))
    before = ctypes.create_string_buffer(64)
    libm.fegetenv(before)
    round_to_nearest = libm.fegetround()
    with render.restored_floating_point():
        libm.fesetround(0x800)  # FE_UPWARD on x86
        assert libm.fegetround() != round_to_nearest
    assert libm.fegetround() == round_to_nearest
    corners = np.array([[-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], float)
    roof = Mesh(vertices=corners, faces=np.array([[0, 2, 1], [0, 3, 2]]),
                normals=np.tile([0.0, 0.0, -1.0], (4, 1)), uv=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float))
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(50_000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    hits = Occluder(roof).hits(np.zeros((50_000, 3)), directions)
    assert hits.any() and not hits.all()
    after = ctypes.create_string_buffer(64)
    libm.fegetenv(after)

    def modes(environment):  # glibc x86-64 fenv_t: x87 control word, MXCSR without its status flags
        return environment.raw[0:2], int.from_bytes(environment.raw[28:32], "little") & ~0x3F

    assert modes(after) == modes(before)


def test_environment_occlusion_changes_nothing_on_a_convex_mesh(lambertian_sphere):
    capture, observations = lambertian_sphere
    plain = observe(capture, Config(texels=TexelConfig(texture_res=TEXTURE_RES),
                                    observe=ObserveConfig(environment_occlusion=False)))
    assert np.array_equal(plain.irradiance, observations.irradiance)
    assert observations.timings["occlusion"] < observations.timings["total"]
