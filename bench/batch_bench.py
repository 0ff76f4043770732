"""Batch throughput: tables x models fitted per minute with 1 and 2 local workers.

    python -m bench.batch_bench            # writes bench/results/batch.{json,md}

Each run (by default 1, 2, 1, 2 workers, 24 tables x 3 models) fits the same
synthetic noise-free tables into a fresh results file on a fresh LocalCluster,
so every run pays the same start-up: worker processes, JAX import, tracing the
fits (XLA compilation comes from the persistent cache after the first run). Two figures per run:

- end to end: fits / wall time of the whole ``run_batch`` call;
- steady: fits / time once every worker has finished its first table, i.e.
  with compiled fits in every worker: what a long batch approaches.

The machine may be shared: CPU idle before each run, the load average before
and after, and the CPU seconds the batch used are recorded beside the figures.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime

from brdffit import __version__, jsonout
from brdffit.batch.job import run_batch
from brdffit.fitting.options import FitOptions
from brdffit.request import FitRequest

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")

#: Table k uses model TABLE_MODELS[k % 3] with parameters stepped by k, so
#: tables differ (the solver takes different paths) but stay easy to recover.
TABLE_MODELS = ("ggx", "beckmann", "lambert")


def make_tables(directory: str, n: int) -> list[str]:
    from data_synth import make_table
    from data_synth.synth import write_table

    paths = []
    for k in range(n):
        model = TABLE_MODELS[k % len(TABLE_MODELS)]
        j = (k // len(TABLE_MODELS)) % 10  # keeps every parameter inside its range
        params = {
            "ggx": {"alpha": 0.06 + 0.03 * j, "kd": [0.1 + 0.02 * j, 0.15, 0.2]},
            "beckmann": {"alpha": 0.1 + 0.03 * j, "f0": 0.5 + 0.05 * j},
            "lambert": {"kd": [0.5, 0.3 + 0.02 * j, 0.2]},
        }[model]
        table, truth = make_table(model, params, source=f"bench-{k}")
        path = os.path.join(directory, f"bench{k:03d}_{model}.binary")
        write_table(path, table, truth)
        paths.append(path)
    return paths


def cpu_idle_pct(seconds: float = 3.0) -> float | None:
    """Share of CPU time idle over ``seconds`` (Linux /proc/stat): how much of the
    machine was free for the run that follows."""
    def sample():
        with open("/proc/stat") as f:
            values = [int(v) for v in f.readline().split()[1:9]]
        return values[3], sum(values)

    try:
        idle0, total0 = sample()
        time.sleep(seconds)
        idle1, total1 = sample()
    except OSError:
        return None
    return round(100.0 * (idle1 - idle0) / max(1, total1 - total0), 1)


def measure(paths: list[str], models: list[str], options: FitOptions, workers: int,
            out: str) -> dict:
    finished: list[tuple[float, str, int]] = []  # (time, worker, fits)
    idle_before = cpu_idle_pct()
    load_before = os.getloadavg()
    cpu0 = _cpu_s()
    t0 = time.monotonic()
    summary = run_batch(paths, FitRequest(models=tuple(models), options=options), out,
                        workers=workers, progress=False,
                        on_result=lambda t, fits: finished.append(
                            (time.monotonic(), t.worker, len(fits))))
    wall = time.monotonic() - t0
    cpu = _cpu_s() - cpu0
    first = {}
    for t, w, _ in finished:
        first.setdefault(w, t)
    warm_from = max(first.values())
    later = [(t, n) for t, w, n in finished if t > warm_from]
    steady_s = (finished[-1][0] - warm_from) if later else float("nan")
    steady_fits = sum(n for _, n in later)
    return {
        "workers": workers,
        "tables": len(paths),
        "models": models,
        "fits": summary.fits,
        "failed": len(summary.failed_tables) + len(summary.failed_fits),
        "wall_s": round(wall, 2),
        "fits_per_min": round(60 * summary.fits / wall, 1),
        "first_result_s": round(finished[0][0] - t0, 2),
        "steady_fits": steady_fits,
        "steady_fits_per_min": round(60 * steady_fits / steady_s, 1) if later else None,
        "workers_seen": len(first),
        "cpu_s": round(cpu, 1),
        "cpu_s_per_fit": round(cpu / max(1, summary.fits), 2),
        "cpu_idle_before_pct": idle_before,
        "loadavg_before": [round(x, 2) for x in load_before],
        "loadavg_after": [round(x, 2) for x in os.getloadavg()],
    }


def _cpu_s() -> float:
    """CPU seconds of this process and its finished children: the local workers
    are children, joined when their cluster closes, so a run's delta is the
    whole batch's CPU, start-up included, whoever else shares the machine."""
    import resource

    me, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(
        resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + children.ru_utime + children.ru_stime


def _git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=HERE, text=True,
                              capture_output=True, timeout=10).stdout.strip()
    except OSError:
        return ""


