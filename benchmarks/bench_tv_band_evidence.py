"""What the coherent image shows above the band tv works at: the depth power
spectrum of the full-band NEDNER image of a sparse scan against that of the same sensors' noise image.

tv works at c / (2 pitch), the band the lateral sampling resolves (`fpscan.service.recon.tv.grid`), unless
the scan declares its sensor band. Whether the data hold more than that is a question for the
coherent image, not for one A-line (its SNR is far below the image's): here NEDNER float32 of the
scan's A-lines on a depth grid of c dt (the record's own band) down to its last echo
(`fpscan.service.recon.tv.grid.data_extent`), and of a seeded white-noise record of the estimated σ̂ at the
same sensors, weights and grid; the power of each image's depth spectrum (FFT along z, summed over
the lateral positions) in 1 MHz bins of temporal frequency f = c k_z / 2π. The ratio image / noise
image is 1 where a bin holds noise alone and 2 where the signal's power equals the noise's (Wiener's
gain 1/2). Printed per row: the ratio at a few frequencies, and the upper edge of the highest bin
where it is at least 2 ("edge"; the record's Nyquist frequency: the signal stands above the noise
to the end).

Cases as `bench_tv_matrix.py` (``vessels``, ``balls``, ``points``, ``paper``: the paper's balls at
half size; masks of 4 % and 11 %, noise ``peak20`` … ``rms30``), and ``paper-full``: the paper's
scan at full size (`bench_tv_paper.paper_case`, its 1653-point mask; the mask argument is ignored).
A few seconds a row.

    .venv/bin/python benchmarks/bench_tv_band_evidence.py [--cases vessels balls points paper paper-full]
        [--masks 4 11] [--noise peak20 peak30 peak40 rms30]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

#: the frequencies (MHz) whose ratio is printed
SHOWN = (5, 10, 13, 20, 30, 44)


def scan(name: str, percent: int, noise: str) -> dict:
    """A case's sparse scan: ``alines`` (n, n_t), ``positions``, ``weights``, ``grid``, ``dt``,
    ``c`` and the lateral ``pitch`` (m)."""
    from fpscan.physics.axes import centred_axis

    if name == "paper-full":
        from bench_tv_paper import DT, PITCH, C, paper_case

        case = paper_case(1.0, float(noise[-2:]), noise=noise[:-2])
        return dict(alines=case["alines"], positions=case["positions"], weights=case["weights"],
                    grid=case["grid"], dt=DT, c=C, pitch=PITCH)
    from bench_tv_matrix import load_case, make_mask, noisy

    case = load_case(name)
    data = noisy(case["clean"], noise)
    mask = make_mask(case, percent)
    ix = np.asarray(mask.indices)
    two_d = data.ndim == 2
    shape, dx = data.shape[1:], case["dx"]
    alines = (data[:, ix[:, 0]] if two_d else data[:, ix[:, 1], ix[:, 0]]).T
    grid = (centred_axis(shape[-1], dx),) if two_d else (centred_axis(shape[1], dx), centred_axis(shape[0], dx))
    return dict(alines=alines, positions=np.asarray(mask.positions, float)[:, : 1 if two_d else 2],
                weights=np.asarray(mask.weights, float), grid=grid, dt=case["dt"], c=case["c"], pitch=dx)


def depth_power(image: np.ndarray) -> np.ndarray:
    """Σ over the lateral positions of |FFT_z(image)|², image (n_z, ...): (n_z // 2 + 1,)."""
    spectrum = np.fft.rfft(np.asarray(image, np.float64), axis=0)
    return (np.abs(spectrum) ** 2).reshape(spectrum.shape[0], -1).sum(axis=1)


def evidence(s: dict) -> dict:
    """The ratio of the image's to the noise image's depth power per 1 MHz bin (module doc):
    ``bins`` (MHz, lower edges), ``ratio``, ``edge`` (MHz) and the lateral band (MHz)."""
    from fpscan.service.recon import reconstruct_points
    from fpscan.service.recon.tv.grid import data_extent, noise_sigma

    alines, dt, c = s["alines"], s["dt"], s["c"]
    sigma = noise_sigma(alines, 1)
    n_z = data_extent(alines, 1, sigma) or alines.shape[1]
    kw = dict(weights=s["weights"], grid=s["grid"], dtype=np.float32, dz=c * dt, n_z=n_z)
    image = reconstruct_points(alines, s["positions"], dt, c, **kw).p0
    white = np.random.default_rng(12345).standard_normal(alines.shape) * sigma
    noise_image = reconstruct_points(white, s["positions"], dt, c, **kw).p0
    f = np.fft.rfftfreq(n_z, dt) / 1e6
    signal, noise = depth_power(image), depth_power(noise_image)
    bins = np.arange(0, int(f[-1]) + 1)
    ratio = np.array([signal[(f >= b) & (f < b + 1)].sum() / max(noise[(f >= b) & (f < b + 1)].sum(), 1e-300)
                      for b in bins])
    above = bins[ratio >= 2]
    edge = float(min(f[-1], above.max() + 1)) if above.size else 0.0
    return dict(bins=bins, ratio=ratio, edge=edge, lateral=c / (2 * s["pitch"]) / 1e6)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["vessels", "balls", "points", "paper", "paper-full"],
                    choices=["vessels", "balls", "points", "paper", "paper-full"])
    ap.add_argument("--masks", nargs="+", type=int, default=[4, 11])
    ap.add_argument("--noise", nargs="+", default=["peak20", "peak30", "peak40", "rms30"])
    args = ap.parse_args(argv)
    print("| case | mask | noise | lateral band | " + " | ".join(f"ratio at {f} MHz" for f in SHOWN)
          + " | edge (ratio >= 2) |")
    print("|" + "---|" * (5 + len(SHOWN)))
    for name in args.cases:
        for percent in ([0] if name == "paper-full" else args.masks):
            for noise in args.noise:
                e = evidence(scan(name, percent, noise))
                shown = [f"{e['ratio'][f]:.2f}" if f < len(e["ratio"]) else "-" for f in SHOWN]
                mask = "1653 points" if name == "paper-full" else f"{percent} %"
                print(f"| {name} | {mask} | {noise} | {e['lateral']:.1f} MHz | " + " | ".join(shown)
                      + f" | {e['edge']:.1f} MHz |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
