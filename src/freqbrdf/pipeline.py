"""The whole job on one capture: observations -> estimate -> uncertainty -> textures; its folder.

``fit`` runs the stages in memory (``FitResult``; on coarser texels than the maps' when
``TexelConfig.estimation_res`` says so, then `to_texels`), ``write_fit`` writes the fit folder
(``export.write_fit_outputs``: EXR maps, previews, material.glb, entropy, roughness_std and flags,
spectra.npz, uncertainty.npz, summary.json with the capture's path), ``load_fit`` reads it back
for the commands that work on a fit (evaluate, report, inpaint), and ``evaluate_fit`` scores a fit
folder against its capture (texture metrics, relighting, and whether the entropy and
roughness_std rank the errors).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy import ndimage

from freqbrdf import export
from freqbrdf.capture import Capture
from freqbrdf.config import Config
from freqbrdf.errors import InputError
from freqbrdf.estimate import MaterialEstimate, estimate as estimate_materials
from freqbrdf.fileio import atomic_directory
from freqbrdf.images import read_image
from freqbrdf.materials import MaterialMaps, load_material_maps, resize
from freqbrdf.observations import Observations, observe
from freqbrdf.progress import SILENT, Reporter
from freqbrdf.relight import RelightSettings, evaluate as relight_evaluate, write_evaluation
from freqbrdf.share import share
from freqbrdf.texels import Texels, estimation_resolution as texels_estimation_resolution, rasterise
from freqbrdf.uncertainty import FLAG_UNOBSERVED, AngularEntropy, Uncertainty, entropy_map, roughness_std

EVALUATION_FOLDER = "evaluation"
SPARSIFICATION_PLOT = "sparsification.png"


@dataclass(eq=False)
class FitResult:
    capture: Capture
    observations: Observations
    estimate: MaterialEstimate
    uncertainty: Uncertainty
    maps: MaterialMaps  # hole-free (T, T, ·) textures, as exported
    timings: dict[str, float] = field(default_factory=dict)  # seconds per stage
    # The texture resolution observed and estimated on (`estimation_resolution`); below T, the
    # observations, estimate and uncertainty above are its, taken to the T x T texels (`to_texels`).
    estimation_res: int | None = None


@dataclass(eq=False)
class FitOutputs:
    """A fit folder read back."""

    folder: Path
    summary: dict
    maps: MaterialMaps  # (T, T, ·) textures
    entropy: np.ndarray | None  # (T, T) float32, dilated like the maps; None without uncertainty
    observed: np.ndarray  # (T, T) bool: texels with at least one sample
    texel_index: np.ndarray  # (N,) flat indices of the mesh's texels (spectra.npz's order)
    arrays: dict  # the per-texel arrays of spectra.npz and uncertainty.npz, (N, ...)

    @property
    def capture_path(self) -> Path | None:
        path = self.summary.get("capture")
        return None if path is None else Path(path)


def estimation_resolution(capture: Capture, config: Config = Config(), fine: Texels | None = None) -> int:
    """The texture resolution ``fit`` observes and estimates on (``TexelConfig.estimation_res``);
    ``fine``: the mesh's texels at T, when already rasterised."""
    setting, texture_res = config.texels.estimation_res, config.texels.texture_res
    if setting == "full":
        return texture_res
    if setting in ("pixel", "coarse"):
        fine = rasterise(capture.mesh, texture_res) if fine is None else fine
        centres = np.array([frame.camera.camera_to_world[:3, 3] for frame in capture.frames]).reshape(-1, 3)
        focal = np.array([0.5 * (frame.camera.fx + frame.camera.fy) for frame in capture.frames])
        return texels_estimation_resolution(fine, centres, focal, setting)
    if isinstance(setting, bool) or not isinstance(setting, int) or not 1 <= setting <= texture_res:
        raise ValueError(f"estimation_res must be 'pixel', 'coarse', 'full' or a whole number from 1 to the "
                         f"texture resolution {texture_res}, got {setting!r}")
    return setting


def observe_on_estimation_texels(capture: Capture, config: Config = Config(),
                                 reporter: Reporter = SILENT) -> tuple[Observations, Texels | None]:
    """`observe` on the texels of `estimation_resolution`; where those are coarser than T, also
    the mesh's T x T texels, to take the results there (`to_texels`, `uncertainty_to_texels`),
    else None."""
    texture_res = config.texels.texture_res
    # "pixel" and "coarse" measure the texels at T: rasterised once, and observed where they settle on T.
    fine = rasterise(capture.mesh, texture_res) if config.texels.estimation_res in ("pixel", "coarse") else None
    estimation_res = estimation_resolution(capture, config, fine)
    if estimation_res == texture_res:
        return observe(capture, config, reporter, texels=fine), None
    coarse = config.replace(texels=replace(config.texels, texture_res=estimation_res))
    return observe(capture, coarse, reporter), rasterise(capture.mesh, texture_res) if fine is None else fine


