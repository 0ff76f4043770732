"""The container image, as far as it can be checked without a container runtime.

- The lock (requirements/service.lock) pins everything the image runs, Dask's
  cluster client included, and the build backend, each with its hash.
- The Dockerfile installs the dependencies from the lock before it copies the
  source, and installs the source with flags that cannot fetch anything, so a
  rebuild after a source edit downloads nothing; it ships data_synth (the shipped
  real materials) and its health check follows BRDFFIT_PORT.
- ``python -m api.healthcheck`` asks the port the server listens on, and a
  ``brdffit serve`` stopped by SIGTERM (``docker stop``) with a fit running says
  so in a line, with no traceback.

docs/service.md, "Docker", says what was run by hand beyond this (a fresh venv
installed the way the image does, with the network cut).
"""

from __future__ import annotations

import http.server
import os
import re
import shlex
import signal
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import httpx
import pytest
from packaging.requirements import Requirement
from packaging.specifiers import SpecifierSet
from packaging.utils import canonicalize_name

from api import healthcheck
from tests.api_fixtures import SLOW_JOB, free_port, table_bytes

ROOT = Path(__file__).resolve().parent.parent
LOCK = ROOT / "requirements" / "service.lock"
REQUIRES = ROOT / "requirements" / "service.requires.json"


def lock_entries() -> dict[str, tuple[str, list[str]]]:
    """name (canonical) -> (version, sha256 hashes) of each pin in the lock."""
    text = re.sub(r"\\\n\s*", " ", LOCK.read_text())
    entries = {}
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        spec, *opts = line.split()
        name, _, version = spec.partition("==")
        hashes = [o.removeprefix("--hash=sha256:") for o in opts if o.startswith("--hash=sha256:")]
        entries[canonicalize_name(name)] = (version, hashes)
    return entries


def lock_requires() -> dict[str, dict]:
    """name (canonical) -> {"version", "requires_dist"} of each pin of the lock, as that
    version declares them (``requirements/lock_from_report.py`` writes it with the lock)."""
    import json

    return {canonicalize_name(k): v for k, v in json.loads(REQUIRES.read_text()).items()}


def dockerfile() -> list[tuple[str, str]]:
    """The Dockerfile's instructions, (KEYWORD, arguments), continuations joined."""
    text = (ROOT / "Dockerfile").read_text()
    lines = [ln for ln in text.splitlines() if not ln.lstrip().startswith("#")]
    joined = re.sub(r"\\\n", " ", "\n".join(lines))
    out = []
    for line in joined.splitlines():
        if line.strip():
            keyword, _, rest = line.strip().partition(" ")
            out.append((keyword.upper(), rest.strip()))
    return out


@pytest.mark.contract
def test_the_lock_pins_every_package_with_a_hash():
    entries = lock_entries()
    assert len(entries) > 40
    for name, (version, hashes) in entries.items():
        assert re.fullmatch(r"[0-9][0-9A-Za-z.+!-]*", version), (name, version)
        assert hashes and all(re.fullmatch(r"[0-9a-f]{64}", h) for h in hashes), name


@pytest.mark.contract
def test_the_lock_holds_the_service_and_batch_extras_closure():
    """Every requirement of brdffit[service,batch], recursively (markers evaluated for
    Linux, CPython 3.11), is pinned: dask[distributed] for BRDFFIT_DASK_SCHEDULER."""
    entries = lock_entries()
    assert {"dask", "distributed"} <= set(entries)
    requires = lock_requires()
    # the record is of the lock's own versions, every one of them
    assert {n: (r["version"],) for n, r in requires.items()} == {
        n: (v,) for n, (v, _) in entries.items()}
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    todo = [Requirement(r) for r in project["dependencies"]]
    todo += [Requirement(r) for extra in ("service", "batch")
             for r in project["optional-dependencies"][extra]]
    env = {"sys_platform": "linux", "platform_system": "Linux", "python_version": "3.11",
           "implementation_name": "cpython", "platform_python_implementation": "CPython",
           "platform_machine": "x86_64", "os_name": "posix"}
    seen: set[tuple[str, frozenset]] = set()
    missing = []
    while todo:
        req = todo.pop()
        name = canonicalize_name(req.name)
        if (name, frozenset(req.extras)) in seen:
            continue
        seen.add((name, frozenset(req.extras)))
        if name not in entries:
            missing.append(str(req))
            continue
        assert entries[name][0] in req.specifier or not req.specifier, (str(req), entries[name])
        # What the pinned package needs in turn: its own metadata, recorded beside the
        # lock when it was made. The installed package's was read here, and a newer
        # release installed by the suite's fresh environment broke the test (dask
        # 2026.11.0 requires distributed 2026.11.x; the lock holds 2026.8.x)
        for text in requires[name]["requires_dist"]:
            sub = Requirement(text)
            if sub.marker is None or any(sub.marker.evaluate({**env, "extra": e})
                                         for e in (req.extras or {""})):
                todo.append(sub)
    assert not missing, f"not in {LOCK.name}: {sorted(missing)}"


@pytest.mark.contract
def test_the_build_backend_is_pinned_in_the_lock():
    build = tomllib.loads((ROOT / "pyproject.toml").read_text())["build-system"]
    entries = lock_entries()
    for text in build["requires"]:
        req = Requirement(text)
        name = canonicalize_name(req.name)
        assert name in entries, f"build requirement {text} is not in the lock"
        assert entries[name][0] in SpecifierSet(str(req.specifier)), (text, entries[name])


