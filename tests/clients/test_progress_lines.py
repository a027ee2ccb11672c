"""Progress a person reads without a terminal: `fpscan recon` writes a line per report (period
0) with stage, % and ETA, in order; the lines repeat every period between reports; a client
that joins a running job reports its stages in the order the job made them (no stale later
stage first). Oracles: the command's own stderr through a pipe, a real ``fpscan serve``."""
from __future__ import annotations

import io
import re
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from tests.clients.clients_servers import clean_env
from tests.waits import HANG_S

TOKEN = "progress-test-token"
LINE = re.compile(r"^recon tv: (?P<stage>[a-z][a-z ]*(?: \d+/\d+)?)  (?P<pct>\d+)%(?P<rest>.*)$")


def test_recon_progress_lines_off_a_terminal(tmp_path):
    """A small tv job with stderr piped (not a terminal) and FPSCAN_PROGRESS_PERIOD=0:
    several lines, stages in order, percentages non-decreasing, the iterations counted
    up, an ETA once the rate is known."""
    rng = np.random.default_rng(0)
    np.save(tmp_path / "in.npy", rng.standard_normal((64, 16)).astype(np.float32))
    res = subprocess.run(
        [sys.executable, "-m", "fpscan", "recon", str(tmp_path / "in.npy"), "--dt", "20ns", "--dx", "30um",
         "--method", "tv", "--iterations", "8", "--n-z", "16", "--out", str(tmp_path / "out")],
        capture_output=True, text=True, timeout=300, env=clean_env(FPSCAN_PROGRESS_PERIOD="0"))
    assert res.returncode == 0, res.stderr
    print(res.stderr)
    lines = [m for m in map(LINE.match, res.stderr.splitlines()) if m]
    assert len(lines) >= 8, res.stderr
    pcts = [int(m["pct"]) for m in lines]
    assert pcts == sorted(pcts) and pcts[0] == 0 and pcts[-1] == 100, pcts
    iterations = [int(m["stage"].split()[1].split("/")[0]) for m in lines if m["stage"].startswith("iteration")]
    assert len(iterations) >= 3 and iterations == sorted(iterations), iterations
    assert any(re.search(r"ETA \d\d:\d\d", m["rest"]) for m in lines), res.stderr
    assert "\x1b[" not in res.stderr  # no terminal control codes in a log


class _Log(io.StringIO):
    """A log stream (not a terminal) that a reader thread may poll."""

    def isatty(self) -> bool:
        return False


def test_progress_lines_repeat_every_period_between_reports():
    """One report, then silence (a long step): the line comes again every period, so a log
    shows the job is alive; the ETA it had counts down, never up."""
    from fpscan.clients.cli.common import ProgressBar

    log = _Log()
    with ProgressBar("recon tv", stream=log, period=0.05) as bar:
        bar({"stage": "iteration 3/60", "fraction": 0.3, "eta_s": 100.0})
        deadline = time.monotonic() + HANG_S
        while log.getvalue().count("\n") < 4 and time.monotonic() < deadline:
            time.sleep(0.01)
    lines = log.getvalue().splitlines()
    assert len(lines) >= 4 and all(line.startswith("recon tv: iteration 3/60  30%") for line in lines), lines
    etas = [int(m[1]) * 60 + int(m[2]) for m in (re.search(r"ETA (\d\d):(\d\d)", line) for line in lines) if m]
    assert len(etas) == len(lines) and etas == sorted(etas, reverse=True), lines


