# syntax=docker/dockerfile:1
# fpscan service image: `fpscan serve` on 0.0.0.0:8000, token required, state in /data,
# tini as PID 1 (signals reach the server, zombies are reaped).
#   docker build -t fpscan .
#   docker run -d -p 8000:8000 -e FPSCAN_TOKEN=... -v fpscan-data:/data \
#     --device /dev/ttyACM0 \
#     -e FPSCAN_DEVICES='{"fp1": "/dev/ttyACM0"}' fpscan
# Clients on the lab network reach it by a name or address the server must be told (a
# request naming any other Host is refused, against DNS rebinding; localhost works as is):
#   docker run ... -e FPSCAN_ALLOWED_HOSTS='["scanner-pc.lab", "192.168.1.20"]' fpscan
# The token from a file instead (Docker/Compose/Swarm secrets): mount it and name it,
#   docker run ... -v "$PWD/token.txt:/run/secrets/fpscan_token:ro" \
#     -e FPSCAN_TOKEN_FILE=/run/secrets/fpscan_token fpscan
#
# Base image pinned by digest: python:3.11-slim at the index digest below, as recorded in
# two independent public Dockerfiles (docker.io/library and its public.ecr.aws mirror);
# it was not pulled from the machine this file was written on. To move to a newer patch
# release, take the digest from `docker buildx imagetools inspect python:3.11-slim` and
# replace it in the ARG BASE line.
#
# The CUDA variant (the GPU path: NER, NEDNER and tv on an NVIDIA GPU through
# CuPy, README "GPU"): the same two stages on NVIDIA's CUDA runtime image, with the `cuda`
# extra (CuPy) beside the server's,
#   docker build -t fpscan:cuda \
#     --build-arg BASE=nvidia/cuda:12.6.3-runtime-ubuntu24.04 --build-arg EXTRAS=server,cuda .
#   docker run -d --gpus all -p 8000:8000 -e FPSCAN_TOKEN=... -v fpscan-data:/data fpscan:cuda
# A base without Python (NVIDIA's images) gets Ubuntu's python3 in both stages. The `cuda` extra
# is CuPy for CUDA 12 drivers (cupy-cuda12x); pin the CUDA base by digest as above for a
# reproducible build. The default build (no build arguments) is the CPU image, without CuPy.
#
# The Python packages are pinned with their hashes: docker/requirements-<EXTRAS, commas as
# dashes>.lock (server: the CPU image; server-cuda: the CUDA variant), installed with
# `pip install --require-hashes`, then fpscan itself without its dependencies and with the
# build backend from the lock (--no-build-isolation). Regenerate the locks after a change of
# pyproject.toml's dependencies, or to move to newer releases: `bash scripts/lock-requirements.sh`.
#
# The serial port: the user `fpscan` (uid 10001) is in the image's group dialout (gid 20), and
# `USER 10001` (the uid alone, no group) gives the process its supplementary groups from the
# image's /etc/group, so a device node of group dialout opens without --group-add. Where the
# host's node has another group, add its number: --group-add "$(stat -c %g /dev/ttyACM0)".
ARG BASE=python:3.11-slim@sha256:9c900dea9e8fb7e16277c179b555cc72d29a352dbc33cff48ad5a0412fd5bfc7

