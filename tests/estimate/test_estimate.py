"""Tests of freqbrdf.estimate: both estimators on observations synthesised by our own forward model."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from freqbrdf.config import Config, EstimateConfig, FitConfig
from freqbrdf.estimate import angular_loss, estimate, prefilter_nodes
from freqbrdf.model import brdf
from freqbrdf.model.brdf import dielectric_fresnel
from freqbrdf.model.light import (
    PREFILTER_GAIN_FLOOR,
    degree_projections,
    environment_burley_factor,
    environment_filtered_light,
    environment_weight,
    lobe_filtered_light,
    prefiltered_environment,
    prefiltered_light,
)
from freqbrdf.model.tables import (
    LOBE_TERMS,
    burley_diffuse_factor,
    environment_response,
    environment_response_table,
    ggx_lobe_gains,
    integrate_split_sum_table,
    lobe_sh_response,
    split_sum_table,
    split_sum_terms,
    table_nodes,
)
from freqbrdf.observe.observations import Observations
from freqbrdf.sphere import envmap as envmaps
from freqbrdf.sphere import harmonics as sh
from freqbrdf.texels import orthonormal_basis
from helpers import observations_from_samples

N_VIEWS = 64
LMAX = 5


def synthetic_observations(
    truth: brdf.PrincipledParams,
    *,
    seed: int,
    n_views: int = N_VIEWS,
    model: str = "angular",
    shadowing: bool = True,
    unobserved: np.ndarray | None = None,
    exact_dielectric: bool = True,
    environment_light: bool = False,
    prefiltered: bool = False,
    environment_blend: tuple[float, float] = EstimateConfig().environment_blend,
    mirror_occluded_share: float = 0.0,
) -> Observations:
    """Observations of texels with known parameters, rendered by one of the global estimator's models.

    ``model`` "angular": brdf.predict_angular (docs/method.md#forward-model, G1-shadowed light when
    ``shadowing``); "split_sum": our default, m (b A S_A + B S_B) + (1 - m) E S_E with S_k the
    filtered unshadowed light read in the mirror direction (`lobe_filtered_light`), E the exact
    dielectric's albedo (Schlick's 0.04 A S_A + B S_B without ``exact_dielectric``), plus Burley's diffuse, written here with numpy
    from `split_sum_terms` and `burley_diffuse_factor`. With ``environment_light`` each S_k is
    blended towards `environment_filtered_light` of a world-frame environment (random frames) over
    ``environment_blend``, and Burley's factor is `environment_burley_factor` under it. With ``prefiltered`` the lobes read `prefiltered_light` of a rotated
    32 x 64 map (degrees up to 12) instead of the fitted light, the environment light gains the
    map's degrees above 5 (prefiltered), and the observations carry the map; the environment is
    then that map's SH. Without either, the observations carry no environment
    (tangent None), as hand-made ones. With ``mirror_occluded_share`` > 0 ("split_sum"), that share of
    the samples has the object in part of its mirror lobe (a random share of it,
    `Observations.mirror_occluded`): that share of the lobes' own light is a random radiance the
    object shows (`Observations.mirror_surface`), the environment light's part stays.

    Per texel: random view directions on the upper hemisphere (20 % missed), a light of a grey
    floor plus four sharp coloured lobes seen in the mirror directions, a random irradiance.
    ``unobserved`` (N,) bool texels get no sample at all. Texels sit row-major in a square texture.
    """
    rng = np.random.default_rng(seed)
    n_texels = truth.roughness.shape[0]
    cos_theta = rng.uniform(0.05, 1.0, (n_texels, n_views))
    phi = rng.uniform(0.0, 2.0 * math.pi, (n_texels, n_views))
    sin_theta = np.sqrt(1.0 - cos_theta**2)
    directions = np.stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), cos_theta], axis=-1)
    visible = rng.uniform(size=(n_texels, n_views)) > 0.2
    if unobserved is not None:
        visible[unobserved] = False
    weight = np.where(visible, cos_theta, 0.0)
    lobe_axes = rng.normal(size=(n_texels, 4, 3))
    lobe_axes /= np.linalg.norm(lobe_axes, axis=-1, keepdims=True)
    lobe_colours = rng.uniform(0.5, 4.0, (n_texels, 4, 3))
    mirror = directions * np.array([-1.0, -1.0, 1.0])  # 2 (n.v) n - v in the local frame
    lobes = np.maximum(np.einsum("tvi,tji->tvj", mirror, lobe_axes), 0.0) ** 30  # (T, V, 4)
    mirrored = 0.3 + np.einsum("tvj,tjc->tvc", lobes, lobe_colours)
    irradiance = rng.uniform(0.5, 3.0, (n_texels, 3))
    sigma = brdf.band_limit_sigma(n_views)
    normal = rng.normal(size=(n_texels, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    tangent = orthonormal_basis(normal)[0]
    environment = rng.normal(0.0, 0.3, (sh.num_coeffs(LMAX), 3))  # world-frame SH, a bright DC
    environment[0] = 3.0
    environment_map = None
    if prefiltered:
        detail = rng.normal(0.0, 0.4, (sh.num_coeffs(12), 3)) / (1.0 + sh.sh_degrees(12)[:, None]) ** 0.5
        detail[0] = 3.0
        to_world = np.eye(4)
        to_world[:3, :3] = Rotation.random(random_state=seed).as_matrix()
        environment_map = envmaps.envmap_from_sh(detail, 32, to_world=to_world)
        environment = envmaps.envmap_sh(environment_map, LMAX)

    fit = FitConfig()

    def fit_signals(values):  # as `observations_from_samples` fits them
        return sh.fit_sh(directions, weight, values, LMAX, fit.reg_lambda, fit.regulariser,
                         fit.scale_lambda_with_weight)

    light_fit = fit_signals(np.concatenate([mirrored, np.ones((n_texels, n_views, 1))], axis=-1))
    mf = brdf.microfacet_from_principled(truth)
    if model == "split_sum":
        scale, bias, dielectric = split_sum_terms(cos_theta, truth.roughness[:, None])
        share = environment_weight(truth.roughness, environment_blend)[:, None, None]
        if prefiltered:
            settings = EstimateConfig(environment_light=environment_light, environment_blend=environment_blend)
            maps = prefiltered_environment(environment_map, prefilter_nodes(settings))
            own_light = prefiltered_light(directions, tangent, normal, maps, environment_map.rotation, truth.roughness)
            # The environment light holds degrees <= 5; the prefiltered maps add the ones above.
            high = prefiltered_environment(environment_map, prefilter_nodes(EstimateConfig(environment_light=False)),
                                           skip_degrees=LMAX + 1)
            high_light = prefiltered_light(directions, tangent, normal, high, environment_map.rotation, truth.roughness)

        mirror_rng = np.random.default_rng(seed + 1)
        met = mirror_rng.uniform(size=(n_texels, n_views)) < mirror_occluded_share
        mirror_occluded = np.where(met, mirror_rng.uniform(0.1, 1.0, (n_texels, n_views)), 0.0)
        mirror_surface = np.where(met[..., None], mirror_rng.uniform(0.2, 2.0, (n_texels, n_views, 3)), 0.0)

        def light(term):
            fitted = own_light if prefiltered else lobe_filtered_light(
                directions, weight, light_fit.coeffs[:, :3], LMAX, sigma, truth.roughness)
            fitted = fitted + mirror_occluded[..., None] * (mirror_surface - fitted)
            if not environment_light:
                return fitted
            return (1.0 - share) * fitted + share * (environment_filtered_light(
                directions, weight, tangent, normal, environment, truth.roughness, term)
                + (high_light if prefiltered else 0.0))

        x, y, z = (albedo[..., None] * light(term) for albedo, term in zip((scale, bias, dielectric), LOBE_TERMS))
        if not exact_dielectric:
            z = brdf.DIELECTRIC_F0 * x + y
        metallic = truth.metallic[:, None, None]
        # With the environment light Burley's view dependence is averaged over that light.
        diffuse = (environment_burley_factor(directions, weight, tangent, normal, environment, truth.roughness)
                   if environment_light else burley_diffuse_factor(cos_theta, truth.roughness[:, None])[..., None]
                   ) * irradiance[:, None] / np.pi
        observed = (metallic * (truth.base_color[:, None] * x + y) + (1.0 - metallic) * z
                    + mf.diffuse_albedo[:, None] * diffuse)
    else:
        if shadowing:
            incoming = fit_signals(brdf.shadowed_light(mirrored, cos_theta, mf.alpha)).coeffs
        else:
            incoming = light_fit.coeffs[:, :3]
        observed = brdf.predict_angular(mf, directions, incoming, irradiance, sigma=sigma)
    return observations_from_samples(
        directions, weight, observed, mirrored, LMAX, irradiance=irradiance, sigma=sigma, reg_lambda=fit.reg_lambda,
        normal=normal.astype(np.float32),
        n_facing=np.full(n_texels, n_views, dtype=np.int32),  # every view faces the texel
        alpha_bound=np.full(n_texels, brdf.min_resolvable_alpha(LMAX), np.float32),
        tangent=tangent.astype(np.float32) if environment_light or prefiltered else None,
        environment_coeffs=environment.astype(np.float32) if environment_light or prefiltered else None,
        environment_radiance=environment_map.radiance if prefiltered else None,
        environment_rotation=environment_map.rotation if prefiltered else None,
        **({"mirror_occluded": np.where(visible, mirror_occluded, 0.0).astype(np.float32),
            "mirror_surface": mirror_surface.astype(np.float32)} if mirror_occluded_share > 0 else {}),
    )


def random_light_and_views(rng: np.random.Generator, n_views: int, spread: float) -> tuple:
    """(environment (K, 3) world SH with a bright DC and structure in every direction (std spread
    / (1 + l)), normal, tangent, bitangent (1, 3) of one random texel frame, cos theta (V,), local
    view directions (1, V, 3) on the upper hemisphere)."""
    environment = rng.normal(0.0, spread, (sh.num_coeffs(LMAX), 3)) / (1.0 + sh.sh_degrees(LMAX)[:, None])
    environment[0] = 3.0
    normal = rng.normal(size=(1, 3))
    normal /= np.linalg.norm(normal)
    tangent = orthonormal_basis(normal)[0]
    cos_theta = rng.uniform(0.05, 1.0, n_views)
    phi = rng.uniform(0.0, 2.0 * math.pi, n_views)
    sin_theta = np.sqrt(1.0 - cos_theta**2)
    directions = np.stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), cos_theta], axis=-1)[None]
    return environment, normal, tangent, np.cross(normal, tangent), cos_theta, directions


def random_truth(n_texels: int, seed: int, min_roughness: float = 0.2) -> brdf.PrincipledParams:
    """A spread of materials: base colours above the 0.04 twin ambiguity, any metallic."""
    rng = np.random.default_rng(seed)
    metallic = rng.uniform(0.0, 1.0, n_texels)
    metallic[: n_texels // 4] = 0.0  # pure dielectrics and pure metals are common: include both
    metallic[n_texels // 4 : n_texels // 2] = 1.0
    return brdf.PrincipledParams(
        base_color=rng.uniform(0.05, 1.0, (n_texels, 3)),
        roughness=rng.uniform(min_roughness, 1.0, n_texels),
        metallic=rng.permutation(metallic),
    )


@pytest.fixture(scope="module")
def truth() -> brdf.PrincipledParams:
    return random_truth(160, seed=1)


@pytest.fixture(scope="module")
def unshadowed(truth) -> Observations:
    return synthetic_observations(truth, seed=2, shadowing=False)


# The angular model of docs/method.md#forward-model (what brdf.predict_angular renders and `paper` fits), without shadowing.
NO_SHADOWING = Config(estimate=EstimateConfig(specular_model="g1", diffuse_model="lambert", shadowing=False))
PAPER_NO_SHADOWING = Config(estimate=EstimateConfig(method="paper", shadowing=False))


def _assert_recovered(result, truth, atol):
    np.testing.assert_allclose(result.base_color, truth.base_color, atol=atol)
    np.testing.assert_allclose(result.roughness, truth.roughness, atol=atol)
    np.testing.assert_allclose(result.metallic, truth.metallic, atol=atol)


def test_global_recovers_parameters_exactly(truth, unshadowed):
    # Noise-free data from the model itself: the global optimum is the truth (loss 0). What is left
    # is float32 storage of the observations (~1e-7 relative).
    result = estimate(unshadowed, NO_SHADOWING)
    _assert_recovered(result, truth, atol=1e-4)
    assert np.all(result.loss < 1e-10)


def test_global_recovers_parameters_exactly_with_the_default_model(truth):
    from freqbrdf.config import preset

    # The default (split-sum specular albedo, Burley diffuse), from data rendered by numpy.
    observations = synthetic_observations(truth, seed=13, model="split_sum")
    result = estimate(observations, Config())
    _assert_recovered(result, truth, atol=1e-4)
    assert np.all(result.loss < 1e-10)
    # The angular model does not explain these data: it must leave a misfit and miss the truth.
    angular = estimate(observations, NO_SHADOWING)
    assert np.median(angular.loss) > 1e4 * np.median(result.loss)
    assert np.mean(np.abs(angular.roughness - truth.roughness)) > 0.01
    # Nor does Schlick's dielectric, except on pure metals; it recovers data rendered with it.
    schlick = Config(estimate=EstimateConfig(dielectric_fresnel="schlick"))
    assert np.median(estimate(observations, schlick).loss[truth.metallic < 1.0]) > 1e4 * np.median(result.loss)
    schlick_data = synthetic_observations(truth, seed=13, model="split_sum", exact_dielectric=False)
    _assert_recovered(estimate(schlick_data, schlick), truth, atol=1e-4)
    # The fast preset's 5-node grid still finds each texel's global optimum.
    _assert_recovered(estimate(observations, preset("fast")), truth, atol=1e-4)


@pytest.mark.parametrize("seeded", [False, True])
def test_brent_matches_scipy_fminbound(seeded):
    # The reverse-communication Brent of the roughness search, on a smooth non-quadratic function:
    # the minimum to its tolerance; seeded with three bracketing nodes, in fewer evaluations.
    from scipy.optimize import fminbound

    from freqbrdf.estimate._profile_kernels import _X, PROBE, brent_next, brent_seed, brent_start

    def function(x):
        return (x - 0.3137) ** 2 * (1.0 + 3.0 * x) + 0.1 * (x - 0.3137) ** 3

    lower, upper, xtol = 0.125, 0.5, 1e-5
    state = np.zeros(13)
    if seeded:
        nodes = (0.125, 0.3125, 0.5)
        values = [function(x) for x in nodes]
        order = np.argsort(values)
        searching = brent_seed(state, lower, upper, xtol, *[v for i in order for v in (nodes[i], values[i])])
    else:
        brent_start(state, lower, upper, xtol)
        searching = True
    evaluations = 0
    while searching:
        evaluations += 1
        searching = brent_next(state, function(state[PROBE]))
    reference, _, _, calls = fminbound(function, lower, upper, xtol=xtol, full_output=True)
    assert abs(state[_X] - reference) < 2 * xtol
    assert abs(state[_X] - 0.3137) < 2 * xtol
    assert evaluations <= calls - (2 if seeded else 0)


def test_global_recovers_parameters_exactly_with_the_environment_light(truth):
    # Rough lobes read the world environment through the lobe's SH response, blended in over
    # roughness 0.3-0.6; the truth's roughness spans 0.2-1, so all three regimes occur.
    observations = synthetic_observations(truth, seed=19, model="split_sum", environment_light=True)
    result = estimate(observations, Config())
    _assert_recovered(result, truth, atol=1e-4)
    assert np.all(result.loss < 1e-10)
    np.testing.assert_allclose(result.loss, angular_loss(observations, result.principled(), Config()), atol=1e-12)
    # Without it (or without the environment in the observations) the model misses the rough texels.
    fitted_only = estimate(observations, Config(estimate=EstimateConfig(environment_light=False)))
    rough = truth.roughness > 0.35
    assert np.median(fitted_only.loss[rough]) > 1e4 * np.median(result.loss[rough])
    # Smooth texels never read it; their diffuse reverts to Burley under uniform light, a slight misfit.
    smooth = truth.roughness < 0.3
    np.testing.assert_allclose(fitted_only.roughness[smooth], truth.roughness[smooth], atol=2e-3)


def test_global_reads_what_the_object_shows_where_it_blocks_the_mirror_direction(truth):
    # A third of the samples see the object in part of their mirror lobe: that share of their smooth
    # lobes' light is its radiance, rough ones read the environment light too (blended over 0.3-0.6,
    # as the estimator does).
    observations = synthetic_observations(truth, seed=29, model="split_sum", environment_light=True,
                                          prefiltered=True, mirror_occluded_share=0.3)
    result = estimate(observations, Config())
    _assert_recovered(result, truth, atol=1e-4)
    np.testing.assert_allclose(result.loss, angular_loss(observations, result.principled(), Config()), atol=1e-12)
    # Read as the environment there (not traced), the smooth lobes miss.
    untraced = dataclasses.replace(observations, mirror_occluded=None, mirror_surface=None)
    smooth = truth.roughness < 0.45
    assert np.median(angular_loss(untraced, truth, Config())[smooth]) > 1e4 * np.median(result.loss[smooth])
    # Nothing blocked reads exactly as not traced.
    unblocked = dataclasses.replace(observations, mirror_occluded=np.zeros_like(observations.mirror_occluded))
    np.testing.assert_array_equal(angular_loss(unblocked, truth, Config()), angular_loss(untraced, truth, Config()))


def test_global_recovers_parameters_exactly_with_the_prefiltered_light(truth):
    # Smooth lobes read the rotated map prefiltered by the GGX gains at their world mirror
    # directions, blended into the environment light over 0.3-0.6: the truth (0.2-1) spans all three.
    observations = synthetic_observations(truth, seed=23, model="split_sum", environment_light=True,
                                          prefiltered=True)
    result = estimate(observations, Config())
    _assert_recovered(result, truth, atol=1e-4)
    assert np.all(result.loss < 1e-10)
    np.testing.assert_allclose(result.loss, angular_loss(observations, result.principled(), Config()), atol=1e-12)
    # The fitted light (l* = 5) cannot hold the map's degrees 6-12 that the smooth lobes see.
    fitted = estimate(observations, Config(estimate=EstimateConfig(prefiltered_light=False)))
    smooth = truth.roughness < 0.45
    assert np.median(fitted.loss[smooth]) > 1e4 * np.median(result.loss[smooth])
    # Without the environment light the maps serve every roughness (nodes up to 1), and a late
    # blend shifts where the environment light takes over.
    for environment_light, blend in ((False, (0.3, 0.6)), (True, (0.5, 0.9))):
        settings = EstimateConfig(environment_light=environment_light, environment_blend=blend)
        data = synthetic_observations(truth, seed=29, model="split_sum", environment_light=environment_light,
                                      prefiltered=True, environment_blend=blend)
        result = estimate(data, Config(estimate=settings))
        _assert_recovered(result, truth, atol=1e-4)
        assert np.all(result.loss < 1e-10)


def test_ggx_lobe_gains_match_the_lobe_response_at_normal_incidence():
    # The gains (no masking, no Fresnel) against the split-sum quadrature of the whole lobe
    # (masking-shadowing and Fresnel included) on each zonal harmonic about the normal.
    zonal = [degree * (degree + 1) for degree in range(9)]
    basis_at_normal = sh.eval_sh(np.array([0.0, 0.0, 1.0]), 8)[zonal]
    for roughness in (0.1, 0.25, 0.4):
        albedo, responses, _ = lobe_sh_response(1.0, roughness, "scale", 8, strata=128)
        np.testing.assert_allclose(ggx_lobe_gains(roughness, 8), responses[zonal] / albedo / basis_at_normal,
                                   atol=0.01)
    gains = ggx_lobe_gains(0.25, 200)
    assert gains[0] == pytest.approx(1.0) and np.all(np.diff(gains[:60]) < 0.0)
    # Heavier tails than the paper's Gaussian exp(-(alpha l)^2): 0.0019 against 8e-7 at degree 60.
    assert gains[60] > 100.0 * math.exp(-(0.25**2 * 60) ** 2)
    assert prefilter_nodes(EstimateConfig()) == 11 and prefilter_nodes(EstimateConfig(environment_light=False)) == 17


def test_roughness_curvature_is_the_profiled_loss_curvature(truth):
    # Noisy data, no robust pass: the search's curvature is the second divided difference of the
    # profiled loss; holding base colour and metallic at the optimum (angular_loss) can only curve
    # more, and the profiled loss at the probes is no higher than angular_loss there.
    observations = synthetic_observations(truth, seed=23, model="split_sum", environment_light=True)
    rng = np.random.default_rng(5)
    observations.observed = observations.observed * (1.0 + 0.05 * rng.standard_normal(observations.observed.shape)
                                                     ).astype(np.float32)
    config = Config(estimate=EstimateConfig(robust_passes=0))
    result = estimate(observations, config)
    inside = (result.roughness > 0.06) & (result.roughness < 0.94)
    step = 0.05  # estimate.CURVATURE_STEP

    def held_loss(roughness):
        return angular_loss(observations, brdf.PrincipledParams(result.base_color, roughness, result.metallic), config)

    held = (held_loss(result.roughness - step) - 2.0 * result.loss + held_loss(result.roughness + step)) / step**2
    assert np.all(result.roughness_curvature[inside] <= held[inside] * (1.0 + 1e-6) + 1e-9)
    assert np.median(result.roughness_curvature[inside] / held[inside]) > 0.1  # within an order of magnitude
    assert np.all(np.isfinite(result.roughness_curvature))


def test_global_recovers_parameters_with_shadowing(truth):
    # With shadowing the light depends on alpha; the refreshes converge to the self-consistent
    # estimate (6 refreshes reach ~1e-6 on this spread) of least squares; a robust pass re-weights
    # the samples after each refresh, which moves the fixed point by up to ~2e-4.
    observations = synthetic_observations(truth, seed=3, shadowing=True)
    angular = EstimateConfig(specular_model="g1", diffuse_model="lambert", shadowing_refreshes=6, robust_passes=0)
    result = estimate(observations, Config(estimate=angular))
    _assert_recovered(result, truth, atol=1e-4)


def test_split_sum_table_against_brute_force_integration():
    # Each node is int f/F cos_i over the hemisphere; check it by uniform Monte Carlo over w_i (an
    # independent estimator), and the limits: a mirror (r = 0) reflects all light with Schlick
    # Fresnel at the view angle (and the dielectric plane with the exact Fresnel), and no lobe
    # reflects more than it receives.
    table = split_sum_table()
    n_cos, n_rough = table.shape[1:]
    mirror_cos = np.linspace(0.0, 1.0, n_cos)[4:]
    np.testing.assert_allclose(table[0, 4:, 0], 1.0 - (1.0 - mirror_cos) ** 5, atol=2e-3)
    np.testing.assert_allclose(table[1, 4:, 0], (1.0 - mirror_cos) ** 5, atol=2e-3)
    np.testing.assert_allclose(table[2, 4:, 0], dielectric_fresnel(mirror_cos), atol=2e-3)
    assert np.all(table[:2].sum(axis=0) <= 1.0 + 1e-3) and np.all(table >= 0.0) and np.all(table[2] <= 1.0)
    rng = np.random.default_rng(14)
    cos_light = rng.uniform(size=400_000)
    phi = rng.uniform(0.0, 2.0 * math.pi, cos_light.size)
    sin_light = np.sqrt(1.0 - cos_light**2)
    light = np.stack([sin_light * np.cos(phi), sin_light * np.sin(phi), cos_light], axis=-1)
    for cos_index, rough_index in [(32, 16), (16, 24), (8, 32), (24, 8)]:
        cos_view = cos_index / (n_cos - 1)
        alpha = brdf.alpha_from_roughness(np.array(rough_index / (n_rough - 1)))
        view = np.array([math.sqrt(1.0 - cos_view**2), 0.0, cos_view])
        half = light + view
        half /= np.linalg.norm(half, axis=-1, keepdims=True)
        ndf = alpha**2 / (math.pi * (half[:, 2] ** 2 * (alpha**2 - 1.0) + 1.0) ** 2)
        brdf_over_fresnel = (ndf * brdf.smith_g1_ggx(cos_light, alpha) * brdf.smith_g1_ggx(cos_view, alpha)
                             / (4.0 * cos_view))  # times cos_i / cos_i
        schlick = (1.0 - half @ view) ** 5
        exact = dielectric_fresnel(half @ view)
        integral = 2.0 * math.pi * np.array([np.mean(brdf_over_fresnel * (1.0 - schlick)),
                                             np.mean(brdf_over_fresnel * schlick), np.mean(brdf_over_fresnel * exact)])
        np.testing.assert_allclose(table[:, cos_index, rough_index], integral, atol=1e-2, rtol=2e-2)


def test_shipped_split_sum_table_equals_the_integration():
    # Shipped with every digit: the loaded table is the integrated one (to the last bit where
    # numpy sums in the same order), so shipping it changes no result.
    np.testing.assert_allclose(split_sum_table(), integrate_split_sum_table(), rtol=1e-12, atol=1e-15)


def test_split_sum_table_is_mitsubas_principled_bsdf():
    # Mitsuba's own principled BSDF, sampled: a metal's directional albedo is R0 A + B with R0 the
    # base colour (Schlick Fresnel, GGX, Smith masking-shadowing, no energy compensation), a black
    # dielectric's is E (the exact Fresnel of eta 1.5; black: no diffuse lobe), so the split-sum
    # table is the BSDF that the estimate is rendered with.
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("llvm_ad_rgb")
    import drjit as dr

    n = 1 << 16
    for cos_view, roughness in [(0.2, 0.8), (0.5, 0.6), (0.9, 1.0), (0.5, 0.3)]:
        scale, bias, dielectric = split_sum_terms(cos_view, roughness)
        for base, metallic, expected in [(0.0, 1.0, bias), (1.0, 1.0, scale + bias), (0.0, 0.0, dielectric)]:
            bsdf = mi.load_dict({"type": "principled", "base_color": {"type": "rgb", "value": [base] * 3},
                                 "roughness": roughness, "metallic": metallic})
            interaction = dr.zeros(mi.SurfaceInteraction3f, n)
            interaction.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
            interaction.wi = mi.Vector3f(math.sqrt(1.0 - cos_view**2), 0.0, cos_view)
            sampler = mi.load_dict({"type": "independent"})
            sampler.seed(17, n)
            _, weight = bsdf.sample(mi.BSDFContext(), interaction, sampler.next_1d(), sampler.next_2d())
            assert np.mean(np.array(weight.x)) == pytest.approx(expected, abs=6e-3)


def test_the_prefiltered_map_of_a_mirror_is_the_map_itself():
    # A small bright light on a dim sky: filtered in SH up to the map's limit, a mirror's map would
    # ring (Gibbs) across the sky; it is the map itself, and the other lobes are filtered.
    radiance = np.full((64, 128, 3), 0.3, np.float32)
    radiance[20:22, 40:42] = 500.0
    environment_map = envmaps.Envmap(radiance, np.eye(4))
    maps = prefiltered_environment(environment_map, 6)
    lmax = 62
    np.testing.assert_array_equal(maps[0], radiance)
    for node in range(1, 6):
        gains = ggx_lobe_gains(node * 0.0625, lmax)
        full = envmaps.zonal_filter(environment_map, gains).radiance
        # The degrees past the last whose gain is PREFILTER_GAIN_FLOOR of the largest are left out:
        # exactly that filter, and within a few of those shares of the peak of the whole one.
        held = np.flatnonzero(np.abs(gains) >= PREFILTER_GAIN_FLOOR * np.abs(gains).max()).max()
        truncated = np.where(np.arange(lmax + 1) <= held, gains, 0.0)
        np.testing.assert_allclose(maps[node], envmaps.zonal_filter(environment_map, truncated).radiance, atol=1e-4)
        assert np.abs(maps[node] - full).max() <= 3 * PREFILTER_GAIN_FLOOR * np.abs(full).max()
    ringing = envmaps.zonal_filter(environment_map, ggx_lobe_gains(0.0, lmax)).radiance
    far = (slice(45, 60), slice(90, 120))
    assert np.abs(ringing[far] - 0.3).max() > 0.01  # what the SH filter would have read
    # With the degrees below skip_degrees left out: the map less its smooth low-degree part.
    high = prefiltered_environment(environment_map, 2, skip_degrees=3)
    low = envmaps.zonal_filter(environment_map, (np.arange(lmax + 1) < 3).astype(float)).radiance
    np.testing.assert_allclose(high[0], radiance - low, atol=1e-3)


def test_shipped_environment_response_table_matches_a_fresh_computation():
    tables = environment_response_table()
    cos_nodes = table_nodes()[0]
    roughness_nodes = np.linspace(0.0, 1.0, tables.shape[1])
    pairs = [(l, m) for l in range(LMAX + 1) for m in range(l + 1)]
    assert tables.shape == (len(LOBE_TERMS), 17, len(cos_nodes), len(pairs))
    for term, table in zip(LOBE_TERMS, tables):
        for i, j in [(4, 13), (16, 6), (28, 10), (10, 16)]:
            np.testing.assert_allclose(environment_response(cos_nodes[i], roughness_nodes[j], term), table[j, i],
                                       atol=1e-5)
        # Relative to the albedo, the response to Y_00 is Y_00 itself; a mirror (roughness 0)
        # reads each harmonic at the view direction (the mirrored parameterisation's mirror).
        np.testing.assert_allclose(table[:, :, 0], 1.0 / math.sqrt(4.0 * math.pi), rtol=1e-6)
        views = np.stack([np.sqrt(1.0 - cos_nodes**2), np.zeros_like(cos_nodes), cos_nodes], axis=1)
        mirror = sh.eval_sh(views, LMAX)[:, [l * l + l + m for l, m in pairs]]
        np.testing.assert_allclose(table[0, 2:], mirror[2:], atol=5e-3)


def test_environment_light_is_the_lobe_integral_of_any_environment():
    # A rough lobe (R0 = 1: A + B) under an environment with structure in every direction, in a
    # random texel frame, at random views: the environment light against the lobe integrated by
    # Monte Carlo over GGX half vectors, with the light read where each reflected ray goes.
    rng = np.random.default_rng(5)
    n_views = 40
    environment, normal, tangent, bitangent, cos_theta, directions = random_light_and_views(rng, n_views, 0.4)
    u = rng.uniform(size=(2, 400_000))
    for roughness in (0.5, 0.75, 1.0):
        alpha = roughness**2
        light = sum(albedo[..., None] * environment_filtered_light(directions, np.ones((1, n_views)), tangent,
                                                                    normal, environment, np.array([roughness]), term)
                    for albedo, term in zip(split_sum_terms(cos_theta, roughness)[:2], LOBE_TERMS[:2]))[0]
        tan2 = alpha**2 * u[0] / (1.0 - u[0])
        cos_half = 1.0 / np.sqrt(1.0 + tan2)
        sin_half = np.sqrt(1.0 - cos_half**2)
        half = np.stack([sin_half * np.cos(2 * math.pi * u[1]), sin_half * np.sin(2 * math.pi * u[1]), cos_half], -1)
        truth = np.empty((n_views, 3))
        for v in range(n_views):
            view_dot_half = half @ directions[0, v]
            incoming = 2.0 * view_dot_half[:, None] * half - directions[0, v]
            lobe = np.where((incoming[:, 2] > 0) & (view_dot_half > 0),
                            brdf.smith_g1_ggx(np.maximum(incoming[:, 2], 1e-9), alpha)
                            * brdf.smith_g1_ggx(cos_theta[v], alpha) * view_dot_half / (cos_theta[v] * cos_half), 0.0)
            world = incoming[:, :1] * tangent + incoming[:, 1:2] * bitangent + incoming[:, 2:] * normal
            truth[v] = np.mean(lobe[:, None] * (sh.eval_sh(world, LMAX) @ environment), axis=0)
        error = np.abs(light / truth - 1.0)
        assert error.mean() < 0.005 and error.max() < 0.02


def test_environment_light_predicts_a_rough_lobe_under_a_sky():
    # A rough metal under a sky brighter overhead (L = 1 + 2 z^2 + z, z up), viewed at grazing
    # angles: the split-sum prediction with the environment light against the lobe integrated by
    # Monte Carlo. The mirror-direction lookup of the fitted light sees the dim horizon.
    rng = np.random.default_rng(21)
    n_views, roughness, alpha = 48, 0.8, 0.64
    cos_theta = rng.uniform(0.05, 0.5, n_views)
    phi = rng.uniform(0.0, 2.0 * math.pi, n_views)
    sin_theta = np.sqrt(1.0 - cos_theta**2)
    directions = np.stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), cos_theta], axis=-1)[None]
    weight = cos_theta[None]

    def sky(z):
        return 1.0 + 2.0 * z**2 + z

    # The light in the mirrored parameterisation has the same z; fit it as the observations do
    # (here exactly: its SH expansion up to degree 2).
    grid = rng.normal(size=(4000, 3))
    grid /= np.linalg.norm(grid, axis=1, keepdims=True)
    coeffs, *_ = np.linalg.lstsq(sh.eval_sh(grid, LMAX), sky(grid[:, 2]), rcond=None)
    light = np.repeat(coeffs[None, None, :], 3, axis=1)
    mirror = np.exp(-(alpha * np.arange(LMAX + 1)) ** 2) @ np.stack(
        [sh.eval_sh(directions[0], LMAX)[:, sh.sh_degrees(LMAX) == l] @ coeffs[sh.sh_degrees(LMAX) == l]
         for l in range(LMAX + 1)])
    scale, bias, _ = split_sum_terms(cos_theta, roughness)
    u = rng.uniform(size=(2, 200_000))
    tan2 = alpha**2 * u[0] / (1.0 - u[0])
    cos_half = 1.0 / np.sqrt(1.0 + tan2)
    sin_half = np.sqrt(1.0 - cos_half**2)
    half = np.stack([sin_half * np.cos(2 * math.pi * u[1]), sin_half * np.sin(2 * math.pi * u[1]), cos_half], -1)
    truth = np.empty(n_views)
    for v in range(n_views):
        view_dot_half = half @ directions[0, v]
        light_z = 2.0 * view_dot_half * cos_half - cos_theta[v]
        lobe = np.where((light_z > 0) & (view_dot_half > 0), brdf.smith_g1_ggx(np.maximum(light_z, 1e-9), alpha)
                        * brdf.smith_g1_ggx(cos_theta[v], alpha) * view_dot_half / (cos_theta[v] * cos_half), 0.0)
        truth[v] = np.mean(lobe * sky(light_z))  # R0 = 1: the lobe integral of the light
    mirror_error = np.abs((scale + bias) * mirror / truth - 1.0)
    np.testing.assert_allclose(mirror, lobe_filtered_light(directions, weight, light, LMAX, 0.0,
                                                           np.array([roughness]))[0, :, 0], rtol=1e-4)
    # The environment light reads the sky's own SH (here in a texel frame turned about the normal,
    # which a zonal sky does not notice) with the lobe's per-degree gains.
    normal, tangent = np.array([[0.0, 0.0, 1.0]]), np.array([[0.6, 0.8, 0.0]])
    environment_scale, environment_bias = (
        environment_filtered_light(directions, weight, tangent, normal, light[0].T, np.array([roughness]), term)[0, :, 0]
        for term in ("scale", "bias"))
    environment_error = np.abs((scale * environment_scale + bias * environment_bias) / truth - 1.0)
    assert np.mean(environment_error) < 0.02 and np.mean(environment_error) < 0.15 * np.mean(mirror_error)


def test_environment_burley_factor_is_mitsubas_diffuse_under_that_light():
    # Mitsuba's principled diffuse (Burley, relative to Lambert) integrated by Monte Carlo over an
    # environment with structure in every direction, in a random texel frame, against
    # `environment_burley_factor`; under uniform light it is `burley_diffuse_factor`.
    rng = np.random.default_rng(8)
    n_views = 24
    environment, normal, tangent, bitangent, cos_theta, directions = random_light_and_views(rng, n_views, 0.5)
    u = rng.uniform(size=(2, 400_000))
    cos_light = np.sqrt(u[0])  # cosine-distributed
    sin_light = np.sqrt(1.0 - cos_light**2)
    light = np.stack([sin_light * np.cos(2 * math.pi * u[1]), sin_light * np.sin(2 * math.pi * u[1]), cos_light], -1)
    world = light[:, :1] * tangent + light[:, 1:2] * bitangent + light[:, 2:] * normal
    radiance = sh.eval_sh(world, LMAX) @ environment  # (M, 3)
    schlick_light = (1.0 - cos_light) ** 5
    uniform = np.zeros_like(environment)
    uniform[0] = 1.0
    for roughness in (0.2, 0.9):
        factor = environment_burley_factor(directions, np.ones((1, n_views)), tangent, normal, environment,
                                           np.array([roughness]))[0]
        truth = np.empty((n_views, 3))
        for v in range(n_views):
            schlick_view = (1.0 - cos_theta[v]) ** 5
            retro = roughness * (1.0 + light @ directions[0, v])
            burley = ((1.0 - 0.5 * schlick_view) * (1.0 - 0.5 * schlick_light)
                      + retro * (schlick_view + schlick_light + schlick_view * schlick_light * (retro - 1.0)))
            truth[v] = (burley[:, None] * radiance).mean(axis=0) / radiance.mean(axis=0)
        np.testing.assert_allclose(factor, truth, rtol=0.01)
        flat = environment_burley_factor(directions, np.ones((1, n_views)), tangent, normal, uniform,
                                         np.array([roughness]))[0]
        # (the table is linear in cos theta_o between its nodes)
        np.testing.assert_allclose(flat, np.repeat(burley_diffuse_factor(cos_theta, roughness)[:, None], 3, 1),
                                   rtol=2e-3)


def test_burley_factor_is_mitsubas_diffuse_averaged_over_light():
    # Monte Carlo of Mitsuba's principled diffuse lobe (relative to Lambert) over cosine-distributed
    # light against the closed form.
    rng = np.random.default_rng(15)
    u = rng.uniform(size=(2, 1_000_000))
    cos_light = np.sqrt(u[0])
    sin_light = np.sqrt(1.0 - cos_light**2)
    light = np.stack([sin_light * np.cos(2 * math.pi * u[1]), sin_light * np.sin(2 * math.pi * u[1]), cos_light], -1)
    for cos_view, roughness in [(1.0, 0.5), (0.2, 1.0), (0.5, 0.0), (0.05, 0.7)]:
        view = np.array([math.sqrt(1.0 - cos_view**2), 0.0, cos_view])
        half = light + view
        half /= np.linalg.norm(half, axis=-1, keepdims=True)
        f_view, f_light = (1.0 - cos_view) ** 5, (1.0 - cos_light) ** 5
        retro = 2.0 * roughness * (half @ view) ** 2
        lobe = (1 - 0.5 * f_light) * (1 - 0.5 * f_view) + retro * (f_view + f_light + f_view * f_light * (retro - 1))
        assert burley_diffuse_factor(cos_view, roughness) == pytest.approx(np.mean(lobe), abs=2e-3)


def test_paper_estimator_is_approximately_right(truth, unshadowed):
    # 100 Adam steps of size ~0.02 on an L1 loss from (0.5, 0.5, 0.5) do not converge to 1e-4:
    # most texels land within 0.01, a few slow ones (dark, weakly specular) stay farther.
    result = estimate(unshadowed, PAPER_NO_SHADOWING)
    for estimated, true in [(result.base_color, truth.base_color), (result.roughness, truth.roughness),
                            (result.metallic, truth.metallic)]:
        error = np.abs(estimated - true)
        assert np.median(error) < 0.01
        assert np.quantile(error, 0.9) < 0.1


def test_global_optimum_is_never_worse_than_paper(truth):
    # With noise the optimum has a positive loss; the exhaustive search must beat or tie Adam on
    # every texel (same model and light: shadowing off). (Without the neighbour vote, which trades
    # a little of a texel's fit for its neighbourhood's roughness.)
    observations = synthetic_observations(truth, seed=4, shadowing=False)
    rng = np.random.default_rng(5)
    observations.observed *= (1.0 + 0.05 * rng.standard_normal(observations.observed.shape)).astype(np.float32)
    least_squares = Config(estimate=dataclasses.replace(NO_SHADOWING.estimate, robust_passes=0, neighbour_vote=False))
    best = estimate(observations, least_squares)
    adam = estimate(observations, PAPER_NO_SHADOWING)
    assert np.all(best.loss > 0)
    assert np.all(best.loss <= adam.loss * (1.0 + 1e-9))
    # ... and than the truth, which no longer fits the noisy data exactly.
    assert np.all(best.loss <= angular_loss(observations, truth, NO_SHADOWING) * (1.0 + 1e-9))


def test_neighbour_median_leaves_out_the_texel_and_missing_values(unshadowed):
    from freqbrdf.estimate.search import neighbour_median

    res = unshadowed.texture_res  # texels row-major in a res x res texture
    values = np.arange(unshadowed.n_texels, dtype=np.float64)
    values[res * 5 + 6] = np.nan
    median = neighbour_median(unshadowed, values)
    for row, col in ((5, 5), (0, 0), (3, 7)):
        neighbours = [values[r * res + c] for r in range(row - 2, row + 3) for c in range(col - 2, col + 3)
                      if (r, c) != (row, col) and 0 <= r < res and 0 <= c < res and r * res + c < len(values)]
        assert median[row * res + col] == np.nanmedian(neighbours)
    assert np.isnan(neighbour_median(unshadowed, np.where(np.arange(len(values)) == 0, 1.0, np.nan))[0])


def test_neighbour_vote_moves_only_texels_whose_data_allow_it(truth, unshadowed):
    # Exact data reject every other roughness: the vote changes nothing.
    without_vote = Config(estimate=dataclasses.replace(NO_SHADOWING.estimate, neighbour_vote=False))
    assert NO_SHADOWING.estimate.neighbour_vote
    np.testing.assert_array_equal(estimate(unshadowed, NO_SHADOWING).roughness,
                                  estimate(unshadowed, without_vote).roughness)
    # With 30 % noise some texels cannot tell their roughness or metallic from their neighbours'
    # medians (the truth is random per texel here): their roughness moves to a minimum within a
    # grid cell of that median, or their metallic to it, at a least-squares loss at most
    # chi^2(95 %) noise variances above their own estimate's.
    noisy = synthetic_observations(truth, seed=8, shadowing=False)
    rng = np.random.default_rng(9)
    noisy.observed *= (1.0 + 0.3 * rng.standard_normal(noisy.observed.shape)).astype(np.float32)
    voted, own = estimate(noisy, NO_SHADOWING), estimate(noisy, without_vote)
    moved = voted.roughness != own.roughness
    changed = moved | (voted.metallic != own.metallic)
    assert 0 < moved.sum() and changed.sum() < len(changed)
    cell = 1.0 / (NO_SHADOWING.estimate.roughness_grid - 1)
    from freqbrdf.estimate import FITTED_PARAMETERS
    from freqbrdf.estimate.search import neighbour_median

    candidate = neighbour_median(noisy, own.roughness)
    assert np.all(np.abs(voted.roughness[moved] - candidate[moved]) < cell)
    assert np.all(np.abs(own.roughness[moved] - candidate[moved]) > cell)
    assert np.all(np.abs(voted.roughness[moved] - own.roughness[moved]) > cell)  # another minimum
    # A texel whose roughness stayed changed its metallic only to its neighbours' median.
    metallic_voted = changed & ~moved
    assert metallic_voted.any()
    np.testing.assert_array_equal(voted.metallic[metallic_voted],
                                  neighbour_median(noisy, own.metallic)[metallic_voted])
    dof = 3 * noisy.n_samples[changed] - FITTED_PARAMETERS
    assert np.all(voted.loss[changed] <= own.loss[changed] * (1.0 + 3.84 / dof) * (1.0 + 1e-9))
    np.testing.assert_allclose(voted.loss, angular_loss(noisy, voted.principled(), NO_SHADOWING), rtol=1e-6)
    for name in ("base_color", "metallic"):
        np.testing.assert_array_equal(getattr(voted, name)[~changed], getattr(own, name)[~changed])


def test_robust_passes_discount_outlier_samples(truth):
    # A tenth of the samples are wrong by 2-4x (as where the model misses an interreflection or a
    # silhouette): the default re-weighted estimate stays near the truth, least squares does not.
    observations = synthetic_observations(truth, seed=23, shadowing=False)
    rng = np.random.default_rng(24)
    outliers = rng.uniform(size=observations.weight.shape) < 0.1
    observations.observed[outliers] *= rng.uniform(2.0, 4.0, (outliers.sum(), 1)).astype(np.float32)
    robust = estimate(observations, NO_SHADOWING)
    least_squares = estimate(observations, Config(estimate=dataclasses.replace(NO_SHADOWING.estimate,
                                                                               robust_passes=0)))
    assert NO_SHADOWING.estimate.robust_passes == 1
    for name in ("roughness", "metallic"):
        robust_error = np.mean(np.abs(getattr(robust, name) - getattr(truth, name)))
        least_squares_error = np.mean(np.abs(getattr(least_squares, name) - getattr(truth, name)))
        assert robust_error < 0.6 * least_squares_error
    # The reported loss is still the weighted squared residual of the estimate.
    np.testing.assert_allclose(robust.loss, angular_loss(observations, robust.principled(), NO_SHADOWING), rtol=1e-6,
                               atol=1e-10)


def test_losses_agree_with_the_forward_model(truth, unshadowed):
    # angular_loss (numba) against brdf.predict_angular: zero at the truth, and the search's own
    # moment-based loss equals a direct evaluation at its estimate.
    at_truth = angular_loss(unshadowed, truth, NO_SHADOWING)
    scale = np.mean(unshadowed.observed.astype(np.float64) ** 2, axis=(1, 2))
    assert np.all(at_truth < 1e-10 * scale)
    perturbed = brdf.PrincipledParams(truth.base_color, np.clip(truth.roughness + 0.05, 0, 1), truth.metallic)
    assert np.all(angular_loss(unshadowed, perturbed, NO_SHADOWING) > 1e3 * at_truth)
    rng = np.random.default_rng(6)
    noisy = synthetic_observations(truth, seed=7, shadowing=False)
    noisy.observed += rng.normal(0.0, 0.05, noisy.observed.shape).astype(np.float32)
    result = estimate(noisy, NO_SHADOWING)
    np.testing.assert_allclose(result.loss, angular_loss(noisy, result.principled(), NO_SHADOWING), rtol=1e-6)


def test_global_leaves_single_sample_texels_to_the_fill(truth, unshadowed):
    # One sample (three channels) cannot determine five parameters: such texels are not estimated.
    from freqbrdf.estimate import MIN_SAMPLES

    single = np.zeros(unshadowed.n_texels, dtype=bool)
    single[::9] = True
    weight = unshadowed.weight.copy()
    first = np.argmax(weight > 0, axis=1)
    keep = np.zeros_like(weight, dtype=bool)
    keep[np.arange(len(first)), first] = True
    weight[single[:, None] & ~keep] = 0.0
    n_samples = np.where(single, 1, unshadowed.n_samples)
    observations = dataclasses.replace(unshadowed, weight=weight, n_samples=n_samples)
    result = estimate(observations, NO_SHADOWING)
    assert MIN_SAMPLES == 2
    np.testing.assert_array_equal(result.estimated, ~single)
    assert np.all(np.isnan(result.roughness[single])) and np.all(np.isnan(result.base_color[single]))
    np.testing.assert_allclose(result.roughness[~single], truth.roughness[~single], atol=1e-4)


@pytest.mark.parametrize("method", ["global", "paper"])
def test_unobserved_texels_are_left_unknown(truth, method):
    unobserved = np.zeros(len(truth.roughness), dtype=bool)
    unobserved[::7] = True
    observations = synthetic_observations(truth, seed=8, shadowing=True, unobserved=unobserved)
    result = estimate(observations, Config(estimate=EstimateConfig(method=method)))
    np.testing.assert_array_equal(result.estimated, ~unobserved)
    assert np.all(np.isnan(result.roughness[unobserved])) and np.all(np.isnan(result.base_color[unobserved]))
    for values in (result.base_color, result.roughness, result.metallic, result.loss):
        assert np.all(np.isfinite(values[~unobserved]))
        assert np.all((values[~unobserved] >= 0) & (values[~unobserved] <= (np.inf if values is result.loss else 1)))
    textures = result.textures()
    res = observations.texture_res
    assert textures["base_color"].shape == (res, res, 3) and textures["roughness"].shape == (res, res)
    flat = textures["roughness"].reshape(-1)
    np.testing.assert_array_equal(flat[observations.texel_index], result.roughness)
    assert np.all(np.isnan(np.delete(flat, observations.texel_index)))


@pytest.mark.parametrize("method", ["global", "paper"])
def test_estimators_are_deterministic(truth, method):
    observations = synthetic_observations(truth, seed=9, shadowing=True)
    config = Config(estimate=EstimateConfig(method=method))
    first, second = estimate(observations, config), estimate(observations, config)
    for name in ("base_color", "roughness", "metallic", "loss"):
        np.testing.assert_array_equal(getattr(first, name), getattr(second, name))


@pytest.mark.parametrize("forward_model", ["angular", "sh_coeffs", "spectrum"])
def test_paper_gradients_match_finite_differences(unshadowed, forward_model):
    from freqbrdf.estimate import paper

    settings = EstimateConfig(method="paper", forward_model=forward_model, shadowing=False)
    rng = np.random.default_rng(10)
    n = unshadowed.n_texels
    params = np.concatenate([rng.uniform(0.2, 0.8, (n, 3)), rng.uniform(0.3, 0.8, (n, 2))], axis=1)
    light, target = unshadowed.mirrored_coeffs.astype(np.float64), unshadowed.observed_coeffs.astype(np.float64)
    proj = degree_projections(unshadowed.view_direction, unshadowed.weight, light, LMAX)
    texture_texels = unshadowed.texture_res**2

    def l1_loss(p):  # the prototype's mean L1 loss through the brdf module's forward models
        mf = brdf.microfacet_from_principled(brdf.PrincipledParams(p[:, :3], p[:, 3], p[:, 4]))
        constant = unshadowed.constant_coeffs.astype(np.float64)
        if forward_model == "angular":
            predicted = brdf.predict_angular(mf, unshadowed.view_direction.astype(np.float64), light,
                                             unshadowed.irradiance, sigma=unshadowed.sigma)
            w = unshadowed.weight[..., None]
            return np.sum(np.abs(w * (predicted - unshadowed.observed)), axis=(1, 2)) / (texture_texels * N_VIEWS * 3)
        if forward_model == "sh_coeffs":
            predicted = brdf.predict_sh_coeffs(mf, light, unshadowed.irradiance, constant, sigma=unshadowed.sigma)
            return np.sum(np.abs(predicted - target), axis=(1, 2)) / (texture_texels * 3 * (LMAX + 1) ** 2)
        predicted = brdf.predict_power_spectrum(mf, sh.power_spectrum(light), unshadowed.irradiance, constant,
                                                sigma=unshadowed.sigma)
        return np.sum(np.abs(predicted - sh.power_spectrum(target)), axis=(1, 2)) / (texture_texels * 3 * (LMAX + 1))

    gradient = paper._data_gradient(unshadowed, settings, params, light, target, proj, texture_texels)
    step = 1e-6
    for p in range(5):
        shifted_up, shifted_down = params.copy(), params.copy()
        shifted_up[:, p] += step
        shifted_down[:, p] -= step
        numeric = (l1_loss(shifted_up) - l1_loss(shifted_down)) / (2 * step)
        # L1 kinks make a few texels' central differences straddle a sign change: judge the bulk.
        close = np.isclose(gradient[:, p], numeric, rtol=1e-3, atol=1e-6 * np.abs(numeric).max())
        assert close.mean() > 0.95, (p, gradient[~close, p][:3], numeric[~close][:3])


def test_total_variation_gradient_matches_finite_differences():
    from freqbrdf.estimate import paper

    res = 6
    mask = np.random.default_rng(11).uniform(size=res * res) > 0.3
    texel_index = np.arange(res * res)
    neighbours = paper._texture_neighbours(res, texel_index, mask)
    params = np.random.default_rng(12).uniform(size=(res * res, 5))

    def tv(p):  # the prototype's masked 3x3 stencil, written out on the image
        image = p.reshape(res, res, 5)
        m = mask.reshape(res, res)
        total = 0.0
        for i in range(res):
            for j in range(res):
                for di in (-1, 0, 1):
                    for dj in (-1, 0, 1):
                        a, b = i + di, j + dj
                        if 0 <= a < res and 0 <= b < res and m[i, j] and m[a, b]:
                            total += np.abs(image[a, b] - image[i, j]).sum()
        return total

    gradient = paper._tv_gradient(params, neighbours, 1.0)
    for t in np.flatnonzero(mask)[:5]:
        for p in range(5):
            up, down = params.copy(), params.copy()
            up[t, p] += 1e-7
            down[t, p] -= 1e-7
            assert gradient[t, p] == pytest.approx((tv(up) - tv(down)) / 2e-7, abs=1e-5)
    assert np.all(gradient[~mask] == 0)


def test_config_presets_and_validation(unshadowed):
    from freqbrdf.config import preset

    assert preset("default").estimate.method == "global"
    assert preset("paper").estimate.method == "paper"
    fast = preset("fast").estimate
    assert fast.method == "global" and fast.robust_passes == 0 and fast.roughness_grid < Config().estimate.roughness_grid
    with pytest.raises(ValueError, match="unknown preset"):
        preset("fastest")
    with pytest.raises(ValueError, match="angular"):
        estimate(unshadowed, Config(estimate=EstimateConfig(forward_model="spectrum")))
    with pytest.raises(ValueError, match="specular_model"):
        estimate(unshadowed, Config(estimate=EstimateConfig(specular_model="beckmann")))
    # A misspelt choice is refused when the settings are made, not when (and if) a stage reads it,
    from freqbrdf.config import UncertaintyConfig

    for make, message in ((lambda: UncertaintyConfig(mode="angualr"), "UncertaintyConfig.mode must be one of "
                                                                      "'calibrated', 'paper', 'angular'; got 'angualr'"),
                          (lambda: EstimateConfig(method="adam"), "EstimateConfig.method"),
                          (lambda: FitConfig(regulariser="l2"), "FitConfig.regulariser"),
                          (lambda: dataclasses.replace(Config().estimate, diffuse_model="oren"), "diffuse_model"),
                          # and so is a value that would give NaN or meaningless maps
                          (lambda: UncertaintyConfig(noise_level=-0.02), "UncertaintyConfig.noise_level must lie in "
                                                                          "(0, inf); got -0.02"),
                          (lambda: UncertaintyConfig(ambiguous_entropy=1.5), "must lie in [0, 1]"),
                          (lambda: FitConfig(attenuation_threshold=2.0), "FitConfig.attenuation_threshold")):
        with pytest.raises(ValueError, match=re.escape(message)):
            make()


def test_model_light_is_shadowed_only_for_the_method_model(unshadowed):
    from freqbrdf.estimate import model_light

    roughness = np.full(unshadowed.n_texels, 0.8)
    assert model_light(unshadowed, roughness, Config()) is unshadowed.mirrored_coeffs  # split-sum
    angular = Config(estimate=EstimateConfig(specular_model="g1"))
    shadowed = model_light(unshadowed, roughness, angular)
    # G1 < 1 away from the normal: the shadowed light is dimmer in the DC coefficient.
    assert np.all(shadowed[..., 0] < unshadowed.mirrored_coeffs[..., 0])


def _metallic_moments(omega, x, y, z, d, f):
    """(3, 14) `estimate._metallic_quadratics`' weighted sums of per-channel samples (3, n)."""
    return np.stack([[np.sum(omega * a * b) for a, b in
                      ((x[c], d[c]), (y[c], d[c]), (z[c], d[c]), (x[c], x[c]), (x[c], y[c]), (x[c], z[c]),
                       (x[c], f[c]), (y[c], y[c]), (y[c], z[c]), (y[c], f[c]), (z[c], z[c]), (z[c], f[c]),
                       (d[c], d[c]), (f[c], d[c]))] for c in range(3)])


