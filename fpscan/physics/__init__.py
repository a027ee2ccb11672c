"""Photoacoustic physics shared by the simulator (`driver`) and the reconstruction
(`fpscan.service.recon`): pure numpy/scipy/finufft/numba functions, no I/O.

- `balls`: exact pressure of uniform spheres ("balls") at point sensors: the N-shaped
  wave p = p0 (r - c t) / (2 r), averaged over each sample interval.
- `forward`: the exact planar forward model p0 on a regular grid -> data on the sensor
  plane (on the sensor grid or at arbitrary sensor positions).
- `nufft`: the 1-D temporal non-uniform FFT (exponential-of-semicircle kernel) used by
  the forward model (spreading) and by the NER reconstruction (interpolation).
- `spectra`: molar extinction spectra of HbO2 and Hb (Prahl's table, shipped as data)
  and the absorption μa of haemoglobin at a given sO2 and concentration.
- `threads`: the compiled kernels' OpenMP threads sleep as soon as a kernel ends (imported
  here, first, so that it runs before any kernel loads OpenMP).

Importing the package loads only `balls` (numpy): import the forward model
(`fpscan.physics.forward`, finufft and numba) and `nufft` (numba) from their modules, so
that each user pays for what it uses.
"""
from fpscan.physics import threads  # noqa: F401  (first: the OpenMP wait policy)
from fpscan.physics.balls import Ball, ball_alines, ball_p0

__all__ = ["Ball", "ball_alines", "ball_p0"]
