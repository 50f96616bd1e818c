"""Sharing across the surface: anchors, chunked KL affinities, and the pull on uncertain texels."""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest
from scipy.special import rel_entr

from freqbrdf.applications.share import (
    PROBABILITY_FLOOR,
    anchor_affinity,
    find_anchors,
    share,
    share_details,
    texel_coordinates,
)
from freqbrdf.config import Config, EstimateConfig, ShareConfig, UncertaintyConfig
from freqbrdf.estimate import angular_loss, estimate, model_light
from freqbrdf.model import brdf
from freqbrdf.observe.observations import Observations
from freqbrdf.sphere import harmonics as sh
from freqbrdf.uncertainty import (
    FLAG_BELOW_BOUND,
    HypothesisGrid,
    Uncertainty,
    entropy_map,
    hypothesis_grid,
)
from helpers import observations_from_samples

LMAX = 5
N_VIEWS = 48


def two_light_observations(truth: brdf.PrincipledParams, informative: np.ndarray, seed: int,
                           noise: float) -> Observations:
    """Observations of a texture (row-major, square) rendered by brdf.predict_angular.

    ``informative`` (N,) texels see a light of sharp coloured lobes (their roughness is pinned
    down); the others a constant light, which says nothing about roughness. Gaussian noise of
    std ``noise`` is added to every observed radiance.
    """
    rng = np.random.default_rng(seed)
    n_texels = len(truth.roughness)
    cos_theta = rng.uniform(0.1, 1.0, (n_texels, N_VIEWS))
    phi = rng.uniform(0.0, 2.0 * math.pi, (n_texels, N_VIEWS))
    sin_theta = np.sqrt(1.0 - cos_theta**2)
    directions = np.stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), cos_theta], axis=-1)
    weight = cos_theta
    mirror = directions * np.array([-1.0, -1.0, 1.0])  # 2 (n.v) n - v in the local frame
    lobe_axes = np.array([[0.6, 0.0, 0.8], [-0.5, 0.5, 0.7], [0.0, -0.6, 0.8]])
    lobe_colours = np.array([[3.0, 1.0, 0.5], [0.5, 3.0, 1.0], [1.0, 0.5, 3.0]])
    lobes = np.maximum(np.einsum("tvi,ji->tvj", mirror, lobe_axes), 0.0) ** 40
    mirrored = np.where(informative[:, None, None], 0.2 + lobes @ lobe_colours, 1.0)
    irradiance = np.where(informative[:, None], 1.5, 3.0) * np.ones((n_texels, 3))
    sigma = brdf.band_limit_sigma(N_VIEWS)

    mf = brdf.microfacet_from_principled(truth)
    incoming = sh.fit_sh(directions, weight, brdf.shadowed_light(mirrored, cos_theta, mf.alpha), LMAX, 1.2e-4).coeffs
    observed = brdf.predict_angular(mf, directions, incoming, irradiance, sigma=sigma)
    observed = observed + rng.normal(0.0, noise, observed.shape)
    return observations_from_samples(
        directions, weight, observed, mirrored, LMAX, irradiance=irradiance, sigma=sigma, reg_lambda=1.2e-4,
        visible=np.ones((n_texels, N_VIEWS), bool), n_facing=np.full(n_texels, N_VIEWS, np.int32),
        alpha_bound=np.full(n_texels, brdf.min_resolvable_alpha(LMAX), np.float32))


@pytest.fixture(scope="module")
def one_material_two_lights():
    """A 16 x 16 texture of one gold-like material; its right half lies under a constant light."""
    resolution = 16
    n_texels = resolution * resolution
    truth = brdf.PrincipledParams(
        base_color=np.tile([0.9, 0.6, 0.3], (n_texels, 1)), roughness=np.full(n_texels, 0.35),
        metallic=np.ones(n_texels),
    )
    informative = np.arange(n_texels) % resolution < resolution // 2
    observations = two_light_observations(truth, informative, seed=3, noise=0.1)
    # Under the constant light the entropy lies in 0.26-0.52, under the lobes below 0.18, with a
    # fixed noise floor. (The default also counts the residual as noise, which on this noisy toy
    # blurs the two halves together; sharing, not the entropy's calibration, is tested here.)
    # Gaussian noise: least squares (no robust passes) is the maximum-likelihood estimate.
    config = Config(share=ShareConfig(enabled=True, anchor_cells=4, uncertain_entropy=0.25),
                    uncertainty=UncertaintyConfig(residual_noise=False), estimate=EstimateConfig(robust_passes=0))
    fitted = estimate(observations, config)
    uncertainty = entropy_map(observations, config.uncertainty)
    return truth, informative, observations, config, fitted, uncertainty


