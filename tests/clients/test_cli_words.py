"""Words the user typed: the command line's errors name its flags (``--lam``,
``--key``, ``--sound-speed``), not the library's keywords; its help lists every input format and
every action as it is spelled. Oracle: the flags argparse declares (``fpscan recon --help``)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import scipy.io

from tests.clients.clients_servers import clean_env


def fpscan(*args):
    return subprocess.run([sys.executable, "-m", "fpscan", *map(str, args)], capture_output=True, text=True,
                          timeout=120, env=clean_env())


def test_refused_options_and_missing_inputs_name_the_flags(tmp_path):
    np.save(tmp_path / "line.npy", np.zeros((64, 8)))
    helps = fpscan("recon", "--help").stdout
    r = fpscan("recon", tmp_path / "line.npy", "--dt", "10ns", "--dx", "100um", "--method", "nedner",
               "--lam", "0.1")
    assert r.returncode == 2, r.stderr
    assert "takes no option --lam (its options: --sound-speed, --sound-speed-range, --force, --eps," in r.stderr, \
        r.stderr
    named = r.stderr.partition("(its options: ")[2].partition(")")[0].split(", ")
    assert named and all(flag in helps for flag in named), named  # each a flag the command has
    r = fpscan("recon", tmp_path / "line.npy", "--dt", "10ns", "--dx", "100um", "--method", "ner", "--eps", "1")
    assert r.returncode == 2 and "error: --eps must be in" in r.stderr, r.stderr
    r = fpscan("recon", tmp_path / "line.npy", "--dx", "100um")
    assert r.returncode == 2 and "needs --dt (s) and --dx (m)" in r.stderr, r.stderr
    scipy.io.savemat(tmp_path / "other.mat", {"p0_true": np.zeros((8, 8)), "rf": np.zeros((8, 40)), "rf2": np.ones((8, 40)), "dt": 1e-8, "dx": 1e-4})
    r = fpscan("recon", tmp_path / "other.mat")
    assert r.returncode == 2 and r.stderr.rstrip().endswith("give --key"), r.stderr
    assert "Traceback" not in r.stderr


def test_help_lists_every_input_format_and_action_as_spelled():
    top = fpscan("--help").stdout
    assert "list, get, wait on, resume (a paused scan), cancel or delete" in " ".join(top.split())
    assert "show" not in top.split("jobs", 1)[1].split("\n\n")[0]
    jobs = fpscan("jobs", "--help").stdout
    for action in ("list", "get", "wait", "resume", "cancel", "delete"):
        assert action in jobs, action
    recon = " ".join(fpscan("recon", "--help").stdout.split())
    assert "(.mat:" in recon and "v7.3" in recon and ".npy" in recon and "IPASC" in recon
    # every format the registry reads, by its name, in --format's choices and in the HTTP docs
    from pathlib import Path

    from fpscan.service.formats import upload_formats

    choices = recon.split("--format {", 1)[1].split("}", 1)[0].split(",")
    api_doc = (Path(__file__).parents[2] / "docs" / "api.md").read_text()
    for fmt in upload_formats():
        assert fmt["name"] in choices, (fmt["name"], choices)
        assert f"`{fmt['name']}`" in api_doc, fmt["name"]


def test_an_unknown_option_names_the_closest():
    r = fpscan("recon", "x.npy", "--lamda", "0.1")
    assert r.returncode == 2, r.stderr
    assert r.stderr.rstrip().splitlines()[-1] == "fpscan recon: error: unrecognized option --lamda: did you mean --lam?"
    assert "usage: fpscan recon" in r.stderr
    r = fpscan("plan", "full", "--n-x", "8", "--pich=100um")  # a sub-command's sub-command, --flag=value
    assert r.returncode == 2 and "unrecognized option --pich: did you mean --pitch?" in r.stderr, r.stderr


def test_a_quantity_takes_its_unit_as_the_next_word(tmp_path):
    r = fpscan("plan", "full", "--n-x", "8", "--pitch", "100", "um", "--dt", "8", "ns", "--out", tmp_path / "p.json")
    assert r.returncode == 0, r.stderr
    import json

    plan = json.loads((tmp_path / "p.json").read_text())
    assert plan["lattice"]["pitch"] == 1e-4 and plan["acquisition"]["dt"] == 8e-9


def test_a_time_in_a_unit_too_large_suggests_the_plausible_one(tmp_path):
    np.save(tmp_path / "line.npy", np.zeros((64, 8)))
    r = fpscan("recon", tmp_path / "line.npy", "--dt", "8us", "--dx", "100um", "--out", tmp_path / "out")
    assert r.returncode == 2, r.stderr
    assert "dt 8e-06 s is implausible" in r.stderr and "did you mean 8 ns (8ns)?" in r.stderr, r.stderr


def test_a_mat_file_of_only_p0_is_named_a_phantom(tmp_path):
    scipy.io.savemat(tmp_path / "phantom.mat", {"p0": np.ones((16, 16)), "dx": 1e-4})
    r = fpscan("recon", tmp_path / "phantom.mat")
    assert r.returncode == 2, r.stderr
    assert "initial pressure p0" in r.stderr and "no sensor data" in r.stderr and "phantom, not a scan" in r.stderr
    assert "variables: " in r.stderr and "give --key" not in r.stderr, r.stderr
