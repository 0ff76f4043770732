"""What a service job costs, measured, beside what the service estimated before it queued it.

    python -m bench.job_shapes [--table PATH] [--repeats 2] [--cold]
        # writes bench/results/job_shapes.{json,md}

Each job shape (a fit request the service takes: the default fit, every bin with one
and four starts, ggx2, auto, the render loss, large subsamples, the bounded fit, auto
among glTF's and MaterialX's candidates, layered models) runs
in a process of its own, as a service worker runs a job: ``brdffit.request.run`` on a
real MERL table read from disk. Measured per run: the wall time of reading the table
and fitting (imports not counted: a worker has made them before its first job), and
the process's peak resident memory (``ru_maxrss``, imports included: the worker holds
them too). The largest of ``--repeats`` runs of each shape is compared with
``api.estimate.estimate`` for the same request: the estimate must be above every
measurement (a job it accepts fits in what it promised) and within 2x of it (it does
not refuse jobs the machine can do).

By default the runs find brdffit's compiled programs in its cache (``--cache-dir``,
else ``~/.cache/brdffit``), as a worker does after ``brdffit warmup`` or its first jobs:
one run of each shape that is not counted fills it first. ``--cold`` gives each run an
empty cache, so it compiles every program it needs.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.machine import machine
from brdffit import jsonout

RESULTS = Path(__file__).with_name("results")
ROOT = Path(__file__).resolve().parents[1]
TABLE = ROOT / ".bench-cache" / "nbrdf" / "gold-metallic-paint.binary"

#: name -> the request's ``FitRequest.of`` keywords (``model`` among them)
SHAPES: dict[str, dict] = {
    "default ggx": {"model": "ggx"},
    "every bin, 1 start": {"model": "ggx", "samples": None, "starts": 1},
    "every bin, 4 starts": {"model": "ggx", "samples": None, "starts": 4},
    "ggx2": {"model": "ggx2"},
    "auto": {"model": "auto"},
    "render loss": {"model": "ggx", "loss": "render"},
    "ggx2, every bin, 4 starts": {"model": "ggx2", "samples": None, "starts": 4},
    "ggx, 131,072 samples x 8 starts": {"model": "ggx", "samples": 131072, "starts": 8},
    "ggx2, 262,144 samples x 4 starts": {"model": "ggx2", "samples": 262144, "starts": 4},
    "bounded ggx": {"model": "ggx", "physical": True},
    "auto, render loss": {"model": "auto", "loss": "render"},
    # what a fit that does not look good is told to try next (brdffit.fitting.quality),
    # and the layered models: a step costs them far more than GGX's
    "auto, glTF's candidates": {"model": "auto", "candidates": ["gltf"]},
    "auto, MaterialX's candidates": {"model": "auto", "candidates": ["materialx"]},
    "standard_surface_coat": {"model": "standard_surface_coat"},
    "gltf_iridescence": {"model": "gltf_iridescence"},
    "rough_plastic": {"model": "rough_plastic"},
    "ggx4": {"model": "ggx4"},
}

#: One job, in a process of its own: reads the table, runs the request, prints the figures.
_ONE_JOB = r"""
import json, resource, sys, time
from brdffit.io import merl
from brdffit.request import FitRequest, run
spec = json.loads(sys.argv[1])
request = FitRequest.of(spec.pop("model"), **spec)
t0 = time.perf_counter()
report = run(merl.read(sys.argv[2]), request)
wall = time.perf_counter() - t0
r = report.chosen_fit
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"wall_s": wall, "peak_rss_mib": peak, "starts": r.starts,
                  "steps": r.steps, "result": r.result, "notes": r.notes}))
