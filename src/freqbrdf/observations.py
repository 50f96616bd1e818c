"""Observations: from a capture to per-texel samples and their SH spectra.

For every texel and view we record, in the mirror parameterisation of METHOD.md §2:

- the view direction w_o in the texel's local frame (t, b, n),
- the observed radiance (the image, bilinearly sampled where the texel projects),
- the environment radiance in the mirror direction r = 2 (n.v) n - v (band-limited, see below),
- the weight w = max(0, cos theta_o) x visible x inside the image and its mask.

Dark texels are observations like any other: only the weight decides what counts as a sample.
Visibility is a shadow ray from the texel (offset along its normal by a scale-aware epsilon) to
the camera centre, traced by Mitsuba in one batch per view.

Then, per texel, one weighted regularised SH fit (``sh.fit_sh``) of seven signals on the same
samples: observed RGB, mirrored environment RGB and the constant 1 (whose fit carries the diffuse
term through the fit, METHOD.md §3.6). Band limit (METHOD.md §3.4): the environment is low-passed
with exp(-(sigma l)^2), sigma = 1/floor(sqrt(N)) for N views, before it is looked up, and the BRDF
kernel divides that blur back out (``brdf.brdf_kernel``).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, fields
from pathlib import Path

import numba
import numpy as np

from freqbrdf import brdf, envmap as envmaps, sh
from freqbrdf.capture import Capture
from freqbrdf.config import Config
from freqbrdf.errors import InputError
from freqbrdf.fileio import atomic_path
from freqbrdf.progress import SILENT, Reporter
from freqbrdf.render import mitsuba
from freqbrdf.texels import Texels, rasterise

# Shadow rays start this far off the surface, in units of the texel's world size, plus a small
# fraction of the object's size for float round-off: far enough to leave the texel's own
# triangle, near enough not to step over thin parts.
RAY_OFFSET_TEXELS = 0.5
RAY_OFFSET_OBJECT = 1e-5
# A sample must lie fully inside the mask: its four bilinear neighbours all on the object, so
# that silhouette pixels blending object and background are not taken for the object.
MASK_INSIDE = 1.0 - 1e-6
# Degree of the environment's SH expansion used for irradiance: the clamped-cosine kernel
# decays as l^-5/2, so degree 16 leaves well under 0.1 % of a smooth map's irradiance out.
IRRADIANCE_LMAX = 16

# Channel layout of the fitted signals.
OBSERVED = slice(0, 3)
MIRRORED = slice(3, 6)
CONSTANT = 6
N_SIGNALS = 7


@dataclass(eq=False)
class Observations:
    """Per-texel samples and spectra of a capture. N texels (valid ones only), V views."""

    texture_res: int  # T
    texel_index: np.ndarray  # (N,) int64 flat row-major index into the T x T texture
    normal: np.ndarray  # (N, 3) float32 world shading normal
    view_direction: np.ndarray  # (N, V, 3) float32 w_o in the local frame (t, b, n)
    observed: np.ndarray  # (N, V, 3) float32 observed radiance
    mirrored: np.ndarray  # (N, V, 3) float32 environment radiance in the mirror direction
    weight: np.ndarray  # (N, V) float32 max(0, cos theta_o) x visible (0: no sample)
    visible: np.ndarray  # (N, V) bool: in front of and unoccluded from the camera, inside its image
    irradiance: np.ndarray  # (N, 3) float32 E = integral of L max(0, n.w) dw
    lmax: int  # l*
    sigma: float  # band-limit width applied to the environment (0: none)
    observed_coeffs: np.ndarray  # (N, 3, K) float32 SH fit of the observed radiance
    mirrored_coeffs: np.ndarray  # (N, 3, K) float32 SH fit of the mirrored environment
    constant_coeffs: np.ndarray  # (N, K) float32 SH fit of the constant 1 (the diffuse response)
    fit_status: np.ndarray  # (N,) uint8 sh.FIT_OK / FIT_UNDERDETERMINED / FIT_EMPTY
    n_samples: np.ndarray  # (N,) int32 views with positive weight
    alpha_bound: np.ndarray  # (N,) float32 alpha' of appendix eq. 12 for this texel's samples
    timings: dict = field(default_factory=dict)  # seconds per stage

    @property
    def n_texels(self) -> int:
        return len(self.texel_index)

    @property
    def n_views(self) -> int:
        return self.weight.shape[1]

    @property
    def observed_spectrum(self) -> np.ndarray:
        """(N, 3, l*+1) power spectrum of the observed radiance."""
        return sh.power_spectrum(self.observed_coeffs)

    @property
    def mirrored_spectrum(self) -> np.ndarray:
        """(N, 3, l*+1) power spectrum of the mirrored environment."""
        return sh.power_spectrum(self.mirrored_coeffs)

    def mask(self) -> np.ndarray:
        """(T, T) bool: texels of the mesh (observed or not)."""
        mask = np.zeros(self.texture_res * self.texture_res, dtype=bool)
        mask[self.texel_index] = True
        return mask.reshape(self.texture_res, self.texture_res)

    def to_texture(self, values: np.ndarray, fill: float = 0.0) -> np.ndarray:
        """Scatter per-texel values (N, ...) into a (T, T, ...) texture."""
        values = np.asarray(values)
        texture = np.full((self.texture_res * self.texture_res, *values.shape[1:]), fill, values.dtype)
        texture[self.texel_index] = values
        return texture.reshape(self.texture_res, self.texture_res, *values.shape[1:])

    def save(self, path: str | Path) -> None:
        """Write everything to one ``.npz`` (atomically)."""
        arrays = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "timings"}
        arrays["timings_json"] = np.array(json.dumps(self.timings))
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as handle:
                np.savez(handle, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> Observations:
        path = Path(path)
        if not path.is_file():
            raise InputError(path, "observations file does not exist")
        try:
            with np.load(path, allow_pickle=False) as data:
                values = {f.name: data[f.name] for f in fields(cls) if f.name != "timings"}
                timings = json.loads(str(data["timings_json"]))
        except (KeyError, ValueError, OSError) as err:
            raise InputError(path, f"not a freqbrdf observations file ({err})") from err
        values["texture_res"] = int(values["texture_res"])
        values["lmax"] = int(values["lmax"])
        values["sigma"] = float(values["sigma"])
        return cls(**values, timings=timings)


# ---------------------------------------------------------------------------------------------
# The stage


def observe(capture: Capture, config: Config = Config(), reporter: Reporter = SILENT,
            texels: Texels | None = None) -> Observations:
    """Observations of every texel of ``capture`` in every view, and their SH spectra."""
    timings: dict[str, float] = {}
    start = time.perf_counter()
    if texels is None:
        texels = rasterise(capture.mesh, config.texels.texture_res)
    timings["raster"] = time.perf_counter() - start

    n_texels, n_views = texels.n_texels, len(capture.frames)
    if n_views == 0:
        raise InputError(capture.root, "the capture has no frames")
    sigma = brdf.band_limit_sigma(n_views) if config.fit.band_limit else 0.0
    lit = envmaps.lowpass_envmap(capture.envmap, sigma) if sigma > 0 else capture.envmap

    # Samples (N, V, 7): observed RGB, mirrored RGB, constant 1; the fit reads them in place.
    signals = np.zeros((n_texels, n_views, N_SIGNALS), dtype=np.float32)
    signals[..., CONSTANT] = 1.0
    view_direction = np.zeros((n_texels, n_views, 3), dtype=np.float32)
    weight = np.zeros((n_texels, n_views), dtype=np.float32)
    visible = np.zeros((n_texels, n_views), dtype=bool)

    position = texels.position
    normal = texels.normal
    frame = np.stack([texels.tangent, texels.bitangent, texels.normal], axis=1)  # (N, 3, 3) rows
    offset = RAY_OFFSET_TEXELS * texels.texel_size + RAY_OFFSET_OBJECT * _extent(capture.mesh.vertices)
    ray_origin = position + offset[:, None] * normal  # (N, 3)
    scene = _occlusion_scene(capture)

    for stage in ("visibility", "projection"):
        timings[stage] = 0.0
    with reporter.stage("observing views", n_views) as advance:
        for view, frame_info in enumerate(capture.frames):
            camera = frame_info.camera
            tick = time.perf_counter()
            to_camera = camera.center[None, :] - position  # (N, 3)
            distance = np.linalg.norm(to_camera, axis=1)
            direction = to_camera / distance[:, None]
            cos_theta = np.einsum("ij,ij->i", direction, normal)
            pixels, depth = camera.project(position)
            in_image = (
                (depth > 0)
                & (pixels[:, 0] >= 0) & (pixels[:, 0] <= camera.width)
                & (pixels[:, 1] >= 0) & (pixels[:, 1] <= camera.height)
            )
            candidates = np.flatnonzero(in_image & (cos_theta > 0))
            timings["projection"] += time.perf_counter() - tick

            tick = time.perf_counter()
            unoccluded = _unoccluded(scene, ray_origin[candidates], camera.center)
            seen = candidates[unoccluded]
            timings["visibility"] += time.perf_counter() - tick

            tick = time.perf_counter()
            image = capture.image(view)
            mask = capture.mask(view).astype(np.float32)
            radiance = np.empty((len(seen), 3), dtype=np.float32)
            coverage = np.empty((len(seen), 1), dtype=np.float32)
            _sample_bilinear(image, pixels[seen], radiance)
            _sample_bilinear(mask[..., None], pixels[seen], coverage)
            seen_inside = coverage[:, 0] >= MASK_INSIDE
            seen, radiance = seen[seen_inside], radiance[seen_inside]

            view_dir = direction[seen]
            signals[seen, view, OBSERVED] = radiance
            mirror = 2.0 * cos_theta[seen, None] * normal[seen] - view_dir
            signals[seen, view, MIRRORED] = envmaps.lookup(lit, mirror)
            view_direction[seen, view] = np.einsum("nij,nj->ni", frame[seen], view_dir)
            weight[seen, view] = cos_theta[seen]
            visible[seen, view] = True
            timings["projection"] += time.perf_counter() - tick
            advance(1)

    tick = time.perf_counter()
    env_coeffs = envmaps.envmap_sh(capture.envmap, IRRADIANCE_LMAX)
    irradiance = envmaps.irradiance(env_coeffs, normal).astype(np.float32)
    timings["irradiance"] = time.perf_counter() - tick

    tick = time.perf_counter()
    with reporter.stage("fitting SH spectra", 1) as advance:
        fit = sh.fit_sh(
            view_direction, weight, signals, config.fit.lmax, config.fit.reg_lambda,
            config.fit.regulariser, config.fit.scale_lambda_with_weight,
        )
        advance(1)
    timings["fits"] = time.perf_counter() - tick

    n_samples = fit.n_samples
    alpha_bound = texel_alpha_bound(n_samples, config.fit.lmax, config.fit.attenuation_threshold)
    timings["total"] = time.perf_counter() - start
    return Observations(
        texture_res=texels.texture_res,
        texel_index=texels.texel_index,
        normal=normal.astype(np.float32),
        view_direction=view_direction,
        observed=signals[..., OBSERVED],
        mirrored=signals[..., MIRRORED],
        weight=weight,
        visible=visible,
        irradiance=irradiance,
        lmax=config.fit.lmax,
        sigma=float(sigma),
        observed_coeffs=fit.coeffs[:, OBSERVED],
        mirrored_coeffs=fit.coeffs[:, MIRRORED],
        constant_coeffs=fit.coeffs[:, CONSTANT],
        fit_status=fit.status,
        n_samples=n_samples,
        alpha_bound=alpha_bound,
        timings=timings,
    )


# ---------------------------------------------------------------------------------------------
# Helpers


def texel_alpha_bound(n_samples: np.ndarray, lmax: int, attenuation: float) -> np.ndarray:
    """(N,) alpha' (appendix eq. 12) per texel: inf where fewer than 2 samples.

    The usable degree is the smaller of what the texel's n samples resolve (l < sqrt(n),
    ``brdf.resolvable_degree``) and the fit's l*: spectra carry no information above l*.
    """
    n_samples = np.asarray(n_samples, dtype=np.int64)
    root = np.floor(np.sqrt(n_samples)).astype(np.int64)
    resolvable = np.minimum(root - (root * root == n_samples), lmax)
    bound = np.full(n_samples.shape, np.inf, dtype=np.float32)
    ok = resolvable >= 1
    bound[ok] = np.sqrt(-np.log(attenuation)) / resolvable[ok]
    return bound


def _extent(vertices: np.ndarray) -> float:
    """Diagonal of the bounding box: the object's scale."""
    return float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))


