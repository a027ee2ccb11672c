"""The GPU path on the paper's scan: NER float32 and tv to its rule, on the GPU and on
the CPU (every core, and one core), in one run; the GPU-CPU differences, the GPU's peak memory,
tv's pairs and stop.

The case is `bench_tv_paper.paper_case` (a 226² lattice of 60 µm, 1024 samples of 8 ns, the
equi-steradian mask of 1653 points around a point of interest 3.6 mm deep, three balls, noise
``--snr`` dB below the A-lines' ``--noise`` level). Rows:

- NER float32 of random data on the full lattice (as bench_tv_paper), warm (plans, taps and
  compiled kernels ready), best of ``--repeat``: on the GPU host to host (the data copied there,
  the image back) and on the device (data already there, synchronised), and on the CPU;
- NEDNER float32 of the scan's A-lines (the lateral step on the host, `fpscan.service.recon.planar`);
- tv float32 at its defaults (its grid, band, λ rule and stopping rule), set-up included: on the
  GPU, and on the CPU; then the GPU again at the CPU's λ (the rest its defaults), whose iterations
  and image are compared with the CPU's (CC), and both images' CC with the true balls.

The one-core rows run in a child process pinned to core 0 (``taskset``/``sched_setaffinity``,
numba and OpenMP at one thread; pocketfft still starts ``os.cpu_count()`` threads on that core).
``--one-core none`` skips them, ``ner`` runs NER only; ``--one-core-scale`` runs them (and the same
rows on every core, for the ratio) at another size, e.g. 0.5 where one core would take minutes
for tv at the paper's size. The GPU's peak is the largest ``used_bytes``
of CuPy's memory pool seen at any allocation (an allocator hook), per step.

    python benchmarks/bench_gpu.py [--scale 1] [--snr 30] [--noise rms|peak] [--repeat 5]
        [--one-core all|ner|none] [--one-core-scale S] [--one-core-timeout SECONDS] [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_tv_paper import DT, PITCH, C, paper_case


def best_of(fn, repeat: int, sync=None) -> float:
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        if sync is not None:
            sync()
        best = min(best, time.perf_counter() - t)
    return best


def _ner_data(case: dict) -> np.ndarray:
    n, n_t = case["n"], case["n_t"]
    return np.random.default_rng(2).standard_normal((n_t, n, n)).astype(np.float32)


_SPENT = {"operator": 0.0, "warm start": 0.0}


def _timed(fn, key: str, sync=None):
    """``fn`` timed into ``_SPENT[key]`` (synchronised with the GPU after each call when ``sync``)."""
    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        out = fn(*args, **kwargs)
        if sync is not None:
            sync()
        _SPENT[key] += time.perf_counter() - t
        return out
    return wrapper


def _tv(case: dict, device: str, **kw) -> tuple[float, object]:
    """tv on ``case``; also the time in its operator pairs (A and B = P Aᵀ, `Model.forward` / `Model.B`) and
    its warm start, in ``rec.params["bench_spent"]`` (an instrumentation of this benchmark only)."""
    from fpscan.service.recon.tv import problem, reconstruct_tv
    from fpscan.service.recon.tv import reconstruct as tv_reconstruct  # where reconstruct_tv reads warm_start

    sync = None
    if device != "cpu":
        import cupy

        sync = cupy.cuda.get_current_stream().synchronize
    saved = problem.Model.forward, problem.Model.B, tv_reconstruct.warm_start
    problem.Model.forward = _timed(saved[0], "operator", sync)
    problem.Model.B = _timed(saved[1], "operator", sync)
    tv_reconstruct.warm_start = _timed(saved[2], "warm start")
    _SPENT.update(operator=0.0, **{"warm start": 0.0})
    try:
        t = time.perf_counter()
        rec = reconstruct_tv(case["alines"], DT, C, positions=case["positions"], weights=case["weights"],
                             grid=case["grid"], dtype=np.float32, device=device, **kw)
        wall = time.perf_counter() - t
    finally:
        problem.Model.forward, problem.Model.B, tv_reconstruct.warm_start = saved
    rec.params["bench_spent"] = dict(_SPENT)
    return wall, rec


def _cpu_rows(case: dict, repeat: int, with_tv: bool) -> dict:
    """NER (and tv) on the CPU: the warm-up compiles numba's kernels (or loads their cache)."""
    from fpscan.service.recon import reconstruct_grid
    from fpscan.service.recon.tv import reconstruct_tv

    data = _ner_data(case)
    reconstruct_grid(data[:32, :16, :16], PITCH, DT, C, dtype=np.float32, device="cpu")
    reconstruct_grid(data, PITCH, DT, C, dtype=np.float32, device="cpu")
    out = {"ner": best_of(lambda: reconstruct_grid(data, PITCH, DT, C, dtype=np.float32, device="cpu"), repeat)}
    if with_tv:
        pos = case["positions"]
        reconstruct_tv(case["alines"][:40, :32], DT, C, positions=pos[:40], n_z=8, max_iter=2, dtype=np.float32,
                       device="cpu")
        wall, rec = _tv(case, "cpu")
        out.update(tv=wall, tv_params={k: rec.params[k] for k in ("lam", "iterations", "operator_pairs",
                                                                     "converged", "stop_reason", "bench_spent")},
                   tv_image=rec)
    return out


