"""The ``freqbrdf`` command line. Bad input is one clear line and exit code 2."""

from __future__ import annotations

import sys

import typer
from rich.console import Console
from rich.markup import escape

from freqbrdf import __version__
from freqbrdf.errors import InputError

app = typer.Typer(
    name="freqbrdf",
    help="Per-texel BRDF maps and their uncertainty from posed HDR photographs.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
err_console = Console(stderr=True)
_state = {"debug": False}


def _version(value: bool) -> None:
    if value:
        typer.echo(f"freqbrdf {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    debug: bool = typer.Option(False, "--debug", help="Show full tracebacks on errors."),
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True),
) -> None:
    _state["debug"] = debug


@app.command()
def demo(out: str = typer.Option("out/demo", help="Output folder.")) -> None:
    """Render the bundled capture, fit it, and write the report (not yet available)."""
    err_console.print("freqbrdf demo: not yet available (it lands with the demo issue).")
    raise typer.Exit(1)


@app.command()
def info(capture: str = typer.Argument(..., help="Capture folder or its transforms file.")) -> None:
    """Summarise a capture: views, resolution, mesh, environment map, test set, ground truth."""
    from rich.table import Table

    from freqbrdf.capture import describe, load  # here: its imports would slow every command

    table = Table(show_header=False, box=None)
    for topic, text in describe(load(capture)):
        table.add_row(f"[bold]{topic}[/bold]", escape(text))
    Console().print(table)


@app.command()
def synth(
    out: str = typer.Argument(..., help="Output folder (replaced as a whole when done)."),
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
) -> None:
    """Render a synthetic capture of a known object with Mitsuba 3 (with ground truth)."""
    from freqbrdf.synth import SynthSettings, synthesize  # imported here: it loads Mitsuba

    settings = SynthSettings(
        mesh=mesh, envmap=envmap, materials=materials, views=views, resolution=resolution,
        spp=spp, texture_res=texture_res, cameras=cameras, seed=seed,
        test_envmaps=int(test_envmaps) if test_envmaps.isdigit() else tuple(test_envmaps.split(",")),
        test_views=test_views, format=format,
    )
    path = synthesize(out, settings)
    Console().print(f"capture written to {escape(str(path))}")


@app.command()
def observe(
    capture: str = typer.Argument(..., help="Capture folder or its transforms file."),
    out: str = typer.Option(..., "--out", help="Output folder (its files are replaced one by one)."),
    texture_res: int = typer.Option(512, min=1, help="Texture resolution T (maps are T x T)."),
    lmax: int = typer.Option(5, min=0, help="Degree l* of the per-texel SH fits."),
    environment_occlusion: bool = typer.Option(
        False, help="Trace the object's occlusion of its own environment (beyond the paper)."
    ),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
) -> None:
    """Per-texel observations and SH spectra: observations.npz, coverage and visibility maps."""
    import dataclasses
    import json
    from pathlib import Path

    import numpy as np

    from freqbrdf.capture import load
    from freqbrdf.config import Config
    from freqbrdf.fileio import atomic_path
    from freqbrdf.observations import observe as observe_capture, write_maps
    from freqbrdf.progress import Reporter

    config = Config()
    config = config.replace(
        texels=dataclasses.replace(config.texels, texture_res=texture_res),
        fit=dataclasses.replace(config.fit, lmax=lmax),
        observe=dataclasses.replace(config.observe, environment_occlusion=environment_occlusion),
    )
    observations = observe_capture(load(capture), config, Reporter(enabled=not quiet))
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
        "environment_occlusion": observations.environment_occlusion,
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


def main() -> None:
    try:
        app()
    except InputError as err:
        if _state["debug"]:
            raise
        # escape: file names may contain brackets, which rich would take for markup
        err_console.print(f"[red]error:[/red] {escape(str(err))}", highlight=False, soft_wrap=True)
        sys.exit(2)


if __name__ == "__main__":
    main()