def test_a_complete_state_is_said_once():
    """A scan at every point done (its job still wrapping up: the final live
    preview) is one line, not one every period; a witness bar beside it, same period, shows
    that several periods passed (its unfinished line came again three times)."""
    from fpscan.clients.cli.common import ProgressBar

    done_log, witness_log = _Log(), _Log()
    with ProgressBar("scan", stream=done_log, period=0.05) as done, \
            ProgressBar("recon", stream=witness_log, period=0.05) as witness:
        done({"stage": "scanning", "fraction": 1.0, "points_done": 1013, "points_total": 1013})
        witness({"stage": "reconstructing", "fraction": 0.5})
        deadline = time.monotonic() + HANG_S
        while witness_log.getvalue().count("\n") < 4 and time.monotonic() < deadline:
            time.sleep(0.01)
    assert witness_log.getvalue().count("\n") >= 4
    lines = done_log.getvalue().splitlines()
    assert lines == ["scan: scanning  100%  1013/1013 points"], lines


def test_progress_period_from_the_environment(monkeypatch):
    from fpscan.clients.cli.common import PROGRESS_PERIOD_S, progress_period

    monkeypatch.delenv("FPSCAN_PROGRESS_PERIOD", raising=False)
    assert progress_period() == PROGRESS_PERIOD_S
    monkeypatch.setenv("FPSCAN_PROGRESS_PERIOD", "0.5")
    assert progress_period() == 0.5
    for bad in ("-1", "soon", "nan"):
        monkeypatch.setenv("FPSCAN_PROGRESS_PERIOD", bad)
        with pytest.raises(ValueError, match="FPSCAN_PROGRESS_PERIOD"):
            progress_period()


def test_wait_joining_a_running_job_reports_stages_in_order(server, tmp_path):
    """``Client.wait`` started while a tv job iterates: the first progress it reports is the
    job's first stage, never the current one before the earlier ones (the demo's stale
    ``writing 90%`` before ``starting 0%``); fractions never go back."""
    from fpscan.clients.http import Client

    rng = np.random.default_rng(1)
    np.save(tmp_path / "in.npy", rng.standard_normal((128, 24)).astype(np.float32))
    with Client(server, token=TOKEN) as api, Client(server, token=TOKEN) as control:
        ds = api.upload_dataset(tmp_path / "in.npy", "npy", dt=20e-9, dx=30e-6)
        # tol 0: no stopping rule, so the job iterates until it is cancelled (with the default rule
        # it may converge, and succeed, before the cancel arrives: CI under load did so once)
        job_id = api.start_reconstruction(dataset_id=ds, method="tv", params={"iterations": 10000, "n_z": 64, "tol": 0})
        deadline = time.monotonic() + HANG_S
        while not str(api.get_job(job_id).progress.stage or "").startswith("iteration"):
            assert time.monotonic() < deadline, api.get_job(job_id)
            time.sleep(0.05)
        seen: list[dict] = []
        cancelled = threading.Event()

        def on_progress(p: dict) -> None:
            seen.append(p)
            if str(p.get("stage", "")).startswith("iteration") and not cancelled.is_set():
                cancelled.set()  # seen iterating: end the job (it would run for minutes)
                control.cancel_job(job_id)

        job = api.wait(job_id, on_progress=on_progress, timeout=120, raise_on_failure=False)
    assert job.state == "cancelled"
    stages = [p.get("stage") for p in seen]
    fractions = [p["fraction"] for p in seen if p.get("fraction") is not None and p.get("stage") != "cancelled"]
    assert stages[0] in ("starting", "loading"), stages
    assert fractions == sorted(fractions), list(zip(stages, fractions))