def _one_core(args: argparse.Namespace) -> dict:
    """The CPU rows at ``--one-core-scale`` in a child pinned to core 0, one numba/OpenMP thread
    (at most ``--one-core-timeout`` seconds)."""
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
               MKL_NUM_THREADS="1", FPSCAN_NO_GPU="1")
    cmd = [sys.executable, __file__, "--child", "--scale", str(args.one_core_scale), "--snr", str(args.snr),
           "--noise", args.noise, "--repeat", str(max(1, args.repeat // 2)), "--one-core", args.one_core]
    try:
        child = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=args.one_core_timeout,
                               preexec_fn=lambda: os.sched_setaffinity(0, {0}))
    except subprocess.TimeoutExpired:
        return {"error": f"the one-core child ran past {args.one_core_timeout:g} s"}
    if child.returncode != 0:
        return {"error": child.stderr[-2000:]}
    return json.loads(child.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--snr", type=float, default=30.0)
    parser.add_argument("--noise", choices=("rms", "peak"), default="rms")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--one-core", choices=("all", "ner", "none"), default="all")
    parser.add_argument("--one-core-scale", type=float, default=None,
                        help="the one-core rows' scale (default --scale); the all-core CPU rows run there too")
    parser.add_argument("--one-core-timeout", type=float, default=600.0)
    parser.add_argument("--json", default=None)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    case = paper_case(args.scale, args.snr, noise=args.noise)
    if args.child:
        rows = _cpu_rows(case, args.repeat, args.one_core == "all")
        rows.pop("tv_image", None)
        print(json.dumps(rows, default=float))
        return

    import cupy

    from fpscan.physics import ball_p0
    from fpscan.physics.fast_lengths import fast_lateral
    from fpscan.service.metrics import correlation_coefficient
    from fpscan.service.recon import device, gpu, reconstruct_grid, reconstruct_points

    gpus = device.cuda_devices()
    if not gpus:
        raise SystemExit("no CUDA GPU visible: bench_gpu needs one (and CuPy)")
    pool = cupy.get_default_memory_pool()
    peak = [0]

    def hook(size: int):
        mem = pool.malloc(size)
        peak[0] = max(peak[0], pool.used_bytes())
        return mem

    cupy.cuda.set_allocator(hook)
    sync = cupy.cuda.get_current_stream().synchronize
    r: dict = dict(card=gpus[0]["name"], cores=os.cpu_count(), commit=os.environ.get("FPSCAN_COMMIT", "?"),
                   scale=args.scale, n=case["n"], n_t=case["n_t"], points=len(case["positions"]))
    started = time.perf_counter()

    # NER on the GPU: host to host, and on the device
    data = _ner_data(case)
    ner_gpu = reconstruct_grid(data, PITCH, DT, C, dtype=np.float32, device="cuda")
    peak[0] = 0
    r["ner_gpu"] = best_of(lambda: reconstruct_grid(data, PITCH, DT, C, dtype=np.float32, device="cuda"), args.repeat)
    r["ner_gpu_peak"] = peak[0]
    n = case["n"]
    n_yp, n_xp = fast_lateral(n, n, square=True)
    p = ner_gpu.params
    d_data = cupy.asarray(data)

    def on_device():
        A = cupy.fft.rfft2(d_data, s=(n_yp, n_xp), axes=(1, 2))
        return gpu.invert(cupy, A, n_xp, PITCH, PITCH, DT, C, p["depth_rows"], p["dz"], 0.0, p["eps"], np.float32, 1,
                          (p["n_z"], n, n))

    on_device()
    r["ner_gpu_device"] = best_of(on_device, args.repeat, sync)
    # NEDNER of the scan's A-lines
    kw = dict(weights=case["weights"], grid=case["grid"], dtype=np.float32)
    nedner_gpu = reconstruct_points(case["alines"], case["positions"], DT, C, device="cuda", **kw)
    r["nedner_gpu"] = best_of(lambda: reconstruct_points(case["alines"], case["positions"], DT, C, device="cuda", **kw),
                            args.repeat)
    print(f"GPU NER and NEDNER done at {time.perf_counter() - started:.1f} s", flush=True)

    # the CPU, every core
    cpu = _cpu_rows(case, args.repeat, True)
    r["ner_cpu"] = cpu["ner"]
    ner_cpu = reconstruct_grid(data, PITCH, DT, C, dtype=np.float32, device="cpu")
    r["ner_rel_diff"] = float(np.abs(ner_gpu.p0 - ner_cpu.p0).max() / np.abs(ner_cpu.p0).max())
    del ner_cpu, ner_gpu
    t = time.perf_counter()
    nedner_cpu = reconstruct_points(case["alines"], case["positions"], DT, C, device="cpu", **kw)
    r["nedner_cpu"] = time.perf_counter() - t
    r["nedner_rel_diff"] = float(np.abs(nedner_gpu.p0 - nedner_cpu.p0).max() / np.abs(nedner_cpu.p0).max())
    del nedner_cpu, nedner_gpu
    r["tv_cpu"], r["tv_cpu_params"] = cpu["tv"], cpu["tv_params"]
    print(f"CPU rows done at {time.perf_counter() - started:.1f} s", flush=True)

    # tv on the GPU: its defaults to the rule (set-up included), then at the CPU's λ and iterations
    _tv(dict(case, alines=case["alines"][:40, :32], positions=case["positions"][:40], weights=None,
             grid=None), "cuda", n_z=8, max_iter=2)
    peak[0] = 0
    r["tv_gpu"], rec = _tv(case, "cuda")
    r["tv_gpu_peak"] = peak[0]
    r["tv_gpu_params"] = {k: rec.params[k] for k in ("lam", "iterations", "operator_pairs", "converged",
                                                      "stop_reason", "device", "bench_spent", "shape")
                          if k in rec.params}
    r["tv_gpu_params"]["image"] = list(rec.p0.shape)
    truth = ball_p0(case["balls"], rec.z, rec.x, rec.y, supersample=2)
    r["tv_gpu_cc_balls"] = correlation_coefficient(rec.p0, truth)
    # the GPU at the CPU's λ (the rest the defaults: the same rule, the same continuation), against the CPU's image
    cp_, cpu_rec = r["tv_cpu_params"], cpu["tv_image"]
    _, same = _tv(case, "cuda", lam=cp_["lam"])
    r["tv_same_iterations"] = same.params["iterations"]
    r["tv_cc_gpu_cpu"] = correlation_coefficient(same.p0, cpu_rec.p0)
    r["tv_cpu_cc_balls"] = correlation_coefficient(cpu_rec.p0, truth)
    r["tv_rel_diff"] = float(np.linalg.norm(same.p0 - cpu_rec.p0) / np.linalg.norm(cpu_rec.p0))
    del cpu["tv_image"], cpu_rec, same
    print(f"tv rows done at {time.perf_counter() - started:.1f} s", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=1, default=float))

    if args.one_core != "none":
        if args.one_core_scale is None or args.one_core_scale == args.scale:
            args.one_core_scale = args.scale
            r["all_core"] = {"ner": r["ner_cpu"], "tv": r["tv_cpu"]}
        else:  # the CPU's scaling at another size: every core there too
            rows = _cpu_rows(paper_case(args.one_core_scale, args.snr, noise=args.noise), args.repeat,
                             args.one_core == "all")
            r["all_core"] = {"ner": rows["ner"], "tv": rows.get("tv")}
        r["one_core_scale"] = args.one_core_scale
        r["one_core"] = _one_core(args)
    r["wall"] = time.perf_counter() - started
    _print(r)
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=1, default=float))


