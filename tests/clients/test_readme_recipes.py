"""The tour (docs/tour.md, linked from the README) runs as written: its shell blocks (the command line and the
curl section) and its Python blocks, in their order, in one bash session in a fresh folder,
against the simulator and a real server, exactly as a lab would paste them. The one change:
the server listens on a free port instead of 8000 (the suite runs beside other servers).

Oracles: each command's exit status (``set -e``: the first failing line fails the test), the
files the tour says it makes, and what the tour states about them: the local and the
server's reconstruction of the same scan are the same volume; tv's defaults are the method's
own (``fpscan.service.recon.methods``)."""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys

import numpy as np
import pytest

from tests.clients.clients_servers import clean_env, free_port, has_command
from tests.conftest import REPO_ROOT
from tests.waits import HANG_S

#: the page of the tour's recipes (the README's "A first reconstruction" points there)
TOUR_PAGE = REPO_ROOT / "docs" / "tour.md"

pytestmark = [pytest.mark.skipif(not (has_command("serve") and has_command("sim")),
                                 reason="`fpscan serve`/`fpscan sim` not available"),
              pytest.mark.long(70)]


TOUR, SPARSE, AFTER = "## A five-minute tour", "## A sparse scan out of dense data", "## The end-to-end demo"


def tour_blocks(text: str, start: str = TOUR, end: str = SPARSE) -> list[tuple[str, str]]:
    """The code blocks of a section of the tour (default "A five-minute tour"), in order: ``("sh", text)``
    for an indented block, ``("python", text)`` for a fenced python block."""
    section = text[text.index(start):text.index(end)]
    lines = section.splitlines()
    blocks: list[tuple[str, str]] = []
    i = 0
    while i < len(lines):
        if lines[i].startswith("```python"):
            j = lines.index("```", i + 1)
            blocks.append(("python", "\n".join(lines[i + 1:j])))
            i = j + 1
        elif lines[i].startswith("    ") and not lines[i - 1].strip():
            body = []
            while i < len(lines) and (lines[i].startswith("    ") or
                                      (not lines[i].strip() and i + 1 < len(lines) and lines[i + 1].startswith("    "))):
                body.append(lines[i][4:])
                i += 1
            blocks.append(("sh", "\n".join(body)))
        else:
            i += 1
    return blocks


def checkout(tmp_path):
    """A checkout's stand-in for the tour's ``CHECKOUT``: a folder whose ``.venv`` is this
    interpreter's environment; the tour itself runs in another, empty folder."""
    root = tmp_path / "checkout"
    root.mkdir()
    (root / ".venv").symlink_to(sys.prefix, target_is_directory=True)
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    return root, fresh


def with_checkout(script: str, root) -> str:
    """The tour's ``CHECKOUT=~/fpscan`` line pointed at ``root``."""
    assert script.count("CHECKOUT=~/fpscan ") == 1
    return script.replace("CHECKOUT=~/fpscan ", f"CHECKOUT={root} ")


def tour_script(blocks: list[tuple[str, str]], port: int) -> str:
    """One bash script of the blocks (each python block through ``python - <<EOF``), stopping at
    the first failing command, on ``port``."""
    parts = ["set -e"]
    for kind, body in blocks:
        parts.append(body if kind == "sh" else f"python - <<'FPSCAN_README_PY'\n{body}\nFPSCAN_README_PY")
    script = "\n".join(parts) + "\n"
    assert script.count("127.0.0.1:8000") >= 2 and "--port 8000" in script
    return script.replace("127.0.0.1:8000", f"127.0.0.1:{port}").replace("--port 8000", f"--port {port}")


def test_the_tour_parses_into_its_blocks():
    kinds = [k for k, _ in tour_blocks(TOUR_PAGE.read_text(encoding="utf-8"))]
    assert kinds == ["sh", "python", "python", "sh", "sh"], kinds


def test_the_readme_states_tvs_own_defaults():
    """What the tour says of tv's options is what the method's options model holds."""
    from fpscan.service.recon.methods import METHODS

    text = " ".join(TOUR_PAGE.read_text(encoding="utf-8").split())
    said = re.search(r"`--max-iter` \(default (\d+)", text)
    options = METHODS["tv"].options_model.model_fields
    assert said and int(said[1]) == options["max_iter"].default, said