def test_eta_of_iterations_moves_at_most_twofold_and_follows_the_measured_rate():
    """``fpscan.service.progress.Eta`` fed as a tv solve reports (a clock of the test's own) whose
    stopping rule does not fall (so the iteration limit is what ends it): no
    estimate in the set-up stages nor before two iterations are measured; then (n - k) times
    the measured time per iteration at a steady rate (the oracle), never more than 2x away
    from the previous estimate counted down by the time since (iterations 2x and 0.25x as
    long as before, a 10x slower stretch), and back on the new rate's figure after it."""
    from fpscan.service.progress import Eta, IterationStage

    now = [0.0]
    eta = Eta(clock=lambda: now[0])
    for f, stage in ((0.0, "warm start"), (0.03, "warm start"), (0.06, "norm estimate"), (0.1, "norm estimate")):
        now[0] += 30.0  # a long set-up: its fractions say nothing of the iterations' cost
        assert eta(f, stage) is None
    n = 200
    steps = [1.0] * 20 + [2.0, 0.25] * 5 + [10.0] * 30 + [1.0] * 60
    shown: list[tuple[int, float, float]] = []  # (k, when, estimate)
    for k, step in enumerate(steps, start=1):
        now[0] += step
        e = eta(0.1 + 0.9 * k / n, IterationStage(k, n, rule=0.5, tol=5e-3))
        if k < 3:
            assert e is None, k  # the first interval carries set-up work: two measured first
            continue
        assert e is not None
        if shown:
            _, t, before = shown[-1]
            expected = max(before - (now[0] - t), 1.0)
            assert expected / 2 - 1e-9 <= e <= 2 * expected + 1e-9, (k, before, e)
        shown.append((k, now[0], e))
    assert shown[10][2] == pytest.approx((n - shown[10][0]) * 1.0)  # steady 1 s per iteration
    k, _, last = shown[-1]
    assert last == pytest.approx((n - k) * 1.0, rel=0.05)  # the rate after the slow stretch, measured again


def test_eta_of_fast_iterations_never_exceeds_the_time_to_the_iteration_limit():
    """Iterations of 10 ms near the limit: the smoothing's floor (half of at least a second)
    never lifts the estimate above :attr:`Eta.limit_s`, the time the iterations left take at the
    measured rate (a server tv job showed ``eta_s`` 0.5 beside ``eta_max_s`` 0.3)."""
    from fpscan.service.progress import Eta, IterationStage

    now, n = [0.0], 20
    eta = Eta(clock=lambda: now[0])
    seen = 0
    for k in range(1, n + 1):
        now[0] += 0.01
        e = eta(k / n, IterationStage(k, n, rule=0.5, tol=5e-3))
        if e is not None:
            seen += 1
            assert 0 <= e <= eta.limit_s == pytest.approx((n - k) * 0.01), (k, e, eta.limit_s)
            assert eta.bound_iterations == n - k
    assert seen == n - 2


def test_eta_of_iterations_is_the_time_to_the_stopping_rule_bounded_by_the_limit():
    """An image change falling geometrically (tenfold every 5 iterations) reaches
    the tolerance at an iteration the oracle computes (log(tol/value)/log(q)); the ETA is that
    many iterations x the measured time per iteration, labelled an estimate, with the iterations
    left to the iteration limit as its bound; the line shows the tolerance (also while λ falls,
    with the iteration from which the rule can stop)."""
    import math

    from fpscan.clients.cli.common import describe_progress
    from fpscan.service.progress import Eta, IterationStage, iteration_fields

    now, n, tol, q = [0.0], 100, 1e-3, 10 ** (-1 / 5)
    eta = Eta(clock=lambda: now[0])
    for k in range(1, 11):
        now[0] += 2.0  # 2 s per iteration
        stage = IterationStage(k, n, rule=0.5 * q ** k, tol=tol)
        e = eta(k / n, stage)
    to_rule = math.log(tol / (0.5 * q ** 10)) / math.log(q)  # 3.5 iterations after iteration 10
    assert e == pytest.approx(to_rule * 2.0, rel=1e-6) and eta.basis == "stopping rule"
    assert eta.bound_iterations == n - 10 and eta.limit_s == pytest.approx((n - 10) * 2.0)
    line = describe_progress({"stage": str(stage), **iteration_fields(stage), "eta_s": e, "eta_max_s": eta.limit_s,
                              "iterations_left_max": eta.bound_iterations, "eta_basis": eta.basis})
    assert "image change 0.005 (stops below 0.001)" in line, line
    assert "ETA ~00:07 (estimate: stopping rule; at most 90 more iterations, ~03:00 at the current rate)" in line, line
    from fpscan.service.recon.methods import get

    waiting = IterationStage(3, n, rule=0.2, tol=tol, armed=False,  # tv while λ still falls: its words
                             waits_for=get("tv").stop_waits_for, armed_at=53)
    fields = iteration_fields(waiting)
    assert fields["stop_tol"] == tol and fields["stop_armed"] is False and fields["stop_armed_at"] == 53
    assert "(stops below 0.001 once λ has settled, from iteration 53)" in describe_progress(
        {"stage": str(waiting), **fields})


