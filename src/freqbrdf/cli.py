"""The ``freqbrdf`` command line: one command per stage of the pipeline, and ``batch`` for many captures.

Each command reads a capture or a fit folder, builds its `freqbrdf.config.Config` from a preset and
the options given, and writes one output folder, whole or not at all. Bad input is one clear line
and exit code 2; a write the system refuses, or running out of memory, one line and exit code 1.
The options' help texts say what each does and when to choose it; docs/results.md has the
figures behind the defaults.
"""

from __future__ import annotations

import atexit
import gc
import signal
import sys

import typer
from rich.console import Console
from rich.markup import escape

from freqbrdf import __version__
from freqbrdf.cli_options import (
    DEVICE_HELP,
    ENTROPY_HELP,
    OCCLUSION_HELP,
    calibration_from_options,
    config_from_options,
    estimation_res_from_option,
)
from freqbrdf.cli_run import (  # noqa: F401 (RERUN_VARIABLE: the tests' and scripts' name for it)
    RERUN_VARIABLE,
    _checked,
    _load_and_check,
    _results_from_cache,
    _say_backend,
    err_console,
)
from freqbrdf.errors import InputError

app = typer.Typer(
    name="freqbrdf",
    help="Per-texel BRDF maps and their uncertainty from posed HDR photographs.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
_state = {"debug": False}
# At exit, the interpreter's last garbage collection walks every object numba and Mitsuba made, for
# memory the process hands back anyway (its cost: docs/results.md#speed). Exit callbacks run
# before that collection, and frozen objects are not walked.
atexit.register(gc.freeze)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"freqbrdf {__version__}")
        raise typer.Exit()


def _output_folder(value: str | None) -> str | None:
    """--out replaced as a whole: refused before any work (see `freqbrdf.fileio.check_output_path`)."""
    if value is not None:
        from freqbrdf.fileio import check_output_path

        check_output_path(value, folder=True, replaced=True)
    return value


def _container_folder(value: str | None) -> str | None:
    """--out written into, not replaced: refused before any work when it cannot become a folder."""
    if value is not None:
        from freqbrdf.fileio import check_output_path

        check_output_path(value, folder=True)
    return value


@app.callback()
def _root(
    debug: bool = typer.Option(False, "--debug", help="Show full tracebacks on errors."),
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                 help="Print the version and exit."),
    force: bool = typer.Option(False, "--force", help="Let an --out replace an existing folder that freqbrdf did "
                               "not write (its files are lost)."),
) -> None:
    _state["debug"] = debug
    from freqbrdf.fileio import allow_replacing_foreign_folders

    allow_replacing_foreign_folders(force)


@app.command()
def demo(
    out: str = typer.Option("out/demo", "--out", help="Output folder (its capture and fit/ are written into it).",
                            callback=_container_folder),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars or messages."),
    json_output: bool = typer.Option(False, "--json", help="Print the demo's results as JSON."),
) -> None:
    """Render the bundled capture (cached), fit it, evaluate it and write the report."""
    from freqbrdf.progress import Reporter
    from freqbrdf.synthetic.demo import run_demo

    result = run_demo(out, reporter=Reporter(enabled=not (quiet or json_output)),
                      before_writing=lambda: _results_from_cache(quiet or json_output))
    if json_output:
        _print_json(result)
    elif not quiet:
        texture, relit = result["texture"] or {}, result["relighting"] or {}
        seconds = ", ".join(f"{step} {value:.0f} s" for step, value in result["timings"].items())
        Console().print(escape(
            f"base colour PSNR {texture.get('base_color_psnr', float('nan')):.2f} dB, roughness MAE "
            f"{texture.get('roughness_mae', float('nan')):.3f}; relighting PSNR-H "
            f"{relit.get('psnr_hdr', float('nan')):.2f} dB ({seconds})"
        ))
        Console().print(f"report: [bold]{escape(result['report'])}[/bold]")


@app.command()
def report(
    fit_dir: str = typer.Argument(..., metavar="FIT", help="Folder written by `freqbrdf fit`."),
    out: str = typer.Option(None, "--out", help="Output folder (default: FIT/report).", callback=_output_folder),
    quiet: bool = typer.Option(False, "--quiet", help="No messages."),
) -> None:
    """Write report.html (maps, entropy, spectra, evaluation, 3D view); opens from disk, no network."""
    from freqbrdf.outputs.report import write_report

    path = write_report(fit_dir, out)
    if not quiet:
        Console().print(f"report: {escape(str(path))}")