"""


def table_on_disk(table: Path) -> Path:
    """``table``, rebuilt from its MERL network where it is not on disk yet (a cache)."""
    if table.exists():
        return table
    from data_synth.nbrdf import cached_table

    return Path(cached_table(table.stem, str(table.parent)))


def run_one(spec: dict, table: Path, cache_dir: str | None) -> dict:
    """One job in a new process; ``cache_dir`` None: brdffit's default cache, whatever
    this process's ``BRDFFIT_CACHE_DIR`` says (the measured jobs are a service worker's,
    which uses its own)."""
    env = {k: v for k, v in os.environ.items() if k != "BRDFFIT_CACHE_DIR"}
    if cache_dir is not None:
        env["BRDFFIT_CACHE_DIR"] = cache_dir
    out = subprocess.run([sys.executable, "-c", _ONE_JOB, json.dumps(spec), str(table)],
                         env=env, cwd=ROOT, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"{spec}: {out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def estimated(spec: dict, usable_bins: int) -> dict:
    from api.estimate import estimate
    from brdffit.request import FitRequest

    spec = dict(spec)
    cost = estimate(FitRequest.of(spec.pop("model"), **spec), usable_bins)
    return cost.to_dict() | {"reference_seconds": cost.reference_seconds}


def learned(res: dict) -> None:
    """What a server that had run every other shape here would estimate for each
    (``api.estimate.machine_factor`` from their runs: leave-one-out, so that no row
    is judged by a factor learned from itself); set as each row's ``learned``."""
    from api.estimate import machine_factor

    for row in res["rows"]:
        others = [(r["estimate"]["reference_seconds"], run["wall_s"])
                  for r in res["rows"] if r is not row for run in r["runs"]]
        factor = machine_factor(others)
        seconds = factor * row["estimate"]["reference_seconds"]
        row["learned"] = {"machine": factor, "seconds": seconds,
                          "time_ratio": seconds / row["wall_s"]}


def run(table: Path, repeats: int, cold: bool, shapes: list[str],
        cache_dir: str | None = None) -> dict:
    from brdffit.fitting.sampling import usable_bins
    from brdffit.io import merl

    usable = int(usable_bins(merl.read(str(table)), None).usable.sum())
    rows = []
    for name in shapes:
        spec = SHAPES[name]
        runs = []
        if not cold:
            run_one(spec, table, cache_dir)  # fills the cache; not counted
        for _ in range(repeats):
            with tempfile.TemporaryDirectory(prefix="brdffit-cold-") as empty:
                runs.append(run_one(spec, table, empty if cold else cache_dir))
        est = estimated(spec, usable)
        peak = max(r["peak_rss_mib"] for r in runs)
        wall = max(r["wall_s"] for r in runs)
        rows.append({"shape": name, "request": spec, "runs": runs,
                     "peak_rss_mib": peak, "wall_s": wall, "estimate": est,
                     "memory_ratio": est["memory_mib"] / peak,
                     "time_ratio": est["seconds"] / wall})
        print(f"{name}: {peak:.0f} MiB, {wall:.1f} s; estimate {est['memory_mib']} MiB "
              f"({est['memory_mib'] / peak:.2f}x), {est['seconds']} s "
              f"({est['seconds'] / wall:.2f}x)", flush=True)
    res = {"machine": machine(), "table": table.name, "usable_bins": usable,
           "repeats": repeats, "cold": cold, "rows": rows}
    learned(res)
    return res


