"""Score a fit folder against its capture: texture metrics, relighting, uncertainty quality.

Implements how results are judged (docs/method.md#evaluation): parameter recovery in texture space, relighting
with the Stanford-ORB protocol (`freqbrdf.outputs.relight`), and sparsification and Spearman
correlation of the uncertainty against the per-texel errors (`freqbrdf.outputs.sparsification`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from freqbrdf.capture.layouts import GROUND_TRUTH_FOLDER, Capture
from freqbrdf.errors import InputError
from freqbrdf.fileio import atomic_directory
from freqbrdf.model.materials import resize
from freqbrdf.outputs import export
from freqbrdf.outputs.fit_folder import (
    CALIBRATION_PLOT,
    EVALUATION_FOLDER,
    SPARSIFICATION_PLOT,
    FitOutputs,
    check_output_folder,
)
from freqbrdf.outputs.relight import UNSEEN_SIDE_PICTURE, RelightSettings, unseen_side_picture, write_evaluation
from freqbrdf.outputs.relight import evaluate as relight_evaluate
from freqbrdf.progress import SILENT, Reporter
from freqbrdf.uncertainty import FLAG_UNOBSERVED


def evaluate_fit(fit_outputs: FitOutputs, capture: Capture, out_dir: str | Path | None = None,
                 settings: RelightSettings = RelightSettings(), reporter: Reporter = SILENT) -> dict:
    """Score a fit against its capture, writing ``<fit>/evaluation`` (or ``out_dir``) as a whole.

    The scores:

    - texture metrics on the observed texels when the capture has ground truth;
    - relighting under the capture's test set (Stanford-ORB protocol) when it has one;
    - the uncertainty's meaning: sparsification (AUSE, AURG) and Spearman rho of the entropy and
      of roughness_std against the per-texel roughness, base-colour and metallic errors (ground
      truth needed).

    Parameters
    ----------
    fit_outputs : FitOutputs
        The fit folder, read back (`freqbrdf.outputs.fit_folder.load_fit`).
    capture : Capture
        The capture it was fitted on.
    out_dir : str or Path, optional
        Where to write the evaluation; default ``<fit>/evaluation``. It must not contain the fit
        or the capture.
    settings : RelightSettings, optional
        Render settings of the relit views.
    reporter : Reporter, optional
        Receives progress.

    Returns
    -------
    dict
        The metrics document, as written to ``metrics.json`` (infinities as null).

    Raises
    ------
    InputError
        If ``out_dir`` would replace the fit or the capture folder, or there is nothing to score:
        no test views, and ground truth in a UV layout the fit's mesh does not have.

    Examples
    --------
    A tiny synthetic capture (with ground-truth maps and one relighting view) fitted, written,
    read back and scored; relit with 4 samples per pixel and without LPIPS, to be quick:

    >>> import tempfile
    >>> from pathlib import Path
    >>> from freqbrdf import pipeline
    >>> from freqbrdf.capture import load
    >>> from freqbrdf.config import Config, TexelConfig
    >>> from freqbrdf.outputs import RelightSettings, evaluate_fit, load_fit
    >>> from freqbrdf.synthetic import example_capture
    >>> work = tempfile.TemporaryDirectory()
    >>> capture = load(example_capture(Path(work.name) / "capture", test_views=1, test_envmaps=1))
    >>> config = Config(texels=TexelConfig(texture_res=32))
    >>> folder = pipeline.write_fit(Path(work.name) / "fit", pipeline.fit(capture, config), config)
    >>> metrics = evaluate_fit(load_fit(folder), capture, settings=RelightSettings(spp=4, lpips=False))
    >>> sorted(metrics["texture"])  # against the ground-truth maps
    ['base_color_psnr', 'metallic_mae', 'roughness_mae', 'texels']
    >>> len(metrics["views"]), sorted(metrics["relighting"])  # the test views relit (Stanford-ORB's scores)
    (1, ['lpips', 'psnr_hdr', 'psnr_ldr', 'ssim'])
    >>> metrics["relighting"]["lpips"] is None  # not computed
    True
    >>> (folder / "evaluation" / "metrics.json").is_file()
    True
    >>> work.cleanup()
    """
    out = Path(out_dir) if out_dir is not None else fit_outputs.folder / EVALUATION_FOLDER
    if capture.ground_truth_refused is not None and not capture.test_frames:
        raise InputError(Path(capture.root) / GROUND_TRUTH_FOLDER, capture.ground_truth_refused)
    check_output_folder(out, {"the fit": fit_outputs.folder.resolve(), "the capture": Path(capture.root).resolve()})
    evaluation = relight_evaluate(capture, fit_outputs.maps, fit_outputs.observed, settings, reporter)
    # One folder, renamed into place when complete: a failure leaves the previous evaluation (or none).
    with atomic_directory(out) as folder:
        extra = {"fit": str(fit_outputs.folder.resolve()), "capture": str(Path(capture.root).resolve())}
        if capture.ground_truth_refused is not None:
            extra["texture_refused"] = f"{GROUND_TRUTH_FOLDER}/: {capture.ground_truth_refused}"
        uncertainty_scores = _uncertainty_scores(fit_outputs, capture, folder)
        if uncertainty_scores is not None:
            extra["uncertainty"] = uncertainty_scores
        calibration = _std_calibration(fit_outputs, capture, folder)
        if calibration is not None:
            extra["calibration"] = calibration
        if capture.frames:
            unseen_side_picture(capture, fit_outputs.maps, folder / UNSEEN_SIDE_PICTURE, settings)
            extra["unseen_side"] = {"picture": UNSEEN_SIDE_PICTURE, "left": "ground truth" if capture.ground_truth
                                    is not None else "fit", "right": "fit" if capture.ground_truth is not None else None}
        metrics_path = write_evaluation(folder, evaluation, extra)
        document = json.loads(metrics_path.read_text(encoding="utf-8"))  # as written (inf as null)
    return document


def _uncertainty_scores(fit_outputs: FitOutputs, capture: Capture, out: Path) -> dict | None:
    """Score the sparsification of the entropy (and of roughness_std) against per-texel errors.

    On observed texels, ground truth needed (None without). The entropy's scores per error kind
    are at the top level of the result; roughness_std's are under its own key.
    """
    # Imported here: scipy.stats is slow to import, and `freqbrdf fit` never needs it.
    from freqbrdf.outputs import sparsification

    arrays = fit_outputs.arrays
    if capture.ground_truth is None or "entropy" not in arrays:
        return None
    truth = resize(capture.ground_truth, fit_outputs.maps.resolution)
    index = fit_outputs.texel_index
    observed = (arrays["flags"] & FLAG_UNOBSERVED) == 0
    # Both uncertainties on the same texels: roughness_std as exported (observed texels without an
    # estimate, whose maps are filled from neighbours, take the prior's std).
    uncertainties = {"entropy": arrays["entropy"][observed]}
    if "roughness_std" in arrays:
        uncertainties["roughness_std"] = export.roughness_std_values(arrays["roughness_std"])[observed]
    flat = index[observed]
    maps = fit_outputs.maps
    errors = {
        "roughness": np.abs(maps.roughness.ravel()[flat] - truth.roughness.ravel()[flat]),
        "base_color": np.abs(maps.base_color.reshape(-1, 3)[flat] - truth.base_color.reshape(-1, 3)[flat]).mean(axis=1),
        "metallic": np.abs(maps.metallic.ravel()[flat] - truth.metallic.ravel()[flat]),
    }
    results = {kind: {name: sparsification.sparsification(values, error) for name, error in errors.items()}
               for kind, values in uncertainties.items()}
    sparsification.plot(results, out / SPARSIFICATION_PLOT)
    scores = {kind: {name: sparsification.to_dict(result) for name, result in by_error.items()}
              for kind, by_error in results.items()}
    return {
        "error_of": "absolute per-texel error on observed texels (base colour: mean over RGB)",
        "uncertainty_of": ("the scores per error: the entropy's; under roughness_std: the estimated roughness's "
                           f"std (texels without an estimate: {export.UNESTIMATED_ROUGHNESS_STD:.3f})"),
        "plot": SPARSIFICATION_PLOT,
        **scores["entropy"],
        **({"roughness_std": scores["roughness_std"]} if "roughness_std" in scores else {}),
    }


# The multiples k of each std at which the calibration counts the texels whose error lies within k std.
CALIBRATION_MULTIPLES = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0)


def _std_calibration(fit_outputs: FitOutputs, capture: Capture, out: Path) -> dict | None:
    """Score each posterior std map against its parameter's error: the fraction within k std.

    Every texel of the atlas (observed or not); base colour per channel. A calibrated std holds
    the truth within k std for 2 Phi(k) - 1 of the texels (68 % at k = 1). None without ground
    truth or std maps.
    """
    from math import erf, sqrt

    arrays = fit_outputs.arrays
    names = [name for name in ("roughness", "metallic", "base_color") if f"{name}_std" in arrays]
    if capture.ground_truth is None or not names:
        return None
    truth = resize(capture.ground_truth, fit_outputs.maps.resolution)
    flat = fit_outputs.texel_index
    observed = (arrays["flags"] & FLAG_UNOBSERVED) == 0
    scores = {}
    for name in names:
        estimate = getattr(fit_outputs.maps, name)
        channels = 3 if name == "base_color" else 1
        error = np.abs(estimate.reshape(-1, channels)[flat] - getattr(truth, name).reshape(-1, channels)[flat])
        sigma = np.asarray(arrays[f"{name}_std"], np.float64).reshape(len(flat), -1)
        usable = np.isfinite(sigma) & np.isfinite(error)
        if not usable.any():  # e.g. a fit with no texel observed: no std to score
            continue
        within = {f"{k:g}": float(np.mean((error <= k * sigma)[usable])) for k in CALIBRATION_MULTIPLES}
        seen = usable & observed[:, None]
        unseen = usable & ~observed[:, None]
        scores[name] = {"within": within,
                        "within_1_observed": float(np.mean((error <= sigma)[seen])) if seen.any() else None,
                        "within_1_unobserved": float(np.mean((error <= sigma)[unseen])) if unseen.any() else None,
                        "texels": int(usable.any(axis=1).sum())}
    if not scores:
        return None
    ideal = {f"{k:g}": erf(k / sqrt(2.0)) for k in CALIBRATION_MULTIPLES}
    _plot_calibration(scores, ideal, out / CALIBRATION_PLOT)
    return {"of": "fraction of atlas texels whose absolute error lies within k std (base colour: per channel)",
            "ideal": ideal, "plot": CALIBRATION_PLOT, **scores}


def _plot_calibration(scores: dict, ideal: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from freqbrdf.fileio import atomic_path

    figure, axis = plt.subplots(figsize=(4.6, 3.6))
    multiples = [float(k) for k in ideal]
    axis.plot(multiples, list(ideal.values()), color="0.4", linestyle="--", label="calibrated (Gaussian)")
    for index, (name, score) in enumerate(scores.items()):
        axis.plot(multiples, list(score["within"].values()), marker="o", color=f"C{index}",
                  label=f"{name.replace('_', ' ')} std")
    axis.set_xlabel("k (multiples of the std)")
    axis.set_ylabel("fraction of texels with |error| <= k std")
    axis.set_ylim(0, 1)
    axis.set_xlim(0, max(multiples))
    axis.grid(alpha=0.3)
    axis.legend(fontsize=8, loc="lower right")
    figure.tight_layout()
    with atomic_path(path) as tmp:
        figure.savefig(tmp, dpi=110, format="png")
    plt.close(figure)
