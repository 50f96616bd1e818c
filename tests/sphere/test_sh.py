"""Real SH: conventions, orthonormality, rotation, and the regularised per-texel fit."""

import math

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from scipy.special import sph_harm_y

from freqbrdf.sphere import harmonics as sh


def random_directions(rng, n):
    directions = rng.normal(size=(n, 3))
    return directions / np.linalg.norm(directions, axis=-1, keepdims=True)


def test_orthonormal_up_to_degree_20_by_gauss_legendre_quadrature():
    # Independent quadrature: 30 Gauss-Legendre nodes in cos(theta) x 61 uniform phi integrate
    # products of two degree-20 harmonics exactly.
    cos_theta, gl_weights = np.polynomial.legendre.leggauss(30)
    phi = 2 * np.pi * np.arange(61) / 61
    sin_theta = np.sqrt(1 - cos_theta**2)
    directions = np.stack(
        np.broadcast_arrays(
            sin_theta[:, None] * np.cos(phi), sin_theta[:, None] * np.sin(phi), cos_theta[:, None]
        ),
        axis=-1,
    ).reshape(-1, 3)
    weights = np.repeat(gl_weights * 2 * np.pi / 61, 61)
    basis = sh.eval_sh(directions, 20)
    gram = (basis * weights[:, None]).T @ basis
    assert np.abs(gram - np.eye(441)).max() < 1e-12


def test_matches_scipy_without_condon_shortley_phase():
    rng = np.random.default_rng(0)
    directions = random_directions(rng, 200)
    theta = np.arccos(directions[:, 2])
    phi = np.arctan2(directions[:, 1], directions[:, 0])
    basis = sh.eval_sh(directions, 12)
    for degree in range(13):
        for order in range(-degree, degree + 1):
            complex_y = sph_harm_y(degree, abs(order), theta, phi)
            part = complex_y.real if order >= 0 else complex_y.imag
            expected = part if order == 0 else math.sqrt(2) * (-1) ** order * part
            np.testing.assert_allclose(basis[:, degree * degree + degree + order], expected, atol=1e-12)


def test_explicit_low_degree_formulas():
    rng = np.random.default_rng(1)
    x, y, z = random_directions(rng, 50).T
    basis = sh.eval_sh(np.stack([x, y, z], -1), 2)
    c1 = math.sqrt(3 / (4 * math.pi))
    expected = {
        0: np.full_like(x, 1 / math.sqrt(4 * math.pi)),
        1: c1 * y,  # m = -1: sin(phi)
        2: c1 * z,
        3: c1 * x,  # m = +1: cos(phi), positive (no Condon-Shortley sign)
        4: math.sqrt(15 / (4 * math.pi)) * x * y,
        5: math.sqrt(15 / (4 * math.pi)) * y * z,
        6: math.sqrt(5 / (16 * math.pi)) * (3 * z * z - 1),
        7: math.sqrt(15 / (4 * math.pi)) * x * z,
        8: math.sqrt(15 / (16 * math.pi)) * (x * x - y * y),
    }
    for index, values in expected.items():
        np.testing.assert_allclose(basis[:, index], values, atol=1e-14)


def test_float32_input_gives_float32_output_close_to_float64():
    directions = random_directions(np.random.default_rng(2), 1000)
    basis64 = sh.eval_sh(directions, 20)
    basis32 = sh.eval_sh(directions.astype(np.float32), 20)
    assert basis32.dtype == np.float32
    assert np.abs(basis32 - basis64).max() < 1e-4 * np.abs(basis64).max()


