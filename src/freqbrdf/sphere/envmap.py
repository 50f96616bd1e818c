"""Distant environment lighting in Mitsuba 3's ``envmap`` emitter convention, and its SH (docs/method.md#conventions).

Mitsuba 3.9 convention (read in src/emitters/envmap.cpp and verified against the emitter's
``eval`` in tests/test_envmap.py). In the emitter's local frame a direction d, the direction
light arrives FROM, has

    u = atan2(d.x, -d.z) / (2 pi) wrapped into [0, 1),    v = acos(d.y) / pi,

and the emitter's to_world maps local directions to world ones. The bitmap is not resampled:
Mitsuba only appends periodic copies of the first/last column. Column j is centred at
u = (j + 0.5) / W, while row i sits at v = i / (H - 1), so the first and last rows lie ON the poles.
Radiance is bilinear between these samples, periodic in u.

For spherical harmonics the map is read as samples on a Clenshaw-Curtis grid (rings at
theta_i = pi i / (H - 1), both poles included) in the frame E with polar axis = local +y; see
`_EMITTER_FROM_SH_FRAME`. The transforms are `freqbrdf.sht`'s.
"""

from __future__ import annotations

import hashlib
import math
import weakref
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np

from freqbrdf.errors import InputError
from freqbrdf.sphere import harmonics as sh
from freqbrdf.sphere import sht

# Degree for irradiance from SH: the clamped-cosine kernel's even coefficients decay like
# l^(-5/2), so truncating at 20 leaves a small error (the test with a bright, sharp-edged source
# measures the residual; docs/results.md).
IRRADIANCE_LMAX = 20

# Columns are the axes of the SH frame E (polar axis z_E = local +y) in emitter-local coordinates:
# x_E = -z_local, y_E = -x_local, z_E = +y_local (a proper rotation). A local direction with
# Mitsuba angles (theta, phi_m) has E-frame azimuth phi_E = -phi_m.
_EMITTER_FROM_SH_FRAME = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])

# Map samples (maps x rings x columns) per `zonal_filters` synthesis, at most: its complex
# spectra and its float64 maps then take 64 MiB each.
_SYNTHESIS_SAMPLES = 2**23
# What was computed from the last map (`_remembered`): a weak reference to its radiance and the results
# by key (its digest, its SH analysis per degree, its downsampled copies per height). The radiance is then
# read-only, so that an edit in place fails rather than meets stale results.
_LAST_MAP: list = [None, {}]


@dataclass
class Envmap:
    """A distant environment map in Mitsuba 3's ``envmap`` convention (module docstring).

    Attributes
    ----------
    radiance : (H, W, 3) float32
        Linear radiance, row 0 at the top (the north pole, local +y); made C-contiguous, and an
        array of its own (a view is copied). Read-only once a fit has transformed it: edit a copy.
    to_world : (4, 4) float64
        Emitter-to-world transform; its linear part must be a rotation.

    Raises
    ------
    ValueError
        If ``radiance`` is not (H, W, 3) with H, W >= 2, or ``to_world`` is not (4, 4) with a
        rotation as its linear part.
    """

    radiance: np.ndarray
    to_world: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self):
        self.radiance = np.ascontiguousarray(self.radiance, dtype=np.float32)
        if self.radiance.base is not None:  # its own copy: a transform of it is remembered (`_analysis`)
            self.radiance = self.radiance.copy()
        self.to_world = np.asarray(self.to_world, dtype=np.float64)
        if self.radiance.ndim != 3 or self.radiance.shape[2] != 3 or min(self.radiance.shape[:2]) < 2:
            raise ValueError(f"radiance must be (H, W, 3) with H, W >= 2, got {self.radiance.shape}")
        if self.to_world.shape != (4, 4):
            raise ValueError(f"to_world must be (4, 4), got {self.to_world.shape}")
        rotation = self.rotation
        if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
            # Mitsuba would not renormalise a scaled direction before acos(d.y): only rotations
            # keep the lat-long mapping meaningful.
            raise ValueError("the linear part of to_world must be a rotation")

    @property
    def rotation(self) -> np.ndarray:
        """The (3, 3) emitter-to-world rotation (translation is irrelevant for directions)."""
        return self.to_world[:3, :3]



