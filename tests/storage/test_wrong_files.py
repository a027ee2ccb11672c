"""A file of the wrong kind is named as what it is: the one plan loader
(``fpscan.driver.plan.load_plan``) and the one dataset loader (``fpscan.service.storage.loader``),
through the CLI as a person meets them."""
from __future__ import annotations

import json

import numpy as np
import pytest

from fpscan.clients.cli import main
from fpscan.service.storage.results import write_volume
from tests.storage.storage_helpers import build_plan


def _result(tmp_path):
    z, x, y = np.arange(4) * 1e-5, np.arange(3) * 1e-4, np.arange(2) * 1e-4
    return write_volume(tmp_path / "volume.h5", np.ones((4, 2, 3), np.float32), z, x, y,
                        method="ner", params={}, input_id="t")


def test_scan_with_a_scan_file_or_result_as_plan(tmp_path, make_scan, capsys):
    scan = make_scan("scan.h5", build_plan(3, 3, 16))
    for wrong, kind in ((scan, "this is a scan file, not a plan"),
                        (_result(tmp_path), "this is a reconstruction result, not a plan")):
        rc = main(["scan", "--device", str(tmp_path / "no-such-device"), "--plan", str(wrong),
                   "--out", str(tmp_path / "out.h5")])
        assert rc == 2
        assert kind in capsys.readouterr().err
    assert not (tmp_path / "out.h5").exists()


def test_server_scan_and_plan_with_a_scan_file(tmp_path, make_scan, capsys):
    """With --server the plan file is read by the same loader: the scan file is named
    before any request (nothing listens at the address), exit 2; so too a scan file
    given to ``fpscan plan points --indices`` (an argparse usage error)."""
    scan = make_scan("scan.h5", build_plan(3, 3, 16))
    nowhere = "http://127.0.0.1:9"
    rc = main(["scan", "--server", nowhere, "--scanner", "sim", "--plan", str(scan), "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and "this is a scan file, not a plan" in err and "codec" not in err
    with pytest.raises(SystemExit) as stop:
        main(["plan", "points", "--indices", str(scan), "--server", nowhere])
    assert stop.value.code == 2
    assert "this is a scan file, not a JSON list" in capsys.readouterr().err


def test_recon_with_a_result_or_a_plan_as_input(tmp_path, capsys):
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(build_plan(3, 3, 16)))
    for wrong, kind in ((_result(tmp_path), "this is a reconstruction result"),
                        (plan, "this is a plan (JSON), not data")):
        assert main(["recon", str(wrong), "-q", "--out", str(tmp_path / "r")]) == 2
        assert kind in capsys.readouterr().err
    with pytest.raises(ValueError, match="this is a reconstruction result"):
        from fpscan.service.storage.loader import load_dataset

        load_dataset(tmp_path / "volume.h5")
