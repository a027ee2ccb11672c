"""
The HTTP client: upload, reconstruct, download
==============================================

fpscan's server (``fpscan serve``) keeps a durable job queue of scans and reconstructions; the
Python client ``fpscan.Client`` (and ``fpscan.AsyncClient``), the command line's ``--server``
and the web page all speak its HTTP API (docs/api.md). This example starts a server of its own
on a free port of 127.0.0.1, with a temporary data folder and without its web page, uploads a
small 2-D data set, reconstructs it with NER on the server, downloads the volume and its MIP
picture and stops the server at the end, whatever happens.

On a lab's machine the server runs already (``fpscan serve``, or the Docker image); then only the
``with fpscan.Client(url, token=...) as api:`` part is needed.
"""

# %%
# Data to upload
# --------------
# A ``.npy`` array in the time-first layout ``(n_t, n_x)`` of a sensor line (50 µm, 10 ns),
# simulated exactly: three small discs.
import io
import os
import secrets
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import fpscan
from fpscan.service.recon import forward_grid

n_x, n_z, dx, dt, n_t, c = 128, 64, 50e-6, 10e-9, 600, 1500.0
z, x = np.meshgrid(np.arange(n_z) * dx, (np.arange(n_x) - n_x // 2) * dx, indexing="ij")
p0 = np.zeros((n_z, n_x))
for xc, zc in [(-1.5e-3, 0.8e-3), (0.0, 1.6e-3), (1.2e-3, 2.4e-3)]:
    p0[(x - xc) ** 2 + (z - zc) ** 2 <= (120e-6) ** 2] = 1.0
tmp = tempfile.TemporaryDirectory(prefix="fpscan-http-")
folder = Path(tmp.name)
npy = folder / "line.npy"
np.save(npy, forward_grid(p0, dx, dx, dt, n_t, c).astype(np.float32))

# %%
# Start a server
# --------------
# ``python -m fpscan serve`` on a free port, its log in a file; a token made at random (32 bytes:
# ``fpscan serve`` refuses a guessable one) in its environment, and no kernel warm-up (a
# short-lived server). The client polls ``GET /api/health`` until it answers, for at most two
# minutes.
with socket.socket() as probe:
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
url = f"http://127.0.0.1:{port}"
token = secrets.token_urlsafe(32)
env = {k: v for k, v in os.environ.items() if not k.startswith("FPSCAN_")}  # no local server settings
with open(folder / "server.log", "w") as log:
    server = subprocess.Popen([sys.executable, "-m", "fpscan", "serve", "--host", "127.0.0.1", "--port", str(port),
                               "--data-dir", str(folder / "data"), "--no-web"],
                              env={**env, "FPSCAN_WARM_UP": "false", "FPSCAN_TOKEN": token}, stdout=log,
                              stderr=subprocess.STDOUT)

# %%
# Upload, reconstruct, download
# -----------------------------
# ``upload_dataset`` stores the file on the server (its format's options: ``dt``, ``dx``);
# ``start_reconstruction`` queues a job and returns its id; ``wait`` follows it to its end
# (a progress callback, or ``quiet=True``); the downloads write the result's files.
try:
    with fpscan.Client(url, token=token, timeout=30) as api:
        deadline = time.monotonic() + 120
        while True:  # until GET /api/health answers
            try:
                api.health()
                break
            except fpscan.FpscanClientError:  # not listening yet
                if server.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError("the server did not start:\n"
                                       + (folder / "server.log").read_text()[-2000:]) from None
                time.sleep(0.2)
        print("methods:", ", ".join(m.name for m in api.methods()))
        dataset_id = api.upload_dataset(npy, "npy", dt=dt, dx=dx)
        job_id = api.start_reconstruction(dataset_id=dataset_id, method="ner", params={"n_z": n_z, "dz": dx})
        job = api.wait(job_id, timeout=300, quiet=True)
        print(f"job {job.id[:8]}: {job.state}")
        api.download_volume(job_id, folder / "volume.h5")
        api.download_mip(job_id, "xz", folder / "mip_xz.png")
finally:
    server.terminate()
    try:
        server.wait(timeout=30)
    except subprocess.TimeoutExpired:
        server.kill()
        server.wait()

# %%
# The downloaded volume is the library's reconstruction
# -----------------------------------------------------
# ``fpscan.read_result`` reads the volume; the same request to the library gives the same
# array (the server and the library share one pipeline and the default precision float32).
served = fpscan.read_result(folder / "volume.h5")
local = fpscan.reconstruct(fpscan.load_dataset(npy, dt=dt, dx=dx), "ner", n_z=n_z, dz=dx, quiet=True)
print(f"served {served.p0.shape}, equal to the library's: {np.array_equal(served.p0, local.p0)}")
print(f"CC with the true p0 {fpscan.correlation_coefficient(served.p0, p0):.3f}")

fig, axes = plt.subplots(1, 2, figsize=(9, 2.8), constrained_layout=True)
axes[0].imshow(served.p0, cmap="gray", extent=[x.min() * 1e3, x.max() * 1e3, z.max() * 1e3, 0])
axes[0].set(title="volume.h5 from the server", xlabel="x (mm)", ylabel="depth (mm)")
axes[1].imshow(plt.imread(io.BytesIO((folder / "mip_xz.png").read_bytes())))
axes[1].set(title="its MIP picture, mip_xz.png")
axes[1].axis("off")
plt.show()
tmp.cleanup()
