"""`fpscan plan <mask> [options] --out plan.json [--preview mask.png]`: make a scan plan.

Prints the point count (obtained of requested), the outer/inner weight ratio and the
expected scan time. The plan JSON is the fixed "Plan JSON" of docs/architecture.md.
"""
from __future__ import annotations

COMMAND = "plan"
HELP = "make a scan plan (sensor mask + weights + order + acquisition settings) as plan JSON"

_KINDS = ("full", "subgrid", "equispaced", "hexagonal", "random", "poisson", "points",
          "equiangular", "equisteradian")


def add_arguments(parser):
    """Declare this sub-command's options on ``parser`` (an ``argparse`` sub-parser)."""
    parser.add_argument("mask", choices=_KINDS, help="mask kind")
    g = parser.add_argument_group("lattice")
    g.add_argument("--n-x", type=int, default=226, help="lattice points along x (default 226)")
    g.add_argument("--n-y", type=int, default=None,
                   help="lattice points along y (default: n_x; 1 for equiangular)")
    g.add_argument("--pitch", type=float, default=60e-6, help="lattice pitch in m (default 6e-05)")
    g = parser.add_argument_group("mask parameters (SI units)")
    g.add_argument("--depth", type=float, help="equiangular/equisteradian: point of interest depth in m")
    g.add_argument("--n-points", type=int, help="requested number of points (equi*, random, poisson cap)")
    g.add_argument("--poi", type=float, nargs="+", metavar="M",
                   help="point of interest x [y] in m (default: lattice centre)")
    g.add_argument("--interval", type=int, help="subgrid: interval in lattice points")
    g.add_argument("--per-side", type=int, nargs="+", metavar="N", help="subgrid: points per side (n or n_x n_y)")
    g.add_argument("--spacing", type=float, help="hexagonal: neighbour distance in m")
    g.add_argument("--min-distance", type=float, help="poisson: minimum distance in m")
    g.add_argument("--seed", type=int, help="random/poisson: seed (default 0)")
    g.add_argument("--points", metavar="FILE",
                   help="points: JSON file with [[x, y], ...] in m (or {\"indices\": [[ix, iy], ...]})")
    g = parser.add_argument_group("plan")
    g.add_argument("--order", default="auto", choices=("auto", "serpentine", "rings", "nearest"),
                   help="scan order (default auto: rings for equisteradian, serpentine otherwise)")
    g.add_argument("--n-t", type=int, default=1024, help="samples per A-line (default 1024)")
    g.add_argument("--dt", type=float, default=8e-9, help="sample interval in s (default 8e-09)")
    g.add_argument("--averages", type=int, default=1, help="pulses averaged per point (default 1)")
    g.add_argument("--wavelength", type=float, action="append", metavar="M",
                   help="excitation wavelength in m; repeat for several (default 7.5e-07)")
    g.add_argument("--wavelength-order", choices=["per_point", "per_pass"], default=None,
                   help="with several wavelengths: tune the laser at every point (per_point, the "
                        "default: wavelengths register) or once per full pass (per_pass: fewer "
                        "tunings, motion between passes); docs/protocol.md §4.1")
    g.add_argument("--prf", type=float, default=50.0, help="laser pulse repetition frequency in Hz (default 50)")
    g.add_argument("--sound-speed", type=float, default=1500.0, help="speed of sound in m/s (default 1500)")
    parser.add_argument("--out", required=True, help="where to write the plan JSON")
    parser.add_argument("--preview", metavar="PNG", help="also write a preview PNG of the mask")


def _mask_params(args) -> dict:  # noqa: C901 -- flags derived from the kind models by helper "plans"
    import json
    from pathlib import Path

    kind = args.mask
    p: dict = {}
    if kind in ("equiangular", "equisteradian"):
        if args.depth is None or args.n_points is None:
            raise ValueError(f"{kind} needs --depth and --n-points")
        p.update(depth=args.depth, n_points=args.n_points)
        if args.poi is not None:
            p["poi"] = args.poi
    elif kind in ("subgrid", "equispaced"):
        if args.interval is None:
            raise ValueError(f"{kind} needs --interval")
        p["interval"] = args.interval
        if args.per_side is not None:
            p["n_per_side"] = args.per_side[0] if len(args.per_side) == 1 else args.per_side
    elif kind == "hexagonal":
        if args.spacing is None:
            raise ValueError("hexagonal needs --spacing")
        p["spacing"] = args.spacing
    elif kind == "random":
        if args.n_points is None:
            raise ValueError("random needs --n-points")
        p["n_points"] = args.n_points
        if args.seed is not None:
            p["seed"] = args.seed
    elif kind == "poisson":
        if args.min_distance is None:
            raise ValueError("poisson needs --min-distance")
        p["min_distance"] = args.min_distance
        if args.seed is not None:
            p["seed"] = args.seed
        if args.n_points is not None:
            p["n_points"] = args.n_points
    elif kind == "points":
        if args.points is None:
            raise ValueError("points needs --points FILE")
        try:
            data = json.loads(Path(args.points).read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise ValueError(f"{args.points} is not valid JSON: {exc}") from None
        if isinstance(data, dict) and "indices" in data:
            p["indices"] = data["indices"]
        elif isinstance(data, dict) and "points" in data:
            p["points"] = data["points"]
        else:
            p["points"] = data
    return p


def run(args) -> int:
    """Run this sub-command with the parsed ``args``; return the exit status."""
    from service.plans import Lattice, make_mask, make_plan, preview_png

    n_y = args.n_y if args.n_y is not None else (1 if args.mask == "equiangular" else args.n_x)
    lattice = Lattice(args.n_x, n_y, args.pitch)
    mask = make_mask(args.mask, lattice, **_mask_params(args))
    plan = make_plan(
        mask, order=args.order, n_t=args.n_t, dt=args.dt, averages=args.averages,
        wavelengths=args.wavelength or [7.5e-7], prf=args.prf, sound_speed=args.sound_speed,
        wavelength_order=args.wavelength_order,
    )
    plan.to_json(args.out)
    if args.preview:
        preview_png(plan, args.preview)
    print(f"plan {plan.id}: {plan.mask.kind} on {lattice.n_x}x{lattice.n_y} at {lattice.pitch:g} m")
    print(f"points: {plan.mask.obtained_points} (requested {plan.mask.requested_points})")
    print(f"weight ratio (outer/inner): {plan.mask.weight_ratio:.4g}")
    print(f"order: {plan.order}; expected scan time: {plan.expected_scan_time_s:.1f} s")
    print(f"wrote {args.out}" + (f" and {args.preview}" if args.preview else ""))
    return 0
