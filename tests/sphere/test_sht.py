"""freqbrdf.sphere.sht: spherical-harmonic transforms of lat-long maps, and their agreement with ducc0's.

ducc0 (GPL-2.0-or-later) is not a dependency of freqbrdf, nor of its test extra. The tests that
compare with it run where it happens to be installed and skip otherwise; so that the comparison
also holds without it, ``data/ducc0_envmap_coefficients.npz`` keeps coefficients of the bundled
maps that ducc0 computed once (``python tests/test_sht.py`` rewrites it, with ducc0 installed).
"""

from __future__ import annotations

import math
from decimal import Decimal, getcontext
from pathlib import Path

import numpy as np
import pytest
from scipy.special import spherical_in

from freqbrdf import assets
from freqbrdf.sphere import envmap as em
from freqbrdf.sphere import harmonics as sh
from freqbrdf.sphere import sht

REFERENCE = Path(__file__).resolve().parent / "data" / "ducc0_envmap_coefficients.npz"
# The degrees the code asks the bundled 256 x 512 maps for: the SH fit (5 by default),
# irradiance (20), the low-pass band limit ceil(3.72 floor(sqrt(N))) for 4..1224 views (8..127),
# and the prefiltered light (every degree the map holds, 254). 253 checks the second rule once
# more where ducc0's grid is as fine as ours.
CODE_DEGREES = (5, 20, 30, 75, 127, 253, 254)
TOLERANCE = 1e-6  # max |ours - ducc0| / max |ducc0|


def relative_difference(ours: np.ndarray, reference: np.ndarray) -> float:
    return float(np.abs(np.asarray(ours, np.float64) - reference).max() / np.abs(reference).max())


def bundled_maps() -> dict[str, np.ndarray]:
    return {name: em.load_envmap(assets.envmap_path(name)).radiance for name in assets.list_envmaps()}


def grid_directions(height: int, width: int, phi0: float) -> np.ndarray:
    """(H, W, 3) directions of the samples of `sht`'s grid (theta from +z, phi from +x)."""
    theta = np.pi * np.arange(height) / (height - 1)
    phi = phi0 + 2 * np.pi * np.arange(width) / width
    theta, phi = np.meshgrid(theta, phi, indexing="ij")
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)


# --------------------------------------------------------------------------------------------
# The transform on its own


@pytest.mark.parametrize("n", [2, 3, 4, 9, 16, 33, 257])
def test_clenshaw_curtis_weights_integrate_polynomials_up_to_degree_n_minus_1(n):
    weights = sht.clenshaw_curtis_weights(n)
    nodes = np.cos(np.pi * np.arange(n) / (n - 1))
    np.testing.assert_array_equal(weights, weights[::-1])
    for degree in range(n):
        # Chebyshev polynomials keep the sums well conditioned: int T_k = 2 / (1 - k^2), k even
        exact = 2.0 / (1.0 - degree**2) if degree % 2 == 0 else 0.0
        assert np.sum(weights * np.cos(degree * np.arccos(nodes))) == pytest.approx(exact, abs=1e-14)
    with pytest.raises(ValueError):
        sht.clenshaw_curtis_weights(1)


# Both rules of `sht.analysis` (H >= 2 lmax + 2 reads the rings as they are; below, through the
# interpolant), odd and even H and W, lmax up to H - 2.
GRIDS = [(8, 24, 48), (8, 17, 34), (8, 10, 17), (11, 13, 30), (7, 9, 15), (30, 32, 64), (1, 3, 4), (0, 2, 1)]


@pytest.mark.parametrize("lmax, height, width", GRIDS)
def test_synthesis_is_direct_evaluation_and_analysis_inverts_it(lmax, height, width):
    rng = np.random.default_rng(lmax + height + width)
    coeffs = rng.normal(size=(2, sh.num_coeffs(lmax)))
    phi0 = 0.3
    maps = sht.synthesis(coeffs, height, width, phi0)
    basis = sh.eval_sh(grid_directions(height, width, phi0).reshape(-1, 3), lmax)  # (H W, K)
    direct = (basis @ coeffs.T).T.reshape(2, height, width)
    np.testing.assert_allclose(maps, direct, atol=1e-12 * np.abs(direct).max())
    np.testing.assert_allclose(sht.analysis(maps, lmax, phi0), coeffs, atol=1e-12)


