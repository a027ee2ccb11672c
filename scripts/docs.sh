#!/usr/bin/env bash
# Build the documentation site into docs/_build/html with warnings as errors: the user guide
# (README.md and docs/*.md), the API reference from the docstrings, the HTTP reference from the
# OpenAPI schema and the gallery (examples/, run on the k-Wave files in $FPSCAN_SHARED/data, by
# default the shared folder beside the checkout, when present; on simulated data otherwise). Sets up
# .venv with fpscan[docs] first, as scripts/test.sh does. FPSCAN_DOCS_GALLERY=False builds without running the examples.
# Arguments go to sphinx-build (e.g. -j 2).
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[docs]'
unset PYTHONDONTWRITEBYTECODE
export MPLBACKEND=Agg
# the pages the build generates (autosummary's stubs, the OpenAPI schema), made afresh: a module
# renamed since the last build leaves no stale page behind
rm -rf docs/reference/generated docs/_generated
# -E: every page read again, so that every warning of every page is seen (and fails the build)
.venv/bin/python -m sphinx -W --keep-going -E -b html "$@" docs docs/_build/html
echo "docs: $(cd docs/_build/html && find . -name '*.html' -not -path './_*' | wc -l) pages in docs/_build/html (index.html)"