@pytest.mark.skipif(not (shutil.which("curl") and shutil.which("jq")), reason="the curl section needs curl and jq")
def test_the_five_minute_tour_runs_as_written(tmp_path):
    blocks = tour_blocks(TOUR_PAGE.read_text(encoding="utf-8"))
    root, fresh = checkout(tmp_path)
    script = with_checkout(tour_script(blocks, free_port()), root)
    proc = subprocess.Popen(["bash", "-c", script], cwd=fresh, env=clean_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=HANG_S)
    finally:
        try:  # the tour's background server and simulator, should a line have failed before its `kill`
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()
    tmp_path = fresh
    logs = "".join(f"\n--- {p.name}\n{p.read_text(errors='replace')[-3000:]}" for p in
                   (tmp_path / "serve.log", tmp_path / "sim.log") if p.exists())
    assert proc.returncode == 0, out[-6000:] + logs
    for made in ("plan.json", "mask.png", "scan.h5", "scan_job.h5", "scan-nedner/volume.h5", "remote-nedner/volume.h5",
                 "scan_ipasc.h5", "volume.ome.tif", "volume.ome.zarr", "scan-nedner-py/volume.h5", "volume_py.ome.zarr",
                 "scan_api.h5", "volume_api.h5", "mip_xy.png", "volume_api.ome.zarr", "volume_curl.h5",
                 "mip_xy_curl.png", "volume.ome.zarr.zip"):
        assert (tmp_path / made).exists(), made
    import h5py

    with h5py.File(tmp_path / "scan-nedner/volume.h5", "r") as a, h5py.File(tmp_path / "remote-nedner/volume.h5") as b:
        np.testing.assert_array_equal(a["p0"][...], b["p0"][...])  # "both give the same volume"
    assert "Broken pipe" not in out and "Traceback" not in out, out[-6000:]


def test_the_sparse_from_dense_section_runs_as_written(tmp_path, shared_data):
    """"A sparse scan out of dense data": its commands and its Python, after the tour's first two
    lines (``CHECKOUT``, the activated venv), in a fresh folder; its volumes are the library's."""
    import fpscan

    text = TOUR_PAGE.read_text(encoding="utf-8")
    blocks = tour_blocks(text, SPARSE, AFTER)
    assert [k for k, _ in blocks] == ["sh", "python"], blocks
    first = tour_blocks(text)[0][1].splitlines()
    head = "\n".join(line for line in first if line.startswith(("CHECKOUT=", "source ")))
    root, fresh = checkout(tmp_path)
    parts = ["set -e", head, blocks[0][1], f"python - <<'FPSCAN_README_PY'\n{blocks[1][1]}\nFPSCAN_README_PY"]
    env = {**clean_env(), "FPSCAN_SHARED": str(shared_data.parent)}
    r = subprocess.run(["bash", "-c", with_checkout("\n".join(parts) + "\n", root)], cwd=fresh, env=env,
                       capture_output=True, text=True, timeout=HANG_S)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-4000:]
    assert "Traceback" not in r.stderr
    sparse = fpscan.subsample(fpscan.load_dataset(shared_data / "kwave3d_balls_yarn.h5"),
                              fpscan.load_plan(fresh / "sparse_plan.json"))
    assert sparse.alines.shape[0] == 976
    want = fpscan.reconstruct(sparse, "nedner")
    got = fpscan.read_result(fresh / "kwave-sparse" / "volume.h5")
    np.testing.assert_array_equal(got.p0, want.p0)
    np.testing.assert_allclose(got.x, want.x, atol=1e-15)
    assert (fresh / "kwave-dense" / "volume.h5").exists()
    assert "PointDataset" in r.stdout and "976" in r.stdout, r.stdout


README = REPO_ROOT / "README.md"
FIRST, WEB = "## A first reconstruction", "## The web page"