def test_a_local_tv_run_ends_on_its_outcome(tmp_path):
    """`fpscan recon --method tv` on noiseless data: the bar's last line is how the solve
    ended (not "reconstructing"), and the last line on stdout says converged or not, the
    iterations, λ = 0 with its reason (the data show no noise) and the residual against the
    noise; the ETA appears only once iterations are measured, never in the set-up stages."""
    from fpscan.physics.balls import Ball, ball_alines

    n, n_t, pitch, dt = 16, 96, 1e-4, 2e-8
    x = (np.arange(n) - (n - 1) / 2) * pitch
    alines = ball_alines(np.stack([x], axis=1), [Ball(x=0.0, y=0.0, z=0.6e-3, radius=1.5e-4, amplitude=1.0)],
                         dt, n_t, 1500.0)
    np.save(tmp_path / "clean.npy", alines.T.astype(np.float32))
    res = subprocess.run(
        [sys.executable, "-m", "fpscan", "recon", str(tmp_path / "clean.npy"), "--dt", "20ns", "--dx", "100um",
         "--method", "tv", "--iterations", "30", "--n-z", "32", "--out", str(tmp_path / "out")],
        capture_output=True, text=True, timeout=HANG_S, env=clean_env(FPSCAN_PROGRESS_PERIOD="0"))
    assert res.returncode == 0, res.stderr
    bar = [line for line in res.stderr.splitlines() if line.startswith("recon tv: ")]
    last = res.stdout.strip().splitlines()[-1]
    assert re.fullmatch(r"recon tv: (converged after \d+ iterations|not converged: stopped at the iteration limit, "
                        r"30 of 30 iterations)  100%", bar[-1]), bar[-3:]
    assert re.match(r"tv: (converged after \d+ iterations|not converged: stopped at the iteration limit, 30 of 30 "
                    r"iterations) \(image change \S+ [<≥>=]+ 0\.005\); λ 0 \(automatic\): the data show no noise", last), last
    assert "; residual " in last and "% of the data, noise 0 %" in last, last
    assert not any("ETA" in line for line in bar if line.startswith(("recon tv: warm start", "recon tv: norm"))), bar
    counted = [(int(m[1]), line) for line in bar if (m := re.match(r"recon tv: iteration (\d+)/30", line))]
    assert len(counted) >= 3 and all(("ETA" in line) == (k >= 3) for k, line in counted), counted


def test_eta_counts_the_iterations_before_the_rule_can_stop():
    """tv's λ continuation: the rule cannot stop the run before iteration 53 (``armed_at``), while
    the image change falls below the tolerance from iteration 30 (a server tv job showed "ETA
    ~00:01" for 26 s while waiting). At 1.3 s per iteration and the stop at 53 (the oracle: the
    change is below tol there), every estimate from iteration 5 on puts the end within 5 % of the
    actual end, and none is under the certain iterations' time."""
    from fpscan.service.progress import Eta, IterationStage

    now, n, tol, armed_at, step = [0.0], 100, 5e-3, 53, 1.3
    eta = Eta(clock=lambda: now[0])
    end = armed_at * step
    for k in range(1, armed_at):  # the run stops at armed_at's report
        now[0] = k * step
        e = eta(k / n, IterationStage(k, n, rule=0.2 / k**1.2, tol=tol, armed=k >= armed_at, armed_at=armed_at))
        if k >= 5:
            assert e is not None and e >= (armed_at - k) * step - 1e-9, (k, e)
            assert abs(now[0] + e - end) <= 0.05 * end, (k, e, now[0] + e, end)


