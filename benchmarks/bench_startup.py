"""Start-up speed a user feels, as ratios measured in one run.

Each case is a fresh interpreter (wall time of the whole process, start to exit); the cases
run interleaved, ``--repeat`` rounds, and the table shows each one's median and its ratio to
``python -c pass`` and to ``python -c "import numpy"``, with the load average beside it:

- ``fpscan --version`` and ``fpscan --help`` (target <= 1.5x ``python -c pass``: no numpy,
  h5py or service code is imported);
- ``import fpscan.service.recon`` (target <= 2x ``import numpy``: scipy.fft, numba, finufft and
  pylops load when a method needs them);
- the first tiny reconstruction (NER of a 32 x 8 x 8 grid + NEDNER of 40 scattered A-lines,
  float32, imports included) with numba's cache cold (a fresh, empty ``NUMBA_CACHE_DIR``)
  and warm (a second fresh interpreter on the cache the cold run wrote; target <= 3x
  ``import numpy``). Transforms this small run in numpy (`fpscan.physics.fft_engine`): no
  kernel compiles or loads, so both rows are the same work (before that path: 10.8 s cold,
  1.74 s warm).

    .venv/bin/python benchmarks/bench_startup.py [--repeat 5]

Run from the repository root (or with the package installed); the CLI cases run the
``fpscan`` console script beside the interpreter when there is one. The children run with
bytecode caching on (``PYTHONDONTWRITEBYTECODE`` removed), as an installed package has it.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TINY_RECON = """
import numpy as np
from fpscan.service.recon import reconstruct_grid, reconstruct_points
data = np.zeros((32, 8, 8), dtype=np.float32)
data[5, 4, 4] = 1.0
reconstruct_grid(data, 1e-4, 2e-8, dtype="float32")
rng = np.random.default_rng(0)
pos = rng.uniform(0.0, 7e-4, (40, 2))
al = rng.standard_normal((40, 32)).astype(np.float32)
grid = (np.arange(8) * 1e-4, np.arange(8) * 1e-4)
reconstruct_points(al, pos, 2e-8, weights=np.full(40, 1e-8), grid=grid, dtype="float32")
"""


def _cli(*args: str) -> list[str]:
    script = Path(sys.executable).with_name("fpscan")
    if script.exists():
        return [sys.executable, str(script), *args]
    return [sys.executable, "-c", f"import sys; from fpscan.clients.cli import main; sys.exit(main({list(args)!r}))"]


def _run(cmd: list[str], env: dict[str, str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="interleaved rounds (median)")
    args = ap.parse_args(argv)
    py = sys.executable
    base = dict(os.environ)
    base.setdefault("PYTHONPATH", str(Path(__file__).resolve().parents[1]))
    # as installed: the modules' bytecode cached (pip compiles it at install); one untimed
    # round below writes it for a source checkout
    base.pop("PYTHONDONTWRITEBYTECODE", None)
    cases = {
        "python -c pass": [py, "-c", "pass"],
        "import numpy": [py, "-c", "import numpy"],
        "fpscan --version": _cli("--version"),
        "fpscan --help": _cli("--help"),
        "import fpscan.service.recon": [py, "-c", "import fpscan.service.recon"],
        "tiny NER+NEDNER, cold cache": [py, "-c", TINY_RECON],
        "tiny NER+NEDNER, warm cache": [py, "-c", TINY_RECON],
    }
    times: dict[str, list[float]] = {k: [] for k in cases}
    loads = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, cmd in cases.items():
            if "tiny" not in name:
                _run(cmd, base)
        for r in range(args.repeat):
            cache = os.path.join(tmp, f"numba-{r}")  # a fresh, empty cache each round
            env = dict(base, NUMBA_CACHE_DIR=cache)
            for name, cmd in cases.items():  # cold before warm: the cold run fills the cache
                times[name].append(_run(cmd, env))
            loads.append(os.getloadavg()[0])
    med = {k: statistics.median(v) for k, v in times.items()}
    p, n = med["python -c pass"], med["import numpy"]
    print(f"start-up, median of {args.repeat} interleaved rounds; load average (1 min) "
          f"{min(loads):.2f}..{max(loads):.2f} on {os.cpu_count()} CPUs")
    print(f"{'case':32s} {'seconds':>8s} {'/ pass':>8s} {'/ numpy':>8s}")
    for name, t in med.items():
        print(f"{name:32s} {t:8.3f} {t / p:8.2f} {t / n:8.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