def test_degrees_counts_spectrum_and_lowpass():
    assert sh.num_coeffs(5) == 36
    np.testing.assert_array_equal(sh.sh_degrees(2), [0, 1, 1, 1, 2, 2, 2, 2, 2])
    coeffs = np.arange(9.0)
    np.testing.assert_allclose(sh.power_spectrum(coeffs), [0.0, 1 + 4 + 9, 16 + 25 + 36 + 49 + 64])
    filtered = sh.gaussian_lowpass(coeffs, 0.5)
    np.testing.assert_allclose(filtered, coeffs * np.exp(-(0.5 * sh.sh_degrees(2)) ** 2))


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_rotation_moves_the_function_and_keeps_the_power_spectrum(seed):
    rng = np.random.default_rng(seed)
    rotation = Rotation.random(random_state=seed).as_matrix()
    coeffs = rng.normal(size=(2, sh.num_coeffs(8)))
    rotated = sh.rotate_sh(coeffs, rotation)
    np.testing.assert_allclose(sh.power_spectrum(rotated), sh.power_spectrum(coeffs), rtol=1e-10)
    # g(R d) = f(d)
    directions = random_directions(rng, 30)
    before = sh.eval_sh(directions, 8) @ coeffs.T
    after = sh.eval_sh(directions @ rotation.T, 8) @ rotated.T
    np.testing.assert_allclose(after, before, atol=1e-10)


def test_rotate_sh_rejects_reflections():
    with pytest.raises(ValueError):
        sh.rotate_sh(np.zeros(9), np.diag([1.0, 1.0, -1.0]))


# --- fitting ------------------------------------------------------------------------------------


def direct_solution(directions, weights, values, lmax, lam, regulariser, scale):
    """The normal equations of the documented objective, solved densely in float64."""
    basis = sh.eval_sh(directions, lmax) * weights[:, None]
    lam_eff = lam * np.sum(weights**2) if scale else lam
    lhs = basis.T @ basis + lam_eff * np.diag(sh.regulariser_weights(lmax, regulariser))
    return np.linalg.solve(lhs, basis.T @ (values * weights[:, None])).T


@pytest.mark.parametrize("regulariser", ["exponential", "constant", "none"])
@pytest.mark.parametrize("scale", [True, False])
def test_fit_solves_the_documented_objective(regulariser, scale):
    rng = np.random.default_rng(3)
    n_texels, n_views, lmax = 37, 64, 4
    directions = random_directions(rng, n_texels * n_views).reshape(n_texels, n_views, 3)
    weights = rng.random((n_texels, n_views)) * (rng.random((n_texels, n_views)) > 0.2)
    values = rng.normal(size=(n_texels, n_views, 5))
    fit = sh.fit_sh(directions, weights, values, lmax, 1e-2, regulariser, scale)
    assert fit.coeffs.shape == (n_texels, 5, 25) and np.all(fit.status == sh.FIT_OK)
    np.testing.assert_array_equal(fit.n_samples, np.sum(weights > 0, axis=1))
    for t in range(n_texels):
        expected = direct_solution(directions[t], weights[t], values[t], lmax, 1e-2, regulariser, scale)
        np.testing.assert_allclose(fit.coeffs[t], expected, rtol=1e-7, atol=1e-9)


