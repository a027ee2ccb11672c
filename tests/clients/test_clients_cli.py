"""The `fpscan` command line driven as a user would: subprocesses, a real server, real
files. Oracles: k-Wave's own p0 for the reconstruction (shared data), the local
reconstruction for the remote one, the server's JSON for `jobs`."""
from __future__ import annotations

import json
import subprocess
import sys

import h5py
import numpy as np
import pytest

from tests.clients.clients_servers import clean_env, free_port
from tests.waits import HANG_S

pytestmark = pytest.mark.long(65)

TOKEN = "cli-test-token"


def fpscan(*args, env=None, timeout=HANG_S, cwd=None):
    return subprocess.run([sys.executable, "-m", "fpscan", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=env or clean_env(), cwd=cwd)


def _mine():
    return ["jobs", "recon", "export", "demo"]


@pytest.mark.parametrize("command", [None, *_mine()])
def test_help_everywhere(command):
    res = fpscan(*([command] if command else []), "--help")
    assert res.returncode == 0, res.stderr
    assert "usage: fpscan" in res.stdout


def test_every_reconstructing_command_states_its_precision():
    """``--help`` of each command that reconstructs says in which precision: the one default
    (``fpscan.service.pipeline.DEFAULT_DTYPE``) for recon, unmix, demo and serve; float64 for evaluate."""
    import argparse

    from fpscan.clients.cli import build_parser
    from fpscan.service.pipeline import DEFAULT_DTYPE

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    text = {name: " ".join(sub[name].format_help().split())
            for name in ("recon", "unmix", "demo", "serve", "evaluate")}
    for name in ("recon", "unmix"):
        assert f"(default {DEFAULT_DTYPE}, locally and on the server)" in text[name], name
    for name in ("demo", "serve"):
        assert f"Precision: reconstructions are {DEFAULT_DTYPE}" in text[name]
    assert "every reconstruction of the experiments is float64" in text["evaluate"]
    assert f"default to {DEFAULT_DTYPE}" in text["evaluate"]


@pytest.mark.parametrize("action", ["list", "get", "wait", "cancel"])
def test_jobs_subcommand_help(action):
    res = fpscan("jobs", action, "--help")
    assert res.returncode == 0 and "--server" in res.stdout


def _one_line_error(res, *needles, code=1):
    assert res.returncode == code, (res.returncode, res.stdout, res.stderr)
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]


def test_server_down_is_one_line_exit_1():
    url = f"http://127.0.0.1:{free_port()}"
    _one_line_error(fpscan("jobs", "list", "--server", url), "cannot reach", url)


def test_bad_local_inputs_are_one_line_errors(tmp_path):
    # refused input is a usage error, exit 2, whichever command refuses it
    _one_line_error(fpscan("recon", tmp_path / "missing.h5"), "no such file", code=2)
    _one_line_error(fpscan("recon", "--scan-job", "x"), "--server", code=2)
    (tmp_path / "junk.h5").write_bytes(b"not hdf5")
    _one_line_error(fpscan("recon", tmp_path / "junk.h5"), "junk.h5", code=2)
    _one_line_error(fpscan("export", tmp_path / "missing.h5"), "no such file", code=2)
    _one_line_error(fpscan("export", "--job", "abc"), "--server", code=2)
    _one_line_error(fpscan("demo", "--out", tmp_path / "d", "--lattice", "3"), "--lattice", code=2)
    _one_line_error(fpscan("recon", tmp_path / "junk.h5", "--eps", "1e-20"), "eps must be in [1e-14, 1e-1]", code=2)
    _one_line_error(fpscan("plan", "equisteradian", "--depth", "1e-300", "--n-points", "200", "--out",
                           tmp_path / "p.json"), "below one lattice pitch", code=2)


@pytest.mark.parametrize("command", ["recon", "unmix"])
def test_input_or_scan_job_refusals_agree(command, tmp_path):
    """recon and unmix refuse the same impossible input choices with the same one-line
    reason (fpscan.clients.cli.common.check_input_files), exit 2, before touching any server."""
    url = f"http://127.0.0.1:{free_port()}"  # nobody listens: a refusal must come first
    (tmp_path / "a.h5").write_bytes(b"x")
    _one_line_error(fpscan(command, "--scan-job", "abc"), "--scan-job needs --server", code=2)
    _one_line_error(fpscan(command, tmp_path / "a.h5", "--scan-job", "abc", "--server", url), "not both", code=2)
    _one_line_error(fpscan(command), "no input:", code=2)
    _one_line_error(fpscan(command, tmp_path / "missing.h5"), "no such file", "missing.h5", code=2)