def test_eta_takes_the_typical_stop_while_the_rule_is_far_from_its_tolerance():
    """A run whose rule behaves as tv's image change does on a sparse scan: it falls fast while λ
    falls (to iteration 12), stalls at 4× the tolerance until iteration 40, then falls tenfold every
    8 iterations and the run stops at iteration 47 (the oracle: the first iteration whose window of
    3 values is below the tolerance). 1 s per iteration. Given the method's typical stop (iteration
    48, ``typical_stop``), each estimate while the value is far from the tolerance is the one the
    documented rule gives, max(typical, (1 + `PAST_SHARE`) k) (the typical stop, and once past it a
    share of the iterations run), and up to iteration 32 the end it predicts is within 5 % of the
    actual end; without it, the fall fitted while λ falls puts the end at the rule's first possible
    stop, more than half the run early."""
    from fpscan.service.progress import PAST_SHARE, Eta, IterationStage

    n, tol, armed_at, typical = 100, 5e-3, 15, 48

    def value(k: int) -> float:  # the rule's value: a window's largest change
        if k <= 12:
            return 0.3 * (0.02 / 0.3) ** (k / 12)
        if k <= 40:
            return 4 * tol
        return 4 * tol * 10 ** (-(k - 40) / 8)

    stop = next(k for k in range(armed_at, n) if all(value(j) < tol for j in range(k - 2, k + 1)))
    assert stop == 47

    def ends(with_typical: bool) -> dict[int, float]:
        now = [0.0]
        eta = Eta(clock=lambda: now[0])
        out = {}
        for k in range(1, stop):
            now[0] = float(k)
            e = eta(k / n, IterationStage(k, n, rule=value(k), tol=tol, armed=k >= armed_at, armed_at=armed_at,
                                          typical_stop=typical if with_typical else None))
            if e is not None:  # (a figure under 5 s is hidden after 5 s)
                out[k] = now[0] + e
        return out

    typical_ends = ends(True)
    for k in range(3, 41):  # the value far from the tolerance: the documented rule
        assert typical_ends[k] == pytest.approx(max(typical, (1 + PAST_SHARE) * k)), (k, typical_ends[k])
    assert all(abs(typical_ends[k] - stop) <= 0.05 * stop for k in range(3, 33)), typical_ends
    plain_ends = ends(False)  # the fall's fit alone
    assert max(abs(plain_ends[k] - stop) / stop for k in range(3, 33) if k in plain_ends) > 0.5, plain_ends


def test_an_eta_under_5_s_is_never_shown_for_5_s():
    """A rule that keeps saying it is about to stop (its value flat just above the tolerance) while
    iterations of 1.5 s go on: the estimate stays about one iteration; what is shown (each report's
    and, between reports, the countdown the CLI prints) is under 5 s for less than 5 s at a
    stretch, then nothing until an estimate of 5 s or more."""
    from fpscan.service.progress import Eta, IterationStage

    now, n = [0.0], 100
    eta = Eta(clock=lambda: now[0])
    shown: list[tuple[float, float | None]] = []
    for k in range(1, 41):
        for tick in range(15):  # the countdown every 0.1 s of the 1.5 s iteration
            now[0] = 1.5 * (k - 1) + 0.1 * tick
            shown.append((now[0], eta.read()))
        now[0] = 1.5 * k
        rule = 0.02 / k if k < 10 else 0.00505 - 1e-6 * k  # a fast fall, then flat just above tol
        shown.append((now[0], eta(k / n, IterationStage(k, n, rule=rule, tol=5e-3))))
    low, longest = None, 0.0
    for t, e in shown:
        if e is not None and e < 5:
            low = t if low is None else low
            longest = max(longest, t - low)
        else:
            low = None
    assert any(e is not None and e < 5 for _, e in shown)  # the estimate did go under 5 s
    assert longest < 5, longest
