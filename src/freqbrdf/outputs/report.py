"""``report.html``: one self-contained folder a person opens from disk to see a fit.

It shows the outputs of docs/method.md#outputs and, once evaluated, the judgements of docs/method.md#evaluation. Sections (each omitted with a note when its inputs are missing): an interactive 3D view of
``material.glb`` with the entropy as a switchable overlay; the estimated maps beside the ground
truth; the entropy, roughness std and flags maps; SH power spectra of a few picked texels
(incoming = the mirrored environment, outgoing = the observations, and the fitted specular
reflection R0^2 k_alpha(l)^2 S_in(l)), as in the paper's teaser; the sparsification curves of
both uncertainties; relit images beside the references with their Stanford-ORB metrics; timings
per stage.

No network: the 3D viewer is the bundled, pinned ``<model-viewer>`` (``freqbrdf/web``), loaded as a
classic script, and the glTF files are embedded as data URLs in ``models.js`` because Chromium does
not let pages opened from file:// fetch other local files.
"""

from __future__ import annotations

import base64
import html
import json
import os
import shutil
from importlib import resources
from pathlib import Path

import numpy as np
from matplotlib import colormaps

from freqbrdf.capture.layouts import load as load_capture
from freqbrdf.capture.mesh import Mesh
from freqbrdf.errors import InputError
from freqbrdf.fileio import atomic_directory
from freqbrdf.images import LUMINANCE, linear_to_srgb, srgb_to_linear, write_png
from freqbrdf.model import brdf
from freqbrdf.model.materials import MaterialMaps, resize
from freqbrdf.outputs import export, gltf
from freqbrdf.outputs.fit_folder import (
    CALIBRATION_PLOT,
    EVALUATION_FOLDER,
    SPARSIFICATION_PLOT,
    FitOutputs,
    load_fit,
)
from freqbrdf.outputs.relight import ERROR_COLORMAP, ERROR_RANGE

REPORT_FOLDER = "report"
REPORT_FILE = "report.html"
VIEWER_SCRIPT = "model-viewer-umd.min.js"
# Linear base colour of untrusted texels in the trust view.
TRUST_UNTRUSTED_COLOUR = (0.8, 0.0, 0.8)
PICKED_TEXELS = 3  # most certain, median, least certain observed texel
COLOUR_BAR_STOPS = 11  # samples of a colour map in a colour bar's CSS gradient
SHOWN_SECONDS = 0.005  # sub-stages that would show as 0.00 s are left out of the timings


def write_report(fit_dir: str | Path, out_dir: str | Path | None = None) -> Path:
    """Write the report of a fit folder, replacing the report folder as a whole.

    Parameters
    ----------
    fit_dir : str or Path
        The fit folder (`freqbrdf.outputs.fit_folder.load_fit`); its evaluation, when present,
        adds the evaluation sections, and its capture, when still readable, the entropy overlay
        and the ground truth.
    out_dir : str or Path, optional
        The report folder; default ``<fit>/report``.

    Returns
    -------
    Path
        The ``report.html`` written.

    Raises
    ------
    InputError
        If the fit folder cannot be read.
    """
    outputs = load_fit(fit_dir)
    out = Path(out_dir) if out_dir is not None else outputs.folder / REPORT_FOLDER
    capture = _capture_or_none(outputs)
    with atomic_directory(out) as folder:
        sections = [
            _viewer_section(folder, outputs, capture.mesh if capture else None),
            _maps_section(folder, outputs, capture.ground_truth if capture else None),
            _entropy_section(folder, outputs),
            _spectra_section(folder, outputs),
            _evaluation_sections(folder, outputs),
            _timings_section(outputs),
        ]
        (folder / REPORT_FILE).write_text(_page(outputs, sections), encoding="utf-8")
    return out / REPORT_FILE


# ---------------------------------------------------------------------------------------------
# Sections: each returns HTML and writes the files it refers to into ``folder``.


