# t2m-service: the HTTP API on onnxruntime. No torch in the image: the runtime needs only the project's base deps.
#   docker build -t t2m-service .
#   docker run -p 8000:8000 t2m-service            # then: curl localhost:8000/health
ARG PYTHON_VERSION=3.11

# ---- builder: a virtualenv holding the project wheel and its runtime dependencies (no [train] extra) ------------
FROM python:${PYTHON_VERSION}-slim AS builder
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 PYTHONDONTWRITEBYTECODE=1
RUN python -m venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH
WORKDIR /src
# the dependency layer is cached until pyproject.toml changes
COPY pyproject.toml ./
RUN python -c "import tomllib; print('\n'.join(tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies']))" \
        > /tmp/requirements.txt \
    && pip install -r /tmp/requirements.txt
COPY . .
RUN pip wheel --no-deps --wheel-dir /wheels . && pip install --no-deps /wheels/*.whl \
    && ! python -c "import torch" 2>/dev/null

# ---- runtime: the venv (its wheel carries the default model), a non-root user ----------------------------
FROM python:${PYTHON_VERSION}-slim AS runtime
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1
RUN groupadd --system --gid 10001 t2m && useradd --system --uid 10001 --gid t2m --home-dir /app t2m
COPY --from=builder /opt/venv /opt/venv
WORKDIR /app
USER t2m
EXPOSE 8000
# /health is 503 while the bundle loads (start period) and 200 once the model answers
HEALTHCHECK --interval=15s --timeout=5s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request; sys.exit(0 if urllib.request.urlopen('http://127.0.0.1:8000/health', timeout=4).status == 200 else 1)"]
ENTRYPOINT ["t2m", "serve", "--host", "0.0.0.0", "--port", "8000"]
