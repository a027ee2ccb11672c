"""tv's stopping rule and its ETA, judged again from traced runs without running tv again.

`bench_tv_matrix.py --rule --json FILE` keeps, per row, the trace of a run to 300 iterations at
tv's λ and grid (``tol`` 0: the default run's iterates up to its stop, then on; per iteration its
time, J, the image's change, the rule's value and the CC with p0, `bench_tv_matrix.TRACE_FIELDS`)
and the default run's progress events (`bench_tv_matrix.EVENT_FIELDS`). From them this script
prints:

- **rules**: per row, where each stopping rule of `RULES` stops (iteration, operator pairs) and its
  CC against the 300-iteration image's (Δ = CC after 300 − CC at the stop; the gate asks Δ <= 0.015);
  the default rule's stop is checked against the default run's own;
- **eta**: per row and ``tol``, the end the progress's ETA (`fpscan.service.progress.Eta`, replayed on
  the run's own reports with their times) predicted at 30, 50 and 70 % of the actual end, as the
  error against that end (the target: within 25 % from 30 % on). At the default ``tol`` the reports
  are the default run's; at a ``tol`` given (``--tols``), the set-up's reports are the default run's and
  each iteration's report is made from the trace (its time from the default run's first iteration on,
  the rule's value; the run ends where that ``tol``'s rule stops it, or at ``--max-iter``, today's
  default ``max_iter`` unless told: the replay of a run made under another cap).

    .venv/bin/python benchmarks/tv_traces.py FILE.jsonl [FILE ...] [--tols 0.005 0.0025] [--max-iter N]
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

#: the share of the actual end at which the ETA's predicted end is read
AT = (0.3, 0.5, 0.7)


def load(paths: list[Path]) -> list[dict]:
    """The rows of the JSON-lines files, the last of each (case, mask, noise, seed) kept."""
    rows: dict[tuple, dict] = {}
    for path in paths:
        for line in path.read_text().splitlines():
            r = json.loads(line)
            rows[(r["case"], r["mask"], r["noise"], r.get("seed", 0))] = r
    return list(rows.values())


def armed_at(row: dict) -> int:
    """The first iteration at which the default rule can stop the run (λ's continuation + the
    window), from the default run's progress events."""
    for e in reversed(row.get("events", [])):
        if e[7] is not None:
            return int(e[7])
    raise ValueError(f"{row['case']}: no progress event says when the rule can stop the run")


def window_rule(tol: float, window: int = 3) -> Callable[[dict], int | None]:
    """The rule ``tol`` on the largest image change of the last ``window`` iterations at λ (tv's rule
    at ``window`` 3): the iteration it stops at, None where it does not stop within the trace."""
    def stop(row: dict) -> int | None:
        first = armed_at(row) - 3 + window  # λ's continuation, then a window at λ
        changes = {t[0]: t[3] for t in row["trace"]}
        for k in sorted(changes):
            if k >= first and all(changes.get(j, math.inf) < tol for j in range(k - window + 1, k + 1)):
                return k
        return None
    return stop


def creeping_rule(tol: float, near: float = 2.0, span: int = 10, fall: float = 0.15) -> Callable[[dict], int | None]:
    """tv's rule at ``tol``, or where the rule's value is below ``near`` × ``tol`` and has fallen by
    less than ``fall`` of itself over the last ``span`` iterations (an image change that creeps down
    without reaching ``tol``)."""
    base = window_rule(tol)

    def stop(row: dict) -> int | None:
        first = armed_at(row)
        rule = {t[0]: t[4] for t in row["trace"]}
        k_base = base(row)
        for k in sorted(rule):
            if k_base is not None and k >= k_base:
                return k_base
            if k >= first + span and rule[k] is not None and rule.get(k - span) is not None \
                    and rule[k] < near * tol and rule[k] > (1 - fall) * rule[k - span]:
                return k
        return k_base
    return stop


#: the rules judged: name -> (row -> the iteration it stops at)
RULES: dict[str, Callable[[dict], int | None]] = {
    "tol 5e-3, window 3 (default)": window_rule(5e-3),
    "tol 3.5e-3, window 3": window_rule(3.5e-3),
    "tol 2.5e-3, window 3": window_rule(2.5e-3),
    "tol 5e-3, window 5": window_rule(5e-3, 5),
    "tol 5e-3, window 8": window_rule(5e-3, 8),
    "tol 5e-3, or creeping below 2 tol": creeping_rule(5e-3),
}


