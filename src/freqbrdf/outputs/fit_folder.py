"""A fit folder read back: the maps, the entropy and the per-texel arrays ``freqbrdf fit`` wrote.

The folder's files are listed in `freqbrdf.outputs.export.FILES` (docs/method.md#outputs).
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
CALIBRATION_PLOT = "calibration.png"  # the std maps' calibration, in the evaluation folder


@dataclass(eq=False)
class FitOutputs:
    """A fit folder read back.

    Attributes
    ----------
    folder : Path
        The fit folder.
    summary : dict
        Its ``summary.json``.
    maps : MaterialMaps
        The material textures, T x T.
    entropy : (T, T) float32 or None
        The entropy texture, dilated like the maps; None for a fit without uncertainty.
    observed : (T, T) bool
        Texels with at least one sample.
    texel_index : (N,) int64
        Flat indices of the mesh's texels (the order of spectra.npz and uncertainty.npz).
    arrays : dict of str to array
        The per-texel arrays of spectra.npz and uncertainty.npz, (N, ...) each.
    trust : (T, T) bool or None
        The trust mask (trust.exr); None for a fit without std maps.
    """

    folder: Path
    summary: dict
    maps: MaterialMaps
    entropy: np.ndarray | None
    observed: np.ndarray
    texel_index: np.ndarray
    arrays: dict
    trust: np.ndarray | None = None

    @property
    def capture_path(self) -> Path | None:
        """The capture the fit was made from, as recorded in ``summary.json``; None if unknown."""
        path = self.summary.get("capture")
        return None if path is None else Path(path)


def load_fit(fit_dir: str | Path) -> FitOutputs:
    """Read a fit folder written by ``freqbrdf fit`` (`freqbrdf.pipeline.write_fit`).

    Parameters
    ----------
    fit_dir : str or Path
        The fit folder.

    Returns
    -------
    FitOutputs
        Its maps, entropy, observed texels and per-texel arrays.

    Raises
    ------
    InputError
        Naming what is missing or unreadable (summary.json, the maps, spectra.npz, ...).
    """
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
    trust_path = folder / export.FILES["trust"]
    trust = read_image(trust_path)[..., 0] > 0.5 if trust_path.is_file() else None
    return FitOutputs(folder, summary, maps, entropy, observed.reshape(resolution, resolution),
                      texel_index, arrays, trust)


def check_output_folder(out_dir: str | Path, inputs: dict[str, Path]) -> None:
    """Refuse an output folder whose replacement would delete an input folder.

    Parameters
    ----------
    out_dir : str or Path
        The output folder, to be replaced as a whole.
    inputs : dict of str to Path
        Input folders (resolved), by the name the error message gives them, e.g. "the fit".

    Raises
    ------
    InputError
        If ``out_dir`` is one of the inputs or contains one.
    """
    out = Path(out_dir).resolve()
    for name, folder in inputs.items():
        if out == folder or out in folder.parents:
            raise InputError(out_dir, f"output folder would replace {name} ({folder}); choose another --out")