def fit(capture: Capture, config: Config = Config(), reporter: Reporter = SILENT) -> FitResult:
    """Observe, estimate, compute the uncertainty and make the textures; seconds per stage.

    The first three run on the texels of `estimation_resolution` (`observe_on_estimation_texels`);
    where those are coarser than T, the results are then taken to the T x T texels (`to_texels`)."""
    if config.fit.lmax < 1:  # checked before the work: the entropy compares degrees 1..l*
        raise ValueError(f"fit needs FitConfig.lmax >= 1 (the entropy compares degrees 1..l*), got {config.fit.lmax}")
    timings: dict[str, float] = {}
    start = time.perf_counter()
    observations, fine = observe_on_estimation_texels(capture, config, reporter)
    estimation_res = observations.texture_res
    timings["observe"] = time.perf_counter() - start
    timings.update({f"observe.{stage}": seconds for stage, seconds in observations.timings.items()
                    if stage != "total"})  # "observe" is the total

    # The angular entropy's hypotheses are probed by the estimator's search anyway: scored on the way.
    angular = AngularEntropy(observations, config) if AngularEntropy.recorded_by_search(config) else None
    start = time.perf_counter()
    estimate = estimate_materials(observations, config, reporter, angular.recorder() if angular else None)
    timings["estimate"] = time.perf_counter() - start - (angular.seconds if angular else 0.0)

    start = time.perf_counter()
    uncertainty = (angular.result() if angular else
                   entropy_map(observations, config.uncertainty, estimate_config=config.estimate))
    uncertainty.roughness_std = roughness_std(observations, estimate, config)
    timings["uncertainty"] = time.perf_counter() - start + (angular.seconds if angular else 0.0)

    if config.share.enabled:
        start = time.perf_counter()
        estimate = share(observations, estimate, uncertainty, config)
        timings["share"] = time.perf_counter() - start

    if fine is not None:
        start = time.perf_counter()
        observations, estimate, uncertainty = to_texels(observations, estimate, uncertainty, fine,
                                                        config.texels.dilation_px)
        timings["upsample"] = time.perf_counter() - start

    start = time.perf_counter()
    maps = export.material_textures(estimate, config.texels.dilation_px)
    timings["textures"] = time.perf_counter() - start
    timings["total"] = sum(seconds for stage, seconds in timings.items() if "." not in stage)
    return FitResult(capture, observations, estimate, uncertainty, maps, timings, estimation_res)


def to_texels(observations: Observations, estimate: MaterialEstimate, uncertainty: Uncertainty, fine: Texels,
              dilation_px: int) -> tuple[Observations, MaterialEstimate, Uncertainty]:
    """A fit made on coarser texels, on the texels ``fine`` of a finer T x T texture: base colour,
    roughness and metallic sampled bilinearly from the coarse estimate's hole-free textures
    (`export.material_textures`, grown by ``dilation_px`` across seams) at each fine texel's
    centre, and so is roughness_std; the rest as `uncertainty_to_texels`."""
    parent = _parent_texels(observations.texture_res, observations.texel_index, fine)
    sample = _bilinear_sampler(observations.texture_res, fine)
    fine_observations, fine_uncertainty = uncertainty_to_texels(observations, uncertainty, fine, dilation_px, parent)
    maps = export.material_textures(estimate, dilation_px)
    estimated = estimate.estimated[parent]

    def where_estimated(values):
        return np.where(estimated.reshape((-1,) + (1,) * (values.ndim - 1)), values, np.nan)

    fine_estimate = replace(
        estimate, texture_res=fine.texture_res, texel_index=fine.texel_index,
        base_color=where_estimated(np.stack([sample(maps.base_color[..., c]) for c in range(3)], axis=1)),
        roughness=where_estimated(sample(maps.roughness)), metallic=where_estimated(sample(maps.metallic)),
        estimated=estimated, loss=estimate.loss[parent],
        roughness_curvature=None if estimate.roughness_curvature is None else estimate.roughness_curvature[parent],
    )
    if uncertainty.roughness_std is not None:
        # Bilinear too, so that neighbouring fine texels are not ranked as ties; NaN (not
        # estimated) from the parent.
        spread = sample(export.roughness_std_texture(uncertainty, estimate, dilation_px)).astype(np.float32)
        fine_uncertainty.roughness_std = np.where(
            np.isfinite(uncertainty.roughness_std[parent]), spread, np.float32(np.nan))
    return fine_observations, fine_estimate, fine_uncertainty