def print_rules(rows: list[dict]) -> None:
    """The rules' table (module doc)."""
    print("| row | default run: iterations, CC | 300 it CC | " + " | ".join(RULES) + " |")
    print("|---|---|---|" + "---|" * len(RULES))
    worst = {name: -math.inf for name in RULES}
    passed = {name: 0 for name in RULES}
    for r in rows:
        if "trace" not in r:
            continue
        cc = {t[0]: t[5] for t in r["trace"]}
        extra = r["pairs"] - r["iterations"]  # the set-up's operator pairs
        cells = []
        for name, rule in RULES.items():
            k = rule(r)
            if k is None:
                cells.append("no stop")
                continue
            gap = r["cc300"] - cc[k]
            worst[name] = max(worst[name], gap)
            passed[name] += gap <= 0.015
            cells.append(f"{k} ({k + extra:g} pairs) {cc[k]:.4f}, Δ {gap:+.4f}")
        k_rule = RULES["tol 5e-3, window 3 (default)"](r)
        check = ("" if k_rule == r["iterations"] else " (at its cap: the rule stops later)"
                 if r.get("stop") == "iterations" and (k_rule is None or k_rule > r["iterations"]) else " (trace's stop differs!)")
        print(f"| {r['case']} {r['mask']} % {r['noise']} | {r['iterations']}, {r['tv']:.4f}{check} | "
              f"{r['cc300']:.4f} | " + " | ".join(cells) + " |")
    n = sum("trace" in r for r in rows)
    print("| within 0.015 (largest Δ) | | | " + " | ".join(f"{passed[k]} of {n} ({worst[k]:+.4f})" for k in RULES) + " |")


def reports(row: dict, tol: float | None, max_iter: int | None = None) -> tuple[list[tuple[float, float, object]], float]:
    """The run's progress reports (seconds, fraction, stage) at ``tol`` (None: the default run's own)
    and its end, s; at a ``tol`` given, the run stops at ``max_iter`` at the latest (default: today's
    `DEFAULT_MAX_ITER`)."""
    from fpscan.service.progress import IterationStage
    from fpscan.service.recon.limits import DEFAULT_MAX_ITER
    from fpscan.service.recon.tv.stopping import typical_stop

    events = row["events"]
    floored = bool(row.get("floored"))  # the reach floor set λ (rows from before it have no such key)
    if tol is None:  # each iteration's stage as tv makes it now (its typical stop from today's rule)
        made = [(e[0], e[1], e[2] if e[3] is None else
                 IterationStage(e[3], e[4], e[5], e[6], armed=e[7] is None or e[3] >= e[7], armed_at=e[7], text=e[2],
                                typical_stop=None if e[7] is None or not e[6] else typical_stop(e[6], e[7], floored)))
                for e in events]
        return made, row["tv_s"]
    setup = [(e[0], e[1], e[2]) for e in events if e[3] is None and e[1] < 0.1 + 1e-9]
    at = armed_at(row)
    n = int(max_iter or DEFAULT_MAX_ITER)
    stop = window_rule(tol)(row)
    stop = n if stop is None or stop > n else stop
    if stop > row["trace"][-1][0]:
        raise ValueError(f"{row['case']}: tol {tol} does not stop within the trace")
    made = list(setup)
    # the trace's iterations from the default run's first one on (the traced run's set-up is shorter:
    # the geometry's figures were kept from the default run's)
    first = next(e[0] for e in events if e[3] is not None)
    shift = first - row["trace"][0][1]
    for t in row["trace"]:
        k, s, _, _, rule, _ = t
        made.append((s + shift, 0.1 + 0.9 * k / n, IterationStage(k, n, rule, tol, armed=k >= at, armed_at=at,
                                                                  typical_stop=typical_stop(tol, at, floored))))
        if k == stop:
            break
    return made, made[-1][0]


def shown_ends(made: list, make_eta: Callable) -> list[tuple[float, float | None]]:
    """Per report, its time and the time left that the ETA showed (None: no figure)."""
    clock = [0.0]
    eta = make_eta(lambda: clock[0])
    shown: list[tuple[float, float | None]] = []
    for s, fraction, stage in made:
        clock[0] = s
        shown.append((s, eta(fraction, stage)))
    return shown


