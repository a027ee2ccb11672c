"""
A delay-and-sum method as a plugin package
==========================================

fpscan's reconstruction methods are not a closed list: another package declares its own through
the plugin API ``fpscan.plugins`` and an entry point of the group ``fpscan.methods``
(docs/plugins.md), and fpscan then offers it everywhere it offers its own methods: the library's
``fpscan.reconstruct``, ``fpscan recon --method`` with a flag per option, and the server's
``POST /api/reconstructions`` with the web page's fields.

This example writes such a package, ``fpscan_das``, into a temporary folder: a delay-and-sum
(DAS) back-projection for a planar sensor with one option of its own, the receive aperture's
f-number. It "installs" it as pip would (the package beside its ``.dist-info`` folder, no network)
and then uses it from the library on a sparse 3-D scan of a few balls (beside NEDNER), from the
command line and over HTTP.
"""

# %%
# The method's module
# -------------------
# One module holds everything fpscan needs to know of the method:
#
# - its options model, a subclass of ``fpscan.plugins.MethodOptions`` (every method's speed of
#   sound and precision) and of the mix-in ``DepthOptions`` (the output depth grid ``n_z``,
#   ``dz``), plus its own field ``f_number`` with its range, unit and description: fpscan
#   generates ``--f-number`` for ``fpscan recon``, the HTTP request's field and the web page's
#   input from it, and checks every request against it;
# - its ``run(dataset, sound_speed, options, progress)``. With ``needs_grid=False`` it gets a
#   ``PointDataset`` (A-lines at any sensor points; fpscan converts grid data) and returns a
#   ``Reconstruction`` on the dataset's lateral grid;
# - its memory and work models, which the server's admission reads before it queues a job (a
#   method without them is judged by a conservative rule for unknown methods instead).
#
# The algorithm: each output pixel r = (x, y, z) is the mean, over the sensors i within the
# aperture (lateral distance at most z / (2 f_number)), of the back-projection term
# ``b_i(t) = 2 p_i(t) − 2 t ∂p_i/∂t`` at the time of flight ``t = |r − r_i| / c``, linearly interpolated
# in time, each sensor weighted by its quadrature area and the solid angle it subtends from r.
# It is vectorised over pixels and sensors and runs in chunks of depth rows, which bounds its
# memory. numpy is imported inside the functions: the command line's ``--help`` imports the
# module to build its flags, and should stay quick.
import importlib
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
import tomllib
from importlib.metadata import distributions
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import fpscan
from fpscan.clients.processes import clean_env, service
from fpscan.plugins import register_method, undeclared_peak, undeclared_work

