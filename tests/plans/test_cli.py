"""`fpscan plan`: the CLI writes a valid plan JSON and a preview, and reports bad input."""
from __future__ import annotations

import hashlib
import json

import pytest

from fpscan.clients.cli import main
from fpscan.service.plans import Plan


def test_plan_equisteradian_in_process(tmp_path, capsys):
    out, png = tmp_path / "plan.json", tmp_path / "mask.png"
    rc = main([
        "plan", "equisteradian", "--n-x", "80", "--pitch", "6e-5", "--depth", "2e-3",
        "--n-points", "400", "--prf", "25", "--out", str(out), "--preview", str(png),
    ])
    assert rc == 0
    text = capsys.readouterr().out
    d = json.loads(out.read_text())
    body = {k: v for k, v in d.items() if k != "id"}
    assert d["id"] == hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()
    plan = Plan.from_json(out)
    assert plan.lattice.n_x == plan.lattice.n_y == 80
    assert f"points: {plan.mask.obtained_points} (requested 400)" in text
    assert f"{plan.mask.weight_ratio:.4g}" in text
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert plan.expected_scan_time_s == pytest.approx(plan.n_points / 25)


def test_plan_line_and_points(tmp_path, capsys):
    out = tmp_path / "line.json"
    rc = main(["plan", "equiangular", "--n-x", "1024", "--depth", "7.68e-3", "--n-points", "32", "--out", str(out)])
    assert rc == 0
    stdout = capsys.readouterr().out
    plan = Plan.from_json(out)
    assert plan.lattice.n_y == 1 and plan.n_points == 32
    assert "weight ratio" in stdout and "points: 32 (requested 32)" in stdout

    pts = tmp_path / "pts.json"
    pts.write_text(json.dumps([[0.0, 0.0], [1e-4, 2e-4], [1.01e-4, 1.98e-4]]))
    out2 = tmp_path / "pts_plan.json"
    assert main(["plan", "points", "--n-x", "20", "--points", str(pts), "--out", str(out2)]) == 0
    p2 = Plan.from_json(out2)
    assert p2.mask.requested_points == 3 and p2.mask.obtained_points == 2  # snapped duplicate dropped


@pytest.mark.parametrize(
    "args, match, code",
    [  # refused input -- implausible values (fpscan.driver.units), missing flags, values out of range -- is a usage
       # error: exit 2, as argparse's own (it was 1 or 2)
        (["equisteradian", "--depth=-1e-3", "--n-points", "10"], "depth", 2),
        (["equisteradian", "--depth", "1e-3"], "--n-points", 2),
        (["equisteradian", "--depth", "1e-3", "--n-points", "10", "--poi", "1", "0"], "outside the lattice", 2),
        (["subgrid", "--interval", "4", "--pitch", "0"], "pitch", 2),
        (["random", "--n-x", "10", "--n-points", "101"], "more than the lattice holds", 2),
    ],
)
def test_plan_bad_input_exit_2_with_reason(tmp_path, capsys, args, match, code):
    out = tmp_path / "p.json"
    rc = main(["plan", *args, "--out", str(out)])
    assert rc == code
    assert match in capsys.readouterr().err
    assert not out.exists()
