"""tv's ETA against the actual end, and what ``tol`` changes, over a real server and the CLI.

Each run (``--runs``, ``CASE:MASK:NOISE:TOL``) is a tv job at its defaults (``tol`` as given,
float32) on a server of this script's own on 127.0.0.1 (``fpscan.clients.processes.service``),
followed twice while it runs: on its event stream (``fpscan.Client.wait``: each progress event's
``elapsed_s`` and ``eta_s``, the worker's clock) and by ``fpscan jobs wait`` (its progress lines
once a second, ``FPSCAN_PROGRESS_PERIOD=1``, each read with the time it came). Cases, masks and
noise as `bench_tv_matrix` makes them (``$FPSCAN_SHARED/data``: ``vessels`` the k-Wave vessel
tree, ``balls`` the balls and yarn, ``points`` the 2-D point targets, or a member of the phantom
family, ``family-06``, at its own grid, noise seed and point of interest; MASK ``100`` the dense
record, else the equi-steradian / equiangular mask of that percentage, sent as a plan that samples
the dense upload; NOISE ``clean``, ``peak20``, ``rms30``, ...); tv's grid is the phantom's, its
depth cut to ``--n-z`` samples on the 3-D cases (the vessel tree lies above sample 37).

Per run: the predicted end (the time a progress report said the job would end: ``elapsed_s +
eta_s`` on the server, the line's time + its ETA on the CLI) as shown at 30, 50 and 70 % of the
actual end, marked ``≥`` where the figure is the rule's earliest stop (a lower bound) and ``L``
where it is the time to the iteration limit, "-" where none was shown; the largest error from 30 %
on; the longest stretch with an ETA under 5 s shown; the iterations, λ's continuation K (the rule
can stop from K + 3), the stop reason and the CC with p0 (the phantom's, on tv's grid).

    .venv/bin/python benchmarks/bench_tv_eta.py                 # the default family, one table
    .venv/bin/python benchmarks/bench_tv_eta.py --runs vessels:100:clean:0.005 vessels:100:clean:0.0025
"""
from __future__ import annotations

import argparse
import math
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

#: the default family: the dense vessel tree (noiseless, as uploaded from its file) and sparse,
#: noisy scans of the three k-Wave cases, at the default tol and at half and a quarter of it
DEFAULT_RUNS = ("vessels:100:clean:0.005", "vessels:100:clean:0.0025", "vessels:11:peak30:0.005",
                "vessels:11:peak30:0.0025", "vessels:4:peak20:0.005", "balls:4:peak20:0.005",
                "points:100:clean:0.005", "points:11:peak30:0.005", "points:11:peak30:0.0025",
                "points:11:peak30:0.00125")
LOW_S = 5.0
ETA = re.compile(r"ETA (?P<kind>[~≥] ?)?(?:(?P<h>\d+):)?(?P<m>\d\d):(?P<s>\d\d)(?P<rest>.*)$")


def case_data(name: str, noise: str) -> dict:
    """The dense record (noisy as asked) and the phantom of a case (`bench_tv_matrix.load_case`)."""
    from bench_tv_matrix import load_case, noisy

    case = load_case(name)
    # a family member's noise is seeded by its own seed, as in its gate row
    case["data"] = case["clean"] if noise == "clean" else noisy(case["clean"], noise, case.get("seed", 0))
    return case


def plan_body(case: dict, percent: int) -> dict:
    """The plan of `bench_tv_matrix.make_mask`'s mask, as the server takes it."""
    if case.get("poi_depth") is not None:  # a family member: its objects' centroid
        depth = case["poi_depth"]
    else:
        p0 = np.maximum(case["p0"], 0)
        depth = float(np.sum(p0.sum(axis=tuple(range(1, p0.ndim))) * np.arange(p0.shape[0]))) / float(p0.sum()) * case["dz"]
    shape = case["data"].shape[1:]
    acquisition = {"n_t": int(case["data"].shape[0]), "dt": case["dt"], "sound_speed": case["c"]}
    if len(shape) == 1:
        return {"lattice": {"n_x": shape[0], "n_y": 1, "pitch": case["dx"]}, "kind": "equiangular",
                "params": {"depth": depth, "n_points": int(round(percent / 100 * shape[0]))}, "acquisition": acquisition}
    return {"lattice": {"n_x": shape[1], "n_y": shape[0], "pitch": case["dx"]}, "kind": "equisteradian",
            "params": {"depth": depth, "n_points": int(round(percent / 100 * shape[0] * shape[1]))},
            "acquisition": acquisition}


