"""``linear``, ``nearest``, ``cubic``: FFT on the regular frequency grid + interpolation onto
the k-space image (k-Wave style; one algorithm, the interpolation its parameter; kernel:
:func:`fpscan.service.recon.planar.reconstruct_grid`). For comparison with NER-NUFFT."""
from __future__ import annotations

from collections.abc import Callable
from functools import partial

from fpscan.service.recon.methods.ner import run_grid
from fpscan.service.recon.methods.options import DepthOptions, MethodOptions, PositivityOption, UpsampleOption
from fpscan.service.recon.methods.registry import Method
from fpscan.service.recon.methods.work import peak_model, planar_work

__all__ = ["Options", "KINDS", "WORK_RATES", "TEMPORAL_STEPS", "METHODS", "LINEAR", "NEAREST", "CUBIC"]


class Options(DepthOptions, PositivityOption, UpsampleOption, MethodOptions):
    """Options of the FFT + interpolation methods (no NUFFT tolerance).

    Attributes
    ----------
    dtype : {"float32", "float64"}
        Working and output precision (default ``"float32"``).
    upsample : int
        Lateral upsampling factor 1..8 (default 1).
    positivity : bool
        Clip negative p0 to 0 (default False).
    n_z : int or None
        Output depth samples, 2..65536 (None: down to c t_last; ``fpscan.service.recon.depth``).
    dz : float or None
        Output depth spacing in m, [1e-9, 0.1] (None: the lateral pitch, c dt where that is finer).

    References
    ----------
    .. [1] M. Xu, D. Feng, L. V. Wang, "Exact frequency-domain reconstruction for
       thermoacoustic tomography: I. Planar geometry", IEEE Trans. Med. Imaging 21 (2002).

    Examples
    --------
    >>> from pydantic import ValidationError
    >>> from fpscan.service.recon.methods import METHODS
    >>> from fpscan.service.recon.methods.interp import Options
    >>> [m for m in METHODS if METHODS[m].options_model is Options]
    ['linear', 'nearest', 'cubic']
    >>> Options(n_z=32).n_z
    32
    >>> try:
    ...     Options(eps=1e-6)  # no NUFFT here
    ... except ValidationError as exc:
    ...     print(exc.errors()[0]["type"])
    extra_forbidden
    """


#: name -> (title, source)
KINDS = {
    "linear": ("FFT + linear interpolation (k-Wave style)", "FFT on the regular frequency grid + linear interpolation"),
    "nearest": ("FFT + nearest-neighbour interpolation",
                "FFT on the regular frequency grid + nearest-neighbour interpolation"),
    "cubic": ("FFT + cubic (pchip) interpolation",
              "FFT on the regular frequency grid + pchip interpolation (not linear in the data: pchip's slopes "
              "depend on the values, so a sum's image is not the sum of the images, nor a mirrored scan's the "
              "mirror image: 0.45 % of a point source's image, 3 % on white noise)"),
}

#: seconds of work per ``transform_units`` unit (float32, the reference 2 cores; ``planar_work``):
#: measured 1.0-2.0e-9 (linear, nearest) and 3.1-3.4e-8 (cubic: pchip per column group) from
#: 256 x 64^2 to 512 x 226^2 at load 5, float64 1.1-2.4x; the largest, rounded up
WORK_RATES = {"linear": 3e-9, "nearest": 3e-9, "cubic": 4e-8}

_run: Callable = run_grid
#: each method's temporal step in the memory model (``fpscan.service.recon.memory.planar_peak``)
TEMPORAL_STEPS = {"linear": "regular", "nearest": "regular", "cubic": "pchip"}
#: the three methods, in :data:`KINDS`' order (each named by an entry point of ``fpscan.methods``)
METHODS = [Method(name=name, title=title, needs_grid=True, options_model=Options, run=partial(_run, name),
                  source=source, peak_memory=peak_model("planar_peak", temporal=TEMPORAL_STEPS[name]),
                  order=30 + k, work=planar_work(WORK_RATES[name]))
           for k, (name, (title, source)) in enumerate(KINDS.items())]
LINEAR, NEAREST, CUBIC = METHODS