def uncertainty_to_texels(observations: Observations, uncertainty: Uncertainty, fine: Texels, dilation_px: int,
                          parent: np.ndarray | None = None) -> tuple[Observations, Uncertainty]:
    """Observations and their uncertainty on coarser texels, on the texels ``fine`` of a finer
    T x T texture: the entropy sampled bilinearly from its hole-free texture (grown by
    ``dilation_px`` across seams) at each fine texel's centre, 1 where unobserved; everything else
    per texel (spectra, sample counts, flags, likelihood, arg-max, roughness_std) from the coarse
    texel the fine one lies in, or the nearest covered one where that one is not covered
    (``parent``, computed when not given). The observations keep no samples
    (`Observations.texel_fields`: V = 0); the coarse ``observations`` hold them."""
    if parent is None:
        parent = _parent_texels(observations.texture_res, observations.texel_index, fine)
    fine_observations = replace(observations.texel_fields(parent), texture_res=fine.texture_res,
                                texel_index=fine.texel_index)
    changes = {name: getattr(uncertainty, name)[parent]
               for name in ("flags", "likelihood", "best_alpha", "best_ks", "channel", "roughness_std")
               if getattr(uncertainty, name) is not None}
    # The entropy varies smoothly: bilinear, so that neighbouring fine texels are not ranked as ties.
    entropy_texture = export.entropy_texture(uncertainty, observations, dilation_px)
    entropy = _bilinear_sampler(observations.texture_res, fine)(entropy_texture).astype(np.float32)
    changes["entropy"] = np.where((changes["flags"] & FLAG_UNOBSERVED) != 0, uncertainty.entropy[parent], entropy)
    return fine_observations, replace(uncertainty, **changes)


def _bilinear_sampler(coarse_res: int, fine: Texels):
    """A function sampling a coarse_res x coarse_res texture bilinearly at the centres of the
    texels ``fine`` (clamped at the border): (coarse_res, coarse_res) -> (N_fine,) float64."""
    rows, columns = np.divmod(fine.texel_index, fine.texture_res)
    scale = coarse_res / fine.texture_res
    coordinates = np.stack([(rows + 0.5) * scale - 0.5, (columns + 0.5) * scale - 0.5])

    def sample(texture):
        return ndimage.map_coordinates(texture.astype(np.float64), coordinates, order=1, mode="nearest")

    return sample


def _parent_texels(coarse_res: int, coarse_index: np.ndarray, fine: Texels) -> np.ndarray:
    """(N_fine,) int64: per texel of ``fine``, the row in ``coarse_index`` (a coarse_res x coarse_res
    texture's covered texels) of the coarse texel its centre lies in, or of the nearest covered
    coarse texel where that one is not covered."""
    if len(coarse_index) == 0:
        raise ValueError("no coarse texel to take the fine texels' values from")
    lookup = np.full(coarse_res * coarse_res, -1, np.int64)
    lookup[coarse_index] = np.arange(len(coarse_index))
    lookup = lookup.reshape(coarse_res, coarse_res)
    _, (nearest_row, nearest_column) = ndimage.distance_transform_edt(lookup < 0, return_indices=True)
    rows, columns = np.divmod(fine.texel_index, fine.texture_res)
    scale = coarse_res / fine.texture_res
    coarse_rows = np.minimum(((rows + 0.5) * scale).astype(np.int64), coarse_res - 1)
    coarse_columns = np.minimum(((columns + 0.5) * scale).astype(np.int64), coarse_res - 1)
    return lookup[nearest_row[coarse_rows, coarse_columns], nearest_column[coarse_rows, coarse_columns]]


def write_fit(out_dir: str | Path, result: FitResult, config: Config = Config()) -> Path:
    """Write the fit folder (replaced as a whole, atomically); returns it."""
    start = time.perf_counter()
    capture_root = Path(result.capture.root).resolve()
    check_output_folder(out_dir, {"the capture": capture_root})
    extra = {"capture": str(capture_root), "layout": result.capture.layout,
             "estimation_res": result.estimation_res or result.estimate.texture_res,
             # The views of the capture, also where the observations were taken to finer texels
             # without their samples (`to_texels`).
             "coverage": {**export.coverage(result.observations, result.estimate),
                          "views": len(result.capture.frames)}}
    out = export.write_fit_outputs(
        out_dir, result.capture.mesh, result.observations, result.estimate, result.uncertainty,
        config, timings=result.timings, extra_summary=extra, maps=result.maps,
    )
    result.timings["write"] = time.perf_counter() - start
    # The write time is known only after the folder exists: record it in place (atomically).
    summary_path = out / export.FILES["summary"]
    summary = json.loads(summary_path.read_text(encoding="utf-8"))
    summary["timings"] = dict(result.timings)
    export.write_json(summary_path, summary)
    return out


