"""The package's layers: data flows one way (capture -> texels -> observations -> spectra ->
{estimate, uncertainty} -> applications -> outputs), so no module imports a later stage.

Every import counts, at module level or inside a function, except those under
``if TYPE_CHECKING:`` (annotations only). Only `freqbrdf.render` imports Mitsuba or Dr.Jit, and
`freqbrdf.model` (what a texel reflects under a light) imports no stage.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import freqbrdf

PACKAGE_ROOT = Path(freqbrdf.__file__).resolve().parent

# Lowest first. A module may import its own layer and the layers before it.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("_numba_cache", "errors", "config", "devices", "progress", "jit", "fileio", "_codecs", "images", "assets"),  # shared foundation
    ("sphere",),  # SH basis, fits and environment-map transforms
    ("model",),  # what a texel reflects under a light
    ("capture",),
    ("texels",),
    ("render",),  # Mitsuba: ray tests for observe, renders for outputs and synthetic captures
    ("observe",),
    ("estimate",),
    ("calibrate",),  # exposure, white balance, the probe's turn: observes and searches coarse texels
    ("uncertainty",),  # the roughness std reads the estimate
    ("applications",),
    ("outputs",),
    ("pipeline",),
    ("batch",),
    ("synthetic",),  # scene and material generators, synth and the demo: never on the fit path
    ("cli_options", "cli_run", "cli"),
)
RANK = {name: rank for rank, names in enumerate(LAYERS) for name in names}
STAGE_PACKAGES = ("capture", "texels", "render", "observe", "estimate", "calibrate", "uncertainty", "applications",
                  "outputs", "pipeline", "batch", "synthetic", "cli_options", "cli_run", "cli")
MITSUBA_MODULES = ("mitsuba", "drjit")


def _modules() -> list[Path]:
    return sorted(path for path in PACKAGE_ROOT.rglob("*.py") if "__pycache__" not in path.parts)


def _top_name(path: Path) -> str:
    """The layer name of a module: its first component under freqbrdf/ (``__init__`` for the root)."""
    parts = path.relative_to(PACKAGE_ROOT).with_suffix("").parts
    return parts[0]


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, dotted module) of every runtime import in ``path`` (relative imports resolved)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = ("freqbrdf", *path.relative_to(PACKAGE_ROOT).parent.parts)
    found: list[tuple[int, str]] = []

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1])
                module = f"{base}.{node.module}" if node.module else base
            else:
                module = node.module or ""
            if module == "freqbrdf":  # from freqbrdf import a, b: each name is a module or a name of the root
                found.extend((node.lineno, f"freqbrdf.{alias.name}") for alias in node.names)
            else:
                found.append((node.lineno, module))
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return found


def _layer_of(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "freqbrdf" or len(parts) < 2:
        return None
    return parts[1]


def test_every_module_is_in_a_layer():
    unplaced = sorted({_top_name(path) for path in _modules()} - set(RANK) - {"__init__", "web"})
    assert not unplaced, f"modules or packages with no layer in LAYERS: {unplaced}"


@pytest.mark.parametrize("path", _modules(), ids=lambda path: str(path.relative_to(PACKAGE_ROOT)))
def test_no_module_imports_a_later_stage(path):
    own = _top_name(path)
    if own == "__init__":
        return
    later = []
    for line, module in _imports(path):
        layer = _layer_of(module)
        if layer is None or layer == "__version__" or layer not in RANK:
            continue
        if RANK[layer] > RANK[own]:
            later.append(f"line {line}: {module} ({layer} comes after {own})")
    assert not later, "\n".join(later)


@pytest.mark.parametrize("path", _modules(), ids=lambda path: str(path.relative_to(PACKAGE_ROOT)))
def test_only_render_imports_mitsuba(path):
    if _top_name(path) == "render":
        return
    offending = [f"line {line}: {module}" for line, module in _imports(path)
                 if module.split(".")[0] in MITSUBA_MODULES]
    assert not offending, "\n".join(offending)


def test_model_imports_no_stage():
    offending = []
    for path in (PACKAGE_ROOT / "model").rglob("*.py"):
        for line, module in _imports(path):
            if _layer_of(module) in STAGE_PACKAGES:
                offending.append(f"{path.name} line {line}: {module}")
    assert not offending, "\n".join(offending)


def test_the_layering_test_sees_imports():
    """The checks above would pass vacuously if the import scan found nothing."""
    scanned = {module for path in _modules() for _, module in _imports(path)}
    assert "freqbrdf.estimate" in scanned and any(module.startswith("freqbrdf.model") for module in scanned)
    render_imports = {module for path in (PACKAGE_ROOT / "render").rglob("*.py") for _, module in _imports(path)}
    assert {"mitsuba", "drjit"} & render_imports
