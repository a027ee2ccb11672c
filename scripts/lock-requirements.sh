#!/usr/bin/env bash
# Regenerate the Docker image's hash-pinned requirements (docker/requirements-*.lock) from
# pyproject.toml: the base dependencies and those of the image's extras (server, which names
# driver; server,cuda for the CUDA variant), plus the build backend that installs fpscan itself
# (pyproject's [build-system] requires), each pinned to one version with the sha256 of every file
# PyPI holds for it. The resolution is universal (uv's --universal, from Python 3.11.1: ome-zarr asks for a Python above 3.11.0): markers
# where a dependency differs by platform or Python, so one lock serves the CPU image (Python 3.11)
# and the CUDA one (Ubuntu's Python 3.12). The Dockerfile installs a lock with
# `pip install --require-hashes`, then fpscan with --no-deps --no-build-isolation.
#
#   bash scripts/lock-requirements.sh            (needs the network: PyPI; commit the locks it writes)
#
# uv is taken from $UV, else from PATH, else installed with pip into a throwaway venv.
set -euo pipefail
cd "$(dirname "$0")/.."
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
uv=${UV:-$(command -v uv || true)}
if [ -z "$uv" ]; then
  python3 -m venv "$tmp/venv"
  "$tmp/venv/bin/python" -m pip install -q uv
  uv="$tmp/venv/bin/uv"
fi
# the build backend's requirements, as a requirements file
python3 -c "import tomllib; print('\n'.join(tomllib.load(open('pyproject.toml', 'rb'))['build-system']['requires']))" \
  > "$tmp/build-requirements.in"
for extras in server server,cuda; do
  out="docker/requirements-${extras//,/-}.lock"
  # uv keeps the versions of the output file it is given where the requirements allow: a lock
  # changes where pyproject.toml changed (rm the locks for a fresh resolution of everything)
  if [ -f "$out" ]; then cp "$out" "$tmp/out.lock"; else rm -f "$tmp/out.lock"; fi
  args=()
  for e in ${extras//,/ }; do args+=(--extra "$e"); done
  "$uv" pip compile --quiet --universal --python-version 3.11.1 --generate-hashes --no-header \
    --no-strip-markers "${args[@]}" pyproject.toml "$tmp/build-requirements.in" -o "$tmp/out.lock"
  {
    echo "# The Docker image's requirements for EXTRAS=$extras, hash-pinned (pip install --require-hashes)."
    echo "# Generated from pyproject.toml by scripts/lock-requirements.sh; do not edit by hand."
    sed "s|$tmp/build-requirements.in|pyproject.toml [build-system]|" "$tmp/out.lock"
  } > "$out"
  echo "wrote $out ($(grep -c '^[a-zA-Z0-9]' "$out") packages)"
done
