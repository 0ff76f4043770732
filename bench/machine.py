"""The machine a benchmark ran on, for its results' header: CPU, cores, Python, JAX and
its device, brdffit's version, the date and the load. Importing this changes nothing
(``bench.speed``, which switches the compile cache off at import for its own cold runs,
imports it from here, and so do the benchmarks that must keep the cache on)."""

from __future__ import annotations

import os
import platform
from datetime import UTC, datetime


def machine() -> dict:
    import jax

    from brdffit import __version__

    try:
        load = os.getloadavg()
    except OSError:
        load = None
    cpu = ""
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((ln.split(":", 1)[1].strip() for ln in f if "model name" in ln), "")
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            "jax": jax.__version__, "backend": jax.default_backend(),
            "device": str(jax.devices()[0]), "brdffit": __version__,
            "date": datetime.now(UTC).isoformat(timespec="seconds"), "loadavg": load}


def machine_line(m: dict) -> str:
    """:func:`machine`'s record as a report's line: CPU, cores, versions, date, load."""
    load = " ".join(f"{x:.1f}" for x in m["loadavg"] or ())
    return (f"{m['cpu']}, {m['cores']} cores; JAX {m['jax']}, brdffit {m['brdffit']}; "
            f"{m['date']} (load average {load})")