def test_sharing_improves_uncertain_texels_and_leaves_certain_ones(one_material_two_lights):
    truth, informative, observations, config, fitted, uncertainty = one_material_two_lights
    uncertain = uncertainty.entropy >= config.share.uncertain_entropy
    # The set-up does what it says: the constant light leaves roughness uncertain and wrong (1.8x
    # the error of the certain texels with the exact-dielectric estimator, 0.046 against 0.026).
    assert uncertain[~informative].mean() > 0.9 and not uncertain[informative].any()
    error_before = np.abs(fitted.roughness - truth.roughness)
    assert error_before[uncertain].mean() > 1.5 * error_before[~uncertain].mean()

    result = share_details(observations, fitted, uncertainty, config)
    shared = result.estimate
    assert len(result.anchor_rows) > 0 and informative[result.anchor_rows].all()
    error_after = np.abs(shared.roughness - truth.roughness)
    # 0.66x with the entropy of commit 6cecb07 (noise floor per sample count), 0.5x before it.
    assert error_after[uncertain].mean() < 0.75 * error_before[uncertain].mean()
    for name in ("base_color", "roughness", "metallic"):  # certain texels: bit for bit the same
        np.testing.assert_array_equal(getattr(shared, name)[~uncertain], getattr(fitted, name)[~uncertain])
    # The pull never costs a texel more data loss than the tolerance allows.
    rows = result.pulled_rows[result.moved]
    own = angular_loss(observations, fitted.principled(), config,
                       model_light(observations, fitted.roughness, config))[rows]
    assert np.all(shared.loss[rows] <= (1.0 + config.share.loss_tolerance) * own + 1e-12)
    assert shared.method == fitted.method + "+share" and "share" in shared.timings
    # `share` is the estimate of `share_details`; deterministic.
    np.testing.assert_array_equal(share(observations, fitted, uncertainty, config).roughness, shared.roughness)


def test_sharing_without_confident_anchors_changes_nothing(one_material_two_lights):
    _, _, observations, config, fitted, uncertainty = one_material_two_lights
    strict = config.replace(share=ShareConfig(enabled=True, uncertain_entropy=0.25, anchor_certainty=1.01))
    result = share_details(observations, fitted, uncertainty, strict)
    assert len(result.anchor_rows) == 0 and not result.moved.any()
    np.testing.assert_array_equal(result.estimate.roughness, fitted.roughness)


def test_bad_arguments_are_rejected(one_material_two_lights):
    _, _, observations, config, fitted, uncertainty = one_material_two_lights
    without_grids = Uncertainty(**{**uncertainty.__dict__, "likelihood": None})
    with pytest.raises(ValueError, match="likelihood"):
        share(observations, fitted, without_grids, config)
    fewer = Uncertainty(**{**uncertainty.__dict__, "entropy": uncertainty.entropy[:-1]})
    with pytest.raises(ValueError, match="same texels"):
        share(observations, fitted, fewer, config)
    with pytest.raises(ValueError, match="neighbours"):
        share(observations, fitted, uncertainty, config.replace(share=ShareConfig(neighbours=0)))


def _uncertainty(entropy: np.ndarray, flags: np.ndarray, likelihood: np.ndarray) -> Uncertainty:
    grid: HypothesisGrid = hypothesis_grid(likelihood.shape[1])
    n_texels = len(entropy)
    nan = np.full(n_texels, np.nan, np.float32)
    return Uncertainty(entropy=entropy.astype(np.float32), flags=flags.astype(np.uint8), likelihood=likelihood,
                       best_alpha=nan, best_ks=nan, channel=np.zeros(n_texels, np.int8), mode="calibrated", grid=grid)