def test_fit_of_a_capture_like_batch_equals_numpy_least_squares():
    """The pipeline's case (l* = 5, 7 right-hand sides, float32) over several SIMD lane groups,
    the last one partial, with well-sampled, underdetermined and empty texels."""
    rng = np.random.default_rng(8)
    n_texels, n_views, lmax, lam = 70, 64, 5, 1e-3
    directions = random_directions(rng, n_texels * n_views).reshape(n_texels, n_views, 3).astype(np.float32)
    n_seen = rng.integers(0, n_views + 1, size=n_texels)
    n_seen[:3] = [0, 10, n_views]
    weights = (rng.random((n_texels, n_views)) * (np.arange(n_views) < n_seen[:, None])).astype(np.float32)
    values = rng.random((n_texels, n_views, 7), dtype=np.float32)
    fit = sh.fit_sh(directions, weights, values, lmax, lam, "exponential", True)
    reg = sh.regulariser_weights(lmax, "exponential")
    n_coeffs = sh.num_coeffs(lmax)
    for t in range(n_texels):
        w = weights[t].astype(np.float64)
        # min |[wY; sqrt(lambda_eff reg)] x - [wf; 0]|^2, the documented objective
        design = np.concatenate([sh.eval_sh(directions[t].astype(np.float64), lmax) * w[:, None],
                                 np.diag(np.sqrt(lam * np.sum(w * w) * reg))])
        targets = np.concatenate([values[t] * w[:, None], np.zeros((n_coeffs, 7))])
        expected = np.linalg.lstsq(design, targets, rcond=None)[0].T
        scale = max(np.abs(expected).max(), 1e-30)
        np.testing.assert_allclose(fit.coeffs[t], expected, rtol=0, atol=1e-5 * scale, err_msg=f"texel {t}")
    expected_status = np.where(
        n_seen == 0, sh.FIT_EMPTY, np.where(n_seen < n_coeffs, sh.FIT_UNDERDETERMINED, sh.FIT_OK)
    )
    np.testing.assert_array_equal(fit.n_samples, np.sum(weights > 0, axis=1))
    np.testing.assert_array_equal(fit.status, expected_status)
    assert np.all(fit.coeffs[0] == 0)


def test_fit_does_not_depend_on_the_thread_count():
    rng = np.random.default_rng(9)
    directions = random_directions(rng, 100 * 20).reshape(100, 20, 3)
    weights = rng.random((100, 20))
    values = rng.normal(size=(100, 20, 3))
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        serial = sh.fit_sh(directions, weights, values, 3, 1e-3).coeffs
    finally:
        numba.set_num_threads(threads)
    np.testing.assert_array_equal(sh.fit_sh(directions, weights, values, 3, 1e-3).coeffs, serial)


def test_fit_recovers_a_band_limited_function_exactly():
    rng = np.random.default_rng(4)
    lmax = 5
    true = rng.normal(size=(8, 3, sh.num_coeffs(lmax)))
    directions = random_directions(rng, 8 * 80).reshape(8, 80, 3)
    values = np.einsum("tvk,tck->tvc", sh.eval_sh(directions, lmax), true)
    weights = rng.uniform(0.2, 1.0, size=(8, 80))
    fit = sh.fit_sh(directions, weights, values, lmax, 0.0, "none", False)
    np.testing.assert_allclose(fit.coeffs, true, atol=1e-9)


def test_scaled_lambda_is_invariant_to_weight_scale_and_absolute_is_not():
    rng = np.random.default_rng(5)
    directions = random_directions(rng, 2 * 40).reshape(2, 40, 3)
    weights = rng.random((2, 40))
    values = rng.normal(size=(2, 40, 3))
    base = sh.fit_sh(directions, weights, values, 4, 1e-2, "exponential", True).coeffs
    scaled = sh.fit_sh(directions, 3 * weights, values, 4, 1e-2, "exponential", True).coeffs
    np.testing.assert_allclose(scaled, base, rtol=1e-9)
    absolute = sh.fit_sh(directions, weights, values, 4, 1e-2, "exponential", False).coeffs
    absolute_scaled = sh.fit_sh(directions, 3 * weights, values, 4, 1e-2, "exponential", False).coeffs
    assert np.abs(absolute_scaled - absolute).max() > 1e-3