def _aspect(width: int, height: int) -> tuple[int, int]:
    """Return the image's aspect as a small ratio, (4, 3); (0, 0) where it is none of 1:1, 4:3, 3:4, 6:1, 1:6."""
    for ratio in ((1, 1), (4, 3), (3, 4), (6, 1), (1, 6)):
        if width * ratio[1] == height * ratio[0]:
            return ratio
    return (0, 0)

def load_envmap(path: str | Path, to_world: np.ndarray | None = None) -> Envmap:
    """Read an equirectangular HDR map (EXR or Radiance HDR) with a 2:1 aspect ratio.

    Negative noise, which HDR merges and lossy encodings leave near black, is clamped to zero
    (`freqbrdf.images.clamp_negative_noise`); deeper negatives and non-finite pixels are an
    InputError.

    Parameters
    ----------
    path : str or Path
        The image file.
    to_world : (4, 4) array_like or None
        Emitter-to-world transform; None: the identity.

    Returns
    -------
    Envmap
        The (H, 2H, 3) map.

    Raises
    ------
    InputError
        If the map is not 2:1, has non-finite or deeply negative pixels (or cannot be read).
    """
    from freqbrdf.images import clamp_negative_noise, read_image

    radiance = read_image(path)
    height, width = radiance.shape[:2]
    if width != 2 * height:
        shape = {(1, 1): ": a mirror-ball or angular map? ", (4, 3): ": a cube-map cross? ", (3, 4): ": a cube-map cross? ",
                 (6, 1): ": a cube-map strip? ", (1, 6): ": a cube-map strip? "}.get(
            _aspect(width, height), "; ")
        raise InputError(path, f"environment map must be 2:1 (width = 2 x height), got {width}x{height}{shape}"
                               "convert it to an equirectangular (latitude-longitude) map")
    if height < 4:
        raise InputError(path, f"environment map of {width}x{height} pixels is too small (at least 8x4)")
    if not np.isfinite(radiance).all():
        raise InputError(path, f"{int(np.sum(~np.isfinite(radiance)))} non-finite values in the environment map")
    return Envmap(clamp_negative_noise(path, radiance), np.eye(4) if to_world is None else to_world)


# --------------------------------------------------------------------------------------------
# Lookup


@numba.njit(fastmath=False, cache=True)
def map_coordinates(world_to_local, dx, dy, dz, height, width):
    """Return where `lookup` reads a world direction in an H x W map, in texels.

    Column centres lie at x = j (x in [-0.5, W - 0.5)), rows at y = i. Compiled with numba (it
    is called from kernels).

    Parameters
    ----------
    world_to_local : (3, 3) float64
        The map's emitter frame from the world (the transpose of its rotation).
    dx, dy, dz : float
        The unit world direction light arrives from.
    height, width : int
        H and W.

    Returns
    -------
    x, y : float
        Texel coordinates.
    """
    lx = world_to_local[0, 0] * dx + world_to_local[0, 1] * dy + world_to_local[0, 2] * dz
    ly = world_to_local[1, 0] * dx + world_to_local[1, 1] * dy + world_to_local[1, 2] * dz
    lz = world_to_local[2, 0] * dx + world_to_local[2, 1] * dy + world_to_local[2, 2] * dz
    u = math.atan2(lx, -lz) / (2.0 * math.pi)
    u -= math.floor(u)
    v = math.acos(min(max(ly, -1.0), 1.0)) / math.pi
    return u * width - 0.5, v * (height - 1)  # column centres at u = (j + 0.5) / W, rows at v = i / (H - 1)


@numba.njit(fastmath=False, cache=True)
def stencil_at(x, y, height, width):
    """Return the bilinear stencil of `lookup_stencil` at texel coordinates.

    x is periodic, y clamped to the poles' rows. Compiled with numba.

    Parameters
    ----------
    x, y : float
        Texel coordinates (`map_coordinates`).
    height, width : int
        H and W.

    Returns
    -------
    row, col, next_col : int
        The top-left tap and the next column (wrapped); the other two taps are at row + 1.
    column_fraction, row_fraction : float
        The bilinear weights of the next column and of the next row.
    """
    col = math.floor(x)
    col0 = int(col) % width
    y = min(max(y, 0.0), height - 1.0)
    row0 = min(int(y), height - 2)
    return row0, col0, (col0 + 1) % width, x - col, y - row0