def test_jobs_against_a_server(server):
    env = clean_env(FPSCAN_SERVER=server, FPSCAN_TOKEN=TOKEN)
    res = fpscan("jobs", "list", "--json", env=env)
    assert res.returncode == 0, res.stderr
    assert isinstance(json.loads(res.stdout), list)
    # an unknown id is refused input, as a missing file is: exit 2
    _one_line_error(fpscan("jobs", "get", "no-such-job", env=env), "404", "no-such-job", code=2)
    res = fpscan("jobs", "cancel", "no-such-job", "--token", "wrong", env=env)
    assert res.returncode == 1 and ("401" in res.stderr or "403" in res.stderr)


def test_a_refused_token_says_how_to_give_it(server):
    """A 401 keeps the server's reason and names the ways to give the token."""
    for token, why in ((None, "missing bearer token"), ("wrong", "invalid bearer token")):
        res = fpscan("jobs", "list", "--server", server, *(("--token", token) if token else ()), env=clean_env())
        _one_line_error(res, "HTTP 401", why, "--token TOKEN", "FPSCAN_TOKEN", "sign-in", code=1)


@pytest.fixture(scope="module")
def kwave3d(shared_data):
    return shared_data / "kwave3d_balls_yarn.h5"


def _p0_and_volume(kwave_file, volume):
    import h5py

    with h5py.File(kwave_file, "r") as f:
        truth = f["p0"][...].astype(np.float64)
    with h5py.File(volume, "r") as f:
        p0 = f["p0"][...].astype(np.float64)
    return truth, p0


def test_recon_locally_on_kwave_data_matches_kwave_phantom(kwave3d, tmp_path):
    """`fpscan recon` (no server) of k-Wave's 3-D forward simulation: the NER image on
    k-Wave's voxel grid correlates with k-Wave's own p0."""
    from PIL import Image

    out = tmp_path / "ner"
    res = fpscan("recon", kwave3d, "--method", "ner", "--dz", "60e-6", "--n-z", "64", "--out", out, "--quiet")
    assert res.returncode == 0, res.stderr
    truth, p0 = _p0_and_volume(kwave3d, out / "volume.h5")
    assert p0.shape == truth.shape
    assert np.corrcoef(p0.ravel(), truth.ravel())[0, 1] > 0.6
    assert np.corrcoef(p0.max(axis=0).ravel(), truth.max(axis=0).ravel())[0, 1] > 0.85
    for plane in ("xy", "xz", "yz"):
        with Image.open(out / f"mip_{plane}.png") as im:
            assert im.format == "PNG"


def test_recon_on_server_equals_local(kwave3d, server, tmp_path):
    env = clean_env(FPSCAN_TOKEN=TOKEN)
    common = ["--method", "ner", "--dz", "60e-6", "--n-z", "64", "--dtype", "float32", "--quiet"]
    local = fpscan("recon", kwave3d, *common, "--out", tmp_path / "local", env=env)
    assert local.returncode == 0, local.stderr
    remote = fpscan("recon", kwave3d, *common, "--server", server, "--out", tmp_path / "remote", env=env)
    assert remote.returncode == 0, remote.stderr
    _, a = _p0_and_volume(kwave3d, tmp_path / "local" / "volume.h5")
    _, b = _p0_and_volume(kwave3d, tmp_path / "remote" / "volume.h5")
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-5 * np.abs(a).max())
    assert sorted(p.name for p in (tmp_path / "remote").iterdir()) == \
        ["mip_xy.png", "mip_xz.png", "mip_yz.png", "volume.h5"]