def _viewer_section(folder: Path, outputs: FitOutputs, mesh: Mesh | None) -> str:
    glb = outputs.folder / export.FILES["gltf"]
    if not glb.is_file():
        return _missing("3D view", f"{glb.name} is missing")
    models = {"material": glb.read_bytes()}
    if mesh is not None and outputs.entropy is not None:
        models["entropy"] = _entropy_glb(mesh, outputs.entropy)
    if mesh is not None and outputs.trust is not None:
        models["trust"] = _trust_glb(mesh, outputs.maps, outputs.trust)
    shutil.copyfile(resources.files("freqbrdf") / "web" / VIEWER_SCRIPT, folder / VIEWER_SCRIPT)
    urls = {name: "data:model/gltf-binary;base64," + base64.b64encode(data).decode("ascii")
            for name, data in models.items()}
    (folder / "models.js").write_text(f"window.FREQBRDF_MODELS = {json.dumps(urls)};\n", encoding="utf-8")
    buttons = "".join(
        f'<button type="button" data-model="{name}" aria-pressed="{str(name == "material").lower()}">{label}</button>'
        for name, label in (("material", "material"), ("entropy", "entropy overlay"), ("trust", "trust mask"))
        if name in models
    )
    if "entropy" in models:
        low, high = export.ENTROPY_RANGE
        overlay = (f'<div id="overlay-colourbar" hidden>'
                   f'{_colour_bar(export.ENTROPY_COLORMAP, f"{low:g} certain", f"{high:g} uncertain")}</div>')
        note = ""
    else:
        overlay = ""
        note = '<p class="note">Entropy overlay unavailable (needs the capture\'s mesh and entropy.exr).</p>'
    return f"""<section id="viewer"><h2>3D view</h2>
<model-viewer id="model" camera-controls auto-rotate shadow-intensity="0" exposure="1"
 alt="estimated material on the mesh" style="width:100%;height:420px;background:#222"></model-viewer>
<div class="buttons" role="group" aria-label="shown on the mesh">{buttons}</div>{overlay}{note}
<p class="note">Drag to orbit. The material view shows the estimated maps as a glTF PBR material under
a neutral light; the entropy overlay colours the surface by normalised entropy
({export.ENTROPY_COLORMAP}, {export.ENTROPY_RANGE[0]:g} = certain, {export.ENTROPY_RANGE[1]:g} = uncertain){_trust_note(outputs)}.</p></section>"""


def _maps_section(folder: Path, outputs: FitOutputs, truth: MaterialMaps | None) -> str:
    estimated = _picture_set(folder, "estimated", outputs.maps)
    rows = [("estimated", estimated)]
    if truth is not None:
        rows.append(("ground truth", _picture_set(folder, "truth", resize(truth, outputs.maps.resolution))))
    header = "".join(f"<th>{name}</th>" for name in ("", "base colour", "roughness", "metallic"))
    body = "".join(
        "<tr><th>" + label + "</th>" + "".join(
            f'<td>{_figure(src, f"{label} {_MAP_NAMES[name]}", _MAP_CAPTIONS[name])}</td>'
            for name, src in pictures.items()) + "</tr>"
        for label, pictures in rows
    )
    note = "" if truth is not None else '<p class="note">No ground truth in this capture.</p>'
    return f"""<section id="maps"><h2>Material maps</h2><div class="scroll"><table class="maps"><tr>{header}</tr>{body}</table></div>
{note}<p class="note">Texture space (T = {outputs.maps.resolution}). Base colour sRGB-encoded;
roughness and metallic grey, 0 black to 1 white. Unobserved texels are filled from their neighbours.</p></section>"""


_MAP_NAMES = {"base_color": "base colour", "roughness": "roughness", "metallic": "metallic"}
# What each map picture's colours mean (its caption).
_MAP_CAPTIONS = {
    "base_color": "Base colour as displayed (sRGB-encoded).",
    "roughness": "Roughness r, grey: 0 black (mirror) to 1 white (rough); GGX &alpha; = r&sup2;.",
    "metallic": "Metallic, grey: 0 black (dielectric) to 1 white (metal).",
}


