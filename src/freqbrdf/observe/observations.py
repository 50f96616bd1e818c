"""Observations: from a capture to per-texel samples and their SH spectra (docs/method.md#observations to docs/method.md#irradiance).

For every texel and view, `observe` records in the mirror parameterisation of docs/method.md#conventions:

- the view direction w_o in the texel's local frame (t, b, n),
- the observed radiance (the image, bilinearly sampled where the texel projects),
- the environment radiance in the mirror direction r = 2 (n.v) n - v (band-limited, see below),
- the weight w = max(0, cos theta_o) x visible x inside the image and its mask,
- which channels of a sample a clipped pixel censors (`freqbrdf.images.clipped_channels`: a
  value on a clipping plateau is a lower bound, docs/method.md#censored-samples); such a sample
  keeps weight 0 until `freqbrdf.estimate.censored.impute_censored` fills its censored channels.

Dark texels are observations like any other: only the weight decides what counts as a sample,
and the weight depends on geometry alone, never on the radiance. Visibility (docs/method.md#observations) is a shadow
ray from the texel (offset along its normal by a scale-aware epsilon) to the camera centre,
traced by `freqbrdf.render.occluder.Occluder`; the rays of several views go in one batch.

Then, per texel, one weighted regularised SH fit (docs/method.md#sh-fit, `freqbrdf.sphere.harmonics.fit_sh`) of
seven signals on the same samples: observed RGB, mirrored environment RGB and the constant 1
(whose fit carries the diffuse term through the fit, docs/method.md#forward-model). Band limit (docs/method.md#band-limit): the environment is
low-passed with exp(-(sigma l)^2), sigma = 1/floor(sqrt(V)) for V views, before it is looked up,
and the BRDF kernel divides that blur back out (`freqbrdf.model.brdf.brdf_kernel`). Irradiance
(docs/method.md#irradiance) comes from the environment's SH with the clamped-cosine kernel
(`freqbrdf.observe.irradiance.texel_irradiance`), corrected where the object hides its own
environment (`freqbrdf.observe.occlusion`, ``ObserveConfig.environment_occlusion``). The numba
kernels of the stage are in `freqbrdf.observe._kernels`; `freqbrdf.observe.maps.write_maps` draws an `Observations`' coverage
and visibility in texture space, for people.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numba
import numpy as np

from freqbrdf.capture.layouts import Capture, read_frame_image, read_frame_mask
from freqbrdf.capture.lens import distort_pixels
from freqbrdf.config import Config
from freqbrdf.errors import InputError
from freqbrdf.fileio import atomic_path
from freqbrdf.images import clipped_channels
from freqbrdf.model import brdf
from freqbrdf.observe._kernels import (
    _clear_occluded,
    _initialise_signals,
    _mirror_directions,
    _project_kernel,
    _record_kernel,
    _sample_offsets,
    _shadow_rays,
    _unpack_samples,
)
from freqbrdf.observe.irradiance import texel_irradiance
from freqbrdf.observe.occlusion import (
    may_be_hidden,
    mirror_occlusion,
    occluded_irradiance,
    occlusion_steps,
    self_occluding,
    uv_texels,
)
from freqbrdf.observe.signals import (
    CONSTANT,
    MIRRORED,
    N_SIGNALS,
    OBSERVED,
    fit_signals,
    mean_over_views,
    texel_alpha_bound,
)
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
# Views projected, traced and sampled together (within RAYS_PER_BATCH shadow rays and this many
# bytes of stacked images and masks), so that each texel writes its samples contiguously.
VIEWS_PER_BATCH = 16
IMAGE_BYTES_PER_BATCH = 512 << 20
# Samples whose mirrored environment is looked up together (24 bytes of direction, 12 of radiance each).
MIRROR_SAMPLES_PER_BATCH = 1 << 21
# Texels per call of the SH fit: the progress bar's step.
FIT_BLOCK = 16384

STAGES = ("raster", "projection", "visibility", "images", "irradiance", "occlusion", "fits")
# The array fields of Observations that are not per texel.
_SHARED_ARRAYS = ("environment_coeffs", "environment_radiance", "environment_rotation")
# Per texel and view (N, V, ...).
_SAMPLE_ARRAYS = ("view_direction", "observed", "mirrored", "weight", "visible", "mirror_occluded", "mirror_surface",
                  "censored", "censored_weight")
# SH coefficients per texel (N, ..., K).
_COEFFICIENT_ARRAYS = ("observed_coeffs", "mirrored_coeffs", "constant_coeffs")


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
        E = integral of L(w) max(0, n.w) dw (docs/method.md#irradiance).
    lmax : int
        l*, the degree of the SH fits.
    sigma : float
        Band-limit width applied to the environment (docs/method.md#band-limit); 0: none.
    observed_coeffs : (N, 3, K) float32
        SH fit of the observed radiance.
    mirrored_coeffs : (N, 3, K) float32
        SH fit of the mirrored environment.
    constant_coeffs : (N, K) float32
        SH fit of the constant 1 on the same samples (the diffuse response, docs/method.md#forward-model).
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
    mirror_occluded : (N, V) float32 or None
        The share of each sample's mirror lobe that meets the object itself, not the environment
        (`freqbrdf.observe.occlusion.mirror_occlusion`). None where not traced.
    mirror_surface : (N, V, 3) float32 or None
        What the object shows there: the mean observed radiance of its texels nearest the hits
        (0 where nothing is hit). None where not traced.
    censored : (N, V, 3) bool or None
        The channels of each sample read from a clipped pixel: ``observed`` holds a lower bound
        there (docs/method.md#censored-samples). None where no photograph is clipped.
    censored_weight : (N, V) float32 or None
        The weight of the samples with a censored channel, which ``weight`` holds at 0 until
        `freqbrdf.estimate.censored.impute_censored` fills those channels (it then moves them
        into ``weight`` and sets this to None). None where no photograph is clipped.
    observed_power, mirrored_power : (N, 3, L) float32 or None
        The power spectra of observations whose SH coefficients were left out (`texel_fields`:
        K = 0); None where the coefficients are kept (the spectra are computed from them).
    timings : dict
        Seconds per stage of `observe` (``STAGES`` and ``"total"``).
    texels : Texels or None
        The texels observed (`freqbrdf.texels.rasterise` at ``texture_res``), so that later stages
        need not rasterise the mesh again; None where the rows are a selection of them
        (`select`, `texel_fields`) or the observations were read from a file.
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
    mirror_occluded: np.ndarray | None = None
    mirror_surface: np.ndarray | None = None
    censored: np.ndarray | None = None
    censored_weight: np.ndarray | None = None
    observed_power: np.ndarray | None = None
    mirrored_power: np.ndarray | None = None
    timings: dict = field(default_factory=dict)
    texels: Texels | None = field(default=None, repr=False)

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
        """(N, 3, L) power spectrum of the observed radiance (docs/method.md#conventions), in its coefficients' float type."""
        return sh.power_spectrum(self.observed_coeffs) if self.observed_power is None else self.observed_power

    @property
    def mirrored_spectrum(self) -> np.ndarray:
        """(N, 3, L) power spectrum of the mirrored environment (docs/method.md#conventions), in its coefficients' float type."""
        return sh.power_spectrum(self.mirrored_coeffs) if self.mirrored_power is None else self.mirrored_power

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
        return replace(self, **changes, texels=None)

    def at_most_views(self, max_views: int) -> Observations:
        """Return the observations with at most ``max_views`` samples a texel, evenly over its views.

        A texel's samples (views with a weight or a censored weight) beyond ``max_views`` are
        thinned to ``max_views`` spread evenly over the views' order; the per-sample arrays hold
        each texel's kept samples first, then slots of weight 0, so that the view axis no longer
        names the photographs. The per-texel arrays (its SH fits from every sample among them)
        are kept but ``n_samples``, which counts the kept samples.

        Parameters
        ----------
        max_views : int
            The most samples kept a texel, at least 2.

        Returns
        -------
        Observations
            N texels, min(V, max_views) slots; the same object where no texel has more samples.
        """
        has_sample = self.weight > 0
        if self.censored_weight is not None:
            has_sample |= self.censored_weight > 0
        counts = np.count_nonzero(has_sample, axis=1)
        if max_views < 2 or counts.max(initial=0) <= max_views:
            return self
        slot = np.arange(max_views)
        order = np.argsort(~has_sample, axis=1, kind="stable")  # each texel's samples first, in the views' order
        spread = np.rint(slot[None, :] * ((counts[:, None] - 1) / (max_views - 1))).astype(np.int64)
        views = np.take_along_axis(order, np.where(counts[:, None] > max_views, spread, slot[None, :]), axis=1)
        changes = {}
        for name in _SAMPLE_ARRAYS:
            array = getattr(self, name)
            if array is not None:
                index = views.reshape(views.shape + (1,) * (array.ndim - 2))
                changes[name] = np.take_along_axis(array, index, axis=1)
        n_samples = np.count_nonzero(changes["weight"] > 0, axis=1).astype(self.n_samples.dtype)
        return replace(self, **changes, n_samples=n_samples)

    def texel_fields(self, rows) -> Observations:
        """Return the per-texel fields of some of the texels, without their samples.

        Like `select`, but the per-sample arrays (view direction, observed, mirrored, weight,
        visible) are kept with no view (V = 0), and the SH coefficients with no coefficient
        (K = 0), their power spectra kept instead (``observed_power``, ``mirrored_power``);
        everything else per texel (counts, normals, irradiance) is indexed. For outputs on other
        texels than the ones observed (`freqbrdf.pipeline.to_texels`), where copying every
        sample and coefficient would cost more than the estimate.

        Parameters
        ----------
        rows : (n,) int array, slice or (N,) bool
            The texels to keep: indices, a slice or a boolean mask over the N texels.

        Returns
        -------
        Observations
            The n texels selected, with V = 0.
        """
        changes = {"observed_power": self.observed_spectrum, "mirrored_power": self.mirrored_spectrum}
        for item in fields(self):
            value = changes.get(item.name, getattr(self, item.name))
            if isinstance(value, np.ndarray) and item.name not in _SHARED_ARRAYS:
                if item.name in _SAMPLE_ARRAYS:
                    value = value[:, :0]
                elif item.name in _COEFFICIENT_ARRAYS:
                    value = value[..., :0]
                changes[item.name] = value[rows]
        return replace(self, **changes, texels=None)

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
        fit = fit_signals(self.view_direction, weight, self.observed, self.mirrored, self.lmax, config)
        settings = config.fit
        censored_weight = None if self.censored_weight is None else np.where(keep, self.censored_weight, 0.0).astype(
            np.float32)
        return replace(
            self, weight=weight, visible=self.visible & keep, censored_weight=censored_weight,
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
                  if f.name not in ("timings", "texels") and getattr(self, f.name) is not None}
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
                          if f.name not in ("timings", "texels") and (f.name in data or f.default is not None)}
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

    The stage of docs/method.md#observations to docs/method.md#irradiance (module docstring): projection, visibility, bilinear image
    samples, the band-limited environment in the mirror directions, the irradiance and one
    regularised SH fit per texel of the observed radiance, the mirrored environment and the
    constant 1.

    Parameters
    ----------
    capture : Capture
        The posed images, their masks, the mesh and the environment map.
    config : Config
        ``config.texels.texture_res`` sets T when ``texels`` is None; ``config.fit`` the degree
        l*, the regulariser, the band limit and alpha's attenuation threshold; ``config.device``
        where the SH fits run.
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

    Examples
    --------
    A tiny synthetic capture (six 24 x 24 views of a sphere) observed on 32 x 32 texels; the
    sphere's atlas fills the texture, so N = 1024:

    >>> import tempfile
    >>> from pathlib import Path
    >>> from freqbrdf.capture import load
    >>> from freqbrdf.config import Config, TexelConfig
    >>> from freqbrdf.observe import observe
    >>> from freqbrdf.synthetic import example_capture
    >>> work = tempfile.TemporaryDirectory()
    >>> capture = load(example_capture(Path(work.name) / "capture"))
    >>> observations = observe(capture, Config(texels=TexelConfig(texture_res=32)))
    >>> observations.observed.shape, observations.observed.dtype  # (N, V, 3)
    ((1024, 6, 3), dtype('float32'))
    >>> observations.weight.shape, observations.irradiance.shape  # (N, V), (N, 3)
    ((1024, 6), (1024, 3))
    >>> observations.lmax, observations.observed_coeffs.shape  # (N, 3, K), K = (l* + 1)^2
    (5, (1024, 3, 36))
    >>> bool((observations.n_samples <= 6).all())  # samples per texel: at most one a view
    True
    >>> work.cleanup()
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
    # Made at the first clipped photograph (most captures have none).
    censored, censored_weight = np.zeros((0, 0, 3), dtype=bool), np.zeros((0, 0), dtype=np.float32)
    no_ceilings = np.zeros((0, 0, 0, 3), dtype=np.float32)

    position = np.ascontiguousarray(texels.position, dtype=np.float64)
    normal = np.ascontiguousarray(texels.normal, dtype=np.float64)
    frame = np.stack([texels.tangent, texels.bitangent, texels.normal], axis=1).astype(np.float64)  # (N, 3, 3) rows
    offset = RAY_OFFSET_TEXELS * texels.texel_size + RAY_OFFSET_OBJECT * _extent(capture.mesh.vertices)
    ray_origin = (position + offset[:, None] * normal).astype(np.float32)  # (N, 3)
    # A mesh that cannot hide part of itself (convex or flat) hides no facing texel from a camera:
    # shadow rays only for the others.
    occluder = _occluder(capture.mesh) if self_occluding(capture.mesh.vertices, capture.mesh.faces) else None

    with reporter.stage("observing views", n_views) as advance:
        for batch in _view_batches(capture, n_texels):
            tick = time.perf_counter()
            # As photographed: a frame with a lens is read where the lens puts each texel (`_through_lenses`).
            images = np.stack([read_frame_image(capture.frames[view], as_taken=True) for view in batch])  # (B, H, W, 3)
            masks = np.stack([read_frame_mask(capture.frames[view], as_taken=True)
                              for view in batch]).astype(np.float32)[..., None]
            # Clipped channels (8-bit data, blown highlights) are lower bounds: censored samples.
            ceilings = np.stack([clipped_channels(image) for image in images])
            if ceilings.any():
                if censored.shape[0] == 0:
                    censored = np.zeros((n_texels, n_views, 3), dtype=bool)
                    censored_weight = np.zeros((n_texels, n_views), dtype=np.float32)
                ceilings = ceilings.astype(np.float32)
            else:
                ceilings = no_ceilings
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
            _through_lenses([capture.frames[view] for view in batch], pixels, seen, n_facing)
            timings["projection"] += time.perf_counter() - tick

            tick = time.perf_counter()
            if occluder is not None:
                ray_offsets = _sample_offsets(seen)
                origins, directions, distances = _shadow_rays(ray_origin, centres, seen, ray_offsets)
                _clear_occluded(seen, ray_offsets, occluder.hits_rows(origins, directions, distances))
            timings["visibility"] += time.perf_counter() - tick

            tick = time.perf_counter()
            _record_kernel(seen, images, masks, ceilings, pixels, cos_theta, position, frame, centres, batch.start,
                           signals, view_direction, weight, visible, censored, censored_weight)
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
    mirror_occluded = mirror_surface = None
    if config.observe.environment_occlusion and occluder is not None:
        with reporter.stage("tracing the object's shadows", occlusion_steps(n_texels, n_views)) as advance:
            surface_radiance = mean_over_views(weight, signals[..., OBSERVED])
            observed = weight.sum(axis=1) > 0
            # Rays that leave upwards from a texel above all of the mesh meet nothing: not traced.
            hidden = may_be_hidden(ray_origin, normal, capture.mesh.vertices)
            uv = uv_texels(capture.mesh.uv, capture.mesh.faces, texels.mask)
            irradiance = occluded_irradiance(occluder, capture.envmap, irradiance, ray_origin, frame,
                                             surface_radiance, observed, texels.texel_size, advance, hidden, uv)
            mirror_occluded, mirror_surface = mirror_occlusion(occluder, ray_origin, frame, view_direction, visible,
                                                              surface_radiance, observed, texels.texel_size, advance,
                                                              hidden, uv)
    if occluder is not None:
        occluder.release_memory()  # the rays' buffers: the stages after this one trace nothing
    timings["occlusion"] = time.perf_counter() - tick

    tick = time.perf_counter()
    # In blocks of texels, so that the bar moves; each texel's fit is its own, whatever the blocks.
    blocks = [slice(start, start + FIT_BLOCK) for start in range(0, max(len(weight), 1), FIT_BLOCK)]
    with reporter.stage("fitting SH spectra", len(blocks)) as advance:
        # Each block's coefficients written in place: no second copy of them all (fresh memory is slow to map).
        single = all(array.dtype == np.float32 for array in (view_direction, weight, signals))
        coeffs = np.empty((len(weight), signals.shape[2], sh.num_coeffs(config.fit.lmax)),
                          np.float32 if single else np.float64)
        parts = []
        for rows in blocks:
            parts.append(sh.fit_sh(
                view_direction[rows], weight[rows], signals[rows], config.fit.lmax, config.fit.reg_lambda,
                config.fit.regulariser, config.fit.scale_lambda_with_weight, config.device, coeffs_out=coeffs[rows],
            ))
            advance(1)
    fit = sh.SHFit(coeffs, *(np.concatenate([getattr(part, name) for part in parts]) for name in ("n_samples", "status")))
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
        mirror_occluded=mirror_occluded,
        mirror_surface=mirror_surface,
        censored=censored if len(censored) else None,
        censored_weight=censored_weight if len(censored_weight) else None,
        timings=timings,
        texels=texels,
    )