def to_markdown(report: dict) -> str:
    o = report["options"]
    lines = [
        "# Batch throughput (`python -m bench.batch_bench`)",
        "",
        f"{report['tables']} synthetic tables x {len(report['models'])} models "
        f"({', '.join(report['models'])}) = {report['tables'] * len(report['models'])} fits "
        f"per run; fit options: samples={o['samples']}, starts={o['starts']}, "
        f"solver={o['solver']}, precision={o['precision']}, max_steps={o['max_steps']}.",
        f"Machine: {report['machine']['cpus']} CPUs ({report['machine']['processor']}), "
        f"brdffit {report['brdffit_version']} ({report['commit']}), {report['date']}.",
        "",
        "| workers | wall (s) | fits/min end to end | fits/min steady | first result (s) "
        "| CPU s per fit | CPU idle before | load avg before/after |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in report["runs"]:
        lines.append(
            f"| {r['workers']} | {r['wall_s']} | {r['fits_per_min']} | "
            f"{r['steady_fits_per_min']} | {r['first_result_s']} | {r['cpu_s_per_fit']} | "
            f"{r['cpu_idle_before_pct']} % | "
            f"{r['loadavg_before'][0]} / {r['loadavg_after'][0]} |")
    lines += ["", "Mean per worker count:", "",
              "| workers | runs | fits/min end to end | fits/min steady |", "|---|---|---|---|"]
    for w, m in report["mean_by_workers"].items():
        lines.append(f"| {w} | {m['runs']} | {m['fits_per_min']} | {m['steady_fits_per_min']} |")
    lines += [
        "",
        "End to end includes starting the local cluster and each worker's first fits "
        "(JAX tracing; XLA binaries come from the persistent compilation cache). Steady "
        "counts only results after every worker has finished its first table.",
        "CPU s per fit: CPU time of the batch process and its workers (start-up included) "
        "per fit, which other load on the machine does not inflate much. CPU idle is "
        "measured over 3 s just before each run; a load average above the CPU count means "
        "other processes shared the machine during the run.",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; ``argv`` as on the command line (None: the defaults, so
    that ``bench/__main__.py`` can call ``main()`` whatever its own arguments)."""
    ap = argparse.ArgumentParser(prog="python -m bench.batch_bench",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--tables", type=int, default=24)
    ap.add_argument("--models", default="ggx,beckmann,lambert")
    ap.add_argument("--workers", default="1,2,1,2",
                    help="comma-separated worker counts, run in this order (alternating "
                         "spreads the drift of a shared machine's load over both)")
    ap.add_argument("--samples", type=int, default=8192)
    ap.add_argument("--starts", type=int, default=1)
    ap.add_argument("--out-dir", default=RESULTS)
    args = ap.parse_args(argv or [])
    models = [m for m in args.models.split(",") if m]
    options = FitOptions(samples=args.samples, starts=args.starts)
    runs = []
    with tempfile.TemporaryDirectory(prefix="brdffit-batch-bench-") as tmp:
        print(f"making {args.tables} synthetic tables in {tmp}", file=sys.stderr)
        paths = make_tables(tmp, args.tables)
        for i, w in enumerate(int(x) for x in args.workers.split(",")):
            # a fresh file per run: the same file again would resume, with nothing to do
            r = measure(paths, models, options, w, os.path.join(tmp, f"run{i}-w{w}.h5"))
            print(f"{w} worker(s): {r['fits']} fits in {r['wall_s']} s, "
                  f"{r['fits_per_min']} fits/min end to end, "
                  f"{r['steady_fits_per_min']} steady", file=sys.stderr)
            runs.append(r)
    by_workers = {}
    for w in sorted({r["workers"] for r in runs}):
        mine = [r for r in runs if r["workers"] == w]
        steady = [r["steady_fits_per_min"] for r in mine if r["steady_fits_per_min"]]
        by_workers[str(w)] = {
            "runs": len(mine),
            "fits_per_min": round(sum(r["fits_per_min"] for r in mine) / len(mine), 1),
            "steady_fits_per_min": round(sum(steady) / len(steady), 1) if steady else None,
        }
    report = {
        "benchmark": "batch",
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "brdffit_version": __version__,
        "commit": _git_commit(),
        "machine": {"cpus": os.cpu_count(), "processor": platform.processor() or
                    platform.machine(), "python": platform.python_version()},
        "tables": args.tables,
        "models": models,
        "options": options.to_dict(),
        "runs": runs,
        "mean_by_workers": by_workers,
    }
    os.makedirs(args.out_dir, exist_ok=True)
    with open(os.path.join(args.out_dir, "batch.json"), "w") as f:
        jsonout.dump(report, f, indent=2)
        f.write("\n")
    with open(os.path.join(args.out_dir, "batch.md"), "w") as f:
        f.write(to_markdown(report))
    print(to_markdown(report))
    return 0 if all(r["failed"] == 0 for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
