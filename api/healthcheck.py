"""``python -m api.healthcheck``: exit 0 when the local service answers ``/healthz``
with 200, else 1 with one line saying why. The container's ``HEALTHCHECK``.

It asks the port in ``BRDFFIT_PORT`` (default 8000), the variable ``brdffit serve``
reads for its own ``--port`` default, so the check follows the server when the
port is moved. Standard library only: it starts every 30 s, and importing httpx
(or the app) would cost more than the check.
"""

from __future__ import annotations

import os
import sys
import urllib.error
import urllib.request

PORT_ENV = "BRDFFIT_PORT"
DEFAULT_PORT = 8000


def port(environ=os.environ) -> int:
    """The port ``brdffit serve`` listens on by default (``BRDFFIT_PORT``)."""
    text = environ.get(PORT_ENV, "").strip()
    if not text:
        return DEFAULT_PORT
    try:
        value = int(text)
    except ValueError:
        raise ValueError(f"{PORT_ENV}={text!r} is not a port number") from None
    if not 0 < value < 65536:
        raise ValueError(f"{PORT_ENV}={value} is not a port number (1..65535)")
    return value


def check(host: str = "127.0.0.1", timeout_s: float = 4.0) -> str | None:
    """None when ``/healthz`` answers 200; else why not, in one line."""
    url = f"http://{host}:{port()}/healthz"
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as response:
            return None if response.status == 200 else f"{url}: {response.status}"
    except urllib.error.HTTPError as e:  # 503: not ready, with its problems in the body
        return f"{url}: {e.code} {e.read(500).decode(errors='replace')}"
    except (OSError, ValueError) as e:
        return f"{url}: {getattr(e, 'reason', e)}"


def main() -> int:
    try:
        problem = check()
    except ValueError as e:  # a bad BRDFFIT_PORT
        problem = str(e)
    if problem:
        print(f"unhealthy: {problem}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
