"""Calibration from the photographs (issue #40): a real capture's imperfections, with calibration off and on.

    python benchmarks/studies/calibration.py [--scenes a,b] [--cases "a;b"] [--quick] [--views 32]

Scenes: the six of the whole-surface suite (scenes.WHOLE_SURFACE_SCENES: among them the bunny with
metal islands under an overcast sky, the sphere of gradients under the lobby map, the dragon with a
photographic material under a turned sunset, the studies that read this one's captures (`SCENES`)
take these three), rendered by Mitsuba once at 32 views of 192 x 192, 32 spp,
T = 256. Each case (`CASES`) copies the clean capture with imperfections applied
to it as a user's camera and probe have them (`imperfections.imperfect_capture`): exposure 0.25-4x,
white balance +-20 % per channel, the map turned 5-20 degrees about the up axis and 10 about
another, cameras turned 0.5-1 degree and moved 0.5-1 % of their distance, sensor noise, 8-bit
clipped sRGB data, HDR data clipped in its highlights (each also with the map turned 10 degrees, 8-bit also at 2x), masks 2 px wider or narrower than the
object (a segmentation's halo or erosion), and several at once. Each copy is fitted by `freqbrdf.pipeline.fit` with the
default settings (T = 256) with calibration off (``CalibrationConfig`` all off) and on (the
default), and scored on the texels a view sees: base-colour PSNR, roughness and metallic MAE,
dielectrics called metal; the calibration's gains against the applied ones (relative to the
clean capture's own, what the model reads as 1 there), the probe's turn left over, and the seconds
of calibration and of the fit.

Writes benchmarks/results/calibration.{json,md} (``--quick``: four cases, calibration_quick.*;
``--views N`` other than 32: the scenes rendered at N views, calibration_<N>views.*), after each
scene, merged into what is there.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from whole_surface import parameter_scores, seen_texels  # noqa: E402

import scenes  # noqa: E402
from _common import machine, save_results, source_commit  # noqa: E402
from freqbrdf import pipeline  # noqa: E402
from freqbrdf.calibrate import axis_angle, rotation_about  # noqa: E402
from freqbrdf.capture.layouts import load  # noqa: E402
from freqbrdf.config import CalibrationConfig, Config, TexelConfig  # noqa: E402
from imperfections import Imperfection, imperfect_capture  # noqa: E402

SCENES = ("bunny_islands_overcast", "sphere_gradients_lobby", "dragon_photo_side")
RENDER = {"views": 32, "resolution": 192, "spp": 32, "texture_res": 256, "test_views": 4}
QUICK_CASES = ("clean", "exposure 2", "probe 10 deg (up)", "combined (2x, wb, 10 deg, noise)")
TEXTURE_RES = 256
CASES = {
    "clean": Imperfection(),
    "exposure 0.25": Imperfection(exposure=0.25),
    "exposure 0.5": Imperfection(exposure=0.5),
    "exposure 2": Imperfection(exposure=2.0),
    "exposure 4": Imperfection(exposure=4.0),
    "white balance (1.2, 1, 0.8)": Imperfection(white_balance=(1.2, 1.0, 0.8)),
    "white balance (0.85, 1, 1.15)": Imperfection(white_balance=(0.85, 1.0, 1.15)),
    "probe 5 deg (up)": Imperfection(probe_deg=5.0),
    "probe 10 deg (up)": Imperfection(probe_deg=10.0),
    "probe 20 deg (up)": Imperfection(probe_deg=20.0),
    "probe 10 deg (tilt)": Imperfection(probe_axis=(1.0, 0.0, 0.0), probe_deg=10.0),
    "cameras 0.5 deg, 0.5 %": Imperfection(camera_deg=0.5, camera_shift=0.005),
    "cameras 1 deg, 1 %": Imperfection(camera_deg=1.0, camera_shift=0.01),
    "noise (3 % shot, 0.003 read)": Imperfection(shot_noise=0.03, read_noise=0.003),
    "8-bit sRGB": Imperfection(eight_bit=True),
    "highlights clipped (HDR at the 97th percentile)": Imperfection(highlight_clip=0.97),
    "8-bit sRGB, probe 10 deg (up)": Imperfection(eight_bit=True, probe_deg=10.0),
    "highlights clipped, probe 10 deg (up)": Imperfection(highlight_clip=0.97, probe_deg=10.0),
    "8-bit sRGB, exposure 2": Imperfection(eight_bit=True, exposure=2.0),
    "masks 2 px wider": Imperfection(mask_offset_px=2),
    "masks 2 px narrower": Imperfection(mask_offset_px=-2),
    "combined (2x, wb, 10 deg, noise)": Imperfection(exposure=2.0, white_balance=(1.1, 1.0, 0.9), probe_deg=10.0,
                                                     shot_noise=0.03, read_noise=0.003),
    "all (2x, wb, 10 deg, cameras 0.5 deg, noise)": Imperfection(
        exposure=2.0, white_balance=(1.1, 1.0, 0.9), probe_deg=10.0, camera_deg=0.5, camera_shift=0.005,
        shot_noise=0.03, read_noise=0.003),
}
OFF = CalibrationConfig(gains=False, cameras=False, probe_rotation=False, frame_gains="off")
# The bounds against the clean fit of the same scene, calibration on.
BOUNDS = {"base_color_psnr": -0.5, "roughness_mae": 0.01, "metallic_mae": 0.02, "dielectric_called_metal": 0.03}


def scores(maps, truth, seen) -> dict:
    found = parameter_scores(maps, truth, seen)
    return {key: found[key] for key in ("base_color_psnr", "roughness_mae", "metallic_mae",
                                        "dielectric_called_metal")}


def camera_turns(cameras, clean) -> np.ndarray:
    """(V,) degrees between each camera's orientation and the one the photographs were rendered with."""
    turns = []
    for camera, frame in zip(cameras, clean.frames):
        _, angle = axis_angle(camera.camera_to_world[:3, :3] @ frame.camera.camera_to_world[:3, :3].T)
        turns.append(np.degrees(angle))
    return np.array(turns)