@app.command()
def info(capture: str = typer.Argument(..., help="Capture folder or its transforms file.")) -> None:
    """Summarise a capture: views, resolution, mesh, environment map, test set, ground truth."""
    from rich.table import Table

    from freqbrdf.capture.layouts import describe  # here: its imports would slow every command

    loaded, check, warning_lines = _load_and_check(capture, None)
    table = Table(show_header=False, box=None)
    for topic, text in describe(loaded):
        table.add_row(f"[bold]{topic}[/bold]", escape(text))
    figures = check.figures
    overlap = "no masks" if figures["mask_overlap"] is None else f"{figures['mask_overlap']:.0%} of it inside the masks"
    exposure = figures["exposure_range"]
    table.add_row("[bold]check[/bold]", escape(
        f"the mesh in front of the cameras in {1 - figures['behind']:.0%} of the views, up to "
        f"{figures['pixels']:.0f} px wide, {overlap}; {figures['black_frames']} black frames"))
    table.add_row("", escape(
        f"a point of the mesh is seen by {figures['views_per_point']['median']:.0f} views (median, up to "
        f"{figures['views_per_point']['most']}); object radiance per frame "
        + ("n/a" if exposure is None else f"{exposure[0]:.2g}-{exposure[1]:.2g}x the median")
        + f"; {figures['duplicate_poses']} repeated poses, {figures['ldr_frames']} LDR frames in HDR files"))
    for warning in check.warnings:
        table.add_row("[bold yellow]warning[/bold yellow]", escape(warning))
    Console().print(table)


