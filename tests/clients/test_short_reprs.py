"""Every public object a notebook shows has a one-line repr of at most 200 characters (what it
is, its sizes, ids and state; never arrays or point lists), and plans, jobs and
reconstructions a small HTML table. Instances are real: a plan from ``fpscan.make_plan``, a
reconstruction and its result file, the method and format registries, and the HTTP client's
answers from a real ``fpscan serve`` on loopback (a plan, an uploaded dataset, a job run to its
end, health, methods, formats)."""
from __future__ import annotations

import numpy as np

import fpscan
from fpscan.clients.http import Client

TOKEN = "short-reprs-token"


def _check(obj):
    text = repr(obj)
    assert len(text) <= 200 and "\n" not in text, (type(obj).__name__, len(text), text[:300])
    return text


def test_library_objects_have_short_reprs(tmp_path):
    from fpscan.service.formats import FORMATS
    from fpscan.service.recon.methods import METHODS

    plan = fpscan.make_plan(fpscan.full_mask(fpscan.Lattice(32, 32, 1e-4)))  # 1024 points and weights
    for obj in (plan, plan.lattice, plan.mask, plan.points, plan.acquisition, plan.lattice_obj,
                fpscan.full_mask(plan.lattice_obj)):
        _check(obj)
    assert _check(plan).startswith(f"Plan({plan.id[:12]}: full, 1024 of 1024 points")
    assert "<table>" in plan._repr_html_() and plan.id in plan._repr_html_()
    ds = fpscan.GridDataset(np.random.default_rng(0).standard_normal((64, 6, 6)).astype(np.float32), dx=1e-4,
                            dt=2e-8, sound_speed=1500.0)
    rec = fpscan.reconstruct(ds, "ner")
    _check(ds)
    assert _check(rec).startswith("Reconstruction(ner: p0 (")
    assert "<table>" in rec._repr_html_() and "ner" in rec._repr_html_()
    fpscan.write_result(tmp_path / "r", rec, input_id="x" * 64)
    assert _check(fpscan.read_result(tmp_path / "r" / "volume.h5")).startswith("ResultVolume(ner: p0 (")
    for registry in (METHODS, FORMATS):
        _check(registry)
        for name, obj in registry.items():
            assert _check(obj).startswith(f"{type(obj).__name__}({name}: ")


def test_client_answers_have_short_reprs(server, tmp_path):
    np.save(tmp_path / "line.npy", np.random.default_rng(1).standard_normal((64, 8)).astype(np.float32))
    points = [[i, j] for i in range(16) for j in range(16)]
    with Client(server, token=TOKEN) as api:
        plan = api.create_plan({"lattice": {"n_x": 16, "n_y": 16, "pitch": 1e-4}, "points": points,
                                "acquisition": {"n_t": 64, "dt": 2e-8, "prf": 0}})
        dataset_id = api.upload_dataset(tmp_path / "line.npy", format="npy", dt=2e-8, dx=1e-4)
        job_id = api.start_reconstruction(dataset_id=dataset_id, method="ner")
        job = api.wait(job_id, quiet=True)
        answers = [plan, job, job.progress, job.timings, api.health(), *api.methods(), *api.formats(),
                   *api.list_datasets(), *api.list_jobs()]
    for answer in answers:
        _check(answer)
    assert _check(job).startswith(f"Job({job.id}: ")
    assert _check(plan).startswith(f"Plan({plan.id[:12]}: ")
    for table in (job._repr_html_(), plan._repr_html_()):
        assert table.startswith("<table>") and "</table>" in table