def camera_errors(given, refined, clean) -> dict:
    """The cameras' turn and shift from the rendered poses, given and refined: median and largest."""
    found = {}
    for label, cameras in (("given", given), ("refined", refined)):
        turns = camera_turns(cameras, clean)
        shifts = np.array([np.linalg.norm(camera.center - frame.camera.center) / np.linalg.norm(frame.camera.center)
                           for camera, frame in zip(cameras, clean.frames)])
        found[label] = {"turn_deg_median": float(np.median(turns)), "turn_deg_max": float(turns.max()),
                        "shift_median": float(np.median(shifts))}
    return found


def run_case(scene: str, source: Path, name: str, imperfection: Imperfection, truth, seen, config: Config,
             clean_gain: np.ndarray | None, clean) -> dict:
    folder = imperfect_capture(source, scenes.CACHE / "calibration" / f"{source.name}_{imperfection.name()}",
                               imperfection)
    capture = load(folder)
    row = {"imperfection": dataclasses.asdict(imperfection)}
    for label, calibration in (("off", OFF), ("on", config.calibration)):
        start = time.perf_counter()
        result = pipeline.fit(capture, config.replace(calibration=calibration))
        row[label] = {"scores": scores(result.maps, truth, seen), "seconds": time.perf_counter() - start,
                      "calibrate_seconds": result.timings.get("calibrate", 0.0)}
        if label == "on":
            found = result.calibration
            applied = imperfection.exposure * np.array(imperfection.white_balance)
            reference = np.ones(3) if clean_gain is None else clean_gain
            row["gain"] = {"applied": applied.tolist(), "found": found.gain.tolist(),
                           "found_std": (found.gain * found.gain_log_std).tolist(),
                           "relative_error": (found.gain / reference / applied - 1.0).tolist()}
            turn = rotation_about(np.array(imperfection.probe_axis) / np.linalg.norm(imperfection.probe_axis),
                                  np.radians(imperfection.probe_deg))
            _, left = axis_angle(found.probe.rotation @ turn) if found.probe is not None else (None, np.nan)
            row["probe"] = {"applied_deg": imperfection.probe_deg,
                            "found_deg": None if found.probe is None else found.probe.angle_deg,
                            "std_deg": None if found.probe is None or not np.isfinite(found.probe.std_deg)
                            else found.probe.std_deg,
                            "left_deg": float(np.degrees(left))}
            row["warnings"] = list(result.warnings)
            if found.cameras is not None:
                row["cameras"] = camera_errors([frame.camera for frame in capture.frames], found.cameras.cameras, clean)
    print(f"[{scene}] {name}: off {row['off']['scores']} on {row['on']['scores']} gain "
          f"{np.round(row['gain']['found'], 3).tolist()} probe left {row['probe']['left_deg']:.2f} deg "
          f"calibrate {row['on']['calibrate_seconds']:.2f} s cameras {row.get('cameras')}", flush=True)
    return row