@pytest.mark.contract
def test_no_pip_step_after_the_source_copy_can_reach_the_network():
    steps = dockerfile()
    assert steps[0][0] == "FROM"
    copies = [i for i, (k, _) in enumerate(steps) if k == "COPY"]
    lock_copy = next(i for i in copies if "service.lock" in steps[i][1])
    source_copies = [i for i in copies if i != lock_copy]
    assert source_copies and min(source_copies) > lock_copy
    first_source = min(source_copies)
    pip_runs = [(i, args) for i, (k, args) in enumerate(steps) if k == "RUN" and "pip " in args]
    before = [args for i, args in pip_runs if i < first_source]
    after = [args for i, args in pip_runs if i > first_source]
    # the dependency layer: the lock alone, checked by hash
    assert len(before) == 1
    assert "--require-hashes" in before[0] and "-r requirements/service.lock" in before[0]
    assert after, "the source is never installed"
    for args in after:
        for command in args.split("&&"):
            words = shlex.split(command)
            if "pip" in words and "install" in words:
                assert {"--no-deps", "--no-build-isolation", "--no-index"} <= set(words), command


@pytest.mark.contract
def test_the_image_ships_data_synth_and_its_weights():
    steps = dockerfile()
    copied = {args.split()[0] for k, args in steps if k == "COPY"}
    assert {"brdffit", "api", "data_synth", "pyproject.toml"} <= copied
    package_data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-data"]
    assert "nbrdf/merl_nbrdf.zip" in package_data["data_synth"]
    assert (ROOT / "data_synth" / "nbrdf" / "merl_nbrdf.zip").stat().st_size > 100_000
    # nothing the Dockerfile copies is kept out of the build context
    ignored = {ln.strip().rstrip("/") for ln in (ROOT / ".dockerignore").read_text().splitlines()
               if ln.strip() and not ln.startswith("#")}
    assert not copied & ignored, copied & ignored


@pytest.mark.contract
def test_the_server_and_the_health_check_share_the_port_variable():
    steps = dockerfile()
    env = " ".join(args for k, args in steps if k == "ENV")
    assert re.search(r"\bBRDFFIT_PORT=\d+", env)
    healthcheck_cmd = next(args for k, args in steps if k == "HEALTHCHECK")
    assert '"api.healthcheck"' in healthcheck_cmd and "8000" not in healthcheck_cmd
    cmd = next(args for k, args in steps if k == "CMD")
    # no --port: brdffit serve takes BRDFFIT_PORT, the variable the check reads
    assert '"serve"' in cmd and "--port" not in cmd


@pytest.mark.unit
def test_healthcheck_port_comes_from_the_environment():
    assert healthcheck.port({}) == 8000
    assert healthcheck.port({"BRDFFIT_PORT": " 9123 "}) == 9123
    for bad in ("http", "0", "70000"):
        with pytest.raises(ValueError, match="BRDFFIT_PORT"):
            healthcheck.port({"BRDFFIT_PORT": bad})


@pytest.mark.unit
def test_healthcheck_answers_by_the_status_of_healthz(monkeypatch):
    status = {"code": 200}

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 - the stdlib's name
            self.send_response(status["code"] if self.path == "/healthz" else 404)
            self.end_headers()
            self.wfile.write(b'{"problems": ["disk full"]}')

        def log_message(self, *args):
            pass

    server = http.server.HTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        monkeypatch.setenv("BRDFFIT_PORT", str(server.server_address[1]))
        assert healthcheck.check() is None
        status["code"] = 503
        assert "503" in healthcheck.check() and "disk full" in healthcheck.check()
        monkeypatch.setenv("BRDFFIT_PORT", str(free_port()))
        assert "refused" in healthcheck.check().lower()
    finally:
        server.shutdown()
        server.server_close()


@pytest.mark.system
def test_serve_on_brdffit_port_then_a_clean_stop_mid_fit(tmp_path):
    """``brdffit serve`` with no --port listens on BRDFFIT_PORT, the health check
    finds it there, and SIGTERM with a fit running logs the job's return to the
    queue and no traceback (it used to log 'Future exception was never retrieved'
    with an EOFError from the killed worker's pipe)."""
    port = free_port()
    env = {**os.environ, "BRDFFIT_PORT": str(port), "BRDFFIT_DATA_DIR": str(tmp_path / "data"),
           "BRDFFIT_WORKERS": "1", "PYTHONUNBUFFERED": "1"}
    env.pop("BRDFFIT_API_TOKEN", None)
    log_path = tmp_path / "server.log"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen([sys.executable, "-m", "brdffit.cli", "serve"], env=env,
                                stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    check = [sys.executable, "-m", "api.healthcheck"]
    try:
        deadline = time.monotonic() + 120
        while subprocess.run(check, env=env, capture_output=True).returncode != 0:
            assert proc.poll() is None, log_path.read_text()
            assert time.monotonic() < deadline, log_path.read_text()
            time.sleep(0.5)
        other = subprocess.run(check, env={**env, "BRDFFIT_PORT": str(free_port())},
                               capture_output=True, text=True)
        assert other.returncode == 1 and other.stderr.startswith("unhealthy: ")
        assert "Traceback" not in other.stderr

        with httpx.Client(base_url=url, timeout=60) as http:
            table = http.post("/v1/tables", content=table_bytes("ggx"),
                              headers={"content-type": "application/octet-stream"}).json()["id"]
            # long enough to be running at the SIGTERM
            answer = http.post("/v1/fits", json={"table_id": table, **SLOW_JOB})
            assert answer.status_code == 202, answer.text
            job = answer.json()
            deadline = time.monotonic() + 120
            while http.get(f"/v1/fits/{job['id']}").json()["status"] != "running":
                assert time.monotonic() < deadline
                time.sleep(0.1)
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
    log = log_path.read_text()
    assert "1 running job(s) back in the queue" in log, log
    assert "Traceback" not in log and "never retrieved" not in log, log
