"""Units a person can't get wrong: explicit units on the command line give the same plan
as SI numbers, and every implausible value (most likely a unit mistake) is refused with
exit code 2 and a message naming the unit that was probably meant -- in the CLI, the
library (ValueError) and, in tests/service/test_units_api.py, the HTTP API (422)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from fpscan.clients.cli import main
from fpscan.driver.units import ImplausibleValue, check_plausible, parse_quantity
from fpscan.service.plans import make_plan

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


@pytest.mark.parametrize("flags, names", [
    (["--pitch", "60mm", "--depth", "2mm"], ["pitch 0.06 m", "did you mean 60 µm (60um)"]),  # not "0.06 mm"
    (["--pitch", "0.06um", "--depth", "2mm"], ["did you mean 60 µm"]),  # too small: the unit 10³ too small
    (["--depth", "2mm", "--dt", "8ms"], ["did you mean 8 ns (8ns)"]),
])
def test_every_plausibility_error_suggests_the_likely_unit(tmp_path, capsys, flags, names):
    """The suggestion is the number typed, in the unit it most likely meant."""
    assert main(BASE + flags + ["--out", str(tmp_path / "p.json")]) == 2
    err = capsys.readouterr().err
    for name in names:
        assert name in err, err


def test_unmix_wavelengths_without_a_unit_suggest_nm(tmp_path, capsys):
    files = []
    for k in range(2):
        files.append(str(tmp_path / f"w{k}.npy"))
        np.save(files[-1], np.zeros((16, 4, 4), np.float32))
    assert main(["unmix", *files, "--wavelengths", "750", "850", "--dt", "2e-8", "--dx", "1e-4", "-q",
                 "--out", str(tmp_path / "u")]) == 2
    err = capsys.readouterr().err
    assert "750 m" in err and "did you mean 750 nm (750nm)" in err, err
    assert not (tmp_path / "u").exists()


@pytest.mark.parametrize("poi", [["--poi=-0.4mm,0.4mm"], ["--poi", "-0.4mm", "0.4mm"], ["--poi", "-0.4mm,0.4mm"],
                                 ["--poi", "-400um", "400 um"], ["--poi", "-4e-4", "4e-4"]])
def test_negative_points_of_interest_with_units(tmp_path, capsys, poi):
    """A point of interest left of / below the axis, typed with units, negative
    first or second, space- or comma-separated: the same plan as SI numbers."""
    out = tmp_path / "p.json"
    assert main(BASE + ["--pitch", "60um", "--depth", "2mm", *poi, "--out", str(out)]) == 0, capsys.readouterr().err
    assert json.loads(out.read_text())["mask"]["params"]["poi"] == pytest.approx([-4e-4, 4e-4])
    flipped = tmp_path / "q.json"
    assert main(BASE + ["--pitch", "60um", "--depth", "2mm", "--poi", "0.4mm", "-0.4mm", "--out", str(flipped)]) == 0
    assert json.loads(flipped.read_text())["mask"]["params"]["poi"] == pytest.approx([4e-4, -4e-4])


def test_a_depth_below_one_pitch_is_refused_and_a_shortfall_is_explained():
    """Depth 1e-300 m with 200 points asked gave a 1-point plan; now a depth
    below one pitch is refused naming why, and a plan with fewer points than asked says why
    (``Mask.shortfall``; the API's ``shortfall``, the CLI's note)."""
    lattice = {"n_x": 64, "n_y": 64, "pitch": 6e-5}
    for depth in (1e-300, 5.9e-5):
        with pytest.raises(ValueError, match="below one lattice pitch"):
            make_plan(kind="equisteradian", lattice=lattice, params={"depth": depth, "n_points": 200})
    from fpscan.service.plans import make_mask
    from fpscan.service.plans.lattice import Lattice

    short = make_mask("equisteradian", Lattice(64, 64, 6e-5), depth=6e-5, n_points=2000)
    assert short.obtained_points < 0.9 * 2000  # points closer than the pitch merge: said why
    assert short.shortfall.startswith(f"{short.obtained_points} of 2000 points asked: ")
    assert "closer than the lattice pitch" in short.shortfall
    plan = make_plan(kind="equisteradian", lattice=lattice, params={"depth": "3.6mm", "n_points": 200})
    assert plan.mask.params["depth"] == 3.6e-3 and abs(plan.mask.obtained_points - 200) <= 0.1 * 200
    assert make_mask("equisteradian", Lattice(64, 64, 6e-5), depth=3.6e-3, n_points=200).shortfall is None
    # a ring design whose last ring, taken whole, gives many more points than asked says so too
    over = make_mask("equisteradian", Lattice(64, 64, 1e-4), depth=5e-3, n_points=14)
    assert over.obtained_points * 0.9 > 14, over.obtained_points
    assert over.shortfall.startswith(f"{over.obtained_points} points for the 14 asked: "), over.shortfall
    line = make_plan(kind="equiangular", lattice={"n_x": 256, "n_y": 1, "pitch": "60um"},
                     params={"depth": "2 mm", "n_points": 32, "poi": "-1mm"})
    assert line.mask.params["poi"][0] == -1e-3 and line.mask.obtained_points >= 29


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
    """One speed-of-sound rule (fpscan.driver.units.check_speeds): ``fpscan recon --sound-speed``
    outside 1000-2000 m/s exits 2 naming the likely unit unless ``--force``; the library's
    ``reconstruct(sound_speed=...)`` raises ValueError the same way unless ``force=True``; the old
    flag ``--c`` still works and warns naming the new one."""
    from fpscan.service.pipeline import reconstruct
    from fpscan.service.recon.dataset import GridDataset

    x = tmp_path / "x.npy"
    np.save(x, np.zeros((16, 4, 4), dtype=np.float32))
    base = ["recon", str(x), "--dt", "20ns", "--dx", "100um", "--method", "ner", "-q"]
    for c, names in (("2500", ["sound speed 2500 m/s", "1000 to 2000", "force"]),
                     ("1.5", ["1.5 m/s", "1.5 km/s"])):
        with pytest.raises(SystemExit) as stop:
            raise SystemExit(main(base + ["--sound-speed", c, "--out", str(tmp_path / "r")]))
        assert stop.value.code == 2
        err = capsys.readouterr().err
        assert all(n in err for n in names), err
    assert not (tmp_path / "r").exists()
    assert main(base + ["--c", "2.5 km/s", "--force", "--out", str(tmp_path / "r")]) == 0
    assert (tmp_path / "r" / "volume.h5").is_file()
    assert "--c is deprecated: use --sound-speed" in capsys.readouterr().err

    ds = GridDataset(data=np.zeros((16, 4, 4), np.float32), dx=1e-4, dt=2e-8, sound_speed=1500.0, dy=1e-4)
    with pytest.raises(ValueError, match="sound_speed: sound speed 2500 m/s is implausible"):
        reconstruct(ds, "ner", sound_speed=2500.0)
    with pytest.raises(ImplausibleValue, match="did you mean 1.5 km/s"):
        reconstruct(ds, "ner", sound_speed=1.5)
    with pytest.raises(ImplausibleValue, match="sound_speed_range: sound speed 900 m/s"):
        reconstruct(ds, "ner", sound_speed="auto", sound_speed_range=[900.0, 1600.0])
    assert reconstruct(ds, "ner", sound_speed=2500.0, force=True).params["sound_speed"] == 2500.0
    with pytest.warns(DeprecationWarning, match="option c is deprecated: use sound_speed"):
        assert reconstruct(ds, "ner", c=1480.0).params["sound_speed"] == 1480.0


def test_sim_demo_unmix_take_units_and_name_unit_mistakes(tmp_path, capsys):
    """``fpscan sim``, ``demo`` and ``unmix`` read lengths, times, frequencies and speeds as
    ``plan``/``recon`` do (the suffix form is the SI number) and refuse a unit mistake
    with exit 2 naming the unit, before anything starts (a bad --source / --lattice after
    the check would exit 1, a missed check would start the simulator or the demo)."""
    from fpscan.clients.cli import build_parser

    parse = build_parser().parse_args
    sim = parse(["sim", "--prf", "500Hz", "--bandwidth", "20 MHz", "--tuning-delay", "2ms",
                 "--laser-tuning-delay", "50 ms", "--sound-speed", "1.54km/s"])
    assert (sim.prf, sim.bandwidth, sim.tuning_delay, sim.laser_tuning_delay, sim.sound_speed) == \
        (500.0, 2e7, 2e-3, 5e-2, 1540.0)
    assert parse(["sim", "--prf", "500"]).prf == 500.0
    demo = parse(["demo", "--pitch", "100um", "--dt", "12ns", "--poi-depth", "3mm"])
    assert (demo.pitch, demo.dt, demo.poi_depth) == (1e-4, 1.2e-8, 3e-3)
    unmix = parse(["unmix", "--wavelengths", "750nm", "850 nm", "--dt", "20ns", "--dx", "100um",
                   "--sound-speed-range", "1.45km/s", "1600"])
    assert unmix.wavelengths == [7.5e-7, 8.5e-7] and (unmix.dt, unmix.dx) == (2e-8, 1e-4)
    assert unmix.sound_speed_range == [1450.0, 1600.0]
    assert parse(["recon", "--c-range", "1.45 km/s", "1.6km/s"]).sound_speed_range == [1450.0, 1600.0]

    def exit_code(argv):
        with pytest.raises(SystemExit) as stop:
            raise SystemExit(main(argv))
        return stop.value.code, capsys.readouterr().err

    for argv, names in (
        (["sim", "--source", "nope", "--sound-speed", "1.5"], ["1.5 m/s", "km/s"]),
        (["sim", "--prf", "500 furlongs"], ["not a frequency"]),
        (["demo", "--lattice", "4", "--pitch", "100", "--out", str(tmp_path / "d")], ["pitch 100 m", "100 µm"]),
        (["demo", "--lattice", "4", "--dt", "12", "--out", str(tmp_path / "d")], ["dt 12 s", "12 ns"]),
        (["demo", "--lattice", "4", "--poi-depth", "3", "--out", str(tmp_path / "d")], ["depth 3 m", "3 mm"]),
    ):
        code, err = exit_code(argv)
        assert code == 2 and all(n in err for n in names), (argv, err)
    assert not (tmp_path / "d").exists()
    code, err = exit_code(["sim", "--source", "nope", "--sound-speed", "2500", "--force"])
    assert code == 2 and "unknown source" in err and "sound speed" not in err, err  # forced: on to the source

    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    for p in (a, b):
        np.save(p, np.zeros((16, 4, 4), dtype=np.float32))
    base = ["unmix", str(a), str(b), "--wavelengths", "750nm", "850nm", "-q", "--out", str(tmp_path / "u")]
    for flags, names in ((["--dt", "20", "--dx", "100um"], ["dt 20 s", "20 ns"]),
                         (["--dt", "20ns", "--dx", "100"], ["dx 100 m", "100 µm"]),
                         (["--dt", "20ns", "--dx", "100um", "--sound-speed", "2500"], ["sound speed 2500 m/s", "force"])):
        code, err = exit_code(base + flags)
        assert code == 2 and all(n in err for n in names), (flags, err)
    assert not (tmp_path / "u").exists()


def test_parsed_values_are_pints_conversion_to_the_last_bit():
    """parse_quantity looks each unit's factor up once (cached): the value is still exactly pint's
    own conversion of the typed number (its registry with decimal arithmetic), for units of every
    kind, many magnitudes and both spellings of micro; a unit of another kind or none pint knows
    is refused with the same words whether or not its factor was looked up before."""
    import random
    from decimal import Decimal

    import pint

    ureg = pint.UnitRegistry(non_int_type=Decimal)  # an independent registry: the oracle
    units = {"length": ["m", "mm", "um", "µm", "μm", "nm", "km", "inch", "micron", "angstrom", "Ym"],
             "time": ["s", "ns", "us", "ms", "min", "h", "ps"], "frequency": ["Hz", "kHz", "MHz", "rpm"],
             "speed": ["m/s", "km/s", "mm/us", "ft/s", "knot"]}
    si = {"length": "m", "time": "s", "frequency": "Hz", "speed": "m/s"}
    rng = random.Random(7)
    for kind, names in units.items():
        for unit in names:
            for _ in range(50):
                number = rng.choice([f"{rng.uniform(-1e4, 1e4):.{rng.randint(1, 12)}g}", str(rng.randint(0, 10**6)),
                                     f"{rng.uniform(0, 10):.6f}e{rng.randint(-30, 29)}"])
                want = float((Decimal(number) * ureg.Unit(unit.replace("μ", "µ"))).to(si[kind]).magnitude)
                assert parse_quantity(f"{number} {unit}", kind) == want, (number, unit)
    for _ in range(2):  # the second time from the cache
        with pytest.raises(ValueError, match="'60 Hz' is not a length"):
            parse_quantity("60 Hz", "length", name="pitch")
        with pytest.raises(ValueError, match="unknown unit 'zorkmid'"):
            parse_quantity("60 zorkmid", "length")
