"""The settings of one capture of a batch: checked, made into a `Config`, hashed.

A manifest line (`freqbrdf.batch.manifest`) may set any key of `SETTINGS`: the options of
``freqbrdf fit`` of the same name (docs/method.md#pipeline), whether to score the fit (docs/method.md#evaluation) and
write its report, and the samples per pixel of the evaluation's relit renders. `parse_settings`
checks and converts them from CSV text or JSON values, `capture_config` makes the `Config` that
``freqbrdf fit`` makes from the same options, and `settings_hash` is what a capture's outputs
depend on besides its inputs (`freqbrdf.batch.state` records it).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json

from freqbrdf.config import PRESETS, Config, EstimateConfig, UncertaintyConfig, choices, preset


def _integer(minimum: int):
    def parse(value):
        if isinstance(value, str) and value.strip().isdigit():
            value = int(value.strip())
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise ValueError(f"must be a whole number >= {minimum}")
        return value
    return parse


def _boolean(value):
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text in ("true", "yes", "1", "on"):
        return True
    if text in ("false", "no", "0", "off"):
        return False
    raise ValueError("must be true or false")


def _evaluate(value):
    return "auto" if str(value).strip().lower() == "auto" else _boolean(value)


def _choice(allowed):
    def parse(value):
        if value not in allowed:
            raise ValueError(f"must be one of {', '.join(allowed)}")
        return value
    return parse


def _estimation_res(value):
    if value in ("pixel", "coarse", "full"):
        return value
    try:
        return _integer(1)(value)
    except ValueError:
        raise ValueError("must be pixel, coarse, full or a whole number >= 1") from None


# Per-capture settings: key -> (parser, default). None keeps the preset's value. They mirror the
# options of `freqbrdf fit` (and `evaluate --spp`).
SETTINGS = {
    "preset": (_choice(PRESETS), "default"),
    "texture_res": (_integer(1), None),
    "lmax": (_integer(1), None),
    "estimator": (_choice(choices(EstimateConfig)["method"]), None),
    "model": (_choice(choices(EstimateConfig)["forward_model"]), None),
    "entropy": (_choice(choices(UncertaintyConfig)["mode"]), None),
    "estimation_res": (_estimation_res, None),
    "split_half": (_boolean, False),
    "per_texel": (_boolean, False),
    "evaluate": (_evaluate, "auto"),  # auto: when the capture has ground truth or test views
    "report": (_boolean, True),
    "spp": (_integer(1), 64),  # samples per pixel of the relit renders of the evaluation
}


def parse_settings(values: dict, where: str = "") -> dict:
    """Check and convert settings given as text (CSV) or JSON values; absent keys are left out.

    Parameters
    ----------
    values : dict
        ``{key: value}`` with keys among `SETTINGS`; None and empty strings count as absent.
    where : str
        Prefix of the error message (e.g. ``"line 3: "``).

    Returns
    -------
    dict
        The settings given, converted (whole numbers, booleans, choices).

    Raises
    ------
    ValueError
        For an unknown key or a value its key does not allow, the message prefixed by ``where``.
    """
    parsed = {}
    for key, value in values.items():
        if key not in SETTINGS:
            raise ValueError(f"{where}unknown setting {key!r}; settings are {', '.join(SETTINGS)}")
        if value is None or (isinstance(value, str) and not value.strip()):
            continue
        try:
            parsed[key] = SETTINGS[key][0](value.strip() if isinstance(value, str) else value)
        except ValueError as err:
            raise ValueError(f"{where}{key} {value!r} {err}") from None
    return parsed


def capture_config(settings: dict) -> Config:
    """Make the `Config` of one capture's settings, as `freqbrdf fit` makes it from the same options.

    Parameters
    ----------
    settings : dict
        Settings as `parse_settings` returns them (absent keys: the preset's values).

    Returns
    -------
    Config
        The preset with the settings given.

    Raises
    ------
    ValueError
        Where the combination is invalid (``estimation_res`` above ``texture_res``, ``split_half``
        without ``per_texel``, or what `Config` refuses).
    """
    config = preset(settings.get("preset", "default"))
    texels = config.texels
    if settings.get("texture_res") is not None:
        texels = dataclasses.replace(texels, texture_res=settings["texture_res"])
    estimation_res = settings.get("estimation_res")
    if estimation_res is not None:
        if isinstance(estimation_res, int) and estimation_res > texels.texture_res:
            raise ValueError(f"estimation_res {estimation_res} exceeds the texture resolution {texels.texture_res}")
        texels = dataclasses.replace(texels, estimation_res=estimation_res)
    fit = config.fit if settings.get("lmax") is None else dataclasses.replace(config.fit, lmax=settings["lmax"])
    estimate = config.estimate
    if settings.get("estimator") is not None:
        estimate = dataclasses.replace(estimate, method=settings["estimator"])
    if settings.get("model") is not None:
        estimate = dataclasses.replace(estimate, forward_model=settings["model"])
    uncertainty = config.uncertainty
    if settings.get("entropy") is not None:
        uncertainty = dataclasses.replace(uncertainty, mode=settings["entropy"])
    if settings.get("split_half"):
        if not settings.get("per_texel"):
            raise ValueError("split_half scores the per-texel estimate: set per_texel too")
        uncertainty = dataclasses.replace(uncertainty, split_half=True)
    surface = dataclasses.replace(config.surface, enabled=False) if settings.get("per_texel") else config.surface
    return config.replace(texels=texels, fit=fit, estimate=estimate, uncertainty=uncertainty, surface=surface)


def full_settings(settings: dict) -> dict:
    """Fill in the defaults of `SETTINGS` for the keys a capture's settings leave out.

    Parameters
    ----------
    settings : dict
        Settings as `parse_settings` returns them.

    Returns
    -------
    dict
        Every key of `SETTINGS`, in its order: the value given, else its default (None: the
        preset's value).
    """
    return {key: settings.get(key, default) for key, (_, default) in SETTINGS.items()}


def settings_hash(settings: dict) -> str:
    """Hash what a capture's outputs depend on besides its inputs.

    That is its whole `Config` (`capture_config`) and the evaluation and report settings.

    Parameters
    ----------
    settings : dict
        Settings as `parse_settings` returns them.

    Returns
    -------
    str
        64 hexadecimal digits.
    """
    full = full_settings(settings)
    document = {"config": capture_config(settings).to_dict(),
                **{key: full[key] for key in ("evaluate", "report", "spp")}}
    return hashlib.sha256(json.dumps(document, sort_keys=True, default=str).encode()).hexdigest()
