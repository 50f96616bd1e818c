"""Synthetic captures: scene and material generators, the ``synth`` job and the demo.

Path-traced captures of a known object with ground-truth maps and relighting views, on which
results are judged (docs/method.md#evaluation). Never on the fit path: no stage imports it, only the CLI.

Modules
-------
synth
    `synthesize`: render a capture in our layout or Stanford-ORB's from `SynthSettings`;
    `example_capture`: the tiny one the documentation's examples fit.
materials
    Ground-truth material maps: colour bands and photo-derived materials.
demo
    `run_demo`: render, fit, evaluate and report the bundled default capture.
"""

from freqbrdf.synthetic.demo import DEFAULT_CAPTURE, capture_folder, run_demo
from freqbrdf.synthetic.materials import bands_material, photo_material
from freqbrdf.synthetic.synth import (
    EXAMPLE_SETTINGS,
    SynthScene,
    SynthSettings,
    example_capture,
    prepare,
    resample_envmap,
    synthesize,
)

__all__ = [
    "DEFAULT_CAPTURE",
    "EXAMPLE_SETTINGS",
    "SynthScene",
    "SynthSettings",
    "bands_material",
    "capture_folder",
    "example_capture",
    "photo_material",
    "prepare",
    "resample_envmap",
    "run_demo",
    "synthesize",
]
