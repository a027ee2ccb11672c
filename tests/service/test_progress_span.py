"""The one progress shape (`fpscan.service.progress`): ``progress(fraction, stage)`` and
``span(progress, lo, hi)``, which maps a part's [0, 1] onto [lo, hi] of the outer callback
-- nested spans compose, fractions are clamped, fraction 1 lands on ``hi`` exactly, a
kernel's one-argument ``progress(fraction)`` reports the span's stage, and no callback
gives no span. Then the callers that use it: the dispatch with autofocus and the
per-wavelength loop report their parts over the ranges their docstrings state."""
from __future__ import annotations

import doctest

import numpy as np
import pytest

from fpscan.service import progress as progress_module
from fpscan.service.progress import DEFAULT_STAGE, Span, rising, span


def _recorder():
    seen: list[tuple[float, str]] = []
    return seen, lambda f, stage: seen.append((f, stage))


def test_span_maps_its_part_onto_the_outer_range():
    seen, outer = _recorder()
    part = span(outer, 0.2, 0.9)
    for f in (0.0, 0.25, 0.5, 1.0):
        part(f, "reconstructing")
    assert [s for _, s in seen] == ["reconstructing"] * 4
    assert [f for f, _ in seen] == pytest.approx([0.2, 0.2 + 0.7 * 0.25, 0.55, 0.9], abs=1e-15)
    assert seen[-1][0] == 0.9  # exactly hi: a later report at hi ("writing" 0.9) is not a step back


@pytest.mark.parametrize(("lo", "hi"), [(0.2, 0.9), (0.1, 0.95), (0.0, 0.05), (1 / 3, 2 / 3), (0.3, 0.75)])
def test_fraction_one_is_hi_and_the_fractions_never_fall(lo, hi):
    seen, outer = _recorder()
    part = span(outer, lo, hi)
    for f in np.linspace(0.0, 1.0, 101):
        part(float(f))
    fractions = [f for f, _ in seen]
    assert fractions[0] == lo and fractions[-1] == hi
    assert all(b >= a for a, b in zip(fractions, fractions[1:])), fractions
    assert all(lo <= f <= hi for f in fractions)


def test_nested_spans_compose():
    seen, outer = _recorder()
    # a job's reconstruction [0.2, 0.9] > the second of four wavelengths > tv's warm start [0, 0.05]
    wavelength = span(span(outer, 0.2, 0.9), 0.25, 0.5, suffix=" (wavelength 2/4)")
    warm = span(wavelength, 0.0, 0.05, "warm start")
    warm(0.0)
    warm(1.0)
    wavelength(1.0, "iteration 3/3")
    expected = [0.2 + 0.7 * 0.25, 0.2 + 0.7 * (0.25 + 0.25 * 0.05), 0.2 + 0.7 * 0.5]
    assert [f for f, _ in seen] == pytest.approx(expected, abs=1e-12)
    assert [s for _, s in seen] == ["warm start (wavelength 2/4)", "warm start (wavelength 2/4)",
                                    "iteration 3/3 (wavelength 2/4)"]


def test_fractions_outside_zero_one_are_clamped():
    seen, outer = _recorder()
    part = span(outer, 0.5, 1.0, "autofocus")
    part(-0.5)
    part(7.0)
    assert seen == [(0.5, "autofocus"), (1.0, "autofocus")]
    with pytest.raises(ValueError, match="nan"):
        part(float("nan"))


def test_the_one_argument_form_reports_the_spans_stage():
    seen, outer = _recorder()
    span(outer, 0.0, 1.0)(0.5)  # a kernel's progress(fraction), no stage given anywhere
    span(outer, 0.0, 1.0, "warm start")(0.5)
    span(outer, 0.0, 1.0, "warm start")(0.5, "norm estimate")  # the caller's stage wins
    assert [s for _, s in seen] == [DEFAULT_STAGE, "warm start", "norm estimate"]


def test_no_callback_gives_no_span_and_bad_ranges_are_refused():
    assert span(None, 0.0, 0.5) is None
    assert span(None, 0.2, 0.9, "autofocus", suffix=" (wavelength 1/2)") is None
    seen, outer = _recorder()
    assert isinstance(span(outer, 0.0, 1.0), Span)
    for lo, hi in [(0.6, 0.5), (-0.1, 0.5), (0.5, 1.2), (float("nan"), 0.5)]:
        with pytest.raises(ValueError, match="lo <= hi"):
            span(outer, lo, hi)
        with pytest.raises(ValueError, match="lo <= hi"):
            span(None, lo, hi)  # refused alike with or without a listener
    assert seen == []


def test_whatever_the_outer_callback_raises_passes_through():
    class Stop(Exception):
        pass

    def cancel(f, stage):
        raise Stop(stage)

    with pytest.raises(Stop, match="iteration 1/5"):
        span(span(cancel, 0.1, 0.9), 0.0, 0.5)(0.3, "iteration 1/5")


def test_a_kernels_spans_pass_on_strictly_rising_fractions_only():
    """A kernel's steps report through spans of ``rising(progress)``: the kernel's own
    one-argument callback sees each fraction once, in strictly increasing order, even where a
    step ends at the fraction the next one starts from, and a cancel still passes through."""
    seen: list[float] = []
    kernel = rising(seen.append)
    kernel(0.1)
    first = span(kernel, 0.1, 0.3)
    for k in range(5):  # a step starting at its lo (no rise), ending at its hi
        first(k / 4)
    kernel(0.3)  # the step's end, said again by the kernel: no rise
    second = span(kernel, 0.3, 1.0)
    second(-1.0)  # clamped to lo: no rise
    second(0.5)
    second(0.4)  # a step back: not passed on
    kernel(1.0)
    assert seen == sorted(set(seen)) and seen[0] == 0.1 and seen[-1] == 1.0
    assert seen == pytest.approx([0.1, 0.15, 0.2, 0.25, 0.3, 0.65, 1.0])
    assert rising(None) is None and span(rising(None), 0.0, 0.5) is None

    class Stop(Exception):
        pass

    def cancel(f):
        raise Stop(f)

    with pytest.raises(Stop):
        span(rising(cancel), 0.2, 0.4)(0.5)


