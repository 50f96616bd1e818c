"""Spread of view directions in capture guidance: misfit correlated between nearby views (docs/method.md#guidance).

What is left of a texel's error once it is seen from several sides is mostly the model's misfit,
not noise, and the misfit of two samples is alike when their view directions are close. A
sample from direction c then tells a texel about as much as one independent sample over the
number of samples it is correlated with: the effective-sample count of a Gaussian process whose
correlation of the misfit between view directions a and b is

    rho(a, b) = exp((a . b - 1) / w^2),    w = `MISFIT_WIDTH`,

to first order, 1 / (1 + sum_j rho(c, j)) of a sample, the sum over the views already sampling the
texel (`Spread.discount`). w is the width of the correlation of per-texel residuals between two
samples of a texel against the angle between them (``benchmarks/studies/guidance.py --misfit``,
fitted as rho_0 rho(a, b), rho_0 < 1 the misfit's share of the residuals). The directions are
the views' directions from the object's centre
(`freqbrdf.applications.candidates.view_directions`), so the kernel is one matrix between the
views taken and the candidates, and a texel's sum over its views is kept per candidate and
updated as views are picked (`Spread.add`).

Where the candidates' expected gains differ by less than the scatter of the difference of two
refits (sqrt(2) `REFIT_NOISE` of the current mean std), the model cannot tell them apart; among
those the guidance takes the view farthest (in angle) from every view taken and picked, as
farthest-point sampling would (`Spread.choose`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

MISFIT_WIDTH = 0.6  # w of the misfit's correlation between view directions
REFIT_NOISE = 0.012  # a refit's own scatter of the mean std, relative to it


class Spread:
    """Per scored texel and candidate, how correlated a candidate's samples are with the texel's own.

    Parameters
    ----------
    n_texels : int
        The scored texels (n).
    taken : (V, 3) array
        Unit directions of the views taken.
    candidates : (C, 3) array
        Unit directions of the candidates.
    taken_texels : sequence of (m_j,) int64
        Per view taken, the scored texels it samples.
    """

    def __init__(self, n_texels: int, taken: np.ndarray, candidates: np.ndarray,
                 taken_texels: Sequence[np.ndarray]) -> None:
        self.candidates = np.asarray(candidates, np.float64)
        self.density = np.zeros((n_texels, len(self.candidates)))  # sum_j rho(c, j) per texel and candidate
        self.closeness = np.full(len(self.candidates), -1.0)  # max cosine to a view taken or picked
        for direction, texel in zip(np.asarray(taken, np.float64), taken_texels):
            self._add_direction(direction, texel)

    def _add_direction(self, direction: np.ndarray, texel: np.ndarray) -> None:
        cosine = self.candidates @ direction
        self.closeness = np.maximum(self.closeness, cosine)
        if MISFIT_WIDTH > 0:
            self.density[texel] += np.exp((cosine - 1.0) / MISFIT_WIDTH ** 2)[None]

    def add(self, candidate: int, texel: np.ndarray) -> None:
        """Commit a picked candidate: its samples now correlate with the later ones (in place).

        Parameters
        ----------
        candidate : int
            Its column.
        texel : (m,) int64
            The scored texels it samples.
        """
        self._add_direction(self.candidates[candidate], texel)

    def discount(self, candidate: int, texel: np.ndarray) -> np.ndarray:
        """Return the effective share of a sample the candidate adds to each texel it sees.

        Parameters
        ----------
        candidate : int
            Its column.
        texel : (m,) int64
            The scored texels it samples.

        Returns
        -------
        (m,) float64
            1 / (1 + sum_j rho(c, j)), in (0, 1].
        """
        return 1.0 / (1.0 + self.density[texel, candidate])

    def choose(self, gains: np.ndarray, columns: Sequence[int], uncertainty: float) -> tuple[int, bool]:
        """Return the position in ``gains`` of the view to pick, and whether the spread decided it.

        The candidates whose gain is within ``sqrt(2) * REFIT_NOISE * uncertainty`` of the best
        compete; of those, the one farthest from the views taken and picked wins (the earliest on
        ties).

        Parameters
        ----------
        gains : (R,) float64
            Expected gain of each remaining candidate.
        columns : sequence of int
            Their columns (R).
        uncertainty : float
            The current mean std.

        Returns
        -------
        tuple of (int, bool)
            The position, and True where it is not the best gain's.
        """
        gains = np.asarray(gains, np.float64)
        best = int(np.argmax(gains))
        close = np.flatnonzero(gains >= gains[best] - np.sqrt(2.0) * REFIT_NOISE * uncertainty)
        chosen = int(close[np.argmin(self.closeness[np.asarray(columns)[close]])])
        return chosen, chosen != best