@app.command()
def synth(
    out: str = typer.Argument(..., help="Output folder (replaced as a whole when done).", callback=_output_folder),
    mesh: str = typer.Option("bunny", help="Bundled mesh (plane, sphere, bunny) or a mesh file."),
    envmap: str = typer.Option("forest", help="Bundled environment map name or an EXR/HDR file."),
    materials: str = typer.Option("bands", help="Bundled material set or a material folder."),
    views: int = typer.Option(32, help="Number of training views."),
    resolution: int = typer.Option(256, help="Image width and height in pixels."),
    spp: int = typer.Option(64, help="Samples per pixel."),
    texture_res: int = typer.Option(512, help="Ground-truth texture resolution."),
    cameras: str = typer.Option("hemisphere", help="hemisphere, sphere (Fibonacci) or random."),
    seed: int = typer.Option(0, help="Seed of random cameras, test maps and render noise."),
    test_envmaps: str = typer.Option("2", help="Test maps: names/paths 'A,B', or a count K."),
    test_views: int = typer.Option(8, help="Number of test (relighting) views."),
    format: str = typer.Option("ours", help="ours, or orb (the Stanford-ORB layout)."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars or messages."),
) -> None:
    """Render a synthetic capture of a known object with Mitsuba 3 (with ground truth)."""
    from freqbrdf.synthetic.synth import (  # imported here: it loads Mitsuba
        SynthSettings,
        synthesize,
    )

    settings = SynthSettings(
        mesh=mesh, envmap=envmap, materials=materials, views=views, resolution=resolution,
        spp=spp, texture_res=texture_res, cameras=cameras, seed=seed,
        test_envmaps=int(test_envmaps) if test_envmaps.isdigit() else tuple(test_envmaps.split(",")),
        test_views=test_views, format=format,
    )
    path = synthesize(out, settings, progress=not quiet)
    if not quiet:
        Console().print(f"capture written to {escape(str(path))}")


@app.command()
def observe(
    capture: str = typer.Argument(..., help="Capture folder or its transforms file."),
    out: str = typer.Option(
        ..., "--out", help="Output folder (its files are replaced one by one).", callback=_container_folder,
    ),
    texture_res: int = typer.Option(512, min=1, help="Texture resolution T (maps are T x T)."),
    lmax: int = typer.Option(5, min=0, help="Degree l* of the per-texel SH fits."),
    occlusion: bool = typer.Option(None, "--environment-occlusion/--no-environment-occlusion", help=OCCLUSION_HELP),
    device: str = typer.Option("auto", "--device", help=DEVICE_HELP),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
) -> None:
    """Observe a capture: per-texel samples and SH spectra (observations.npz), coverage and visibility maps.

    For inspecting what the views give each texel; `fit` observes by itself. Every texel of T is observed.
    """
    import json
    from pathlib import Path

    import numpy as np

    from freqbrdf.fileio import atomic_path
    from freqbrdf.observe.maps import write_maps
    from freqbrdf.observe.observations import observe as observe_capture
    from freqbrdf.progress import Reporter

    config = config_from_options("default", texture_res, lmax, device=device, environment_occlusion=occlusion)
    loaded, _ = _checked(capture, quiet, config.fit.lmax, out)
    _say_backend(device, quiet)
    observations = observe_capture(loaded, config, Reporter(enabled=not quiet))
    _results_from_cache(quiet)
    folder = Path(out)
    observations.save(folder / "observations.npz")
    maps = write_maps(observations, folder)
    summary = {
        "capture": capture,
        "texture_res": observations.texture_res,
        "texels": observations.n_texels,
        "views": observations.n_views,
        "texels_with_samples": int((observations.n_samples > 0).sum()),
        "median_samples_per_texel": float(np.median(observations.n_samples)),
        "config": config.to_dict(),
        "timings_s": {stage: round(seconds, 4) for stage, seconds in observations.timings.items()},
    }
    with atomic_path(folder / "observations.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    if not quiet:
        written = ", ".join(path.name for path in [folder / "observations.npz", *maps])
        Console().print(
            f"{summary['texels_with_samples']} of {summary['texels']} texels observed "
            f"(median {summary['median_samples_per_texel']:g} of {summary['views']} views); "
            f"wrote {escape(written)}, observations.json to {escape(str(folder))}"
        )


def _print_json(document: dict) -> None:
    import json

    typer.echo(json.dumps(document, indent=2, default=str))


@app.command()
def fit(
    capture: str = typer.Argument(..., help="Capture folder or its transforms file."),
    out: str = typer.Option(
        ..., "--out", help="Output folder (replaced as a whole when done).", callback=_output_folder,
    ),
    texture_res: int = typer.Option(None, min=1, help="Texture resolution T (default 512)."),
    lmax: int = typer.Option(
        None, min=1, help="Degree l* of the per-texel SH fits (default 5; the entropy needs >= 1).",
    ),
    estimator: str = typer.Option(None, help="global (ours, default) or paper (the prototype's Adam, to compare "
                                  "with the paper)."),
    model: str = typer.Option(None, help="Forward model of `paper`: angular (the most accurate), sh_coeffs or "
                              "spectrum."),
    preset: str = typer.Option("default", help="default; fast (estimated on texels at least a pixel wide, no "
                               "robust pass, a coarser roughness grid: smoother maps, less time); or paper (the "
                               "prototype's hyper-parameters)."),
    entropy: str = typer.Option(None, help=ENTROPY_HELP),
    per_texel: bool = typer.Option(
        False, "--per-texel", help="Keep each texel's own estimate (no whole-surface solve): the ablation of the "
        "default, which weighs every texel's evidence against its neighbours' and fills texels no view sees."),
    neighbour_vote: bool = typer.Option(
        True, "--neighbour-vote/--no-neighbour-vote", help="Let a texel whose data fit two roughness values "
        "about equally take the one nearer its neighbours' (a likelihood-ratio test keeps what the data decide)."),
    estimation_res: str = typer.Option(
        None, help="Texture resolution to observe and estimate on before the maps are sampled up to T: pixel "
        "(the coarsest whose texels are no wider than a pixel of the closest view), coarse (the finest whose "
        "texels are at least a pixel wide), full (T, the per-texel recipe of docs/method.md#texels) or a number. Default: the "
        "preset's (pixel; fast: coarse; paper: full)."),
    split_half: bool = typer.Option(
        False, "--split-half", help="With --per-texel: add to roughness_std the scatter between two more "
        "estimates, from the even and from the odd views alone: it ranks the roughness errors better, for a large "
        "share of the fit's time again (docs/results.md#the-roughness-std)."),
    occlusion: bool = typer.Option(None, "--environment-occlusion/--no-environment-occlusion", help=OCCLUSION_HELP),
    calibration: str = typer.Option(
        "auto", "--calibration", help="What the photographs calibrate before the fit: auto (exposure and white "
        "balance, the cameras' poses against the masks, the environment map's turn), gains (exposure and white balance only) or none (the photographs "
        "and the map share one scale and frame, as given)."),
    frame_gains: bool = typer.Option(
        False, "--frame-gains", help="Also measure and apply a relative gain per photograph (photographs at other "
        "shutter speeds or with auto-exposure)."),
    drop_bad_views: bool = typer.Option(
        False, "--drop-bad-views", help="Leave out photographs whose outline refining does not bring onto their mask "
        "(--calibration auto) or, with --frame-gains, whose gain is more than 2x the others' (they are named in a "
        "warning either way)."),
    calibrate_std: bool = typer.Option(
        True, "--calibrate-std/--no-calibrate-std", help="Widen the roughness and base-colour std maps where views "
        "held out of the fit (4 folds, up to 2000 texels) and the samples' misfit show them too narrow for this "
        "capture (docs/method.md#held-out-std-calibration)."),
    trust_std: float = typer.Option(
        None, "--trust-std", min=1e-6, max=1.0, help="The largest std (roughness, metallic, the base "
        "colour's mean over RGB) a texel may have to be trusted in trust.exr and the report (default 0.2)."),
    device: str = typer.Option("auto", "--device", help=DEVICE_HELP),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars or messages."),
    json_output: bool = typer.Option(False, "--json", help="Print summary.json to stdout."),
) -> None:
    """Estimate base colour, roughness and metallic maps and their uncertainty; write EXR, glTF, PNG."""
    import dataclasses
    import json
    from pathlib import Path

    from freqbrdf import pipeline
    from freqbrdf.progress import Reporter

    config = config_from_options(preset, texture_res, lmax, estimator=estimator, model=model, entropy=entropy,
                                 device=device, environment_occlusion=occlusion)
    if per_texel:
        config = config.replace(surface=dataclasses.replace(config.surface, enabled=False))
    if split_half:
        if not per_texel:
            raise typer.BadParameter("--split-half scores the per-texel estimate: add --per-texel (the default "
                                     "whole-surface estimate has its own roughness std)")
        config = config.replace(uncertainty=dataclasses.replace(config.uncertainty, split_half=True))
    if trust_std is not None:
        config = config.replace(uncertainty=dataclasses.replace(config.uncertainty, trust_std=trust_std))
    if not calibrate_std:
        config = config.replace(uncertainty=dataclasses.replace(config.uncertainty, heldout_folds=0))
    if estimation_res is not None:
        config = config.replace(texels=dataclasses.replace(config.texels, estimation_res=estimation_res_from_option(
            estimation_res, config.texels.texture_res)))
    # The flag only takes away from what the preset sets.
    config = config.replace(estimate=dataclasses.replace(
        config.estimate, neighbour_vote=config.estimate.neighbour_vote and neighbour_vote))
    config = config.replace(calibration=calibration_from_options(config.calibration, calibration, frame_gains,
                                                                 drop_bad_views))
    reporter = Reporter(enabled=not (quiet or json_output))
    loaded, capture_warnings = _checked(capture, quiet or json_output, config.fit.lmax, out)
    _say_backend(device, quiet or json_output)
    result = pipeline.fit(loaded, config, reporter)
    if not (quiet or json_output):
        for line in result.warnings:
            Console(stderr=True).print(f"[yellow]warning:[/yellow] {escape(line)}", highlight=False, soft_wrap=True)
        if result.calibration is not None and config.calibration.enabled:
            Console().print(escape(result.calibration.summary_line()), soft_wrap=True)
    result.warnings = capture_warnings + result.warnings
    _results_from_cache(quiet or json_output)
    folder = pipeline.write_fit(out, result, config)
    summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    if json_output:
        _print_json(summary)
    elif not quiet:
        coverage = summary["coverage"]
        Console().print(
            f"fit written to {escape(str(Path(out)))}: {coverage['observed_fraction']:.0%} of texels "
            f"observed, mean entropy {summary['uncertainty']['entropy_mean']:.2f}, "
            f"{result.timings['total']:.1f} s"
            + (f" (estimated on {result.estimation_res} x {result.estimation_res} texels)"
               if result.estimation_res < coverage["texture_res"] else "")
            + (f"; {summary['trust']['trusted_fraction']:.0%} of the surface trusted (every std <= "
               f"{summary['trust']['threshold']:g}: trust.exr)" if "trust" in summary else "")
            + (f"; {summary['lens']['frames']} photographs read through their lens's distortion"
               if summary.get("lens") else ""),
            soft_wrap=True,  # no line break inside a path
        )


# Why `freqbrdf uncertainty` has no roughness_std (its summary and message say so).
ROUGHNESS_STD_NEEDS_FIT = "it is the spread of the material estimate, which this command does not make; run `freqbrdf fit`"


@app.command()
def uncertainty(
    capture: str = typer.Argument(..., help="Capture folder or its transforms file."),
    out: str = typer.Option(
        ..., "--out", help="Output folder (replaced as a whole when done).", callback=_output_folder,
    ),
    texture_res: int = typer.Option(None, min=1, help="Texture resolution T (default 512)."),
    lmax: int = typer.Option(
        None, min=1, help="Degree l* of the per-texel SH fits (default 5; the entropy needs >= 1).",
    ),
    preset: str = typer.Option("default", help="default (calibrated entropy), fast (as default here) or paper."),
    entropy: str = typer.Option(None, help=ENTROPY_HELP),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars or messages."),
    device: str = typer.Option("auto", "--device", help=DEVICE_HELP),
    json_output: bool = typer.Option(False, "--json", help="Print the summary as JSON to stdout."),
) -> None:
    """Compute the entropy map without a material estimate (so no roughness std): entropy, flags, summary."""
    import time

    from freqbrdf import pipeline
    from freqbrdf.fileio import atomic_directory, write_json
    from freqbrdf.images import write_png
    from freqbrdf.outputs import export
    from freqbrdf.progress import Reporter
    from freqbrdf.uncertainty import entropy_map
    from freqbrdf.uncertainty import summary as uncertainty_summary

    config = config_from_options(preset, texture_res, lmax, entropy=entropy, device=device)
    loaded, _ = _checked(capture, quiet or json_output, config.fit.lmax, out)
    _say_backend(device, quiet or json_output)
    start = time.perf_counter()
    # Calibrated and on the texels `fit` would estimate on, so that the two entropy maps agree.
    from freqbrdf.calibrate import calibrate

    loaded, calibration = calibrate(loaded, config)
    observations, fine = pipeline.observe_on_estimation_texels(
        loaded, config, Reporter(enabled=not (quiet or json_output)))
    estimation_res = observations.texture_res
    observe_seconds = time.perf_counter() - start
    start = time.perf_counter()
    result = entropy_map(observations, config.uncertainty, return_likelihood=False, estimate_config=config.estimate,
                         device=config.device)
    if fine is not None:
        observations, result = pipeline.uncertainty_to_texels(observations, result, fine, config.texels.dilation_px)
    seconds = time.perf_counter() - start
    _results_from_cache(quiet or json_output)
    summary = {
        "capture": str(loaded.root.resolve()),
        "uncertainty": uncertainty_summary(result),
        "timings": {"observe": observe_seconds,
                    **{f"observe.{stage}": value for stage, value in observations.timings.items()
                       if stage != "total"},
                    "uncertainty": seconds},
        "settings": config.to_dict(),
        "calibration": calibration.to_dict(),
        "estimation_res": estimation_res,
        "entropy_png": {"colormap": export.ENTROPY_COLORMAP, "range": list(export.ENTROPY_RANGE)},
        "not_computed": {"roughness_std": ROUGHNESS_STD_NEEDS_FIT},
    }
    atlas = observations.mask()
    entropy = observations.to_texture(result.entropy.astype("float32"), fill=0.0)
    with atomic_directory(out) as folder:
        export.write_scalar_map(folder / export.FILES["entropy"], entropy,
                                description=export.entropy_description(result.mode))
        export.write_scalar_map(folder / export.FILES["entropy_png"], entropy, export.ENTROPY_COLORMAP,
                                export.ENTROPY_RANGE)
        write_png(folder / export.FILES["flags_png"],
                         export.flags_picture(observations.to_texture(result.flags, fill=0), atlas))
        write_json(folder / "uncertainty.json", summary)
    if json_output:
        _print_json(summary)
    elif not quiet:
        Console().print(
            f"mean entropy {summary['uncertainty']['entropy_mean']:.2f} over "
            f"{summary['uncertainty']['observed_texels']} observed texels ({seconds * 1000:.0f} ms); "
            f"wrote {escape(str(out))}", soft_wrap=True
        )
        Console().print(f"roughness_std not computed: {escape(ROUGHNESS_STD_NEEDS_FIT)}", soft_wrap=True)


@app.command()
def evaluate(
    fit_dir: str = typer.Argument(..., metavar="FIT", help="Folder written by `freqbrdf fit`."),
    capture: str = typer.Option(None, "--capture", help="Capture to score against (default: the fit's)."),
    out: str = typer.Option(
        None, "--out", help="Output folder, replaced as a whole (default: FIT/evaluation).", callback=_output_folder,
    ),
    spp: int = typer.Option(64, min=1, help="Samples per pixel of the relit renders."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars or messages."),
    json_output: bool = typer.Option(False, "--json", help="Print metrics.json to stdout."),
) -> None:
    """Score a fit: texture metrics vs ground truth, Stanford-ORB relighting scores, AUSE/AURG of the uncertainty."""
    from freqbrdf.capture.layouts import load
    from freqbrdf.outputs.evaluate import evaluate_fit
    from freqbrdf.outputs.fit_folder import load_fit
    from freqbrdf.outputs.relight import RelightSettings
    from freqbrdf.progress import Reporter

    outputs = load_fit(fit_dir)
    capture_path = capture or outputs.capture_path
    if capture_path is None:
        raise InputError(outputs.folder / "summary.json", "names no capture: pass --capture")
    document = evaluate_fit(outputs, load(capture_path), out, RelightSettings(spp=spp),
                                     Reporter(enabled=not (quiet or json_output)))
    if json_output:
        _print_json(document)
    elif not quiet:
        lines = []
        if document.get("texture_refused"):
            lines.append(f"texture: not compared ({document['texture_refused']})")
        if document.get("texture"):
            t = document["texture"]
            lines.append(f"texture: base colour PSNR {_figure(t['base_color_psnr'], '.2f')} dB, roughness MAE "
                         f"{_figure(t['roughness_mae'], '.3f')}, metallic MAE {_figure(t['metallic_mae'], '.3f')}")
        if document["views"]:
            r = document["relighting"]
            lines.append(f"relighting ({len(document['views'])} views): PSNR-H {_figure(r['psnr_hdr'], '.2f')}, "
                         f"PSNR-L {_figure(r['psnr_ldr'], '.2f')}, SSIM {_figure(r['ssim'], '.3f')}")
        if "uncertainty" in document:
            scored = {"entropy": document["uncertainty"].get("roughness"),
                      "roughness std": document["uncertainty"].get("roughness_std", {}).get("roughness")}
            for name, u in scored.items():
                if u:
                    lines.append(f"{name} vs roughness error: Spearman {_figure(u['spearman'], '.2f')}, AUSE "
                                 f"{_figure(u['ause'], '.3f')}, AURG {_figure(u['aurg'], '.3f')}")
        for line in lines:
            Console().print(escape(line), soft_wrap=True)


def _figure(value: float | None, spec: str) -> str:
    """Format a metric for a person; n/a where there was nothing to measure (e.g. no texel observed)."""
    return "n/a" if value is None else format(value, spec)


@app.command()
def inpaint(
    fit_dir: str = typer.Argument(..., metavar="FIT", help="Folder written by `freqbrdf fit`."),
    out: str = typer.Option(
        ..., "--out", help="Output folder (replaced as a whole when done).", callback=_output_folder,
    ),
    threshold: float = typer.Option(
        None, min=0.0, max=1.0, help="Fill observed texels with entropy >= H (default: texels flagged unobserved or ambiguous)."),
    maps: str = typer.Option("base_color,roughness,metallic", help="Maps to fill, comma-separated."),
    model: str = typer.Option(
        None, help="Local diffusers inpainting pipeline folder (needs the diffusion extra: pip install -e '.\\[diffusion]'); default: biharmonic."),
    prompt: str = typer.Option(None, help="Diffusion prompt."),
    steps: int = typer.Option(25, min=1, help="Diffusion denoising steps."),
    capture: str = typer.Option(None, "--capture", help="Capture with the mesh (default: the fit's)."),
    quiet: bool = typer.Option(False, "--quiet", help="No messages."),
) -> None:
    """Fill the uncertain texels of a fit's maps from confident ones, chart by chart; EXR, PNG, glTF."""
    import json

    from freqbrdf.applications.inpaint import MAP_NAMES, InpaintSettings
    from freqbrdf.pipeline import inpaint_fit

    names = tuple(name.strip() for name in maps.split(",") if name.strip())
    if not names or set(names) - set(MAP_NAMES):
        raise typer.BadParameter(f"--maps takes names among {', '.join(MAP_NAMES)}; got {maps!r}")
    settings = InpaintSettings(threshold=threshold, maps=names, backend="diffusion" if model else "biharmonic",
                               model=model, steps=steps,
                               **({} if prompt is None else {"prompt": prompt}))
    folder = inpaint_fit(fit_dir, out, settings, capture)
    if not quiet:
        summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
        Console().print(escape(
            f"filled {summary['masked_texels']} texels ({summary['masked_fraction']:.1%} of the atlas, "
            f"{summary['charts']} charts) in {summary['seconds']:.1f} s; wrote {folder}"
        ))


@app.command("next-views")
def next_views(
    capture: str = typer.Argument(..., help="Capture folder or its transforms file."),
    out: str = typer.Option(
        ..., "--out", help="Output folder (replaced as a whole when done).", callback=_output_folder,
    ),
    candidates: str = typer.Option(None, "--candidates", help="Transforms file of candidate cameras."),
    sample: int = typer.Option(None, "--sample", min=1, help="Or: N candidates evenly spread around the object."),
    hemisphere: bool = typer.Option(False, "--hemisphere", help="Sampled candidates above the object only (+y)."),
    budget: int = typer.Option(..., "--budget", min=1, help="How many views to choose."),
    texture_res: int = typer.Option(None, min=1, help="Texture resolution T (default 512)."),
    max_texels: int = typer.Option(8192, min=1, help="Texels scored (a seeded random subset)."),
    fit_out: str = typer.Option(
        None, "--fit-out", help="Also write the capture's fit (as `freqbrdf fit` does, calibration included) to this "
        "folder; the picks then reuse its observations and whole-surface solve.", callback=_output_folder),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars or messages."),
) -> None:
    """Choose the next photographs by the expected drop of the posterior std: next_views.json and a picture."""
    import dataclasses
    import time
    from pathlib import Path

    import numpy as np

    from freqbrdf import pipeline
    from freqbrdf.applications import candidates as candidate_views
    from freqbrdf.applications import guidance
    from freqbrdf.applications import next_views as next_views_folder
    from freqbrdf.progress import Reporter

    if (candidates is None) == (sample is None):
        raise typer.BadParameter("give exactly one of --candidates FILE and --sample N")
    if fit_out is not None and Path(fit_out).resolve() == Path(out).resolve():
        raise typer.BadParameter("--fit-out must be another folder than --out")
    config = config_from_options("default", texture_res)
    loaded, capture_warnings = _checked(capture, quiet, config.fit.lmax, out)
    if fit_out is not None:
        from freqbrdf.outputs.fit_folder import check_output_folder

        check_output_folder(fit_out, {"the capture": loaded.root.resolve()})
    if candidates is not None:
        cameras = candidate_views.load_candidates(candidates, loaded)
        source = candidates
    else:
        cameras = candidate_views.sample_candidates(loaded, sample, hemisphere)
        source = f"{sample} sampled on the {'hemisphere' if hemisphere else 'sphere'}"
    taken = candidate_views.view_directions(loaded, [frame.camera for frame in loaded.frames])
    competing = sum(float(np.max(taken @ direction)) < guidance.TAKEN_COSINE
                    for direction in candidate_views.view_directions(loaded, cameras))
    if budget > competing:
        raise InputError(candidates, f"--budget {budget} exceeds the {competing} candidate cameras ({source}) "
                                     "away from the views taken")
    start = time.perf_counter()
    reporter = Reporter(enabled=not quiet)
    if fit_out is not None:  # one observation for the fit and the picks
        result = pipeline.fit(loaded, config, reporter, keep_surface_fit=True)
        result.warnings = capture_warnings + result.warnings
        pipeline.write_fit(fit_out, result, config)
        estimation_res = result.estimation_res
        picks = pipeline.next_views(result, cameras, budget, config, max_texels=max_texels, reporter=reporter)
    else:
        # Scored on the texels `fit` would estimate on (observing every texel of T costs more, for
        # the same --max-texels scored).
        estimation_res = pipeline.estimation_resolution(loaded, config)
        scoring = config.replace(texels=dataclasses.replace(config.texels, texture_res=estimation_res))
        picks = guidance.select_views(loaded, cameras, budget, scoring, max_texels=max_texels, reporter=reporter)
    _results_from_cache(quiet)
    summary = {
        "capture": str(loaded.root.resolve()),
        "candidates": source,
        "n_candidates": len(cameras),
        "budget": budget,
        "max_texels": max_texels,
        "mean_std_before": picks[0].uncertainty_before,
        "picks": [{"rank": p.rank, "candidate": p.candidate, "expected_mean_std": p.expected_uncertainty,
                   "expected_gain": p.expected_gain, "unseen_area": p.unseen_area,
                   "texels_seen": p.texels_seen, "seconds": p.seconds} for p in picks],
        "seconds": time.perf_counter() - start,
        "settings": config.to_dict(),
        "estimation_res": estimation_res,
        **({"fit": str(Path(fit_out).resolve())} if fit_out is not None else {}),
    }
    next_views_folder.write_next_views(out, loaded, picks, summary, cameras)
    if not quiet:
        Console().print(escape(
            f"mean posterior std {picks[0].uncertainty_before:.4f} -> {picks[-1].expected_uncertainty:.4f} "
            f"(expected) with "
            f"{budget} of {len(cameras)} candidates in {summary['seconds']:.1f} s; wrote {out}"
        ))


@app.command()
def batch(
    manifest: str = typer.Argument(..., help="CSV or JSON Lines file (a capture a line: name, capture, settings) "
                                   "or a folder of captures."),
    out: str = typer.Option(..., "--out", help="Output folder: <name>/ per capture, batch.json, index.html.",
                            callback=_container_folder),
    workers: int = typer.Option(None, "--workers", min=1, help="Captures at once (default: as many as this "
                                "machine's cores give --threads each and its memory holds; on a cluster, its CPUs)."),
    threads: int = typer.Option(None, "--threads", min=1, help="CPUs (numba threads) per capture (default 2, or "
                                "the cores shared among --workers)."),
    address: str = typer.Option(None, "--address", help="Join this Ray cluster (auto, HOST:6379, ray://HOST:10001) "
                                "instead of starting Ray here; its nodes need the captures and --out at the same paths."),
    force: bool = typer.Option(False, "--force", help="Redo captures whose outputs are up to date."),
    preset: str = typer.Option(None, help="Preset of captures whose line sets none (default, fast, paper)."),
    texture_res: int = typer.Option(None, min=1, help="T of captures whose line sets none (default 512)."),
    lmax: int = typer.Option(None, min=1, help="l* of captures whose line sets none (default 5)."),
    evaluate: bool = typer.Option(None, "--evaluate/--no-evaluate", help="Score captures whose line does not say "
                                  "(default: those with ground truth or test views)."),
    report: bool = typer.Option(None, "--report/--no-report", help="Write each capture's report (default: yes)."),
    spp: int = typer.Option(None, min=1, help="Samples per pixel of the evaluation's relit renders (default 64)."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar or messages."),
    json_output: bool = typer.Option(False, "--json", help="Print batch.json to stdout at the end."),
) -> None:
    """Fit many captures on Ray, resumably: OUT/<name>/, batch.json, index.html. Exit 1 if a capture failed, 130 on Ctrl-C."""
    import json
    from pathlib import Path

    from freqbrdf.batch import BATCH_FILE, BatchInterrupted
    from freqbrdf.batch import run as run_batch
    from freqbrdf.progress import Reporter

    given = {"preset": preset, "texture_res": texture_res, "lmax": lmax, "evaluate": evaluate, "report": report,
             "spp": spp}
    try:
        summary = run_batch(manifest, out, workers=workers, threads=threads, address=address, force=force,
                            defaults={key: value for key, value in given.items() if value is not None},
                            reporter=Reporter(enabled=not (quiet or json_output)))
    except BatchInterrupted as interrupted:
        if json_output:
            _print_json(interrupted.summary)
        elif not quiet:
            err_console.print(f"interrupted: completed captures kept; run again to go on "
                              f"({escape(str(Path(out) / BATCH_FILE))})", highlight=False, soft_wrap=True)
        _state["interrupt_said"] = True
        raise typer.Exit(128 + interrupted.signal_number) from None
    except KeyboardInterrupt:  # before any capture started
        raise typer.Exit(130) from None
    if json_output:
        typer.echo(json.dumps(summary, indent=2, default=str))
    if summary["counts"].get("failed"):
        raise typer.Exit(1)


def _terminate(signal_number: int, frame) -> None:
    """Stop on SIGTERM as on Ctrl-C: unwinding removes the outputs in progress."""
    raise SystemExit(128 + signal_number)


def main() -> None:
    """Run the command line: bad input is one line and exit code 2, a refused write or no memory exit code 1.

    ``--debug`` shows the traceback instead. Ctrl-C is exit code 130 and SIGTERM 143, each after the
    outputs in progress are removed (the previous ones stay as they were).
    """
    signal.signal(signal.SIGTERM, _terminate)
    try:
        code = app(standalone_mode=False)  # typer's own error panels replaced by one line below
        sys.exit(code if isinstance(code, int) else 0)
    except typer.TyperException as err:  # a misspelt command or option, a value out of range
        if _state["debug"]:
            raise
        context = getattr(err, "ctx", None)
        if type(err).__name__ == "NoArgsIsHelpError":  # a bare command group: its help
            err.show()
            sys.exit(err.exit_code)
        see = "" if context is None else f" (see {escape(context.command_path)} --help)"
        err_console.print(f"[red]error:[/red] {escape(err.format_message())}{see}", highlight=False, soft_wrap=True)
        sys.exit(err.exit_code)
    except typer.Abort:  # end of input at a prompt
        sys.exit(130)
    except SystemExit as stop:
        if stop.code in (130, 143) and not _state.get("interrupt_said"):  # typer makes Ctrl-C exit 130
            err_console.print("interrupted: the outputs in progress were removed, earlier ones are unchanged",
                              highlight=False)
        raise
    except InputError as err:
        if _state["debug"]:
            raise
        # escape: file names may contain brackets, which rich would take for markup
        err_console.print(f"[red]error:[/red] {escape(str(err))}", highlight=False, soft_wrap=True)
        sys.exit(2)
    except OSError as err:  # the system refused a read or write: no space, no permission, no such folder
        if _state["debug"] or err.strerror is None:
            raise
        where = err.filename if err.filename is not None else "input/output"
        err_console.print(f"[red]error:[/red] {escape(f'{where}: {err.strerror}')}", highlight=False, soft_wrap=True)
        sys.exit(1)
    except MemoryError as err:  # e.g. a --texture-res far beyond this machine's memory
        if _state["debug"]:
            raise
        err_console.print(f"[red]error:[/red] out of memory ({escape(str(err) or 'MemoryError')}); a smaller "
                          "--texture-res (or --max-texels, --sample) needs less", highlight=False, soft_wrap=True)
        sys.exit(1)


if __name__ == "__main__":
    main()
