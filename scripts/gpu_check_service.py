"""The GPU path through fpscan's doors: ``fpscan recon --device cuda`` locally, and a
reconstruction job with ``device: "cuda"`` through a real server on loopback (``fpscan serve``,
the CLI as its client), each on the same grid data; prints the device each result's params
record, the GPU-CPU difference and what ``/api/health`` lists. Part of ``scripts/gpu-check.sh
full``; ``--device cpu`` runs it on a machine without a GPU.

    python scripts/gpu_check_service.py [--device cuda] [--out DIR] [--port 8765]
"""
from __future__ import annotations

import argparse
import json
import os
import secrets
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py
import httpx
import numpy as np

FPSCAN = [sys.executable, "-c", "import sys; from fpscan.clients.cli import main; sys.exit(main())"]


def _recon(npy: Path, out: Path, device: str, *extra: str) -> dict:
    cmd = [*FPSCAN, "recon", str(npy), "--dx", "60e-6", "--dt", "8e-9", "--method", "ner", "--device", device,
           "--out", str(out), "--quiet", *extra]
    t = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    wall = time.perf_counter() - t
    print(f"$ fpscan recon ... --device {device} {' '.join(extra)}  (rc {done.returncode}, {wall:.1f} s)")
    if done.returncode != 0:
        print(done.stdout[-1500:], done.stderr[-3000:])
        raise SystemExit(1)
    with h5py.File(out / "volume.h5") as f:
        params = json.loads(f.attrs["params"])
        p0 = f["p0"][()]
    print("  params:", {k: params.get(k) for k in ("method", "device", "device_name", "device_fallback", "dtype")})
    return dict(params=params, p0=p0)


def main(argv: list[str] | None = None) -> None:
    """Run the checks (module doc); exit 1 where a command fails."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--out", default=None)
    parser.add_argument("--port", type=int, default=8765)
    args = parser.parse_args(argv)
    out = Path(args.out or tempfile.mkdtemp(prefix="gpu-check-"))
    out.mkdir(parents=True, exist_ok=True)
    npy = out / "grid.npy"
    np.save(npy, np.random.default_rng(0).standard_normal((512, 128, 128)).astype(np.float32))
    local = _recon(npy, out / "local", args.device)
    cpu = _recon(npy, out / "local-cpu", "cpu")
    diff = float(np.abs(local["p0"] - cpu["p0"]).max() / np.abs(cpu["p0"]).max())
    print(f"  {args.device} vs cpu: max |Δ| / max = {diff:.2e}")
    assert local["params"]["device"] == (args.device if args.device != "auto" else local["params"]["device"])

    data_dir = Path(tempfile.mkdtemp(prefix="gpu-check-server-"))
    os.environ["FPSCAN_TOKEN"] = token = secrets.token_hex(32)  # the server's and the CLI client's
    server = subprocess.Popen([*FPSCAN, "serve", "--port", str(args.port), "--data-dir", str(data_dir),
                               "--workers", "2", "--log-level", "warning"],
                              stdout=open(out / "server.log", "w"), stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{args.port}"
    try:
        deadline = time.monotonic() + 180
        while True:
            try:
                health = httpx.get(f"{url}/api/health", headers={"Authorization": f"Bearer {token}"}, timeout=5)
                if health.status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if server.poll() is not None or time.monotonic() > deadline:
                print((out / "server.log").read_text()[-3000:])
                raise SystemExit("the server did not come up")
            time.sleep(0.5)
        body = health.json()
        print("GET /api/health devices:", json.dumps(body.get("devices")))
        remote = _recon(npy, out / "remote", args.device, "--server", url)
        diff = float(np.abs(remote["p0"] - cpu["p0"]).max() / np.abs(cpu["p0"]).max())
        print(f"  server job on {remote['params'].get('device')} vs local cpu: max |Δ| / max = {diff:.2e}")
        assert remote["params"]["device"] == local["params"]["device"]
    finally:
        server.terminate()
        server.wait(timeout=60)
    print("service check done")


if __name__ == "__main__":
    main()
