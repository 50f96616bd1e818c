"""Progress that tells the truth: the SH fit and the estimate advance block by block, every stage of a
fit reports, and the blocks change nothing in the results."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest

from freqbrdf import pipeline
from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, TexelConfig
from freqbrdf.progress import Reporter
from freqbrdf.synthetic.synth import SynthSettings, synthesize

TINY = SynthSettings(mesh="bunny", views=6, resolution=40, spp=4, texture_res=32, test_views=0)


class RecordingReporter(Reporter):
    """Keeps each stage's total and the steps it advanced."""

    def __init__(self):
        super().__init__(enabled=False)
        self.stages: dict[str, list[int]] = {}

    @contextlib.contextmanager
    def stage(self, description, total):
        record = self.stages.setdefault(description, [total, 0])

        def advance(steps=1):
            record[1] += steps

        yield advance


@pytest.fixture(scope="module")
def tiny_capture(tmp_path_factory):
    return load(synthesize(tmp_path_factory.mktemp("capture") / "tiny", TINY, progress=False))


def test_the_fit_and_the_search_advance_per_block_and_the_blocks_change_nothing(tiny_capture, monkeypatch):
    config = Config(texels=TexelConfig(texture_res=32))
    whole = pipeline.fit(tiny_capture, config)
    monkeypatch.setattr("freqbrdf.observe.observations.FIT_BLOCK", 100)
    monkeypatch.setattr("freqbrdf.estimate.search.SEARCH_BLOCK", 150)
    reporter = RecordingReporter()
    blocked = pipeline.fit(tiny_capture, config, reporter)
    n_texels = len(blocked.observations.texel_index)
    fit_total, fit_done = reporter.stages["fitting SH spectra"]
    search_total, search_done = reporter.stages["estimating (global)"]
    assert fit_total == fit_done == -(-n_texels // 100) > 1
    assert search_total == search_done >= -(-n_texels // 150) > 1
    for stage in ("observing views", "tracing the object's shadows", "entropy", "whole-surface solve"):
        assert reporter.stages[stage][0] == reporter.stages[stage][1] >= 1, stage
    for name in ("base_color", "roughness", "metallic"):
        np.testing.assert_array_equal(getattr(blocked.maps, name), getattr(whole.maps, name), err_msg=name)
    np.testing.assert_array_equal(blocked.observations.observed_coeffs, whole.observations.observed_coeffs)
    np.testing.assert_array_equal(blocked.uncertainty.entropy, whole.uncertainty.entropy)