@pytest.mark.parametrize("lmax, height", [(6, 16), (6, 9)])
def test_the_discrete_transform_is_orthonormal(lmax, height):
    # Each basis function, synthesised and analysed, gives its own unit vector: the transform
    # pair is the identity on band-limited maps, so the basis is orthonormal under it.
    identity = np.eye(sh.num_coeffs(lmax))
    maps = sht.synthesis(identity, height, 2 * height)
    np.testing.assert_allclose(sht.analysis(maps, lmax), identity, atol=1e-13)


@pytest.mark.parametrize("lmax, height", [(20, 64), (20, 24)])
def test_analysis_of_a_smooth_map_matches_its_analytic_coefficients(lmax, height):
    # f(w) = exp(kappa w.v) = sum_lm 4 pi i_l(kappa) Y_lm(v) Y_lm(w) is not band-limited; its
    # coefficients fall so fast that both rules must reproduce them to rounding.
    kappa, v = 2.0, np.array([0.48, -0.6, 0.64])
    width = 2 * height
    values = np.exp(kappa * grid_directions(height, width, 0.1) @ v)[None]
    expected = 4 * np.pi * spherical_in(sh.sh_degrees(lmax), kappa) * sh.eval_sh(v[None], lmax)[0]
    np.testing.assert_allclose(sht.analysis(values, lmax, 0.1)[0], expected, atol=1e-13)


def decimal_legendre(m: int, lmax: int, theta: float) -> list[Decimal]:
    """lambda_lm(theta), l = m..lmax, by the same recurrence in 40-digit decimals (whose exponent
    range does not underflow)."""
    getcontext().prec = 40
    sin_theta, cos_theta = Decimal(math.sin(theta)), Decimal(math.cos(theta))
    value = Decimal(1) / (Decimal(4) * Decimal(math.pi)).sqrt() * (Decimal(2).sqrt() if m > 0 else 1)
    for k in range(1, m + 1):
        value *= (Decimal(2 * k + 1) / Decimal(2 * k)).sqrt() * sin_theta
    out = [value, Decimal(2 * m + 3).sqrt() * cos_theta * value]
    for degree in range(m + 2, lmax + 1):
        a = (Decimal(4 * degree * degree - 1) / Decimal(degree * degree - m * m)).sqrt()
        b = (Decimal((degree - 1) ** 2 - m * m) / Decimal(4 * (degree - 1) ** 2 - 1)).sqrt()
        out.append(a * (cos_theta * out[-1] - b * out[-2]))
    return out[: lmax - m + 1]


@pytest.mark.parametrize("ring, order", [(56, 171), (100, 300), (1, 100), (9, 3)])
def test_legendre_functions_survive_an_underflowing_start(ring, order):
    # On a 2048-row grid, lambda_mm at these rings starts below 1e-180 (1e-245 for m = 300) and
    # the functions grow back to O(1) by l = 2046: a start flushed to zero would lose them.
    lmax, theta = 2046, math.pi * ring / 2047
    expected = np.array([float(value) for value in decimal_legendre(order, lmax, theta)])
    ours = sht._legendre_values(order, lmax, np.array([theta]))[:, 0]
    representable = np.abs(expected) > 1e-170
    np.testing.assert_allclose(ours[representable], expected[representable],
                               rtol=0, atol=1e-12 * np.abs(expected).max())
    assert np.all(np.abs(ours[~representable]) < 1e-170)
    if ring in (56, 100):
        assert np.abs(expected).max() > 1.0


def test_transforms_are_deterministic():
    radiance = em.load_envmap(assets.envmap_path("studio")).radiance
    maps = np.ascontiguousarray(radiance.transpose(2, 0, 1), np.float64)
    for lmax in (30, 254):  # one per rule
        first = sht.analysis(maps, lmax, 0.2)
        assert np.array_equal(first, sht.analysis(maps, lmax, 0.2))
        assert np.array_equal(sht.synthesis(first, 256, 512, 0.2), sht.synthesis(first, 256, 512, 0.2))


def test_transforms_check_their_inputs():
    with pytest.raises(ValueError):
        sht.analysis(np.zeros((1, 8, 16)), 7)  # lmax > H - 2
    with pytest.raises(ValueError):
        sht.analysis(np.zeros((1, 16, 12)), 6)  # 2 lmax + 1 > W
    with pytest.raises(ValueError):
        sht.analysis(np.zeros((8, 16)), 3)
    with pytest.raises(ValueError):
        sht.synthesis(np.zeros((1, 64)), 8, 16)  # lmax 7 > H - 2
    with pytest.raises(ValueError):
        sht.synthesis(np.zeros((1, 50)), 8, 16)  # not (lmax + 1)^2 coefficients