def test_metallic_profile_derivatives_match_finite_differences_and_brute_force():
    # The global search profiles the metallic with Newton on analytic derivatives of the loss at
    # the best (clipped) base colour; check them against finite differences, and the profile's
    # minimum against a dense scan, on moments of random samples.
    from freqbrdf.estimate import _profile_kernels as profile

    rng = np.random.default_rng(7)
    n = 40
    omega = rng.uniform(0.1, 1.0, n)
    # per channel: base colour term X, Fresnel bias Y, dielectric Z, diffuse factor D
    x, y, z, d = rng.uniform(0.1, 1.0, (4, 3, n))
    f = 0.3 * x + 0.2 * y + 0.1 * z + 0.4 * d + rng.normal(0.0, 0.02, (3, n))
    moments = _metallic_moments(omega, x, y, z, d, f)
    squared_values = np.sum(omega * f * f, axis=1)
    diffuse_scale = np.array([1.0, 0.8, 1.2])
    quadratics = np.empty((3, 3, 3))
    profile.metallic_quadratics(moments, squared_values, diffuse_scale, quadratics)
    state = np.empty(4)

    def terms(m):
        return profile.metallic_terms(m, quadratics, state)

    # The quadratics are the loss sum_v w (b (m X + (1 - m) e D) + m Y + (1 - m) Z - f)^2, directly.
    for m in (0.0, 0.3, 1.0):
        loss = terms(m)[0]
        base = state[:3, None]
        model = base * (m * x + (1 - m) * diffuse_scale[:, None] * d) + m * y + (1 - m) * z
        assert loss == pytest.approx(np.sum(omega * (model - f) ** 2), rel=1e-9)

    step = 1e-6
    for m in np.linspace(0.05, 0.95, 7):
        _, gradient, curvature = terms(m)
        above, below = terms(m + step), terms(m - step)
        np.testing.assert_allclose(gradient, (above[0] - below[0]) / (2 * step), rtol=1e-4, atol=1e-8)
        np.testing.assert_allclose(curvature, (above[1] - below[1]) / (2 * step), rtol=1e-4, atol=1e-6)
    profiled = profile.profile_metallic(quadratics, state, 4)
    scan = min(terms(m)[0] for m in np.linspace(0.0, 1.0, 20001))
    assert profiled <= scan + 1e-12