def _entropy_section(folder: Path, outputs: FitOutputs) -> str:
    entropy_png = outputs.folder / export.FILES["entropy_png"]
    if not entropy_png.is_file():
        return _missing("Uncertainty", "entropy.png is missing")
    legend = "".join(
        f'<span class="swatch" style="background:{_css(colour)}"></span>{name} '
        for name, colour in _flag_legend()
    )
    low, high = export.ENTROPY_RANGE
    spread = outputs.summary.get("roughness_std_png", {})
    spread_map = str(spread.get("colormap", export.ROUGHNESS_STD_COLORMAP))
    spread_low, spread_high = spread.get("range", export.ROUGHNESS_STD_RANGE)
    meanings = {
        "entropy_png": f"Normalised entropy, {export.ENTROPY_COLORMAP}: {low:g} certain to {high:g} uncertain."
                       + _colour_bar(export.ENTROPY_COLORMAP, f"{low:g}", f"{high:g}"),
        "roughness_std_png": f"Roughness std, {html.escape(spread_map)}: {spread_low:g} to {spread_high:g} "
                             "roughness units (clipped above)."
                             + _colour_bar(spread_map, f"{spread_low:g}", f"&ge; {spread_high:g}"),
        "metallic_std_png": f"Metallic std, {html.escape(spread_map)}: 0 certain to 0.5, a coin toss between "
                            "dielectric and metal." + _colour_bar(spread_map, "0", "0.5"),
        "base_color_std_png": f"Base colour std (mean over RGB), {html.escape(spread_map)}: "
                              f"{export.BASE_COLOR_STD_RANGE[0]:g} to {export.BASE_COLOR_STD_RANGE[1]:g} linear units "
                              "(clipped above)." + _colour_bar(spread_map, f"{export.BASE_COLOR_STD_RANGE[0]:g}",
                                                                f"&ge; {export.BASE_COLOR_STD_RANGE[1]:g}"),
        "flags_png": f"Flags, the first set bit: {legend}",
        "trust_png": "Trust mask: white where every std is at most "
                     f"{outputs.summary.get('trust', {}).get('threshold', float('nan')):g}, black elsewhere.",
    }
    captions, cells = [], []
    for key, caption in (("entropy_png", "entropy"), ("roughness_std_png", "roughness std"),
                         ("metallic_std_png", "metallic std"), ("base_color_std_png", "base colour std"),
                         ("flags_png", "flags"), ("trust_png", "trust")):
        source = outputs.folder / export.FILES[key]
        if source.is_file():
            shutil.copyfile(source, folder / source.name)
            captions.append(f"<th>{caption}</th>")
            cells.append(f"<td>{_figure(source.name, f'{caption} map', meanings[key])}</td>")
    stats = outputs.summary.get("uncertainty", {})
    fractions = ", ".join(f"{name} {value:.1%}" for name, value in stats.get("flagged_fraction", {}).items())
    return f"""<section id="uncertainty"><h2>Uncertainty</h2><div class="scroll"><table class="maps"><tr>{''.join(captions)}</tr>
<tr>{''.join(cells)}</tr></table></div>
<p>Mean entropy {_number(stats.get('entropy_mean'))}, median {_number(stats.get('entropy_median'))}
over {stats.get('observed_texels', '?')} observed texels ({html.escape(_entropy_kind(stats))}).
{_ENTROPY_MEANING.get(stats.get('mode'), '')}
Flagged: {html.escape(fractions)}.</p>{_roughness_std_text(outputs)}
<p class="note">Entropy: {export.ENTROPY_COLORMAP}, 0 certain to 1 uncertain.
Flags (first set bit shown): {legend}</p></section>"""


# What the entropy says, per mode (README, "Uncertainty"): the reader should know which question
# the map answers and what it is good for.
_ENTROPY_MEANING = {
    "calibrated": "It says how ambiguous the light makes the material, from the SH spectra: high where the light "
                  "is smooth or the texel rarely seen; it flags texels for sharing and inpainting.",
    "paper": "It is the paper's recipe, kept for comparison: it depends on exposure and calls dark texels "
             "uncertain.",
    "angular": "It scores the hypotheses on the samples with the estimator's own model, as a path tracer "
               "would rank them.",
}


def _entropy_kind(stats: dict) -> str:
    """Describe what the entropy scored, from summary.json's uncertainty section: its mode and grid."""
    parts = [f"{stats.get('mode', '?')} mode"]
    if stats.get("grid_res"):
        parts.append(f"{stats['grid_res']} x {stats['grid_res']} hypotheses")
    return ", ".join(parts)


