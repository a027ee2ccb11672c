"""The reconstruction options' ranges and vocabularies: plain numbers, no imports.

One owner for each bound: the kernels' rules (:mod:`fpscan.service.recon.checks`) and the typed
option models of the methods (:mod:`fpscan.service.recon.methods`) both read them, so the schema
a client sees states the range the kernel enforces. This module imports only ``typing`` (the
method registry loads without numpy, for the command line of a client-only install).
"""
from __future__ import annotations

from typing import Final

__all__ = ["BANDWIDTH_RANGE", "EPS_RANGE", "UPSAMPLE_RANGE", "N_Z_RANGE", "DZ_RANGE", "LAM_RANGE", "ITERATIONS_RANGE",
           "TIME_LIMIT_MAX", "TOL_RANGE", "DEFAULT_TOL", "DEFAULT_DTYPE", "DTYPES", "DEVICES", "DEFAULT_DEVICE", "KWAVE_INTERPS", "DEFAULT_EPS", "DEFAULT_MAX_ITER",
           "DEFAULT_TIME_LIMIT"]

#: NUFFT tolerance, inclusive
EPS_RANGE = (1e-14, 1e-1)
#: lateral upsampling factor, inclusive
UPSAMPLE_RANGE = (1, 8)
#: output depth samples, inclusive
N_Z_RANGE = (2, 65536)
#: output depth spacing, m, inclusive
DZ_RANGE = (1e-9, 0.1)
#: TV weight λ (data units), inclusive
LAM_RANGE = (0.0, 1e30)
#: a sensor bandwidth tv may be told, Hz, inclusive (1 kHz: no photoacoustic sensor passes
#: less; 1 THz: far above any sampling a scanner records)
BANDWIDTH_RANGE = (1e3, 1e12)
#: iterations of the model-based solver, inclusive
ITERATIONS_RANGE = (1, 100000)
#: wall-time limit of the model-based solver, s: (0, max]
TIME_LIMIT_MAX = 7 * 86400.0
#: the model-based solver's stopping threshold (the iterate's relative change per iteration,
#: the largest of the last 3; 0: run every iteration), inclusive
TOL_RANGE = (0.0, 0.5)
#: the stopping threshold used when none is asked for
DEFAULT_TOL = 5e-3

#: the working and output precision used when none is asked for (every method, every caller)
DEFAULT_DTYPE: Final = "float32"
#: the precisions a reconstruction may work in
DTYPES = ("float32", "float64")
#: where a reconstruction runs (`fpscan.service.recon.device`): the GPU where one fits, the CPU, the GPU
DEVICES = ("auto", "cpu", "cuda")
#: the default device: the GPU where CuPy sees one and the job fits it, else the CPU
DEFAULT_DEVICE: Final = "auto"
#: k-Wave's interpolation modes (``kspaceLineRecon`` / ``kspacePlaneRecon``)
KWAVE_INTERPS = ("*nearest", "nearest", "*linear", "linear", "*cubic", "cubic")
#: NUFFT tolerance used when none is asked for
DEFAULT_EPS = 1e-6
#: most iterations of the model-based solver when none are asked for: above the latest stop of its
#: stopping rule measured at the default tol (126 iterations on tv's phantom family), so that the rule,
#: not the cap, ends a run (docs/tv-measurements.md, "Stopping rule")
DEFAULT_MAX_ITER = 150
#: default wall-time limit of one model-based reconstruction, s (the server's setting
#: ``time_limit_s`` caps it there)
DEFAULT_TIME_LIMIT = 3600.0
