"""Numerical phantoms of the paper's experiments (initial pressure p0 on a grid).

- :func:`tree_phantom` (§6): a tree — a crown of discs and a vertical trunk — whose
  vertical edges a line sensor of limited aperture sees poorly (limited view).
- :func:`yarn_phantom` (§7): curved strands and a central knot (a trefoil) of a thin
  tube, like the paper's yarn; its knot is the point of interest.
- :func:`layer_phantom` (§4): a thin absorbing layer of finite width (Gaussian in
  depth, blurred steps laterally), for axial line-spread and lateral edge-spread
  measurements, like the paper's 0.1 µm thin chrome USAF chart seen by a band-limited
  system.
- :func:`vessel_phantom` (the ``vessels`` experiment): a branching tree of tubes 1–4 voxels
  wide (a trunk that forks three times), in 2-D and 3-D, the thin structures an FP scanner
  images; :func:`vessel_tree` gives its centre lines and widths.

Grids follow docs/architecture.md: ``z_j = j·dz`` (row 0 at the sensor plane),
``x_i = (i - (n_x - 1)/2)·dx``.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from fpscan.physics.axes import centred_axis

__all__ = ["tree_phantom", "tree_roi", "yarn_geometry", "yarn_phantom", "layer_phantom", "vessel_tree", "vessel_phantom"]


def tree_phantom(n_z: int, n_x: int, *, amplitude: float = 1.0) -> np.ndarray:
    """A tree (crown of 8 discs, trunk) of height ~0.85 n_z centred laterally.

    Geometry in units of ``n_z`` pixels, so it scales with the grid.

    Parameters
    ----------
    n_z : int
        Depth rows (>= 16).
    n_x : int
        Lateral pixels (>= n_z // 2).
    amplitude : float, optional
        p0 inside the tree (default 1).

    Returns
    -------
    ndarray, shape ``(n_z, n_x)``
        p0: ``amplitude`` inside, 0 outside, edge pixels anti-aliased by 4 × 4 supersampling.

    Raises
    ------
    ValueError
        ``n_x < n_z // 2`` or ``n_z < 16``.
    """
    if n_z < 16 or n_x < n_z // 2:
        raise ValueError(f"tree phantom needs n_z >= 16 and n_x >= n_z/2, got ({n_z}, {n_x})")
    h = float(n_z)
    discs = [  # (depth, lateral offset, radius) in units of n_z
        (0.30, 0.00, 0.14), (0.22, -0.12, 0.10), (0.22, 0.12, 0.10), (0.38, -0.16, 0.10),
        (0.38, 0.16, 0.10), (0.13, 0.00, 0.09), (0.45, -0.06, 0.08), (0.45, 0.08, 0.08),
    ]
    s = 4
    off = (np.arange(s) + 0.5) / s - 0.5
    zz = (np.arange(n_z)[:, None] + off[None, :]).ravel()
    xx = (centred_axis(n_x, 1.0)[:, None] + off[None, :]).ravel()  # lateral, in pixels from the centre
    Z, X = np.meshgrid(zz, xx, indexing="ij")
    inside = np.zeros(Z.shape, dtype=bool)
    for dz_, dx_, r in discs:
        inside |= (Z - dz_ * h) ** 2 + (X - dx_ * h) ** 2 <= (r * h) ** 2
    inside |= (np.abs(X) <= 0.035 * h) & (Z >= 0.40 * h) & (Z <= 0.90 * h)
    p0 = inside.reshape(n_z, s, n_x, s).mean(axis=(1, 3))
    return amplitude * p0


def tree_roi(n_z: int, dz: float) -> tuple[tuple[float, float], float]:
    """The §6 region of interest around :func:`tree_phantom`: a disc enclosing the tree.

    Parameters
    ----------
    n_z : int
        Depth rows of the phantom's grid.
    dz : float
        Its depth spacing, m.

    Returns
    -------
    tuple of ((float, float), float)
        The disc's centre ``(z, x)`` and its diameter, m.
    """
    return (0.5 * n_z * dz, 0.0), 0.95 * n_z * dz


def _curve_distance(points: np.ndarray, grids: tuple[np.ndarray, ...], reach: float) -> np.ndarray:
    tree = cKDTree(points)
    coords = np.stack([g.ravel() for g in np.meshgrid(*grids, indexing="ij")], axis=1)
    dist, _ = tree.query(coords, distance_upper_bound=reach)
    return dist.reshape(tuple(len(g) for g in grids))


def yarn_geometry(half_width: float) -> tuple[np.ndarray, float]:
    """Centre-line samples of the yarn (three wavy strands and a trefoil knot), and the knot depth.

    The knot sits at depth ``0.53 · half_width`` (3.6 mm for the paper's 13.56 mm aperture).

    Parameters
    ----------
    half_width : float
        Half the lateral extent of the lattice, m.

    Returns
    -------
    tuple of (ndarray, float)
        The samples ``(m, 3)`` as (z, y, x) in m, and the knot's depth in m.
    """
    L = half_width
    zc = 0.53 * L
    parts = []
    s = np.linspace(-0.85 * L, 0.85 * L, 4000)
    for i, phase in enumerate((0.0, 2.1, 4.2)):
        y = (i - 1) * 0.35 * L + 0.12 * L * np.sin(2 * np.pi * s / (0.8 * L) + phase)
        z = zc + 0.10 * L * np.cos(2 * np.pi * s / (0.9 * L) + phase)
        parts.append(np.column_stack([z, y, s]))
    t = np.linspace(0, 2 * np.pi, 3000)
    a = 0.07 * L  # trefoil knot
    parts.append(np.column_stack([zc - 0.8 * a * np.sin(3 * t), a * (np.cos(t) - 2 * np.cos(2 * t)), a * (np.sin(t) + 2 * np.sin(2 * t))]))
    return np.concatenate(parts), zc


def yarn_phantom(n_z: int, n_xy: int, d: float, *, radius_voxels: float = 1.5) -> tuple[np.ndarray, float]:
    """Yarn: three wavy strands across the volume and a trefoil knot at the centre.

    Parameters
    ----------
    n_z, n_xy : depth rows and lateral points per side; ``d`` voxel size in m (cubic).
    radius_voxels : tube radius in voxels.

    Returns
    -------
    (p0, knot_depth): p0 ``(n_z, n_xy, n_xy)`` (z, y, x) with 1 inside the tube (linear
    partial-volume ramp over one voxel at the surface), and the knot's depth in m.

    Raises ValueError if the knot does not fit in the depth range.
    """
    half = n_xy * d / 2
    line, zc = yarn_geometry(half)
    if zc + 0.25 * half > n_z * d:
        raise ValueError(f"n_z = {n_z} rows of {d} m do not reach below the yarn (needs {zc + 0.25 * half:.3g} m)")
    r = radius_voxels * d
    dist = _curve_distance(line, (np.arange(n_z) * d, centred_axis(n_xy, d), centred_axis(n_xy, d)), r + d)
    p0 = np.clip((r + d / 2 - dist) / d, 0.0, 1.0)
    p0[~np.isfinite(dist)] = 0.0
    return p0, zc


def layer_phantom(n_z: int, n_x: int, dz: float, dx: float, *, depth: float, width: float,
                  thickness: float, edge: float) -> np.ndarray:
    """A thin absorbing layer of finite width: Gaussian in depth, smoothed steps laterally.

    Parameters
    ----------
    n_z, n_x : grid size; dz, dx : spacing in m.
    depth : layer centre depth in m (need not be on the grid).
    width : lateral extent in m, centred on x = 0 (between the half-maximum points).
    thickness : FWHM of the Gaussian depth profile in m (a thin, nearly delta-like layer
        when close to dz, as the paper's 0.1 µm chrome seen by a band-limited system).
    edge : FWHM in m of the Gaussian that blurs each lateral edge (its error-function
        edge-spread profile).

    Returns
    -------
    ndarray, shape ``(n_z, n_x)``
        p0, maximum 1 at the layer centre.

    Raises
    ------
    ValueError
        The layer leaves the grid or a size is not positive.
    """
    from scipy.special import erf

    if min(thickness, edge, width) <= 0:
        raise ValueError("thickness, edge and width must be > 0 m")
    z = np.arange(n_z) * dz
    if not (4 * thickness < depth < z[-1] - 4 * thickness):
        raise ValueError("the layer must lie inside the depth range")
    x = centred_axis(n_x, dx)
    if width / 2 + 4 * edge > x[-1]:
        raise ValueError("the layer must fit laterally inside the grid")
    sz = thickness / (2 * np.sqrt(2 * np.log(2)))
    se = edge / (2 * np.sqrt(2 * np.log(2)))
    prof = np.exp(-0.5 * ((z - depth) / sz) ** 2)
    lat = 0.5 * (erf((x + width / 2) / (np.sqrt(2) * se)) - erf((x - width / 2) / (np.sqrt(2) * se)))
    return prof[:, None] * lat[None, :]


#: the vessel tree's generations: width in voxels of each generation (trunk first)
VESSEL_WIDTHS = (4.0, 3.0, 2.0, 1.0)


def vessel_tree(shape: tuple[int, ...]) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Centre lines of :func:`vessel_phantom`: a trunk that forks three times (1 + 2 + 4
    + 8 = 15 straight segments), widths `VESSEL_WIDTHS` (4, 3, 2, 1 voxels) by generation.

    The trunk enters near the left edge (x = -0.42 n_x) at depth 0.55 n_z and runs
    laterally; each fork turns its two children ±22° (in depth, scaled by n_z / n_x when that is below 1; and in 3-D also ±0.3 n_y
    towards the two y sides), so the tree lies mostly parallel to the sensor plane, as
    skin vessels do. Geometry in units of the grid, so it scales with it.

    Parameters
    ----------
    shape : (n_z, n_x) or (n_z, n_y, n_x) voxels (n_z >= 16, n_x >= 32, n_y >= 16).

    Returns
    -------
    list of (start, end, width): start and end are the segment's centre-line end points in
    voxel coordinates (z, x) / (z, y, x) (z = row index, lateral = index from the grid's
    centre, ``(i - (n - 1)/2)``), width in voxels.

    Raises ValueError for a shape that is not 2-D or 3-D or too small.
    """
    shape = tuple(int(s) for s in shape)
    if len(shape) not in (2, 3) or shape[0] < 16 or shape[-1] < 32 or (len(shape) == 3 and shape[1] < 16):
        raise ValueError(f"the vessel phantom needs (n_z >= 16, [n_y >= 16,] n_x >= 32) voxels, got {shape}")
    three = len(shape) == 3
    n_z, n_x = shape[0], shape[-1]
    n_y = shape[1] if three else 1
    segments: list[tuple[np.ndarray, np.ndarray, float]] = []

    def grow(start: np.ndarray, angle: float, side: float, gen: int) -> None:
        if gen >= len(VESSEL_WIDTHS):
            return
        length = (0.30 if gen == 0 else 0.22 * 0.8 ** (gen - 1)) * n_x
        dz, dx = np.sin(angle) * length * min(1.0, n_z / n_x), np.cos(angle) * length  # depth scaled to the grid
        dz = float(np.clip(dz, 0.12 * n_z - start[0], 0.88 * n_z - start[0]))  # stay inside in depth
        step = [dz, dx] if not three else [dz, side * 0.3 * n_y * 0.6**gen, dx]
        end = start + np.array(step)
        segments.append((start, end, VESSEL_WIDTHS[gen]))
        turn = np.deg2rad(22.0)
        grow(end, angle - turn, -1.0, gen + 1)
        grow(end, angle + turn, 1.0, gen + 1)

    origin = [0.55 * n_z, -0.42 * n_x] if not three else [0.55 * n_z, 0.0, -0.42 * n_x]
    grow(np.array(origin), np.deg2rad(-8.0), 0.0, 0)
    return segments


def vessel_phantom(shape: tuple[int, ...], *, amplitude: float = 1.0) -> np.ndarray:
    """A vessel tree: tubes (3-D) or strips (2-D) 4, 3, 2 and 1 voxels wide along the
    centre lines of :func:`vessel_tree`, p0 = ``amplitude`` inside.

    Parameters
    ----------
    shape : (n_z, n_x) or (n_z, n_y, n_x) voxels (cubic voxels; rules as `vessel_tree`).
    amplitude : p0 inside the vessels, Pa.

    Returns
    -------
    ndarray of ``shape`` (z, x) / (z, y, x): p0 with a linear partial-volume ramp over one
    voxel at the surface (``clip(r + ½ - distance, 0, 1)``, r = width / 2, as
    :func:`yarn_phantom`), so a 1-voxel vessel is one voxel across.

    Raises ValueError as `vessel_tree`.
    """
    segments = vessel_tree(shape)
    grids = tuple(np.arange(n, dtype=float) if i == 0 else centred_axis(n, 1.0) for i, n in enumerate(shape))
    p0 = np.zeros(shape)
    for start, end, width in segments:
        n_s = int(np.ceil(np.linalg.norm(end - start) * 4)) + 2
        line = start[None, :] + np.linspace(0.0, 1.0, n_s)[:, None] * (end - start)[None, :]
        r = width / 2
        dist = _curve_distance(line, grids, r + 1.0)
        inside = np.where(np.isfinite(dist), np.clip(r + 0.5 - dist, 0.0, 1.0), 0.0)
        np.maximum(p0, inside, out=p0)
    return amplitude * p0
