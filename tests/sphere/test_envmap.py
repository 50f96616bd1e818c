"""Environment maps: Mitsuba's convention, SH transforms and irradiance."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from freqbrdf.errors import InputError
from freqbrdf.sphere import envmap as em
from freqbrdf.sphere import harmonics as sh


def random_directions(rng, n):
    directions = rng.normal(size=(n, 3))
    return directions / np.linalg.norm(directions, axis=-1, keepdims=True)


def transform(rotation):
    to_world = np.eye(4)
    to_world[:3, :3] = rotation
    to_world[:3, 3] = [0.3, -2.0, 1.0]  # translation must not matter for directions
    return to_world


def pixel_directions(height, width, rotation):
    """World directions of Mitsuba's sample positions: u = (j + 0.5) / W, v = i / (H - 1)."""
    theta = np.pi * np.arange(height) / (height - 1)
    phi = 2 * np.pi * (np.arange(width) + 0.5) / width
    theta, phi = np.meshgrid(theta, phi, indexing="ij")
    local = np.stack([np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)], -1)
    return local @ rotation.T, theta


@pytest.mark.slow
def test_lookup_matches_mitsuba_envmap_emitter():
    mi = pytest.importorskip("mitsuba", reason="Mitsuba is a project dependency")
    import drjit as dr

    mi.set_variant("llvm_ad_rgb")
    rng = np.random.default_rng(0)
    radiance = rng.random((7, 12, 3)).astype(np.float32) * 5
    rotation = Rotation.random(random_state=1).as_matrix()
    envmap = em.Envmap(radiance, transform(rotation))
    emitter = mi.load_dict(
        {"type": "envmap", "bitmap": mi.Bitmap(radiance), "to_world": mi.ScalarTransform4f(envmap.to_world)}
    )
    # Mitsuba keeps the bitmap as is, only padding one periodic column on each side.
    data = np.array(mi.traverse(emitter)["data"])
    np.testing.assert_array_equal(data[:, 1:-1], radiance)

    directions = random_directions(rng, 20000)
    si = dr.zeros(mi.SurfaceInteraction3f, len(directions))
    si.wi = mi.Vector3f(-directions.T.astype(np.float32))  # the ray travels along -direction
    expected = np.array(emitter.eval(si)).T
    ours = em.lookup(envmap, directions)
    # Mitsuba maps directions to (u, v) in float32; where the bitmap is steep that rounding shows.
    np.testing.assert_allclose(ours, expected, rtol=2e-4, atol=2e-4)
    assert np.median(np.abs(ours - expected)) < 1e-6


def test_lookup_reproduces_pixels_at_their_sample_positions():
    rng = np.random.default_rng(2)
    radiance = rng.random((9, 18, 3)).astype(np.float32)
    rotation = Rotation.random(random_state=3).as_matrix()
    envmap = em.Envmap(radiance, transform(rotation))
    directions, theta = pixel_directions(9, 18, rotation)
    inner = (theta > 0) & (theta < np.pi)  # at the poles every column is the same point
    np.testing.assert_allclose(em.lookup(envmap, directions)[inner], radiance[inner], atol=1e-5)


def test_envmap_rejects_bad_shapes_and_non_rotations():
    with pytest.raises(ValueError):
        em.Envmap(np.zeros((4, 8)))
    with pytest.raises(ValueError):
        em.Envmap(np.zeros((4, 8, 3)), np.diag([2.0, 1.0, 1.0, 1.0]))


@pytest.mark.parametrize("seed", [4, 5])
def test_sh_transform_and_synthesis_agree_with_direct_evaluation(seed):
    rng = np.random.default_rng(seed)
    lmax, height = 8, 24
    coeffs = rng.normal(size=(sh.num_coeffs(lmax), 3))
    rotation = Rotation.random(random_state=seed).as_matrix()
    envmap = em.envmap_from_sh(coeffs, height, to_world=transform(rotation))
    directions, _ = pixel_directions(height, 2 * height, rotation)
    direct = sh.eval_sh(directions, lmax) @ coeffs  # the basis in the WORLD frame
    np.testing.assert_allclose(envmap.radiance, direct, atol=2e-6 * np.abs(direct).max())
    np.testing.assert_allclose(em.envmap_sh(envmap, lmax), coeffs, atol=1e-5)


def test_sh_transform_rejects_degrees_beyond_the_map_resolution():
    with pytest.raises(ValueError):
        em.envmap_sh(em.Envmap(np.ones((8, 16, 3))), 7)


