"""The Examples sections of the package's docstrings run as doctests.

Every module of src/freqbrdf whose source holds a ``>>>`` example is collected, so a new Examples
section (say on `freqbrdf.pipeline.fit`) runs here without being listed.
"""

import doctest
import importlib
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "freqbrdf"
MODULES = sorted(
    ".".join(("freqbrdf", *path.relative_to(PACKAGE).with_suffix("").parts)).removesuffix(".__init__")
    for path in PACKAGE.rglob("*.py") if ">>> " in path.read_text(encoding="utf-8")
)


# The functions a user calls first, each with an Examples section (module, function).
ENTRY_POINTS = [
    ("freqbrdf.capture.layouts", "load"),
    ("freqbrdf.pipeline", "fit"),
    ("freqbrdf.observe.observations", "observe"),
    ("freqbrdf.estimate", "estimate"),
    ("freqbrdf.uncertainty", "entropy_map"),
    ("freqbrdf.applications.guidance", "select_views"),
    ("freqbrdf.applications.next_views", "write_next_views"),
    ("freqbrdf.outputs.export", "write_fit_outputs"),
    ("freqbrdf.outputs.evaluate", "evaluate_fit"),
    ("freqbrdf.batch.runner", "run"),
    ("freqbrdf.sphere.harmonics", "fit_sh"),
]


@pytest.mark.parametrize("module_name, name", ENTRY_POINTS)
def test_the_entry_points_have_examples(module_name, name):
    assert module_name in MODULES
    doc = getattr(importlib.import_module(module_name), name).__doc__
    assert "\n    Examples\n    --------\n" in doc and "\n    >>> " in doc


@pytest.mark.parametrize("name", MODULES)
def test_examples(name):
    module = importlib.import_module(name)
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    tests = [test for test in finder.find(module, name) if test.examples]
    assert tests, f"{name} has '>>> ' in its source but no docstring example"
    for test in tests:
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"
