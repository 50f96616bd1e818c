"""The inpainting application of the uncertainty (issue #8), measured on Mitsuba-rendered captures.

    python benchmarks/studies/applications.py [--applications inpaint]
        [--scenes bunny_forest,...] [--texture-res 128] [--pool 100] [--sparse-views 20]

Capture guidance is measured by studies/guidance.py (issue #28).

Re-measuring after a change to the entropy, the estimator or an application is this one line (the
renders are cached).

One function per application; each returns its results, which are saved as JSON (and a plot) in
benchmarks/results/applications_<application>.{json,png}.

Scenes (scenes.APPLICATION_SCENES): bundled meshes, materials and environment maps, each rendered
once by Mitsuba as a pool of ``--pool`` views evenly spread (Fibonacci) over the whole sphere
around the object, 128 x 128 pixels at 16 spp, with 8 relighting views under two other maps,
cached in benchmarks/.cache/applications_<scene>_<pool> (scenes.application_capture).

inpaint works on one fit per scene of its first ``--sparse-views`` farthest-point views (sparse,
so that uncertain texels are common), errors measured per texel against the ground truth: masks from the flags (the command's default) and from entropy thresholds; per mask
  either every map is filled ("all maps") or, on observed texels, only roughness and metallic
  ("specular"; the entropy is about the specular lobe); MAE on the masked texels before and after,
  and relighting (`relight.evaluate`, Stanford-ORB scores, 32 spp) of the fit and of each result.
Every results file records the commit and which source files differed from it. ``--entropy
angular`` (or paper) runs inpaint with that entropy mode, saved beside the default's as
applications_<application>_<mode>.{json,png}.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from freqbrdf.applications.candidates import farthest_point_views, view_directions
from freqbrdf.applications.inpaint import biharmonic_fill, inpaint_maps, inpaint_mask
from freqbrdf.capture.layouts import Capture, load
from freqbrdf.config import Config, TexelConfig, UncertaintyConfig
from freqbrdf.fileio import atomic_path, write_json
from freqbrdf.model.materials import MaterialMaps, resize
from freqbrdf.outputs.relight import RelightSettings
from freqbrdf.outputs.relight import evaluate as relight_evaluate
from freqbrdf.pipeline import FitResult, fit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import RESULTS_DIR as RESULTS
from _common import machine
from scenes import APPLICATION_SCENES, APPLICATION_TEST_VIEWS, application_capture

APPLICATIONS = ("inpaint",)


def scene_capture(name: str, pool: int) -> Capture:
    """The scene's pool of views, rendered once (cached)."""
    return load(application_capture(name, pool))


def source_state() -> dict:
    """What was measured: the package's folder, a hash of its sources, and (in a git checkout) the
    commit and the source files that differ from it (others may be mid-change)."""
    import freqbrdf

    package = Path(freqbrdf.__file__).parent
    digest = hashlib.sha256()
    for path in sorted(package.glob("*.py")):
        digest.update(path.read_bytes())

    def git(*arguments):
        return subprocess.run(["git", *arguments], cwd=package, capture_output=True, text=True).stdout

    return {"package": str(package), "sources_sha256": digest.hexdigest()[:16],
            "commit": git("rev-parse", "HEAD").strip() or None,
            "modified": [line[3:] for line in git("status", "--porcelain", "--", ".").splitlines()]}


def with_views(capture: Capture, views: list[int]) -> Capture:
    return dataclasses.replace(capture, frames=tuple(capture.frames[view] for view in views))


# --------------------------------------------------------------------------------------------
# Inpainting: one sparse fit per scene (the first --sparse-views farthest-point views
# of the pool, where uncertainty is common).

PARAMETERS = ("roughness", "metallic", "base_color")
# Relighting renders: the test views at the pool's resolution; LPIPS left out (it needs weights
# that are not always installed, and PSNR/SSIM already show a change).
RELIGHT = RelightSettings(spp=32, lpips=False)
_sparse_fits: dict = {}


