"""The HTTP client's notebook bar: in a real Jupyter kernel (ipykernel, driven by
nbclient as Jupyter runs a notebook) ``Client.wait`` and ``AsyncClient.wait`` on a real
``fpscan serve`` draw one progress bar in the cell's output, updated in place, that ends on the
job's final state; ``quiet=True`` or a callback draws nothing, and neither does a script.

Oracle: the cells' outputs as Jupyter records them (one ``display_data`` per bar; its updates
replace it in place), and the job's final state from ``GET /api/jobs/{id}``."""
from __future__ import annotations

import re

import h5py
import numpy as np
import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

pytestmark = pytest.mark.timeout(300)

TOKEN = "notebook-bar-token"


def _dataset(path):
    """A small k-Wave-named HDF5 upload: (t, y, x) = (256, 16, 16)."""
    data = np.random.default_rng(7).standard_normal((256, 16, 16)).astype(np.float32)
    with h5py.File(path, "w") as f:
        f.create_dataset("sensor_data", data=data).attrs["kwave_DataOrder"] = "tyz"
        f.attrs.update({"dt_s": 1e-8, "dy_m": 1e-4, "dz_m": 1e-4})
    return path


class _Recording(nbclient.NotebookClient):
    """nbclient's client, recording each cell's display messages (``display_data`` and its
    ``update_display_data``) with their display ids."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.displays: dict[int, list[tuple[str, str | None]]] = {}

    def process_message(self, msg, cell, cell_index):
        kind = msg["msg_type"]
        if kind in ("display_data", "update_display_data"):
            display_id = msg["content"].get("transient", {}).get("display_id")
            self.displays.setdefault(cell_index, []).append((kind, display_id))
        return super().process_message(msg, cell, cell_index)


def _outputs(cell) -> list[tuple[str, dict]]:
    return [(o["output_type"], o.get("data", {})) for o in cell.get("outputs", [])]


def _bars(cell) -> list[dict]:
    return [data for kind, data in _outputs(cell) if kind == "display_data"]


def test_client_waits_draw_one_bar_in_a_notebook_and_none_when_quiet(server, tmp_path):
    upload = _dataset(tmp_path / "small.h5")
    code = [
        # 0: a dataset on the server
        f"from fpscan.clients.http import AsyncClient, Client\n"
        f"api = Client({server!r}, token={TOKEN!r})\n"
        f"ds = api.upload_dataset({str(upload)!r}, 'kwave-hdf5')",
        # 1: a wait without a callback: one bar, ending on the job's final state
        "job = api.start_reconstruction(dataset_id=ds, method='ner')\n"
        "final = api.wait(job, timeout=240)",
        # 2: quiet: nothing
        "job2 = api.start_reconstruction(dataset_id=ds, method='ner')\n"
        "final2 = api.wait(job2, timeout=240, quiet=True)",
        # 3: a callback: nothing but what the callback does
        "seen = []\n"
        "final3 = api.wait(job2, timeout=240, on_progress=seen.append)",
        # 4: the async client: one bar
        f"async with AsyncClient({server!r}, token={TOKEN!r}) as aapi:\n"
        "    job4 = await aapi.start_reconstruction(dataset_id=ds, method='ner')\n"
        "    final4 = await aapi.wait(job4, timeout=240)",
        # 5: a failed job's end
        "from fpscan.clients.http.notebook import JobBar\n"
        "bar = JobBar({'id': 'abcdef1234', 'kind': 'scan', 'state': 'running',\n"
        "              'progress': {'fraction': 0.4, 'stage': 'acquiring'}})\n"
        "bar({'fraction': 0.5, 'stage': 'acquiring', 'eta_s': 3.0})\n"
        "bar.close({'id': 'abcdef1234', 'state': 'failed', 'error': 'scanner lost'})",
        # 6: what the waits returned
        "print(final.state, final2.state, final3.state, final4.state, len(seen) > 0, job[:8], job4[:8])",
    ]
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c) for c in code])
    client = _Recording(nb, timeout=280, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    cells = nb.cells
    printed = "".join(o["text"] for o in cells[6]["outputs"] if o["output_type"] == "stream")
    states = printed.split()
    assert states[:5] == ["succeeded"] * 4 + ["True"], printed
    job, job4 = states[5], states[6]
    for cell, job_id in ((cells[1], job), (cells[4], job4)):
        bars = _bars(cell)
        assert len(bars) == 1 and len(_outputs(cell)) == 1, _outputs(cell)  # one bar, updated in place
        assert re.fullmatch(rf"ner \(job {job_id}\): succeeded  100%", bars[0]["text/plain"]), bars
        assert '<progress value="1.0000"' in bars[0]["text/html"], bars
        shown = client.displays[cells.index(cell)]  # one display, then its updates in place
        assert shown[0][0] == "display_data" and len(shown) >= 2, shown
        assert {kind for kind, _ in shown[1:]} == {"update_display_data"} and len({i for _, i in shown}) == 1, shown
    for cell in (cells[0], cells[2], cells[3]):
        assert _outputs(cell) == [], _outputs(cell)  # quiet, a callback, no wait: no bar
    (failed,) = _bars(cells[5])
    assert failed["text/plain"] == "scan (job abcdef12): failed: scanner lost  50%", failed


def test_no_bar_outside_a_notebook(server, tmp_path, capsys):
    """In a script (no Jupyter kernel) a wait without a callback prints nothing."""
    from fpscan.clients.http import Client
    from fpscan.clients.http.notebook import in_notebook

    assert not in_notebook()
    with Client(server, token=TOKEN) as api:
        ds = api.upload_dataset(_dataset(tmp_path / "small.h5"), "kwave-hdf5")
        assert api.wait(api.start_reconstruction(dataset_id=ds, method="ner"), timeout=240).state == "succeeded"
    assert capsys.readouterr() == ("", "")
