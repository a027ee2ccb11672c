#!/usr/bin/env bash
# Set up everything from scratch (a virtual environment with fpscan and its test
# dependencies), run the guard rails (ruff, import-linter contracts, mypy; configured in
# pyproject.toml) and then the whole test suite. Any guard-rail error fails the run.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[test]'
if [ -x scripts/test-setup.d ] || [ -d scripts/test-setup.d ]; then
  for step in scripts/test-setup.d/*.sh; do [ -e "$step" ] && bash "$step"; done
fi
bash scripts/lint.sh
exec .venv/bin/python -m pytest "$@"
