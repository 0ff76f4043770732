"""Shared fixtures.

Every test runs inside ``brdffit.runtime.float64()``, as brdffit's own entry points
do, so a test may evaluate a model directly in double precision. That brdffit
needs no such help from its caller (and changes no JAX setting) is tested in a
fresh process by tests/test_runtime.py.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

# Tests keep brdffit's cache (bin grid, compiled code) inside the checkout unless told
# otherwise.
os.environ.setdefault(
    "BRDFFIT_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".venv", "brdffit-cache")
)

import pytest  # noqa: E402

from brdffit import runtime  # noqa: E402

#: Every test belongs to one layer (``pytestmark`` of its file, or its own mark):
#: ``unit`` (one module, in process), ``contract`` (the shells agree with the
#: library: options, result schema, imports, catalogue), ``system`` (real
#: processes: the CLI, a uvicorn server, a Dask cluster, real materials).
#: ``make test-quick`` runs all but ``system``.
LAYERS = ("unit", "contract", "system")


@pytest.hookimpl(tryfirst=True)
def pytest_sessionstart(session):
    """Under pytest-xdist (``make test``), the controller fills the tests' compile
    cache with ``brdffit warmup`` before it starts the workers, so that the default
    programs are compiled once, side by side (~25 s), rather than by several
    processes at once (the two workers, the servers, CLIs and Dask workers they
    start) each before any other has stored them. A cache that is already filled
    makes this a ~3 s load; ``BRDFFIT_TEST_WARMUP=0`` skips it. A failed warmup costs
    speed only."""
    config = session.config
    if (hasattr(config, "workerinput") or not config.getoption("numprocesses", None)
            or os.environ.get("BRDFFIT_TEST_WARMUP") == "0"):
        return
    t0 = time.perf_counter()
    try:
        r = subprocess.run([sys.executable, "-m", "brdffit.cli", "warmup"], capture_output=True,
                           text=True, timeout=900,
                           cwd=os.path.dirname(os.path.dirname(__file__)))
        what = "done" if r.returncode == 0 else f"failed ({r.stderr.strip()[-300:]})"
    except (subprocess.TimeoutExpired, OSError) as e:  # the tests run all the same
        what = f"failed ({e})"
    reporter = config.pluginmanager.get_plugin("terminalreporter")
    if reporter is not None:
        reporter.write_line(f"brdffit warmup into {os.environ['BRDFFIT_CACHE_DIR']}: {what} "
                            f"in {time.perf_counter() - t0:.0f} s")


@pytest.hookimpl(tryfirst=True)  # before xdist turns the xdist_group marks into groups
def pytest_collection_modifyitems(config, items):
    unmarked = [i.nodeid for i in items if _layer(i) is None]
    if unmarked:
        raise pytest.UsageError(f"tests without a layer mark {LAYERS}: {unmarked[:5]}")
    _spread_over_workers(items)


def _uses_a_module_fixture(item) -> bool:
    info = getattr(item, "_fixtureinfo", None)
    return info is not None and any(
        getattr(d, "scope", None) in ("module", "package")
        for name in info.names_closure for d in info.name2fixturedefs.get(name, ()))


def _layer(item) -> str | None:
    return next((m.name for m in item.iter_markers() if m.name in LAYERS), None)


def _spread_over_workers(items) -> None:
    """How ``make test`` (pytest-xdist, ``--dist loadgroup``) shares the tests out.

    A test that uses a module-scoped fixture (a server, a cluster, a fitted table)
    runs on the worker that holds its file's other such tests, so that the fixture
    starts once; every other test goes to whichever worker is free. The ``system``
    tests (processes, servers, real materials: most of the run's time) are handed out
    first, so that the last minutes are not one worker finishing a long file alone.
    (Handing the other ``slow`` tests out right after them made a fresh clone's run
    slower, 16:08 against 15:37: two workers both on heavy tests at once.) Without
    xdist the marks are inert and the order is the only change.
    """
    for item in items:
        if _uses_a_module_fixture(item):
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0]))
    items.sort(key=lambda i: _layer(i) != "system")  # stable: files keep their order


@pytest.fixture(autouse=True)
def _brdffit_precision():
    with runtime.float64():
        yield