def test_anchors_are_the_most_certain_eligible_texel_of_each_cell():
    resolution = 8
    rng = np.random.default_rng(0)
    entropy = rng.uniform(0.0, 0.1, resolution * resolution)
    flags = np.zeros(resolution * resolution, np.uint8)
    best = np.argmin(entropy.reshape(4, 2, 4, 2).transpose(0, 2, 1, 3).reshape(4, 4, 4), axis=2)  # per 2x2 cell
    # The most certain texel of cell (0, 0) lies below the sampling bound: the runner-up is its anchor.
    cell_rows = np.array([0, 1, 8, 9])
    flags[cell_rows[best[0, 0]]] = FLAG_BELOW_BOUND
    likelihood = np.full((resolution * resolution, 4, 4), 1 / 16, np.float32)
    uncertainty = _uncertainty(entropy, flags, likelihood)
    coordinates = texel_coordinates(resolution, np.arange(resolution * resolution))
    anchors = find_anchors(resolution, coordinates, uncertainty, np.ones(resolution * resolution, bool),
                           ShareConfig(anchor_cells=4, anchor_certainty=0.5))
    assert len(anchors) == 16  # one per 2 x 2 cell
    cells = (coordinates[anchors] // 2).astype(int)
    assert len({tuple(cell) for cell in cells}) == 16
    for anchor, (row, column) in zip(anchors, cells):
        members = [(2 * row + dr) * resolution + 2 * column + dc for dr in (0, 1) for dc in (0, 1)]
        eligible = [m for m in members if not flags[m]]
        assert entropy[anchor] == min(entropy[eligible])
    assert cell_rows[best[0, 0]] not in anchors


def test_chunked_affinity_equals_the_dense_definition():
    rng = np.random.default_rng(1)
    n_texels, n_anchors, resolution = 400, 30, 6
    likelihood = rng.dirichlet(np.full(resolution * resolution, 0.3), n_texels).astype(np.float32)
    likelihood[likelihood < 1e-20] = 0.0  # exact zeros, as the entropy kernel writes them
    likelihood = likelihood.reshape(n_texels, resolution, resolution)
    coordinates = rng.uniform(0.0, 100.0, (n_texels, 2))
    anchor_rows = rng.choice(n_texels, n_anchors, replace=False)
    pulled_rows = np.setdiff1d(np.arange(n_texels), anchor_rows)
    settings = ShareConfig(neighbours=5, chunk_texels=37)
    nearest, affinity = anchor_affinity(coordinates, likelihood, anchor_rows, pulled_rows, settings)

    # Dense: every texel against every anchor, then the 5 nearest by distance.
    floored = np.maximum(likelihood.reshape(n_texels, -1).astype(np.float64), PROBABILITY_FLOOR)
    anchor_p = likelihood.reshape(n_texels, -1)[anchor_rows].astype(np.float64)
    divergence = np.array([[rel_entr(p, q).sum() for p in anchor_p] for q in floored[pulled_rows]])  # KL(P_a || P_x)
    distance = np.linalg.norm(coordinates[pulled_rows, None] - coordinates[anchor_rows][None], axis=2)
    expected_nearest = np.argsort(distance, axis=1)[:, :5]
    np.testing.assert_array_equal(nearest, expected_nearest)
    chosen = np.take_along_axis(divergence, expected_nearest, axis=1)
    width = 0.4 * chosen.mean()
    np.testing.assert_allclose(affinity, np.exp(-0.5 * (chosen / width) ** 2), rtol=2e-4, atol=1e-6)
    assert affinity.dtype == np.float32


def test_affinity_memory_is_bounded_by_the_chunk_not_the_texture():
    """T = 512 sized input: 250k texels, 1024 anchors. The dense formulation would hold
    250k x 1024 x 64 floats (65 GB); the chunked one stays near chunk x k x R^2."""
    rng = np.random.default_rng(2)
    n_texels, resolution = 250_000, 8
    likelihood = rng.dirichlet(np.ones(resolution * resolution), n_texels).astype(np.float32)
    likelihood = likelihood.reshape(n_texels, resolution, resolution)
    coordinates = texel_coordinates(512, rng.choice(512 * 512, n_texels, replace=False))
    anchor_rows = rng.choice(n_texels, 1024, replace=False)
    settings = ShareConfig(neighbours=8, chunk_texels=16384)
    tracemalloc.start()
    nearest, affinity = anchor_affinity(coordinates, likelihood, anchor_rows, np.arange(n_texels), settings)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    outputs = nearest.nbytes + affinity.nbytes + affinity.nbytes  # + the divergences
    per_chunk = settings.chunk_texels * settings.neighbours * resolution**2 * 4
    assert peak < outputs + 4 * per_chunk  # a few chunk-sized temporaries, nothing of size N x A
    assert nearest.shape == (n_texels, 8) and np.all(np.isfinite(affinity))