@numba.njit(fastmath=False, cache=True)
def lookup_stencil(world_to_local, dx, dy, dz, height, width):
    """Return the bilinear stencil of `lookup` for a world direction in an H x W map.

    Compiled with numba.

    Parameters
    ----------
    world_to_local : (3, 3) float64
        The map's emitter frame from the world (the transpose of its rotation).
    dx, dy, dz : float
        The unit world direction light arrives from.
    height, width : int
        H and W.

    Returns
    -------
    row, col, next_col : int
        The top-left tap and the next column (wrapped); the other two taps are at row + 1.
    column_fraction, row_fraction : float
        The bilinear weights of the next column and of the next row.
    """
    x, y = map_coordinates(world_to_local, dx, dy, dz, height, width)
    return stencil_at(x, y, height, width)


@numba.njit(parallel=True, fastmath=False, cache=True)
def _lookup_kernel(radiance, world_to_local, directions, out):
    height, width = radiance.shape[0], radiance.shape[1]
    for n in numba.prange(directions.shape[0]):
        row0, col0, col1, fx, fy = lookup_stencil(world_to_local, directions[n, 0], directions[n, 1],
                                                  directions[n, 2], height, width)
        for c in range(3):
            top = (1.0 - fx) * radiance[row0, col0, c] + fx * radiance[row0, col1, c]
            bottom = (1.0 - fx) * radiance[row0 + 1, col0, c] + fx * radiance[row0 + 1, col1, c]
            out[n, c] = (1.0 - fy) * top + fy * bottom


def lookup(envmap: Envmap, directions_world: np.ndarray) -> np.ndarray:
    """Look up the radiance arriving FROM unit world directions.

    Exactly what Mitsuba's envmap emitter ``eval`` returns for a ray travelling along
    -direction (bilinear, same sample positions), up to float32 rounding.

    Parameters
    ----------
    envmap : Envmap
        The map.
    directions_world : (..., 3) array_like
        Unit world directions.

    Returns
    -------
    (..., 3) float32
        Radiance per direction.

    Raises
    ------
    ValueError
        If the trailing axis is not 3.
    """
    directions_world = np.asarray(directions_world)
    if directions_world.shape[-1] != 3:
        raise ValueError(f"directions must have a trailing axis of 3, got {directions_world.shape}")
    flat = np.ascontiguousarray(directions_world.reshape(-1, 3), dtype=np.float64)
    out = np.empty(flat.shape, dtype=np.float32)
    _lookup_kernel(envmap.radiance, np.ascontiguousarray(envmap.rotation.T), flat, out)
    return out.reshape(directions_world.shape)


