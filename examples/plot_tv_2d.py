"""
NER, NEDNER and tv from 11 % of a line of sensors (2-D)
=======================================================

The model-based method ``tv`` (TV + positivity on the exact planar model, NER-preconditioned
FISTA) against the direct methods on a sparse line scan: NER-NUFFT from every sensor, NEDNER-NUFFT
and tv from an equiangular mask of 11 % of them, pictures side by side.

The data: the k-Wave simulation ``kwave2d_points.h5`` of the shared folder (point targets; a
line of 1024 sensors at 50 µm, 3519 samples of 10 ns) when it is there, else discs simulated
with fpscan's exact planar forward model (``fpscan.service.recon.forward_grid``) on 256 sensors. tv
is the slow one: its first run in a fresh environment also compiles its kernels (numba).
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
kwave_file = shared / "data" / "kwave2d_points.h5"

if kwave_file.is_file():
    dense = fpscan.load_dataset(kwave_file)  # (n_t, n_x) = (3519, 1024)
    assert isinstance(dense, fpscan.GridDataset)  # a k-Wave file is grid data
    with h5py.File(kwave_file, "r") as f:
        p0 = f["p0"][()]  # (n_z, n_x), 50 µm pixels
    dz = float(dense.dx)
    source = "k-Wave kwave2d_points.h5"
else:
    from fpscan.service.recon import forward_grid

    n_x, n_z, dx, dt, n_t = 256, 96, 50e-6, 10e-9, 1200
    z, x = np.meshgrid(np.arange(n_z) * dx, (np.arange(n_x) - (n_x - 1) / 2) * dx, indexing="ij")
    p0 = np.zeros((n_z, n_x))
    for xc, zc in [(-3e-3, 1.0e-3), (0.0, 2.0e-3), (2.5e-3, 3.5e-3), (0.3e-3, 2.0e-3)]:
        p0[(x - xc) ** 2 + (z - zc) ** 2 <= (75e-6) ** 2] = 1.0
    dense = fpscan.GridDataset(forward_grid(p0, dx, dx, dt, n_t, 1500.0), dx=dx, dt=dt, sound_speed=1500.0)
    dz = dx
    source = "simulated discs"
print(source, dense)

# %%
# An equiangular mask of 11 % of the sensors
# ------------------------------------------
# Around a point of interest under the line's centre at the depth of p0's centroid: the sensors
# are spaced at equal angles seen from there, each with its quadrature weight.
n_t, n_x = dense.data.shape
profile = np.maximum(p0, 0).sum(axis=1)
depth = float(np.sum(profile * np.arange(p0.shape[0])) / profile.sum()) * dz
mask = fpscan.make_mask("equiangular", fpscan.Lattice(n_x, 1, dense.dx), depth=depth,
                        n_points=round(0.11 * n_x))
sparse = fpscan.subsample(dense, mask)
print(mask)

# %%
# Reconstruct
# -----------
# All three on p0's own grid; tv at its defaults (its λ from the data's noise level, its
# stopping rule), in the default precision float32.
grid = {"dz": dz, "n_z": p0.shape[0], "quiet": True}
images = {
    "true p0": p0,
    f"NER, all {n_x} sensors": fpscan.reconstruct(dense, "ner", **grid).p0,
    f"NEDNER, {mask.obtained_points} sensors (11 %)": fpscan.reconstruct(sparse, "nedner", **grid).p0,
}
tv = fpscan.reconstruct(sparse, "tv", **grid)
images[f"tv, {mask.obtained_points} sensors (11 %)"] = tv.p0
print(f"tv: {tv.params['iterations']} iterations, converged {tv.params['converged']}")
for name, image in list(images.items())[1:]:
    print(f"{name}: CC with the true p0 {fpscan.correlation_coefficient(np.maximum(image, 0), p0):.3f}")

# %%
# Side by side
# ------------
# Depth down, each image scaled to its own maximum (negative values shown as 0); the orange
# ticks above the first image mark the mask's sensors.
x_mm = (np.arange(n_x) - (n_x - 1) / 2) * dense.dx * 1e3
extent = [x_mm[0], x_mm[-1], p0.shape[0] * dz * 1e3, 0]
fig, axes = plt.subplots(len(images), 1, figsize=(9, 1.9 * len(images) + 0.6), sharex=True,
                         layout="constrained")
for ax, (title, image) in zip(axes, images.items()):
    ax.imshow(np.maximum(image, 0), extent=extent, aspect="equal", cmap="gray")
    ax.set_title(title, fontsize=10)
    ax.set_ylabel("depth (mm)")
sensors = np.asarray(mask.positions)[:, 0] * 1e3
axes[0].plot(sensors, np.zeros_like(sensors), "|", color="tab:orange", markersize=6, clip_on=False)
axes[-1].set_xlabel("x (mm)")
plt.show()
