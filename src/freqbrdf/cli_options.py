"""The command line's options turned into a `freqbrdf.config.Config`, each checked before any work.

A preset (`freqbrdf.config.PRESETS`) with the options a user gave on top; an unknown name or a
combination that cannot work is a `typer.BadParameter`, one line and exit code 2 (docs/method.md#data for
what the settings mean). The help texts shared by several commands live here too.
"""

from __future__ import annotations

import typer


def config_from_options(preset: str, texture_res: int | None = None, lmax: int | None = None, *,
            estimator: str | None = None, model: str | None = None,
            entropy: str | None = None, device: str = "auto", environment_occlusion: bool | None = None):
    """Build the preset's Config with the options the user gave (None: keep the preset's value).

    The device is resolved here, before any work (summary.json records the backend that ran).
    """
    import dataclasses

    from freqbrdf.config import PRESETS
    from freqbrdf.config import preset as named_preset

    if preset not in PRESETS:
        raise typer.BadParameter(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
    config = named_preset(preset)
    texels = dataclasses.replace(config.texels, **({} if texture_res is None else {"texture_res": texture_res}))
    fit_settings = dataclasses.replace(config.fit, **({} if lmax is None else {"lmax": lmax}))
    estimate_changes = option_choices(config.estimate, {"method": ("estimator", estimator),
                                                  "forward_model": ("model", model)})
    uncertainty_changes = option_choices(config.uncertainty, {"mode": ("entropy mode", entropy)})
    estimate = dataclasses.replace(config.estimate, **estimate_changes)
    if estimate.method == "global" and estimate.forward_model != "angular":  # checked before any work
        raise typer.BadParameter(f"--model {estimate.forward_model} is a forward model of the paper's estimator: "
                                 "add --estimator paper (the global estimator searches the angular model)")
    from freqbrdf.devices import resolve_device

    try:
        backend = resolve_device(device)
    except ValueError as err:
        raise typer.BadParameter(str(err)) from err
    observe_settings = dataclasses.replace(
        config.observe, **({} if environment_occlusion is None else {"environment_occlusion": environment_occlusion}))
    return config.replace(texels=texels, fit=fit_settings, estimate=estimate, device=backend, observe=observe_settings,
                          uncertainty=dataclasses.replace(config.uncertainty, **uncertainty_changes))


def option_choices(settings, options: dict[str, tuple[str, str | None]]) -> dict:
    """Return the changes to ``settings`` that the given options make, each checked against the field's choices.

    ``options`` maps a field to (the option's name, its value or None if not given); the choices are
    `freqbrdf.config.choices`'.
    """
    from freqbrdf.config import choices

    allowed = choices(type(settings))
    changes = {}
    for name, (label, value) in options.items():
        if value is not None:
            if value not in allowed[name]:
                raise typer.BadParameter(f"unknown {label} {value!r}; choose {', '.join(allowed[name])}")
            changes[name] = value
    return changes


def estimation_res_from_option(value: str, texture_res: int):
    """Parse --estimation-res as TexelConfig.estimation_res: "pixel", "coarse", "full" or a number from 1 to T."""
    if value in ("pixel", "coarse", "full"):
        return value
    if not value.isdigit() or not 1 <= int(value) <= texture_res:
        raise typer.BadParameter(f"--estimation-res must be pixel, coarse, full or a number from 1 to the "
                                 f"texture resolution {texture_res}, got {value!r}")
    return int(value)


OCCLUSION_HELP = ("Correct the light each texel receives where the object hides its own environment (shadow rays "
                  "to the sun and lamps, cosine rays and rays around each view's mirror direction that see the object "
                  "itself). Default: the preset's (on; paper: off). docs/results.md#environment-occlusion")
DEVICE_HELP = ("Where the SH fits, the search and the entropy run: cpu, cuda (pip install 'freqbrdf\\[gpu]' and an "
               "NVIDIA GPU) or auto (cuda when both are there, else cpu).")
ENTROPY_HELP = ("Entropy mode: calibrated (from the spectra, fast; what next-views predicts and what "
                "inpainting is tuned on), paper (the published recipe, to compare with it) or angular (the "
                "estimator's model on the samples: agrees with a path tracer; little extra time inside fit). "
                "Default: the preset's. Figures: docs/results.md#the-entropy.")


CALIBRATION_CHOICES = ("auto", "gains", "none")
"""The values of ``fit --calibration``."""


def calibration_from_options(settings, calibration: str, frame_gains: bool, drop_bad_views: bool):
    """Build the `freqbrdf.config.CalibrationConfig` of ``fit``'s calibration options, checked before any work.

    ``auto``: exposure and white balance, the cameras' poses and the map's turn; ``gains``:
    exposure and white balance only; ``none``: nothing. ``frame_gains`` adds a gain per photograph;
    ``drop_bad_views`` leaves out photographs far from the others (by their gains, with
    ``frame_gains``) or whose outline refining does not bring onto their mask.
    """
    import dataclasses

    if calibration not in CALIBRATION_CHOICES:
        raise typer.BadParameter(f"--calibration must be one of {', '.join(CALIBRATION_CHOICES)}; got {calibration!r}")
    if drop_bad_views and calibration != "auto" and not frame_gains:
        raise typer.BadParameter("--drop-bad-views finds bad views by their outline (--calibration auto) or their "
                                 "gains (--frame-gains)")
    chosen = {"auto": {"gains": True, "cameras": True, "probe_rotation": True},
              "gains": {"gains": True, "cameras": False, "probe_rotation": False},
              "none": {"gains": False, "cameras": False, "probe_rotation": False}}[calibration]
    return dataclasses.replace(settings, drop_bad_views=drop_bad_views, frame_gains="on" if frame_gains else "off",
                               **chosen)
