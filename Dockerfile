# t2m-service: the HTTP API on onnxruntime. No torch in the image: the runtime needs only the project's base deps.
#   docker build -t t2m-service .
#   docker run -p 8000:8000 t2m-service            # then: curl localhost:8000/health
# Offline / behind a TLS-intercepting proxy (no package index reachable from inside the build), see deploy/README.md:
#   scripts/build_wheelhouse.sh deploy/wheelhouse   # on a machine whose pip can reach an index (or a mirror)
#   docker build --build-arg WHEELHOUSE=1 [--build-arg BASE_IMAGE=my-python3.11] -t t2m-service .
# Any base image with python3 (3.10+, the venv module) and groupadd/useradd works: the default is the official one.
# GPU image (docs/service.md "GPUs"): a CUDA 13 + cuDNN 9 runtime base (python3 is added from apt when it lacks one)
# and the `gpu` extra, which installs onnxruntime-gpu instead of onnxruntime:
#   docker build --build-arg BASE_IMAGE=nvidia/cuda:13.0.1-cudnn-runtime-ubuntu24.04 --build-arg EXTRAS=gpu \
#       -t t2m-service:gpu .                    # offline: T2M_IMAGE_PYTHON=3.12 T2M_EXTRAS=gpu build_wheelhouse.sh
#   docker run --gpus all -e T2M_EXECUTION_PROVIDERS=cuda -p 8000:8000 t2m-service:gpu
ARG BASE_IMAGE=python:3.11-slim

# ---- builder: a virtualenv holding the project wheel and its runtime dependencies (no [train] extra) ------------
FROM ${BASE_IMAGE} AS builder
# WHEELHOUSE=1: install from deploy/wheelhouse only (--no-index); 0: from the package index pip is configured for
ARG WHEELHOUSE=0
# EXTRAS: optional dependency groups of pyproject.toml to install too (gpu: onnxruntime-gpu replaces onnxruntime)
ARG EXTRAS=
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 PYTHONDONTWRITEBYTECODE=1
# a CUDA runtime base has no Python: take the distribution's (a no-op on python:* images)
RUN python3 -c "import venv, ensurepip" 2>/dev/null || { apt-get update \
        && apt-get install -y --no-install-recommends python3 python3-venv && rm -rf /var/lib/apt/lists/*; }
RUN python3 -m venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH
WORKDIR /src
# the dependency layer is cached until pyproject.toml or the wheelhouse changes
COPY pyproject.toml ./
COPY scripts/image_requirements.py scripts/
COPY deploy/wheelhouse/ /wheelhouse/
RUN set -eu; \
    python scripts/image_requirements.py pyproject.toml "$EXTRAS" > /tmp/requirements.txt; \
    if [ "$WHEELHOUSE" = 1 ]; then \
        ls /wheelhouse/*.whl > /dev/null 2>&1 \
            || { echo "WHEELHOUSE=1 but deploy/wheelhouse holds no wheels: run scripts/build_wheelhouse.sh" >&2; exit 1; }; \
        printf '[global]\nno-index = true\nfind-links = /wheelhouse\n' > /etc/pip.conf; \
    fi; \
    pip install -r /tmp/requirements.txt
COPY . .
# the project wheel's build backend (setuptools) comes from the same place as the dependencies; pip itself is not
# needed at run time (the compiled .pyc files stay: a read-only root filesystem cannot write them at start)
RUN pip wheel --no-deps --wheel-dir /wheels . && pip install --no-deps /wheels/*.whl \
    && ! python -c "import torch" 2>/dev/null \
    && rm -rf /opt/venv/lib/python3*/site-packages/pip /opt/venv/lib/python3*/site-packages/pip-*

# ---- runtime: the venv (its wheel carries the default and masked models), a non-root user ---------------------
FROM ${BASE_IMAGE} AS runtime
RUN python3 -c "import venv" 2>/dev/null || { apt-get update \
        && apt-get install -y --no-install-recommends python3 && rm -rf /var/lib/apt/lists/*; }
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    T2M_HOST=0.0.0.0 \
    T2M_PORT=8000
RUN groupadd --system --gid 10001 t2m && useradd --system --uid 10001 --gid t2m --home-dir /app t2m
COPY --from=builder /opt/venv /opt/venv
WORKDIR /app
USER t2m
EXPOSE 8000
# /health is 503 while the bundle loads and 200 once the model answers. It is probed every 5 s so that the container
# turns healthy (and nginx/compose send it traffic) a few seconds after the model loads, not 15 s later.
# T2M_PORT moves the server and the check together (e.g. `docker run --network host -e T2M_PORT=9001`).
HEALTHCHECK --interval=5s --timeout=4s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import os, sys, urllib.request; sys.exit(0 if urllib.request.urlopen('http://127.0.0.1:' + os.environ.get('T2M_PORT', '8000') + '/health', timeout=3).status == 200 else 1)"]
# docker stop sends SIGTERM: uvicorn stops accepting, finishes the requests in flight (up to T2M_REQUEST_TIMEOUT_S),
# then exits; give it that long (docker stop -t 75, compose stop_grace_period, Kubernetes terminationGracePeriod).
STOPSIGNAL SIGTERM
ENTRYPOINT ["t2m", "serve"]
