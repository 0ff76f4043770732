"""An interrupted batch leaves no work on the cluster, and keeps each finished fit.

A ``dask scheduler`` and two ``dask worker`` processes are started on 127.0.0.1, as
an operator would (docs/batch.md, "On a real cluster"); ``brdffit batch
--scheduler`` is interrupted (SIGINT, as Ctrl-C; SIGTERM, as ``kill``) once a first
fit is in. Then the batch says so in one line, the scheduler holds none of its
tasks, the workers go idle (a running fit cannot be stopped, so at most the one
each was running finishes), and the file holds the finished fits one by one: a
table whose other model was still running keeps the model that was done.

On a local cluster (``--workers 2``), a Ctrl-C at a terminal reaches the whole
process group, the workers included: the batch still ends with one line.

The fits in flight are of a plugin model (installed for these processes as a
package would be, as in tests/test_adding_a_model.py) that waits at each step of
its solve: a fit that stays in flight for seconds without taking the CPU that a
long real fit takes from the rest of the suite (ggx2 on 65,536 samples cost these
tests ~100 s of CPU, most of it compiling and solving on a loaded machine).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from brdffit.batch.store import read_results
from tests.dask_fixtures import REPO, executing, scheduler_tasks, separate_cluster
from tests.table_files import write_tables

pytestmark = pytest.mark.system

#: lambert is fitted in a fraction of a second; the slow model takes seconds, so the
#: batch is interrupted with fits in flight
MODELS = "lambert,slow_diffuse"
TABLES = {
    "a_ggx": ("ggx", {"kd": [0.2, 0.1, 0.05], "ks": [0.8, 0.7, 0.6], "alpha": 0.2, "f0": 0.6}),
    "b_ggx": ("ggx", {"kd": [0.1, 0.15, 0.2], "ks": [0.6, 0.6, 0.5], "alpha": 0.1, "f0": 0.8}),
}


#: The plugin: Lambert's formula, with a wait at each evaluation on the solver's
#: samples (the default sample count, in float64; the full-table error, in float32
#: blocks of the same size, and the start scoring, on every 8th sample, do not wait).
SLOW_MODEL = """
import time

import jax
import jax.numpy as jnp

from brdffit.fitting.sampling import DEFAULT_SAMPLES
from brdffit.models.base import KD, AbstractBRDFModel

WAIT_S = 0.4


def _wait():
    time.sleep(WAIT_S)


class SlowDiffuse(AbstractBRDFModel):
    name = "slow_diffuse"
    param_specs = (KD,)

    def eval_frame(self, params, frame):
        if frame.cos_i.shape[-1] == DEFAULT_SAMPLES and frame.cos_i.dtype == jnp.float64:
            jax.debug.callback(_wait)
        return jnp.broadcast_to(params["kd"] / jnp.pi, frame.cos_i.shape + (3,)).astype(
            frame.cos_i.dtype)