def follow_cli(url: str, job_id: str, lines: list, t0: float) -> subprocess.Popen:
    """``fpscan jobs wait`` on the job, its progress lines collected as (time since t0, text)."""
    from fpscan.clients.processes import clean_env

    proc = subprocess.Popen([sys.executable, "-m", "fpscan", "jobs", "wait", job_id, "--server", url],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env=clean_env(FPSCAN_PROGRESS_PERIOD="1"))

    def read() -> None:
        assert proc.stderr is not None
        for line in proc.stderr:
            lines.append((time.monotonic() - t0, line.rstrip("\n")))

    threading.Thread(target=read, daemon=True).start()
    return proc


def predictions(shown: list[tuple[float, float | None, str]], end: float) -> tuple[list, float | None, float]:
    """(the predicted end and its kind at 30/50/70 % of ``end``, the largest relative error from
    30 % on, the longest stretch an ETA under 5 s was shown) from (time, ETA or None, kind)."""
    at = []
    for q in (0.3, 0.5, 0.7):
        before = [s for s in shown if s[0] <= q * end]
        at.append(None if not before or before[-1][1] is None else (before[-1][0] + before[-1][1], before[-1][2]))
    errors = [abs(t + e - end) / end for t, e, _ in shown if t >= 0.3 * end and e is not None]
    low, since = 0.0, None
    for (t, e, _), nxt in zip(shown, [s[0] for s in shown[1:]] + [end]):
        if e is not None and e < LOW_S:
            since = t if since is None else since
            low = max(low, nxt - since)
        else:
            since = None
    return at, (max(errors) if errors else None), low


def server_shown(events: list[dict]) -> list[tuple[float, float | None, str]]:
    kinds = {"earliest stop": "≥", "iteration limit": "L"}
    return [(e["elapsed_s"], e.get("eta_s"), kinds.get(e.get("eta_basis") or "", "")) for e in events
            if e.get("elapsed_s") is not None]


def cli_shown(lines: list[tuple[float, str]], label: str) -> list[tuple[float, float | None, str]]:
    out = []
    for t, text in lines:
        if not text.startswith(label):
            continue
        m = ETA.search(text)
        if m is None:
            out.append((t, None, ""))
            continue
        seconds = 3600 * int(m["h"] or 0) + 60 * int(m["m"]) + int(m["s"])
        kind = "≥" if (m["kind"] or "").startswith("≥") else "L" if "iteration limit" in m["rest"] else ""
        out.append((t, float(seconds), kind))
    return out


