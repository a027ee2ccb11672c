"""
Spectral unmixing: sO2 from two wavelengths
===========================================

A multi-wavelength scan holds one data set per excitation wavelength. fpscan reconstructs each
(every method, the same options) and unmixes the per-wavelength p0 images into oxy- and
deoxyhaemoglobin per voxel (non-negative least squares on Prahl's haemoglobin spectra), giving
total haemoglobin (THb) and the oxygen saturation sO2 = HbO2 / THb (docs/spectral.md).

Here: a simulated 2-D cross-section of an artery (sO2 97 %) and a vein (sO2 60 %) of equal THb,
seen at 750 nm and 850 nm, where Hb and HbO2 absorb in opposite order. The data at each
wavelength come from fpscan's exact forward model; each image is reconstructed with NER, then
``fpscan.unmix`` and ``fpscan.so2_map`` give the sO2 picture. The same from a scan file:
``fpscan unmix SCAN.h5``; over HTTP: ``POST /api/reconstructions`` with ``"unmix": {}``.
"""

# %%
# Two vessels at two wavelengths
# ------------------------------
# p0(λ) = Γ Φ μa(λ): with the same fluence at both wavelengths (the unmixing's assumption when
# no fluence is given) p0 is proportional to the absorption μa(λ) of the blood in each pixel.
import matplotlib.pyplot as plt
import numpy as np

import fpscan
from fpscan.physics import spectra
from fpscan.service.recon import forward_grid

wavelengths = [750e-9, 850e-9]  # m
n_x, n_z, dx, dt, n_t, c = 128, 64, 50e-6, 10e-9, 600, 1500.0
z, x = np.meshgrid(np.arange(n_z) * dx, (np.arange(n_x) - n_x // 2) * dx, indexing="ij")
artery = (x + 0.8e-3) ** 2 + (z - 1.5e-3) ** 2 <= (250e-6) ** 2
vein = (x - 0.8e-3) ** 2 + (z - 1.5e-3) ** 2 <= (300e-6) ** 2
so2_true = np.where(artery, 0.97, np.where(vein, 0.60, 0.0))
thb = np.where(artery | vein, spectra.BLOOD_THB, 0.0)  # mol/m³
p0 = spectra.absorption(wavelengths, so2_true, thb)  # (2, n_z, n_x), μa in 1/m (Γ Φ = 1)
p0 /= p0.max()

# %%
# Reconstruct each wavelength
# ---------------------------
# The data at each wavelength on a 128-sensor line (50 µm, 10 ns), then NER on p0's grid.
images = []
for k, wavelength in enumerate(wavelengths):
    data = fpscan.GridDataset(forward_grid(p0[k], dx, dx, dt, n_t, c), dx=dx, dt=dt, sound_speed=c,
                              wavelengths=(wavelength,))
    images.append(fpscan.reconstruct(data, "ner", n_z=n_z, dz=dx, quiet=True).p0)
    print(f"{wavelength * 1e9:.0f} nm: artery/vein p0 {p0[k][artery].mean() / p0[k][vein].mean():.2f}")

# %%
# Unmix
# -----
# ``fpscan.unmix`` solves the per-voxel NNLS problem; voxels whose THb is below 10 % of the
# largest are masked (sO2 NaN there). In 2-D ``so2_map`` is the sO2 image itself.
u = fpscan.unmix(np.stack(images), wavelengths)
so2 = fpscan.so2_map(u)
for name, region in [("artery", artery), ("vein", vein)]:
    inner = region & u.mask
    print(f"{name}: sO2 {np.nanmedian(so2[inner]):.2f} (true {so2_true[region].mean():.2f})")

fig, axes = plt.subplots(1, 3, figsize=(11, 2.8), constrained_layout=True)
extent = [x.min() * 1e3, x.max() * 1e3, z.max() * 1e3, 0]
for ax, image, title in zip(axes[:2], images, [f"NER at {w * 1e9:.0f} nm" for w in wavelengths], strict=True):
    ax.imshow(image, extent=extent, cmap="gray")
    ax.set(title=title, xlabel="x (mm)")
shown = axes[2].imshow(so2, extent=extent, cmap="RdYlBu_r", vmin=0, vmax=1)
axes[2].set(title="sO2 (masked: white)", xlabel="x (mm)")
axes[0].set_ylabel("depth (mm)")
fig.colorbar(shown, ax=axes[2], label="sO2")
plt.show()