DAS_MODULE = '''
"""fpscan_das: delay-and-sum back-projection for a planar sensor, an fpscan method plugin."""
from pydantic import Field

from fpscan.plugins import DepthOptions, Method, MethodOptions, Reconstruction, depth_grid

#: elements of one chunk's (rows, pixels, sensors) arrays
CHUNK = 1 << 21
#: seconds per (sensor, pixel) pair on the reference 2 cores, float32: measured 21-24 ns from 7e6 to
#: 4e8 pairs (float64: 41 ns), rounded up
PAIR_RATE = 4e-8
#: float64 costs this factor more (measured 1.7)
FLOAT64_FACTOR = 2.0


class Options(DepthOptions, MethodOptions):
    """Options of ``das``: the aperture's f-number, the depth grid (``n_z``, ``dz``) and every
    method's (``sound_speed``, ``dtype``, ...)."""

    f_number: float = Field(1.0, gt=0, le=20, json_schema_extra={"unit": "1"},
                            description="receive aperture: a pixel at depth z sums the sensors "
                                        "within z / (2 f_number) of it laterally")


def _sizes(n_t, n_x, n_y, n_z, n_points):
    pixels = int(n_x) * int(n_y)
    return pixels, int(n_points or pixels), int(n_z or n_t)


def chunk_rows(pixels, sensors):
    """Depth rows per chunk: CHUNK elements of (rows, pixels, sensors), at least one row."""
    return max(1, CHUNK // max(1, pixels * sensors))


def peak_memory(n_t, n_x, n_y=1, *, n_z=None, n_points=None, dtype="float32", **_):
    """Bytes at the peak, an upper bound: four float64 copies of the A-lines while b is made,
    b, the image and the lateral distances, eight 8-byte arrays of one chunk, and 64 MiB."""
    pixels, sensors, rows = _sizes(n_t, n_x, n_y, n_z, n_points)
    item = 8 if str(dtype) == "float64" else 4
    chunk = min(rows, chunk_rows(pixels, sensors)) * pixels * sensors
    return (32 * sensors * int(n_t) + item * (sensors * int(n_t) + rows * pixels + pixels * sensors)
            + 64 * chunk + (64 << 20))


def work(n_t, n_x, n_y=1, *, n_z=None, n_points=None, dtype="float32", **_):
    """Seconds on the reference 2 cores: PAIR_RATE per (sensor, pixel) pair."""
    pixels, sensors, rows = _sizes(n_t, n_x, n_y, n_z, n_points)
    return PAIR_RATE * sensors * pixels * rows * (FLOAT64_FACTOR if str(dtype) == "float64" else 1.0)


def run(ds, sound_speed, options, progress):
    """Delay-and-sum of the PointDataset ``ds`` on its lateral grid ``ds.grid``: p0
    ``(n_z, n_x)`` or ``(n_z, n_y, n_x)``, depth rows ``n_z`` at ``dz`` (default: fpscan's depth
    grid, depth_grid: the lateral pitch, as deep as the record reaches)."""
    import numpy as np

    dtype = np.dtype(options.dtype)
    c, dt, t0 = float(sound_speed), float(ds.dt), float(ds.t0)
    alines = np.asarray(ds.alines, dtype=np.float64)  # (n, n_t)
    n, n_t = alines.shape
    if n == 0:
        raise ValueError("the input has no A-lines to reconstruct")
    # the back-projection term of every A-line, flattened for one gather per chunk
    t = t0 + dt * np.arange(n_t)
    b = (2 * alines - 2 * t * np.gradient(alines, dt, axis=1)).astype(dtype).ravel()
    del alines
    area = (np.ones(n) if ds.weights is None else np.asarray(ds.weights, dtype=np.float64)).astype(dtype)

    axes = [np.asarray(a, dtype=np.float64) for a in ds.grid]  # (x,) or (x, y)
    pixels = np.stack([g.ravel() for g in np.meshgrid(*axes[::-1], indexing="ij")[::-1]], axis=1)
    sensors = np.asarray(ds.positions, dtype=np.float64)  # (n, 1) or (n, 2), m
    rho2 = ((pixels[:, None, :] - sensors[None]) ** 2).sum(axis=2).astype(dtype)  # lateral distance²

    pitch = float(axes[0][1] - axes[0][0]) if len(axes[0]) > 1 else None
    dz, n_z = depth_grid(n_t, dt, c, pitch, dz=options.dz, n_z=options.n_z, t0=t0)
    z = np.arange(n_z) * dz
    reach = (2 * options.f_number) ** 2
    first = (np.arange(n) * n_t).astype(np.intp)  # where each A-line starts in b
    image = np.zeros((n_z, len(pixels)), dtype=dtype)
    step = chunk_rows(len(pixels), n)
    for start in range(0, n_z, step):
        zs = z[start:start + step].astype(dtype)[:, None, None]  # (rows, 1, 1)
        r = np.sqrt(rho2 + zs * zs)  # (rows, pixels, n): distance to each sensor, m
        frac = (r / c - t0) / dt  # time of flight in samples
        at = np.floor(frac)
        frac -= at  # the linear interpolation's weight of the later sample
        use = (at >= 0) & (at < n_t - 1) & (rho2 * reach <= zs * zs)  # in the record and the aperture
        at = np.where(use, at, 0).astype(np.intp)
        at += first
        value = b[at + 1] * frac
        frac -= 1
        value -= b[at] * frac
        del at, frac
        weight = np.maximum(r, dz, out=r)
        weight **= -3
        weight *= area * zs  # sensor area x solid angle seen from the pixel
        weight[~use] = 0
        total = weight.sum(axis=2)
        value *= weight
        image[start:start + step] = value.sum(axis=2) / np.where(total > 0, total, 1)
        del r, weight, value, use
        progress(min(1.0, (start + step) / n_z), "delay and sum")
    y = axes[1] if len(axes) == 2 else None
    params = {"sound_speed": c, "f_number": options.f_number, "n_z": n_z, "dz": dz, "dtype": dtype.name,
              "n_points": n, "dt": dt, "t0": t0}
    return Reconstruction(image.reshape(n_z, *(len(a) for a in axes[::-1])), z, axes[0], y, params)


METHOD = Method(name="das", title="delay-and-sum back-projection (any sensor mask)", needs_grid=False,
                options_model=Options, run=run, peak_memory=peak_memory, work=work, order=200,
                source="delay and sum of the back-projection term 2p - 2t dp/dt, solid-angle weighted")
'''