def sparse_fit(name: str, args) -> tuple[FitResult, np.ndarray, Config]:
    """The scene's fit on its first ``args.sparse_views`` farthest-point views, and the ground
    truth per texel (N, 5: base colour RGB, roughness, metallic) in the fit's texel order."""
    key = (name, args.pool, args.sparse_views, args.texture_res, args.entropy)
    if key not in _sparse_fits:
        pool = scene_capture(name, args.pool)
        config = Config(texels=TexelConfig(texture_res=args.texture_res),
                        uncertainty=UncertaintyConfig(mode=args.entropy))
        directions = view_directions(pool, [frame.camera for frame in pool.frames])
        result = fit(with_views(pool, farthest_point_views(directions, args.sparse_views)), config)
        truth = resize(pool.ground_truth, args.texture_res)
        index = result.observations.texel_index
        truth_params = np.column_stack([truth.base_color.reshape(-1, 3)[index], truth.roughness.ravel()[index],
                                        truth.metallic.ravel()[index]])
        _sparse_fits[key] = (result, truth_params, config)
    return _sparse_fits[key]


def parameter_errors(params: np.ndarray, truth: np.ndarray, rows: np.ndarray) -> dict:
    """MAE of roughness, metallic and base colour (mean over RGB) on ``rows``; None when empty."""
    if len(rows) == 0:
        return dict.fromkeys(PARAMETERS)
    error = np.abs(params[rows] - truth[rows])
    return {"roughness": float(error[:, 3].mean()), "metallic": float(error[:, 4].mean()),
            "base_color": float(error[:, :3].mean())}


def estimate_params(estimate) -> np.ndarray:
    """(N, 5) base colour RGB, roughness, metallic of a MaterialEstimate."""
    return np.column_stack([estimate.base_color, estimate.roughness, estimate.metallic]).astype(np.float64)


def inpaint_scene(name: str, args) -> dict:
    result, truth, _ = sparse_fit(name, args)
    observations, uncertainty = result.observations, result.uncertainty
    atlas = observations.mask()
    index = observations.texel_index
    observed = observations.n_samples > 0
    capture = result.capture

    def relighting(maps: MaterialMaps) -> dict:
        scores = relight_evaluate(capture, maps, settings=RELIGHT).relighting
        return {key: scores[key] for key in ("psnr_hdr", "psnr_ldr", "ssim")}

    def texel_params(maps: MaterialMaps) -> np.ndarray:
        return np.column_stack([maps.base_color.reshape(-1, 3)[index], maps.roughness.ravel()[index],
                                maps.metallic.ravel()[index]]).astype(np.float64)

    before = texel_params(result.maps)
    unobserved_mask = np.zeros(atlas.size, bool)
    unobserved_mask[index[~observed]] = True
    unobserved_mask = unobserved_mask.reshape(atlas.shape)
    masks = {}
    for threshold in [None, *args.inpaint_entropies]:
        mask = inpaint_mask(atlas, index, uncertainty.flags, uncertainty.entropy, threshold)
        masked = mask.ravel()[index]
        # "all maps": every map filled on the whole mask. "specular": the entropy is about the
        # specular lobe, so observed texels keep their base colour; unobserved ones get every map.
        for maps_filled in ("all maps", "specular"):
            label = ("flags" if threshold is None else f"entropy>={threshold:g}") + f", {maps_filled}"
            start = time.perf_counter()
            if maps_filled == "all maps":
                filled = inpaint_maps(result.maps, atlas, mask, biharmonic_fill)
            else:
                filled = inpaint_maps(result.maps, atlas, mask, biharmonic_fill, names=("roughness", "metallic"))
                filled = inpaint_maps(filled.maps, atlas, mask & unobserved_mask, biharmonic_fill,
                                      names=("base_color",))
            seconds = time.perf_counter() - start
            after = texel_params(filled.maps)
            masks[label] = {
                "masked_texels": int(masked.sum()),
                "masked_observed_texels": int((masked & observed).sum()),
                "masked_fraction": float(masked.mean()),
                "seconds": seconds,
                "masked_observed_before": parameter_errors(before, truth, np.flatnonzero(masked & observed)),
                "masked_observed_after": parameter_errors(after, truth, np.flatnonzero(masked & observed)),
                "masked_unobserved_before": parameter_errors(before, truth, np.flatnonzero(masked & ~observed)),
                "masked_unobserved_after": parameter_errors(after, truth, np.flatnonzero(masked & ~observed)),
                "relighting": relighting(filled.maps),
            }
            print(f"[{name}] inpaint {label}: {json.dumps(masks[label])}", flush=True)
    return {"fit_seconds": result.timings["total"], "fit_relighting": relighting(result.maps), "masks": masks}


