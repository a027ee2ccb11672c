"""Every example of the gallery (``examples/*.py``, built into the documentation site by
sphinx-gallery) runs as a user would run it: a fresh interpreter, pictures to matplotlib's
Agg backend, in an empty folder, within a bounded time, and leaves no temporary folder behind.

Oracles: the exit status, the example's own printed figures where it states them (each checks
what its text claims: the plugin's refusal and its CCs, the unmixed sO2, the served volume equal
to the library's, every export holding the volume), and the temporary folder left empty."""
from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest

from tests.conftest import REPO_ROOT

EXAMPLES = sorted((REPO_ROOT / "examples").glob("*.py"))

pytestmark = pytest.mark.long(50)


def _plugin_das(text: str) -> None:
    assert "refused: f_number: Input should be greater than 0" in text
    cc = {name: float(v) for name, v in re.findall(r"^(das, f_number [\d.]+|nedner): CC with the true p0 ([\d.]+)",
                                                  text, re.MULTILINE)}
    assert set(cc) == {"das, f_number 1.0", "das, f_number 0.25", "nedner"}, text
    assert cc["das, f_number 0.25"] > cc["das, f_number 1.0"] > 0.2 and cc["nedner"] > 0.5, cc
    assert "--f-number F_NUMBER" in text and "method das" in text  # the CLI's help and its result line
    assert re.search(r"served methods: .*\bdas\b", text) and ": succeeded" in text and "'f_number': 2.0" in text


def _unmixing(text: str) -> None:
    so2 = dict(re.findall(r"^(artery|vein): sO2 ([\d.]+)", text, re.MULTILINE))
    assert float(so2["artery"]) == pytest.approx(0.97, abs=0.03) and float(so2["vein"]) == pytest.approx(0.6, abs=0.05)


def _kwave(text: str) -> None:
    assert "GridDataset(kwave-hdf5" in text
    assert float(re.search(r"CC with NER on its grid ([\d.]+)", text)[1]) > 0.95, text


def _http(text: str) -> None:
    assert "succeeded" in text and "equal to the library's: True" in text, text


def _exports(text: str) -> None:
    assert "every export holds the reconstructed volume" in text and "p0.mat: ['p0'" in text, text


def _tv_pyproximal(text: str) -> None:
    found = {name: (float(j), float(cc)) for name, j, cc in re.findall(
        r"^(tv at its stopping rule|tv, \d+ iterations|PrimalDual)[^:]*: J = ([\d.e-]+), CC with the true p0 ([\d.]+)",
        text, re.MULTILINE)}
    assert len(found) == 3, text
    warm = float(re.search(r"J\(warm start\) = ([\d.e-]+)", text)[1])
    j_tv, j_pd = found[next(k for k in found if k.startswith("tv, "))][0], found["PrimalDual"][0]
    assert j_tv <= j_pd * 1.001 and j_pd < 0.5 * warm, found  # tv reaches PrimalDual's J on the same problem
    assert min(cc for _, cc in found.values()) > 0.85, found


#: what each example's output states (an example not named here: its exit status alone)
CHECKS = {"plot_plugin_das": _plugin_das, "plot_spectral_unmixing": _unmixing, "plot_kwave_files": _kwave,
          "plot_http_client": _http, "plot_exports": _exports, "plot_tv_pyproximal": _tv_pyproximal}


def test_every_example_is_collected():
    assert len(EXAMPLES) >= 8 and set(CHECKS) <= {p.stem for p in EXAMPLES}


@pytest.mark.timeout(320)
@pytest.mark.parametrize("example", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_the_example_runs(example, tmp_path):
    env = {**os.environ, "MPLBACKEND": "Agg", "TMPDIR": str(tmp_path)}
    out = subprocess.run([sys.executable, str(example)], capture_output=True, text=True, timeout=300, env=env,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-4000:]
    if example.stem in CHECKS:
        CHECKS[example.stem](out.stdout)
    assert not [p.name for p in tmp_path.glob("fpscan-*")], "the example left its temporary folder behind"
