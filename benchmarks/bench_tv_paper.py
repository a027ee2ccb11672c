"""tv at the paper's size: wall time over one NER, iterations, operator
pairs, converged, peak memory over the image and CC with the true p0, per grid.

The case: the paper's scan — a 226 x 226 lattice of 60 µm, 1024 samples of 8 ns, c = 1500 m/s,
the equi-steradian mask of `fpscan.service.plans.equisteradian_mask` asked for 1625 points around
a point of interest 3.6 mm deep (1653 points) — of three uniform balls near that point (radii
0.30, 0.20 and 0.15 mm at 3.6, 4.32 and 2.88 mm; amplitudes 1, 0.7, 0.5), exact A-lines
(`fpscan.physics.ball_alines`: the N-waves averaged over each sample) with seeded white noise
``--snr`` dB below the signal's RMS (``--noise peak``: below its peak, k-Wave's ``addNoise(...,
'peak')``); tv in float32 at its defaults but for the grid. Rows:

- ``defaults``: the grid tv picks (`fpscan.service.recon.tv.grid`: the band the 60 µm pitch resolves,
  12.5 MHz, on an isotropic grid down to the last echo, the record kept for it);
- ``today's grid``: dz = c·dt at the record's own sampling over the whole record (``bandwidth`` =
  the Nyquist frequency, ``whole_record``);
- ``22 MHz sensor`` (with ``--declared 22e6``): the same data with a sensor bandwidth declared
  (the operator and the data cut there), to show what a band-limited grid costs and buys.

Each row runs in a fresh process: NER float32 of random data on the full 226 x 226 lattice
(the same grid, best of ``--repeat``), then tv; tv's peak is the process's VmHWM above its
RSS before tv (reset after NER, `/proc/self/clear_refs`), over the image's bytes (n_z n_y n_x
float32). The CC is against the analytic balls sampled on tv's own grid (`ball_p0`,
supersampled 2x), tv's and (after tv, for scale) NEDNER's of the same A-lines on that grid,
clipped at 0: the kind of image tv starts from. The admission estimate is the server's
(`fpscan.service.jobs.admission.estimate_memory` of the job as for a stored dataset, whose record facts
the import found: `fpscan.service.recon.tv.grid.record_facts`) over that peak. ``--scale 0.5`` runs the
same case at half the size in every dimension (113², 512 samples, 437 points) for a quick look.
``--no-continuation`` runs tv without its λ continuation (the solver until 2026-11-26), to
compare. ``--max-iter K`` caps tv's iterations at K (stop "iterations"; the continuation then
reaches λ within K / 2): the image a budget of K + 3 pairs buys in a fresh process, e.g. K = 17 for
the 20 pairs that a budget of 120x NER allows at a pair's 5.9 NERs. ``--sensor-band F`` puts the
A-lines behind the simulated scanner's sensor model (a 2nd-order Butterworth at F Hz, before the
noise) without declaring it, as on a real scan (tv's band is the pitch's unless declared), and
the CC is still with the balls themselves. ``--rule`` adds, per row,
what the stopping rule's threshold buys at this size: a 300-iteration solve
at the row's λ and a run to the rule at ``tol`` = 2e-3 (the default is 5e-3), with their wall
times, iterations, CC with the true p0 and relative distances ‖x − x₃₀₀‖ / ‖x₃₀₀‖ (5-8 x the
row's time more).

    .venv/bin/python benchmarks/bench_tv_paper.py [--scale 1] [--snr 30] [--noise rms|peak] [--declared 22e6] [--rule]
        [--no-continuation] [--max-iter K] [--sensor-band 20e6]
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import resource
import time

import numpy as np

C, DT, PITCH = 1500.0, 8e-9, 60e-6


def paper_case(scale: float = 1.0, snr_db: float = 30.0, seed: int = 1, sensor_band: float | None = None,
               noise: str = "rms") -> dict:
    """The scan above (``scale`` < 1 shrinks the lattice, the record, the depth and the balls;
    ``sensor_band``: the A-lines low-passed as the simulated scanner's sensor does, a 2nd-order
    Butterworth of that −3 dB frequency in Hz (`fpscan.driver.simulator.sensor_response`), before the noise;
    ``noise``: ``"rms"`` (``snr_db`` below the A-lines' RMS) or ``"peak"`` (below their peak, k-Wave's
    ``addNoise(..., 'peak')``))."""
    from fpscan.physics import Ball, ball_alines
    from fpscan.physics.axes import centred_axis
    from fpscan.service.plans import Lattice, equisteradian_mask

    n = int(round(226 * scale))
    n_t = int(round(1024 * scale))
    depth = 3.6e-3 * n / 226
    mask = equisteradian_mask(Lattice(n, n, PITCH), depth, int(round(1625 * n * n / 226**2)))
    pos = np.asarray(mask.positions, float)
    balls = [Ball(0.0, 0.0, depth, 0.3e-3 * scale),
             Ball(0.8e-3 * scale, -0.5e-3 * scale, 1.2 * depth, 0.2e-3 * scale, 0.7),
             Ball(-0.9e-3 * scale, 0.6e-3 * scale, 0.8 * depth, 0.15e-3 * scale, 0.5)]
    clean = ball_alines(pos, balls, DT, n_t, C)
    if sensor_band:
        from fpscan.driver.simulator import sensor_response

        clean = sensor_response(clean, sensor_band, DT)
    white = np.random.default_rng(seed).standard_normal(clean.shape)
    level = float(np.max(np.abs(clean))) if noise == "peak" else float(np.sqrt(np.mean(clean**2)))
    alines = clean + white * level / 10 ** (snr_db / 20)
    x = centred_axis(n, PITCH)
    return dict(alines=alines, positions=pos, weights=np.asarray(mask.weights, float), grid=(x, x), balls=balls,
                n=n, n_t=n_t)


def ner_seconds(data: np.ndarray, dx: float, dt: float, c: float, repeat: int = 2) -> float:
    """Seconds of one NER float32 of the dense record ``data`` ``(n_t, n_y, n_x)`` / ``(n_t, n_x)``
    (pitch ``dx`` in m, ``dt`` in s, ``c`` in m/s) at NER's own default grid: the best of ``repeat``,
    after a small run that compiles its kernels. The unit of tv's time here and in
    `bench_tv_matrix`."""
    from fpscan.service.recon import reconstruct_grid

    data = np.asarray(data, np.float32)
    reconstruct_grid(data[(slice(32),) + (slice(16),) * (data.ndim - 1)], dx, dt, c, dtype=np.float32)
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        reconstruct_grid(data, dx, dt, c, dtype=np.float32)
        best = min(best, time.perf_counter() - t)
    return float(best)


def _rss() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * resource.getpagesize()


def _reset_peak() -> None:
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def _peak() -> int:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _row(label: str, scale: float, snr: float, bandwidth, whole: bool, repeat: int, queue, rule: bool = False,
         continuation: bool = True, max_iter: int | None = None, sensor_band: float | None = None,
         noise: str = "rms") -> None:
    from fpscan.physics import ball_p0
    from fpscan.service.jobs.admission import estimate_memory
    from fpscan.service.metrics import correlation_coefficient
    from fpscan.service.recon import reconstruct_points
    from fpscan.service.recon.tv import reconstruct_tv
    from fpscan.service.recon.tv.grid import record_facts

    case = paper_case(scale, snr, sensor_band=sensor_band, noise=noise)
    n, n_t = case["n"], case["n_t"]
    data = np.random.default_rng(2).standard_normal((n_t, n, n)).astype(np.float32)
    best = ner_seconds(data, PITCH, DT, C, repeat)
    del data
    pos = case["positions"]
    # the admission's estimate of this job (fpscan.service.jobs.admission, as for a stored dataset: its record facts)
    shape = {"n_t": n_t, "n_x": n, "n_y": n, "n_points": len(pos), "dt": DT, "sound_speed": C, "dx": PITCH, "t0": 0.0,
             "record_facts": record_facts(case["alines"], DT, 1).as_dict(), "bandwidth": bandwidth}
    estimate = estimate_memory(shape, {"method": "tv", "dtype": "float32", "whole_record": whole})
    reconstruct_tv(case["alines"][:40, :32], DT, C, positions=pos[:40], n_z=8, max_iter=2, dtype=np.float32)
    base = _rss()
    _reset_peak()
    t = time.perf_counter()
    rec = reconstruct_tv(case["alines"], DT, C, positions=pos, weights=case["weights"], grid=case["grid"],
                         dtype=np.float32, bandwidth=bandwidth, whole_record=whole, continuation=continuation,
                         **({} if max_iter is None else {"max_iter": max_iter}))
    wall = time.perf_counter() - t
    peak = _peak() - base
    p = rec.params
    truth = ball_p0(case["balls"], rec.z, rec.x, rec.y, supersample=2)
    result = dict(label=label, ner=best, tv=wall, iterations=p["iterations"], pairs=p["operator_pairs"],
                  converged=p["converged"], stop=p["stop_reason"], peak=peak / rec.p0.nbytes,
                  cc=correlation_coefficient(rec.p0, truth), shape=rec.p0.shape, dz=float(rec.z[1]),
                  op_n_t=p["operator_n_t"], band=p["band"], reason=p["band_reason"], lam=p["lam_factor"],
                  record=p["record_n_t"], n_t=n_t, admission=estimate / peak)
    # what tv starts from: NEDNER float32 of the same A-lines on tv's grid, clipped at 0 (its warm start's kind)
    nedner = reconstruct_points(case["alines"], pos, DT, C, weights=case["weights"], grid=case["grid"],
                                dtype=np.float32, dz=float(rec.z[1]), n_z=len(rec.z))
    result["nedner_cc"] = correlation_coefficient(np.maximum(nedner.p0, 0), truth)
    del nedner
    if rule:  # the rule's threshold at this size: a 300-iteration solve and tol 2e-3, at the row's λ
        runs = {}
        for name, opts in (("300 iterations", dict(max_iter=300, tol=0.0)), ("tol 2e-3", dict(max_iter=300, tol=2e-3))):
            t = time.perf_counter()
            r = reconstruct_tv(case["alines"], DT, C, positions=pos, weights=case["weights"], grid=case["grid"],
                               dtype=np.float32, bandwidth=bandwidth, whole_record=whole, lam=p["lam"],
                               continuation=continuation, **opts)
            runs[name] = (time.perf_counter() - t, r)
        long = runs["300 iterations"][1].p0
        size = float(np.linalg.norm(long))
        result["rule"] = [(name, s_, r.params["iterations"], correlation_coefficient(r.p0, truth),
                           float(np.linalg.norm(r.p0 - long)) / size)
                          for name, (s_, r) in [("tol 5e-3 (the row)", (wall, rec)), *runs.items()]]
    queue.put(result)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--snr", type=float, default=30.0)
    ap.add_argument("--noise", choices=["rms", "peak"], default="rms",
                    help="the SNR below the A-lines' RMS (default) or their peak (k-Wave's addNoise 'peak')")
    ap.add_argument("--repeat", type=int, default=3, help="NER runs (best of)")
    ap.add_argument("--declared", type=float, default=None, help="also a row with this sensor bandwidth, Hz")
    ap.add_argument("--rows", nargs="+", default=["defaults", "today"], choices=["defaults", "today", "declared"])
    ap.add_argument("--rule", action="store_true", help="also a 300-iteration solve and tol 2e-3 per row (slow)")
    ap.add_argument("--no-continuation", action="store_true",
                    help="tv without λ continuation (continuation=False: the solver until 2026-11-26), to compare")
    ap.add_argument("--sensor-band", type=float, default=None,
                    help="A-lines behind the simulated scanner's sensor: a 2nd-order Butterworth of this -3 dB "
                         "frequency, Hz (not declared to tv: its band rule reads the data)")
    ap.add_argument("--max-iter", type=int, default=None,
                    help="cap tv's iterations (its max_iter): what a budget of pairs buys, e.g. 17 = 20 pairs")
    args = ap.parse_args(argv)
    rows = [r for r in args.rows]
    if args.declared and "declared" not in rows:
        rows.append("declared")
    print(f"paper case x{args.scale:g}: {args.snr:g} dB below the A-lines' {args.noise}, float32; NER float32 of the "
          "same lattice in the same process")
    print("| grid | tv s | NER s | tv / NER | iterations | pairs | converged | peak / image | CC (true p0) | image "
          "(n_z x n_y x n_x, dz) | record kept | operator samples, band | admission estimate / peak | "
          "NEDNER CC (clipped) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    ctx = mp.get_context("spawn")
    rules: list[tuple] = []
    for row in rows:
        bandwidth = {"defaults": None, "today": 1 / (2 * DT), "declared": args.declared}[row]
        label = {"defaults": "defaults", "today": "today's grid (dz = c·dt)",
                 "declared": f"{(args.declared or 0) / 1e6:g} MHz sensor declared"}[row]
        label += ", without λ continuation" if args.no_continuation else ""
        label += f", max_iter {args.max_iter}" if args.max_iter is not None else ""
        label += f", behind a {args.sensor_band / 1e6:g} MHz sensor" if args.sensor_band else ""
        queue = ctx.Queue()
        proc = ctx.Process(target=_row, args=(label, args.scale, args.snr, bandwidth, row == "today", args.repeat,
                                              queue, args.rule, not args.no_continuation, args.max_iter,
                                              args.sensor_band, args.noise))
        proc.start()
        r = queue.get()
        proc.join()
        band = "none" if r["band"] is None else f"{r['band'] / 1e6:.1f} MHz ({r['reason']})"
        print(f"| {r['label']} | {r['tv']:.1f} | {r['ner']:.3f} | {r['tv'] / r['ner']:.0f} | {r['iterations']} | "
              f"{r['pairs']:g} | {r['converged']} ({r['stop']}) | {r['peak']:.1f} | {r['cc']:.4f} | "
              f"{' x '.join(map(str, r['shape']))}, {r['dz'] * 1e6:.1f} µm | {r['record']} of {r['n_t']} | "
              f"{r['op_n_t']}, {band} | {r['admission']:.2f} | {r['nedner_cc']:.4f} |", flush=True)
        rules.extend((r["label"], *run) for run in r.get("rule", []))
    if rules:
        print("\n| grid | run (the row's λ) | tv s | iterations | CC (true p0) | distance to the 300-iteration image |")
        print("|---|---|---|---|---|---|")
        for label, name, wall, its, cc, distance in rules:
            print(f"| {label} | {name} | {wall:.1f} | {its} | {cc:.4f} | {distance:.4f} |")


if __name__ == "__main__":
    main()
