"""Named records of arrays and scalars that the global search's kernels take (docs/method.md#estimation).

numba compiles a kernel once per combination of its arguments' types, so each field keeps one
type: the builders in `freqbrdf.estimate.search` convert what they store. Shapes use n texels,
V views, K SH coefficients, P azimuthal harmonics (`model.tables.environment_pairs`), Q
quadrature points, R hypotheses and G roughness grid nodes.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Samples(NamedTuple):
    """The texels' samples and frames."""

    view_direction: np.ndarray  # (n, V, 3) float32 local view directions
    weight: np.ndarray  # (n, V) float32, 0 where unsampled
    observed: np.ndarray  # (n, V, 3) float32 radiance
    diffuse_scale: np.ndarray  # (n, 3) float64 E / pi, the Lambertian radiance per unit albedo
    tangent: np.ndarray  # (n, 3) float32 world frame of each texel
    normal: np.ndarray  # (n, 3) float32
    mirror_occluded: np.ndarray  # (n, V) float32 the share of the mirror lobe on the object; (n, 0): not traced
    mirror_surface: np.ndarray  # (n, V, 3) float32 the radiance it shows there; (n, 0, 3): not traced


class ShRecurrence(NamedTuple):
    """The SH basis recurrence of `sphere.harmonics._sh_block` up to degree lmax."""

    lmax: int
    diag: np.ndarray
    rec_a: np.ndarray
    rec_b: np.ndarray


class ModelOptions(NamedTuple):
    """Which reflection model the kernels evaluate (``EstimateConfig``)."""

    sigma: float  # the band-limit compensation of the BRDF kernel (`model.brdf.brdf_kernel`)
    fresnel: bool
    masking: bool
    split_sum: bool  # the split-sum albedo, else the angular model of docs/method.md#forward-model
    exact_dielectric: bool  # the dielectric's own albedo E, else Schlick's 0.04 A + B
    burley: bool  # Burley's diffuse, else Lambert's


class ModelTables(NamedTuple):
    """The model's tables (`model.tables`)."""

    split_sum: np.ndarray  # (3, cos nodes, roughness nodes) `split_sum_table`
    split_sum_rows: np.ndarray  # (3, roughness nodes, cos nodes) `split_sum_rows`
    environment_response: np.ndarray  # (3, environment nodes, cos nodes, 21) `environment_response_table`
    burley_response: np.ndarray  # (4, cos nodes, P) `burley_response_table`; P = 0: uniform light


class EnvironmentLight(NamedTuple):
    """The environment light of rough lobes; K = 0 without it."""

    coeffs: np.ndarray  # (K, 3) float64 world-frame SH of the environment
    blend: np.ndarray  # (2,) float64 roughness where its share starts and reaches 1
    quadrature: np.ndarray  # (Q, 3) `model.light.environment_quadrature` directions
    projection: np.ndarray  # (K, Q) its projection onto the SH


class PrefilteredLight(NamedTuple):
    """The prefiltered environment maps of smooth lobes; no nodes without them."""

    maps: np.ndarray  # (H W, nodes, 3) float32, pixel-major
    n_full: int  # the first n_full nodes are full maps, the others the degrees above the environment light's
    world_to_local: np.ndarray  # (3, 3) float64 world to the map's emitter frame
    height: int  # H
    width: int  # W


class SearchSettings(NamedTuple):
    """What the search kernel does."""

    roughness_grid: int
    metallic_grid: int
    robust_passes: int
    search: bool  # search the roughness, else only the hypotheses (or the vote)


class Hypotheses(NamedTuple):
    """Roughness hypotheses whose moments (`estimate.hypothesis_moments`) the kernel records."""

    roughness: np.ndarray  # (R,) float64
    moments: np.ndarray  # (n, R, 3, 8) float64, written
    node_rows: np.ndarray  # (G,) int64 the hypothesis at each grid node or -1; (0,): none


class Estimates(NamedTuple):
    """The kernel's output per texel, and its input for the neighbour vote."""

    params: np.ndarray  # (n, 5) float64 base colour RGB, roughness, metallic
    loss: np.ndarray  # (n,) float64
    curvature: np.ndarray  # (n,) float64
    label_loss: np.ndarray  # (n, 2) float64 the loss as a dielectric and as a metal; (0, 2): not recorded
    label_base_color: np.ndarray  # (n, 2, 3) float64 their base colours
    label_moments: np.ndarray  # (n, S, 3, 16) float64 per channel the 14 weighted sums of `metallic_quadratics`,
    # s_ff and the diffuse scale e, at the estimated roughness (slot 0) and at S - 1 roughness nodes evenly on
    # [0, 1]; (0, 1, 3, 16): not recorded
