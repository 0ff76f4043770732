"""The service under pressure: many clients submit heavy fits at once to a real server.

    python -m bench.service_load                  # 20 clients, full-table ggx2, 2 starts
    python -m bench.service_load --quick          # 6 clients, small fits (a smoke run)

Starts ``brdffit serve`` (uvicorn) on 127.0.0.1 and a free port with its own data
dir and ``--workers`` worker processes; makes real tables from the shipped
materials (``POST /v1/materials/{name}``); then ``--clients`` threads, released
together, each submit ``--jobs`` fits and poll them to their end. Meanwhile the
resident memory (RSS, from /proc) of the server process and of each of its worker
processes is sampled every half second.

It checks, and exits 1 (with the reasons) when one fails:

- every accepted job (202) ends (``done``; ``failed`` or ``cancelled`` are counted
  and reported as failures), and the job listing holds exactly the accepted jobs;
- no answer is a 5xx;
- memory stays bounded while the queue is long: no worker above the service's own
  per-job memory estimate (``api.estimate``, the bound it refuses jobs by), and the
  server process itself within ``SERVER_GROWTH_MIB`` of its size before the load.

Each job's queue wait (``started_at - created_at``) and run time (``finished_at -
started_at``) go to ``bench/results/service_load.{json,md}`` with their medians and
90th percentiles.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from datetime import datetime
from pathlib import Path

import httpx

RESULTS = Path(__file__).with_name("results")
#: how much the server process (not its workers) may grow under load: it holds the
#: queue in SQLite, not in memory, so a long queue must not make it much bigger
SERVER_GROWTH_MIB = 300
#: a worker's peak over the service's estimate for one job: the estimate is a fit's
#: peak measured in a bare process, and a service worker also holds the API's and
#: matplotlib's imports (about 190 MiB idle)
ESTIMATE_MARGIN = 1.25
MiB = 1024 * 1024
TERMINAL = ("done", "failed", "cancelled")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _workers(pid: int) -> list[int]:
    """The server's fit worker processes: its 'spawn' children (not multiprocessing's
    resource tracker)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if (int(stat.read_text().rsplit(")", 1)[1].split()[1]) == pid
                    and b"spawn_main" in (stat.parent / "cmdline").read_bytes()):
                out.append(int(stat.parent.name))
        except (OSError, IndexError, ValueError):
            continue  # ended while we looked
    return out


