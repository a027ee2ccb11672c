"""`fpscan demo`: the end-to-end demonstration (the README's first command)."""
from __future__ import annotations

COMMAND = "demo"
HELP = "run the end-to-end demo: simulated scanner, equi-steradian plan, scan, NEDNER reconstruction"


def add_arguments(parser):
    parser.add_argument("--out", default="demo-output", help="output folder (default: demo-output)")


def run(args) -> int:
    from pathlib import Path

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"fpscan demo: outputs in {out}/ (the full pipeline lands with the service)")
    return 0
