"""
A sparse 3-D scan: NER from every sensor, NEDNER from 11 % of them
===================================================================

A planar Fabry–Pérot scanner can interrogate any subset of its lattice. Here an equi-steradian
mask of 11 % of the points around a point of interest (``fpscan.make_mask``) is picked out of
dense data (``fpscan.subsample``: the A-lines a replay scan of that mask records) and
reconstructed with NEDNER-NUFFT, beside NER-NUFFT from every sensor.

The data: the k-Wave simulation ``kwave3d_balls_yarn.h5`` of the shared folder (six balls and a
curved "yarn", 96 × 96 sensors at 60 µm, 751 samples of 8 ns) when it is there, else a few
balls simulated exactly on a 48 × 48 lattice (``fpscan.ball_alines``).
"""

# %%
# The dense data and the true p0
# ------------------------------
import os
from pathlib import Path

import h5py
import matplotlib.pyplot as plt
import numpy as np

import fpscan

shared = Path(os.environ.get("FPSCAN_SHARED", Path(fpscan.__file__).resolve().parents[1].parent / "shared"))
kwave_file = shared / "data" / "kwave3d_balls_yarn.h5"

if kwave_file.is_file():
    dense = fpscan.load_dataset(kwave_file)  # (n_t, n_y, n_x) = (751, 96, 96)
    assert isinstance(dense, fpscan.GridDataset)  # a k-Wave file is grid data
    with h5py.File(kwave_file, "r") as f:
        p0 = f["p0"][()]  # (n_z, n_y, n_x), 60 µm voxels
    dz = float(dense.dx)
    source = "k-Wave kwave3d_balls_yarn.h5"
else:
    n, pitch, dt, n_t = 48, 60e-6, 8e-9, 400
    balls = [fpscan.Ball(x=0.0, y=0.0, z=1.2e-3, radius=0.2e-3, amplitude=1.0),
             fpscan.Ball(x=-0.7e-3, y=0.5e-3, z=0.8e-3, radius=0.12e-3, amplitude=1.0),
             fpscan.Ball(x=0.6e-3, y=-0.6e-3, z=1.8e-3, radius=0.15e-3, amplitude=0.8)]
    full = fpscan.make_mask("full", fpscan.Lattice(n, n, pitch))
    alines = fpscan.ball_alines(full.positions, balls, dt, n_t, 1500.0)  # (n_points, n_t)
    dense = fpscan.GridDataset(alines.T.reshape(n_t, n, n), dx=pitch, dt=dt, sound_speed=1500.0)
    dz = pitch
    axis = (np.arange(n) - (n - 1) / 2) * pitch
    p0 = fpscan.ball_p0(balls, np.arange(40) * dz, axis, axis)
    source = "simulated balls"
print(source, dense)

# %%
# An equi-steradian mask of 11 % of the lattice
# ---------------------------------------------
# Around a point of interest under the lattice centre, at the depth of p0's centroid: the mask's
# points subtend equal solid angles seen from there, and each carries its quadrature weight.
n_t, n_y, n_x = dense.data.shape
profile = np.maximum(p0, 0).sum(axis=(1, 2))
depth = float(np.sum(profile * np.arange(p0.shape[0])) / profile.sum()) * dz
lattice = fpscan.Lattice(n_x, n_y, dense.dx)
mask = fpscan.make_mask("equisteradian", lattice, depth=depth, n_points=round(0.11 * n_x * n_y))
sparse = fpscan.subsample(dense, mask)
print(mask)

# %%
# Reconstruct
# -----------
# NER needs every lattice point; NEDNER takes any set of points. Both on p0's own depth grid.
grid = {"dz": dz, "n_z": p0.shape[0], "quiet": True}
ner = fpscan.reconstruct(dense, "ner", **grid)
nedner = fpscan.reconstruct(sparse, "nedner", **grid)
for name, rec in (("NER", ner), ("NEDNER", nedner)):
    cc = fpscan.correlation_coefficient(np.maximum(rec.p0, 0), p0)
    print(f"{name}: p0 {rec.p0.shape}, CC with the true p0 {cc:.3f}")

# %%
# Side by side: maximum-intensity projections
# -------------------------------------------
# Top row: the projection along depth (x-y, seen from the sensor); bottom row: along y (depth
# down). Each image is scaled to its own maximum; the orange dots on NEDNER's are the mask's points.
assert ner.y is not None  # 3-D
extent_xy = [ner.x[0] * 1e3, ner.x[-1] * 1e3, ner.y[-1] * 1e3, ner.y[0] * 1e3]
extent_xz = [ner.x[0] * 1e3, ner.x[-1] * 1e3, ner.z[-1] * 1e3, ner.z[0] * 1e3]
images = {"true p0": p0, f"NER, all {n_x * n_y} sensors": ner.p0,
          f"NEDNER, {mask.obtained_points} sensors (11 %)": nedner.p0}
fig, axes = plt.subplots(2, 3, figsize=(10, 6.4), layout="constrained")
for column, (title, volume) in enumerate(images.items()):
    volume = np.maximum(volume, 0)
    axes[0, column].imshow(volume.max(axis=0), extent=extent_xy, cmap="gray")
    axes[1, column].imshow(volume.max(axis=1), extent=extent_xz, cmap="gray")
    axes[0, column].set_title(title, fontsize=10)
    axes[1, column].set_xlabel("x (mm)")
axes[0, 0].set_ylabel("y (mm)")
axes[1, 0].set_ylabel("depth (mm)")
sensors = np.asarray(mask.positions) * 1e3  # the mask's points, over NEDNER's image
axes[0, 2].autoscale(False)
axes[0, 2].plot(sensors[:, 0], sensors[:, 1], ",", color="tab:orange", alpha=0.6)
plt.show()
