"""``brdffit serve``: run the fitting service (``api``) with uvicorn.

Settings come from ``BRDFFIT_*`` environment variables (``api.settings``); the
flags here override the ones a command line is expected to set.
"""

from __future__ import annotations

import os

from brdffit import child_process, extras


def add_arguments(p) -> None:
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1; 0.0.0.0 in a container)")
    # BRDFFIT_PORT is the default so that one variable moves the server and the
    # container's health check (python -m api.healthcheck) together.
    p.add_argument("--port", type=int, default=os.environ.get("BRDFFIT_PORT", "8000"),
                   help="port to listen on (default: env BRDFFIT_PORT, else 8000)")
    p.add_argument("--data-dir", help="tables, jobs database, plots (env BRDFFIT_DATA_DIR; default "
                        "./.brdffit-data)")
    p.add_argument("--workers", type=int, help="fit worker processes (env BRDFFIT_WORKERS)")
    p.add_argument("--log-level", default="info",
                   choices=["critical", "error", "warning", "info", "debug"])
    # The container sets BRDFFIT_WARMUP=default: a new volume's first users then find
    # the default fits compiled instead of waiting for their compilation.
    p.add_argument("--warmup", default=os.environ.get("BRDFFIT_WARMUP", ""),
                   metavar="MODELS",
                   help="at start, compile these models' fits in a low-priority background "
                        "process (`brdffit warmup --models MODELS`; 'default' for its "
                        "default models and auto; env BRDFFIT_WARMUP; default: none)")


def run(args) -> int:
    extras.require("service", "brdffit serve")
    import logging

    import uvicorn

    from api.main import create_app
    from api.settings import Settings

    overrides = {k: v for k, v in (("data_dir", args.data_dir), ("workers", args.workers))
                 if v is not None}
    settings = Settings(**overrides)  # a bad value raises ValueError: a one-line CLI error
    # a directory another server holds: one line, before uvicorn (whose start holds the
    # lock for good, api.main; a server that takes it in between is refused there)
    from api.store import ServerLock

    with ServerLock(settings.data_dir):
        pass
    # The service's own messages (recovered jobs, worker crashes) beside uvicorn's.
    logging.basicConfig(level=args.log_level.upper(), format="%(levelname)s:     %(message)s")
    warmup = _start_warmup(args.warmup)  # an unknown model: a one-line CLI error
    try:
        # One server process: the job queue lives in it (the workers are its children).
        uvicorn.run(create_app(settings), host=args.host, port=args.port,
                    log_level=args.log_level)
    finally:
        child_process.stop(warmup)  # a half-filled cache is fine: what is written is whole
    return 0


def _start_warmup(models: str):
    """``brdffit warmup`` beside the server, at the lowest CPU priority, so that it
    takes only what the server and its workers leave; its lines go to the server's
    log. The server answers at once: a job that comes first compiles what it needs
    itself, as without a warm-up."""
    from brdffit.models import catalogue
    from brdffit.request import split_names

    models = models.strip()
    if models.lower() in ("", "0", "off", "none", "false"):
        return None
    argv = ["warmup"]
    if models.lower() not in ("1", "default", "on", "true"):
        # an unknown name, or an empty item, stops the server, not the warm-up
        for name in split_names(models, "--warmup"):
            catalogue.check_name(name, allow_auto=True)
        argv += ["--models", models]
    return child_process.start(argv, nice=19)
