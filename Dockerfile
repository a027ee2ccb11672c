# syntax=docker/dockerfile:1
# fpscan service image: `fpscan serve` on 0.0.0.0:8000, token required, state in /data.
#   docker build -t fpscan .
#   docker run -d -p 8000:8000 -e FPSCAN_TOKEN=... -v fpscan-data:/data \
#     --device /dev/ttyACM0 --group-add dialout \
#     -e FPSCAN_DEVICES='{"fp1": "/dev/ttyACM0"}' fpscan

# ---- build stage: compile wheels (cobs has a C extension) into a venv --------------
FROM python:3.11-slim AS build
# hadolint ignore=DL3008
RUN apt-get update \
 && apt-get install -y --no-install-recommends gcc libc6-dev \
 && rm -rf /var/lib/apt/lists/*
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
RUN python -m venv /opt/fpscan
WORKDIR /src
COPY pyproject.toml README.md ./
COPY service ./service
COPY driver ./driver
COPY clients ./clients
RUN /opt/fpscan/bin/python -m pip install --no-cache-dir ".[server]"

# ---- runtime stage: slim, no compiler, non-root ------------------------------------
FROM python:3.11-slim
RUN useradd --create-home --uid 10001 --user-group fpscan \
 && usermod --append --groups dialout fpscan \
 && mkdir -p /data \
 && chown fpscan:fpscan /data
COPY --from=build /opt/fpscan /opt/fpscan
ENV PATH=/opt/fpscan/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    FPSCAN_DATA_DIR=/data \
    FPSCAN_PORT=8000
VOLUME ["/data"]
WORKDIR /data
USER 10001:10001
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
  CMD ["python", "-c", "import os, urllib.request as u; r = u.Request('http://127.0.0.1:%s/api/health' % os.environ.get('FPSCAN_PORT', '8000'), headers={'Authorization': 'Bearer ' + os.environ.get('FPSCAN_TOKEN', '')}); u.urlopen(r, timeout=4)"]
# The token is required: refuse to start without FPSCAN_TOKEN.
CMD ["sh", "-c", "if [ -z \"$FPSCAN_TOKEN\" ]; then echo 'fpscan: set FPSCAN_TOKEN (the bearer token is required in the container)' >&2; exit 64; fi; exec fpscan serve --host 0.0.0.0 --port \"$FPSCAN_PORT\""]
