"""Tests of freqbrdf.estimate.surface: the whole-surface solve's graph, labels and smoothing."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy import sparse

from freqbrdf.config import Config, SurfaceConfig, TexelConfig
from freqbrdf.estimate.surface import (
    border_variance,
    chart_prior,
    lookalike_graph,
    metal_posterior,
    shrink_unseen_to_charts,
    smooth_on_surface,
    surface_graph,
)
from freqbrdf.synthetic.synth import SynthSettings, synthesize

SETTINGS = SurfaceConfig()
TINY = SynthSettings(mesh="bunny", views=6, resolution=40, spp=4, texture_res=32, test_views=0)


@pytest.fixture(scope="module")
def tiny_capture_path(tmp_path_factory):
    """A tiny bunny capture whose six views leave part of the atlas unseen."""
    return synthesize(tmp_path_factory.mktemp("capture") / "tiny", TINY, progress=False)


def grid(side: int) -> tuple[np.ndarray, np.ndarray]:
    """(side^2, 3) points of a flat side x side grid of unit spacing, and their normals (+z)."""
    rows, cols = np.divmod(np.arange(side * side), side)
    position = np.stack([cols, rows, np.zeros_like(rows)], axis=1).astype(np.float64)
    return position, np.tile([0.0, 0.0, 1.0], (side * side, 1))


def test_graph_joins_surface_neighbours_across_a_seam_and_not_the_two_sides_of_a_thin_part():
    position, normal = grid(8)
    # A second sheet 0.5 below with opposite normals: as close as the grid's spacing, other side.
    below = position - [0.0, 0.0, 0.5]
    graph = surface_graph(np.vstack([position, below]), np.vstack([normal, -normal]), np.zeros((128, 1)),
                          np.ones(128, bool), SETTINGS)
    assert (graph != graph.T).nnz == 0
    coo = graph.tocoo()
    assert np.all((coo.row < 64) == (coo.col < 64)), "an edge joins the two sides"
    assert graph[0, 1] == 1.0 and graph[0, 8] == 1.0  # neighbours on one sheet (in 3D: the seam does not matter)


def test_graph_weighs_unlike_neighbours_down():
    position, normal = grid(8)
    appearance = np.where(position[:, :1] < 4, 0.0, 1.0)  # two materials, an edge between columns 3 and 4
    graph = surface_graph(position, normal, appearance, np.ones(64, bool), SETTINGS)
    assert graph[3, 4] == pytest.approx(np.exp(-1.0 / (2 * SETTINGS.appearance_width ** 2)))
    assert graph[2, 3] == 1.0
    unobserved = surface_graph(position, normal, appearance, np.zeros(64, bool), SETTINGS)
    assert unobserved[3, 4] == 1.0  # no appearance to compare


def test_metal_needs_evidence_and_a_metal_island_keeps_its_edge():
    side = 16
    position, normal = grid(side)
    island = (np.abs(position[:, 0] - 8) < 3) & (np.abs(position[:, 1] - 8) < 3)
    appearance = np.where(island, 1.0, 0.0)[:, None]
    observed = np.ones(side * side, bool)
    graph = surface_graph(position, normal, appearance, observed, SETTINGS)
    # Strong evidence on the island; a weak pull towards metal on the dielectric around it, as a
    # rough dielectric's model misfit gives, short of the prior's odds.
    log_ratio = np.where(island, 20.0, 0.2)
    probability = metal_posterior(log_ratio, observed, graph, SETTINGS)
    assert np.all(probability[island] > 0.95) and np.all(probability[~island] < 0.5)
    # No evidence at all: the prior's dielectric.
    assert np.all(metal_posterior(np.zeros(side * side), observed, graph, SETTINGS) < 0.5)


def test_lookalikes_join_alike_texels_far_apart_and_only_them():
    # Two alike patches at opposite corners of a grid, unlike the rest; one texel unobserved.
    position, normal = grid(16)
    patch_a = (position[:, 0] < 3) & (position[:, 1] < 3)
    patch_b = (position[:, 0] > 12) & (position[:, 1] > 12)
    appearance = np.where((patch_a | patch_b)[:, None], 1.0, np.linspace(-2.0, -1.0, 256)[:, None])
    observed = np.ones(256, bool)
    observed[0] = False
    graph = lookalike_graph(appearance, observed, observed, SETTINGS)
    assert (graph != graph.T).nnz == 0 and graph.diagonal().sum() == 0
    coo = graph.tocoo()
    strong = coo.data > 0.1
    joined = set(zip(coo.row[strong].tolist(), coo.col[strong].tolist()))
    assert any(patch_a[i] and patch_b[j] for i, j in joined), "alike patches far apart are not joined"
    assert not any((patch_a | patch_b)[i] != (patch_a | patch_b)[j] for i, j in joined), "unlike texels joined"
    assert graph[0].nnz == 0  # an unobserved texel has no appearance to match
    # The label crosses over: a patch without evidence of its own takes its look-alike's.
    log_ratio = np.where(patch_b, 30.0, np.where(patch_a, 0.0, -5.0))
    alone = metal_posterior(log_ratio, observed, surface_graph(position, normal, appearance, observed, SETTINGS),
                            SETTINGS)
    shared = metal_posterior(log_ratio, observed, surface_graph(position, normal, appearance, observed, SETTINGS)
                             .maximum(graph).tocsr(), SETTINGS)
    assert np.all(alone[patch_a & observed] < 0.5) and np.all(shared[patch_a & observed] > 0.5)


def test_a_texel_without_samples_takes_its_neighbours_label():
    position, normal = grid(12)
    observed = np.ones(144, bool)
    observed[60:64] = False  # a hole in a metal plate
    graph = surface_graph(position, normal, np.zeros((144, 1)), observed, SETTINGS)
    probability = metal_posterior(np.where(observed, 30.0, 0.0), observed, graph, SETTINGS)
    assert np.all(probability[~observed] > 0.9)


def test_smoothing_fills_unseen_texels_from_their_neighbours_and_keeps_edges():
    side = 20
    position, normal = grid(side)
    truth = np.where(position[:, 0] < 10, 0.2, 0.8)[:, None]
    rng = np.random.default_rng(0)
    values = truth + rng.normal(0.0, 0.02, truth.shape)
    precision = np.full(truth.shape, 1.0 / 0.02 ** 2)
    unseen = (position[:, 1] >= 8) & (position[:, 1] < 12) & (np.abs(position[:, 0] - 4) < 2)  # inside the 0.2 half
    precision[unseen] = 0.0
    values[unseen] = 5.0  # ignored: no data
    # The two materials look different (the graph's appearance), as at a material edge.
    graph = surface_graph(position, normal, 4.0 * truth, ~unseen, SETTINGS)
    solution, std = smooth_on_surface(values, precision, graph, 1.0, 0.05, SETTINGS)
    assert np.abs(solution[unseen] - 0.2).max() < 0.02
    edge_left, edge_right = position[:, 0] == 9, position[:, 0] == 10
    assert np.abs(solution[edge_left] - 0.2).max() < 0.05 and np.abs(solution[edge_right] - 0.8).max() < 0.05
    # Less noisy than the data, and the unseen texels are the least certain.
    seen = ~unseen
    assert np.sqrt(np.mean((solution[seen] - truth[seen]) ** 2)) < 0.02
    assert std[unseen].min() > np.median(std[seen])


def test_std_is_calibrated_on_a_case_with_known_noise():
    """Per-texel values with known Gaussian noise around a smooth truth: the 1-sigma interval of
    the solution holds the truth for about 68 % of texels."""
    side = 48
    position, normal = grid(side)
    truth = (0.3 + 0.2 * np.sin(position[:, 0] / 9.0) * np.cos(position[:, 1] / 11.0))[:, None]
    rng = np.random.default_rng(1)
    noise = rng.uniform(0.02, 0.1, truth.shape)
    values = truth + rng.normal(0.0, 1.0, truth.shape) * noise
    graph = surface_graph(position, normal, np.zeros((side * side, 1)), np.ones(side * side, bool), SETTINGS)
    solution, std = smooth_on_surface(values, 1.0 / noise ** 2, graph, 0.3, 1.0, SETTINGS)
    coverage = np.mean(np.abs(solution - truth) <= std)
    assert 0.55 <= coverage <= 0.8, coverage


def test_solve_is_deterministic():
    position, normal = grid(24)
    rng = np.random.default_rng(2)
    values = rng.uniform(0.0, 1.0, (576, 3))
    precision = rng.uniform(0.0, 100.0, (576, 3))
    graph = surface_graph(position, normal, rng.normal(0.0, 0.3, (576, 3)), np.ones(576, bool), SETTINGS)
    first = smooth_on_surface(values, precision, graph, 0.3, 0.05, SETTINGS)
    second = smooth_on_surface(values.copy(), precision.copy(), graph.copy(), 0.3, 0.05, SETTINGS)
    assert all(np.array_equal(a, b) for a, b in zip(first, second))


@pytest.mark.slow
def test_fit_gives_every_texel_a_value_and_its_ablation_leaves_unseen_texels_empty(tiny_capture_path):
    from freqbrdf import pipeline
    from freqbrdf.capture.layouts import load

    capture = load(tiny_capture_path)
    config = Config(texels=TexelConfig(texture_res=32))
    solved = pipeline.fit(capture, config)
    per_texel = pipeline.fit(capture, config.replace(surface=dataclasses.replace(config.surface, enabled=False)))
    unseen = ~per_texel.estimate.estimated
    assert unseen.any() and np.all(np.isnan(per_texel.estimate.roughness[unseen]))
    assert np.all(np.isfinite(solved.estimate.roughness)) and np.all(np.isfinite(solved.estimate.base_color))
    assert np.all(np.isin(solved.estimate.metallic[unseen], [0.0, 1.0]))  # a label; mixed metals need samples
    for name in ("roughness_std", "metallic_std", "base_color_std"):
        assert np.all(np.isfinite(getattr(solved.uncertainty, name))), name
    assert "surface" in solved.timings


@pytest.mark.slow
def test_evaluation_and_report_show_the_std_calibration_and_the_unseen_side(tiny_capture_path, tmp_path):
    from freqbrdf import pipeline
    from freqbrdf.capture.layouts import load
    from freqbrdf.outputs.evaluate import evaluate_fit
    from freqbrdf.outputs.fit_folder import load_fit
    from freqbrdf.outputs.report import write_report

    capture = load(tiny_capture_path)
    config = Config(texels=TexelConfig(texture_res=32))
    folder = pipeline.write_fit(tmp_path / "fit", pipeline.fit(capture, config), config)
    for name in ("metallic_std.exr", "base_color_std.exr", "metallic_std.png", "base_color_std.png"):
        assert (folder / name).is_file(), name
    carry = json.loads((folder / "summary.json").read_text(encoding="utf-8"))["unseen_carry_hops"]
    assert set(carry) == {"roughness", "base_color"}  # six views leave part of the atlas unseen
    assert all(hops == "inf" or hops is None or hops > 0.0 for hops in carry.values()), carry
    metrics = evaluate_fit(load_fit(folder), capture)
    calibration = metrics["calibration"]
    picture = folder / "evaluation" / metrics["unseen_side"]["picture"]
    assert picture.is_file() and metrics["unseen_side"]["left"] == "ground truth"
    for name in ("roughness", "metallic", "base_color"):
        within = list(calibration[name]["within"].values())
        assert all(0.0 <= a <= b <= 1.0 for a, b in zip(within, within[1:])), (name, within)
    assert calibration["ideal"]["1"] == pytest.approx(0.6827, abs=1e-4)
    assert (folder / "evaluation" / calibration["plot"]).is_file()
    write_report(folder)
    page = (folder / "report" / "report.html").read_text(encoding="utf-8")
    assert "Calibration of the std maps" in page and "metallic std" in page and "saw least" in page


def _unseen_block(truth: np.ndarray, side: int) -> tuple:
    """Noisy data of ``truth`` on a side x side grid (one chart) but for a block no view sees, and the solve."""
    position, normal = grid(side)
    rng = np.random.default_rng(3)
    values = truth + rng.normal(0.0, 0.01, truth.shape)
    precision = np.full(truth.shape, 1.0 / 0.01 ** 2)
    unseen = (np.abs(position[:, 0] - side / 2) < side / 5) & (np.abs(position[:, 1] - side / 2) < side / 5)
    precision[unseen] = 0.0
    graph = surface_graph(position, normal, np.zeros((side * side, 1)), ~unseen, SETTINGS)
    solution, _ = smooth_on_surface(values, precision, graph, 1.0, 1.0, SETTINGS)
    return values, precision, solution, graph, np.zeros(side * side, np.int64), unseen


def test_a_smooth_gradient_carries_into_the_unseen_texels():
    side = 40
    position, _ = grid(side)
    truth = (0.1 + 0.8 * position[:, 0] / (side - 1))[:, None]
    values, precision, solution, graph, charts, unseen = _unseen_block(truth, side)
    shrunk, carry, std = shrink_unseen_to_charts(values, precision, solution, graph, charts, 1.0, 1.0, SETTINGS)
    assert carry > 16.0  # measured on held-out balls of the seen texels: the gradient holds
    assert np.abs(shrunk[unseen] - solution[unseen]).max() < 0.05
    assert np.abs(shrunk[unseen] - truth[unseen]).max() < 0.05
    assert np.array_equal(shrunk[~unseen], solution[~unseen])
    assert not std[~unseen].any() and np.all(std[unseen] > 0.0)  # the held-out texels' error by hops


def test_unrelated_cells_fall_back_to_their_charts_mean_away_from_the_data():
    side = 40
    position, _ = grid(side)
    cells = np.random.default_rng(4).uniform(0.0, 1.0, (side // 2, side // 2))
    truth = cells[(position[:, 1] // 2).astype(int), (position[:, 0] // 2).astype(int)][:, None]
    values, precision, solution, graph, charts, unseen = _unseen_block(truth, side)
    shrunk, carry, std = shrink_unseen_to_charts(values, precision, solution, graph, charts, 1.0, 1.0, SETTINGS)
    assert carry < 2.0  # a cell says little of the next
    mean = values[~unseen].mean()
    deep = unseen & (np.abs(position[:, 0] - side / 2) < 3) & (np.abs(position[:, 1] - side / 2) < 3)
    assert np.abs(shrunk[deep] - mean).max() < 0.02
    # Far from data the std is the error of the chart mean itself: the cells' spread (uniform: 0.29).
    assert 0.2 < std[deep].min() < 0.4
    again = shrink_unseen_to_charts(values.copy(), precision.copy(), solution.copy(), graph.copy(), charts, 1.0, 1.0,
                                    SETTINGS)
    assert np.array_equal(again[0], shrunk) and again[1] == carry and np.array_equal(again[2], std)


def test_nothing_to_shrink_where_every_texel_has_data():
    position, normal = grid(12)
    values = np.random.default_rng(5).uniform(0.0, 1.0, (144, 1))
    graph = surface_graph(position, normal, np.zeros((144, 1)), np.ones(144, bool), SETTINGS)
    solution = values.copy()
    shrunk, carry, std = shrink_unseen_to_charts(values, np.ones((144, 1)), solution, graph, np.zeros(144, np.int64),
                                                 1.0, 1.0, SETTINGS)
    assert shrunk is solution and np.isnan(carry) and not std.any()


def test_chart_prior_gives_each_texel_its_charts_seen_mean():
    charts = np.repeat([0, 1], 10)
    truth = np.where(charts == 0, 0.2, 0.8)[:, None]
    seen = np.ones(20, bool)
    seen[[9, 19]] = False
    mean, variance = chart_prior(truth, seen, charts)
    assert np.allclose(mean[charts == 1], 0.8) and np.allclose(mean[charts == 0], 0.2) and np.allclose(variance, 0.0)


def test_the_metallic_std_is_widest_on_a_border_between_sure_labels():
    # A chain of texels, sure metal on the left, sure dielectric on the right.
    n = 10
    rows = np.r_[np.arange(n - 1), np.arange(1, n)]
    graph = sparse.csr_matrix((np.full(2 * (n - 1), 0.01), (rows, np.r_[np.arange(1, n), np.arange(n - 1)])),
                              shape=(n, n))  # weak (appearance) weights: counted alike all the same
    probability = np.where(np.arange(n) < 5, 0.999, 0.001)
    variance = border_variance(probability, graph)
    assert variance[4] > 0.2 and variance[5] > 0.2  # the two texels either side of the border
    assert np.all(variance[[0, 1, 2, 7, 8, 9]] < 1e-6)


def test_a_label_without_evidence_starts_from_its_charts_share_of_metal():
    # Two charts of ten texels each, no edges: the first's seen texels are metal, the second's not.
    graph = sparse.csr_matrix((20, 20))
    charts = np.repeat([0, 1], 10)
    observed = np.array([True] * 9 + [False] + [True] * 9 + [False])
    log_ratio = np.where(charts == 0, 20.0, -20.0) * observed
    settings = dataclasses.replace(SETTINGS)
    with_charts = metal_posterior(log_ratio, observed, graph, settings, charts)
    alone = metal_posterior(log_ratio, observed, graph, settings)
    assert with_charts[9] > 0.9 and with_charts[19] < 0.1  # the unseen texel of each chart follows its chart
    assert alone[9] < 0.5  # the global prior alone: a dielectric