def load_fit(fit_dir: str | Path) -> FitOutputs:
    """Read a fit folder written by `write_fit`; InputError naming what is missing or bad."""
    folder = Path(fit_dir)
    summary_path = folder / export.FILES["summary"]
    if not folder.is_dir():
        raise InputError(folder, "fit folder does not exist")
    if not summary_path.is_file():
        raise InputError(summary_path, "missing: this is not a fit folder written by `freqbrdf fit`")
    try:
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(summary_path, f"unreadable: {err}") from None
    if not isinstance(summary, dict):
        raise InputError(summary_path, "must hold a JSON object")
    maps = load_material_maps(folder)
    entropy_path = folder / export.FILES["entropy"]
    entropy = read_image(entropy_path)[..., 0] if entropy_path.is_file() else None
    arrays: dict = {}
    for name in ("spectra", "uncertainty"):
        path = folder / export.FILES[name]
        if path.is_file():
            try:
                with np.load(path) as data:
                    arrays.update({key: data[key] for key in data.files})
            except (OSError, ValueError) as err:
                raise InputError(path, f"unreadable: {err}") from None
    resolution = maps.resolution
    if "texel_index" not in arrays:
        raise InputError(folder / export.FILES["spectra"], "missing: the fit folder is incomplete")
    texel_index = arrays["texel_index"]
    if texel_index.size and (texel_index.min() < 0 or texel_index.max() >= resolution * resolution):
        raise InputError(folder / export.FILES["spectra"], f"texel indices do not fit {resolution}x{resolution} maps")
    observed = np.zeros(resolution * resolution, bool)
    if "n_samples" in arrays:
        observed[texel_index[arrays["n_samples"] > 0]] = True
    return FitOutputs(folder, summary, maps, entropy, observed.reshape(resolution, resolution),
                      texel_index, arrays)


def evaluate_fit(fit_outputs: FitOutputs, capture: Capture, out_dir: str | Path | None = None,
                 settings: RelightSettings = RelightSettings(), reporter: Reporter = SILENT) -> dict:
    """Score a fit against its capture; writes ``<fit>/evaluation`` (or ``out_dir``) as a whole.

    - texture metrics on the observed texels when the capture has ground truth;
    - relighting under the capture's test set (Stanford-ORB protocol) when it has one;
    - the uncertainty's meaning: sparsification (AUSE, AURG) and Spearman rho of the entropy and
      of roughness_std against the per-texel roughness, base-colour and metallic errors (ground
      truth needed).
    Returns the metrics document (also written as metrics.json).
    """
    out = Path(out_dir) if out_dir is not None else fit_outputs.folder / EVALUATION_FOLDER
    check_output_folder(out, {"the fit": fit_outputs.folder.resolve(), "the capture": Path(capture.root).resolve()})
    evaluation = relight_evaluate(capture, fit_outputs.maps, fit_outputs.observed, settings, reporter)
    # One folder, renamed into place when complete: a failure leaves the previous evaluation (or none).
    with atomic_directory(out) as folder:
        extra = {"fit": str(fit_outputs.folder.resolve()), "capture": str(Path(capture.root).resolve())}
        uncertainty_scores = _uncertainty_scores(fit_outputs, capture, folder)
        if uncertainty_scores is not None:
            extra["uncertainty"] = uncertainty_scores
        metrics_path = write_evaluation(folder, evaluation, extra)
        document = json.loads(metrics_path.read_text(encoding="utf-8"))  # as written (inf as null)
    return document


def check_output_folder(out_dir: str | Path, inputs: dict[str, Path]) -> None:
    """InputError if replacing ``out_dir`` as a whole would delete one of the named input folders."""
    out = Path(out_dir).resolve()
    for name, folder in inputs.items():
        if out == folder or out in folder.parents:
            raise InputError(out_dir, f"output folder would replace {name} ({folder}); choose another --out")


def _uncertainty_scores(fit_outputs: FitOutputs, capture: Capture, out: Path) -> dict | None:
    """Sparsification of the entropy (and of roughness_std when the fit has it) against the
    per-texel errors on observed texels (needs GT). The entropy's scores per error kind stay at the
    top level (as before roughness_std existed); roughness_std's are under its own key."""
    # Imported here: scipy.stats would add ~0.3 s to every `freqbrdf fit`, which never needs it.
    from freqbrdf import sparsification

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