def test_downsample_averages_in_pixel_space():
    # A smooth map comes out as itself at the coarser texels' directions; a light smaller than a
    # coarse texel keeps its power (solid-angle weighted), and nothing rings around it.
    height = 64
    polar = np.pi * np.arange(height) / (height - 1)
    azimuth = 2.0 * np.pi * (np.arange(2 * height) + 0.5) / (2 * height)
    smooth = 1.0 + 0.5 * em.local_directions(polar, azimuth)  # linear in the direction, per channel
    coarse = em.downsample(smooth.astype(np.float32), 16)
    expected = 1.0 + 0.5 * em.local_directions(np.pi * np.arange(16) / 15, 2.0 * np.pi * (np.arange(32) + 0.5) / 32)
    assert coarse.shape == (16, 32, 3)
    np.testing.assert_allclose(coarse[1:-1], expected[1:-1], atol=0.03)
    lit = np.full((height, 2 * height, 3), 0.25, np.float32)
    lit[30:32, 40:42] = 100.0
    small = em.downsample(lit, 16)

    def power(radiance):
        rows = radiance.shape[0]
        return float((np.sin(np.pi * np.arange(rows) / (rows - 1))[:, None, None] * (radiance - 0.25)).sum()
                     * (np.pi / (rows - 1)) * (np.pi / rows))

    assert power(small) == pytest.approx(power(lit), rel=0.05)
    assert small.min() >= 0.25 - 1e-6  # no negative lobes
    np.testing.assert_array_equal(em.downsample(lit, height), lit)


@pytest.mark.parametrize("rotated", [False, True])
def test_lowpass_and_zonal_filter_scale_each_degree(rotated):
    # The filter runs in the map's own frame; a rotated emitter checks that it commutes with the
    # rotation into the world frame, as a zonal filter must.
    rng = np.random.default_rng(6)
    lmax, sigma = 6, 0.25
    coeffs = rng.normal(size=(sh.num_coeffs(lmax), 3))
    to_world = np.eye(4)
    if rotated:
        to_world[:3, :3] = Rotation.random(random_state=4).as_matrix()
    envmap = em.envmap_from_sh(coeffs, 32, to_world=to_world)
    filtered = em.envmap_sh(em.lowpass_envmap(envmap, sigma), lmax)
    np.testing.assert_allclose(filtered, sh.gaussian_lowpass(coeffs.T, sigma).T, atol=1e-5)
    # Any per-degree gains (zonal_filter): each degree scaled, degrees beyond the gains dropped.
    gains = np.array([1.0, 0.5, -0.25, 2.0])
    zonal = em.envmap_sh(em.zonal_filter(envmap, gains), lmax)
    expected = np.where(sh.sh_degrees(lmax)[:, None] < len(gains),
                        coeffs * np.append(gains, np.zeros(lmax + 1 - len(gains)))[sh.sh_degrees(lmax)][:, None], 0.0)
    np.testing.assert_allclose(zonal, expected, atol=1e-5)
    # Several gains at once (zonal_filters), and resampled to another height: the same function.
    stacked = em.zonal_filters(envmap, np.stack([gains, gains[::-1]]), height=16)
    assert stacked.shape == (2, 16, 32, 3)
    for row, expected_gains in zip(stacked, (gains, gains[::-1])):
        resampled = em.envmap_sh(em.Envmap(row, envmap.to_world), lmax)
        expected = np.where(sh.sh_degrees(lmax)[:, None] < len(gains), coeffs * np.append(
            expected_gains, np.zeros(lmax + 1 - len(gains)))[sh.sh_degrees(lmax)][:, None], 0.0)
        np.testing.assert_allclose(resampled, expected, atol=1e-5)


def test_zonal_filters_in_chunks_give_the_same_maps(monkeypatch):
    # zonal_filters synthesises several filters at once, in chunks of at most _SYNTHESIS_SAMPLES
    # map samples: how it splits them must not change a bit.
    rng = np.random.default_rng(13)
    envmap = em.Envmap(rng.random((16, 32, 3)).astype(np.float32) * 4)
    gains = rng.random((5, 15))
    whole = em.zonal_filters(envmap, gains)
    monkeypatch.setattr(em, "_SYNTHESIS_SAMPLES", 2 * 3 * 16 * 32)  # two filters per chunk
    np.testing.assert_array_equal(em.zonal_filters(envmap, gains), whole)
    for row, gain in zip(whole, gains):
        np.testing.assert_array_equal(row, em.zonal_filter(envmap, gain).radiance)


