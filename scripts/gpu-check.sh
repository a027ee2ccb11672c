#!/usr/bin/env bash
# The GPU device checks, as one script for a GPU machine (the device tool's lease is 15
# minutes): the GPU tests (tests/gpu: NER, NEDNER, the operator pair and tv on the GPU against the
# CPU, the fallback and the memory rules), the GPU path's NumPy tests, then benchmarks/bench_gpu.py
# on the paper's scan and the CLI / HTTP checks (scripts/gpu_check_service.py).
#
#   bash scripts/gpu-check.sh [quick|full|service|profile|scaling]     (results in $OUT, default /tmp/gpu-check)
#
# quick: the tests and bench_gpu at half the paper's size without the one-core rows (about 2
# minutes); full: the tests, bench_gpu at the paper's size (the one-core rows at half of it), then
# the CLI and HTTP checks (at most 9 minutes: the steps' timeouts); service: the CLI and HTTP
# checks alone; profile: a profile of tv on the CPU (benchmarks/profile_tv_cpu.py); scaling: how
# NER's CPU parts scale with cores (benchmarks/bench_cpu_scaling.py).
# Python packages the machine lacks travel as wheels in .whl/ (docs/configuration.md "GPU"), installed first. The
# device tool's H100/H200 image (Python 3.12, numpy, scipy, numba, h5py, CuPy) lacked these; fill
# .whl/ (git ignores it) before the first call:
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
#     --platform manylinux1_x86_64 --platform any -d .whl finufft pylops pyproximal pydantic pydantic_core \
#     pydantic-settings annotated-types typing-inspection fastapi starlette uvicorn python-multipart \
#     sse-starlette python-dotenv distributed dask partd locket tblib zict tornado pyserial cobs pint \
#     flexcache flexparser platformdirs httpx-sse httptools websockets opentelemetry-api sniffio watchfiles
# (the versions this project's .venv holds: `.venv/bin/pip freeze`).
set -u
mode=${1:-quick}
OUT=${OUT:-/tmp/gpu-check}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
if [ -d .whl ] && ls .whl/*.whl >/dev/null 2>&1; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    && export PYTHONPATH=/tmp/site || echo "wheel install failed"
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
# fpscan's metadata (its version and console script) where it is not installed:
# a dist-info written from pyproject.toml, without a build
if ! python3 -c "import importlib.metadata as m; m.distribution('fpscan')" 2>/dev/null; then
  python3 - <<'PY'
import pathlib, tomllib
p = tomllib.load(open("pyproject.toml", "rb"))["project"]
d = pathlib.Path("/tmp/site-fpscan") / f"fpscan-{p['version']}.dist-info"
d.mkdir(parents=True, exist_ok=True)
(d / "METADATA").write_text(f"Metadata-Version: 2.1\nName: fpscan\nVersion: {p['version']}\n")
groups = {"console_scripts": p.get("scripts", {}), **p.get("entry-points", {})}
(d / "entry_points.txt").write_text("".join(f"[{g}]\n" + "".join(f"{k} = {v}\n" for k, v in e.items()) + "\n"
                                            for g, e in groups.items()))
PY
  export PYTHONPATH="$PYTHONPATH:/tmp/site-fpscan"
fi
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c "import numpy, scipy, numba, cupy, finufft, pylops; print('numpy', numpy.__version__, 'scipy', scipy.__version__, 'numba', numba.__version__, 'cupy', cupy.__version__, 'finufft', finufft.__version__, 'cores', __import__('os').cpu_count())"
if [ "$mode" = service ]; then
  timeout 150 python3 scripts/gpu_check_service.py --device cuda --out /tmp/gpu-check-service 2>&1 \
    | tee "$OUT/service.log" | tail -30
elif [ "$mode" = profile ]; then
  timeout 150 python3 benchmarks/profile_tv_cpu.py --scale 0.5 2>&1 | tee "$OUT/profile.log" | tail -40
elif [ "$mode" = scaling ]; then
  timeout 200 python3 benchmarks/bench_cpu_scaling.py --repeat 3 2>&1 | tee "$OUT/scaling.log" | tail -12
elif [ "$mode" = quick ]; then
  timeout 150 python3 -m pytest -q -p no:cacheprovider tests/gpu 2>&1 | tee "$OUT/pytest.log" | tail -25
  timeout 150 python3 benchmarks/bench_gpu.py --scale 0.5 --one-core none --repeat 2 --json "$OUT/bench_half.json" 2>&1 | tee "$OUT/bench_half.log"
else
  timeout 100 python3 -m pytest -q -p no:cacheprovider tests/gpu 2>&1 | tee "$OUT/pytest.log" | tail -8
  timeout 330 python3 benchmarks/bench_gpu.py --scale 1 --repeat 5 --one-core all --one-core-scale 0.5 \
    --one-core-timeout 150 --json "$OUT/bench.json" 2>&1 | tee "$OUT/bench.log"
  timeout 110 python3 scripts/gpu_check_service.py --device cuda --out /tmp/gpu-check-service 2>&1 \
    | tee "$OUT/service.log" | tail -30
fi
