#!/usr/bin/env bash
# Set up everything from scratch (a virtual environment with fpscan and its test
# dependencies), run the guard rails (ruff, import-linter contracts, mypy; configured in
# pyproject.toml) and then the whole test suite. Any guard-rail error fails the run.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[test]'
# numba's cache of the reconstruction's kernels filled once (`fpscan warmup`: every method, both
# precisions; ~100 s of one core on a fresh clone), beside the set-up steps and the guard rails:
# without it the first tests that reconstruct compiled the same kernels at once in several
# processes (the parallel part, the long files first: 18:26 and 1917 s of CPU cold, 16:56 and
# 1668 s warm; the guard rails alone take ~45 s).
warm_log=$(mktemp)
.venv/bin/fpscan warmup >"$warm_log" 2>&1 &
warm_pid=$!
trap 'kill "$warm_pid" 2>/dev/null || true; rm -f "$warm_log"' EXIT
if [ -x scripts/test-setup.d ] || [ -d scripts/test-setup.d ]; then
  for step in scripts/test-setup.d/*.sh; do [ -e "$step" ] && bash "$step"; done
fi
bash scripts/lint.sh
# a failed warm-up only costs time (the tests compile what they need, and say what fails)
wait "$warm_pid" || echo "fpscan warmup failed; the tests compile the kernels themselves:" >&2
cat "$warm_log" >&2
# Three parts: the tests in parallel on FPSCAN_TEST_WORKERS processes (default 2, one per core of
# the reference machine; 0 runs them in this process), a test file's tests on one worker
# (they share its servers and browser; the 25 slowest are listed), the files marked `long` first,
# longest first (tests/conftest.py; xdist's own order, most tests first, ran a long file last,
# beside an idle core: 18:45 against 16:56 warm); then, alone, the tests marked `serial`, which
# hold a time bound (health p99, cancel latency; docs/performance.md) that a neighbour's load would blur.
# Beside the parallel part, in a lane of their own, the tests marked `waits`: they mostly wait on a
# real clock (the two-minute stream at 1 Hz, the serial link's PRF and timeouts: ~170 s of wall
# time, ~30 s of CPU), which on a test worker held it and its core idle; their output follows the
# parallel part's.
# Arguments go to every part (a part that selects no test counts as passed).
# Bytecode caches on (a caller's PYTHONDONTWRITEBYTECODE=1 made every pytest process parse and
# assertion-rewrite ~450 modules again: collection took 13.7 s of CPU instead of 6.5 s).
unset PYTHONDONTWRITEBYTECODE
# One numba thread per test worker when the workers fill the cores: numba's OpenMP threads
# spin-wait, and 2 workers x 2 threads on 2 cores spent their time waiting for each other
# (the two tv test files on 2 workers, machine loaded: 342 s wall, 234 s CPU with 2 threads
# each, 234 s and 134 s with 1; run in the other order, 196 s / 244 s against 143 s / 140 s).
# The serial part keeps numba's default (every core).
workers="${FPSCAN_TEST_WORKERS:-2}"
threads="${NUMBA_NUM_THREADS:-}"
case "$workers" in
  ''|0|*[!0-9]*) ;;  # in this process, or a count pytest-xdist works out itself: numba's default
  *) if [ -z "$threads" ]; then
       threads=$(( $(.venv/bin/python -c "import os; print(os.cpu_count() or 1)") / workers ))
       [ "$threads" -ge 1 ] || threads=1
     fi ;;
esac
set +e
lane_log=$(mktemp)
NUMBA_NUM_THREADS=1 .venv/bin/python -m pytest -p no:xdist -p no:cacheprovider -m "waits and not serial" "$@" \
  >"$lane_log" 2>&1 &
lane_pid=$!
trap 'kill "$warm_pid" "$lane_pid" 2>/dev/null || true; rm -f "$warm_log" "$lane_log"' EXIT
if [ -n "$threads" ]; then
  NUMBA_NUM_THREADS="$threads" .venv/bin/python -m pytest -n "$workers" --dist loadfile --no-loadscope-reorder -m "not serial and not waits" --durations=25 "$@"
else
  .venv/bin/python -m pytest -n "$workers" --dist loadfile --no-loadscope-reorder -m "not serial and not waits" --durations=25 "$@"
fi
parallel=$?
wait "$lane_pid"
lane=$?
echo "--- the tests marked waits, run beside the parallel part:"
cat "$lane_log"
.venv/bin/python -m pytest -p no:xdist -m serial "$@"
alone=$?
set -e
[ "$parallel" -eq 5 ] && parallel=0  # 5: no test selected
[ "$lane" -eq 5 ] && lane=0
[ "$alone" -eq 5 ] && alone=0
if [ "$parallel" -ne 0 ]; then exit "$parallel"; fi
if [ "$lane" -ne 0 ]; then exit "$lane"; fi
exit "$alone"
