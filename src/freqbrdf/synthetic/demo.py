"""``freqbrdf demo``: from nothing to a report on the bundled default capture.

Renders the default synthetic capture with Mitsuba (the bunny with an image-based material under a
bundled HDR map, 96 views, and a relighting test set under two other maps), fits it (docs/method.md#pipeline), evaluates it (docs/method.md#evaluation) and writes the report. The capture is cached under
``<out>/capture-<hash of its settings>``, so a second run starts at the fit.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

from freqbrdf import __version__, pipeline
from freqbrdf.capture.layouts import load
from freqbrdf.config import Config
from freqbrdf.outputs.evaluate import evaluate_fit
from freqbrdf.outputs.fit_folder import load_fit
from freqbrdf.outputs.relight import RelightSettings
from freqbrdf.outputs.report import write_report
from freqbrdf.progress import SILENT, Reporter
from freqbrdf.synthetic.synth import SynthSettings, synthesize

DEFAULT_CAPTURE = SynthSettings(
    # 96 views: each observed texel is then seen more often than the 36 coefficients of the
    # degree-5 fits, so that few texels are underdetermined (docs/results.md).
    mesh="bunny", envmap="forest", materials="coffee", views=96, resolution=256, spp=64,
    texture_res=512, test_envmaps=("studio", "sunset"), test_views=6,
)
RELIGHT_SPP = 64


def capture_folder(out: Path, settings: SynthSettings) -> Path:
    """Return where the capture of some settings is cached.

    Parameters
    ----------
    out : Path
        The demo's output folder.
    settings : SynthSettings
        The capture's settings.

    Returns
    -------
    Path
        ``out/capture-<hash>``; the hash covers the settings and the package version.
    """
    key = json.dumps({"settings": asdict(settings), "version": __version__}, sort_keys=True)
    return out / f"capture-{hashlib.sha256(key.encode()).hexdigest()[:12]}"


def run_demo(out: str | Path = "out/demo", settings: SynthSettings = DEFAULT_CAPTURE,
             config: Config = Config(), reporter: Reporter = SILENT,
             relight: RelightSettings = RelightSettings(spp=RELIGHT_SPP),
             before_writing: Callable[[], None] = lambda: None) -> dict:
    """Run the whole demo: render (or reuse) the capture, fit, evaluate, report.

    Parameters
    ----------
    out : str or Path, optional
        The output folder: the cached capture, ``fit/`` with its evaluation and report.
    settings : SynthSettings, optional
        The synthetic capture.
    config : Config, optional
        The fit's settings.
    reporter : Reporter, optional
        Receives progress.
    relight : RelightSettings, optional
        Render settings of the evaluation's relit views.
    before_writing : callable () -> None, optional
        Called between the fit and writing it (the command line may re-run itself there).

    Returns
    -------
    dict
        ``capture``, ``fit`` and ``report`` paths, ``capture_cached``, the ``texture`` and
        ``relighting`` scores, the ``uncertainty`` headline scores (Spearman, AUSE, AURG per error
        kind, of the entropy and of the roughness std) and ``timings`` (seconds per step).
    """
    out = Path(out)
    timings = {}
    capture_dir = capture_folder(out, settings)
    start = time.perf_counter()
    cached = capture_dir.is_dir()
    if not cached:
        synthesize(capture_dir, settings, progress=reporter.enabled)
    timings["capture"] = time.perf_counter() - start

    start = time.perf_counter()
    capture = load(capture_dir)
    result = pipeline.fit(capture, config, reporter)
    before_writing()
    fit_dir = pipeline.write_fit(out / "fit", result, config)
    timings["fit"] = time.perf_counter() - start

    start = time.perf_counter()
    metrics = evaluate_fit(load_fit(fit_dir), capture, settings=relight, reporter=reporter)
    timings["evaluate"] = time.perf_counter() - start

    start = time.perf_counter()
    report = write_report(fit_dir)
    timings["report"] = time.perf_counter() - start
    return {
        "capture": str(capture_dir),
        "capture_cached": cached,
        "fit": str(fit_dir),
        "report": str(report),
        "texture": metrics.get("texture"),
        "relighting": metrics.get("relighting"),
        "uncertainty": _headline_scores(metrics.get("uncertainty", {})),
        "timings": timings,
    }


def _headline_scores(uncertainty: dict) -> dict:
    """Pick Spearman, AUSE and AURG per error kind of the entropy and of the roughness std.

    From metrics.json's "uncertainty" (the entropy's scores at its top level, roughness_std's
    nested).
    """
    def pick(scores: dict) -> dict:
        return {kind: {key: value for key, value in result.items() if key in ("spearman", "ause", "aurg")}
                for kind, result in scores.items() if isinstance(result, dict) and "spearman" in result}
    return {"entropy": pick(uncertainty), "roughness_std": pick(uncertainty.get("roughness_std", {}))}
