"""
tv's problem in pyproximal: PrimalDual beside tv on fpscan's physics
=====================================================================

``tv`` minimises J(p) = ½‖A p − g‖² + λ TV(p) over p ≥ 0, with A fpscan's exact planar forward
model (Arridge et al., Phys. Med. Biol. 61 (2016) 8908). ``fpscan.tv_problem`` hands out that
problem for a dataset: the operator A as a ``pylops.LinearOperator``, the record g tv fits, the
warm start, the grid and the automatic λ, and J itself (``objective``). Here pyproximal's
Chambolle–Pock solver (``PrimalDual``) runs on it, side by side with tv.

The data: a few balls simulated exactly (``fpscan.ball_alines``) on a 24 × 24 lattice of 100 µm
with noise 30 dB below the peak, scanned at an equi-steradian mask of 25 % of the lattice.
"""

# %%
# A sparse, noisy scan
# --------------------
import matplotlib.pyplot as plt
import numpy as np
import pylops
import pyproximal
from pyproximal.optimization.primaldual import PrimalDual

import fpscan

n, pitch, dt, n_t, c = 24, 100e-6, 20e-9, 128, 1500.0
balls = [fpscan.Ball(x=0.0, y=0.2e-3, z=0.9e-3, radius=0.25e-3, amplitude=1.0),
         fpscan.Ball(x=-0.7e-3, y=-0.5e-3, z=0.6e-3, radius=0.15e-3, amplitude=0.8),
         fpscan.Ball(x=0.6e-3, y=-0.4e-3, z=1.4e-3, radius=0.2e-3, amplitude=0.6)]
lattice = fpscan.Lattice(n, n, pitch)
full = fpscan.make_mask("full", lattice)
clean = fpscan.ball_alines(full.positions, balls, dt, n_t, c).T.reshape(n_t, n, n)  # (n_t, n_y, n_x)
rng = np.random.default_rng(0)
noisy = clean + rng.standard_normal(clean.shape) * np.abs(clean).max() / 10 ** (30 / 20)
dense = fpscan.GridDataset(noisy, dx=pitch, dt=dt, sound_speed=c)
mask = fpscan.make_mask("equisteradian", lattice, depth=1.0e-3, n_points=round(0.25 * n * n))
sparse = fpscan.subsample(dense, mask)
print(mask)

# %%
# tv's problem
# ------------
# One call: the operator on tv's grid (dims = the image (n_z, n_y, n_x), dimsd = the A-lines
# (n_points, n_t) at tv's band), the data, the warm start (NEDNER, clipped at 0), λ.
problem = fpscan.tv_problem(sparse)
A, g = problem.operator, problem.data
print(f"A: {A.dims} -> {A.dimsd}, {A.dtype}; λ = {problem.lam:.4g}; "
      f"J(warm start) = {problem.objective(problem.warm_start):.5g}")
truth = fpscan.ball_p0(balls, problem.z, problem.x, problem.y)

# %%
# tv
# --
# At its defaults (its stopping rule) and for a fixed count of iterations.
iterations = 150
tv = fpscan.reconstruct(sparse, "tv", quiet=True)
tv_long = fpscan.reconstruct(sparse, "tv", max_iter=iterations, tol=0.0, quiet=True)
assert tv.params["lam"] == problem.lam  # the same problem

# %%
# pyproximal's PrimalDual on the same problem
# -------------------------------------------
# K = [A; ∇] (``problem.gradient``: TV's forward differences), f = positivity, g(K p) =
# ½‖A p − g‖² + λ‖∇p‖₂,₁; steps τ μ ‖K‖² < 1, their ratio τ / μ picked from three by J after a
# few iterations.
K = pylops.VStack([A, problem.gradient])
proxg = pyproximal.VStack([pyproximal.L2(b=g.ravel().astype(A.dtype)),
                           pyproximal.L21(ndim=len(A.dims), sigma=problem.lam)], nn=[g.size, problem.gradient.shape[0]])
proxf = pyproximal.Box(lower=0.0)
x = rng.standard_normal(A.shape[1]).astype(A.dtype)
for _ in range(10):  # ‖A‖ by power iterations; ‖∇‖² <= 4 d
    x = A.rmatvec(A.matvec(x))
    norm_a2 = float(np.linalg.norm(x))
    x /= norm_a2
norm_k = np.sqrt(norm_a2 + 4 * len(A.dims))


def primal_dual(ratio, niter, callback=None):
    """PrimalDual from the warm start, τ μ ‖K‖² = 0.95 and τ / μ = ``ratio``: the image."""
    tau, mu = np.sqrt(0.95 * ratio) / norm_k, np.sqrt(0.95 / ratio) / norm_k
    return PrimalDual(proxf, proxg, K, x0=problem.warm_start.ravel().copy(), tau=tau, mu=mu, theta=1.0,
                      niter=niter, callback=callback).reshape(A.dims)


ratio = min((10.0, 100.0, 1000.0), key=lambda r: problem.objective(primal_dual(r, 20)))
history = []
pd = primal_dual(ratio, iterations, callback=lambda x: history.append(problem.objective(x)))

# %%
# J and CC, side by side
# ----------------------
for name, image in ((f"tv at its stopping rule ({tv.params['iterations']} iterations)", tv.p0),
                    (f"tv, {iterations} iterations", tv_long.p0),
                    (f"PrimalDual (τ/μ = {ratio:g}), {iterations} iterations", pd)):
    print(f"{name}: J = {problem.objective(image):.5g}, "
          f"CC with the true p0 {fpscan.correlation_coefficient(image, truth):.3f}")

fig, axes = plt.subplots(1, 4, figsize=(12, 3.2), layout="constrained")
axes[0].semilogy(np.arange(1, iterations + 1), np.array(history), label="PrimalDual")
axes[0].axhline(problem.objective(tv_long.p0), color="tab:orange", label=f"tv after {iterations}")
axes[0].set_xlabel("iteration")
axes[0].set_ylabel("J (Pa²)")
axes[0].legend()
for ax, (title, image) in zip(axes[1:], (("true p0", truth), ("tv", tv.p0), ("PrimalDual", pd))):
    ax.imshow(image.max(axis=1), cmap="gray", aspect="equal")  # projection along y: depth down
    ax.set_title(title)
    ax.set_xlabel("x (voxels)")
axes[1].set_ylabel("depth (voxels)")
plt.show()