def test_recon_reads_kwave_mat_files_locally_and_on_the_server(shared_data, server, tmp_path):
    """k-Wave's .mat output as a k-Wave user saves it: Octave's MAT v5 and the same arrays as
    MATLAB's v7.3, each reconstructed by `fpscan recon` locally and on the server (uploaded,
    format sniffed from the content) into the same volume; a file without its spacings takes
    them as options with units."""
    import scipy.io

    from tests.storage.mat_files import write_mat5, write_mat73

    v5 = shared_data / "kwave_mat" / "kwave2d_line_sensor_v7.mat"
    arrays = {k: v for k, v in scipy.io.loadmat(v5).items() if not k.startswith("__")}
    v73 = write_mat73(tmp_path / "sensor_data_v73.mat", arrays)
    env = clean_env(FPSCAN_TOKEN=TOKEN)
    volumes = {}
    for name, path in (("v5", v5), ("v73", v73)):
        for where in ("local", "remote"):
            out = tmp_path / f"{name}-{where}"
            remote = ("--server", server) if where == "remote" else ()
            res = fpscan("recon", path, "--method", "ner", "--n-z", "96", "--out", out, "--quiet", *remote, env=env)
            assert res.returncode == 0, res.stderr
            with h5py.File(out / "volume.h5", "r") as f:
                volumes[name, where] = f["p0"][...]
    first = volumes["v5", "local"]
    assert first.shape == (96, 128)
    for key, vol in volumes.items():
        np.testing.assert_array_equal(vol, first, err_msg=str(key))
    bare = write_mat5(tmp_path / "bare.mat", {"sensor_data": arrays["sensor_data"]})
    res = fpscan("recon", bare, "--method", "ner", "--out", tmp_path / "bare", "--quiet", env=env)
    assert res.returncode == 2 and "dt is neither given nor in the MAT-file" in res.stderr, res.stderr
    res = fpscan("recon", bare, "--dt", "10ns", "--dx", "50um", "--method", "ner", "--n-z", "96",
                 "--out", tmp_path / "bare", "--quiet", env=env)
    assert res.returncode == 0, res.stderr
    with h5py.File(tmp_path / "bare" / "volume.h5", "r") as f:
        np.testing.assert_array_equal(f["p0"][...], first)


def test_cli_messages_and_ids_a_lab_meets(server, tmp_path):
    """An --out that cannot be written is refused before any work, in one line; an
    implausible sound speed names the flag that accepts it (--force); a reader that closes
    the pipe (`fpscan jobs list | head`) gets no error line (exit 141, as `ls | head`); a
    dataset id prefix works as a job id prefix does, and `--ids` lists full ids for scripts."""
    from fpscan.clients.http import Client

    env = clean_env(FPSCAN_TOKEN=TOKEN)
    data = tmp_path / "d.npy"
    np.save(data, np.random.default_rng(0).standard_normal((64, 8)).astype(np.float32))
    res = fpscan("recon", data, "--dt", "20ns", "--dx", "100um", "--out", "/proc/forbidden/out", env=env)
    assert res.returncode == 2 and res.stderr.strip().splitlines() == [
        "fpscan recon: error: --out /proc/forbidden/out: cannot write in /proc/forbidden (No such file or directory)"], \
        res.stderr
    res = fpscan("recon", data, "--dt", "20ns", "--dx", "100um", "--sound-speed", "15000", env=env)
    assert res.returncode == 2 and "give --force for a value outside the range" in res.stderr, res.stderr
    with Client(server, token=TOKEN) as api:
        ds = api.upload_dataset(data, "npy", dt=20e-9, dx=100e-6)
    res = fpscan("datasets", "list", "--server", server, "--ids", env=env)
    assert ds in res.stdout.split(), res.stdout
    res = fpscan("datasets", "delete", ds[:8], "--server", server, env=env)
    assert res.returncode == 0 and res.stdout.startswith(f"{ds}: deleted"), (res.stdout, res.stderr)
    res = fpscan("datasets", "delete", "feedfacefeed", "--server", server, env=env)
    assert res.returncode == 2 and "no dataset id starts with 'feedfacefeed'" in res.stderr, res.stderr
    closed = subprocess.Popen([sys.executable, "-m", "fpscan", "jobs", "list", "--server", server], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    closed.stdout.close()  # the reader is gone before the command writes a byte
    _, err = closed.communicate(timeout=HANG_S)
    assert closed.returncode == 141 and err == b"", (closed.returncode, err)