# ---------------------------------------------------------------------------------------------
# Helpers

def _through_lenses(frames: list, pixels: np.ndarray, seen: np.ndarray, n_facing: np.ndarray) -> None:
    """Move the projected pixels (N, B, 2) of the batch's frames that have a lens to where it images them.

    A texel the lens puts outside its photograph is no longer seen there (``seen`` (N, B) and ``n_facing`` (N,)).
    """
    for b, photograph in enumerate(frames):
        if photograph.lens is None:
            continue
        rows = np.flatnonzero(seen[:, b])
        camera = photograph.camera
        x, y = distort_pixels(pixels[rows, b, 0], pixels[rows, b, 1], camera, photograph.lens)
        pixels[rows, b, 0], pixels[rows, b, 1] = x, y
        outside = (x < 0.0) | (x > camera.width) | (y < 0.0) | (y > camera.height)
        seen[rows[outside], b] = False
        n_facing[rows[outside]] -= 1


# The last mesh loaded for ray tests and its `Occluder`: calibration and observation trace the same
# mesh, and building the ray-tracing scene is a share of a fit.
_LAST_OCCLUDER: list = []


def _occluder(mesh) -> Occluder:
    """Return an `Occluder` of ``mesh``, the last one made when it was made for this very mesh object.

    It traces on the threads the fit's kernels run on (``NUMBA_NUM_THREADS``: a batch task's CPUs).
    """
    if not (_LAST_OCCLUDER and _LAST_OCCLUDER[0] is mesh):
        _LAST_OCCLUDER[:] = [mesh, Occluder(mesh)]
    _LAST_OCCLUDER[1].set_threads(numba.get_num_threads())
    return _LAST_OCCLUDER[1]


def _extent(vertices: np.ndarray) -> float:
    """Diagonal of the bounding box: the object's scale."""
    return float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))


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