def test_the_readmes_first_reconstruction_runs_as_written(tmp_path, shared_data):
    """README "A first reconstruction": its commands and Python, in order, in the checkout's stand-in
    (its ``.venv``), the server on a free port; the command line's, the library's, the server's and
    the client's volumes of the k-Wave file are one volume, as the README says."""
    import fpscan

    blocks = tour_blocks(README.read_text(encoding="utf-8"), FIRST, WEB)
    assert [k for k, _ in blocks] == ["sh", "sh", "python", "sh", "python"], blocks
    root, _ = checkout(tmp_path)
    script = tour_script(blocks, free_port()) + "kill %1\n"
    proc = subprocess.Popen(["bash", "-c", script], cwd=root, env={**clean_env(), "FPSCAN_SHARED": str(shared_data.parent)},
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=HANG_S)
    finally:
        try:  # the README's background server, should a line have failed before the end
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()
    assert proc.returncode == 0, out[-6000:]
    assert "Traceback" not in out, out[-6000:]
    volumes = [fpscan.read_result(root / p).p0 for p in
               ("kwave-ner/volume.h5", "kwave-ner-py/volume.h5", "kwave-remote/volume.h5", "kwave-http.h5")]
    assert volumes[0].shape[0] == 64
    for other in volumes[1:]:
        np.testing.assert_array_equal(other, volumes[0])
    assert (root / "kwave.ome.zarr").is_dir() and (root / "kwave-http-mip-xy.png").is_file()


def dense_recipes() -> list[str]:
    """The README's and the tour's dense reconstructions of ``$KWAVE`` on this machine: their
    ``fpscan recon $KWAVE`` lines without ``--plan`` or ``--server``, as written."""
    lines = []
    for page, start, end in ((README, FIRST, WEB), (TOUR_PAGE, SPARSE, AFTER)):
        for kind, body in tour_blocks(page.read_text(encoding="utf-8"), start, end):
            lines += [line.strip() for line in body.splitlines() if kind == "sh" and
                      line.strip().startswith("fpscan recon $KWAVE") and not re.search(r"--(plan|server)\b", line)]
    return lines


def test_the_dense_recipes_cover_the_vessel_tree(tmp_path, shared_data):
    """README "A first reconstruction" and the tour's "A sparse scan out of dense data": their NER of
    every sensor of the k-Wave file, run as written on the vessel tree (``$KWAVE``), reaches the
    phantom's whole depth and correlates with its true p0 at CC >= 0.85 (Pearson, on p0's own
    64 rows of 60 µm: the image linear in depth between its rows). Oracles: the file's p0 and the
    volume as stored, read with h5py."""
    import h5py

    recipes = dense_recipes()
    assert len(recipes) == 2 and all("--n-z" in r for r in recipes), recipes
    root, fresh = checkout(tmp_path)
    kwave = shared_data / "kwave3d_vessel_tree.h5"
    with h5py.File(kwave, "r") as f:
        p0 = np.asarray(f["p0"][...], dtype=np.float64)  # (depth, y, z), k-Wave's x the depth
        p0_dz = float(f.attrs["dx_m"])
    zt = np.arange(p0.shape[0]) * p0_dz
    for recipe in recipes:
        script = f"set -e\nsource {root}/.venv/bin/activate\nexport KWAVE={kwave}\n{recipe}\n"
        r = subprocess.run(["bash", "-c", script], cwd=fresh, env=clean_env(), capture_output=True, text=True,
                           timeout=HANG_S)
        assert r.returncode == 0, recipe + "\n" + r.stdout[-3000:] + r.stderr[-3000:]
        out = re.search(r"--out (\S+)", recipe)[1]
        with h5py.File(fresh / out / "volume.h5", "r") as f:
            img, z = np.asarray(f["p0"][...], dtype=np.float64), np.asarray(f["z"][...])
        assert img.shape[1:] == p0.shape[1:], img.shape
        assert z[-1] >= zt[-1] - 1e-9, (f"{recipe}: the image ends {z[-1] * 1e3:.3g} mm deep, the phantom "
                                        f"{zt[-1] * 1e3:.3g} mm")
        j = np.clip(np.searchsorted(z, zt, side="right") - 1, 0, len(z) - 2)
        w = ((zt - z[j]) / (z[j + 1] - z[j]))[:, None, None]
        cc = float(np.corrcoef((img[j] * (1 - w) + img[j + 1] * w).ravel(), p0.ravel())[0, 1])
        assert cc >= 0.85, (recipe, cc)
