"""
Exports for napari, ImageJ/Fiji and MATLAB
==========================================

A reconstruction's result folder holds ``volume.h5`` (p0 with its coordinates and parameters)
and the MIP pictures. ``fpscan.export_file`` (``fpscan export`` on the command line, ``GET
/api/jobs/{id}/export/{format}`` over HTTP, ``Client.export``) writes it as:

- ``ome-zarr``: an OME-Zarr multiscale image for napari (voxel size and position in µm);
- ``ome-tiff``: an OME-TIFF stack for ImageJ/Fiji (and napari);
- ``npz``: NumPy arrays (``p0``, ``z``, ``x``, ``y`` in m), which ``scipy.io.savemat`` turns
  into a MAT-file for MATLAB.

Here on a small simulated 3-D scan of two balls, reconstructed with NER; each export is read
back and checked against the volume (docs/file-formats.md, "Exports").
"""

# %%
# A small 3-D reconstruction and its result folder
# ------------------------------------------------
import shutil
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import scipy.io
import tifffile
import zarr

import fpscan
from fpscan.service.recon import forward_grid

n, n_z, pitch, dt, n_t, c = 32, 32, 50e-6, 10e-9, 300, 1500.0
lateral = (np.arange(n) - n // 2) * pitch
z = np.arange(n_z) * pitch
balls = [fpscan.Ball(x=-0.3e-3, y=0.2e-3, z=0.6e-3, radius=150e-6), fpscan.Ball(x=0.35e-3, y=-0.3e-3, z=1.0e-3, radius=120e-6)]
p0 = fpscan.ball_p0(balls, z, lateral, lateral)  # (n_z, n_y, n_x)
data = fpscan.GridDataset(forward_grid(p0, pitch, pitch, dt, n_t, c), dx=pitch, dy=pitch, dt=dt, sound_speed=c)
rec = fpscan.reconstruct(data, "ner", n_z=n_z, dz=pitch, quiet=True)

folder = Path(tempfile.mkdtemp(prefix="fpscan-exports-"))
fpscan.write_result(folder / "result", rec, input_id="simulated balls")
volume = folder / "result" / "volume.h5"
print(sorted(p.name for p in (folder / "result").iterdir()))
print("export formats of a result:", ", ".join(fpscan.export_formats("result")))

# %%
# Export and read back
# --------------------
# Each export holds p0 as float32 in the result file's array order ``(z, y, x)``.
fpscan.export_file(volume, folder / "p0.ome.zarr", "ome-zarr")
fpscan.export_file(volume, folder / "p0.ome.tif", "ome-tiff")
fpscan.export_file(volume, folder / "p0.npz", "npz")

group = zarr.open_group(folder / "p0.ome.zarr", mode="r")
multiscale = group.attrs["ome"]["multiscales"][0]
from_zarr = np.asarray(group[multiscale["datasets"][0]["path"]])
print("OME-Zarr:", from_zarr.shape, "axes", [a["name"] for a in multiscale["axes"]],
      "scale (µm)", multiscale["datasets"][0]["coordinateTransformations"][0]["scale"])

with tifffile.TiffFile(folder / "p0.ome.tif") as tif:
    from_tiff = tif.asarray()
    pixels = tifffile.xml2dict(tif.ome_metadata)["OME"]["Image"]["Pixels"]
print("OME-TIFF:", from_tiff.shape, "PhysicalSizeX", pixels["PhysicalSizeX"], pixels["PhysicalSizeXUnit"])

with np.load(folder / "p0.npz") as npz:
    arrays = {key: npz[key] for key in npz.files}
print("npz:", {key: value.shape for key, value in arrays.items()})
for array in (from_zarr, from_tiff, arrays["p0"]):
    np.testing.assert_allclose(array, rec.p0.astype(np.float32), rtol=1e-6, atol=1e-6 * np.abs(rec.p0).max())
print("every export holds the reconstructed volume")

# %%
# For MATLAB
# ----------
# The npz arrays as a MAT-file (MATLAB's ``load('p0.mat')``; its arrays keep the ``(z, y, x)``
# order).
scipy.io.savemat(folder / "p0.mat", {k: v for k, v in arrays.items() if v.dtype.kind in "fiu"})
print("p0.mat:", sorted(k for k in scipy.io.loadmat(folder / "p0.mat") if not k.startswith("__")))

# %%
# What napari shows: the volume's MIP along depth, as the OME-Zarr holds it.
fig, ax = plt.subplots(figsize=(4, 3.5), constrained_layout=True)
ax.imshow(from_zarr.max(axis=0), cmap="gray",
          extent=[lateral[0] * 1e3, lateral[-1] * 1e3, lateral[-1] * 1e3, lateral[0] * 1e3])
ax.set(title="OME-Zarr level 0, MIP over z", xlabel="x (mm)", ylabel="y (mm)")
plt.show()
shutil.rmtree(folder)