# --------------------------------------------------------------------------------------------
# Agreement with ducc0, the transform this one replaced


def _ducc0_index(lmax: int) -> tuple[np.ndarray, np.ndarray]:
    """For every flat real index: order m and the index of a_l|m| in ducc0's (m-major) layout."""
    degrees = sh.sh_degrees(lmax)
    orders = np.arange(sh.num_coeffs(lmax)) - degrees * (degrees + 1)
    return orders, np.abs(orders) * (2 * lmax + 1 - np.abs(orders)) // 2 + degrees


def ducc0_analysis(radiance: np.ndarray, lmax: int) -> np.ndarray:
    """`envmap._analysis` as it was with ducc0: (H, W, 3) -> (3, K). ducc0's harmonics carry the
    Condon-Shortley phase: c_l0 = Re a_l0, c_lm = sqrt(2) (-1)^m Re a_lm, c_l,-m = -sqrt(2) (-1)^m Im a_lm."""
    import ducc0

    orders, index = _ducc0_index(lmax)
    sign = np.where(np.abs(orders) % 2 == 1, -math.sqrt(2.0), math.sqrt(2.0))
    width = radiance.shape[1]
    out = []
    for channel in np.ascontiguousarray(radiance[:, ::-1, :].transpose(2, 0, 1), dtype=np.float64):
        alm = ducc0.sht.experimental.analysis_2d(map=channel[None], spin=0, lmax=lmax, geometry="CC",
                                                 phi0=math.pi / width)[0][index]
        out.append(np.where(orders == 0, alm.real, np.where(orders > 0, sign * alm.real, -sign * alm.imag)))
    return np.stack(out)


