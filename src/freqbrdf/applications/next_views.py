"""The ``next_views`` folder of capture guidance: ranked cameras, a picture, a summary (docs/method.md#guidance).

`write_next_views` writes the views `freqbrdf.applications.guidance.select_views` picked
(docs/method.md#guidance) as a transforms file of the capture format (`NEXT_VIEWS_FILE`), which loads as a
capture once the photographs are taken, together with `plot_views`' 3D picture of the mesh, the
capture's cameras, the candidates and the picks (`PICTURE_FILE`) and a JSON summary
(`SUMMARY_FILE`). matplotlib is imported only when a picture is drawn.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from freqbrdf.applications.guidance import Pick
from freqbrdf.capture.camera import Camera
from freqbrdf.capture.camera_layouts import bounding_sphere
from freqbrdf.capture.layouts import Capture

NEXT_VIEWS_FILE = "next_views.json"  # the chosen cameras, ranked, as a transforms file
PICTURE_FILE = "next_views.png"
SUMMARY_FILE = "guidance.json"


def write_next_views(out_dir: str | Path, capture: Capture, picks: Sequence[Pick], summary: dict,
                     candidates: Sequence[Camera] = ()) -> Path:
    """Write the ranked cameras, a picture of them and a summary to a folder.

    The folder is written atomically and replaced as a whole. ``next_views.json``
    (`NEXT_VIEWS_FILE`) is a transforms file of the capture format naming the capture's mesh and
    light: once the photographs are saved as its ``images/next_<rank>.exr`` it loads with
    `freqbrdf.capture.layouts.load` (alone, or merged into the capture's own transforms).
    ``next_views.png`` (`PICTURE_FILE`) is `plot_views`' picture, ``guidance.json``
    (`SUMMARY_FILE`) the summary.

    Parameters
    ----------
    out_dir : str or Path
        The folder.
    capture : Capture
        Its mesh, environment map (with its scale) and cameras.
    picks : sequence of Pick
        The chosen views (`select_views`).
    summary : dict
        Written as ``guidance.json``.
    candidates : sequence of Camera
        Drawn as dots in the picture, if given.

    Returns
    -------
    Path
        ``out_dir``.

    Examples
    --------
    The two views `select_views` picks among twelve around a tiny synthetic capture, written as
    ``freqbrdf next-views`` writes them:

    >>> import json
    >>> import tempfile
    >>> from pathlib import Path
    >>> from freqbrdf.applications import sample_candidates, select_views, write_next_views
    >>> from freqbrdf.capture import load
    >>> from freqbrdf.config import Config, TexelConfig
    >>> from freqbrdf.synthetic import example_capture
    >>> work = tempfile.TemporaryDirectory()
    >>> capture = load(example_capture(Path(work.name) / "capture"))
    >>> candidates = sample_candidates(capture, 12)
    >>> picks = select_views(capture, candidates, 2, Config(texels=TexelConfig(texture_res=32)))
    >>> folder = write_next_views(Path(work.name) / "next", capture, picks, {"budget": 2}, candidates)
    >>> sorted(path.name for path in folder.iterdir())
    ['.freqbrdf', 'guidance.json', 'next_views.json', 'next_views.png']
    >>> frames = json.loads((folder / "next_views.json").read_text())["frames"]
    >>> [frame["file_path"] for frame in frames]  # where the new photographs go
    ['images/next_000.exr', 'images/next_001.exr']
    >>> sorted(frames[0])
    ['candidate', 'decided_by', 'expected_gain', 'expected_mean_std', 'file_path', 'rank', 'transform_matrix',
     'unseen_area']
    >>> work.cleanup()
    """
    from freqbrdf.capture.layouts import Frame
    from freqbrdf.capture.transforms_file import write_transforms
    from freqbrdf.fileio import atomic_directory, write_json
    from freqbrdf.sphere.envmap import load_envmap

    # The capture holds its light with envmap_scale applied; recover the scale for the file.
    stored = load_envmap(capture.envmap_path, capture.envmap.to_world).radiance
    envmap_scale = float(capture.envmap.radiance.sum() / stored.sum()) if stored.sum() > 0 else 1.0
    with atomic_directory(out_dir) as folder:
        frames = [Frame(pick.camera, folder / "images" / f"next_{pick.rank:03d}.exr") for pick in picks]
        fields = [{"rank": pick.rank, "candidate": pick.candidate, "expected_mean_std": pick.expected_uncertainty,
                   "expected_gain": pick.expected_gain, "unseen_area": pick.unseen_area,
                   "decided_by": pick.decided_by} for pick in picks]
        write_transforms(folder / NEXT_VIEWS_FILE, frames, mesh=capture.mesh.path, envmap=capture.envmap_path,
                         envmap_to_world=capture.envmap.to_world, envmap_scale=envmap_scale, frame_fields=fields)
        plot_views(folder / PICTURE_FILE, capture, picks, candidates)
        write_json(folder / SUMMARY_FILE, summary)
    return Path(out_dir)


def plot_views(path: str | Path, capture: Capture, picks: Sequence[Pick], candidates: Sequence[Camera] = ()) -> None:
    """Draw a 3D picture of the views: the mesh, the capture's cameras, the candidates and the picks.

    The capture's cameras are grey frusta, the candidates dots, the picks coloured frusta
    numbered by rank, each labelled with its expected gain: the drop of the mean posterior std and
    the share of the area without data it covers, and whether the spread of views decided it
    (``Pick.decided_by``). World +y is drawn up.

    Parameters
    ----------
    path : str or Path
        The PNG file to write (atomically).
    capture : Capture
        Its mesh and cameras.
    picks : sequence of Pick
        The chosen views.
    candidates : sequence of Camera
        Drawn as dots, if given.
    """
    from matplotlib import colormaps
    from matplotlib.figure import Figure  # here: importing matplotlib is slow

    from freqbrdf.fileio import atomic_path

    def drawn(points):  # world (x, y, z) -> plot (x, -z, y): a rotation that puts +y up
        points = np.asarray(points)
        return points[..., 0], -points[..., 2], points[..., 1]

    mesh = capture.mesh
    centre, radius = bounding_sphere(mesh.vertices)
    figure = Figure(figsize=(8, 8), dpi=100)
    axes = figure.add_subplot(projection="3d")
    faces = mesh.faces
    if len(faces) > 4000:  # enough for the silhouette; matplotlib sorts every polygon
        faces = faces[np.random.default_rng(0).choice(len(faces), 4000, replace=False)]
    x, y, z = drawn(mesh.vertices)
    axes.plot_trisurf(x, y, z, triangles=faces, color="0.75", edgecolor="none", alpha=0.6)
    cameras = [frame.camera for frame in capture.frames]
    if candidates:
        axes.scatter(*drawn(np.stack([camera.center for camera in candidates])), s=4, color="0.5",
                     label="candidates")
    colours = colormaps["plasma"](np.linspace(0.0, 0.85, max(len(picks), 1)))
    depth = 0.35 * radius
    for index, camera in enumerate(cameras):
        _draw_frustum(axes, drawn, camera, depth, "0.4", "capture views" if index == 0 else None, 0.8)
    for pick, colour in zip(picks, colours):
        label = (f"{pick.rank + 1}: std -{pick.expected_gain:.4f}, unseen area seen {pick.unseen_area:.1%}"
                 + (" (spread: gains within a refit's scatter)" if pick.decided_by == "spread" else ""))
        _draw_frustum(axes, drawn, pick.camera, depth, colour, label, 2.5)
        axes.text(*drawn(pick.camera.center), str(pick.rank + 1), color=colour, fontsize=11, weight="bold")
    extent = max(np.linalg.norm(camera.center - centre) for camera in cameras + [p.camera for p in picks])
    for setter, middle in zip((axes.set_xlim, axes.set_ylim, axes.set_zlim), drawn(centre)):
        setter(middle - extent, middle + extent)
    axes.set_box_aspect((1, 1, 1))
    axes.set_axis_off()
    axes.legend(loc="upper left", fontsize=8)
    axes.set_title("next views by the expected drop of the mean posterior std (1 = first)")
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png")


def _draw_frustum(axes, drawn, camera: Camera, depth: float, colour, label: str | None, width: float) -> None:
    """Draw the camera's pyramid to ``depth`` along its axis, its image corners as the base."""
    corners_px = np.array([[0, 0], [camera.width, 0], [camera.width, camera.height], [0, camera.height]], float)
    local = np.stack([(corners_px[:, 0] - camera.cx) / camera.fx, -(corners_px[:, 1] - camera.cy) / camera.fy,
                      -np.ones(4)], axis=1) * depth  # OpenGL camera looks down -z
    corners = local @ camera.camera_to_world[:3, :3].T + camera.center
    apex = camera.center
    lines = [np.stack([apex, corner]) for corner in corners] + [np.stack([corners[k], corners[(k + 1) % 4]])
                                                                  for k in range(4)]
    for number, line in enumerate(lines):
        axes.plot(*drawn(line), color=colour, linewidth=width, label=label if number == 0 else None)
