"""Maps of an observation for people: coverage and visibility in texture space (docs/method.md#observations).

`write_maps` draws, per texel of an `freqbrdf.observe.observations.Observations`, how many views
sample it and which fraction of the views facing it do (the visibility test of docs/method.md#observations:
neither hidden by the object itself nor on the mask's edge), as PNG figures with colour bars.
matplotlib is imported only when a map is drawn.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from freqbrdf.fileio import atomic_path
from freqbrdf.observe.observations import Observations


def write_maps(observations: Observations, folder: str | Path) -> list[Path]:
    """Write PNG maps of an Observations in texture space, with colour-bar legends.

    - ``coverage.png``: views with a sample per texel (0 .. V);
    - ``visibility.png``: the fraction of the views that face a texel (it lies in their image,
      front side towards them) in which it is sampled, i.e. neither hidden by the object itself
      nor on the mask's edge; texels facing no view are left out.

    Texels outside the mesh's charts are grey.

    Parameters
    ----------
    observations : Observations
        What to draw.
    folder : str or Path
        Where ``coverage.png`` and ``visibility.png`` are written (atomically; the folder is
        created if needed).

    Returns
    -------
    list of Path
        The two PNG files written.
    """
    folder = Path(folder)
    n_facing = observations.n_facing
    fraction = np.where(n_facing > 0, observations.n_samples / np.maximum(n_facing, 1), np.nan)
    maps = [
        ("coverage.png", observations.n_samples.astype(np.float64), "views with a sample",
         (0, observations.n_views), "viridis"),
        ("visibility.png", fraction, "sampled / facing views", (0, 1), "magma"),
    ]
    paths = []
    for name, values, label, value_range, colour_map in maps:
        texture = observations.to_texture(values.astype(np.float64), fill=np.nan)
        paths.append(folder / name)
        _write_colour_mapped(paths[-1], texture, label, value_range, colour_map)
    return paths


def _write_colour_mapped(path: Path, texture: np.ndarray, label: str, value_range, colour_map: str) -> None:
    """Write a (T, T) texture (NaN: no value, grey) as a PNG figure with a labelled colour bar."""
    from matplotlib.figure import Figure  # here: importing matplotlib is slow

    # Large enough that the texture is drawn at (at least) one screen pixel per texel.
    inches = max(4.0, texture.shape[0] / 70.0)
    figure = Figure(figsize=(1.3 * inches, 1.1 * inches), dpi=100)
    axes = figure.add_subplot()
    axes.set_facecolor("0.5")
    shown = axes.imshow(texture, cmap=colour_map, vmin=value_range[0], vmax=value_range[1],
                        interpolation="nearest")
    axes.set_xticks([])
    axes.set_yticks([])
    axes.set_title(f"{path.stem}: texture space, grey = no value")
    figure.colorbar(shown, ax=axes, label=label)
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png")
