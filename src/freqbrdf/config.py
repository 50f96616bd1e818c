"""One typed configuration with one set of defaults, and named presets.

Every stage reads its settings from here; the CLI only overrides fields. ``preset("paper")``
reproduces the hyper-parameters of the authors' prototype for comparison.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Literal

RegulariserKind = Literal["none", "constant", "exponential"]


@dataclass(frozen=True)
class TexelConfig:
    texture_res: int = 512  # T: textures are T x T
    dilation_px: int = 8  # how far exported maps are grown across chart seams


@dataclass(frozen=True)
class FitConfig:
    """The weighted, degree-regularised SH least squares (appendix eqs. 19-20, App. B)."""

    lmax: int = 5  # l*: (l*+1)^2 = 36 coefficients
    reg_lambda: float = 1e-3  # lambda in  sum w^2 (Yc - f)^2 + lambda sum_lm e^l c_lm^2
    regulariser: RegulariserKind = "exponential"
    # Scale lambda by the texel's mean squared weight so its strength does not depend on the
    # number of views (the prototype's lambda was absolute).
    scale_lambda_with_weight: bool = True
    # Band limit: the environment is low-passed with exp(-(sigma l)^2), sigma = 1/floor(sqrt(N)),
    # and the blur is divided back out of the BRDF kernel (prototype behaviour).
    band_limit: bool = True
    attenuation_threshold: float = 0.5  # t in alpha' = sqrt(-ln t) / l*  (appendix eq. 12)


@dataclass(frozen=True)
class UncertaintyConfig:
    mode: Literal["calibrated", "paper"] = "calibrated"
    grid_res: int = 8  # R: R x R hypotheses (alpha_i = (i/(R-1))^2, k_j = j/(R-1))
    temperature: float = 1e-5  # tau of the paper's likelihood exp(-(E - min E)/tau)


@dataclass(frozen=True)
class Config:
    texels: TexelConfig = field(default_factory=TexelConfig)
    fit: FitConfig = field(default_factory=FitConfig)
    uncertainty: UncertaintyConfig = field(default_factory=UncertaintyConfig)
    seed: int = 0

    def replace(self, **sections) -> "Config":
        """Copy with whole sections or top-level fields replaced."""
        return dataclasses.replace(self, **sections)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def preset(name: str = "default") -> Config:
    """Named configurations: ``default`` (ours) and ``paper`` (the prototype's hyper-parameters)."""
    if name == "default":
        return Config()
    if name == "paper":
        return Config(
            fit=FitConfig(scale_lambda_with_weight=False),
            uncertainty=UncertaintyConfig(mode="paper", grid_res=8, temperature=1e-5),
        )
    raise ValueError(f"unknown preset {name!r}; choose 'default' or 'paper'")


PRESETS = ("default", "paper")
