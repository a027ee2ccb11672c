"""tv's quality gate on data nobody here wrote, the CI subset of
`benchmarks/bench_tv_matrix.py`: k-Wave's vessel tree and balls + yarn (the ``shared_data``
fixture), a 4 % equi-steradian mask, noise 20 dB below the peak (k-Wave's ``addNoise(..., 'peak')``).
tv's default image (the one dispatch, float32, the phantom's depth grid) must beat full-data NER's
CC with the true p0, stop by its rule, and on the vessel tree keep the amplitude and the thin vessels
the gate asks for (the mean over three noise draws); the reference run itself is the whole matrix's,
too slow for CI."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

pytestmark = pytest.mark.long(95)

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_tv_matrix.py"


def _bench():
    spec = importlib.util.spec_from_file_location("bench_tv_matrix", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("case", ["vessels", "balls"])
def test_tv_defaults_pass_the_quality_gate_on_kwave_data_at_4_percent_and_20_db_peak(case, shared_data):
    bench = _bench()
    assert (shared_data / bench.FILES[case]).is_file()
    row = bench.run_row(case, 4, "peak20", reference=False)
    print(bench.format_row(row))
    assert row["band_reason"] == "lateral" and row["converged"], row
    assert row["tv"] >= row["ner"], row  # beats full-data NER from 4 % of the points
    if case == "vessels":
        # the amplitude and the thin vessels as the gate asks: the share of the 72 thin segments seen, averaged
        # over noise seeds 0-2 (one draw sees 94-99 % of them; tv's own reference, the whole record at full
        # band, sees 92 % at seed 0)
        assert row["thin"] == 72 and row["amp"] >= bench.GATE_AMP, row
        assert sorted(row["seen_seeds"]) == [0, 1, 2], row
        assert row["seen_mean"] >= bench.GATE_SEEN, row["seen_seeds"]
    assert not bench.gate(row), bench.gate(row)  # the whole gate of a row without its reference run
