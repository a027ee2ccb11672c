"""Image-quality measures of the paper's Appendix "Quality measures" and §4.

- :mod:`.roi` — regions of interest: a disc intersected with the pixels above a
  threshold of the reference, and the bounding rectangle of a region.
- :mod:`.correlation` — the correlation coefficient (paper eq. (A1)) within a region.
- :mod:`.sharpness` — the normalised Tenenbaum sharpness (Sobel, paper Appendix).
- :mod:`.projections` — maximum-intensity projections (MIPs) along each axis.
- :mod:`.resolution` — axial FWHM by a Lorentz (Cauchy) fit to a line-spread profile,
  lateral FWHM by an arctan edge-spread fit (paper §4), peak side-lobe level.
- :mod:`.curves` — "CC vs number of pixels of interest" and "CC vs ROI diameter"
  (paper §7, Figs. "Correlation coefficient ...").

Pure numpy/scipy; no I/O. The names load on first use (PEP 562): the sharpness and the
fits import scipy.ndimage and scipy.optimize (about 1.2 s of a fresh interpreter), which the
MIP pictures of every result (`fpscan.service.pictures.render`) do not need.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

_LAZY = {"correlation_coefficient": "correlation", "cc_vs_diameter": "curves", "cc_vs_pixels": "curves",
         "sharpness_vs_diameter": "curves", "mip": "projections", "mips": "projections",
         "EdgeFit": "resolution", "LorentzFit": "resolution", "edge_spread": "resolution",
         "fit_edge_spread": "resolution", "fit_lorentz": "resolution", "lorentz": "resolution",
         "side_lobe_level": "resolution", "bounding_box": "roi", "disc_mask": "roi", "roi_mask": "roi",
         "tenenbaum_sharpness": "sharpness"}

if TYPE_CHECKING:
    from fpscan.service.metrics.correlation import correlation_coefficient
    from fpscan.service.metrics.curves import cc_vs_diameter, cc_vs_pixels, sharpness_vs_diameter
    from fpscan.service.metrics.projections import mip, mips
    from fpscan.service.metrics.resolution import (
        EdgeFit,
        LorentzFit,
        edge_spread,
        fit_edge_spread,
        fit_lorentz,
        lorentz,
        side_lobe_level,
    )
    from fpscan.service.metrics.roi import bounding_box, disc_mask, roi_mask
    from fpscan.service.metrics.sharpness import tenenbaum_sharpness

__all__ = [
    "EdgeFit",
    "LorentzFit",
    "bounding_box",
    "cc_vs_diameter",
    "cc_vs_pixels",
    "correlation_coefficient",
    "disc_mask",
    "edge_spread",
    "fit_edge_spread",
    "fit_lorentz",
    "lorentz",
    "mip",
    "mips",
    "roi_mask",
    "sharpness_vs_diameter",
    "side_lobe_level",
    "tenenbaum_sharpness",
]


def __getattr__(name: str) -> Any:
    """Each measure from its module, on first use."""
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
