"""Helpers for the service tests: synthetic tables, and a real server on loopback.

:class:`Server` runs ``python -m brdffit.cli serve`` as a subprocess on
127.0.0.1 and a free port, with its own data dir (a real SQLite file), in its own
process group so that stopping it stops its worker processes too. Every wait is
bounded.
"""

from __future__ import annotations

import functools
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import httpx
import numpy as np

from brdffit.io import merl
from data_synth import make_table

#: name -> (model, params) of the synthetic tables the service tests share.
TABLES = {
    "ggx": ("ggx", {"kd": [0.2, 0.1, 0.05], "ks": [0.8, 0.8, 0.8], "alpha": 0.2, "f0": 0.6}),
    "lambert": ("lambert", {"kd": [0.5, 0.35, 0.2]}),
}

#: Fit options that keep a test's fit to a second or so.
FAST = {"samples": 2048, "starts": 1}
#: A job (the body of ``POST /v1/fits`` less ``table_id``) that runs for seconds in a
#: new worker process without compiling anything that the suite's warmup did not:
#: auto with default options, every candidate loaded, then fitted. For the tests that
#: catch a job while it runs (cancel it, kill its worker, stop the server).
SLOW_JOB = {"model": "auto"}


@functools.cache
def table(name: str) -> merl.MerlTable:
    """A synthetic table (made once per test session: about a second each)."""
    model, params = TABLES[name]
    t, _ = make_table(model, params, source=f"{name}.binary")
    return t


@functools.cache
def table_bytes(name: str) -> bytes:
    return merl.to_bytes(table(name))


def scaled_table_bytes(name: str, scale: float) -> bytes:
    """The table with every value times ``scale`` (a distinct table, made fast)."""
    t = table(name)
    return merl.to_bytes(merl.MerlTable.from_values(t.rgb * scale, t.mask))


def write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


class Process(NamedTuple):
    """One process as /proc shows it: ``state`` "Z" for a zombie; ``cmdline`` its
    arguments, NUL-separated (empty for a zombie)."""

    pid: int
    state: str
    parent: int
    group: int
    cmdline: bytes


def processes() -> Iterator[Process]:
    """Every process on this machine, from /proc; one that ends while it is read is
    left out."""
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            cmdline = (stat.parent / "cmdline").read_bytes()
            yield Process(int(stat.parent.name), fields[0], int(fields[1]), int(fields[2]),
                          cmdline)
        except (OSError, IndexError, ValueError):
            continue


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """``brdffit serve`` in a subprocess; use as a context manager."""

    def __init__(self, data_dir: Path, *, workers: int = 1, env: dict | None = None):
        self.data_dir = Path(data_dir)
        self.workers = workers
        self.extra_env = env or {}
        self.proc: subprocess.Popen | None = None
        self.port = 0
        self.log_path = self.data_dir / "server.log"

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self, timeout: float = 120.0, *, ready: bool = True) -> Server:
        """Start, and wait until ``/healthz`` answers 200 (``ready=False``: answers at all)."""
        self.data_dir.mkdir(parents=True, exist_ok=True)
        env = {k: v for k, v in os.environ.items() if k != "BRDFFIT_API_TOKEN"}
        env.update({"BRDFFIT_DATA_DIR": str(self.data_dir), "BRDFFIT_WORKERS": str(self.workers),
                    "PYTHONUNBUFFERED": "1"})
        env.update(self.extra_env)
        self.port = free_port()
        log = open(self.log_path, "ab")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "brdffit.cli", "serve", "--host", "127.0.0.1",
             "--port", str(self.port), "--log-level", "info"],
            env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
        )
        log.close()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}:\n{self.log()}")
            try:
                code = httpx.get(f"{self.url}/healthz", timeout=2.0).status_code
                if code == 200 or not ready:
                    return self
            except httpx.TransportError:
                pass
            time.sleep(0.2)
        self.stop()
        raise RuntimeError(f"server not up after {timeout} s:\n{self.log()}")

    def run_to_exit(self, timeout: float = 120.0) -> subprocess.CompletedProcess:
        """Run ``brdffit serve`` expecting it to refuse to start: its exit code and output."""
        env = {k: v for k, v in os.environ.items() if k != "BRDFFIT_API_TOKEN"}
        env.update({"BRDFFIT_DATA_DIR": str(self.data_dir), "PYTHONUNBUFFERED": "1"})
        env.update(self.extra_env)
        return subprocess.run(
            [sys.executable, "-m", "brdffit.cli", "serve", "--host", "127.0.0.1",
             "--port", str(free_port())],
            env=env, capture_output=True, text=True, timeout=timeout,
        )

    def log(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    def kill(self) -> None:
        """SIGKILL the server process alone, as a crash would (its workers are
        left to notice on their own)."""
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=30)

    def worker_pids(self) -> list[int]:
        """The server's worker processes (its 'spawn' children), from /proc."""
        return [p.pid for p in processes()
                if p.parent == self.proc.pid and b"spawn_main" in p.cmdline]

    def mapped_files(self, pid: int | None = None) -> set[str]:
        """The files the server process (or ``pid``) has mapped: its shared
        libraries, so what it has imported of JAX or matplotlib, from /proc."""
        maps = Path(f"/proc/{pid or self.proc.pid}/maps").read_text()
        return {line.split(None, 5)[5] for line in maps.splitlines() if len(line.split()) == 6}

    def group_alive(self) -> bool:
        """Does any process of the server's group (server, workers, multiprocessing's
        resource tracker) still run? A zombie does not count: an orphan's exit is
        reaped by PID 1 in its own time (~1.5 s in this sandbox), which
        ``os.killpg(pgid, 0)`` would wait for on every server stop."""
        return any(p.group == self.proc.pid and p.state != "Z" for p in processes())

    def wait_group_gone(self, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if not self.group_alive():
                return True
            time.sleep(0.2)
        return False

    def stop(self, timeout: float = 30.0) -> None:
        """SIGTERM (a clean shutdown), then SIGKILL to whatever of the group is left."""
        if self.proc is None:
            return
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                pass
        if not self.wait_group_gone(5.0):
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if self.proc.poll() is None:
            self.proc.wait(timeout=10)

    def __enter__(self) -> Server:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def wait_status(http: httpx.Client, job_id: str, statuses: tuple[str, ...],
                timeout: float = 180.0, poll: float = 0.05) -> dict:
    """Poll ``GET /v1/fits/{id}`` until its status is one of ``statuses``."""
    deadline = time.monotonic() + timeout
    while True:
        job = http.get(f"/v1/fits/{job_id}").json()
        if job["status"] in statuses:
            return job
        if time.monotonic() > deadline:
            raise TimeoutError(f"job {job_id} still {job['status']} after {timeout} s")
        time.sleep(poll)


def header(dims) -> bytes:
    return np.asarray(dims, dtype="<i4").tobytes()
