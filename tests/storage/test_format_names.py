"""One format sniffer: a file given where another kind was wanted is named by the registry
of formats (``fpscan.service.formats.describe``), the driver gives its plain reason, and the CLI
says what the file is ("this is a scan file, not a plan")."""
from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

import fpscan.driver.plan
from fpscan.clients.cli import main
from fpscan.service.formats import describe
from fpscan.service.storage.results import write_volume
from tests.storage.storage_helpers import build_plan


def _files(tmp_path, make_scan) -> dict[str, object]:
    npy = tmp_path / "a.npy"
    np.save(npy, np.zeros((8, 3)))
    png = tmp_path / "a.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(32))
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(build_plan(3, 3, 16)))
    bare = tmp_path / "bare.h5"
    with h5py.File(bare, "w") as f:
        f.create_dataset("data", data=np.zeros(64))
    bare.write_bytes(bare.read_bytes()[:600])  # truncated: refused as unreadable, still HDF5
    junk = tmp_path / "junk.bin"
    junk.write_bytes(bytes(range(200, 256)) * 4)
    z, x, y = np.arange(4) * 1e-5, np.arange(3) * 1e-4, np.arange(2) * 1e-4
    result = write_volume(tmp_path / "volume.h5", np.ones((4, 2, 3), np.float32), z, x, y,
                          method="ner", params={}, input_id="t")
    return {"scan": make_scan("scan.h5", build_plan(3, 3, 16)), "result": result, "npy": npy, "png": png,
            "plan": plan, "bare": bare, "junk": junk}


def test_describe_names_each_file_by_its_content(tmp_path, make_scan):
    f = _files(tmp_path, make_scan)
    assert describe(f["scan"]) == "a scan file"
    assert describe(f["result"]) == "a reconstruction result"
    assert describe(f["npy"]) == "a NumPy .npy array"
    assert describe(f["png"]) == "a PNG picture"
    assert describe(f["plan"]) == "a plan (JSON)"
    assert describe(f["plan"], unless=("plan",)) is None  # the caller wanted a plan: its own reason
    assert describe(f["bare"]) == "an HDF5 file"  # HDF5, but unreadable: no format can say more
    assert describe(f["junk"]) is None
    assert describe(tmp_path / "missing.h5") is None
    # the name does not come from the file's name: a scan file called plan.json is a scan file
    renamed = tmp_path / "looks-like-a-plan.json"
    renamed.write_bytes(f["scan"].read_bytes())
    assert describe(renamed) == "a scan file"


def test_the_driver_gives_a_plain_reason_and_has_no_sniffer(tmp_path, make_scan):
    f = _files(tmp_path, make_scan)
    assert not hasattr(fpscan.driver.plan, "file_kind")
    for kind in ("scan", "result", "npy", "png"):
        with pytest.raises(ValueError, match="not a plan: the file is not UTF-8 JSON text") as err:
            fpscan.driver.plan.load_plan(str(f[kind]))
        assert "scan file" not in str(err.value) and "result" not in str(err.value)


def test_the_library_plan_loader_names_the_file(tmp_path, make_scan):
    """fpscan.load_plan (fpscan.service.formats.plan.read_plan: the driver's loader plus the
    registry's name for a file of another format)."""
    import fpscan
    from fpscan.service.formats.plan import read_plan

    f = _files(tmp_path, make_scan)
    assert fpscan.load_plan is read_plan
    with pytest.raises(ValueError, match="this is a scan file, not a plan"):
        fpscan.load_plan(f["scan"])
    with pytest.raises(ValueError, match="not a plan: the file is not UTF-8 JSON text"):
        fpscan.load_plan(f["junk"])
    assert fpscan.load_plan(f["plan"]) == fpscan.driver.plan.load_plan(str(f["plan"]))
    assert fpscan.load_plan(f["plan"].read_text())["id"] == json.loads(f["plan"].read_text())["id"]


@pytest.mark.parametrize("kind, what", [("scan", "a scan file"), ("result", "a reconstruction result"),
                                        ("npy", "a NumPy .npy array"), ("png", "a PNG picture")])
def test_the_cli_names_a_wrong_plan_file(tmp_path, make_scan, capsys, kind, what):
    f = _files(tmp_path, make_scan)
    rc = main(["scan", "--device", str(tmp_path / "no-such-device"), "--plan", str(f[kind]),
               "--out", str(tmp_path / "out.h5")])
    err = capsys.readouterr().err
    assert rc == 2 and f"this is {what}, not a plan" in err, err
    assert not (tmp_path / "out.h5").exists()
    with pytest.raises(SystemExit) as stop:
        main(["plan", "points", "--indices", str(f[kind]), "--server", "http://127.0.0.1:9"])
    assert stop.value.code == 2
    assert f"this is {what}, not a JSON list of pairs" in capsys.readouterr().err


def test_unknown_bytes_keep_the_plain_reason(tmp_path, make_scan, capsys):
    f = _files(tmp_path, make_scan)
    assert main(["scan", "--device", str(tmp_path / "dev"), "--plan", str(f["junk"]),
                 "--out", str(tmp_path / "out.h5")]) == 2
    assert "not a plan: the file is not UTF-8 JSON text" in capsys.readouterr().err


def test_the_scan_layout_has_one_reader():
    """The scan file's layout (its datasets ``aline_meta``, ``completed``, ``plan_json`` and
    the ``fpscan-scan/`` format names) is spelled in fpscan.driver.scanfile alone: the registry's
    entry (fpscan.service.formats.scan) and every other module go through it."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    owners = set()
    for package in ("driver", "service", "clients", "fpscan"):
        for path in (root / package).rglob("*.py"):
            text = path.read_text(encoding="utf-8")
            if any(word in text for word in ('"aline_meta"', '"completed"]', '"plan_json"', '"fpscan-scan/')):
                owners.add(path.relative_to(root).as_posix())
    assert owners == {"driver/scanfile.py"}, owners


def test_plan_module_examples_run():
    import doctest

    import fpscan.service.formats.plan

    assert doctest.testmod(fpscan.service.formats.plan).failed == 0