@pytest.mark.parametrize("true_metallic", [-0.1, 0.35, 1.1])
def test_metallic_profile_leaves_its_winner_in_state(true_metallic):
    # The profile skips re-evaluating the winner when it was the last point evaluated: whichever
    # path it takes (a pure dielectric, not the last node evaluated; Newton inside a cell; a pure
    # metal, the last node), state must hold the returned loss's base colour and metallic. Data
    # of metallic beyond [0, 1] put the optimum on the bounds.
    from freqbrdf.estimate import _profile_kernels as profile

    rng = np.random.default_rng(11)
    n = 30
    omega = rng.uniform(0.1, 1.0, n)
    x, y, z, d = rng.uniform(0.1, 1.0, (4, 3, n))
    base_color = np.array([0.6, 0.4, 0.2])[:, None]
    m = true_metallic
    f = base_color * (m * x + (1 - m) * d) + m * y + (1 - m) * z + rng.normal(0.0, 0.01, (3, n))
    moments = _metallic_moments(omega, x, y, z, d, f)
    quadratics = np.empty((3, 3, 3))
    profile.metallic_quadratics(moments, np.sum(omega * f * f, axis=1), np.ones(3), quadratics)
    state = np.empty(4)
    profiled = profile.profile_metallic(quadratics, state, 4)
    winner = state.copy()
    assert winner[3] == pytest.approx(min(max(true_metallic, 0.0), 1.0), abs=5e-3)
    check = np.empty(4)
    assert profile.metallic_terms(winner[3], quadratics, check)[0] == profiled
    np.testing.assert_array_equal(check, winner)


def test_scattering_stride_visits_every_item_once():
    """The search's and the angular entropy's order of work items: a permutation for any count."""
    from freqbrdf.estimate import scattering_stride

    for n_items in range(1, 300):
        stride = scattering_stride(n_items)
        assert sorted((item * stride) % n_items for item in range(n_items)) == list(range(n_items))