def ducc0_synthesis(coeffs_sh_frame: np.ndarray, height: int, width: int, out: np.ndarray | None = None) -> np.ndarray:
    """`envmap._synthesis` with ducc0: (..., 3, K) -> (..., H, W, 3) float32."""
    import ducc0

    coeffs_sh_frame = np.asarray(coeffs_sh_frame, np.float64)
    lmax = sh.lmax_of(coeffs_sh_frame.shape[-1])
    orders, index = _ducc0_index(lmax)
    sign = np.where(np.abs(orders) % 2 == 1, -1.0, 1.0) / math.sqrt(2.0)
    flat = coeffs_sh_frame.reshape(-1, 3, coeffs_sh_frame.shape[-1])
    given, out = out, np.empty((len(flat), height, width, 3), np.float32)
    for n, channels in enumerate(flat):
        for c, coeffs in enumerate(channels):
            alm = np.zeros((lmax + 1) * (lmax + 2) // 2, np.complex128)
            alm[index[orders == 0]] = coeffs[orders == 0]
            alm[index[orders > 0]] += sign[orders > 0] * coeffs[orders > 0]
            alm[index[orders < 0]] += -1j * sign[orders < 0] * coeffs[orders < 0]
            out[n, :, :, c] = ducc0.sht.experimental.synthesis_2d(
                alm=alm[None], spin=0, lmax=lmax, geometry="CC", ntheta=height, nphi=width, phi0=math.pi / width,
            )[0][:, ::-1]
    maps = out.reshape(coeffs_sh_frame.shape[:-2] + (height, width, 3))
    if given is None:
        return maps
    given[...] = maps
    return given


def ducc0_fine_points(height: int, lmax: int) -> int:
    """The fine circle of ducc0's second rule: 4 times the smallest 2^a 3^b 5^c 7^d 11^e >= lmax + 1
    (n_fine / 2 + 1 rings, too few for the product's degree H - 1 + lmax when lmax is below ~H)."""
    size = lmax + 1
    while True:
        rest = size
        for prime in (2, 3, 5, 7, 11):
            while rest % prime == 0:
                rest //= prime
        if rest == 1:
            return 4 * size
        size += 1


try:
    import ducc0  # noqa: F401
except ImportError:
    HAVE_DUCC0 = False
else:
    HAVE_DUCC0 = True
needs_ducc0 = pytest.mark.skipif(
    not HAVE_DUCC0,
    reason="ducc0 (GPL, not a dependency) is not installed; the stored reference still checks",
)


@needs_ducc0
def test_envmap_coefficients_agree_with_ducc0_at_every_degree_the_code_uses():
    for name, radiance in bundled_maps().items():
        for lmax in CODE_DEGREES:
            difference = relative_difference(em._analysis(radiance, lmax), ducc0_analysis(radiance, lmax))
            assert difference <= TOLERANCE, (name, lmax, difference)


@needs_ducc0
@pytest.mark.parametrize("lmax", [128, 200])
def test_between_the_rules_the_difference_is_ducc0s_coarser_grid(lmax, monkeypatch):
    # For H / 2 - 1 < lmax < ~H - 2 ducc0 integrates the interpolant on a circle too coarse for
    # the product's degree; on that circle our rule reproduces ducc0 to rounding.
    radiance = em.load_envmap(assets.envmap_path("forest")).radiance  # the largest difference
    reference = ducc0_analysis(radiance, lmax)
    assert relative_difference(em._analysis(radiance, lmax), reference) < 1e-4
    sht._interpolation_rule.cache_clear()
    monkeypatch.setattr(sht, "_fine_circle_points", ducc0_fine_points)
    try:
        assert relative_difference(em._analysis(radiance, lmax), reference) < 1e-12
    finally:
        sht._interpolation_rule.cache_clear()


@needs_ducc0
def test_synthesis_agrees_with_ducc0():
    rng = np.random.default_rng(11)
    coeffs = rng.normal(size=(2, 3, sh.num_coeffs(254))) / (1.0 + sh.sh_degrees(254))
    for height, width in ((256, 512), (257, 511)):
        assert relative_difference(em._synthesis(coeffs, height, width), ducc0_synthesis(coeffs, height, width)) < 1e-6


@pytest.mark.slow
@needs_ducc0
def test_the_maps_the_estimator_reads_agree_with_ducc0s(monkeypatch):
    # The low-passed light (64 views), the prefiltered light (every degree) and the irradiance
    # map, with our transforms and then with ducc0's.
    from freqbrdf.model import brdf, light
    from freqbrdf.observe import observations

    sigma = brdf.band_limit_sigma(64)
    normals = np.random.default_rng(12).normal(size=(500, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)

    def maps_of(envmap):
        return {"lowpass": em.lowpass_envmap(envmap, sigma).radiance,
                "prefiltered": light.prefiltered_environment(envmap, 17),
                "irradiance": observations.texel_irradiance(envmap, normals)}

    envmaps = [em.Envmap(radiance) for radiance in bundled_maps().values()]
    ours = [maps_of(envmap) for envmap in envmaps]
    monkeypatch.setattr(em, "_analysis", ducc0_analysis)
    monkeypatch.setattr(em, "_synthesis", ducc0_synthesis)
    for mine, envmap in zip(ours, envmaps):
        for kind, reference in maps_of(envmap).items():
            assert relative_difference(mine[kind], reference) <= TOLERANCE, kind


def reference_indices(lmax: int) -> np.ndarray:
    """Flat indices the stored reference keeps at lmax: every degree <= 16 and 256 others."""
    rng = np.random.default_rng(lmax)
    low = sh.num_coeffs(16)
    return np.concatenate([np.arange(low), np.sort(rng.choice(np.arange(low, sh.num_coeffs(lmax)), 256, replace=False))])


STORED_DEGREES = (127, 254)  # one per rule; the first rule's c_lm do not depend on lmax


def test_envmap_coefficients_agree_with_the_stored_ducc0_reference():
    reference = np.load(REFERENCE)
    for name, radiance in bundled_maps().items():
        for lmax in STORED_DEGREES:
            ours = em._analysis(radiance, lmax)[:, reference_indices(lmax)]
            assert relative_difference(ours, reference[f"{name}_{lmax}"]) <= TOLERANCE, (name, lmax)


def write_reference() -> None:
    """Rewrite the stored reference with ducc0 (float32: its rounding is 6e-8 of the largest)."""
    arrays = {f"{name}_{lmax}": ducc0_analysis(radiance, lmax)[:, reference_indices(lmax)].astype(np.float32)
              for name, radiance in bundled_maps().items() for lmax in STORED_DEGREES}
    REFERENCE.parent.mkdir(exist_ok=True)
    np.savez_compressed(REFERENCE, **arrays)
    print(f"wrote {REFERENCE} ({REFERENCE.stat().st_size} bytes)")


if __name__ == "__main__":
    write_reference()