def test_module_examples_run():
    result = doctest.testmod(progress_module, optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0 and result.failed == 0


def _grid(seed=0):
    from fpscan.service.recon.dataset import GridDataset

    rng = np.random.default_rng(seed)
    return GridDataset(data=rng.standard_normal((24, 7)), dx=1e-4, dt=2e-8, sound_speed=1500.0)


def test_autofocus_reports_its_search_then_the_reconstruction():
    from fpscan.service.pipeline import reconstruct

    seen, outer = _recorder()
    reconstruct(_grid(), "ner", sound_speed="auto", progress=span(outer, 0.2, 0.9))
    fractions = [f for f, _ in seen]
    assert all(b >= a for a, b in zip(fractions, fractions[1:])), seen
    search = [f for f, s in seen if s == "autofocus"]
    final = [f for f, s in seen if s == "reconstructing"]
    assert search and final and {s for _, s in seen} == {"autofocus", "reconstructing"}
    # the search over [0, 0.5] of the dispatch's range, the final reconstruction the rest
    assert 0.2 < min(search) and max(search) <= 0.2 + 0.7 * 0.5 + 1e-12
    assert min(final) == pytest.approx(0.2 + 0.7 * 0.5) and final[-1] == 0.9


def test_wavelengths_share_the_range_and_name_themselves():
    from fpscan.service.pipeline import method_options, reconstruct
    from fpscan.service.spectral import reconstruct_wavelengths

    seen, outer = _recorder()
    reconstruct_wavelengths([_grid(1), _grid(2), _grid(3)], "ner", reconstruct=reconstruct, options=method_options("ner"),
                            progress=outer)
    fractions = [f for f, _ in seen]
    assert fractions[0] == 0.0 and fractions[-1] == 1.0
    assert all(b >= a for a, b in zip(fractions, fractions[1:])), seen
    for k in range(3):
        mine = [f for f, s in seen if s == f"reconstructing (wavelength {k + 1}/3)"]
        assert mine[0] == pytest.approx(k / 3) and mine[-1] == pytest.approx((k + 1) / 3), (k, mine)


def test_forward_never_steps_back_in_fraction_or_stage():
    """`forward`: a lower fraction is reported as the highest so far; a stage of a kind left
    behind comes back only with a rise of the fraction (the next wavelength's new work), else the
    current stage is said again; every report is passed on, so a cancel raised there is heard."""
    from fpscan.service.progress import Forward, IterationStage, forward

    seen, outer = _recorder()
    report = forward(outer)
    assert isinstance(report, Forward) and forward(report) is report and forward(None) is None
    report(0.2, "reconstructing")
    report(0.5, IterationStage(9, 100))
    report(0.4, IterationStage(10, 100))  # a step back in fraction: raised to 0.5
    report(0.9, "converged after 10 iterations (wavelength 1/2)")
    report(0.9, "reconstructing")  # the dispatch's closing stage, no progress: not a step back
    report(0.9, "writing")
    report(0.95, "warm start (wavelength 2/2)")
    report(0.96, "converged after 10 iterations (wavelength 2/2)")  # left behind, but new work: it rose
    assert seen == [(0.2, "reconstructing"), (0.5, "iteration 9/100"), (0.5, "iteration 10/100"),
                    (0.9, "converged after 10 iterations (wavelength 1/2)"),
                    (0.9, "converged after 10 iterations (wavelength 1/2)"), (0.9, "writing"),
                    (0.95, "warm start (wavelength 2/2)"), (0.96, "converged after 10 iterations (wavelength 2/2)")]
    assert isinstance(seen[2][1], IterationStage) and seen[2][1].k == 10  # the stage itself, its numbers kept

    class Stop(Exception):
        pass

    def cancel(f, stage):
        raise Stop(stage)

    guarded = forward(cancel)
    with pytest.raises(Stop, match="iteration 1/5"):
        guarded(0.3, "iteration 1/5")


def test_a_tv_reconstruction_ends_on_its_outcome_not_on_the_dispatchs_stage():
    """`reconstruct` with tv: once tv said how it ended ("converged after k iterations" or
    "stopped after ..."), the dispatch's closing report at the same fraction keeps that stage
    (it said "reconstructing" there, a step back); fractions never fall."""
    from fpscan.physics.forward import forward_grid
    from fpscan.service.pipeline import reconstruct
    from fpscan.service.recon.dataset import GridDataset

    p0 = np.zeros((12, 16))
    p0[5:8, 7:10] = 1.0
    g = forward_grid(p0, dx=1e-4, dz=1e-4, dt=1e-4 / 1500, n_t=24, c=1500.0)
    seen, outer = _recorder()
    reconstruct(GridDataset(g, dx=1e-4, dt=1e-4 / 1500, sound_speed=1500.0), "tv", n_z=12, max_iter=6,
                progress=span(outer, 0.2, 0.9))
    stages = [s for _, s in seen]
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions) and fractions[-1] == 0.9, seen
    ended = [i for i, s in enumerate(stages) if s.startswith(("converged after", "stopped after", "iteration 6/6"))]
    assert ended and all(not s.startswith("reconstructing") for s in stages[ended[0]:]), stages
    assert stages[-1].startswith(("converged after", "stopped after", "iteration 6/6")), stages