def _occlusion_scene(capture: Capture):
    """A Mitsuba scene holding only the mesh, for batched shadow-ray tests."""
    from freqbrdf.render import mesh_shape

    mi = mitsuba()
    return mi.load_dict({"type": "scene", "object": mesh_shape(capture.mesh, {"type": "diffuse"})})


def _unoccluded(scene, origins: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(M,) bool: the segment from each origin (M, 3) to ``target`` (3,) hits nothing."""
    if len(origins) == 0:
        return np.zeros(0, dtype=bool)
    mi = mitsuba()
    to_target = target[None, :] - origins
    distance = np.linalg.norm(to_target, axis=1)
    direction = to_target / distance[:, None]
    ray = mi.Ray3f(
        mi.Point3f(*(mi.Float(np.ascontiguousarray(origins[:, k], np.float32)) for k in range(3))),
        mi.Vector3f(*(mi.Float(np.ascontiguousarray(direction[:, k], np.float32)) for k in range(3))),
    )
    # Stop just short of the camera centre; cameras never sit on the surface.
    ray.maxt = mi.Float(np.asarray(distance * (1.0 - 1e-5), np.float32))
    return ~np.array(scene.ray_test(ray), dtype=bool)


@numba.njit(parallel=True, cache=True)
def _sample_bilinear(image, pixels, out):  # image (H, W, C); pixels (M, 2) x, y; out (M, C)
    """Bilinear interpolation at pixel coordinates whose pixel centres lie at (j + 0.5, i + 0.5);
    the border is clamped (the sample is the edge pixel's value half a pixel beyond its centre)."""
    height, width, channels = image.shape
    for k in numba.prange(pixels.shape[0]):
        x = min(max(pixels[k, 0] - 0.5, 0.0), width - 1.0)
        y = min(max(pixels[k, 1] - 0.5, 0.0), height - 1.0)
        col = min(int(x), width - 2) if width > 1 else 0
        row = min(int(y), height - 2) if height > 1 else 0
        fx = x - col
        fy = y - row
        col_next = min(col + 1, width - 1)
        row_next = min(row + 1, height - 1)
        for c in range(channels):
            top = image[row, col, c] * (1.0 - fx) + image[row, col_next, c] * fx
            bottom = image[row_next, col, c] * (1.0 - fx) + image[row_next, col_next, c] * fx
            out[k, c] = top * (1.0 - fy) + bottom * fy
