"""``brdffit serve --warmup`` (env ``BRDFFIT_WARMUP``, which the image sets): the
default fits are compiled into the cache beside a server that answers at once, and
the warm-up goes when the server goes."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from tests.api_fixtures import Server, free_port, processes

pytestmark = pytest.mark.system


def _warmup_pids(server_pid: int) -> list[int]:
    return [p.pid for p in processes()
            if p.parent == server_pid and b"warmup" in p.cmdline.split(b"\0")]


def _wait_for(predicate, timeout: float, what: str, log) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f"{what} after {timeout} s:\n{log()}"
        time.sleep(0.2)


def test_the_server_answers_while_its_warmup_fills_an_empty_cache(tmp_path):
    cache = tmp_path / "cache"
    server = Server(tmp_path / "data", env={"BRDFFIT_CACHE_DIR": str(cache),
                                            "BRDFFIT_WARMUP": "lambert"})
    with server:
        # answering (the with-statement waited for /healthz), and the warm-up runs
        # beside it at the lowest priority
        pids = _warmup_pids(server.proc.pid)
        assert len(pids) == 1, server.log()
        nice = int(Path(f"/proc/{pids[0]}/stat").read_text().rsplit(")", 1)[1].split()[16])
        assert nice == 19
        _wait_for(lambda: "brdffit warmup: done" in server.log(), 300,
                  "no 'brdffit warmup: done'", server.log)
        log = server.log()
        assert f"brdffit warmup: cache {cache} (what it holds" in log
        line = next(ln for ln in log.splitlines() if ln.strip().startswith("lambert"))
        assert int(line.split("s ")[1].split(" compiled")[0]) > 0, line
        assert sorted(cache.glob("executables/*/solve_batch-*.xla")), log
        assert httpx.get(f"{server.url}/healthz").status_code == 200
        _wait_for(lambda: not _warmup_pids(server.proc.pid), 30, "warm-up still there",
                  server.log)
    assert "Traceback" not in server.log()


@pytest.mark.parametrize("how", [signal.SIGTERM, signal.SIGKILL])
def test_stopping_the_server_stops_its_warmup(tmp_path, how):
    server = Server(tmp_path / "data", env={"BRDFFIT_CACHE_DIR": str(tmp_path / "cache"),
                                            "BRDFFIT_WARMUP": "default"})
    server.start()
    try:
        pids = _warmup_pids(server.proc.pid)
        assert len(pids) == 1, server.log()
        server.proc.send_signal(how)  # uvicorn re-raises a SIGTERM once stopped
        assert server.proc.wait(timeout=60) in (0, -how), server.log()
        _wait_for(lambda: not Path(f"/proc/{pids[0]}").exists()
                  or b"warmup" not in Path(f"/proc/{pids[0]}/cmdline").read_bytes(),
                  30, "the warm-up outlived its server", server.log)
    finally:
        server.stop()


def test_an_unknown_warmup_model_is_a_one_line_error(tmp_path):
    r = subprocess.run([sys.executable, "-m", "brdffit.cli", "serve", "--warmup", "ggx,nope",
                        "--port", str(free_port()), "--data-dir", str(tmp_path)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.strip().splitlines() == [
        r.stderr.strip()] and "unknown model 'nope'" in r.stderr and "Traceback" not in r.stderr