def _roughness_std_text(outputs: FitOutputs) -> str:
    """Write one sentence on what the roughness std map means, with its Spearman figure when evaluated."""
    if not (outputs.folder / export.FILES["roughness_std_png"]).is_file():
        return '<p class="note">No roughness std map (fits before it existed, or turned off in the settings).</p>'
    stats = outputs.summary.get("uncertainty", {})
    settings = outputs.summary.get("settings", {}).get("uncertainty", {})
    picture = outputs.summary.get("roughness_std_png", {})
    low, high = picture.get("range", export.ROUGHNESS_STD_RANGE)
    window = settings.get("roughness_window", 0)
    terms = [f"the scatter of the per-texel estimates over a {window} &times; {window}-texel window"] if window else []
    if settings.get("loss_curvature"):
        terms.append("the Laplace variance of the estimator's loss")
    if outputs.summary.get("settings", {}).get("surface", {}).get("enabled"):
        terms = ["the whole-surface posterior (each texel's loss curvature and its neighbours', growing with the "
                 "distance from the texels the views see)"]
    scores = (_read_metrics(outputs) or {}).get("uncertainty", {})
    spread_rho = scores.get("roughness_std", {}).get("roughness", {}).get("spearman")
    entropy_rho = scores.get("roughness", {}).get("spearman")
    ranking = ("" if spread_rho is None else
               f" Against this capture's ground truth it ranks the roughness errors with Spearman &rho; "
               f"{spread_rho:.2f} (the entropy: {_number(entropy_rho)}).")
    return (f"<p>Roughness std ({html.escape(str(picture.get('colormap', export.ROUGHNESS_STD_COLORMAP)))}, "
            f"{low:g} to {high:g} in roughness units; mean {_number(stats.get('roughness_std_mean'), 3)}, median "
            f"{_number(stats.get('roughness_std_median'), 3)}): how far the estimated roughness itself may be off, "
            f"from {' plus '.join(terms) or 'its settings'}; texels without an estimate show the prior's "
            f"{export.UNESTIMATED_ROUGHNESS_STD:.2f}.{ranking}</p>")


