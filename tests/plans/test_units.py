"""Units a person can't get wrong: explicit units on the command line give the same plan
as SI numbers, and every implausible value (most likely a unit mistake) is refused with
exit code 2 and a message naming the unit that was probably meant -- in the CLI, the
library (ValueError) and, in tests/service/test_units_api.py, the HTTP API (422)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from clients.cli import main
from driver.units import ImplausibleValue, check_plausible, parse_quantity
from service.plans import make_plan

BASE = ["plan", "equisteradian", "--n-x", "40", "--n-points", "60"]


@pytest.mark.parametrize("flags, names", [
    (["--pitch", "60", "--depth", "2mm"], ["pitch 60 m", "60 µm", "60um"]),
    (["--depth", "3.6"], ["depth 3.6 m", "3.6 mm"]),
    (["--depth", "2mm", "--dt", "8"], ["dt 8 s", "8 ns"]),
    (["--depth", "2mm", "--prf", "500000"], ["PRF 500 kHz", "500 Hz", "n_t·dt"]),
    (["--depth", "2mm", "--sound-speed", "1.5"], ["1.5 m/s", "km/s"]),
    (["--depth", "2mm", "--dt", "8 furlongs"], ["not a time"]),
])
def test_cli_unit_mistakes_exit_2_naming_the_unit(tmp_path, capsys, flags, names):
    out = tmp_path / "plan.json"
    with pytest.raises(SystemExit) as stop:  # argparse's own usage errors exit 2 as well
        raise SystemExit(main(BASE + flags + ["--out", str(out)]))
    assert stop.value.code == 2
    err = capsys.readouterr().err
    for name in names:
        assert name in err, err
    assert not out.exists()


def test_unit_suffixes_give_the_same_plan_as_si_numbers(tmp_path, capsys):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert main(BASE + ["--pitch", "60um", "--depth", "3.6 mm", "--dt", "8ns", "--prf", "500 Hz",
                        "--sound-speed", "1.54 km/s", "--out", str(a)]) == 0
    assert main(BASE + ["--pitch", "6e-5", "--depth", "0.0036", "--dt", "8e-9", "--prf", "500",
                        "--sound-speed", "1540", "--out", str(b)]) == 0
    pa, pb = json.loads(a.read_text()), json.loads(b.read_text())
    assert pa["id"] == pb["id"]
    assert pa["lattice"]["pitch"] == 6e-5 and pa["acquisition"]["dt"] == 8e-9
    # an unusual medium is accepted when forced
    assert main(BASE + ["--depth", "2mm", "--sound-speed", "2500", "--force", "--out", str(a)]) == 0


def test_recon_dt_dx_unit_mistakes_and_suffixes(tmp_path, capsys):
    x = tmp_path / "x.npy"
    np.save(x, np.zeros((16, 4, 4), dtype=np.float32))
    for flags, names in ((["--dt", "20", "--dx", "100um"], ["dt 20 s", "20 ns"]),
                         (["--dt", "20ns", "--dx", "100"], ["dx 100 m", "100 µm"])):
        with pytest.raises(SystemExit) as stop:
            raise SystemExit(main(["recon", str(x), *flags, "-q", "--out", str(tmp_path / "r")]))
        assert stop.value.code == 2
        err = capsys.readouterr().err
        assert all(n in err for n in names), err
    assert not (tmp_path / "r").exists()


def test_library_rules():
    """The same rules as ValueError from the library (make_plan, check_plausible)."""
    lattice = {"n_x": 20, "n_y": 20, "pitch": 60.0}
    with pytest.raises(ValueError, match="60 µm"):
        make_plan(kind="full", lattice=lattice)
    with pytest.raises(ImplausibleValue, match="3.6 mm"):
        make_plan(kind="equisteradian", lattice={**lattice, "pitch": 6e-5},
                  params={"depth": 3.6, "n_points": 20})
    with pytest.raises(ImplausibleValue, match="shorter than one recording"):
        make_plan(kind="full", lattice={**lattice, "pitch": 6e-5}, prf=5e5)
    check_plausible(pitch=6e-5, dt=8e-9, n_t=1024, prf=500.0, sound_speed=1500.0, depth=3.6e-3)
    assert parse_quantity("60 µm", "length") == 6e-5 == parse_quantity("6e-5", "length")
    for bad in ("9**9**9", "1e999 m", "60 Hz", "", "m"):
        with pytest.raises(ValueError):
            parse_quantity(bad, "length")


def test_recon_sound_speed_rule_cli_and_library(tmp_path, capsys):
    """One speed-of-sound rule (driver.units.check_speeds): ``fpscan recon --c`` outside
    1000-2000 m/s exits 2 naming the likely unit unless ``--force``; the library's
    ``reconstruct(c=...)`` raises ValueError the same way unless ``force=True``."""
    from service.pipeline import reconstruct
    from service.storage.datasets import GridDataset

    x = tmp_path / "x.npy"
    np.save(x, np.zeros((16, 4, 4), dtype=np.float32))
    base = ["recon", str(x), "--dt", "20ns", "--dx", "100um", "--method", "ner", "-q"]
    for c, names in (("2500", ["sound speed 2500 m/s", "1000 to 2000", "force"]),
                     ("1.5", ["1.5 m/s", "1.5 km/s"])):
        with pytest.raises(SystemExit) as stop:
            raise SystemExit(main(base + ["--c", c, "--out", str(tmp_path / "r")]))
        assert stop.value.code == 2
        err = capsys.readouterr().err
        assert all(n in err for n in names), err
    assert not (tmp_path / "r").exists()
    assert main(base + ["--c", "2.5 km/s", "--force", "--out", str(tmp_path / "r")]) == 0
    assert (tmp_path / "r" / "volume.h5").is_file()

    ds = GridDataset(data=np.zeros((16, 4, 4), np.float32), dx=1e-4, dt=2e-8, c=1500.0, dy=1e-4)
    with pytest.raises(ValueError, match="c: sound speed 2500 m/s is implausible"):
        reconstruct(ds, "ner", c=2500.0)
    with pytest.raises(ImplausibleValue, match="did you mean 1.5 km/s"):
        reconstruct(ds, "ner", c=1.5)
    with pytest.raises(ImplausibleValue, match="c_range: sound speed 900 m/s"):
        reconstruct(ds, "ner", c="auto", c_range=[900.0, 1600.0])
    assert reconstruct(ds, "ner", c=2500.0, force=True).params["c"] == 2500.0
