"""``brdffit serve``: run the fitting service (``api``) with uvicorn.

Settings come from ``BRDFFIT_*`` environment variables (``api.settings``); the
flags here override the ones a command line is expected to set.
"""

from __future__ import annotations

import os

from brdffit import extras


def add_arguments(p) -> None:
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1; 0.0.0.0 in a container)")
    # BRDFFIT_PORT is the default so that one variable moves the server and the
    # container's health check (python -m api.healthcheck) together.
    p.add_argument("--port", type=int, default=os.environ.get("BRDFFIT_PORT", "8000"),
                   help="port to listen on (default: env BRDFFIT_PORT, else 8000)")
    p.add_argument("--data-dir", help="tables, jobs database, plots (env BRDFFIT_DATA_DIR)")
    p.add_argument("--workers", type=int, help="fit worker processes (env BRDFFIT_WORKERS)")
    p.add_argument("--log-level", default="info",
                   choices=["critical", "error", "warning", "info", "debug"])


def run(args) -> int:
    extras.require("service", "brdffit serve")
    import logging

    import uvicorn

    from api.main import create_app
    from api.settings import Settings

    overrides = {k: v for k, v in (("data_dir", args.data_dir), ("workers", args.workers))
                 if v is not None}
    settings = Settings(**overrides)  # a bad value raises ValueError: a one-line CLI error
    # The service's own messages (recovered jobs, worker crashes) beside uvicorn's.
    logging.basicConfig(level=args.log_level.upper(), format="%(levelname)s:     %(message)s")
    # One server process: the job queue lives in it (the workers are its children).
    uvicorn.run(create_app(settings), host=args.host, port=args.port, log_level=args.log_level)
    return 0