def test_clamped_cosine_kernel_matches_numerical_integral():
    kernel = em.clamped_cosine_coeffs(12)
    t, w = np.polynomial.legendre.leggauss(40)
    t, w = (t + 1) / 2, w / 2  # Gauss-Legendre on [0, 1]
    for degree in range(13):
        legendre = np.polynomial.legendre.Legendre.basis(degree)(t)
        assert kernel[degree] == pytest.approx(2 * np.pi * np.sum(w * t * legendre), abs=1e-13)


def test_irradiance_of_a_constant_unit_environment_is_pi():
    envmap = em.Envmap(np.ones((32, 64, 3), np.float32))
    coeffs = em.envmap_sh(envmap, em.IRRADIANCE_LMAX)
    normals = random_directions(np.random.default_rng(7), 100).astype(np.float32)
    result = em.irradiance(coeffs, normals)
    assert result.dtype == np.float32
    np.testing.assert_allclose(result, np.pi, rtol=1e-5)


def test_irradiance_agrees_with_brute_force_quadrature_over_pixels():
    rng = np.random.default_rng(8)
    height, width = 128, 256
    rotation = Rotation.random(random_state=9).as_matrix()
    # A smooth sky, a sharp bright rectangle ("sun", 50x the sky) and per-channel tints.
    sky_coeffs = rng.normal(size=(sh.num_coeffs(3), 3)) * 0.2
    sky_coeffs[0] += 2.0 * math.sqrt(4 * math.pi)  # mean radiance 2
    sky = em.envmap_from_sh(sky_coeffs, height)
    radiance = np.maximum(sky.radiance, 0.0)
    radiance[20:26, 40:52] += np.array([60.0, 50.0, 40.0], np.float32)
    envmap = em.Envmap(radiance, transform(rotation))
    normals = random_directions(rng, 64)

    # Brute force: sum over the pixels' sample points, each with its exact solid angle (the
    # polar rows own half a ring).
    directions, theta = pixel_directions(height, width, rotation)
    half = np.pi / (height - 1) / 2
    ring_area = 2 * np.pi / width * (np.cos(np.maximum(theta - half, 0)) - np.cos(np.minimum(theta + half, np.pi)))
    assert ring_area.sum() == pytest.approx(4 * np.pi)
    cosines = np.maximum(directions.reshape(-1, 3) @ normals.T, 0.0)  # (H W, N)
    brute = cosines.T @ (radiance.reshape(-1, 3) * ring_area.reshape(-1, 1))

    result = em.irradiance(em.envmap_sh(envmap, em.IRRADIANCE_LMAX), normals.astype(np.float32))
    assert np.abs(result / brute - 1).max() < 0.01


def test_load_envmap_checks_aspect_ratio(tmp_path):
    images = pytest.importorskip("freqbrdf.images", reason="freqbrdf.images lands with another issue")
    good = np.random.default_rng(10).random((8, 16, 3)).astype(np.float32)
    images.write_exr(tmp_path / "good.exr", good)
    loaded = em.load_envmap(tmp_path / "good.exr", transform(np.eye(3)))
    np.testing.assert_allclose(loaded.radiance, good, rtol=1e-3)
    images.write_exr(tmp_path / "square.exr", good[:, :8])
    with pytest.raises(InputError, match="2:1"):
        em.load_envmap(tmp_path / "square.exr")


def test_a_maps_transforms_are_remembered_and_its_radiance_then_read_only():
    rng = np.random.default_rng(3)
    pixels = rng.uniform(0.0, 2.0, (16, 32, 4)).astype(np.float32)
    envmap = em.Envmap(pixels[..., :3])  # a view: the map takes a copy of its own
    assert envmap.radiance.base is None and not np.shares_memory(envmap.radiance, pixels)
    first = em.envmap_sh(envmap, 4)
    assert not envmap.radiance.flags.writeable  # an edit in place would meet stale transforms
    with pytest.raises(ValueError):
        envmap.radiance[0, 0, 0] = 5.0
    np.testing.assert_array_equal(em.envmap_sh(envmap, 4), first)
    # Another degree, another map, the same contents: computed again, each as its own.
    np.testing.assert_allclose(em.envmap_sh(envmap, 2), first[:9], rtol=1e-12, atol=1e-12)
    edited = envmap.radiance.copy()
    edited[0] *= 3.0
    assert not np.allclose(em.envmap_sh(em.Envmap(edited), 4), first)
    assert em.radiance_digest(envmap.radiance) == em.radiance_digest(envmap.radiance.copy())
    assert em.radiance_digest(edited) != em.radiance_digest(envmap.radiance)
    # A view is never frozen nor remembered: its base could change under it.
    view = pixels[..., :3]
    em.downsample(view, 8)
    assert view.flags.writeable and pixels.flags.writeable