@pytest.mark.parametrize("regulariser", ["exponential", "constant", "none"])
def test_sparse_and_empty_texels_are_finite_and_flagged(regulariser):
    rng = np.random.default_rng(6)
    lmax, n_views = 3, 30
    directions = random_directions(rng, 4 * n_views).reshape(4, n_views, 3).astype(np.float32)
    values = rng.normal(size=(4, n_views, 2)).astype(np.float32)
    weights = np.zeros((4, n_views), np.float32)
    weights[1, :5] = 1.0  # 5 < K = 16 samples
    weights[2, :] = 1.0  # well sampled
    weights[3, :] = 1.0
    values[3, 0, 1] = np.nan  # a broken sample is dropped, not propagated
    fit = sh.fit_sh(directions, weights, values, lmax, 1e-3, regulariser, True)
    assert fit.coeffs.dtype == np.float32 and np.isfinite(fit.coeffs).all()
    np.testing.assert_array_equal(fit.status, [sh.FIT_EMPTY, sh.FIT_UNDERDETERMINED, sh.FIT_OK, sh.FIT_OK])
    np.testing.assert_array_equal(fit.n_samples, [0, 5, n_views, n_views - 1])
    assert np.all(fit.coeffs[0] == 0)
    if regulariser == "none":  # minimum-norm interpolant of the 5 samples
        basis = sh.eval_sh(directions[1, :5].astype(np.float64), lmax)
        expected = np.linalg.pinv(basis) @ values[1, :5].astype(np.float64)
        np.testing.assert_allclose(fit.coeffs[1], expected.T, rtol=1e-4, atol=1e-5)


def test_appendix_fig1_exponential_regulariser_recovers_the_brdf_filter():
    """Appendix B / Fig. 1: only the e^l penalty keeps S_g(l) / S_f(l) close to exp(-2 a^2 l^2)."""
    alpha, lmax, signal_lmax = 0.2, 5, 10
    degrees = sh.sh_degrees(signal_lmax)
    true_ratio = np.exp(-2 * alpha**2 * np.arange(1, lmax + 1) ** 2)
    # 100 Fibonacci samples on the upper hemisphere
    index = np.arange(100) + 0.5
    z = 1 - index / 100
    phi = np.pi * (1 + 5**0.5) * index
    hemisphere = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], -1)
    errors = {"none": [], "constant": [], "exponential": []}
    for seed in range(10):
        rng = np.random.default_rng(seed)
        light = rng.normal(size=degrees.shape) * np.exp(-0.3 * degrees)  # low-frequency light f
        filtered = light * np.exp(-((alpha * degrees) ** 2))  # g = BRDF-filtered f
        hole_centre = hemisphere[rng.integers(100)]
        directions = hemisphere[np.argsort(hemisphere @ hole_centre)[:88]]  # mask 12: 88 left
        basis = sh.eval_sh(directions, signal_lmax)
        values = np.stack([basis @ light, basis @ filtered], -1)[None]
        for regulariser in errors:
            fit = sh.fit_sh(directions[None], directions[None, :, 2], values, lmax, 1e-3, regulariser, False)
            spectra = sh.power_spectrum(fit.coeffs[0])[:, 1:]
            errors[regulariser].append(np.mean(np.abs(np.log(spectra[1] / spectra[0] / true_ratio))))
    median = {name: float(np.median(values)) for name, values in errors.items()}
    assert median["exponential"] < 0.5 * median["constant"] < 0.5 * median["none"], median


def test_fit_sh_writes_into_a_block_of_a_larger_array():
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(6, 40, 3)).astype(np.float32)
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    weights = rng.uniform(0.5, 1.0, size=(6, 40)).astype(np.float32)
    values = rng.uniform(size=(6, 40, 2)).astype(np.float32)
    whole = sh.fit_sh(directions, weights, values, lmax=2, reg_lambda=1e-3, device="cpu")
    larger = np.full((9, 2, 9), np.nan, np.float32)
    fit = sh.fit_sh(directions, weights, values, lmax=2, reg_lambda=1e-3, device="cpu", coeffs_out=larger[2:8])
    assert np.shares_memory(fit.coeffs, larger)
    np.testing.assert_array_equal(larger[2:8], whole.coeffs)
    assert np.isnan(larger[:2]).all() and np.isnan(larger[8:]).all()
    with pytest.raises(ValueError, match="coeffs_out"):
        sh.fit_sh(directions, weights, values, lmax=2, reg_lambda=1e-3, device="cpu",
               coeffs_out=np.empty((6, 2, 9), np.float64))
