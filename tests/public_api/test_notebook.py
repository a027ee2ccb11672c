"""The notebook example: docs/notebook.ipynb runs in a real Jupyter kernel
(ipykernel, driven by nbclient as Jupyter runs a notebook); its objects print as one line each;
``fpscan.reconstruct`` draws one progress bar in the cell's output and ends it on "done", and
nothing with ``quiet=True``; the committed notebook holds the outputs of such a run."""
from __future__ import annotations

import re

import pytest

from tests.conftest import REPO_ROOT

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

NOTEBOOK = REPO_ROOT / "docs" / "notebook.ipynb"


def _outputs(cell) -> list[tuple[str, dict]]:
    return [(o["output_type"], o.get("data", {})) for o in cell.get("outputs", [])]


def test_the_notebook_example_runs_with_a_bar_and_short_reprs(tmp_path):
    committed = nbformat.read(NOTEBOOK, as_version=4)
    code = [c for c in committed.cells if c.cell_type == "code"]
    assert code and all(c.get("outputs") for c in code), "the committed notebook is executed"
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbclient.NotebookClient(nb, timeout=300, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()
    cells = {c.source.splitlines()[0]: c for c in nb.cells if c.cell_type == "code"}
    reprs = [data["text/plain"] for c in nb.cells if c.cell_type == "code"
             for kind, data in _outputs(c) if kind == "execute_result"]
    for start in ("GridDataset((128, 24, 24)", "Mask(equisteradian:", "PointDataset(subsample:", "Reconstruction(nedner:"):
        found = [r for r in reprs if r.startswith(start)]
        assert found and all(len(r) < 200 and "\n" not in r for r in found), (start, reprs)
    recon = cells['rec = fpscan.reconstruct(sparse, "nedner")  # a progress bar while it runs']
    bars = [data for kind, data in _outputs(recon) if kind == "display_data"]
    assert len(bars) == 1, _outputs(recon)  # one bar, updated in place
    assert "<progress" in bars[0]["text/html"] and bars[0]["text/plain"] == "nedner: done  100%", bars
    quiet = [c for c in nb.cells if c.cell_type == "code" and "quiet=True" in c.source][0]
    assert [kind for kind, _ in _outputs(quiet)] == ["execute_result"], _outputs(quiet)  # no bar
    out = [o["text"] for c in nb.cells for o in c.get("outputs", []) if o["output_type"] == "stream"]
    found = re.fullmatch(r"brightest voxel: x (\S+) mm, y (\S+) mm, z (\S+) mm\n", "".join(out))
    assert found, out  # within the ball (centre (0.25, -0.15, 1.0) mm, radius 0.15 mm) on the 0.1 mm lattice
    x, y, z = (float(found[i]) for i in (1, 2, 3))
    assert abs(x - 0.25) <= 0.15 and abs(y + 0.15) <= 0.15 and abs(z - 1.0) <= 0.15, out


def test_no_bar_outside_a_notebook(capsys):
    """In a script (no Jupyter kernel) the library prints nothing."""
    import numpy as np

    import fpscan
    from fpscan.service.notebook import in_notebook

    assert not in_notebook()
    fpscan.reconstruct(fpscan.GridDataset(np.zeros((32, 8)), dx=1e-4, dt=1e-8, sound_speed=1500.0), "ner")
    assert capsys.readouterr() == ("", "")