# %%
# The package and its entry point
# -------------------------------
# The project is that module as ``fpscan_das/__init__.py`` and a ``pyproject.toml`` whose
# ``[project.entry-points."fpscan.methods"]`` table names the method: ``das =
# "fpscan_das:METHOD"``. The entry point's name is the method's name.
PYPROJECT = '''
[build-system]
requires = ["setuptools>=68"]
build-backend = "setuptools.build_meta"

[project]
name = "fpscan-das"
version = "0.1"
description = "delay-and-sum reconstruction for fpscan"
dependencies = ["fpscan", "numpy", "pydantic>=2"]

[project.entry-points."fpscan.methods"]
das = "fpscan_das:METHOD"
'''

tmp = tempfile.TemporaryDirectory(prefix="fpscan-das-")
folder = Path(tmp.name)
project = folder / "fpscan-das"
(project / "fpscan_das").mkdir(parents=True)
(project / "pyproject.toml").write_text(textwrap.dedent(PYPROJECT).lstrip())
(project / "fpscan_das" / "__init__.py").write_text(textwrap.dedent(DAS_MODULE).lstrip())

# %%
# Install it
# ----------
# ``pip install ./fpscan-das`` would copy the package into site-packages beside a
# ``fpscan_das-0.1.dist-info`` folder holding ``METADATA`` and ``entry_points.txt``, which is where
# ``importlib.metadata`` (and so fpscan) finds entry points. The same by hand, into a folder of
# its own that this process and its children put on their path: nothing is downloaded and the
# environment is left as it was.
site = folder / "site"
shutil.copytree(project / "fpscan_das", site / "fpscan_das")
meta = tomllib.loads((project / "pyproject.toml").read_text())["project"]
info = site / f"fpscan_das-{meta['version']}.dist-info"
info.mkdir()
(info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {meta['name']}\nVersion: {meta['version']}\n")
groups = meta["entry-points"]
(info / "entry_points.txt").write_text("".join(
    f"[{group}]\n" + "".join(f"{name} = {value}\n" for name, value in points.items()) + "\n"
    for group, points in groups.items()))
print((info / "entry_points.txt").read_text())

sys.path.insert(0, str(site))
importlib.invalidate_caches()
env = clean_env(PYTHONPATH=os.pathsep.join([str(site), *filter(None, [os.environ.get("PYTHONPATH")])]))  # no FPSCAN_*

# %%
# The method in the library
# -------------------------
# fpscan reads the ``fpscan.methods`` entry points the first time its registry is read
# (``fpscan.METHODS``, ``fpscan.reconstruct``), so in a fresh process ``das`` is simply there. This
# process may have read the registry before the package was installed (a documentation build
# does), so the entry point's method is registered here where it is missing.
#
# The admission reads the method's own memory and work models. A method that declares none is
# judged by the rules for unknown methods, ``undeclared_peak`` (32 float64 copies of the larger of
# input and output) and ``undeclared_work`` (50 ns per sensor and voxel, above what a plain numpy
# back-projection such as this one costs). A method that declares its own models is judged by its
# own figures: here 40 ns per pair, measured.
if str(site) not in sys.path:  # a documentation build runs each section with the path it started with
    sys.path.insert(0, str(site))
(dist,) = distributions(path=[str(site)])  # the package installed above, read from its own folder
(point,) = dist.entry_points.select(group="fpscan.methods", name="das")
if "das" not in fpscan.METHODS:
    register_method(point.load())
das = fpscan.METHODS["das"]
print(f"{das.name}: {das.title}\n  options {das.options}\n  defaults {das.defaults}")
size = {"n_t": 200, "n_x": 32, "n_y": 32, "n_z": 28, "n_points": 256}
print(f"  at {size}: peak {das.memory(**size) / 2**20:.0f} MiB, work {das.estimate_work(**size):.2f} s "
      f"(the rules for a method without models: {undeclared_peak(**size) / 2**20:.0f} MiB, "
      f"{undeclared_work(**size):.2f} s)")

# %%
# A sparse scan of three balls
# ----------------------------
# A 32 × 32 lattice at 60 µm, of which an equi-steradian mask around a point 0.9 mm deep keeps a
# quarter; the balls' A-lines are simulated exactly at the mask's points (``fpscan.ball_alines``)
# and carry the mask's quadrature weights.
n, pitch, dt, n_t, c = 32, 60e-6, 8e-9, 200, 1500.0
balls = [fpscan.Ball(x=0.0, y=0.0, z=0.9e-3, radius=0.15e-3),
         fpscan.Ball(x=-0.5e-3, y=0.4e-3, z=0.6e-3, radius=0.1e-3),
         fpscan.Ball(x=0.45e-3, y=-0.4e-3, z=1.3e-3, radius=0.12e-3, amplitude=0.8)]
lattice = fpscan.Lattice(n, n, pitch)
mask = fpscan.make_mask("equisteradian", lattice, depth=0.9e-3, n_points=round(0.25 * n * n))
sparse = fpscan.PointDataset(alines=fpscan.ball_alines(mask.positions, balls, dt, n_t, c),
                             positions=np.asarray(mask.positions), weights=np.asarray(mask.weights), dt=dt,
                             sound_speed=c, grid=(lattice.x, lattice.y))
n_z = 28  # 1.68 mm deep at dz = pitch
p0 = fpscan.ball_p0(balls, np.arange(n_z) * pitch, lattice.x, lattice.y)  # (n_z, n_y, n_x)
print(mask)

# %%
# Reconstruct with ``das`` and ``nedner``
# ---------------------------------------
# ``das``'s own option is checked like any other (a bad value is refused naming it). A small
# f-number opens the aperture; the default, 1, sums only the sensors within half the depth.
grid = {"dz": pitch, "n_z": n_z, "quiet": True}
try:
    fpscan.reconstruct(sparse, "das", f_number=0, **grid)
except ValueError as exc:
    print("refused:", exc)
images = {"true p0": p0}
for f_number in (1.0, 0.25):
    started = time.perf_counter()
    rec = fpscan.reconstruct(sparse, "das", f_number=f_number, **grid)
    seconds = time.perf_counter() - started
    cc = fpscan.correlation_coefficient(np.maximum(rec.p0, 0), p0)
    print(f"das, f_number {f_number}: CC with the true p0 {cc:.3f}, {seconds:.2f} s "
          f"(its work model: {das.estimate_work(n_t, n, n, n_z=n_z, n_points=len(mask.positions)):.2f} s)")
    images[f"DAS, f/{f_number:g}"] = rec.p0
nedner = fpscan.reconstruct(sparse, "nedner", **grid)
print(f"nedner: CC with the true p0 {fpscan.correlation_coefficient(np.maximum(nedner.p0, 0), p0):.3f}")
images["NEDNER"] = nedner.p0
print(rec.params)

# %%
# Side by side: maximum-intensity projections
# -------------------------------------------
# Top row: the projection along depth (x-y, seen from the sensor); bottom row: along y (depth
# down). Each image is scaled to its own maximum.
assert rec.y is not None  # 3-D
extent_xy = [rec.x[0] * 1e3, rec.x[-1] * 1e3, rec.y[-1] * 1e3, rec.y[0] * 1e3]
extent_xz = [rec.x[0] * 1e3, rec.x[-1] * 1e3, rec.z[-1] * 1e3, rec.z[0] * 1e3]
fig, axes = plt.subplots(2, 4, figsize=(12, 5.6), layout="constrained")
for column, (title, volume) in enumerate(images.items()):
    volume = np.maximum(volume, 0)
    axes[0, column].imshow(volume.max(axis=0), extent=extent_xy, cmap="gray")
    axes[1, column].imshow(volume.max(axis=1), extent=extent_xz, cmap="gray")
    axes[0, column].set_title(f"{title}, {len(mask.positions)} sensors" if column else title, fontsize=10)
    axes[1, column].set_xlabel("x (mm)")
axes[0, 0].set_ylabel("y (mm)")
axes[1, 0].set_ylabel("depth (mm)")
plt.show()

# %%
# On the command line
# -------------------
# A new process finds the plugin through its entry point. ``fpscan recon --help`` lists ``das``
# and its ``--f-number`` flag, generated from the options model; the dense scan of every lattice
# point, saved as a ``.npy`` array (time first), is reconstructed with ``das`` (grid data are
# handed to a point method as sensor points).
full = fpscan.make_mask("full", lattice)
dense = fpscan.ball_alines(full.positions, balls, dt, n_t, c).T.reshape(n_t, n, n)  # (n_t, n_y, n_x)
npy = folder / "balls.npy"
np.save(npy, dense)


def fpscan_cli(*args: str) -> str:
    """Run ``python -m fpscan ARGS`` with the plugin on its path; its standard output."""
    done = subprocess.run([sys.executable, "-m", "fpscan", *args], capture_output=True, text=True, env=env,
                          timeout=300)
    if done.returncode != 0:
        raise RuntimeError(f"fpscan {args[0]} failed:\n{done.stderr}")
    return done.stdout


helped = fpscan_cli("recon", "--help").splitlines()
flag = next(k for k, line in enumerate(helped) if line.lstrip().startswith("--f-number"))
print("\n".join(helped[flag:flag + 3]))
print(fpscan_cli("recon", str(npy), "--dt", "8ns", "--dx", "60um", "--method", "das", "--f-number", "2",
                 "--n-z", str(n_z), "--dz", "60um", "--out", str(folder / "cli"), "--quiet"))

# %%
# Over HTTP
# ---------
# A server started in an environment where the package is installed serves ``das`` like a
# built-in method: ``GET /api/reconstructions/methods`` lists it with its options (the web
# page's fields), and ``POST /api/reconstructions`` takes ``f_number`` in its ``params``.
# The server runs on a free port of 127.0.0.1 with its own data folder (no token: it listens on
# loopback only), without its kernel warm-up.
# ``fpscan.clients.processes.service`` starts it, waits until ``GET /api/health`` answers (at most
# two minutes) and stops it when the block ends.
try:
    with service(folder / "data", web=False, timeout=120, log_path=folder / "server.log",
                 env={"PYTHONPATH": env["PYTHONPATH"], "FPSCAN_WARM_UP": "false"}) as server, \
            fpscan.Client(server.url, timeout=30) as api:
        served = {m.name: m for m in api.methods()}
        print(f"served methods: {', '.join(served)}")
        print("das's f_number:", next(o for o in served["das"].options if o.name == "f_number"))
        dataset_id = api.upload_dataset(npy, "npy", dt=dt, dx=pitch, dy=pitch)
        job_id = api.start_reconstruction(dataset_id=dataset_id, method="das",
                                          params={"f_number": 2.0, "n_z": n_z, "dz": pitch})
        job = api.wait(job_id, timeout=300, quiet=True)
        print(f"job {job.id}: {job.state}\n  its options: {job.params['params']}\n"
              f"  used: {job.params['result']['params_used']}")
finally:
    tmp.cleanup()
