#!/usr/bin/env bash
# The guard rails (configuration in pyproject.toml), run by scripts/test.sh before the
# tests and by .pre-commit-config.yaml: style and bugs (ruff), the import contracts
# between packages (import-linter), and types (mypy). Needs the venv of scripts/test.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
echo "guard rails: ruff" >&2
.venv/bin/ruff check --no-cache .
echo "guard rails: import contracts" >&2
.venv/bin/lint-imports --no-cache
echo "guard rails: mypy (the package fpscan; disallow_untyped_defs)" >&2
.venv/bin/mypy