def _rss_mib(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


class MemorySampler(threading.Thread):
    """RSS of the server and of each of its children, every ``interval_s``."""

    def __init__(self, server_pid: int, interval_s: float = 0.5):
        super().__init__(daemon=True)
        self.server_pid, self.interval_s = server_pid, interval_s
        self.samples: list[dict] = []  # {"t", "server", "workers": {pid: MiB}}
        self._done = threading.Event()
        self.t0 = time.monotonic()

    def sample(self) -> dict:
        workers = {pid: _rss_mib(pid) for pid in _workers(self.server_pid)}
        return {"t": round(time.monotonic() - self.t0, 2),
                "server": round(_rss_mib(self.server_pid), 1),
                "workers": {str(p): round(v, 1) for p, v in workers.items() if v}}

    def run(self) -> None:
        while not self._done.wait(self.interval_s):
            self.samples.append(self.sample())

    def stop(self) -> None:
        self._done.set()
        if self.is_alive():
            self.join(timeout=5)


def _pct(values: list[float], q: float) -> float | None:
    if not values:
        return None
    values = sorted(values)
    k = (len(values) - 1) * q
    lo, hi = int(k), min(int(k) + 1, len(values) - 1)
    return values[lo] + (values[hi] - values[lo]) * (k - lo)


def _seconds(a: str | None, b: str | None) -> float | None:
    if not a or not b:
        return None
    return (datetime.fromisoformat(b) - datetime.fromisoformat(a)).total_seconds()


def start_server(data_dir: Path, workers: int, env: dict) -> tuple[subprocess.Popen, str]:
    port = free_port()
    log = open(data_dir / "server.log", "ab")
    proc = subprocess.Popen(
        [sys.executable, "-m", "brdffit.cli", "serve", "--host", "127.0.0.1", "--port",
         str(port), "--data-dir", str(data_dir), "--workers", str(workers),
         "--log-level", "warning"],
        env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    log.close()
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError((data_dir / "server.log").read_text())
        try:
            if httpx.get(f"{url}/healthz", timeout=2).status_code == 200:
                return proc, url
        except httpx.TransportError:
            pass
        time.sleep(0.3)
    proc.kill()
    raise RuntimeError("the server did not answer /healthz in 180 s")


def stop_server(proc: subprocess.Popen) -> None:
    import signal

    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)


def client(url: str, requests: list[dict], barrier: threading.Barrier, out: list,
           statuses: list, deadline: float) -> None:
    """One client: submit its fits together with the others, then poll each to its end."""
    with httpx.Client(base_url=url, timeout=60) as http:
        barrier.wait()
        ids = []
        for body in requests:
            r = http.post("/v1/fits", json=body)
            statuses.append(r.status_code)
            if r.status_code == 202:
                ids.append(r.json()["id"])
        for job_id in ids:
            while True:
                r = http.get(f"/v1/fits/{job_id}")
                statuses.append(r.status_code)
                job = r.json() if r.status_code == 200 else {}
                if job.get("status") in TERMINAL or time.monotonic() > deadline:
                    out.append(job or {"id": job_id, "status": f"http {r.status_code}"})
                    break
                time.sleep(1.0)


def run(args) -> dict:
    from api.estimate import estimate
    from brdffit.request import FitRequest

    options = {"samples": None if args.samples == "all" else int(args.samples),
               "starts": args.starts, "max_steps": args.max_steps}
    env = {k: v for k, v in os.environ.items() if k != "BRDFFIT_API_TOKEN"}
    env["PYTHONUNBUFFERED"] = "1"
    with tempfile.TemporaryDirectory(prefix="brdffit-load-") as tmp:
        data_dir = Path(tmp)
        proc, url = start_server(data_dir, args.workers, env)
        sampler = MemorySampler(proc.pid)
        try:
            tables = []
            with httpx.Client(base_url=url, timeout=300) as http:
                for name in args.materials:
                    r = http.post(f"/v1/materials/{name}")
                    r.raise_for_status()
                    tables.append(r.json())
                idle = sampler.sample()
                sampler.start()
                requests = [
                    [{"table_id": tables[(c * args.jobs + j) % len(tables)]["id"],
                      **FitRequest.of(args.model, **options).to_dict()}
                     for j in range(args.jobs)]
                    for c in range(args.clients)]
                jobs: list[dict] = []
                statuses: list[int] = []
                barrier = threading.Barrier(args.clients)
                deadline = time.monotonic() + args.timeout
                t0 = time.monotonic()
                threads = [threading.Thread(target=client, args=(url, reqs, barrier, jobs,
                                                                 statuses, deadline))
                           for reqs in requests]
                for t in threads:
                    t.start()
                for t in threads:
                    t.join()
                wall = time.monotonic() - t0
                listing = http.get("/v1/fits", params={"limit": 500}).json()
        finally:
            sampler.stop()
            stop_server(proc)

    bins = max(t["summary"]["measured_bins"] for t in tables)
    bound = estimate(FitRequest.of(args.model, **options), bins)
    accepted = sum(s == 202 for s in statuses)
    by_status: dict[str, int] = {}
    for job in jobs:
        by_status[job["status"]] = by_status.get(job["status"], 0) + 1
    waits = [w for j in jobs if (w := _seconds(j.get("created_at"), j.get("started_at")))
             is not None]
    runs = [w for j in jobs if (w := _seconds(j.get("started_at"), j.get("finished_at")))
            is not None]
    peak_worker = max((v for s in sampler.samples for v in s["workers"].values()), default=0.0)
    peak_server = max((s["server"] for s in sampler.samples), default=0.0)
    peak_total = max((s["server"] + sum(s["workers"].values()) for s in sampler.samples),
                     default=0.0)
    problems = []
    if accepted != args.clients * args.jobs:
        problems.append(f"{accepted} of {args.clients * args.jobs} fits accepted (202)")
    if by_status.get("done", 0) != accepted:
        problems.append(f"not every accepted job is done: {by_status}")
    if listing["total"] != accepted:
        problems.append(f"the job listing holds {listing['total']} jobs, {accepted} accepted")
    if any(s >= 500 for s in statuses):
        problems.append(f"{sum(s >= 500 for s in statuses)} answers were 5xx")
    if peak_worker > ESTIMATE_MARGIN * bound.memory_mib:
        problems.append(f"a worker reached {peak_worker:.0f} MiB, over {ESTIMATE_MARGIN} x "
                        f"the service's own estimate {bound.memory_mib:.0f} MiB")
    most_workers = max((len(s["workers"]) for s in sampler.samples), default=0)
    if most_workers > args.workers:
        problems.append(f"{most_workers} worker processes at once, {args.workers} configured")
    if peak_server - idle["server"] > SERVER_GROWTH_MIB:
        problems.append(f"the server grew {peak_server - idle['server']:.0f} MiB under load "
                        f"(> {SERVER_GROWTH_MIB})")

    def stats(values):
        return {"n": len(values), "median_s": _round(statistics.median(values) if values
                                                      else None),
                "p90_s": _round(_pct(values, 0.9)), "max_s": _round(max(values, default=None))}

    return {
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "load_before": os.getloadavg()[0]},
        "setup": {"clients": args.clients, "jobs_per_client": args.jobs,
                  "workers": args.workers, "model": args.model, "options": options,
                  "materials": args.materials, "measured_bins": bins},
        "wall_s": round(wall, 1),
        "accepted": accepted, "by_status": by_status, "listing_total": listing["total"],
        "http_5xx": sum(s >= 500 for s in statuses), "requests": len(statuses),
        "queue_wait": stats(waits), "run": stats(runs),
        "memory_mib": {"server_idle": idle["server"],
                       "workers_idle": sorted(idle["workers"].values()),
                       "server_peak": peak_server, "worker_peak": round(peak_worker, 1),
                       "total_peak": round(peak_total, 1),
                       "estimate_per_job": round(bound.memory_mib),
                       "worker_peak_over_estimate": round(peak_worker / bound.memory_mib, 2),
                       "most_workers_at_once": most_workers,
                       "server_growth_limit": SERVER_GROWTH_MIB},
        "memory_timeline": sampler.samples[:: max(1, len(sampler.samples) // 120)],
        "problems": problems,
    }


def _round(v):
    return None if v is None else round(v, 1)


def markdown(r: dict) -> str:
    s, m = r["setup"], r["memory_mib"]
    lines = [
        "# The service under load (`python -m bench.service_load`)",
        "",
        f"{s['clients']} clients released together, each submitting {s['jobs_per_client']} "
        f"fit(s) of `{s['model']}` with `{json.dumps(s['options'])}` (`samples: null`: "
        f"every measured bin, {s['measured_bins']:,}) on the real materials "
        f"{', '.join(s['materials'])} (`POST /v1/materials/{{name}}`), to `brdffit serve` "
        f"on 127.0.0.1 with {s['workers']} worker process(es). {r['machine']['cpus']} CPUs, "
        f"shared (load average {r['machine']['load_before']:.1f} before the run).",
        "",
        "| | n | median | p90 | max |",
        "|---|---|---|---|---|",
    ]
    for key, label in (("queue_wait", "queue wait (created -> started)"),
                       ("run", "run (started -> finished)")):
        q = r[key]
        lines.append(f"| {label} | {q['n']} | {q['median_s']} s | {q['p90_s']} s | "
                     f"{q['max_s']} s |")
    lines += [
        "",
        f"- Wall time: {r['wall_s']} s. Accepted: {r['accepted']}; ended: "
        f"{json.dumps(r['by_status'])}; the job listing holds {r['listing_total']}; "
        f"5xx answers: {r['http_5xx']} of {r['requests']} requests.",
        f"- Memory (RSS): server {m['server_idle']:.0f} MiB idle, {m['server_peak']:.0f} MiB "
        f"at most (allowed growth {m['server_growth_limit']} MiB); workers "
        f"{', '.join(f'{w:.0f}' for w in m['workers_idle'])} MiB idle, {m['worker_peak']:.0f} "
        f"MiB at most, {m['worker_peak_over_estimate']} x the service's own estimate for one "
        f"such job ({m['estimate_per_job']:,} MiB; allowed: {ESTIMATE_MARGIN} x); at most "
        f"{m['most_workers_at_once']} worker processes at once; server and workers "
        f"together {m['total_peak']:.0f} MiB at most.",
        "- Result: " + ("every check passed." if not r["problems"]
                        else "FAILED: " + "; ".join(r["problems"])),
        "",
    ]
    return "\n".join(lines)


def parse(argv) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m bench.service_load", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--clients", type=int, default=20)
    p.add_argument("--jobs", type=int, default=1, help="fits each client submits")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--model", default="ggx2")
    p.add_argument("--samples", default="all", help="an integer, or 'all' (every bin)")
    p.add_argument("--starts", type=int, default=2)
    p.add_argument("--max-steps", type=int, default=32,
                   help="solver steps per start at most (these fits converge in about 20)")
    p.add_argument("--materials", type=lambda t: t.split(","),
                   default=["gold-metallic-paint", "blue-fabric"])
    p.add_argument("--timeout", type=float, default=1500.0,
                   help="give up polling after this long (the jobs then count as not ended)")
    p.add_argument("--quick", action="store_true",
                   help="6 clients, small ggx fits: a smoke run of a minute or two")
    p.add_argument("--out", default=str(RESULTS / "service_load"),
                   help="writes OUT.json and OUT.md ('' for none)")
    args = p.parse_args(argv)
    if args.quick:
        args.clients, args.model, args.samples, args.starts = 6, "ggx", "4096", 1
        args.max_steps = 64
    return args


def main(argv=None) -> int:
    args = parse(sys.argv[1:] if argv is None else argv)
    result = run(args)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out + ".json").write_text(json.dumps(result, indent=1) + "\n")
        Path(args.out + ".md").write_text(markdown(result))
    print(markdown(result))
    return 1 if result["problems"] else 0


if __name__ == "__main__":
    sys.exit(main())