def _spectra_section(folder: Path, outputs: FitOutputs) -> str:
    arrays = outputs.arrays
    needed = ("observed_spectrum", "mirrored_spectrum", "entropy", "n_samples")
    if not all(name in arrays for name in needed):
        return _missing("SH power spectra", "spectra.npz or uncertainty.npz is missing")
    observed = np.flatnonzero(arrays["n_samples"] > 0)
    if len(observed) == 0:
        return _missing("SH power spectra", "no texel was observed")
    order = observed[np.argsort(arrays["entropy"][observed], kind="stable")]
    picks = {"most certain": order[0], "median": order[len(order) // 2], "least certain": order[-1]}
    _plot_spectra(folder / "spectra.png", outputs, picks)
    return """<section id="spectra"><h2>SH power spectra of picked texels</h2>
<figure><img class="wide" src="spectra.png" alt="power spectra">
<figcaption>Lines, per the legend in each panel: incoming light (blue, circles), outgoing radiance
(orange, squares), fitted specular reflection (green, dashed, triangles); log scale.</figcaption></figure>
<p class="note">Per degree l (luminance-weighted mean over RGB): incoming light (the mirrored environment,
low-passed as fitted), outgoing radiance (the observations) and the fitted specular reflection
R0&sup2; k<sub>&alpha;</sub>(l)&sup2; S<sub>in</sub>(l). A sharp material passes the incoming spectrum;
a rough one cuts it off; where the incoming spectrum is flat and weak the roughness is not determined.</p></section>"""


def _evaluation_sections(folder: Path, outputs: FitOutputs) -> str:
    evaluation = outputs.folder / EVALUATION_FOLDER
    metrics = _read_metrics(outputs)
    if metrics is None:
        return _missing("Evaluation", "run `freqbrdf evaluate FIT` first")
    parts = []
    texture = metrics.get("texture")
    if texture:
        parts.append(
            f"<p>Texture space, {texture['texels']} observed texels: base colour PSNR "
            f"{_number(texture['base_color_psnr'])} dB, roughness MAE {_number(texture['roughness_mae'], 3)}, "
            f"metallic MAE {_number(texture['metallic_mae'], 3)}.</p>")
    sparsification = evaluation / SPARSIFICATION_PLOT
    if sparsification.is_file():
        shutil.copyfile(sparsification, folder / SPARSIFICATION_PLOT)
        parts.append(f'<h3>Sparsification</h3><figure><img class="wide" src="{SPARSIFICATION_PLOT}" '
                     'alt="sparsification curves"><figcaption>Curves, per the legend: the mean error of the texels '
                     'kept, as the most uncertain are removed first by each uncertainty, and by the oracle (the '
                     'true error).</figcaption></figure><p class="note">Remove the most uncertain texels first (by the entropy, and by the roughness '
                     'std): a useful uncertainty lowers the mean error of the rest (AURG &gt; 0) and approaches '
                     'the oracle (AUSE &rarr; 0).</p>')
    calibration = evaluation / CALIBRATION_PLOT
    if calibration.is_file():
        shutil.copyfile(calibration, folder / CALIBRATION_PLOT)
        within = {name: score.get("within", {}).get("1") for name, score in metrics.get("calibration", {}).items()
                  if isinstance(score, dict) and "within" in score}
        figures = ", ".join(f"{html.escape(name.replace('_', ' '))} {_number(value * 100 if value is not None else None, 0)} %"
                            for name, value in within.items())
        parts.append(f'<h3>Calibration of the std maps</h3><figure><img class="wide" src="{CALIBRATION_PLOT}" '
                     'alt="calibration of the std maps"><figcaption>Per std map, the fraction of texels whose '
                     'absolute error lies within k std, against k; the dashed line is a calibrated std '
                     f'(68 % within 1 std). Within 1 std: {figures}.</figcaption></figure>')
    unseen = metrics.get("unseen_side") or {}
    if unseen and (evaluation / unseen.get("picture", "")).is_file():
        shutil.copyfile(evaluation / unseen["picture"], folder / unseen["picture"])
        sides = (f"{html.escape(unseen['left'])} (left) and {html.escape(unseen['right'])} (right)" if unseen.get("right")
                 else html.escape(unseen["left"]))
        parts.append(f'<h3>The side the views saw least</h3><figure><img class="wide" src="{unseen["picture"]}" '
                     f'alt="renders from the side the training views saw least"><figcaption>Path traced by Mitsuba '
                     f'under the capture\'s light from the direction farthest from every training camera: {sides}, '
                     'sRGB, one exposure for both.</figcaption></figure>')
    views = metrics.get("views", [])
    if views:
        relit = metrics["relighting"]
        rows = []
        for view in views:
            source = evaluation / view["comparison"]
            name = f"relit_{view['index']:04d}.png"
            if source.is_file():
                shutil.copyfile(source, folder / name)
            picture = (f'<div class="panels" aria-hidden="true"><span>reference</span><span>estimate, relit</span>'
                       f'<span>error</span></div><img class="relit" src="{name}" alt="relit view {view["index"]}: '
                       f'reference, estimate relit, error">')
            caption = (f"Reference photograph | our estimate rendered by Mitsuba under the same light (scaled as "
                       f"the protocol does) | mean absolute sRGB error, {ERROR_COLORMAP}: 0 (black) to "
                       f"{ERROR_RANGE:g} or more (light yellow).{_colour_bar(ERROR_COLORMAP, '0', f'&ge; {ERROR_RANGE:g}')}")
            rows.append(f'<tr><td><figure>{picture}<figcaption>{caption}</figcaption></figure></td>'
                        f'<td>PSNR-H {_number(view.get("psnr_hdr"))}<br>PSNR-L {_number(view.get("psnr_ldr"))}'
                        f'<br>SSIM {_number(view.get("ssim"), 3)}<br>LPIPS {_number(view.get("lpips"), 3)}'
                        f'<br><span class="note">{html.escape(view["envmap"])}</span></td></tr>')
        parts.append(
            f"<h3>Relighting ({len(views)} views, Stanford-ORB protocol)</h3><p>Mean PSNR-H "
            f"{_number(relit.get('psnr_hdr'))}, PSNR-L {_number(relit.get('psnr_ldr'))}, SSIM "
            f"{_number(relit.get('ssim'), 3)}, LPIPS {_number(relit.get('lpips'), 3)}.</p>"
            '<p class="note">Each row: reference | our estimate rendered by Mitsuba under the same light | error.</p>'
            '<div class="scroll"><table class="relit"><tr><th>reference | estimate, relit | error</th>'
            f'<th>scores</th></tr>{"".join(rows)}</table></div>')
    return '<section id="evaluation"><h2>Evaluation</h2>' + "".join(parts) + "</section>"


def _timings_section(outputs: FitOutputs) -> str:
    timings = outputs.summary.get("timings", {})
    if not timings:
        return _missing("Timings", "summary.json has none")
    rows = "".join(f'<tr class="{"sub" if "." in stage else "stage"}"><td>{html.escape(stage)}</td>'
                   f"<td>{_seconds(seconds)}</td></tr>" for stage, seconds in _timing_rows(timings))
    return (f'<section id="timings"><h2>Timings</h2><table class="timings">{rows}</table>'
            '<p class="note">Wall-clock seconds per stage (sub-stages indented, those under 0.01 s left out); '
            'the total includes writing the folder.</p></section>')


def _timing_rows(timings: dict) -> list[tuple[str, float]]:
    """Order a fit's timings for the report: the stages as run, then "write", then "total".

    Parameters
    ----------
    timings : dict of str to float
        ``summary.json``'s ``timings``: seconds per stage, sub-stages named ``stage.part``,
        ``total`` (the stages before writing) and ``write`` (recorded after the folder exists).

    Returns
    -------
    list of (str, float)
        The rows: sub-stages that would show as 0.00 s are left out; ``total`` is last and
        includes ``write``.
    """
    numbers = {stage: float(seconds) for stage, seconds in timings.items()
               if isinstance(seconds, (int, float)) and not isinstance(seconds, bool)}
    rows = [(stage, seconds) for stage, seconds in numbers.items()
            if stage not in ("total", "write") and not ("." in stage and seconds < SHOWN_SECONDS)]
    if "write" in numbers:
        rows.append(("write", numbers["write"]))
    if "total" in numbers:
        rows.append(("total", numbers["total"] + numbers.get("write", 0.0)))
    return rows


# ---------------------------------------------------------------------------------------------
# Helpers


def _read_metrics(outputs: FitOutputs) -> dict | None:
    """Read the evaluation's metrics.json; None before `freqbrdf evaluate`."""
    path = outputs.folder / EVALUATION_FOLDER / "metrics.json"
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        raise InputError(path, f"unreadable: {err}") from None


def _capture_or_none(outputs: FitOutputs):
    """Load the fit's capture when it can still be read (the report is possible without it)."""
    path = outputs.capture_path
    if path is None or not path.exists():
        return None
    try:
        return load_capture(path)
    except InputError:
        return None


def _entropy_glb(mesh: Mesh, entropy: np.ndarray) -> bytes:
    """Colour the mesh by the entropy colour map (matte), as glTF binary bytes."""
    low, high = export.ENTROPY_RANGE
    colour = colormaps[export.ENTROPY_COLORMAP](np.clip((entropy - low) / (high - low), 0.0, 1.0))[..., :3]
    maps = MaterialMaps(
        base_color=srgb_to_linear(colour.astype(np.float32)),  # write_gltf encodes to sRGB again
        roughness=np.ones(entropy.shape, np.float32),
        metallic=np.zeros(entropy.shape, np.float32),
    )
    return gltf.gltf_bytes(mesh, maps)


def _trust_note(outputs: FitOutputs) -> str:
    trust = outputs.summary.get("trust")
    if outputs.trust is None or not isinstance(trust, dict):
        return ""
    return (f"; the trust mask shows the material where every std is at most {trust.get('threshold', float('nan')):g} "
            f"({trust.get('trusted_fraction', float('nan')):.0%} of the surface) and magenta elsewhere")


def _trust_glb(mesh: Mesh, maps: MaterialMaps, trust: np.ndarray) -> bytes:
    """Colour the mesh with the material where trusted and a flat magenta where not, as glTF binary bytes."""
    untrusted = ~trust
    base_color = maps.base_color.copy()
    base_color[untrusted] = TRUST_UNTRUSTED_COLOUR
    roughness, metallic = maps.roughness.copy(), maps.metallic.copy()
    roughness[untrusted], metallic[untrusted] = 1.0, 0.0
    return gltf.gltf_bytes(mesh, MaterialMaps(base_color=base_color, roughness=roughness, metallic=metallic))


def _picture_set(folder: Path, prefix: str, maps: MaterialMaps) -> dict[str, str]:
    names = {"base_color": f"{prefix}_base_color.png", "roughness": f"{prefix}_roughness.png",
             "metallic": f"{prefix}_metallic.png"}
    write_png(folder / names["base_color"], linear_to_srgb(maps.base_color))
    write_png(folder / names["roughness"], np.clip(maps.roughness, 0.0, 1.0))
    write_png(folder / names["metallic"], np.clip(maps.metallic, 0.0, 1.0))
    return names


def _plot_spectra(path: Path, outputs: FitOutputs, picks: dict[str, int]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from freqbrdf.fileio import atomic_path

    arrays, maps = outputs.arrays, outputs.maps
    sigma = float(arrays.get("sigma", 0.0))
    figure, axes = plt.subplots(1, len(picks), figsize=(4.2 * len(picks), 3.3), squeeze=False)
    for axis, (label, texel) in zip(axes[0], picks.items()):
        flat = outputs.texel_index[texel]
        roughness = float(maps.roughness.ravel()[flat])
        metallic = float(maps.metallic.ravel()[flat])
        base_color = maps.base_color.reshape(-1, 3)[flat].astype(np.float64)
        r0 = brdf.DIELECTRIC_F0 * (1.0 - metallic) + base_color * metallic  # (3,)
        incoming = arrays["mirrored_spectrum"][texel].astype(np.float64)  # (3, L)
        outgoing = arrays["observed_spectrum"][texel].astype(np.float64)
        lmax = incoming.shape[-1] - 1
        kernel = brdf.brdf_kernel(np.array([roughness**2]), lmax, sigma)[0]  # (L,)
        fitted = (r0[:, None] ** 2) * kernel[None, :] ** 2 * incoming
        degrees = np.arange(lmax + 1)
        for values, name, style in ((incoming, "incoming (mirrored env.)", "-o"),
                                    (outgoing, "outgoing (observed)", "-s"),
                                    (fitted, "fitted specular", "--^")):
            axis.semilogy(degrees, np.maximum(LUMINANCE @ values, 1e-12), style, label=name, markersize=4)
        axis.set_title(f"{label}: entropy {arrays['entropy'][texel]:.2f}\nroughness {roughness:.2f}, "
                       f"metallic {metallic:.2f}, {int(arrays['n_samples'][texel])} views", fontsize=9)
        axis.set_xlabel("SH degree l")
        axis.set_ylabel("power S(l)")
        axis.legend(fontsize=7)
    figure.tight_layout()
    with atomic_path(path) as tmp:
        figure.savefig(tmp, dpi=110, format="png")
    plt.close(figure)


def _flag_legend() -> list[tuple[str, tuple[float, float, float]]]:
    from freqbrdf.uncertainty import FLAG_NAMES

    return [(FLAG_NAMES[bit], colour) for bit, colour in export.FLAG_COLOURS.items()] + [("none", (1.0, 1.0, 1.0))]


def _seconds(seconds: float) -> str:
    """Format seconds with two decimals; below what they show, "< 0.01 s" rather than "0.00 s"."""
    return "&lt; 0.01 s" if seconds < SHOWN_SECONDS else f"{seconds:.2f} s"


def _figure(source: str, alt: str, caption: str) -> str:
    """Return an image with its caption as HTML (``caption`` is HTML already)."""
    return (f'<figure><img src="{html.escape(source)}" alt="{html.escape(alt)}">'
            f"<figcaption>{caption}</figcaption></figure>")


def _colour_bar(colormap: str, low_label: str, high_label: str) -> str:
    """Return a horizontal colour bar of a matplotlib colour map, labelled at both ends, as HTML."""
    stops = ", ".join(_css(colormaps[colormap](position)[:3])
                      for position in np.linspace(0.0, 1.0, COLOUR_BAR_STOPS))
    return (f'<span class="colourbar" data-colormap="{html.escape(colormap)}"><span class="bar" '
            f'style="background:linear-gradient(to right, {stops})"></span>'
            f'<span class="ends"><span>{low_label}</span><span>{high_label}</span></span></span>')


def _css(colour) -> str:
    return "rgb(" + ",".join(str(int(round(255 * c))) for c in colour) + ")"


def _number(value, digits: int = 2) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _missing(title: str, reason: str) -> str:
    return f'<section><h2>{html.escape(title)}</h2><p class="note">Not shown: {html.escape(reason)}.</p></section>'


_STYLE = """
body{font-family:system-ui,sans-serif;max-width:1100px;margin:1em auto;padding:0 1em;color:#222}
code{overflow-wrap:anywhere} th{white-space:nowrap}
h1{font-size:1.5em} h2{border-bottom:1px solid #ccc;padding-bottom:.2em}
.scroll{max-width:100%;overflow-x:auto}
figure{margin:0} figcaption{color:#444;font-size:.85em;max-width:256px}
table.maps td,table.maps th{vertical-align:top}
table.maps{width:100%} table.maps td{width:256px}
table.maps img{width:100%;max-width:256px;height:auto;aspect-ratio:1/1;image-rendering:pixelated;border:1px solid #ccc;box-sizing:border-box}
img.wide{max-width:100%} img.relit{max-width:720px;width:100%;display:block}
table.relit figcaption{max-width:720px}
.panels{display:grid;grid-template-columns:repeat(3,1fr);max-width:720px;font-size:.85em;font-weight:bold;text-align:center}
.colourbar{display:block;max-width:256px;margin:.3em 0} .colourbar .bar{display:block;height:.8em;border:1px solid #999}
.colourbar .ends{display:flex;justify-content:space-between;font-size:.85em}
#overlay-colourbar{max-width:320px}
.note{color:#666;font-size:.9em} .swatch{display:inline-block;width:.9em;height:.9em;border:1px solid #999;margin:0 .2em}
.buttons button{margin:.4em .4em 0 0;padding:.3em .8em;border:1px solid #888;background:#f4f4f4;color:#222;cursor:pointer}
.buttons button[aria-pressed="true"]{background:#2a5db0;border-color:#2a5db0;color:#fff;font-weight:bold}
table.timings td{padding:0 1em 0 0} table.timings tr.sub td:first-child{padding-left:1.5em;color:#555}
table.timings tr:last-child td{font-weight:bold;border-top:1px solid #ccc}
"""

_SCRIPT = """
const viewer = document.getElementById('model');
if (viewer && window.FREQBRDF_MODELS) {
  viewer.src = window.FREQBRDF_MODELS.material;
  const buttons = [...document.querySelectorAll('button[data-model]')];
  const overlayBar = document.getElementById('overlay-colourbar');
  for (const button of buttons) {
    button.addEventListener('click', () => {
      viewer.src = window.FREQBRDF_MODELS[button.dataset.model];
      for (const other of buttons) { other.setAttribute('aria-pressed', String(other === button)); }
      if (overlayBar) { overlayBar.hidden = button.dataset.model !== 'entropy'; }
    });
  }
}
"""


def _capture_name(outputs: FitOutputs) -> str:
    """Name the fit's capture relative to the fit folder (its folder name when no relative path exists)."""
    path = outputs.capture_path
    if path is None:
        return "?"
    try:
        return Path(os.path.relpath(path, outputs.folder.resolve())).as_posix()
    except ValueError:  # another drive: no relative path
        return path.name


def _calibration_paragraph(summary: dict) -> str:
    """Say what the photographs calibrated (gains with their std, the probe's turn) and the warnings, as HTML."""
    found = summary.get("calibration")
    lines = []
    if found:
        gains = ", ".join(f"{gain:.3f} ± {std:.3f}" for gain, std in zip(found["gain"], found["gain_std"]))
        source = {"dielectrics": f", read on {found.get('texels', 0)} texels found dielectric",
                  "every texel": f", the exposure read on {found.get('texels', 0)} texels of every material (too few "
                                 "dielectrics)"}.get(found.get("exposure_from", ""), "")
        lines.append(f"Calibration: the photographs are {gains} (R, G, B) times the environment map's radiance{source}")
        probe = found.get("probe")
        if probe is not None:
            spread = "" if probe.get("std_deg") is None else f" (± {probe['std_deg']:.1f}°)"
            lines.append(f"the map turned {probe['angle_deg']:.1f}°{spread} to match their reflections"
                         if probe["angle_deg"] > 0.0 else f"the map's registration kept{spread}")
        if found.get("frame_gains") is not None:
            lines.append("a gain per photograph applied")
    text = "; ".join(lines) + "." if lines else ""
    text = " ".join(part for part in (text, _std_calibration_sentence(summary.get("std_calibration"))) if part)
    warnings = "".join(f"<li>{html.escape(line)}</li>" for line in summary.get("warnings", []))
    return (f"<p>{html.escape(text)}</p>" if text else "") + (f'<ul class="warnings">{warnings}</ul>' if warnings
                                                               else "")


def _std_calibration_sentence(found: dict | None) -> str:
    """Say how the held-out views scaled the std maps (docs/method.md#held-out-std-calibration); "" if not done."""
    if not found or not found.get("factors"):
        return ""
    names = {"roughness": "roughness", "base_color": "base colour"}
    factors = ", ".join(f"{names.get(name, name)} × {factor:.2f}" for name, factor in found["factors"].items())
    after = ", ".join(f"{found['coverage_before'].get(name, float('nan')):.0%} → {share:.0%}"
                      for name, share in found.get("coverage_after", {}).items())
    return (f"Std calibration: {found['folds']} folds of held-out views on {found['texels']} texels scaled the std "
            f"maps by {factors} (held-out deviations within one std: {after}).")


def _page(outputs: FitOutputs, sections: list[str]) -> str:
    summary = outputs.summary
    coverage = summary.get("coverage", {})
    method = summary.get("estimate", {}).get("method", "?")
    capture = html.escape(_capture_name(outputs))
    has_viewer = 'id="viewer"' in sections[0]
    scripts = (f'<script src="{VIEWER_SCRIPT}"></script><script src="models.js"></script>'
               if has_viewer else "")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>freqbrdf report</title>
<style>{_STYLE}</style>{scripts}</head><body>
<h1>freqbrdf report</h1>
<p>Capture <code>{capture}</code> (relative to the fit folder); estimator <b>{html.escape(str(method))}</b>;
{coverage.get('observed_fraction', 0):.0%} of {coverage.get('texels', '?')} texels observed,
{_number(coverage.get('mean_views_per_observed_texel'), 1)} views per observed texel on average.</p>
{_calibration_paragraph(summary)}
{''.join(sections)}
<script>{_SCRIPT}</script>
</body></html>
"""
