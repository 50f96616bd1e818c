"""freqbrdf: per-texel Principled BRDF maps and their uncertainty by frequency analysis.

From a known mesh, posed HDR photographs and a known environment map, freqbrdf estimates base
colour, roughness and metallic per texel and how certain each estimate is (docs/method.md). Data
flows one way, one subpackage per stage::

    capture -> texels -> observe -> {estimate, uncertainty} -> applications -> outputs

on a shared foundation: `sphere` (spherical harmonics and environment-map transforms) and
`model` (what a texel reflects under a light). `render` is the only package that speaks to
Mitsuba; `pipeline` runs the stages on one capture, `batch` on many; `synthetic` makes test
captures; `cli` is the command line.

Shape letters used in every docstring:

- T: texture side (maps are T x T); N: texels (valid ones only); V: views;
- K: SH coefficients, (l* + 1)^2, flat index l^2 + l + m; L: degrees, l* + 1;
- R: side of the hypothesis grid (R x R hypotheses); M: rays or points;
- H x W: an image or environment map; C: channels (3 for RGB).
"""

__version__ = "0.2.0"

from freqbrdf._numba_cache import key_cache_by_sources

key_cache_by_sources()  # before any kernel is defined: numba's cache keyed by the kernels' sources

from freqbrdf.errors import InputError  # noqa: E402

__all__ = ["InputError", "__version__"]