def local_directions(polar: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Return the emitter-local directions at Mitsuba's polar angles and azimuths.

    The map's texel centres lie at polar pi i / (H - 1), azimuth 2 pi (j + 0.5) / W.

    Parameters
    ----------
    polar : (P,) array_like
        Polar angles from local +y.
    azimuth : (A,) array_like
        Azimuths from -z towards +x.

    Returns
    -------
    (P, A, 3) float64
        Unit directions, one per (polar, azimuth) pair.
    """
    return np.stack(
        np.broadcast_arrays(
            np.sin(polar)[:, None] * np.sin(azimuth)[None, :],
            np.cos(polar)[:, None],
            -np.sin(polar)[:, None] * np.cos(azimuth)[None, :],
        ),
        axis=-1,
    )


def downsample(radiance: np.ndarray, height: int) -> np.ndarray:
    """Average a lat-long map down to a coarser one in pixel space.

    Each texel of the coarser grid averages k x k bilinear lookups (k = ceil(H / height) + 1),
    weighted by sin(theta), so that a light smaller than a texel keeps its power and nothing
    rings around it (as an SH resampling would).

    Parameters
    ----------
    radiance : (H, W, 3) array_like
        The map, in Mitsuba's layout.
    height : int
        The coarser map's height.

    Returns
    -------
    (height, 2 height, 3) float32
        The coarser map; a float32 copy of ``radiance`` when ``height`` >= H.
    """
    if height >= radiance.shape[0]:
        return np.array(radiance, np.float32)
    return _remembered(radiance, ("downsample", height), lambda: _downsampled(radiance, height))


def _downsampled(radiance, height: int) -> np.ndarray:
    """`downsample`'s averaging."""
    width = 2 * height
    source = Envmap(np.ascontiguousarray(radiance, np.float32), np.eye(4))
    steps = math.ceil(radiance.shape[0] / height) + 1
    offsets = (np.arange(steps) + 0.5) / steps - 0.5  # texel fractions about the centre
    total = np.zeros((height, width, 3))
    weight_sum = np.zeros((height, 1, 1))
    for row_offset in offsets:
        polar = np.pi * np.clip(np.arange(height) + row_offset, 0.0, height - 1) / (height - 1)
        weight = np.sin(polar)[:, None, None]
        for column_offset in offsets:
            total += weight * lookup(source, local_directions(polar, 2.0 * np.pi * (np.arange(width) + 0.5
                                                                                     + column_offset) / width))
        weight_sum += steps * weight
    return (total / np.maximum(weight_sum, np.finfo(np.float64).tiny)).astype(np.float32)


# --------------------------------------------------------------------------------------------
# Spherical harmonics


def _check_resolution(height: int, width: int, lmax: int) -> None:
    sht.check_resolution(height, width, lmax)


def envmap_sh(envmap: Envmap, lmax: int) -> np.ndarray:
    """SH coefficients (K, 3) float64 of the map in the WORLD frame (`freqbrdf.sphere.harmonics` basis).

    Parameters
    ----------
    envmap : Envmap
        The (H, W, 3) map.
    lmax : int
        The highest degree.

    Returns
    -------
    (K, 3) float64
        World-frame coefficients per channel.

    Raises
    ------
    ValueError
        If the map does not resolve degree ``lmax``.

    Notes
    -----
    The map is read as samples on a Clenshaw-Curtis grid (Mitsuba's rows sit on theta =
    pi i / (H - 1)) and transformed exactly for its band limit (`freqbrdf.sht.analysis`), then
    rotated from the emitter's SH frame into the world frame. Needs lmax <= H - 2 and 2 lmax + 1 <= W.
    """
    coeffs_sh_frame = _analysis(envmap.radiance, lmax)  # (3, K)
    return sh.rotate_sh(coeffs_sh_frame, envmap.rotation @ _EMITTER_FROM_SH_FRAME).T


def envmap_from_sh(
    coeffs: np.ndarray, height: int, width: int | None = None, to_world: np.ndarray | None = None
) -> Envmap:
    """Synthesise an Envmap from world-frame SH coefficients: the inverse of `envmap_sh`.

    The pixels are the band-limited function's exact values at Mitsuba's sample positions.

    Parameters
    ----------
    coeffs : (K, 3) array_like
        World-frame coefficients per channel.
    height : int
        H.
    width : int or None
        W; None: 2 H.
    to_world : (4, 4) array_like or None
        The new map's emitter-to-world transform; None: the identity.

    Returns
    -------
    Envmap
        The (H, W, 3) map.

    Raises
    ------
    ValueError
        If an H x W map does not resolve the coefficients' degree.
    """
    coeffs = np.asarray(coeffs, dtype=np.float64)
    lmax = sh.lmax_of(coeffs.shape[0])
    width = 2 * height if width is None else width
    envmap = Envmap(np.zeros((height, width, 3), np.float32), np.eye(4) if to_world is None else to_world)
    _check_resolution(height, width, lmax)
    coeffs_sh_frame = sh.rotate_sh(coeffs.T, (envmap.rotation @ _EMITTER_FROM_SH_FRAME).T)  # (3, K)
    envmap.radiance[...] = _synthesis(coeffs_sh_frame, height, width)
    return envmap


def _analysis(radiance: np.ndarray, lmax: int) -> np.ndarray:
    """(H, W, 3) map -> (3, K) real SH coefficients in the emitter's SH frame (no rotation).

    The map is read as samples on a Clenshaw-Curtis grid (Mitsuba's rows sit on theta =
    pi i / (H - 1)) and transformed exactly for its band limit (`freqbrdf.sht.analysis`). The
    last map's transforms are remembered (`_remembered`): a fit filters one map several times.
    """
    height, width = radiance.shape[:2]
    _check_resolution(height, width, lmax)

    def transform() -> np.ndarray:
        # Reversed columns run with increasing phi_E = 2 pi (j' + 0.5) / W.
        sh_frame_maps = np.ascontiguousarray(radiance[:, ::-1, :].transpose(2, 0, 1), dtype=np.float64)
        return sht.analysis(sh_frame_maps, lmax, phi0=math.pi / width)

    return _remembered(radiance, ("analysis", lmax), transform)


def radiance_digest(radiance: np.ndarray) -> str:
    """Return a digest of a map's radiance (BLAKE2b, 32 hex digits), remembered for the last map.

    Parameters
    ----------
    radiance : (H, W, 3) array
        The map's radiance (`Envmap.radiance`); an array that owns its data becomes read-only
        (`_remembered`).

    Returns
    -------
    str
        The digest: equal for equal contents.
    """
    return _remembered(radiance, ("digest",), lambda: hashlib.blake2b(
        np.ascontiguousarray(radiance).tobytes(), digest_size=16).hexdigest())


def _remembered(radiance: np.ndarray, key: tuple, compute):
    """Return ``compute()``, remembered for the last map by ``key`` (`_LAST_MAP`); arrays as copies.

    Remembered for an array that owns its data, which is made read-only; a view's results are
    computed each time (its data could change through its base).
    """
    last, results = _LAST_MAP
    remembered = last is not None and last() is radiance and not radiance.flags.writeable
    if not (remembered and key in results):
        value = compute()
        if not (isinstance(radiance, np.ndarray) and radiance.base is None):
            return value
        radiance.flags.writeable = False
        if not remembered:
            _LAST_MAP[:] = [weakref.ref(radiance), {}]
        _LAST_MAP[1][key] = value
    value = _LAST_MAP[1][key]
    return value.copy() if isinstance(value, np.ndarray) else value


def _synthesis(coeffs_sh_frame: np.ndarray, height: int, width: int, out: np.ndarray | None = None) -> np.ndarray:
    """Invert `_analysis`: (..., 3, K) SH-frame coefficients -> (..., H, W, 3) float32 maps.

    Written to ``out`` if given.
    """
    coeffs_sh_frame = np.asarray(coeffs_sh_frame, dtype=np.float64)
    lmax = sh.lmax_of(coeffs_sh_frame.shape[-1])
    _check_resolution(height, width, lmax)
    leading = coeffs_sh_frame.shape[:-2]
    sh_frame_maps = sht.synthesis(coeffs_sh_frame.reshape(-1, coeffs_sh_frame.shape[-1]), height, width,
                                  phi0=math.pi / width)  # (n 3, H, W)
    radiance = np.moveaxis(sh_frame_maps.reshape(leading + (3, height, width))[..., ::-1], -3, -1)
    if out is None:
        return np.ascontiguousarray(radiance, dtype=np.float32)
    out[...] = radiance
    return out


def lowpass_envmap(envmap: Envmap, sigma: float) -> Envmap:
    """Low-pass a map by exp(-(sigma l)^2) in SH (the band limit of docs/method.md#band-limit).

    Degrees are kept up to where the filter falls below 1e-6 (l = 3.7 / sigma), or the map's
    own limit if lower.

    Parameters
    ----------
    envmap : Envmap
        The (H, W, 3) map.
    sigma : float
        The filter's width; <= 0 returns an unfiltered copy.

    Returns
    -------
    Envmap
        The filtered (H, W, 3) map, same to_world.
    """
    if sigma <= 0:
        return Envmap(envmap.radiance.copy(), envmap.to_world.copy())
    height, width = envmap.radiance.shape[:2]
    lmax = min(math.ceil(math.sqrt(-math.log(1e-6)) / sigma), height - 2, (width - 1) // 2)
    return zonal_filter(envmap, np.exp(-(sigma * np.arange(lmax + 1)) ** 2))


def zonal_filter(envmap: Envmap, gains: np.ndarray) -> Envmap:
    """Filter a map by gains per SH degree, degrees above dropped.

    The convolution with a kernel rotationally symmetric about each direction.

    Parameters
    ----------
    envmap : Envmap
        The (H, W, 3) map.
    gains : (L,) array_like
        gains[l] scales the degree-l components; L - 1 must not exceed the map's own limit
        (lmax <= H - 2 and 2 lmax + 1 <= W).

    Returns
    -------
    Envmap
        The filtered (H, W, 3) map, same to_world.

    Raises
    ------
    ValueError
        If the map does not resolve degree L - 1.
    """
    return Envmap(zonal_filters(envmap, np.asarray(gains)[None])[0], envmap.to_world.copy())


def zonal_filters(envmap: Envmap, gains: np.ndarray, height: int | None = None) -> np.ndarray:
    """Filter a map by several sets of gains per SH degree, with one analysis for all.

    Parameters
    ----------
    envmap : Envmap
        The (H, W, 3) map.
    gains : (M, L) array_like
        One `zonal_filter` per row.
    height : int or None
        Resample to height x 2 height pixels (same convention; needs L - 1 <= height - 2);
        None: the map's own H x W.

    Returns
    -------
    (M, H, W, 3) float32
        The filtered maps' radiance (H, W those of ``height`` when given).

    Raises
    ------
    ValueError
        If the map or the output size does not resolve degree L - 1.
    """
    gains = np.asarray(gains, dtype=np.float64)
    height, width = envmap.radiance.shape[:2] if height is None else (height, 2 * height)
    lmax = gains.shape[1] - 1
    # The filter is zonal, so it commutes with rotations: filter in the map's own SH frame and
    # skip the two rotations to and from the world frame (dense and slow at high degree).
    coeffs = _analysis(envmap.radiance, lmax)  # (3, K)
    # Each filter is synthesised up to its last nonzero gain, several filters per synthesis (they
    # share its Legendre functions) as long as they keep its complex spectra within
    # _SYNTHESIS_SAMPLES and need at least half its degrees.
    nonzero = gains != 0.0
    last = np.where(nonzero.any(axis=1), gains.shape[1] - 1 - np.argmax(nonzero[:, ::-1], axis=1), 0)
    chunk = max(1, _SYNTHESIS_SAMPLES // (3 * height * width))
    out = np.empty((len(gains), height, width, 3), np.float32)
    first = 0
    while first < len(gains):
        stop = first + 1
        while stop < min(first + chunk, len(gains)) and 2 * last[stop] >= last[first] and last[stop] <= last[first]:
            stop += 1
        degrees = int(last[first])  # the group's most
        n_coeffs = (degrees + 1) ** 2
        gains_by_degree = np.ascontiguousarray(gains[first: stop, sh.sh_degrees(degrees)].T)  # (K, n)
        # (K, n, 3), by flat index first: the layout the synthesis reads, so it need not transpose
        part = gains_by_degree[:, :, None] * coeffs.T[:n_coeffs, None, :]
        count = part.shape[1]
        _synthesis(part.reshape(len(part), -1).T.reshape(count, 3, -1), height, width, out=out[first: stop])
        first = stop
    return out


def clamped_cosine_coeffs(lmax: int) -> np.ndarray:
    """Return the Funk-Hecke eigenvalues a_l of the kernel max(0, cos): E_lm = a_l L_lm.

    a_l = 2 pi int_0^1 t P_l(t) dt: a_0 = pi, a_1 = 2 pi / 3, 0 for odd l > 1, and for even l
    a_l = 2 pi (-1)^(l/2 - 1) / ((l + 2)(l - 1)) * binom(l, l/2) / 2^l.

    Parameters
    ----------
    lmax : int
        The highest degree.

    Returns
    -------
    (L,) float64
        a_0 .. a_lmax.
    """
    kernel = np.zeros(lmax + 1)
    kernel[0] = math.pi
    if lmax >= 1:
        kernel[1] = 2.0 * math.pi / 3.0
    for degree in range(2, lmax + 1, 2):
        kernel[degree] = (
            2.0 * math.pi * (-1.0) ** (degree // 2 - 1) / ((degree + 2) * (degree - 1))
            * math.comb(degree, degree // 2) / 2.0**degree
        )
    return kernel


def irradiance(env_coeffs: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Compute the irradiance E(n) = int L(w) max(0, n.w) dw from world-frame SH (docs/method.md#irradiance).

    Exact for the band-limited part of L; the truncation error is that of the omitted degrees
    (use lmax >= IRRADIANCE_LMAX).

    Parameters
    ----------
    env_coeffs : (K, 3) array_like
        The environment's world-frame coefficients per channel.
    normals : (N, 3) array_like
        Unit world normals.

    Returns
    -------
    (N, 3) float32 or float64
        Irradiance per normal and channel; float32 for float32 normals, else float64.
    """
    env_coeffs = np.asarray(env_coeffs)
    lmax = sh.lmax_of(env_coeffs.shape[0])
    irradiance_coeffs = env_coeffs * clamped_cosine_coeffs(lmax)[sh.sh_degrees(lmax)][:, None]  # (K, 3)
    basis = sh.eval_sh(normals, lmax)  # (N, K)
    return basis @ irradiance_coeffs.astype(basis.dtype)