"""


@pytest.fixture(scope="module")
def plugin_env(tmp_path_factory) -> dict:
    """The environment of a process that has the slow model installed."""
    root = tmp_path_factory.mktemp("site")
    (root / "slow_diffuse.py").write_text(SLOW_MODEL)
    info = root / "brdffit_slow_diffuse-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: brdffit-slow-diffuse\n"
                                   "Version: 0.1\n")
    (info / "entry_points.txt").write_text(
        "[brdffit.models]\nslow_diffuse = slow_diffuse:SlowDiffuse\n")
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), REPO])}


@pytest.fixture(scope="module")
def table_dir(tmp_path_factory):
    return write_tables(tmp_path_factory.mktemp("tables"), TABLES)


@pytest.fixture(scope="module")
def cluster(plugin_env):
    with separate_cluster(2, env=plugin_env) as (address, client):
        yield address, client


def _fits_in(out: Path) -> int:
    """Fits finished so far: journaled, or already checkpointed into the file."""
    n = 0
    with contextlib.suppress(OSError):
        n += Path(f"{out}.journal").read_text().count('"kind":"fit"')
    with contextlib.suppress(OSError, KeyError, ValueError):
        n += sum(len(t["fits"]) for t in read_results(out)["tables"])
    return n


def _interrupt_after_first_fit(cmd: list[str], out: Path, sig: int, *, group: bool,
                               env: dict | None = None) -> subprocess.CompletedProcess:
    # A process started with SIGINT ignored (a shell's background job) passes that
    # on to its children; a handler (this one) is reset to the default by exec, so
    # the batch sees Ctrl-C as a terminal's user would.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, start_new_session=True)
    finally:
        signal.signal(signal.SIGINT, previous)
    try:
        deadline = time.monotonic() + 300
        while _fits_in(out) == 0:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no fit finished in 300 s"
            time.sleep(0.1)
        assert proc.poll() is None, "the batch finished before it could be interrupted"
        if group:  # a terminal's Ctrl-C: the batch and its local workers
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    return subprocess.CompletedProcess(cmd, proc.returncode, stdout, stderr)


def _wait_until(what, timeout: float, poll: float = 0.5):
    deadline = time.monotonic() + timeout
    while True:
        value = what()
        if value or time.monotonic() > deadline:
            return value
        time.sleep(poll)


def _finished(out: Path) -> dict[tuple[str, str], str]:
    """(table name, model) -> finished_at of each good fit in the file or its journal
    (what a killed batch left to the next run)."""
    done = {(t["name"], m): f["finished_at"] for t in read_results(out)["tables"]
            for m, f in t["fits"].items() if f["status"] == "ok"}
    with contextlib.suppress(FileNotFoundError):
        for line in Path(f"{out}.journal").read_text().splitlines():
            with contextlib.suppress(ValueError):
                r = json.loads(line)
                if r.get("kind") == "fit" and r["status"] == "ok":
                    done[(Path(r["path"]).stem, r["model"])] = r["finished_at"]
    return done


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL],
                         ids=["SIGINT", "SIGTERM", "SIGKILL"])
def test_an_interrupted_batch_leaves_nothing_on_the_cluster(cluster, plugin_env, table_dir,
                                                            tmp_path, sig):
    address, client = cluster
    out = tmp_path / "results.h5"
    cmd = [sys.executable, "-m", "brdffit.cli", "batch", str(table_dir), "--models", MODELS,
           "--out", str(out), "--scheduler", address, "--quiet"]
    r = _interrupt_after_first_fit(cmd, out, sig, group=False, env=plugin_env)

    if sig == signal.SIGKILL:  # nothing to say, nothing cleaned up: the journal stays
        assert r.returncode == -signal.SIGKILL and r.stderr == "", r.stderr
    else:
        assert r.returncode == 130, r.stderr
        assert r.stderr.strip().splitlines() == [
            f"brdffit: interrupted; the finished fits are in {out}, run the same command "
            "again to go on"], r.stderr
        assert not os.path.exists(f"{out}.journal"), "the interrupt checkpointed the journal"
    # the scheduler dropped every task of the batch (a killed client: when its
    # connection closed)
    assert _wait_until(lambda: client.run_on_scheduler(scheduler_tasks) == 0, 30), \
        client.run_on_scheduler(scheduler_tasks)
    # the workers finish the fit each was running, and start none
    assert _wait_until(lambda: sum(client.run(executing).values()) == 0, 600), \
        client.run(executing)
    assert client.run_on_scheduler(scheduler_tasks) == 0

    # the file is whole and holds each fit that finished, by itself
    kept = _finished(out)
    assert kept and len(kept) < 2 * len(TABLES), kept
    # a fit is kept while its table's other model was still running: per-model resume
    assert any(len([m for n, m in kept if n == name]) == 1 for name in TABLES), kept

    # the same command again makes only the fits that are missing
    rerun = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=900,
                           env=plugin_env)
    assert rerun.returncode == 0, rerun.stderr
    assert f"{2 * len(TABLES) - len(kept)} fits on" in rerun.stdout, rerun.stdout
    final = _finished(out)
    assert {m for _, m in final} == set(MODELS.split(",")) and len(final) == 2 * len(TABLES)
    for key, finished_at in kept.items():  # kept, not made again
        assert final[key] == finished_at, key


def test_ctrl_c_on_local_workers_is_one_line(plugin_env, table_dir, tmp_path):
    """Ctrl-C at a terminal signals the process group: the batch and its local Dask
    worker processes. The user sees one line, none of the workers' tracebacks."""
    out = tmp_path / "results.h5"
    cmd = [sys.executable, "-m", "brdffit.cli", "batch", str(table_dir), "--models", MODELS,
           "--out", str(out), "--workers", "2", "--quiet"]
    r = _interrupt_after_first_fit(cmd, out, signal.SIGINT, group=True, env=plugin_env)
    assert r.returncode == 130, r.stderr
    assert r.stderr.strip().splitlines() == [
        f"brdffit: interrupted; the finished fits are in {out}, run the same command again "
        "to go on"], r.stderr
    assert json.loads(read_results(out)["attrs"]["models"]) == MODELS.split(",")