def markdown(res: dict) -> str:
    ok = all(1.0 <= r["memory_ratio"] <= 2.0 and 1.0 <= r["time_ratio"] <= 2.0
             for r in res["rows"])
    ok_learned = all(1.0 <= r["memory_ratio"] and 1.0 <= r["learned"]["time_ratio"] <= 2.0
                     for r in res["rows"])
    never_under = all(1.0 <= r["learned"]["time_ratio"] for r in res["rows"])
    m = res["machine"]
    lines = [
        "## Job shapes: measured cost against the service's estimate", "",
        f"{m['cpu']}, {m['cores']} cores; brdffit {m['brdffit']}, JAX {m['jax']}; {m['date']} "
        f"(load average {m['loadavg']}). Table {res['table']} ({res['usable_bins']:,} usable "
        f"bins); each shape run {res['repeats']}x, each run a new process "
        + ("with an empty compilation cache" if res["cold"] else
           "finding its programs in brdffit's cache") + "; the largest run is shown.", "",
        ("From an empty cache a job compiles its programs first, which the estimate does "
         "not count (api/estimate.py: `brdffit serve --warmup` fills the cache before "
         "jobs come): these runs show what that costs." if res["cold"] else
         "The estimate must be at least the measurement and at most 2x it: "
         + ("**every shape is**." if ok else "**not every shape is** (marked below).")
         + " With the machine factor a server learns from its jobs (`api.estimate."
         "machine_factor`, here from every other shape's runs: never below 1, so it only "
         "raises the estimate on a machine slower than the constants'), "
         + ("**every shape is**." if ok_learned else
            "**the estimate is never under the measurement**, but not every shape is within "
            "2x." if never_under else "**not every shape is**.")), "",
        "| shape | peak RSS (MiB) | estimate (MiB) | ratio | wall (s) | estimate (s) | ratio "
        "| learned factor | learned estimate (s) | ratio | starts | steps |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in res["rows"]:
        est, run0 = r["estimate"], r["runs"][0]
        mark = lambda x: f"{x:.2f}" + ("" if 1.0 <= x <= 2.0 else " **!**")  # noqa: E731
        got = r["learned"]
        lines.append(f"| {r['shape']} | {r['peak_rss_mib']:.0f} | {est['memory_mib']} | "
                     f"{mark(r['memory_ratio'])} | {r['wall_s']:.1f} | {est['seconds']} | "
                     f"{mark(r['time_ratio'])} | {got['machine']:.2f} | {got['seconds']:.1f} | "
                     f"{mark(got['time_ratio'])} | {run0['starts']} | {run0['steps']} |")
    lines += ["", "Wall time: reading the table and `brdffit.request.run` (a worker's "
              "imports not counted); peak RSS: the whole process (`ru_maxrss`)."]
    if res.get("note"):
        lines += ["", res["note"]]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.job_shapes")
    ap.add_argument("--table", type=Path, default=TABLE)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--cold", action="store_true", help="an empty compilation cache per run")
    ap.add_argument("--cache-dir", help="brdffit's cache for the runs (default: its own)")
    ap.add_argument("--shape", action="append", choices=sorted(SHAPES),
                    help="only these shapes (default: all); the others keep their rows")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--rescore", action="store_true",
                    help="no runs: the stored measurements against today's estimate")
    ap.add_argument("--stem", help="the results' file name (default job_shapes, or "
                                   "job_shapes_cold with --cold)")
    ap.add_argument("--note", help="a paragraph under the table, kept by --rescore")
    args = ap.parse_args(argv)
    stem = args.stem or ("job_shapes_cold" if args.cold else "job_shapes")
    if args.rescore:
        res = json.loads((args.out / f"{stem}.json").read_text())
        for r in res["rows"]:
            r["estimate"] = est = estimated(r["request"], res["usable_bins"])
            r["memory_ratio"] = est["memory_mib"] / r["peak_rss_mib"]
            r["time_ratio"] = est["seconds"] / r["wall_s"]
        learned(res)
        if args.note is not None:
            res["note"] = args.note
        (args.out / f"{stem}.json").write_text(jsonout.dumps(res, indent=1))
        (args.out / f"{stem}.md").write_text(markdown(res))
        print(markdown(res))
        return 0
    args.table = table_on_disk(args.table)
    res = run(args.table, args.repeats, args.cold, args.shape or list(SHAPES), args.cache_dir)
    if args.note is not None:
        res["note"] = args.note
    args.out.mkdir(parents=True, exist_ok=True)
    if args.shape and (args.out / f"{stem}.json").exists():
        # some shapes again: the others keep their rows (and the file its order)
        old = json.loads((args.out / f"{stem}.json").read_text())
        new = {r["shape"]: r for r in res["rows"]}
        res["rows"] = [new.pop(r["shape"], r) for r in old["rows"]] + list(new.values())
    (args.out / f"{stem}.json").write_text(jsonout.dumps(res, indent=1))
    (args.out / f"{stem}.md").write_text(markdown(res))
    print(markdown(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