def worst_error(made: list, end: float, make_eta: Callable, share: float = AT[0]) -> float | None:
    """The largest error of the predicted end against ``end`` over every report from ``share`` of
    the run on (the target's "from 30 % of a tv run onward"); None where no figure was shown then."""
    errors = [abs(s + left - end) / end for s, left in shown_ends(made, make_eta)
              if s >= share * end and left is not None]
    return max(errors, default=None)


def eta_errors(made: list, end: float, make_eta: Callable) -> list[float | None]:
    """The predicted end's error against ``end`` at each share `AT` of it (None: no ETA shown yet)."""
    shown = shown_ends(made, make_eta)
    out: list[float | None] = []
    for share in AT:
        before = [(s, left) for s, left in shown if s <= share * end]
        if not before or before[-1][1] is None:
            out.append(None)
            continue
        s, left = before[-1]
        out.append((s + left - end) / end)
    return out


def print_eta(rows: list[dict], tols: list[float | None], max_iter: int | None = None) -> None:
    """The ETA's table (module doc)."""
    from fpscan.service.progress import Eta

    print("\n| row | tol | iterations (first possible stop) | end, s | predicted end's error at 30 / 50 / 70 % | "
          "largest from 30 % on | without the typical stop |")
    print("|---|---|---|---|---|---|---|")
    met = met_before = total = 0
    worst_all: list[float] = []
    for r in rows:
        if "events" not in r:
            continue
        for tol in tols:
            if tol is not None and "trace" not in r:
                continue
            try:
                made, end = reports(r, tol, max_iter)
            except ValueError as exc:
                print(f"| {r['case']} | {tol} | {exc} | | |")
                continue
            errors = eta_errors(made, end, lambda clock: Eta(clock=clock))
            worst = worst_error(made, end, lambda clock: Eta(clock=clock))
            worst_all += [] if worst is None else [worst]
            # the same reports without the method's typical stop: the ETA that extends the rule's fall alone
            plain = [(s, f, st._with(typical_stop=None) if hasattr(st, "typical_stop") else st) for s, f, st in made]
            before = eta_errors(plain, end, lambda clock: Eta(clock=clock))
            last = [st for _, _, st in made if getattr(st, "k", None) is not None][-1]
            ok = all(e is not None and abs(e) <= 0.25 for e in errors)
            ok_before = all(e is not None and abs(e) <= 0.25 for e in before)
            met, met_before, total = met + ok, met_before + ok_before, total + 1
            cells = " / ".join("-" if e is None else f"{e:+.0%}" for e in errors)
            cells_before = " / ".join("-" if e is None else f"{e:+.0%}" for e in before)
            print(f"| {r['case']} {r['mask']} % {r['noise']} | {tol or 'default'} | {last.k} ({armed_at(r)}) | "
                  f"{end:.1f} | {cells}{'' if ok else ' ✗'} | {'-' if worst is None else f'{worst:.0%}'} | "
                  f"{cells_before}{'' if ok_before else ' ✗'} |")
    print(f"\nwithin 25 % at 30, 50 and 70 %: {met} of {total} ({met_before} without the typical stop; "
          "\"-\": no figure shown, one under 5 s hidden after 5 s)")
    if worst_all:
        ranked = sorted(worst_all)
        print(f"largest error from 30 % on: {ranked[-1]:.0%} (median {statistics.median(ranked):.0%}); "
              f"within 25 % on {sum(w <= 0.25 for w in ranked)}, within 40 % on {sum(w <= 0.40 for w in ranked)} "
              f"of {len(ranked)}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+", type=Path)
    ap.add_argument("--tols", nargs="+", type=float, default=[], help="also replay the ETA at these tol")
    ap.add_argument("--max-iter", type=int, default=None,
                    help="the replays' iteration cap at --tols (default: today's DEFAULT_MAX_ITER)")
    args = ap.parse_args(argv)
    rows = load(args.files)
    print_rules(rows)
    print_eta(rows, [None, *args.tols], args.max_iter)
    return 0


if __name__ == "__main__":
    sys.exit(main())