def run(api, url: str, spec: str, uploads: dict, n_z: int, folder: Path) -> dict:
    """One run (module doc): its figures."""
    from fpscan.service.metrics import correlation_coefficient

    name, mask, noise, tol = spec.split(":")
    key = (name, noise)
    if key not in uploads:
        case = case_data(name, noise)
        path = folder / f"{name}-{noise}.npy"
        np.save(path, case["data"].astype(np.float32))
        fields = {"dt": case["dt"], "dx": case["dx"], "sound_speed": case["c"]}
        if case["data"].ndim == 3:
            fields["dy"] = case["dx"]
        uploads[key] = (case, api.upload_dataset(path, "npy", **fields))
    case, dataset_id = uploads[key]
    plan_id = None if int(mask) == 100 else str(api.create_plan(plan_body(case, int(mask))).id)
    params: dict = {"tol": float(tol), "dtype": "float32"}
    if case["p0"] is not None:  # the k-Wave phantom's grid; a family member: tv's own
        depth = case["p0"].shape[0] if case["data"].ndim == 2 else min(n_z, case["p0"].shape[0])
        params.update(dz=case["dz"], n_z=depth)
    lines: list[tuple[float, str]] = []
    events: list[dict] = []
    t0 = time.monotonic()
    job_id = api.start_reconstruction(dataset_id=dataset_id, method="tv", params=params, plan_id=plan_id)
    cli = follow_cli(url, job_id, lines, t0)
    job = api.wait(job_id, on_progress=lambda p: events.append(dict(p)), timeout=3600)
    cli.wait(timeout=120)
    time.sleep(0.2)  # the reader thread's last lines
    used = job.params["result"]["params_used"]
    done = [e["elapsed_s"] for e in events if e.get("stage") == "done" and e.get("elapsed_s") is not None]
    end = done[-1] if done else max(e.get("elapsed_s") or 0.0 for e in events)
    label = f"job {job_id[:8]}: "
    ended = [t for t, text in lines if text.startswith(label + "done")]
    cli_end = ended[-1] if ended else lines[-1][0]
    volume = folder / f"{job_id}.h5"
    api.download_volume(job_id, volume)
    import fpscan

    result = fpscan.read_result(volume)
    image = result.p0
    if case["p0"] is not None:
        truth = case["p0"][:depth]
    else:  # the family's balls on tv's grid (`tv_family.balls_p0`)
        import tv_family

        truth = tv_family.balls_p0(case["balls"], result.z, result.x, result.y, supersample=2)
    return dict(run=spec, end=end, events=events, lines=lines, server=predictions(server_shown(events), end),
                cli_end=cli_end, cli=predictions(cli_shown(lines, label), cli_end),
                iterations=used["iterations"], K=used["continuation_iterations"], stop=used["stop_reason"],
                change=used.get("iterate_change"), cc=correlation_coefficient(image, truth))


def worst(w: float | None) -> str:
    return "-" if w is None or math.isnan(w) else f"{100 * w:.0f} %"


def cell(p, end: float) -> str:
    if p is None:
        return "-"
    value, kind = p
    return f"{kind}{value:.0f} ({100 * (value - end) / end:+.0f} %)"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", nargs="+", default=list(DEFAULT_RUNS), help="CASE:MASK:NOISE:TOL each")
    ap.add_argument("--n-z", type=int, default=40, help="tv's image depth on the 3-D cases, samples")
    ap.add_argument("--json", type=Path, default=None, help="append each run's figures, events and CLI lines")
    args = ap.parse_args(argv)
    import fpscan
    from fpscan.clients.processes import service

    print("| run | server: predicted end at 30 / 50 / 70 % (s) | actual end (s) | worst from 30 % | ETA < 5 s "
          "shown | CLI: predicted end at 30 / 50 / 70 % (s) | actual end (s) | worst | ETA < 5 s | iterations "
          "(K + 3) | stop | CC |")
    print("|" + "---|" * 13)
    with tempfile.TemporaryDirectory(prefix="fpscan-eta-") as tmp:
        folder = Path(tmp)
        with service(folder / "data", web=False, timeout=120, log_path=folder / "server.log",
                     env={"FPSCAN_WARM_UP": "false"}) as srv, fpscan.Client(srv.url, timeout=60) as api:
            uploads: dict = {}
            for spec in args.runs:
                r = run(api, srv.url, spec, uploads, args.n_z, folder)
                if args.json:
                    import json

                    with args.json.open("a") as fh:
                        fh.write(json.dumps(r, default=str) + "\n")
                (s30, s50, s70), sw, slow = r["server"]
                (c30, c50, c70), cw, clow = r["cli"]
                print(f"| {r['run']} | {cell(s30, r['end'])} / {cell(s50, r['end'])} / {cell(s70, r['end'])} | "
                      f"{r['end']:.0f} | {worst(sw)} | {slow:.1f} s | {cell(c30, r['cli_end'])} / "
                      f"{cell(c50, r['cli_end'])} / {cell(c70, r['cli_end'])} | {r['cli_end']:.0f} | {worst(cw)} | "
                      f"{clow:.1f} s | {r['iterations']} ({r['K'] + 3}) | {r['stop']}, change "
                      f"{r['change']:.2g} | {r['cc']:.4f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
