"""
Reading k-Wave files: NER beside k-Wave's own reconstruction
============================================================

fpscan reads sensor data as k-Wave writes it: HDF5 in k-Wave's layout (``--format
kwave-hdf5``), k-Wave's MAT-files (``kwave-mat``) and plain ``.npy`` arrays
(docs/file-formats.md). This example writes a small 2-D k-Wave-layout file itself, with h5py,
in k-Wave's conventions (a time-first array ``sensor_data/clean`` of shape ``(Nt, Ny)``, the
attribute ``kwave_DataOrder = "ty"`` on it, ``dt_s``, ``dy_m`` and ``c_m_per_s`` on the file;
k-Wave calls the depth axis x, so the sensor line's spacing is ``dy_m``), then reconstructs it
with NER (exact NUFFT) and with ``kwave``, fpscan's port of k-Wave's ``kspaceLineRecon``
(linear interpolation).

The same works on the k-Wave reference files (for example ``kwave2d_points.h5``) or on your
own simulations: ``fpscan.load_dataset(path)`` or ``fpscan recon path``.
"""

# %%
# A k-Wave-layout file
# --------------------
# The data: three small discs, simulated exactly with fpscan's forward model on a 128-sensor
# line at 50 µm, 10 ns sampling, as k-Wave's ``kspaceFirstOrder2D`` would record them.
import shutil
import tempfile
from pathlib import Path

import h5py
import matplotlib.pyplot as plt
import numpy as np

import fpscan
from fpscan.service.recon import forward_grid

n_x, n_z, dx, dt, n_t, c = 128, 64, 50e-6, 10e-9, 600, 1500.0
z, x = np.meshgrid(np.arange(n_z) * dx, (np.arange(n_x) - n_x // 2) * dx, indexing="ij")
p0 = np.zeros((n_z, n_x))
for xc, zc in [(-1.5e-3, 0.8e-3), (0.0, 1.6e-3), (1.2e-3, 2.4e-3)]:
    p0[(x - xc) ** 2 + (z - zc) ** 2 <= (120e-6) ** 2] = 1.0
sensor_data = forward_grid(p0, dx, dx, dt, n_t, c)  # (n_t, n_x): k-Wave's 'ty' order

folder = Path(tempfile.mkdtemp(prefix="fpscan-kwave-"))
path = folder / "kwave2d_discs.h5"
with h5py.File(path, "w") as f:
    f.attrs.update({"kwave_commit": "example", "dt_s": dt, "dy_m": dx, "c_m_per_s": c, "Nt": n_t})
    data = f.create_dataset("sensor_data/clean", data=sensor_data.astype(np.float32))
    data.attrs["kwave_DataOrder"] = "ty"

dataset = fpscan.load_dataset(path)  # the format is detected from the content: kwave-hdf5
print(dataset)

# %%
# NER and kwave
# -------------
# ``kwave`` reproduces k-Wave's ``kspaceLineRecon`` with its interpolation (here ``*linear``,
# ``*`` for k-Wave's ``interp1`` extrapolation) on k-Wave's own depth grid (spacing c·dt, one row
# per time sample); NER is exact up to its NUFFT tolerance and takes any depth grid: here p0's
# own, and k-Wave's, to compare the two row by row.
kw = fpscan.reconstruct(dataset, "kwave", interp="*linear", quiet=True)
ner = fpscan.reconstruct(dataset, "ner", n_z=n_z, dz=dx, quiet=True)
ner_on_kw = fpscan.reconstruct(dataset, "ner", n_z=kw.p0.shape[0], dz=float(kw.z[1] - kw.z[0]), quiet=True)
print(f"kwave: {kw.p0.shape} at dz {(kw.z[1] - kw.z[0]) * 1e6:.0f} um; NER: {ner.p0.shape} at {dx * 1e6:.0f} um")
print(f"NER: CC with the true p0 {fpscan.correlation_coefficient(ner.p0, p0):.3f}")
print(f"kwave (*linear): CC with NER on its grid {fpscan.correlation_coefficient(kw.p0, ner_on_kw.p0):.3f}")

fig, axes = plt.subplots(1, 3, figsize=(10, 2.8), constrained_layout=True)
for ax, (name, rec_z, image) in zip(axes, [("true p0", z[:, 0], p0), ("NER", ner.z, ner.p0),
                                             ("kwave (*linear)", kw.z, kw.p0)], strict=True):
    ax.imshow(image, extent=[x.min() * 1e3, x.max() * 1e3, rec_z[-1] * 1e3, rec_z[0] * 1e3], cmap="gray",
              aspect="auto")
    ax.set(title=name, xlabel="x (mm)", ylim=(z.max() * 1e3, 0))
axes[0].set_ylabel("depth (mm)")
plt.show()

# %%
# The same file from the command line: ``fpscan recon kwave2d_discs.h5 --method kwave
# --interp '*linear' --out kwave-result`` (``volume.h5`` and the MIPs).
shutil.rmtree(folder)
