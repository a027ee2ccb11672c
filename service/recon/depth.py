"""The output depth grid of a reconstruction: one rule for every method that takes ``n_z`` and
``dz`` (docs/methods.md, "The depth grid").

- **spacing** ``dz``: as given, else the lateral pitch (an isotropic voxel), or c·dt where the
  pitch is finer than c·dt: the record resolves no finer depth (its Nyquist frequency 1/(2 dt)
  is the depth wavenumber π / (c dt) of the planar model, paper eq. (1), ω = c |k|);
- **rows** ``n_z``: as given, else as deep as the record reaches, c·t_last = c (t0 + (n_t - 1)
  dt), the depth a source straight below a sensor is heard at in the last sample.

``n_z`` alone is that many rows at the default spacing, ``dz`` alone that spacing down to
c·t_last. The methods that follow the rule: ``ner``, ``nedner``, ``linear``, ``nearest``, ``cubic``
(`fpscan.service.recon.planar.depth_axis`) and ``tv`` (`fpscan.service.recon.tv.grid.tv_grid`:
its default spacing is the one its band resolves, c / (2 f_c), which is the pitch's unless a
sensor band is declared, and its default depth the record's last echo above the noise);
``kwave`` reproduces k-Wave's ``kspacePlaneRecon``, whose output is the record's own n_t rows
of c·dt. The server sizes a job on the same grid (``fpscan.service.jobs.admission``).

No compiled kernels: the server sizes a job with it before any is loaded.
"""
from __future__ import annotations

import math

from fpscan.service.recon import checks

__all__ = ["default_spacing", "depth_grid"]


def default_spacing(dt: float, c: float, pitch: float | None = None) -> float:
    """The default depth spacing (module doc): the lateral ``pitch``, or c·dt where the pitch
    is finer (or not known).

    Parameters
    ----------
    dt : float
        Sample interval, s.
    c : float
        Sound speed, m/s.
    pitch : float, optional
        The lateral pitch of the image's lattice, m (along x); None: not known.

    Returns
    -------
    float
        m.

    Examples
    --------
    >>> from fpscan.service.recon.depth import default_spacing
    >>> default_spacing(8e-9, 1500.0, 60e-6)  # a 60 µm lattice, c·dt = 12 µm
    6e-05
    >>> round(default_spacing(8e-9, 1500.0, 5e-6), 12), round(default_spacing(8e-9, 1500.0), 12)  # c·dt
    (1.2e-05, 1.2e-05)
    """
    step = float(c) * float(dt)
    if pitch is None or not (math.isfinite(float(pitch)) and float(pitch) > 0):
        return step
    return max(float(pitch), step)


def depth_grid(n_t: int, dt: float, c: float, pitch: float | None = None, *, dz: float | None = None,
               n_z: int | None = None, t0: float = 0.0) -> tuple[float, int]:
    """The output depth grid ``(dz, n_z)`` of a record (module doc): the spacing asked for, else
    :func:`default_spacing`; the rows asked for, else those down to c·t_last. Row j is at
    z = j dz, row 0 on the sensor plane.

    Parameters
    ----------
    n_t : int
        Samples per A-line (>= 1).
    dt : float
        Sample interval, s (> 0).
    c : float
        Sound speed, m/s (> 0).
    pitch : float, optional
        The lateral pitch of the image's lattice, m (along x; the data's, not an upsampled
        grid's); None: not known (the spacing is then c·dt).
    dz : float, optional
        Depth spacing asked for, m (``fpscan.service.recon.checks.check_dz``'s range).
    n_z : int, optional
        Rows asked for (``fpscan.service.recon.checks.check_n_z``'s range).
    t0 : float, optional
        Time of sample 0, s.

    Returns
    -------
    tuple
        ``(dz, n_z)``: m, rows (at least 2).

    Raises
    ------
    ValueError
        ``dz`` or ``n_z`` out of range, or a ``dz`` so fine that the rows down to c·t_last overflow
        (``fpscan.service.recon.checks.OptionError``); non-positive ``dt``, ``c`` or ``n_t``.

    Examples
    --------
    k-Wave's vessel tree: 751 samples of 8 ns on a 60 µm lattice reach 9 mm, 151 rows of 60 µm:

    >>> from fpscan.service.recon.depth import depth_grid
    >>> depth_grid(751, 8e-9, 1500.0, 60e-6)
    (6e-05, 151)
    >>> depth_grid(751, 8e-9, 1500.0, 60e-6, n_z=64)  # 64 rows of the pitch: 3.84 mm
    (6e-05, 64)
    >>> depth_grid(751, 8e-9, 1500.0, 60e-6, dz=3e-5)  # 30 µm down to 9 mm
    (3e-05, 301)
    >>> depth_grid(751, 8e-9, 1500.0)  # no pitch known: c·dt, the record's n_t rows
    (1.2e-05, 751)
    >>> depth_grid(751, 8e-9, 1500.0, 60e-6, dz=1e-15)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: dz must be in [1e-09, 0.1] m, got 1e-15
    """
    n_t, dt, c = int(n_t), checks.positive("dt", dt), checks.positive("c", c)
    if n_t < 1:
        raise ValueError(f"n_t must be >= 1, got {n_t}")
    spacing = default_spacing(dt, c, pitch) if dz is None else checks.check_dz(dz)
    if n_z is not None:
        return spacing, checks.check_n_z(n_z)
    reach = c * (float(t0 or 0.0) + (n_t - 1) * dt) / spacing * (1 + 1e-9)
    if not reach < 2**31 - 1:  # also inf; fewer rows are bounded by the memory they take (checks.check_memory)
        raise checks.OptionError(f"dz = {spacing:g} m is too fine for this recording: {reach:.3g} rows would reach c·t "
                                 f"of the last sample; give n_z, or use a larger dz (c·dt is {c * dt:.3g} m)")
    return spacing, max(2, int(math.floor(reach)) + 1)
