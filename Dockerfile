# The brdffit fitting service: `brdffit serve` on port 8000, data in the /data volume.
#
#   docker build -t brdffit .
#   docker run -d -p 8000:8000 -v brdffit-data:/data [-e BRDFFIT_API_TOKEN=...] brdffit
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    # Tables, the job database and cached plots; JAX's compile cache beside them,
    # so a restarted container does not compile its fits again.
    BRDFFIT_DATA_DIR=/data \
    BRDFFIT_CACHE_DIR=/data/cache \
    # matplotlib wants a writable config dir; the image's home is not one.
    MPLCONFIGDIR=/tmp/matplotlib

WORKDIR /src
# 1. The dependencies, pinned with hashes (requirements/service.lock): this layer
#    depends on the lock alone, so an edit of the source reuses it.
COPY requirements/service.lock ./requirements/
RUN pip install --no-deps --require-hashes -r requirements/service.lock \
    && useradd --system --uid 10001 --home-dir /nonexistent --shell /usr/sbin/nologin brdffit \
    && mkdir -p /data \
    && chown brdffit /data
# 2. The package itself, without dependencies (they are all in): only what the service
#    runs, brdffit/ and api/ (not data_synth, tests, docs, bench; see .dockerignore).
COPY pyproject.toml README.md ./
COPY brdffit ./brdffit
COPY api ./api
RUN pip install --no-deps . && rm -rf /src
WORKDIR /
USER brdffit

# Declared after the chown: a fresh named volume starts owned by the service user.
VOLUME ["/data"]
EXPOSE 8000

HEALTHCHECK --interval=30s --timeout=5s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import sys, httpx; sys.exit(httpx.get('http://127.0.0.1:8000/healthz', timeout=4).status_code != 200)"]

# Exec form: brdffit (uvicorn) is PID 1 and gets docker stop's SIGTERM, so running
# jobs go back to the queue before the container exits.
CMD ["brdffit", "serve", "--host", "0.0.0.0", "--port", "8000"]
