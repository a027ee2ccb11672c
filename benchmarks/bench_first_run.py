"""A new user's first run, measured from a fresh clone, as ratios in one run.

Clones this repository's committed HEAD into a temporary folder (nothing of this checkout's
``.venv`` or numba cache comes along), then times, on that clone:

1. the install, as ``scripts/demo.sh`` does it (a virtual environment, ``pip install -e
   '.[server]'``; pip's own download cache is used where warm);
2. the set-up's kernel warm-up (the ``fpscan warmup`` line of ``scripts/demo.sh``, run as that
   script runs it after the install: numba's cache written once for the methods quick to warm);
3. the demo (``fpscan demo``), and how often its log repeats a line (each state should be said
   once), then the demo again (everything warm) for the ratio;
4. the first local NEDNER of 405 points at 512 × 96² (an equi-steradian plan around a ball) in
   a fresh interpreter: the process's wall time and the ``reconstruct`` call's, then the same
   call again in that process for the ratio.

With ``--cold`` the NEDNER of step 4 also runs on a second clone that skipped step 2 (numba's
cache empty: what a first run cost before the set-up's warm-up).

    .venv/bin/python benchmarks/bench_first_run.py [--cold]

Minutes of both cores of a 2-core machine: run it alone.
"""
from __future__ import annotations

import argparse
import collections
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

FIRST_NEDNER = """
import time
t0 = time.perf_counter()
import numpy as np
import fpscan
plan = fpscan.make_plan("equisteradian", lattice=fpscan.Lattice(96, 96, 100e-6),
                        params={"depth": 3e-3, "n_points": 405}, acquisition={"n_t": 512, "dt": 8e-9})
pos = plan.recon_positions()
balls = [fpscan.Ball(x=0.2e-3, y=-0.3e-3, z=3e-3, radius=2e-4, amplitude=1.0)]
ds = fpscan.PointDataset(alines=fpscan.ball_alines(pos, balls, 8e-9, 512, 1500.0), positions=pos,
                         weights=plan.weights_array(), dt=8e-9, sound_speed=1500.0,
                         grid=(np.arange(96) * 1e-4 - 4.75e-3, np.arange(96) * 1e-4 - 4.75e-3))
t1 = time.perf_counter()
rec = fpscan.reconstruct(ds, "nedner")
t2 = time.perf_counter()
fpscan.reconstruct(ds, "nedner")
t3 = time.perf_counter()
print(f"{rec.p0.shape} setup {t1 - t0:.2f} first {t2 - t1:.2f} again {t3 - t2:.2f}")
"""


def _run(cmd: list[str], cwd: Path, env: dict | None = None) -> tuple[float, str]:
    """Run ``cmd`` in ``cwd``; (wall seconds, stdout + stderr); raises on failure."""
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    return time.perf_counter() - t0, r.stdout + r.stderr


def _clone(tmp: Path, name: str) -> tuple[Path, float]:
    """A fresh clone with its install; (folder, install seconds)."""
    dest = tmp / name
    subprocess.run(["git", "clone", "-q", str(REPO), str(dest)], check=True)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "venv", ".venv"], cwd=dest, check=True)
    _run([".venv/bin/python", "-m", "pip", "install", "-q", "-e", ".[server]"], dest)
    return dest, time.perf_counter() - t0


def _setup_warmup() -> list[str]:
    """The warm-up command of ``scripts/demo.sh`` (its ``fpscan warmup`` line, without redirections)."""
    for line in (REPO / "scripts" / "demo.sh").read_text().splitlines():
        words = line.split("#", 1)[0].split()
        if words[:2] == [".venv/bin/fpscan", "warmup"]:
            return words[:next((i for i, w in enumerate(words) if w.startswith((">", "2>"))), len(words))]
    raise SystemExit("scripts/demo.sh has no `.venv/bin/fpscan warmup` line")


def _env() -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("FPSCAN_", "NUMBA_CACHE"))}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def _nedner(clone: Path) -> tuple[float, str]:
    return _run([".venv/bin/python", "-c", FIRST_NEDNER], clone, _env())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cold", action="store_true", help="also the first NEDNER on a clone without the warm-up")
    a = ap.parse_args()
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="fpscan-first-run-") as tmp_name:
        tmp = Path(tmp_name)
        clone, install_s = _clone(tmp, "clone")
        warm_cmd = _setup_warmup()
        warm_s, _ = _run(warm_cmd, clone, _env())
        demo_s, log = _run([".venv/bin/fpscan", "demo", "--out", "demo-output"], clone, _env())
        lines = [line for line in log.splitlines() if line.strip()]
        repeats = sum(n - 1 for n in collections.Counter(lines).values() if n > 1)
        demo2_s, _ = _run([".venv/bin/fpscan", "demo", "--out", "demo-output-2"], clone, _env())
        nedner_s, said = _nedner(clone)
        rows = [("install (venv + pip install -e .[server])", install_s, ""),
                (f"set-up warm-up ({' '.join(warm_cmd[1:]).replace('bin/', '')})", warm_s, ""),
                ("first demo (fpscan demo)", demo_s, f"{demo_s / demo2_s:.2f}x the warm rerun"),
                ("demo again, warm", demo2_s, ""),
                ("first NEDNER 405 pts, 512 x 96^2 (process)", nedner_s, said.strip())]
        if a.cold:
            cold, _ = _clone(tmp, "cold")
            cold_s, cold_said = _nedner(cold)
            rows.append(("first NEDNER without the warm-up (process)", cold_s,
                         f"{cold_s / nedner_s:.2f}x with it; {cold_said.strip()}"))
    print(f"load average at start {load:.2f} ({os.cpu_count()} cores)")
    for what, seconds, note in rows:
        print(f"{what:<46} {seconds:7.1f} s  {note}")
    print(f"demo log lines repeated: {repeats} (of {len(lines)})")
    print(f"scripts/demo.sh after its install (warm-up + first demo): {warm_s + demo_s:.1f} s (target <= 40 s)")


if __name__ == "__main__":
    main()