def _print(r: dict) -> None:
    one = r.get("one_core", {})
    gp, cp_ = r["tv_gpu_params"], r["tv_cpu_params"]
    print(f"\nbench_gpu: the paper's scan x{r['scale']:g} ({r['n']}² lattice, {r['n_t']} samples, {r['points']} "
          f"points), float32; GPU {r['card']}, CPU {r['cores']} cores; commit {r['commit']}; {r['wall']:.0f} s")
    print("| step | GPU | CPU, all cores | CPU, 1 core | CPU all / GPU | CPU 1 / all |")
    print("|---|---|---|---|---|---|")

    def row(name: str, g: float | None, c: float | None, c1: float | None) -> None:
        f = (lambda v: "–" if v is None else (f"{v * 1e3:.1f} ms" if v < 1 else f"{v:.2f} s"))
        ratio = (lambda a, b: "–" if a is None or b is None else f"{a / b:.1f}×")
        print(f"| {name} | {f(g)} | {f(c)} | {f(c1)} | {ratio(c, g)} | {ratio(c1, c)} |")

    same = r.get("one_core_scale", r["scale"]) == r["scale"]
    row("NER f32, warm, host to host", r["ner_gpu"], r["ner_cpu"], one.get("ner") if same else None)
    row("NER f32, warm, data on the GPU", r["ner_gpu_device"], None, None)
    row("NEDNER f32 (lateral step on the host)", r["nedner_gpu"], r["nedner_cpu"], None)
    row("tv to its rule, set-up included", r["tv_gpu"], r["tv_cpu"], one.get("tv") if same else None)
    print(f"\nGPU vs CPU: NER max |Δ| / max = {r['ner_rel_diff']:.2e}; NEDNER {r['nedner_rel_diff']:.2e}; "
          f"tv at the CPU's λ: {r['tv_same_iterations']} iterations (CPU {cp_['iterations']}), "
          f"CC {r['tv_cc_gpu_cpu']:.6f}, "
          f"‖Δ‖/‖x‖ {r['tv_rel_diff']:.2e}")
    print(f"tv GPU: {gp['iterations']} iterations, {gp['operator_pairs']:.1f} pairs, {gp['stop_reason']} "
          f"(converged {gp['converged']}), CC with the balls {r['tv_gpu_cc_balls']:.4f}; "
          f"tv CPU: {cp_['iterations']} iterations, {cp_['operator_pairs']:.1f} pairs, {cp_['stop_reason']}, "
          f"CC {r['tv_cpu_cc_balls']:.4f}")
    gs, cs = gp.get("bench_spent", {}), cp_.get("bench_spent", {})
    print(f"tv's time: GPU {r['tv_gpu']:.2f} s = warm start {gs.get('warm start', 0):.2f} s + operator pairs "
          f"{gs.get('operator', 0):.2f} s + the rest (set-up, solver steps, proximal map) "
          f"{r['tv_gpu'] - gs.get('warm start', 0) - gs.get('operator', 0):.2f} s; CPU {r['tv_cpu']:.2f} s = "
          f"{cs.get('warm start', 0):.2f} + {cs.get('operator', 0):.2f} + "
          f"{r['tv_cpu'] - cs.get('warm start', 0) - cs.get('operator', 0):.2f} s; image {gp.get('image')}")
    print(f"GPU peak memory: NER {r['ner_gpu_peak'] / 2**30:.2f} GiB, tv {r['tv_gpu_peak'] / 2**30:.2f} GiB")
    if one and not same and "error" not in one:
        a = r["all_core"]
        print(f"CPU scaling at x{r['one_core_scale']:g}: NER {a['ner'] * 1e3:.1f} ms on {r['cores']} cores, "
              f"{one['ner'] * 1e3:.1f} ms on 1 ({one['ner'] / a['ner']:.1f}×)" + (
                  f"; tv {a['tv']:.2f} s on {r['cores']} cores, {one['tv']:.2f} s on 1 ({one['tv'] / a['tv']:.1f}×)"
                  if a.get("tv") and one.get("tv") else ""))
    if "error" in one:
        print("one-core child failed:", one["error"])


if __name__ == "__main__":
    main()