def run_scene(scene: str, render: dict, cases: list[str], earlier: dict | None = None, commit: str = "") -> dict:
    source = scenes.whole_surface_capture(scene, render)
    clean = load(source)
    seen = seen_texels(clean, TEXTURE_RES)
    config = Config(texels=TexelConfig(texture_res=TEXTURE_RES))
    pipeline.fit(clean, config)  # numba's first calls, outside the timings
    rows = dict(earlier or {})  # the cases not run this time are kept, each with the commit that ran it
    clean_gain = None
    for name in ["clean"] + [case for case in cases if case != "clean"]:
        rows[name] = run_case(scene, source, name, CASES[name], clean.ground_truth, seen, config, clean_gain, clean)
        rows[name]["commit"] = commit
        if name == "clean":
            clean_gain = np.array(rows[name]["gain"]["found"])
    clean_on, clean_off = rows["clean"]["on"]["scores"], rows["clean"]["off"]["scores"]
    for name, row in rows.items():
        row["cost_on"] = {key: row["on"]["scores"][key] - clean_off[key] for key in BOUNDS}
        row["within_bounds_on"] = all(
            (row["cost_on"][key] >= bound) if key == "base_color_psnr" else (row["cost_on"][key] <= bound)
            for key, bound in BOUNDS.items())
    return {"capture": str(source), "cases": rows,
            "clean_change": {key: clean_on[key] - clean_off[key] for key in BOUNDS}}


def markdown(results: dict) -> str:
    lines = ["# Calibration study", "",
             "Errors on the texels a view sees (`benchmarks/studies/calibration.py`); each cell: calibration "
             "off / on. BC: base-colour PSNR (dB), R, M: roughness and metallic MAE, D->M: dielectrics called "
             "metal. Gain: the calibration's gain over the clean capture's, against the applied one "
             "(relative error per channel). Captures: {views} views of {resolution} x {resolution}, T = {texture_res}."
             .format(**{**RENDER, **results.get("render", {}), "texture_res": TEXTURE_RES}), ""]
    for scene, found in results["scenes"].items():
        lines += [f"## {scene}", "", "| case | BC dB | R MAE | M MAE | D->M | gain error (R, G, B) | probe left (deg) "
                  "| cameras' turn (deg): given / refined, median (largest) | calibrate s | fit s (on) |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for name, row in found["cases"].items():
            off, on = row["off"]["scores"], row["on"]["scores"]
            cells = [f"{off['base_color_psnr']:.2f} / {on['base_color_psnr']:.2f}",
                     f"{off['roughness_mae']:.3f} / {on['roughness_mae']:.3f}",
                     f"{off['metallic_mae']:.3f} / {on['metallic_mae']:.3f}",
                     f"{off['dielectric_called_metal']:.1%} / {on['dielectric_called_metal']:.1%}",
                     ", ".join(f"{value:+.1%}" for value in row["gain"]["relative_error"]),
                     f"{row['probe']['left_deg']:.2f}" if row["probe"]["left_deg"] == row["probe"]["left_deg"]
                     else "-",
                     _camera_cell(row.get("cameras")),
                     f"{row['on']['calibrate_seconds']:.2f}", f"{row['on']['seconds']:.1f}"]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def _camera_cell(cameras: dict | None) -> str:
    if cameras is None:
        return "-"
    given, refined = cameras["given"], cameras["refined"]
    return (f"{given['turn_deg_median']:.2f} ({given['turn_deg_max']:.2f}) / "
            f"{refined['turn_deg_median']:.3f} ({refined['turn_deg_max']:.3f})")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default=",".join(scenes.WHOLE_SURFACE_SCENES))
    parser.add_argument("--cases", default=";".join(CASES), help="case names separated by semicolons")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--views", type=int, default=RENDER["views"],
                        help="photographs a capture (other than 32: calibration_<N>views.*)")
    args = parser.parse_args(argv)
    render = {**RENDER, "views": args.views}
    name = "calibration_quick" if args.quick else "calibration"
    if args.views != RENDER["views"]:
        name += f"_{args.views}views"
    path = Path(__file__).resolve().parents[1] / "results" / f"{name}.json"
    results = json.loads(path.read_text()) if path.is_file() else {"scenes": {}}
    results["machine"] = machine()
    results["render"] = render
    for scene in args.scenes.split(","):
        cases = list(QUICK_CASES) if args.quick else args.cases.split(";")
        earlier = results["scenes"].get(scene, {}).get("cases")
        results["scenes"][scene] = run_scene(scene, render, cases, earlier, source_commit())
        save_results(name, results)
        (path.with_suffix(".md")).write_text(markdown(results))
    return 0


def scene_study_main(argv, doc: str, name: str, study: str, run_scene, markdown) -> int:
    """Run a study of the calibration study's captures (``--scenes``): ``run_scene(scene)`` for each, saved as
    benchmarks/results/<name>.json with the machine and the commit, and ``markdown(results)`` as <name>.md."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--scenes", default=",".join(SCENES))
    args = parser.parse_args(argv)
    results = {"study": study, **machine(), "commit": source_commit(), "render": RENDER, "texture_res": TEXTURE_RES,
               "scenes": {scene: run_scene(scene) for scene in args.scenes.split(",")}}
    save_results(name, results)
    (Path(__file__).resolve().parents[1] / "results" / f"{name}.md").write_text(markdown(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