# ---- build stage: compile wheels (cobs has a C extension) into a venv --------------
FROM ${BASE} AS build
# the extras of pyproject.toml installed: `server` (the CPU image), `server,cuda` (with CuPy)
ARG EXTRAS=server
# hadolint ignore=DL3008
RUN apt-get update \
 && apt-get install -y --no-install-recommends gcc libc6-dev \
 && if ! command -v python3 >/dev/null 2>&1; then \
      apt-get install -y --no-install-recommends python3 python3-dev python3-venv; \
    fi \
 && rm -rf /var/lib/apt/lists/*
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
RUN python3 -m venv /opt/fpscan
WORKDIR /src
# dependencies first, in their own layer: a change of the source reuses it. The lock of the
# EXTRAS (every package pinned, with its hashes: pyproject's base requirements, those of the
# EXTRAS and of the extras they name — server names driver —, and the build backend)
COPY docker/requirements-*.lock ./docker/
# (the one pipe, echo into tr, cannot fail unseen: a missing lock is reported)
# hadolint ignore=DL4006
RUN lock="docker/requirements-$(echo "$EXTRAS" | tr ',' '-').lock" \
 && if [ ! -f "$lock" ]; then echo "no $lock for EXTRAS=$EXTRAS: bash scripts/lock-requirements.sh" >&2; exit 1; fi \
 && /opt/fpscan/bin/python -m pip install --no-cache-dir --require-hashes -r "$lock"
COPY pyproject.toml README.md ./
COPY service ./service
COPY driver ./driver
COPY clients ./clients
COPY fpscan ./fpscan
RUN /opt/fpscan/bin/python -m pip install --no-cache-dir --no-deps --no-build-isolation ".[${EXTRAS}]"
# ship the compiled (numba) reconstruction kernels warm: `fpscan warmup --quick` (every kernel
# but tv's, which a server's workers compile in the background), float32 and float64, into
# NUMBA_CACHE_DIR, which the runtime stage copies and gives to its user (numba uses a cache
# directory only where it can write; a host whose CPU differs from the build machine's
# recompiles on first use, into the same directory); run outside /src so that the installed
# modules, not the sources, are imported
ENV NUMBA_CACHE_DIR=/var/cache/fpscan/numba
WORKDIR /tmp
RUN /opt/fpscan/bin/fpscan warmup --quick

# ---- runtime stage: slim, no compiler, non-root, tini as init ----------------------
# (the venv's python links to the base's interpreter: python3 from apt where the base has none)
FROM ${BASE}
# hadolint ignore=DL3008
RUN apt-get update \
 && apt-get install -y --no-install-recommends tini \
 && if ! command -v python3 >/dev/null 2>&1; then \
      apt-get install -y --no-install-recommends python3; \
    fi \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --create-home --uid 10001 --user-group --groups dialout fpscan \
 && mkdir -p /data \
 && chown fpscan:fpscan /data
COPY --from=build /opt/fpscan /opt/fpscan
COPY --from=build --chown=fpscan:fpscan /var/cache/fpscan /var/cache/fpscan
ENV PATH=/opt/fpscan/bin:$PATH \
    NUMBA_CACHE_DIR=/var/cache/fpscan/numba \
    PYTHONUNBUFFERED=1 \
    FPSCAN_DATA_DIR=/data \
    FPSCAN_PORT=8000
VOLUME ["/data"]
WORKDIR /data
# the uid alone: the process gets the user's supplementary groups (dialout), which a uid:gid drops
USER 10001
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
  CMD ["python", "-c", "import os, urllib.request as u; f = os.environ.get('FPSCAN_TOKEN_FILE'); t = os.environ.get('FPSCAN_TOKEN') or (open(f).read().strip() if f else ''); r = u.Request('http://127.0.0.1:%s/api/health' % os.environ.get('FPSCAN_PORT', '8000'), headers={'Authorization': 'Bearer ' + t}); u.urlopen(r, timeout=4)"]
# tini (PID 1) forwards SIGTERM to the server and reaps the worker processes it starts
ENTRYPOINT ["/usr/bin/tini", "--"]
# The token is required: refuse to start without FPSCAN_TOKEN or FPSCAN_TOKEN_FILE.
CMD ["sh", "-c", "if [ -z \"$FPSCAN_TOKEN\" ] && [ -z \"$FPSCAN_TOKEN_FILE\" ]; then echo 'fpscan: set FPSCAN_TOKEN or FPSCAN_TOKEN_FILE (the bearer token is required in the container)' >&2; exit 64; fi; exec fpscan serve --host 0.0.0.0 --port \"$FPSCAN_PORT\""]
