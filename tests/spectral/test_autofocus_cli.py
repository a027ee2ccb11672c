"""`fpscan recon --c auto` (local, the one dispatch): the chosen c, the sharpness curve
and the search time land in the result file's params; a bad or unused ``--c-range`` is
refused with the reason before anything is reconstructed."""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.clients.cli import main as fpscan_main
from fpscan.physics import Ball, ball_alines
from fpscan.service.storage.results import read_result

N, DX, DT, NT, C_TRUE = 32, 80e-6, 16e-9, 192, 1480.0


@pytest.fixture(scope="module")
def npy(tmp_path_factory):
    x = (np.arange(N) - (N - 1) / 2) * DX
    yy, xx = np.meshgrid(x, x, indexing="ij")
    pos = np.stack([xx.ravel(), yy.ravel()], axis=1)
    balls = [Ball(0.0, 0.0, 1.2e-3, 120e-6), Ball(0.5e-3, -0.4e-3, 1.7e-3, 150e-6, 0.7),
             Ball(-0.6e-3, 0.5e-3, 1.5e-3, 100e-6)]
    data = ball_alines(pos, balls, DT, NT, C_TRUE).T.reshape(NT, N, N).astype(np.float32)
    path = tmp_path_factory.mktemp("af") / "balls.npy"
    np.save(path, data)
    return path


def test_recon_c_auto_records_the_search(npy, tmp_path, capsys):
    out = tmp_path / "r"
    rc = fpscan_main(["recon", str(npy), "--dt", str(DT), "--dx", str(DX), "--method", "ner", "--c", "auto",
                      "--out", str(out), "-q"])
    printed = capsys.readouterr()
    assert rc == 0, printed.err
    res = read_result(out / "volume.h5")
    af = res.params["autofocus"]  # the file names the speed of sound as a person reads it
    assert res.params["sound_speed"] == af["sound_speed"] and af["sound_speed_range"] == [1450.0, 1600.0]
    values = af["sound_speed_values"]
    assert len(values) == len(af["sharpness"]) == af["evaluations"] >= 7
    assert values == sorted(values) and af["sound_speed"] in values
    assert af["sharpness"][values.index(af["sound_speed"])] == max(af["sharpness"])
    assert af["time_s"] > 0 and af["decimation"] >= 1
    c = af["sound_speed"]
    assert abs(c - C_TRUE) / C_TRUE < 0.01, af  # plumbing; accuracy: test_autofocus.py
    assert f"sound speed {c:.1f} m/s (autofocus" in printed.out
    # the final volume is on the chosen c's default depth grid: rows of the pitch down to c·t_last
    assert res.z[1] - res.z[0] == pytest.approx(DX, rel=1e-9)
    assert len(res.z) == int(c * (NT - 1) * DT / DX) + 1


@pytest.mark.parametrize("extra, reason", [
    (["--sound-speed", "auto", "--sound-speed-range", "1600", "1450"], "sound_speed_range must satisfy"),
    (["--sound-speed-range", "1450", "1600"], "needs sound_speed='auto'"),
    (["--c", "1500", "--c-range", "1450", "1600"], "needs sound_speed='auto'"),  # the old flags: the same rule
    (["--c", "fast"], "argument --sound-speed/--c: "),  # --c: the deprecated name of --sound-speed
])
def test_bad_c_options_are_refused(npy, tmp_path, capsys, extra, reason):
    out = tmp_path / "r"
    argv = ["recon", str(npy), "--dt", str(DT), "--dx", str(DX), "--method", "ner", *extra, "--out", str(out), "-q"]
    try:
        rc = fpscan_main(argv)
    except SystemExit as exc:  # argparse: usage error
        rc = exc.code
    err = capsys.readouterr().err
    assert rc in (1, 2) and reason in err, err
    assert not out.exists()
