"""The peer baseline: Mitsuba 3 inverse rendering (``freqbrdf.render.inverse.mitsuba_inverse``) of a
capture, timed, and scored against its ground-truth maps.

    python benchmarks/studies/mitsuba_inverse.py CAPTURE [--out benchmarks/results/mitsuba_inverse_<name>.json]
        [--iterations N] [--spp S] [--texture-res T] [--learning-rate LR] [--tv-weight W] ...

Prints and saves JSON (by default benchmarks/results/mitsuba_inverse_<name>.json): cpu count, seconds, settings, the loss curve and, when the capture has
ground truth (``gt/``), `freqbrdf.outputs.metrics.texture_scores` on the observed texels (texels with at
least one sample in `freqbrdf.observe.observations.observe` at the estimate's resolution): base-colour
PSNR (linear, peak 1), roughness MAE and metallic MAE, for the initial maps and at checkpoints
along the way; with test views, the Stanford-ORB relighting scores of the final maps
(`freqbrdf.outputs.relight.evaluate`). The estimated maps are written as EXR into a folder beside the
JSON (``--maps``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from pathlib import Path

import numpy as np

from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, TexelConfig
from freqbrdf.errors import InputError
from freqbrdf.fileio import atomic_path
from freqbrdf.model.materials import MaterialMaps, save_material_maps
from freqbrdf.observe.observations import observe
from freqbrdf.outputs.metrics import texture_scores
from freqbrdf.outputs.relight import RelightSettings, evaluate
from freqbrdf.render import inverse as baselines

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import RESULTS_DIR as RESULTS


def observed_texels(capture, texture_res: int) -> np.ndarray:
    """(T, T) bool: texels seen (in front, unoccluded, inside the mask) by at least one view."""
    observations = observe(capture, Config().replace(texels=TexelConfig(texture_res=texture_res)))
    observed = np.zeros(texture_res * texture_res, dtype=bool)
    observed[observations.texel_index[observations.n_samples > 0]] = True
    return observed.reshape(texture_res, texture_res)


def default_checkpoints(iterations: int) -> list[int]:
    """Powers of two below ``iterations``, and ``iterations`` itself."""
    return sorted({2**k for k in range(max(iterations, 1).bit_length())} | {iterations})


def parse_arguments(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("capture", type=Path, help="capture folder or transforms file")
    parser.add_argument("--out", type=Path,
                        help="JSON file (default: benchmarks/results/mitsuba_inverse_<capture>.json)")
    parser.add_argument("--maps", type=Path,
                        help="folder for the estimated maps (default: beside --out)")
    parser.add_argument("--texture-res", type=int, help="default: the ground truth's, else "
                        f"{baselines.DEFAULT_TEXTURE_RES}")
    parser.add_argument("--iterations", type=int, default=baselines.DEFAULT_ITERATIONS)
    parser.add_argument("--spp", type=int, default=baselines.DEFAULT_SPP)
    parser.add_argument("--learning-rate", type=float, default=baselines.DEFAULT_LEARNING_RATE)
    parser.add_argument("--tv-weight", type=float, default=baselines.DEFAULT_TV_WEIGHT)
    parser.add_argument("--views-per-step", type=int, default=1)
    parser.add_argument("--max-depth", type=int, default=baselines.DEFAULT_MAX_DEPTH,
                        help="path length; match the renderer of the photographs")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--checkpoints", type=lambda text: [int(v) for v in text.split(",")],
                        help="comma-separated iteration counts to score (default: powers of two)")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_arguments(argv)
    try:
        return run(args)
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


def run(args: argparse.Namespace) -> int:
    capture = load(args.capture)
    name = capture.root.name
    out = args.out or RESULTS / f"mitsuba_inverse_{name}.json"
    maps_folder = args.maps or out.with_name(out.stem + "_maps")
    truth = capture.ground_truth
    texture_res = args.texture_res or (
        truth.resolution if truth is not None else baselines.DEFAULT_TEXTURE_RES
    )
    settings = {
        "texture_res": texture_res,
        "iterations": args.iterations,
        "spp": args.spp,
        "learning_rate": args.learning_rate,
        "tv_weight": args.tv_weight,
        "views_per_step": args.views_per_step,
        "max_depth": args.max_depth,
        "seed": args.seed,
        "initial": {
            "base_color": baselines.INITIAL_BASE_COLOR,
            "roughness": baselines.INITIAL_ROUGHNESS,
            "metallic": baselines.INITIAL_METALLIC,
        },
    }

    snapshots = []  # (iterations, seconds, maps), scored once the run is over

    def keep(iterations: int, seconds: float, maps: MaterialMaps) -> None:
        snapshots.append((iterations, seconds, maps))

    checkpoints = args.checkpoints or default_checkpoints(args.iterations)
    maps, seconds, loss_history = baselines.mitsuba_inverse(
        capture, texture_res, args.iterations, args.spp, args.learning_rate, args.tv_weight,
        args.seed, args.views_per_step, args.max_depth, checkpoints,
        keep if truth is not None else None,
    )
    save_material_maps(maps_folder, maps)

    result = {
        "benchmark": "Mitsuba 3 inverse rendering (prb, principled BSDF, Adam)",
        "capture": str(capture.root),
        "views": len(capture.frames),
        "image_size": [capture.frames[0].camera.width, capture.frames[0].camera.height],
        "cpu_count": os.cpu_count(),
        "machine": platform.processor() or platform.machine(),
        "seconds": round(seconds, 3),
        "seconds_per_iteration": round(seconds / args.iterations, 4),
        "settings": settings,
        "loss_first_last": [float(loss_history[0]), float(loss_history[-1])],
        "loss_history": [round(float(loss), 6) for loss in loss_history],
        "maps": str(maps_folder),
    }
    if capture.test_frames:
        # Stanford-ORB scores of the estimate relit under the test views' lights.
        relight_settings = RelightSettings(max_depth=args.max_depth, seed=args.seed)
        relit = evaluate(capture, maps, settings=relight_settings)
        result["relighting"] = relit.relighting
        result["relighting_views"] = len(relit.views)
    if truth is not None:
        observed = observed_texels(capture, texture_res)
        initial = MaterialMaps(
            np.full_like(maps.base_color, baselines.INITIAL_BASE_COLOR),
            np.full_like(maps.roughness, baselines.INITIAL_ROUGHNESS),
            np.full_like(maps.metallic, baselines.INITIAL_METALLIC),
        )
        result["metrics_initial"] = texture_scores(initial, truth, observed)
        result["metrics"] = texture_scores(maps, truth, observed)
        result["curve"] = [
            {"iterations": iterations, "seconds": round(elapsed, 3),
             **texture_scores(snapshot, truth, observed)}
            for iterations, elapsed, snapshot in snapshots
        ]
        for entry in result["curve"]:
            print(json.dumps(entry))
    summary = {key: value for key, value in result.items() if key not in ("loss_history", "curve")}
    print(json.dumps(summary, indent=2))
    with atomic_path(out) as tmp:
        tmp.write_text(json.dumps(result, indent=2) + "\n")
    print(f"saved {out} and {maps_folder}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
