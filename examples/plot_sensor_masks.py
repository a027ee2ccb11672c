"""
Sensor masks: where a sparse scan interrogates the sensor
=========================================================

Four masks of about 11 % of a 64 × 64 lattice at 60 µm (``fpscan.make_mask``): an equispaced
sub-grid, random points, a Poisson-disc set (at least 150 µm apart) and the equi-steradian mask around a point of
interest 2 mm below the lattice centre, whose points subtend equal solid angles seen from
there. Each point carries a quadrature weight (its clipped Voronoi cell, m²): the colours.
The weight ratio is the mean weight of the points farthest from the centre over that of the
points nearest to it (the paper's §6: 9.7 for its equi-steradian mask).
"""

import matplotlib.pyplot as plt
import numpy as np

import fpscan

lattice = fpscan.Lattice(64, 64, 60e-6)
n_points = round(0.11 * 64 * 64)
masks = {
    "equispaced (every 3rd)": fpscan.make_mask("equispaced", lattice, interval=3),
    "random": fpscan.make_mask("random", lattice, n_points=n_points, seed=1),
    "Poisson disc": fpscan.make_mask("poisson", lattice, min_distance=150e-6, n_points=n_points, seed=1),
    "equi-steradian, 2 mm": fpscan.make_mask("equisteradian", lattice, depth=2e-3, n_points=n_points),
}

fig, axes = plt.subplots(1, 4, figsize=(13, 3.8), layout="constrained")
for ax, (title, mask) in zip(axes, masks.items()):
    xy = np.asarray(mask.positions) * 1e3
    dots = ax.scatter(xy[:, 0], xy[:, 1], c=np.asarray(mask.weights) * 1e6, s=3, cmap="viridis")
    ax.set_title(f"{title}\n{mask.obtained_points} points, weight ratio {mask.weight_ratio:.1f}",
                 fontsize=9)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    fig.colorbar(dots, ax=ax, shrink=0.7, label="weight (mm²)")
axes[0].set_ylabel("y (mm)")
plt.show()
