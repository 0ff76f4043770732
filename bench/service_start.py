"""How soon a new service answers, and what its front costs: ``brdffit serve`` to ``/healthz``.

    python -m bench.service_start                          # 5 starts of this checkout
    python -m bench.service_start --baseline /tmp/base     # and of another, alternately

Each start is a new ``brdffit serve`` on 127.0.0.1, a free port and an empty data
directory, with one worker. Measured: the wall time from the command to the first
``200`` from ``/healthz``; the server process's CPU seconds by then; its resident
memory (RSS, from /proc) three seconds later. The worker process imports JAX and
matplotlib as it starts, beside the server; it is not counted here. Medians to
``bench/results/service_start.{json,md}``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

from bench.machine import machine
from bench.service_load import free_port
from brdffit import jsonout

RESULTS = Path(__file__).with_name("results")
ROOT = Path(__file__).resolve().parents[1]


def _proc_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _proc_rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for process {pid}")


def one_start(checkout: Path, timeout: float = 120.0) -> dict:
    """One ``brdffit serve`` from ``checkout``, timed to its first healthy answer."""
    port = free_port()
    with tempfile.TemporaryDirectory(prefix="brdffit-start-") as data:
        env = {**os.environ, "BRDFFIT_DATA_DIR": data, "BRDFFIT_WORKERS": "1",
               "PYTHONPATH": str(checkout)}
        log = open(os.path.join(data, "serve.log"), "w+")  # noqa: SIM115 - closed below
        t0 = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, "-m", "brdffit.cli", "serve", "--port", str(port),
             "--log-level", "warning"], cwd=checkout, env=env,
            stdout=subprocess.DEVNULL, stderr=log)
        try:
            while True:
                try:
                    urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=1).read()
                    break
                except OSError:
                    if proc.poll() is not None:
                        log.seek(0)
                        raise RuntimeError(f"server exited: {log.read()}")
                    if time.perf_counter() - t0 > timeout:
                        raise RuntimeError(f"no healthy answer in {timeout:g} s") from None
                    time.sleep(0.02)
            healthy_s = time.perf_counter() - t0
            cpu_s = _proc_cpu_s(proc.pid)
            time.sleep(3.0)
            return {"healthy_s": healthy_s, "server_cpu_s": cpu_s,
                    "server_rss_mib": _proc_rss_mib(proc.pid)}
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            log.close()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.service_start")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--baseline", metavar="CHECKOUT",
                    help="also start the service of this checkout, alternately with this one")
    ap.add_argument("--out", default=RESULTS)
    args = ap.parse_args(argv)
    checkouts = {"this checkout": ROOT}
    if args.baseline:
        checkouts[f"baseline ({args.baseline})"] = Path(args.baseline).resolve()
    runs: dict[str, list[dict]] = {name: [] for name in checkouts}
    for i in range(args.repeats):
        for name, checkout in checkouts.items():
            runs[name].append(one_start(checkout))
            print(f"{i + 1}/{args.repeats} {name}: {runs[name][-1]}", file=sys.stderr)
    report = {"machine": machine(), "repeats": args.repeats, "runs": runs,
              "medians": {name: {k: statistics.median(r[k] for r in rs) for k in rs[0]}
                          for name, rs in runs.items()}}
    lines = ["# A new service: `brdffit serve` to its first healthy answer",
             "", f"{report['machine']['cpu']}, {report['machine']['cores']} cores, "
             f"{report['machine']['date']}; `python -m bench.service_start"
             f"{' --baseline ' + args.baseline if args.baseline else ''}`; medians of "
             f"{args.repeats} starts, run alternately. The server process only (its worker "
             "imports JAX and matplotlib beside it, not counted).", "",
             "| | healthy after | server CPU by then | server RSS 3 s later | each start |",
             "|---|---|---|---|---|"]
    for name, med in report["medians"].items():
        each = ", ".join(f"{r['healthy_s']:.2f}" for r in runs[name])
        lines.append(f"| {name} | {med['healthy_s']:.2f} s | {med['server_cpu_s']:.2f} s | "
                     f"{med['server_rss_mib']:.0f} MiB | {each} s |")
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "service_start.json"), "w") as f:
        jsonout.dump(report, f, indent=1)
    Path(args.out, "service_start.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
