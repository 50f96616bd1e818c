"""A fit folder read back: the maps, the entropy and the per-texel arrays ``freqbrdf fit`` wrote.

The folder's files are listed in `freqbrdf.outputs.export.FILES` (METHOD.md §3.9).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from freqbrdf.errors import InputError
from freqbrdf.images import read_image
from freqbrdf.model.materials import MaterialMaps, load_material_maps
from freqbrdf.outputs import export

EVALUATION_FOLDER = "evaluation"


SPARSIFICATION_PLOT = "sparsification.png"


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


def check_output_folder(out_dir: str | Path, inputs: dict[str, Path]) -> None:
    """InputError if replacing ``out_dir`` as a whole would delete one of the named input folders."""
    out = Path(out_dir).resolve()
    for name, folder in inputs.items():
        if out == folder or out in folder.parents:
            raise InputError(out_dir, f"output folder would replace {name} ({folder}); choose another --out")