def test_ctrl_c_while_the_local_workers_start_is_one_line(table_dir, tmp_path):
    """A Ctrl-C as the worker processes appear, while they still import: each printed
    its KeyboardInterrupt traceback under the batch's line (they ignore SIGINT only
    once started). The batch holds the signal while its cluster starts, and the
    workers inherit that: one line, and the batch stops."""
    import psutil

    out = tmp_path / "results.h5"
    cmd = [sys.executable, "-m", "brdffit.cli", "batch", str(table_dir), "--models", "lambert",
           "--out", str(out), "--workers", "2", "--quiet"]
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # as above
    try:
        proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, start_new_session=True)
    finally:
        signal.signal(signal.SIGINT, previous)
    try:
        def workers_spawned() -> bool:
            with contextlib.suppress(psutil.Error):
                return any("--multiprocessing-fork" in c.cmdline()
                           for c in psutil.Process(proc.pid).children(recursive=True))
            return False

        assert _wait_until(workers_spawned, 120, poll=0.02), proc.communicate()
        os.killpg(proc.pid, signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    assert proc.returncode == 130, stderr
    assert stderr.strip().splitlines() == [
        f"brdffit: interrupted; the finished fits are in {out}, run the same command again "
        "to go on"], stderr


@pytest.mark.unit
def test_the_upstream_error_of_a_cancelled_call_that_had_not_started_is_not_shown():
    """distributed's ``sync`` cancels a client call on Ctrl-C; where the interrupt came
    before the call's coroutine ran, its ``cancel`` raised a NameError, which tornado
    logged with a traceback under the batch's one line (a fresh clone's run). Once the
    batch is stopping, that one record is dropped; any other, and any before, is kept."""
    import logging

    from brdffit.batch.job import stop_requested
    from brdffit.cli.batch import _LostSyncCancel

    def record(callback: str) -> logging.LogRecord:
        return logging.LogRecord("tornado.application", logging.ERROR, __file__, 1,
                                 "Exception in callback %r", (callback,), None)

    lost = "functools.partial(<function sync.<locals>.cancel at 0x7f9c58da7060>)"
    keep = _LostSyncCancel()
    stop_requested.clear()
    try:
        assert keep.filter(record(lost))  # not stopping: whatever it is, it is shown
        stop_requested.set()
        assert not keep.filter(record(lost))
        assert keep.filter(record("functools.partial(<function other at 0x1>)"))
        # the scheduler's word on a fit cancelled while gathered (a flake of
        # test_ctrl_c_on_local_workers_is_one_line, session 39)
        gather = logging.LogRecord("distributed.scheduler", logging.ERROR, __file__, 1,
                                   "Couldn't gather keys: %s", ({"fit_table-1": "forgotten"},),
                                   None)
        assert not keep.filter(gather)
    finally:
        stop_requested.clear()
