# The brdffit fitting service: `brdffit serve` on $BRDFFIT_PORT (8000), data in the
# /data volume. docs/service.md, "Docker", says how to build it with docker or podman.
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
    # The one port setting: `brdffit serve` listens on it and the health check
    # (python -m api.healthcheck) asks it, so `-e BRDFFIT_PORT=9000` moves both.
    BRDFFIT_PORT=8000 \
    # At start, `brdffit serve` compiles the default fits into the cache in a
    # low-priority background process (`brdffit warmup`), so that a new volume's
    # first users load them; on a filled cache it only loads them. -e BRDFFIT_WARMUP=
    # switches it off, -e BRDFFIT_WARMUP=ggx,lambert picks models.
    BRDFFIT_WARMUP=default \
    # matplotlib wants a writable config dir; the image's home is not one.
    MPLCONFIGDIR=/tmp/matplotlib

WORKDIR /src
# 1. The dependencies, pinned with hashes (requirements/service.lock): the service's,
#    Dask's (BRDFFIT_DASK_SCHEDULER) and the build backend (setuptools). This layer
#    depends on the lock alone, so an edit of the source reuses it.
COPY requirements/service.lock ./requirements/
RUN pip install --no-deps --require-hashes -r requirements/service.lock \
    # the dependencies' own test suites (scipy's, numpy's, matplotlib's, ...): 67 MB
    # the service never imports
    && find "$(python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')" \
        -depth -type d -name tests -exec rm -rf {} + \
    && useradd --system --uid 10001 --home-dir /nonexistent --shell /usr/sbin/nologin brdffit \
    && mkdir -p /data \
    && chown brdffit /data
# 2. The package itself: brdffit/, api/ and data_synth/ (the 100 shipped real
#    materials' weights, package data); not tests, docs, bench (.dockerignore).
#    Everything it needs is installed above, so this step must fetch nothing:
#    --no-build-isolation builds with the locked setuptools instead of downloading
#    one into a fresh build environment, and --no-index makes any attempt to fetch
#    an error rather than a silent download.
COPY pyproject.toml README.md ./
COPY brdffit ./brdffit
COPY api ./api
COPY data_synth ./data_synth
RUN pip install --no-deps --no-build-isolation --no-index . && rm -rf /src
WORKDIR /
USER brdffit

# Declared after the chown: a fresh named volume starts owned by the service user.
VOLUME ["/data"]
EXPOSE 8000

# Reads BRDFFIT_PORT like `brdffit serve` does. (podman keeps a HEALTHCHECK only in
# the docker image format: podman build --format docker.)
HEALTHCHECK --interval=30s --timeout=5s --start-period=60s --retries=3 \
    CMD ["python", "-m", "api.healthcheck"]

# Exec form: brdffit (uvicorn) is PID 1 and gets docker stop's SIGTERM, so running
# jobs go back to the queue before the container exits. The port is BRDFFIT_PORT's.
CMD ["brdffit", "serve", "--host", "0.0.0.0"]
