#!/usr/bin/env bash
# Set up everything from scratch (a virtual environment with fpscan) and run the
# end-to-end demo; outputs land in ./demo-output/.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[server]'
# set-up: the numba kernels of the methods quick to compile (all but tv), in the default precision (float32),
# into numba's cache once (loaded in well under a second by every later process: the server's workers, its
# live preview, the CLI); a server's workers compile the rest in the background, after their first job can start
.venv/bin/fpscan warmup --quick --dtype float32 > /dev/null
exec .venv/bin/fpscan demo --out demo-output "$@"
