"""The previous capture guidance, by expected spectral entropy: a baseline of studies/guidance.py.

Kept here, out of the package, only to be measured against the guidance that replaced it
(`freqbrdf.applications.guidance`, METHOD.md §4): greedy next-best-view by expected entropy with
exact incremental rank-one fit updates (`FitState`), each pick among the (1 - ``spread``) of the
candidates farthest from the views so far. Unchanged from the package's version before the
replacement, apart from this docstring and its imports.

What a candidate camera would add to a texel is known before any photograph is taken, except the
radiance itself; for every specular hypothesis psi = (alpha, k) of the uncertainty grid the new
sample is simulated (`expected_entropy`), f_psi = k sum_l K(alpha, l) P_l(w_o) + D_psi, and the
candidate's expected entropy at a texel is sum_psi P(psi) H(psi). A pick is committed without a
photograph (the posterior-mean radiance); the band limit stays that of the capture's own views.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from freqbrdf.applications.candidates import CandidateSamples, candidate_samples, view_directions
from freqbrdf.applications.guidance import subset_texels, texel_subset
from freqbrdf.capture.camera import Camera
from freqbrdf.capture.layouts import Capture
from freqbrdf.config import Config
from freqbrdf.model import brdf
from freqbrdf.observe.observations import Observations, observe
from freqbrdf.progress import SILENT, Reporter
from freqbrdf.sphere import harmonics as sh
from freqbrdf.texels import rasterise
from freqbrdf.uncertainty import (
    Uncertainty,
    cross_spectrum,
    entropy_from_spectra,
    hypothesis_filter,
    hypothesis_grid,
)

MAX_TEXELS = 1024  # texels scored per candidate (a seeded random subset of the atlas)
# Each pick is chosen among the (1 - SPREAD) of the remaining candidates farthest (in angle, seen
# from the object) from every view taken or picked so far (0: all candidates compete). Pure
# expected entropy clusters views; the measurement before its replacement compared 0.5
# with 0 (docs/measurements.md).
SPREAD = 0.5
# Hypotheses less likely than this are left out of a texel's expectation (the rest renormalised):
# a uniform posterior keeps all of its R (R - 1) + 1 materials (57 on the default grid, R = 8), a
# confident one a handful.
MIN_CELL_PROBABILITY = 1e-3

# Right-hand sides of the per-texel normal equations.
LIGHT = slice(0, 3)
OBSERVED = slice(3, 6)
ONE = 6
N_RHS = 7


@dataclass(frozen=True)
class Pick:
    """One chosen view, in the order chosen.

    Attributes
    ----------
    rank : int
        0 = take this photograph first.
    candidate : int
        Index into the candidate list.
    camera : Camera
        The candidate camera.
    entropy_before : float
        Mean entropy of the scored texels before this pick.
    expected_entropy : float
        Their mean expected entropy once this view is added.
    texels_seen : int
        Scored texels the view samples.
    seconds : float
        Time spent scoring every remaining candidate and committing this one.
    """

    rank: int
    candidate: int
    camera: Camera
    entropy_before: float
    expected_entropy: float
    texels_seen: int
    seconds: float


@dataclass(eq=False)
class FitState:
    """Per-texel normal equations of the SH fits and their eigenbasis (n texels, K coefficients).

    Per texel: G = sum w^2 y y^T, the right-hand sides b = sum w^2 y f (light RGB, observed RGB,
    the constant 1) and sum w^2, which sets the penalty lambda_eff = lambda sum w^2
    (``FitConfig.scale_lambda_with_weight``). Adding a sample is a rank-one update of G and b.
    With the generalised eigenbasis of (G, R), R = diag(reg(l)),
    G = R^1/2 Q diag(mu) Q^T R^1/2, the regularised inverse for any penalty s is
    (G + s R)^-1 = B diag(1 / (mu + s)) B^T, B = R^-1/2 Q. Scoring a candidate is then
    Sherman-Morrison on top of that, O(K^2) per texel and exact (the penalty's growth with the
    new weight included); committing a pick re-diagonalises only the texels it sees. The fits
    equal fits from scratch on the enlarged sample set (tests/test_guidance.py).

    Attributes
    ----------
    gram : (n, K, K) float64
        G = sum_i w_i^2 y_i y_i^T (unregularised).
    rhs : (n, K, 7) float64
        b = sum_i w_i^2 y_i f_i: light RGB, observed RGB, constant 1.
    weight_sq : (n,) float64
        sum_i w_i^2.
    n_samples : (n,) int64
        Samples with positive weight.
    basis : (n, K, K) float64
        B = R^-1/2 Q.
    eigenvalues : (n, K) float64
        mu >= 0.
    projected_rhs : (n, K, 7) float64
        B^T b.
    regulariser : (K,) float64
        R's diagonal, reg(l) of `freqbrdf.sphere.harmonics.regulariser_weights`.
    """

    gram: np.ndarray
    rhs: np.ndarray
    weight_sq: np.ndarray
    n_samples: np.ndarray
    basis: np.ndarray
    eigenvalues: np.ndarray
    projected_rhs: np.ndarray
    regulariser: np.ndarray


# --------------------------------------------------------------------------------------------
# The selection


def select_views(
    capture: Capture,
    candidates: Sequence[Camera],
    budget: int,
    config: Config = Config(),
    *,
    observations: Observations | None = None,
    max_texels: int = MAX_TEXELS,
    spread: float = SPREAD,
    reporter: Reporter = SILENT,
) -> list[Pick]:
    """Choose some of the candidate views greedily by expected entropy (module docstring).

    The texel subset and every tie are deterministic in ``config.seed``; ties go to the earliest
    candidate.

    Parameters
    ----------
    capture : Capture
        The views taken so far, the mesh and the environment map.
    candidates : sequence of Camera
        The cameras to choose from (`sample_candidates`, `load_candidates`).
    budget : int
        How many to choose, 1 .. len(candidates).
    config : Config
        Texture resolution T, the SH fit (it must be regularised) and the uncertainty (mode
        ``"calibrated"`` or ``"paper"``).
    observations : Observations or None
        Observations of the whole capture at T (e.g. a fit's), reused when given; None observes
        only the scored texels.
    max_texels : int
        Texels scored per candidate (a seeded random subset of the atlas), >= 1.
    spread : float
        In [0, 1): each pick competes only among the (1 - spread) of the remaining candidates
        farthest from the views taken or picked so far (`SPREAD`).
    reporter : Reporter
        Progress of the picks.

    Returns
    -------
    list of Pick
        ``budget`` picks, in the order chosen.

    Raises
    ------
    ValueError
        If ``budget`` or ``spread`` is out of range, ``max_texels`` < 1, ``observations`` are of
        other texels, the SH fit is unregularised or the uncertainty mode is ``"angular"``.
    """
    _check_fit_settings(config)
    if budget < 1:
        raise ValueError(f"budget must be at least 1, got {budget}")
    if budget > len(candidates):
        raise ValueError(f"budget {budget} exceeds the {len(candidates)} candidates")
    if not 0.0 <= spread < 1.0:
        raise ValueError(f"spread must lie in [0, 1), got {spread}")
    texels = rasterise(capture.mesh, config.texels.texture_res)
    rows = texel_subset(texels.n_texels, max_texels, config.seed)
    scored = subset_texels(texels, rows)
    if observations is None:
        observations = observe(capture, config, reporter, texels=scored)
    else:
        if not np.array_equal(observations.texel_index, texels.texel_index):
            raise ValueError("observations were made at another texture resolution or of another mesh")
        observations = observations.select(rows)
    lmax = observations.lmax
    state = initial_state(observations, config)
    samples = candidate_samples(capture, scored, candidates, observations, lmax)

    directions = view_directions(capture, candidates)
    # cos of the angle to the nearest view taken so far, per candidate
    closeness = (directions @ view_directions(capture, [frame.camera for frame in capture.frames]).T).max(axis=1)
    picks: list[Pick] = []
    remaining = list(range(len(candidates)))
    with reporter.stage("choosing views", budget) as advance:
        for rank in range(budget):
            start = time.perf_counter()
            coeffs = state_coeffs(state, config)
            current = _state_uncertainty(state, coeffs, observations.sigma, config)
            entropy = current.entropy.astype(np.float64)
            n_competing = max(1, int(np.ceil((1.0 - spread) * len(remaining))))
            competing = sorted(sorted(remaining, key=lambda index: closeness[index])[:n_competing])
            best = None
            for candidate in competing:
                expected, radiance = expected_entropy(
                    state, coeffs, current.likelihood, samples[candidate], observations.sigma, config
                )
                gain = float(np.sum(entropy[samples[candidate].texel] - expected))
                if best is None or gain > best[1]:  # the earliest candidate wins ties
                    best = (candidate, gain, radiance)
            candidate, gain, radiance = best
            add_samples(state, samples[candidate], radiance)
            remaining.remove(candidate)
            closeness = np.maximum(closeness, directions @ directions[candidate])
            n_scored = len(entropy)
            picks.append(Pick(
                rank=rank, candidate=candidate, camera=candidates[candidate],
                entropy_before=float(entropy.mean()), expected_entropy=float((entropy.sum() - gain) / n_scored),
                texels_seen=len(samples[candidate].texel), seconds=time.perf_counter() - start,
            ))
            advance(1)
    return picks


def initial_state(observations: Observations, config: Config = Config()) -> FitState:
    """Build the normal equations of an Observations' fits and their eigenbasis.

    Parameters
    ----------
    observations : Observations
        Its n texels' samples (mirrored environment, observed radiance, weights).
    config : Config
        ``config.fit.regulariser`` sets R (the penalty itself is applied in `state_coeffs`).

    Returns
    -------
    FitState
        The n texels' state, diagonalised.
    """
    lmax = observations.lmax
    weight_sq = np.square(observations.weight.astype(np.float64))  # (n, V)
    basis = sh.eval_sh(observations.view_direction.astype(np.float64), lmax)  # (n, V, K)
    values = np.concatenate(
        [observations.mirrored, observations.observed, np.ones(observations.weight.shape + (1,))], axis=2
    ).astype(np.float64)  # (n, V, 7)
    weighted = basis * weight_sq[..., None]
    gram = np.einsum("tvk,tvj->tkj", weighted, basis)
    rhs = np.einsum("tvk,tvr->tkr", weighted, values)
    n_coeffs = sh.num_coeffs(lmax)
    state = FitState(
        gram, rhs, weight_sq.sum(axis=1), (observations.weight > 0).sum(axis=1).astype(np.int64),
        basis=np.zeros_like(gram), eigenvalues=np.zeros((len(gram), n_coeffs)), projected_rhs=np.zeros_like(rhs),
        regulariser=sh.regulariser_weights(lmax, config.fit.regulariser),
    )
    _diagonalise(state, np.arange(len(gram)))
    return state


def state_coeffs(state: FitState, config: Config) -> np.ndarray:
    """Solve the state's regularised fits.

    Parameters
    ----------
    state : FitState
        The n texels' normal equations.
    config : Config
        ``config.fit``'s penalty lambda and its scaling with the total weight.

    Returns
    -------
    (n, 7, K) float64
        SH coefficients of the light RGB, observed RGB and the constant 1 (zeros for texels
        without a sample).
    """
    penalty = _penalty(state.weight_sq, config)  # (n,)
    inverse = _inverse(state.eigenvalues + penalty[:, None])  # (n, K)
    return np.swapaxes(state.basis @ (state.projected_rhs * inverse[..., None]), 1, 2)


def add_samples(state: FitState, samples: CandidateSamples, observed: np.ndarray) -> None:
    """Commit a view: rank-one updates of the seen texels' normal equations, then re-diagonalise.

    Parameters
    ----------
    state : FitState
        Updated in place.
    samples : CandidateSamples
        The view's samples at the m texels it sees.
    observed : (m, 3) float64
        The radiance the view is taken to show at each of them.
    """
    rows = samples.texel
    weight_sq = np.square(samples.weight)  # (n,)
    values = np.concatenate([samples.light, observed, np.ones((len(rows), 1))], axis=1)  # (n, 7)
    weighted = samples.basis * weight_sq[:, None]
    state.gram[rows] += weighted[:, :, None] * samples.basis[:, None, :]
    state.rhs[rows] += weighted[:, :, None] * values[:, None, :]
    state.weight_sq[rows] += weight_sq
    state.n_samples[rows] += 1
    _diagonalise(state, rows)


def expected_entropy(
    state: FitState,
    coeffs: np.ndarray,
    likelihood: np.ndarray,
    samples: CandidateSamples,
    sigma: float,
    config: Config,
) -> tuple[np.ndarray, np.ndarray]:
    """Score a candidate: the expected entropy of the texels it sees, and their expected radiance.

    For each hypothesis psi = (alpha, k) of the uncertainty grid the new sample is simulated,
    f_psi = k sum_l K(alpha, l) P_l(w_o) + D_psi: P_l the degree-l part of the light's SH fit,
    updated with the candidate's mirror sample, at the new direction; K the lobe the entropy uses
    (`freqbrdf.uncertainty.hypothesis_filter`, band-limit compensated, in calibrated mode;
    `freqbrdf.model.brdf.brdf_kernel` in paper mode); D_psi = max(0, (c_obs,00 - k c_light,00)
    / c_one,00) the Lambertian radiance that explains the rest of the fitted DC (0 for a texel
    with no sample yet). The observed fit updated with f_psi (Sherman-Morrison, `FitState`) is
    scored by `freqbrdf.uncertainty.entropy_from_spectra` with the texel's sample count + 1; the
    expectation is over the texel's current posterior P (the hypothesis is applied to all three
    channels, whose minimum entropy is the texel's, as in `freqbrdf.uncertainty`), leaving out
    hypotheses below `MIN_CELL_PROBABILITY` and renormalising.

    Parameters
    ----------
    state : FitState
        The n texels' fits before the sample.
    coeffs : (n, 7, K) float64
        Their coefficients (`state_coeffs`).
    likelihood : (n, R, R)
        Their current posteriors over (alpha, k).
    samples : CandidateSamples
        The candidate's samples at m of the n texels.
    sigma : float
        The capture's band limit.
    config : Config
        The fit's penalty and the uncertainty settings.

    Returns
    -------
    expected : (m,) float64
        Expected entropy of each texel the candidate sees.
    radiance : (m, 3) float64
        Posterior-mean radiance of its sample there (what `add_samples` commits).
    """
    rows = samples.texel
    lmax = sh.lmax_of(samples.basis.shape[1])
    weight_sq = np.square(samples.weight)
    basis, eigenvalues = state.basis[rows], state.eigenvalues[rows]  # (m, K, K), (m, K)
    # Sherman-Morrison in the eigenbasis, with the penalty the enlarged sample set will have.
    inverse = _inverse(eigenvalues + _penalty(state.weight_sq[rows] + weight_sq, config)[:, None])  # (m, K)
    z = (samples.basis[:, None, :] @ basis)[:, 0]  # B^T y (matmul: einsum does not use BLAS here)
    zeta = z * inverse  # (G + s' R)^-1 y in eigen coordinates
    gamma = state.projected_rhs[rows] * inverse[..., None]  # (m, K, 7): current rhs, new penalty
    gain = weight_sq / (1.0 + weight_sq * np.einsum("tk,tk->t", z, zeta))  # (m,)
    predicted = np.einsum("tk,tkr->tr", z, gamma)  # (m, 7): y . c for each rhs before the sample
    # Light: its new sample is known. Observed: keep the part that does not depend on the sample.
    light_step = gain[:, None] * (samples.light - predicted[:, LIGHT])  # (m, 3)
    light_eigen = gamma[..., LIGHT] + zeta[..., None] * light_step[:, None, :]
    columns = np.concatenate([light_eigen, gamma[..., OBSERVED], (zeta * gain[:, None])[..., None]], axis=2)
    updated = np.swapaxes(basis @ columns, 1, 2)  # (m, 7, K)
    light_coeffs, observed_base, update = updated[:, 0:3], updated[:, 3:6], updated[:, 6]
    light_spectrum = sh.power_spectrum(light_coeffs)  # (m, 3, L)
    base_spectrum = sh.power_spectrum(observed_base)
    base_update = cross_spectrum(observed_base, update[:, None, :])  # (m, 3, L)
    update_power = sh.power_spectrum(update)  # (m, L)

    # The hypotheses' radiance at the new sample.
    settings = config.uncertainty
    grid = hypothesis_grid(settings.resolution())
    grid_res, ks = grid.resolution, grid.specular
    calibrated = settings.mode == "calibrated"
    # The entropy's own lobe: filter per degree.
    kernel = (hypothesis_filter(grid, lmax, sigma) if calibrated
              else brdf.brdf_kernel(grid.alpha, lmax))  # (R, L)
    light_by_degree = cross_spectrum(light_coeffs, samples.basis[:, None, :])  # (m, 3, L): the light at the sample
    filtered = np.einsum("il,tcl->tic", kernel, light_by_degree)  # (m, R, 3)
    current = coeffs[rows]  # (m, 7, K) before the sample
    with np.errstate(divide="ignore", invalid="ignore"):
        specular_dc = ks[None, :, None] * current[:, None, LIGHT, 0]  # (m, R_k, 3)
        diffuse = np.where(
            current[:, ONE, 0, None, None] > 0,
            (current[:, None, OBSERVED, 0] - specular_dc) / current[:, ONE, 0, None, None],
            0.0,
        )  # (m, R_k, 3): the same for every alpha
    diffuse = np.maximum(diffuse, 0.0)
    # Cells: (alpha_i, k_j) for j >= 1, and the one k = 0 material (all alphas alike).
    cell_alpha = np.concatenate([np.zeros(1, np.int64), np.repeat(np.arange(grid_res), grid_res - 1)])
    cell_k = np.concatenate([np.zeros(1, np.int64), np.tile(np.arange(1, grid_res), grid_res)])
    probability = likelihood[rows].astype(np.float64)  # (m, R, R) [alpha, k]
    cell_probability = np.concatenate(
        [probability[:, :, 0].sum(axis=1, keepdims=True), probability[:, cell_alpha[1:], cell_k[1:]]], axis=1
    )  # (m, cells)
    pair, cell = np.nonzero(cell_probability >= MIN_CELL_PROBABILITY)
    radiance = (ks[cell_k[cell], None] * filtered[pair, cell_alpha[cell]]
                + diffuse[pair, cell_k[cell]])  # (P, 3)
    delta = radiance - predicted[pair, OBSERVED]  # (P, 3)
    observed_spectrum = (  # of c + delta u, degree by degree
        base_spectrum[pair] + 2.0 * delta[..., None] * base_update[pair]
        + np.square(delta)[..., None] * update_power[pair, None, :]
    )
    entropy = entropy_from_spectra(
        light_spectrum[pair], np.maximum(observed_spectrum, 0.0),
        n_samples=state.n_samples[rows][pair] + 1, sigma=sigma, config=settings,
        return_likelihood=False,
    ).entropy.astype(np.float64)
    weights = cell_probability[pair, cell]
    total = np.bincount(pair, weights, minlength=len(rows))
    expected = np.bincount(pair, weights * entropy, minlength=len(rows)) / total
    mean_radiance = np.stack(
        [np.bincount(pair, weights * radiance[:, c], minlength=len(rows)) for c in range(3)], axis=1
    ) / total[:, None]
    return expected, mean_radiance


# --------------------------------------------------------------------------------------------
# Helpers


def _check_fit_settings(config: Config) -> None:
    """Refuse settings guidance cannot score.

    The eigenbasis needs a positive penalty on every coefficient; candidates are scored on
    spectra.
    """
    if config.fit.regulariser == "none" or config.fit.reg_lambda <= 0:
        raise ValueError("capture guidance needs a regularised SH fit (reg_lambda > 0, a regulariser)")
    if config.uncertainty.mode == "angular":
        raise ValueError("capture guidance predicts spectra: use uncertainty mode 'calibrated' or 'paper'")


def _penalty(weight_sq: np.ndarray, config: Config) -> np.ndarray:
    """lambda_eff per texel, as `sh.fit_sh` sets it."""
    if config.fit.scale_lambda_with_weight:
        return config.fit.reg_lambda * weight_sq
    return np.full_like(weight_sq, config.fit.reg_lambda)


def _inverse(values: np.ndarray) -> np.ndarray:
    """1 / values, 0 where values is 0 (a texel without samples and no penalty: no fit)."""
    with np.errstate(divide="ignore"):
        return np.where(values > 0, 1.0 / values, 0.0)


def _diagonalise(state: FitState, rows: np.ndarray) -> None:
    """Refresh the eigenbasis of ``rows`` from their Gram matrices and right-hand sides."""
    inverse_sqrt = 1.0 / np.sqrt(state.regulariser)  # (K,)
    scaled = state.gram[rows] * inverse_sqrt[None, :, None] * inverse_sqrt[None, None, :]
    eigenvalues, vectors = np.linalg.eigh(scaled)
    basis = vectors * inverse_sqrt[None, :, None]
    state.basis[rows] = basis
    state.eigenvalues[rows] = np.maximum(eigenvalues, 0.0)  # G is positive semi-definite
    state.projected_rhs[rows] = np.swapaxes(basis, 1, 2) @ state.rhs[rows]


def _state_uncertainty(state: FitState, coeffs: np.ndarray, sigma: float, config: Config) -> Uncertainty:
    """Return the uncertainty (with likelihoods) of the state's fits, as `uncertainty.entropy_map` gives it."""
    n_coeffs = len(state.regulariser)
    status = np.where(state.n_samples == 0, sh.FIT_EMPTY,
                      np.where(state.n_samples < n_coeffs, sh.FIT_UNDERDETERMINED, sh.FIT_OK)).astype(np.uint8)
    observed, light = coeffs[:, OBSERVED], coeffs[:, LIGHT]
    return entropy_from_spectra(
        sh.power_spectrum(light), sh.power_spectrum(observed),
        n_samples=state.n_samples, sigma=sigma, fit_status=status, config=config.uncertainty,
    )
