"""freqbrdf: per-texel Principled BRDF estimation and its uncertainty by frequency analysis.

Stages (one module each, data flows one way):
capture -> texels -> observations -> sh spectra -> {estimate, uncertainty} -> applications -> outputs.
"""

__version__ = "0.1.0"

from freqbrdf.errors import InputError

__all__ = ["InputError", "__version__"]
