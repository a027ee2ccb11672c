"""A ``.npy`` array's axes are declared or shown by its shape, never guessed silently: k-Wave's
time-last orders ((x, t): sensor_data's sensor, time; (y, x, t) reshaped) are refused undeclared,
naming both readings and the option that says which, and read right with ``axes`` — by the
library (``fpscan.load_dataset``) and by ``fpscan recon`` (exit 2 with the reason; ``--axes``).
Files written with numpy; the data are k-Wave-like A-lines of a ball (``fpscan.ball_alines``)."""
from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pytest

import fpscan
from fpscan.service.formats.load_options import check_load_options
from fpscan.service.formats.npy import time_axes
from tests.waits import HANG_S

N_Y, N_X, N_T, DT, DX = 10, 12, 48, 8e-9, 60e-6
#: the default depth rows (fpscan.service.recon.depth): the pitch down to c·t_last = 0.56 mm at 1500 m/s
N_Z = int(1500.0 * (N_T - 1) * DT / DX) + 1


def _tyx() -> np.ndarray:
    """A-lines of a ball under a (N_Y, N_X) sensor grid, fpscan's order (n_t, n_y, n_x)."""
    y, x = np.meshgrid((np.arange(N_Y) - (N_Y - 1) / 2) * DX, (np.arange(N_X) - (N_X - 1) / 2) * DX, indexing="ij")
    pos = np.stack([x.ravel(), y.ravel()], axis=1)
    alines = fpscan.ball_alines(pos, [fpscan.Ball(x=0.0, y=0.0, z=0.2e-3, radius=1e-4, amplitude=1.0)], DT, N_T,
                                1500.0)
    return alines.T.reshape(N_T, N_Y, N_X).astype(np.float32)


@pytest.fixture
def files(tmp_path):
    """k-Wave's time-last orders and fpscan's time-first one, of the same A-lines."""
    tyx = _tyx()
    out = {"tyx": tmp_path / "kw_tyx.npy", "yxt": tmp_path / "kw_yxt.npy", "tx": tmp_path / "kw_tx.npy",
           "xt": tmp_path / "kw_xt.npy"}
    np.save(out["tyx"], tyx)
    np.save(out["yxt"], tyx.transpose(1, 2, 0))       # (y, x, t)
    np.save(out["tx"], tyx[:, N_Y // 2, :])             # (t, x)
    np.save(out["xt"], tyx[:, N_Y // 2, :].T.copy())    # (x, t): k-Wave's sensor_data (sensor, time)
    return out


@pytest.mark.parametrize("name, layouts", [("yxt", ("(y, x, t)", "(t, y, x)", 'axes="y,x,t"')),
                                           ("xt", ("(x, t)", "(t, x)", "sensor, time", 'axes="x,t"'))])
def test_time_last_undeclared_is_refused_naming_the_layouts(files, name, layouts):
    with pytest.raises(ValueError, match="which axis") as err:
        fpscan.load_dataset(files[name], dt=DT, dx=DX)
    for words in layouts:
        assert words in str(err.value), (words, str(err.value))


def test_declared_axes_read_time_first(files):
    want = fpscan.load_dataset(files["tyx"], dt=DT, dx=DX)
    assert want.data.shape == (N_T, N_Y, N_X)
    for axes in ("y,x,t", " Y, X, T "):
        got = fpscan.load_dataset(files["yxt"], dt=DT, dx=DX, axes=axes)
        assert got.data.shape == (N_T, N_Y, N_X) and got.data.flags.c_contiguous
        np.testing.assert_array_equal(got.data, want.data)
    line = fpscan.load_dataset(files["tx"], dt=DT, dx=DX).data
    for axes in ("x,t", "sensor,time"):
        np.testing.assert_array_equal(fpscan.load_dataset(files["xt"], dt=DT, dx=DX, axes=axes).data, line)
    # declared time first is read as it is, and a time-first file needs no declaration
    np.testing.assert_array_equal(fpscan.load_dataset(files["tyx"], dt=DT, dx=DX, axes="t,y,x").data, want.data)


def test_axes_that_do_not_fit_are_refused(files):
    with pytest.raises(ValueError, match="names 3 axes, the array has 2"):
        fpscan.load_dataset(files["xt"], dt=DT, dx=DX, axes="y,x,t")
    for bad in ("t,y", "x,x,t", "sensor,y,t", "depth,t"):
        with pytest.raises(ValueError, match="axes must name"):
            fpscan.load_dataset(files["xt"], dt=DT, dx=DX, axes=bad)
    # a format that knows its layout takes no axes
    with pytest.raises(ValueError, match="takes no option axes"):
        check_load_options("kwave-hdf5", {"axes": "y,x,t"})


def test_the_rule_on_known_shapes():
    """Time first is the first axis when it is the longest (k-Wave's shared examples as
    fpscan saves them: (751, 96, 96), (3519, 1024)) silently; a tie of the first and last axis
    or a longer middle axis is read time first with a warning; a longer last axis is refused."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert time_axes((751, 96, 96)) == (0, 1, 2) and time_axes((3519, 1024)) == (0, 1)
        assert time_axes((96, 96, 751), "y,x,t") == (2, 0, 1) and time_axes((96, 751), "sensor,time") == (1, 0)
        assert time_axes((96, 751, 96), "y,t,x") == (1, 0, 2)
    for shape in ((64, 64), (96, 96, 96), (64, 128, 32)):
        with pytest.warns(UserWarning, match="read time first"):
            assert time_axes(shape) == tuple(range(len(shape)))
    for shape in ((96, 96, 751), (128, 534), (96, 751, 751)):
        with pytest.raises(ValueError, match="which axis"):
            time_axes(shape)


def _recon(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fpscan", "recon", *args], capture_output=True, text=True,
                          timeout=HANG_S)


@pytest.mark.parametrize("name, axes, shape", [("yxt", "y,x,t", f"{N_Z}x{N_Y}x{N_X}"),
                                               ("xt", "x,t", f"{N_Z}x{N_X}")])
def test_cli_refuses_undeclared_and_reads_declared(files, tmp_path, name, axes, shape):
    res = _recon(str(files[name]), "--dt", "8ns", "--dx", "60um", "--out", str(tmp_path / "refused"))
    assert res.returncode == 2, res.stderr
    assert "which axis" in res.stderr and f"--axes {axes}" in res.stderr, res.stderr
    assert not (tmp_path / "refused").exists()
    res = _recon(str(files[name]), "--dt", "8ns", "--dx", "60um", "--axes", axes, "--out", str(tmp_path / "o"))
    assert res.returncode == 0, res.stderr
    assert f"p0 {shape} " in res.stdout, res.stdout
