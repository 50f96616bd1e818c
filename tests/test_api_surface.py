"""The public API: each subpackage names what it offers in ``__all__``, and every function or
class it offers is documented as reference (numpydoc: a summary, Parameters, Returns)."""

from __future__ import annotations

import importlib
import inspect

import pytest

SUBPACKAGES = (
    "freqbrdf.sphere", "freqbrdf.model", "freqbrdf.capture", "freqbrdf.render", "freqbrdf.observe",
    "freqbrdf.estimate", "freqbrdf.uncertainty", "freqbrdf.applications", "freqbrdf.outputs",
    "freqbrdf.synthetic", "freqbrdf.batch",
)


def _public(package: str) -> list[tuple[str, object]]:
    module = importlib.import_module(package)
    return [(name, getattr(module, name)) for name in module.__all__]


@pytest.mark.parametrize("package", SUBPACKAGES)
def test_every_subpackage_declares_its_api(package):
    module = importlib.import_module(package)
    assert module.__doc__ and module.__doc__.strip(), f"{package} has no docstring"
    names = getattr(module, "__all__", None)
    assert names, f"{package} has no __all__"
    assert len(set(names)) == len(names), f"{package}.__all__ repeats a name"
    missing = [name for name in names if not hasattr(module, name)]
    assert not missing, f"{package}.__all__ names what it does not have: {missing}"
    private = [name for name in names if name.startswith("_")]
    assert not private, f"{package}.__all__ exports private names: {private}"


def _takes_parameters(function) -> bool:
    try:
        signature = inspect.signature(function)
    except (TypeError, ValueError):
        return False
    return any(name not in ("self", "cls") for name in signature.parameters)


def _returns_something(function) -> bool:
    annotation = inspect.signature(function).return_annotation
    return annotation not in (inspect.Signature.empty, None, "None")


def _problems(qualified: str, function) -> list[str]:
    doc = inspect.getdoc(function) or ""
    if not doc.strip():
        return [f"{qualified}: no docstring"]
    found = []
    if _takes_parameters(function) and "Parameters\n----------" not in doc:
        found.append(f"{qualified}: no Parameters section")
    if _returns_something(function) and not any(
            section in doc for section in ("Returns\n-------", "Yields\n------")):
        found.append(f"{qualified}: no Returns section")
    return found


# The uncertainty stage's public functions still lack numpydoc sections: listed here so that the
# gap is visible in the test, not hidden; remove the entry when they have them.
NOT_YET_NUMPYDOC: tuple[str, ...] = ()


@pytest.mark.parametrize("package", [package for package in SUBPACKAGES if package not in NOT_YET_NUMPYDOC])
def test_every_public_function_is_documented(package):
    problems = []
    for name, value in _public(package):
        qualified = f"{package}.{name}"
        if inspect.isfunction(value):
            problems += _problems(qualified, value)
        elif inspect.isclass(value):
            if not (inspect.getdoc(value) or "").strip():
                problems.append(f"{qualified}: no docstring")
            for attribute, member in vars(value).items():
                if attribute.startswith("_") or not inspect.isfunction(member):
                    continue
                problems += _problems(f"{qualified}.{attribute}", member)
    assert not problems, "\n".join(problems)


def test_the_surface_is_not_empty():
    """The checks above would pass vacuously on packages that export nothing."""
    exported = sum(len(_public(package)) for package in SUBPACKAGES)
    assert exported >= 60
