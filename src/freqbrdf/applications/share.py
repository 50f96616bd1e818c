"""Sharing across the surface: uncertain texels borrow from confident look-alikes (METHOD.md §4).

The paper's recipe, with bounded memory and safe for the texels the data does pin down
(`share`, `share_details`; ``ShareConfig`` holds the settings named below):

1. **Anchors.** Certainty is 1 - H (normalised entropy). The texture is split into
   ``anchor_cells`` x ``anchor_cells`` cells; the most certain observed texel of each cell is an
   anchor if its certainty reaches ``anchor_certainty`` (local maxima of certainty in texture
   space, at most one per cell, so plateaus of equal certainty do not make every texel an anchor).
   Texels whose most likely roughness lies below the sampling bound (FLAG_BELOW_BOUND) are never
   anchors: their posterior is sharp but their roughness is not resolved.
2. **Affinity.** Each uncertain texel x (entropy >= ``uncertain_entropy``) looks at its
   ``neighbours`` nearest anchors in texture space (a k-d tree over texel coordinates) and scores
   each by the KL divergence between their likelihood grids over the (alpha, k_s) hypotheses,

       D(a, x) = KL(P_a || P_x) = sum_psi P_a(psi) log(P_a(psi) / P_x(psi)),

   i.e. how surprised x's data would be by the anchor's material. This direction is deliberate:
   KL(P_x || P_a) would call a broad (uncertain) posterior far from every sharp anchor, even one
   that sits on the anchor's hypothesis. Affinity w = exp(-D^2 / (2 s^2)), s = ``affinity_width``
   x the mean D over all (texel, anchor) pairs (the paper's 0.4 x mean KL). Probabilities are
   floored at e^-CUTOFF, the resolution of ``uncertainty``'s likelihoods. Texels go in chunks
   of ``chunk_texels``, each holding (chunk, k, R^2) floats, whatever the number of anchors.
3. **Pull.** The target of x is the affinity-weighted mean of its anchors' parameters. x moves
   as close to it as its own data allows: among the candidates (whole parameter vector or
   roughness alone, moved 1/4, 1/2, 3/4 or all of the way to the target), x takes the one
   nearest the target whose angular data loss (``estimate.angular_loss``, the estimator's
   weighted mean squared residual, with the light shadowed at the candidate's roughness) exceeds
   its current loss by at most ``loss_tolerance`` (relative). This is a re-solve with the
   anchors as a prior, in constrained form: the data decides what it can, the anchors decide
   what it cannot. Texels below ``uncertain_entropy``, anchors and texels whose summed affinity
   is below ``min_affinity`` are returned unchanged.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from freqbrdf.config import Config, ShareConfig
from freqbrdf.estimate import MaterialEstimate, angular_loss, model_light
from freqbrdf.model import brdf
from freqbrdf.observe.observations import Observations
from freqbrdf.uncertainty import CUTOFF, FLAG_BELOW_BOUND, FLAG_UNOBSERVED, Uncertainty

# Fractions of the way to the target that are tried, nearest the target first.
PULL_FRACTIONS = (1.0, 0.75, 0.5, 0.25)
PROBABILITY_FLOOR = float(np.exp(-CUTOFF))  # likelihood cells below this are indistinguishable from 0


@dataclass(eq=False)
class Sharing:
    """The result of `share_details`: A anchors, P pulled (uncertain, estimated) texels, k neighbours.

    Attributes
    ----------
    estimate : MaterialEstimate
        The shared estimate (N texels).
    anchor_rows : (A,) int64
        Rows (into the N texels) of the anchors.
    pulled_rows : (P,) int64
        Rows of the uncertain texels that were considered.
    nearest_anchors : (P, k) int64
        Indices into ``anchor_rows`` of each pulled texel's nearest anchors.
    affinity : (P, k) float32
        Affinity of each pulled texel to those anchors.
    moved : (P,) bool
        Whether the texel's parameters changed.
    seconds : float
        Time spent sharing.
    """

    estimate: MaterialEstimate
    anchor_rows: np.ndarray
    pulled_rows: np.ndarray
    nearest_anchors: np.ndarray
    affinity: np.ndarray
    moved: np.ndarray
    seconds: float

    def summary(self) -> dict:
        """Summarise the sharing for ``summary.json``.

        Returns
        -------
        dict
            ``anchors``, ``uncertain_texels``, ``moved_texels`` (counts), ``mean_affinity_sum``
            (None without pulled texels) and ``seconds``.
        """
        n_pulled = len(self.pulled_rows)
        return {
            "anchors": len(self.anchor_rows),
            "uncertain_texels": n_pulled,
            "moved_texels": int(self.moved.sum()),
            "mean_affinity_sum": float(self.affinity.sum(axis=1).mean()) if n_pulled else None,
            "seconds": self.seconds,
        }


def share(observations: Observations, estimate: MaterialEstimate, uncertainty: Uncertainty,
          config: Config = Config()) -> MaterialEstimate:
    """Pull the uncertain texels of an estimate towards their affine anchors (module docstring).

    Parameters
    ----------
    observations : Observations
        The N texels' samples (for the data loss).
    estimate : MaterialEstimate
        The estimate of the same N texels.
    uncertainty : Uncertainty
        Their uncertainty, with the likelihood grids (``return_likelihood=True``).
    config : Config
        ``config.share`` the sharing settings; the estimator's settings set the data loss.

    Returns
    -------
    MaterialEstimate
        The shared estimate: method ``"<method>+share"``, a ``"share"`` timing.

    Raises
    ------
    ValueError
        If the likelihoods are missing, the three inputs describe different texels or
        ``config.share`` is out of range.
    """
    return share_details(observations, estimate, uncertainty, config).estimate


def share_details(observations: Observations, estimate: MaterialEstimate, uncertainty: Uncertainty,
                  config: Config = Config()) -> Sharing:
    """Share as `share` does, and return the anchors, affinities and which texels moved.

    Parameters
    ----------
    observations : Observations
        The N texels' samples (for the data loss).
    estimate : MaterialEstimate
        The estimate of the same N texels.
    uncertainty : Uncertainty
        Their uncertainty, with the likelihood grids (``return_likelihood=True``).
    config : Config
        ``config.share`` the sharing settings; the estimator's settings set the data loss.

    Returns
    -------
    Sharing
        The shared estimate and how it came about.

    Raises
    ------
    ValueError
        If the likelihoods are missing, the three inputs describe different texels or
        ``config.share`` is out of range.
    """
    settings = config.share
    _validate(settings)
    if uncertainty.likelihood is None:
        raise ValueError("sharing needs the likelihood grids: compute entropy_map(..., return_likelihood=True)")
    if not (np.array_equal(observations.texel_index, estimate.texel_index)
            and len(uncertainty.entropy) == estimate.n_texels):
        raise ValueError("observations, estimate and uncertainty must describe the same texels")
    start = time.perf_counter()
    coordinates = texel_coordinates(estimate.texture_res, estimate.texel_index)
    anchor_rows = find_anchors(estimate.texture_res, coordinates, uncertainty, estimate.estimated, settings)
    is_anchor = np.zeros(estimate.n_texels, bool)
    is_anchor[anchor_rows] = True
    pulled_rows = np.flatnonzero(estimate.estimated & ~is_anchor & (uncertainty.entropy >= settings.uncertain_entropy))
    n_neighbours = min(settings.neighbours, len(anchor_rows))
    if n_neighbours == 0 or len(pulled_rows) == 0:
        empty = np.zeros((len(pulled_rows), 0))
        return Sharing(estimate, anchor_rows, pulled_rows, empty.astype(np.int64), empty.astype(np.float32),
                       np.zeros(len(pulled_rows), bool), time.perf_counter() - start)

    nearest, affinity = anchor_affinity(coordinates, uncertainty.likelihood, anchor_rows, pulled_rows, settings)
    params = _parameter_matrix(estimate)  # (N, 5)
    anchor_params = params[anchor_rows]  # (A, 5)
    total = affinity.sum(axis=1)  # (P,)
    affine = total >= settings.min_affinity
    target = np.einsum("pk,pkc->pc", affinity[affine], anchor_params[nearest[affine]]) / total[affine, None]
    rows = pulled_rows[affine]
    moved = np.zeros(len(pulled_rows), bool)
    loss = estimate.loss.copy()
    if len(rows):
        new_params, new_loss = _pull(observations.select(rows), params[rows], target, config)
        changed = np.any(new_params != params[rows], axis=1)
        moved[affine] = changed
        params[rows] = new_params
        loss[rows[changed]] = new_loss[changed]
    seconds = time.perf_counter() - start
    shared = dataclasses.replace(
        estimate,
        base_color=params[:, :3], roughness=params[:, 3], metallic=params[:, 4], loss=loss,
        method=f"{estimate.method}+share", timings={**estimate.timings, "share": seconds},
    )
    return Sharing(shared, anchor_rows, pulled_rows, nearest, affinity, moved, seconds)


def texel_coordinates(texture_res: int, texel_index: np.ndarray) -> np.ndarray:
    """Return the (row, column) of each texel in the texture.

    Parameters
    ----------
    texture_res : int
        T, the texture side.
    texel_index : (N,) int
        Flat row-major indices into the T x T texture.

    Returns
    -------
    (N, 2) float64
        Row and column per texel.
    """
    rows, columns = np.divmod(np.asarray(texel_index, np.int64), texture_res)
    return np.stack([rows, columns], axis=1).astype(np.float64)


def find_anchors(texture_res: int, coordinates: np.ndarray, uncertainty: Uncertainty, estimated: np.ndarray,
                 settings: ShareConfig) -> np.ndarray:
    """Find the anchors: per texture cell, its most certain eligible texel (module docstring, step 1).

    Eligible: estimated, observed, not below the sampling bound, certainty
    1 - H >= ``anchor_certainty``. Ties go to the lowest row.

    Parameters
    ----------
    texture_res : int
        T, the texture side.
    coordinates : (N, 2) float64
        Texel (row, column) (`texel_coordinates`).
    uncertainty : Uncertainty
        The texels' entropy and flags.
    estimated : (N,) bool
        Texels the estimate holds.
    settings : ShareConfig
        ``anchor_cells`` and ``anchor_certainty``.

    Returns
    -------
    (A,) int64
        Rows of the anchors, ascending.
    """
    certainty = 1.0 - uncertainty.entropy.astype(np.float64)
    eligible = (estimated & ((uncertainty.flags & (FLAG_UNOBSERVED | FLAG_BELOW_BOUND)) == 0)
                & (certainty >= settings.anchor_certainty))
    candidates = np.flatnonzero(eligible)
    if len(candidates) == 0:
        return candidates
    cell_size = max(texture_res / settings.anchor_cells, 1.0)
    cell = np.floor(coordinates[candidates] / cell_size).astype(np.int64)
    cell_id = cell[:, 0] * (settings.anchor_cells + 1) + cell[:, 1]
    # Sort by cell, then by decreasing certainty (stable: ties keep the lower row); first per cell wins.
    order = np.lexsort((-certainty[candidates], cell_id))
    first_of_cell = np.ones(len(order), bool)
    first_of_cell[1:] = cell_id[order][1:] != cell_id[order][:-1]
    return np.sort(candidates[order[first_of_cell]])


def anchor_affinity(coordinates: np.ndarray, likelihood: np.ndarray, anchor_rows: np.ndarray,
                    pulled_rows: np.ndarray, settings: ShareConfig) -> tuple[np.ndarray, np.ndarray]:
    """Find the k nearest anchors of each pulled texel and their affinities (module docstring, step 2).

    Peak memory beyond the outputs is O(chunk_texels k R^2), whatever N and A.

    Parameters
    ----------
    coordinates : (N, 2) float64
        Texel (row, column) (`texel_coordinates`).
    likelihood : (N, R, R)
        Likelihood grids, each summing to 1.
    anchor_rows : (A,) int64
        Rows of the anchors.
    pulled_rows : (P,) int64
        Rows of the texels to pull.
    settings : ShareConfig
        ``neighbours`` (k, at most A), ``affinity_width`` and ``chunk_texels``.

    Returns
    -------
    nearest : (P, k) int64
        Indices into ``anchor_rows``.
    affinity : (P, k) float32
        Affinities in (0, 1].
    """
    n_neighbours = min(settings.neighbours, len(anchor_rows))
    tree = cKDTree(coordinates[anchor_rows])
    anchor_grid = likelihood[anchor_rows].reshape(len(anchor_rows), -1).astype(np.float32)  # (A, R^2)
    # sum_psi P_a log P_a per anchor; KL(P_a || P_x) = that - sum_psi P_a log P_x.
    anchor_neg_entropy = np.sum(anchor_grid * np.log(np.maximum(anchor_grid, PROBABILITY_FLOOR)), axis=1)
    nearest = np.empty((len(pulled_rows), n_neighbours), np.int64)
    divergence = np.empty((len(pulled_rows), n_neighbours), np.float32)
    for begin in range(0, len(pulled_rows), settings.chunk_texels):
        rows = pulled_rows[begin:begin + settings.chunk_texels]
        _, neighbours = tree.query(coordinates[rows], k=n_neighbours)
        neighbours = neighbours.reshape(len(rows), n_neighbours)
        log_texel = np.log(np.maximum(likelihood[rows].reshape(len(rows), -1), PROBABILITY_FLOOR))  # (c, R^2)
        cross = np.einsum("ckr,cr->ck", anchor_grid[neighbours], log_texel.astype(np.float32))
        nearest[begin:begin + len(rows)] = neighbours
        # >= 0 in exact arithmetic; float32 rounding may dip below
        divergence[begin:begin + len(rows)] = np.maximum(anchor_neg_entropy[neighbours] - cross, 0.0)
    width = settings.affinity_width * float(divergence.mean(dtype=np.float64))
    if width <= 0.0:  # every anchor matches every texel exactly
        return nearest, np.ones_like(divergence)
    affinity = np.exp(-0.5 * np.square(divergence / np.float32(width)))
    return nearest, affinity.astype(np.float32)


# ---------------------------------------------------------------------------------------------
# Helpers


def _validate(settings: ShareConfig) -> None:
    """Refuse out-of-range sharing settings."""
    if settings.neighbours < 1 or settings.anchor_cells < 1 or settings.chunk_texels < 1:
        raise ValueError("share: neighbours, anchor_cells and chunk_texels must be >= 1")
    if settings.affinity_width <= 0 or settings.loss_tolerance < 0 or settings.min_affinity < 0:
        raise ValueError("share: affinity_width must be > 0, loss_tolerance and min_affinity >= 0")


def _parameter_matrix(estimate: MaterialEstimate) -> np.ndarray:
    """(N, 5) float64: base colour RGB, roughness, metallic."""
    return np.column_stack([estimate.base_color, estimate.roughness, estimate.metallic]).astype(np.float64)


def _principled(params: np.ndarray) -> brdf.PrincipledParams:
    return brdf.PrincipledParams(base_color=params[:, :3], roughness=params[:, 3], metallic=params[:, 4])


def _pull(observations: Observations, own: np.ndarray, target: np.ndarray, config: Config):
    """Move each texel's parameters ``own`` (P, 5) towards ``target`` (P, 5) as far as its data allows.

    ``observations`` holds the same P texels. Returns the new parameters (P, 5) and their data
    loss (P,) (module docstring, step 3).
    """
    tolerance = 1.0 + config.share.loss_tolerance
    own_loss = angular_loss(observations, _principled(own), config, model_light(observations, own[:, 3], config))
    best, best_loss = own.copy(), own_loss.copy()
    best_distance = np.linalg.norm(own - target, axis=1)
    for fraction in PULL_FRACTIONS:
        moved_all = own + fraction * (target - own)
        moved_roughness = own.copy()
        moved_roughness[:, 3] = moved_all[:, 3]
        light = model_light(observations, moved_all[:, 3], config)  # both candidates share the roughness
        for candidate in (moved_all, moved_roughness):
            loss = angular_loss(observations, _principled(candidate), config, light)
            distance = np.linalg.norm(candidate - target, axis=1)
            better = (loss <= tolerance * own_loss) & (distance < best_distance)
            best[better], best_loss[better], best_distance[better] = candidate[better], loss[better], distance[better]
    return best, best_loss
