"""Observations: from a capture to per-texel samples and their SH spectra (METHOD.md §3.2-3.5).

For every texel and view, `observe` records in the mirror parameterisation of METHOD.md §2:

- the view direction w_o in the texel's local frame (t, b, n),
- the observed radiance (the image, bilinearly sampled where the texel projects),
- the environment radiance in the mirror direction r = 2 (n.v) n - v (band-limited, see below),
- the weight w = max(0, cos theta_o) x visible x inside the image and its mask.

Dark texels are observations like any other: only the weight decides what counts as a sample,
and the weight depends on geometry alone, never on the radiance. Visibility (§3.2) is a shadow
ray from the texel (offset along its normal by a scale-aware epsilon) to the camera centre,
traced by `freqbrdf.render.occluder.Occluder`; the rays of several views go in one batch.

Then, per texel, one weighted regularised SH fit (§3.3, `freqbrdf.sphere.harmonics.fit_sh`) of
seven signals on the same samples: observed RGB, mirrored environment RGB and the constant 1
(whose fit carries the diffuse term through the fit, §3.6). Band limit (§3.4): the environment is
low-passed with exp(-(sigma l)^2), sigma = 1/floor(sqrt(V)) for V views, before it is looked up,
and the BRDF kernel divides that blur back out (`freqbrdf.model.brdf.brdf_kernel`). Irradiance
(§3.5) comes from the environment's SH with the clamped-cosine kernel (`texel_irradiance`).

`write_maps` draws an `Observations`' coverage and visibility in texture space, for people.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numba
import numpy as np

from freqbrdf.capture.layouts import Capture
from freqbrdf.config import Config
from freqbrdf.errors import InputError
from freqbrdf.fileio import atomic_path
from freqbrdf.model import brdf
from freqbrdf.progress import SILENT, Reporter
from freqbrdf.render.occluder import RAYS_PER_BATCH, Occluder
from freqbrdf.sphere import envmap as envmaps
from freqbrdf.sphere import harmonics as sh
from freqbrdf.texels import Texels, rasterise

# Shadow rays start this far off the surface, in units of the texel's world size, plus a small
# fraction of the object's size for float round-off: far enough to leave the texel's own
# triangle, near enough not to step over thin parts.
RAY_OFFSET_TEXELS = 0.5
RAY_OFFSET_OBJECT = 1e-5
# A sample must lie fully inside the mask: its four bilinear neighbours all on the object, so
# that silhouette pixels blending object and background are not taken for the object.
MASK_INSIDE = 1.0 - 1e-6
# Views projected, traced and sampled together (within RAYS_PER_BATCH shadow rays and this many
# bytes of stacked images and masks), so that each texel writes its samples contiguously.
VIEWS_PER_BATCH = 16
IMAGE_BYTES_PER_BATCH = 512 << 20
# Samples whose mirrored environment is looked up together (24 bytes of direction, 12 of radiance each).
MIRROR_SAMPLES_PER_BATCH = 1 << 21
# Irradiance is smooth (its SH decay like l^-5/2), so it is synthesised once on a lat-long grid
# of this height and interpolated bilinearly at the normals, rather than evaluating every SH at
# every texel (docs/measurements.md has the error and the cost of both).
IRRADIANCE_MAP_HEIGHT = 256

# Channel layout of the fitted signals.
OBSERVED = slice(0, 3)
MIRRORED = slice(3, 6)
CONSTANT = 6
N_SIGNALS = 7

STAGES = ("raster", "projection", "visibility", "images", "irradiance", "fits")
# The array fields of Observations that are not per texel.
_SHARED_ARRAYS = ("environment_coeffs", "environment_radiance", "environment_rotation")
# Per texel and view (N, V, ...).
_SAMPLE_ARRAYS = ("view_direction", "observed", "mirrored", "weight", "visible")


@dataclass(eq=False)
class Observations:
    """Per-texel samples and spectra of a capture: N texels (valid ones only), V views.

    Written by `observe`; per-texel arrays are rows of the texels' order, per-sample arrays are
    (N, V, ...) with weight 0 where a texel has no sample in a view.

    Attributes
    ----------
    texture_res : int
        T, the texture side.
    texel_index : (N,) int64
        Flat row-major index of each texel into the T x T texture.
    normal : (N, 3) float32
        World shading normal.
    view_direction : (N, V, 3) float32
        w_o in the texel's local frame (t, b, n).
    observed : (N, V, 3) float32
        Observed radiance.
    mirrored : (N, V, 3) float32
        Environment radiance in the mirror direction (band-limited by ``sigma``).
    weight : (N, V) float32
        max(0, cos theta_o) x visible; 0: no sample.
    visible : (N, V) bool
        In front of and unoccluded from the camera, inside its image and its mask.
    irradiance : (N, 3) float32
        E = integral of L(w) max(0, n.w) dw (METHOD.md §3.5).
    lmax : int
        l*, the degree of the SH fits.
    sigma : float
        Band-limit width applied to the environment (METHOD.md §3.4); 0: none.
    observed_coeffs : (N, 3, K) float32
        SH fit of the observed radiance.
    mirrored_coeffs : (N, 3, K) float32
        SH fit of the mirrored environment.
    constant_coeffs : (N, K) float32
        SH fit of the constant 1 on the same samples (the diffuse response, METHOD.md §3.6).
    fit_status : (N,) uint8
        ``FIT_OK``, ``FIT_UNDERDETERMINED`` or ``FIT_EMPTY`` of `freqbrdf.sphere.harmonics`.
    n_samples : (N,) int32
        Views with positive weight.
    alpha_bound : (N,) float32
        alpha' of appendix eq. 12 for the texel's samples (`texel_alpha_bound`).
    n_facing : (N,) int32
        Views whose image holds the texel, facing the camera: the samples there would be before
        the occlusion and mask tests (n_samples / n_facing is the visible fraction).
    tangent : (N, 3) float32 or None
        World tangent of the local frame (bitangent = normal x tangent); None where unknown
        (hand-made observations).
    environment_coeffs : (K, 3) float32 or None
        The environment's SH in the world frame, unfiltered: what the estimator's environment
        light reads (``EstimateConfig.environment_light``). None where unknown.
    environment_radiance : (H, W, 3) float32 or None
        The environment map itself (`freqbrdf.sphere.envmap.Envmap.radiance`, unfiltered): what
        smooth lobes read, prefiltered (``EstimateConfig.prefiltered_light``). None where unknown.
    environment_rotation : (3, 3) float64 or None
        The environment map's emitter-to-world rotation. None where unknown.
    timings : dict
        Seconds per stage of `observe` (``STAGES`` and ``"total"``).
    """

    texture_res: int
    texel_index: np.ndarray
    normal: np.ndarray
    view_direction: np.ndarray
    observed: np.ndarray
    mirrored: np.ndarray
    weight: np.ndarray
    visible: np.ndarray
    irradiance: np.ndarray
    lmax: int
    sigma: float
    observed_coeffs: np.ndarray
    mirrored_coeffs: np.ndarray
    constant_coeffs: np.ndarray
    fit_status: np.ndarray
    n_samples: np.ndarray
    alpha_bound: np.ndarray
    n_facing: np.ndarray
    tangent: np.ndarray | None = None
    environment_coeffs: np.ndarray | None = None
    environment_radiance: np.ndarray | None = None
    environment_rotation: np.ndarray | None = None
    timings: dict = field(default_factory=dict)

    @property
    def n_texels(self) -> int:
        """N, the number of texels."""
        return len(self.texel_index)

    @property
    def n_views(self) -> int:
        """V, the number of views."""
        return self.weight.shape[1]

    @property
    def observed_spectrum(self) -> np.ndarray:
        """(N, 3, L) power spectrum of the observed radiance (METHOD.md §2), in its coefficients' float type."""
        return sh.power_spectrum(self.observed_coeffs)

    @property
    def mirrored_spectrum(self) -> np.ndarray:
        """(N, 3, L) power spectrum of the mirrored environment (METHOD.md §2), in its coefficients' float type."""
        return sh.power_spectrum(self.mirrored_coeffs)

    def environment(self) -> envmaps.Envmap | None:
        """Return the environment map of the capture, unfiltered.

        Returns
        -------
        Envmap or None
            The map with its emitter-to-world rotation (no translation); None where the
            map or its rotation is unknown.
        """
        if self.environment_radiance is None or self.environment_rotation is None:
            return None
        to_world = np.eye(4)
        to_world[:3, :3] = self.environment_rotation
        return envmaps.Envmap(self.environment_radiance, to_world)

    def select(self, rows) -> Observations:
        """Return the Observations of some of the texels.

        Every per-texel and per-sample array is indexed; the environment (SH, map, rotation) and
        the scalars are kept.

        Parameters
        ----------
        rows : (n,) int array, slice or (N,) bool
            The texels to keep: indices, a slice or a boolean mask over the N texels.

        Returns
        -------
        Observations
            The n texels selected, all V views.
        """
        changes = {item.name: getattr(self, item.name)[rows] for item in fields(self)
                   if isinstance(getattr(self, item.name), np.ndarray) and item.name not in _SHARED_ARRAYS}
        return replace(self, **changes)

    def texel_fields(self, rows) -> Observations:
        """Return the per-texel fields of some of the texels, without their samples.

        Like `select`, but the per-sample arrays (view direction, observed, mirrored, weight,
        visible) are kept with no view (V = 0); everything per texel (spectra, counts, normals)
        is indexed. For outputs on other texels than the ones observed
        (`freqbrdf.pipeline.to_texels`), where copying every sample would cost more than the
        estimate.

        Parameters
        ----------
        rows : (n,) int array, slice or (N,) bool
            The texels to keep: indices, a slice or a boolean mask over the N texels.

        Returns
        -------
        Observations
            The n texels selected, with V = 0.
        """
        changes = {}
        for item in fields(self):
            value = getattr(self, item.name)
            if isinstance(value, np.ndarray) and item.name not in _SHARED_ARRAYS:
                changes[item.name] = (value[:, :0] if item.name in _SAMPLE_ARRAYS else value)[rows]
        return replace(self, **changes)

    def with_views(self, keep: np.ndarray, config: Config = Config()) -> Observations:
        """Return the Observations as if only some of the views had been captured.

        The other views' samples are dropped (weight 0, not visible), then the SH spectra, fit
        status, sample counts and alpha' are refitted from the samples left, to degree
        l* = ``self.lmax`` with ``config.fit``'s regulariser and alpha' threshold, as `observe`
        fits them. What describes the light rather than the samples is kept: the band limit sigma
        (set by the whole capture's view count), the irradiance, the environment and n_facing.

        Parameters
        ----------
        keep : (V,) bool
            The views to keep.
        config : Config
            Its ``fit`` settings (regulariser, penalty, attenuation threshold) are used.

        Returns
        -------
        Observations
            All N texels and V views, with the samples of the dropped views zeroed and empty
            ``timings``.

        Raises
        ------
        ValueError
            If ``keep`` is not of shape (V,).
        """
        keep = np.asarray(keep, dtype=bool)
        if keep.shape != (self.n_views,):
            raise ValueError(f"keep must be ({self.n_views},) bool, got shape {keep.shape}")
        weight = np.where(keep, self.weight, 0.0).astype(np.float32)
        signals = np.empty((self.n_texels, self.n_views, N_SIGNALS), dtype=np.float32)
        signals[..., OBSERVED] = self.observed
        signals[..., MIRRORED] = self.mirrored
        signals[..., CONSTANT] = 1.0
        settings = config.fit
        fit = sh.fit_sh(self.view_direction, weight, signals, self.lmax, settings.reg_lambda,
                        settings.regulariser, settings.scale_lambda_with_weight)
        return replace(
            self, weight=weight, visible=self.visible & keep,
            observed_coeffs=fit.coeffs[:, OBSERVED], mirrored_coeffs=fit.coeffs[:, MIRRORED],
            constant_coeffs=fit.coeffs[:, CONSTANT], fit_status=fit.status, n_samples=fit.n_samples,
            alpha_bound=texel_alpha_bound(fit.n_samples, self.lmax, settings.attenuation_threshold),
            timings={},
        )

    def mask(self) -> np.ndarray:
        """Return the texels of the mesh in texture space.

        Returns
        -------
        (T, T) bool
            True at the N texels (observed or not).
        """
        mask = np.zeros(self.texture_res * self.texture_res, dtype=bool)
        mask[self.texel_index] = True
        return mask.reshape(self.texture_res, self.texture_res)

    def to_texture(self, values: np.ndarray, fill: float = 0.0) -> np.ndarray:
        """Scatter per-texel values into a texture.

        Parameters
        ----------
        values : (N, ...) array_like
            One value (of any trailing shape) per texel.
        fill : float
            The value of the texture outside the N texels.

        Returns
        -------
        (T, T, ...) array
            The texture, of ``values``' dtype.
        """
        values = np.asarray(values)
        texture = np.full((self.texture_res * self.texture_res, *values.shape[1:]), fill, values.dtype)
        texture[self.texel_index] = values
        return texture.reshape(self.texture_res, self.texture_res, *values.shape[1:])

    def save(self, path: str | Path) -> None:
        """Write everything to one ``.npz`` file, atomically.

        Fields that are None are left out; `load` reads them back as None.

        Parameters
        ----------
        path : str or Path
            The file to write (replaced if it exists).
        """
        arrays = {f.name: getattr(self, f.name) for f in fields(self)
                  if f.name != "timings" and getattr(self, f.name) is not None}
        arrays["timings_json"] = np.array(json.dumps(self.timings))
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as handle:
                np.savez(handle, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> Observations:
        """Read an Observations written by `save`.

        Parameters
        ----------
        path : str or Path
            The ``.npz`` file.

        Returns
        -------
        Observations
            What was saved; optional fields missing from the file are None.

        Raises
        ------
        InputError
            If the file does not exist or is not a freqbrdf observations file.
        """
        path = Path(path)
        if not path.is_file():
            raise InputError(path, "observations file does not exist")
        try:
            with np.load(path, allow_pickle=False) as data:
                values = {f.name: data[f.name] for f in fields(cls)
                          if f.name != "timings" and (f.name in data or f.default is not None)}
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
    """Observe every texel of a capture in every view and fit the SH spectra of its samples.

    The stage of METHOD.md §3.2-3.5 (module docstring): projection, visibility, bilinear image
    samples, the band-limited environment in the mirror directions, the irradiance and one
    regularised SH fit per texel of the observed radiance, the mirrored environment and the
    constant 1.

    Parameters
    ----------
    capture : Capture
        The posed images, their masks, the mesh and the environment map.
    config : Config
        ``config.texels.texture_res`` sets T when ``texels`` is None; ``config.fit`` the degree
        l*, the regulariser, the band limit and alpha's attenuation threshold.
    reporter : Reporter
        Progress of the views and of the fits.
    texels : Texels or None
        The texels to observe (e.g. a subset); None rasterises the capture's mesh at T.

    Returns
    -------
    Observations
        N texels (those of ``texels``), V = the capture's frames, with ``timings`` per stage.

    Raises
    ------
    InputError
        If the capture has no frames.
    """
    timings = dict.fromkeys(STAGES, 0.0)
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
    signals = np.empty((n_texels, n_views, N_SIGNALS), dtype=np.float32)
    _initialise_signals(signals, CONSTANT)
    view_direction = np.zeros((n_texels, n_views, 3), dtype=np.float32)
    weight = np.zeros((n_texels, n_views), dtype=np.float32)
    visible = np.zeros((n_texels, n_views), dtype=bool)
    n_facing = np.zeros(n_texels, dtype=np.int32)

    position = np.ascontiguousarray(texels.position, dtype=np.float64)
    normal = np.ascontiguousarray(texels.normal, dtype=np.float64)
    frame = np.stack([texels.tangent, texels.bitangent, texels.normal], axis=1).astype(np.float64)  # (N, 3, 3) rows
    offset = RAY_OFFSET_TEXELS * texels.texel_size + RAY_OFFSET_OBJECT * _extent(capture.mesh.vertices)
    ray_origin = (position + offset[:, None] * normal).astype(np.float32)  # (N, 3)
    occluder = Occluder(capture.mesh)  # the object, for shadow rays

    with reporter.stage("observing views", n_views) as advance:
        for batch in _view_batches(capture, n_texels):
            tick = time.perf_counter()
            images = np.stack([capture.image(view) for view in batch])  # (B, H, W, 3)
            masks = np.stack([capture.mask(view) for view in batch]).astype(np.float32)[..., None]
            timings["images"] += time.perf_counter() - tick

            tick = time.perf_counter()
            cameras = [capture.frames[view].camera for view in batch]
            camera_to_world = np.stack([camera.camera_to_world for camera in cameras])  # (B, 4, 4)
            centres = np.ascontiguousarray(camera_to_world[:, :3, 3])  # (B, 3)
            intrinsics = np.array([[camera.fx, camera.fy, camera.cx, camera.cy] for camera in cameras])
            pixels = np.empty((n_texels, len(batch), 2))
            cos_theta = np.empty((n_texels, len(batch)))
            seen = np.empty((n_texels, len(batch)), dtype=bool)  # facing; then also unoccluded
            _project_kernel(position, normal, camera_to_world, intrinsics, images.shape[2],
                            images.shape[1], pixels, cos_theta, seen, n_facing)
            timings["projection"] += time.perf_counter() - tick

            tick = time.perf_counter()
            ray_offsets = _sample_offsets(seen)
            origins, directions, distances = _shadow_rays(ray_origin, centres, seen, ray_offsets)
            _clear_occluded(seen, ray_offsets, occluder.hits_rows(origins, directions, distances))
            timings["visibility"] += time.perf_counter() - tick

            tick = time.perf_counter()
            _record_kernel(seen, images, masks, pixels, cos_theta, position, frame, centres, batch.start, signals,
                           view_direction, weight, visible)
            timings["projection"] += time.perf_counter() - tick
            advance(len(batch))

    # The environment in the mirror direction of every sample: lookups of the packed samples, a
    # batch of texels at a time, which bounds the memory of the directions and radiance (fresh
    # memory is slow to map).
    tick = time.perf_counter()
    texels_per_batch = max(1, MIRROR_SAMPLES_PER_BATCH // n_views)
    for first in range(0, n_texels, texels_per_batch):
        rows = slice(first, first + texels_per_batch)
        sample_offsets = _sample_offsets(visible[rows])
        directions = _mirror_directions(frame[rows], view_direction[rows], visible[rows], sample_offsets)
        _unpack_samples(visible[rows], sample_offsets, envmaps.lookup(lit, directions), signals[rows],
                        MIRRORED.start)
    timings["projection"] += time.perf_counter() - tick

    tick = time.perf_counter()
    irradiance = texel_irradiance(capture.envmap, normal)
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
        n_facing=n_facing,
        tangent=texels.tangent.astype(np.float32),
        environment_coeffs=envmaps.envmap_sh(capture.envmap, config.fit.lmax).astype(np.float32),
        environment_radiance=capture.envmap.radiance,
        environment_rotation=capture.envmap.rotation.copy(),
        timings=timings,
    )


# ---------------------------------------------------------------------------------------------
# Irradiance


def texel_irradiance(envmap: envmaps.Envmap, normals: np.ndarray) -> np.ndarray:
    """Compute the irradiance E(n) = integral of L(w) max(0, n.w) dw at world normals.

    The clamped-cosine kernel applied to the map's SH (`freqbrdf.sphere.envmap.irradiance`'s
    method, up to ``IRRADIANCE_LMAX`` of `freqbrdf.sphere.envmap` or what the map resolves),
    synthesised on a lat-long grid of ``IRRADIANCE_MAP_HEIGHT`` rows and read bilinearly
    (METHOD.md §3.5).

    Parameters
    ----------
    envmap : Envmap
        The environment, unfiltered.
    normals : (N, 3) array_like
        Unit world normals.

    Returns
    -------
    (N, 3) float32
        Irradiance per normal and channel.
    """
    height, width = envmap.radiance.shape[:2]
    lmax = min(envmaps.IRRADIANCE_LMAX, height - 2, (width - 1) // 2)
    kernel = envmaps.clamped_cosine_coeffs(lmax)[sh.sh_degrees(lmax)]  # (K,)
    irradiance_coeffs = envmaps.envmap_sh(envmap, lmax) * kernel[:, None]  # (K, 3), world frame
    irradiance_map = envmaps.envmap_from_sh(irradiance_coeffs, max(IRRADIANCE_MAP_HEIGHT, lmax + 2))
    return envmaps.lookup(irradiance_map, normals)


# ---------------------------------------------------------------------------------------------
# Helpers


def texel_alpha_bound(n_samples: np.ndarray, lmax: int, attenuation: float) -> np.ndarray:
    """Return the roughness bound alpha' (appendix eq. 12, METHOD.md §3.4) of each texel.

    alpha' = sqrt(-ln t) / l, with l the usable degree: the smaller of what the texel's n
    samples resolve (l < sqrt(n), `freqbrdf.model.brdf.resolvable_degree`) and the fit's l*
    (spectra carry no information above l*).

    Parameters
    ----------
    n_samples : (N,) int
        Samples per texel.
    lmax : int
        l*, the degree of the fits.
    attenuation : float
        t in (0, 1), the acceptable attenuation (``FitConfig.attenuation_threshold``).

    Returns
    -------
    (N,) float32
        alpha' per texel; inf where fewer than 2 samples (no degree resolved).
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


def _sample_offsets(selected: np.ndarray) -> np.ndarray:
    """Return where each texel's selected entries start when they are packed.

    selected (N, B) bool; packed row-major (texel by texel, views in order). Returns (N + 1,)
    int64 offsets, their total at the end.
    """
    offsets = np.zeros(len(selected) + 1, dtype=np.int64)
    np.cumsum(np.count_nonzero(selected, axis=1), out=offsets[1:])
    return offsets


@numba.njit(parallel=True, cache=True)
def _shadow_rays(ray_origin, centres, seen, offsets):
    """Segments from texels to camera centres, as `Occluder.hits_rows` takes them.

    ray_origin (N, 3) float32; centres (B, 3); one ray per True of seen (N, B), packed at
    `_sample_offsets`. Returns origins (3, M), unit directions (3, M) float32 and lengths (M,)
    float32 that stop just short of the camera (cameras never sit on the surface).
    """
    n_rays = offsets[-1]
    origins = np.empty((3, n_rays), dtype=np.float32)
    directions = np.empty((3, n_rays), dtype=np.float32)
    lengths = np.empty(n_rays, dtype=np.float32)
    for t in numba.prange(seen.shape[0]):
        k = offsets[t]
        for b in range(seen.shape[1]):
            if not seen[t, b]:
                continue
            dx = centres[b, 0] - ray_origin[t, 0]
            dy = centres[b, 1] - ray_origin[t, 1]
            dz = centres[b, 2] - ray_origin[t, 2]
            distance = math.sqrt(dx * dx + dy * dy + dz * dz)
            for axis in range(3):
                origins[axis, k] = ray_origin[t, axis]
            directions[0, k], directions[1, k], directions[2, k] = dx / distance, dy / distance, dz / distance
            lengths[k] = distance * (1.0 - 1e-5)
            k += 1
    return origins, directions, lengths


@numba.njit(parallel=True, cache=True)
def _clear_occluded(seen, offsets, hit):
    """Set seen (N, B) to False where the packed ray of that entry (`_sample_offsets`) hit."""
    for t in numba.prange(seen.shape[0]):
        k = offsets[t]
        for b in range(seen.shape[1]):
            if seen[t, b]:
                if hit[k]:
                    seen[t, b] = False
                k += 1


@numba.njit(parallel=True, cache=True)
def _mirror_directions(frame, view_direction, sampled, offsets):
    """Return the (M, 3) world mirror directions r = 2 (n.v) n - v of the selected samples.

    sampled (N, V) bool selects them, packed at offsets (`_sample_offsets`); frame (N, 3, 3)
    rows t, b, n; view_direction (N, V, 3) local. In the local frame the mirror of (x, y, z)
    about n = z is (-x, -y, z).
    """
    mirror = np.empty((offsets[-1], 3))
    for t in numba.prange(sampled.shape[0]):
        k = offsets[t]
        for v in range(sampled.shape[1]):
            if not sampled[t, v]:
                continue
            x, y, z = -np.float64(view_direction[t, v, 0]), -np.float64(view_direction[t, v, 1]), np.float64(
                view_direction[t, v, 2])
            for axis in range(3):
                mirror[k, axis] = x * frame[t, 0, axis] + y * frame[t, 1, axis] + z * frame[t, 2, axis]
            k += 1
    return mirror


@numba.njit(parallel=True, cache=True)
def _initialise_signals(signals, constant):
    """Set signals (N, V, C) to 0 and channel ``constant`` to 1.

    In parallel and in one contiguous pass, which also maps the fresh memory (faster than
    np.zeros and a strided assignment; docs/measurements.md).
    """
    for t in numba.prange(signals.shape[0]):
        for v in range(signals.shape[1]):
            for k in range(signals.shape[2]):
                signals[t, v, k] = 0.0
            signals[t, v, constant] = 1.0


@numba.njit(parallel=True, cache=True)
def _unpack_samples(sampled, offsets, packed, signals, first_channel):
    """Write the packed row of each selected sample to signals[t, v, first_channel:first_channel + C]."""
    for t in numba.prange(sampled.shape[0]):
        k = offsets[t]
        for v in range(sampled.shape[1]):
            if sampled[t, v]:
                for c in range(packed.shape[1]):
                    signals[t, v, first_channel + c] = packed[k, c]
                k += 1


def _view_batches(capture: Capture, n_texels: int) -> list[range]:
    """Split the views into consecutive batches processed together.

    A batch has one image size (its images are stacked), at most VIEWS_PER_BATCH views, about
    RAYS_PER_BATCH shadow rays and IMAGE_BYTES_PER_BATCH of images.
    """
    cameras = [frame.camera for frame in capture.frames]
    batches, first = [], 0
    for view, camera in enumerate(cameras):
        size = (camera.width, camera.height)
        limit = min(VIEWS_PER_BATCH, max(1, RAYS_PER_BATCH // max(n_texels, 1)),
                    max(1, IMAGE_BYTES_PER_BATCH // (16 * camera.width * camera.height)))
        if view > first and (size != (cameras[first].width, cameras[first].height) or view - first >= limit):
            batches.append(range(first, view))
            first = view
    batches.append(range(first, len(cameras)))
    return batches


@numba.njit(parallel=True, cache=True)
def _project_kernel(position, normal, camera_to_world, intrinsics, width, height,
                    pixels, cos_theta, facing, n_facing):
    """Project texels into a batch of B views (OpenGL cameras, see freqbrdf.capture.camera).

    position, normal (N, 3); camera_to_world (B, 4, 4); intrinsics (B, 4) fx, fy, cx, cy; images
    width x height. Writes pixels (N, B, 2) x, y, cos_theta (N, B) between the normal and the
    direction to the camera, and facing (N, B): in front of the camera, inside the image and
    facing it (cos_theta > 0). Pixels are written where facing only. Adds the facing views of
    each texel to n_facing (N,).
    """
    for t in numba.prange(position.shape[0]):
        for b in range(camera_to_world.shape[0]):
            rotation = camera_to_world[b, :3, :3]
            dx = camera_to_world[b, 0, 3] - position[t, 0]
            dy = camera_to_world[b, 1, 3] - position[t, 1]
            dz = camera_to_world[b, 2, 3] - position[t, 2]
            cosine = (normal[t, 0] * dx + normal[t, 1] * dy + normal[t, 2] * dz) / math.sqrt(
                dx * dx + dy * dy + dz * dz
            )
            cos_theta[t, b] = cosine
            # Camera-space coordinates of the texel: R^T (p - c) = -R^T d; depth along -z.
            local_x = -(rotation[0, 0] * dx + rotation[1, 0] * dy + rotation[2, 0] * dz)
            local_y = -(rotation[0, 1] * dx + rotation[1, 1] * dy + rotation[2, 1] * dz)
            depth = rotation[0, 2] * dx + rotation[1, 2] * dy + rotation[2, 2] * dz
            facing[t, b] = False
            if depth <= 0.0 or cosine <= 0.0:
                continue
            x = intrinsics[b, 2] + intrinsics[b, 0] * local_x / depth
            y = intrinsics[b, 3] - intrinsics[b, 1] * local_y / depth  # camera y up, pixel y down
            if 0.0 <= x <= width and 0.0 <= y <= height:
                pixels[t, b, 0] = x
                pixels[t, b, 1] = y
                facing[t, b] = True
                n_facing[t] += 1


@numba.njit(parallel=True, cache=True)
def _record_kernel(seen, images, masks, pixels, cos_theta, position, frame, centres, first_view, signals,
                   view_direction, weight, visible):
    """Record the samples of a batch of B views, texel by texel (contiguous writes).

    seen (N, B): facing and unoccluded; images (B, H, W, 3), masks (B, H, W, 1) in [0, 1], both
    sampled bilinearly; a sample counts where the mask is 1 at all four neighbours. For counted
    samples writes the observed radiance, local view direction, weight and visibility into columns
    first_view + b of the (N, V, ...) outputs.
    """
    height, width = images.shape[1], images.shape[2]
    for t in numba.prange(seen.shape[0]):
        for b in range(seen.shape[1]):
            if not seen[t, b]:
                continue
            row, col, row_next, col_next, fx, fy = _bilinear_stencil(pixels[t, b, 0], pixels[t, b, 1], height, width)
            if _blend(masks[b], row, col, row_next, col_next, fx, fy, 0) < MASK_INSIDE:
                continue
            view = first_view + b
            for c in range(3):
                signals[t, view, c] = _blend(images[b], row, col, row_next, col_next, fx, fy, c)
            dx = centres[b, 0] - position[t, 0]
            dy = centres[b, 1] - position[t, 1]
            dz = centres[b, 2] - position[t, 2]
            inverse_distance = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
            dx *= inverse_distance
            dy *= inverse_distance
            dz *= inverse_distance
            for axis in range(3):
                view_direction[t, view, axis] = frame[t, axis, 0] * dx + frame[t, axis, 1] * dy + frame[t, axis, 2] * dz
            weight[t, view] = cos_theta[t, b]
            visible[t, view] = True


@numba.njit(inline="always")
def _bilinear_stencil(x, y, height, width):
    """Return the neighbours and fractions for bilinear interpolation at pixel coordinates (x, y).

    Pixel centres lie at (j + 0.5, i + 0.5); the border is clamped (the edge pixel's value holds
    up to half a pixel beyond its centre).
    """
    x = min(max(x - 0.5, 0.0), width - 1.0)
    y = min(max(y - 0.5, 0.0), height - 1.0)
    col = min(int(x), width - 2) if width > 1 else 0
    row = min(int(y), height - 2) if height > 1 else 0
    return row, col, min(row + 1, height - 1), min(col + 1, width - 1), x - col, y - row


@numba.njit(inline="always")
def _blend(image, row, col, row_next, col_next, fx, fy, c):
    top = image[row, col, c] * (1.0 - fx) + image[row, col_next, c] * fx
    bottom = image[row_next, col, c] * (1.0 - fx) + image[row_next, col_next, c] * fx
    return top * (1.0 - fy) + bottom * fy


@numba.njit(parallel=True, cache=True)
def _sample_bilinear(image, pixels, out):  # image (H, W, C); pixels (M, 2) x, y; out (M, C)
    """Bilinear samples of ``image`` at pixel coordinates (see `_bilinear_stencil`)."""
    height, width, channels = image.shape
    for k in numba.prange(pixels.shape[0]):
        row, col, row_next, col_next, fx, fy = _bilinear_stencil(pixels[k, 0], pixels[k, 1], height, width)
        for c in range(channels):
            out[k, c] = _blend(image, row, col, row_next, col_next, fx, fy, c)


# ---------------------------------------------------------------------------------------------
# Maps for people


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