def plot_inpaint(scenes: dict, path: Path) -> None:
    """Relighting PSNR-H of the fit and of each inpainting mask, per scene."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=(3.6 * len(scenes), 3.2), dpi=100, layout="constrained")
    axes = figure.subplots(1, len(scenes), squeeze=False)[0]
    for ax, (name, scene) in zip(axes, scenes.items()):
        labels = ["fit", *scene["masks"]]
        values = [scene["fit_relighting"]["psnr_hdr"]] + [m["relighting"]["psnr_hdr"] for m in scene["masks"].values()]
        ax.bar(np.arange(len(labels)), values, color=["C0"] + ["C3"] * (len(labels) - 1))
        ax.set_ylim(min(values) - 1.0, max(values) + 0.5)
        ax.set_xticks(np.arange(len(labels)), labels, fontsize=7, rotation=30, ha="right")
        ax.set_title(name)
        ax.set_ylabel("relighting PSNR-H (dB)")
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png")



def inpaint_benchmark(args) -> dict:
    scenes = {name: inpaint_scene(name, args) for name in args.scenes}
    plot_inpaint(scenes, RESULTS / f"applications_inpaint{args.suffix}.png")
    return {"application": "inpainting uncertain regions (issue #8)", **sparse_settings(args),
            "relight": dataclasses.asdict(RELIGHT), "scenes": scenes}


def sparse_settings(args) -> dict:
    return {**machine(), "entropy_mode": args.entropy, "texture_res": args.texture_res, "pool": args.pool,
            "views": args.sparse_views, "views_chosen": "farthest-point",
            "test_views": APPLICATION_TEST_VIEWS}


# --------------------------------------------------------------------------------------------


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--applications", default=",".join(APPLICATIONS))
    parser.add_argument("--scenes", default=",".join(APPLICATION_SCENES))
    parser.add_argument("--texture-res", type=int, default=128)
    parser.add_argument("--pool", type=int, default=100)
    parser.add_argument("--sparse-views", type=int, default=20, help="views of the inpaint fits")
    parser.add_argument("--inpaint-entropies", default="0.3", help="entropy thresholds besides the flags")
    parser.add_argument("--entropy", default="calibrated", choices=("calibrated", "paper", "angular"),
                        help="the inpaint fits' entropy mode; results other than calibrated's are "
                             "saved as applications_<application>_<mode>.{json,png}")
    args = parser.parse_args(argv)
    args.suffix = "" if args.entropy == "calibrated" else f"_{args.entropy}"
    args.scenes = args.scenes.split(",")
    args.inpaint_entropies = [float(value) for value in args.inpaint_entropies.split(",") if value]
    runners = {"inpaint": inpaint_benchmark}
    RESULTS.mkdir(exist_ok=True)
    for application in args.applications.split(","):
        start = time.perf_counter()
        results = runners[application](args)
        results["seconds"] = time.perf_counter() - start
        results["source"] = source_state()
        write_json(RESULTS / f"applications_{application}{args.suffix}.json", results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
