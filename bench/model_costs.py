"""What each model's job costs beyond GGX's, measured, for the service's estimate.

    python -m bench.model_costs [--table PATH] [--repeats 3]
        # writes api/model_costs.py and bench/results/model_costs.md

``api.estimate`` counts a model's fit by its parameters and steps; a layered model's
evaluation (a coat's Fresnel, a thin film's Airy sum, MaterialX's standard_surface)
costs far more per step than GGX's, and some refine several starts by default (the
film's 4). So each model's default job is measured here as ``bench.job_shapes``
measures one (a new process finding its programs in brdffit's cache, on a real MERL
table), and set beside the estimate's own count for it. A model's added cost is how
many seconds its estimate gains for it to exceed the default GGX job's by
:data:`HEADROOM` times what its job took beyond that one, in the same run (a slow hour
slows both); none for auto's default candidates, whose jobs
``bench/results/job_shapes.md`` holds. Each run of this
writes ``api/model_costs.py``, which the estimate reads (a module, not a data file:
the service's front reads it without JAX, and it installs with the package).
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from bench.job_shapes import TABLE, table_on_disk
from bench.machine import machine, machine_line

ROOT = Path(__file__).resolve().parents[1]
MODULE = ROOT / "api" / "model_costs.py"
RESULTS = Path(__file__).with_name("results")


#: What a model's extra time over the default GGX job is counted at: the estimate of a
#: default GGX job is 1.5x its measurement (bench/results/job_shapes.md)
HEADROOM = 1.4


def measure(table_path: Path, repeats: int) -> dict:
    from api.estimate import estimate
    from bench.job_shapes import run_one
    from brdffit.fitting.sampling import usable_bins
    from brdffit.io import merl
    from brdffit.models import catalogue
    from brdffit.request import FitRequest

    bins = int(usable_bins(merl.read(str(table_path)), None).usable.sum())
    defaults = set(catalogue.auto_candidates())

    def job(name: str, runs: int) -> tuple[float, float]:
        """The median wall time of new processes, cache warm, and the largest peak RSS."""
        run_one({"model": name}, table_path, None)  # fills the cache: not counted
        done = [run_one({"model": name}, table_path, None) for _ in range(runs)]
        return (statistics.median(r["wall_s"] for r in done),
                max(r["peak_rss_mib"] for r in done))

    def counted(name: str) -> float:  # nothing added
        return estimate(FitRequest.of(name), bins, extra={}).reference_seconds

    def counted_mib(name: str) -> float:
        return estimate(FitRequest.of(name), bins, extra_mib={}).memory_mib

    ggx_wall, ggx_peak = job("ggx", 2 * repeats + 1)
    rows: dict[str, dict] = {}
    for d in catalogue.describe():  # a parent before the models nested in it
        name, parent = d["name"], d.get("parent")
        wall, peak = (ggx_wall, ggx_peak) if name == "ggx" else job(name, repeats)
        # seconds for its estimate to exceed GGX's by HEADROOM times what its job took
        # beyond GGX's, less what its parameters count already and its parents add
        chain = rows[parent]["chain_s"] if parent in rows else 0.0
        short = HEADROOM * (wall - ggx_wall) - (counted(name) - counted("ggx")) - chain
        added = 0.0 if name in defaults else max(0.0, short)
        # memory: the peak, not a sum; above GGX's as GGX's estimate is above its peak
        short_mib = (counted_mib("ggx") / ggx_peak * peak - counted_mib(name))
        added_mib = 0.0 if name in defaults else max(0.0, short_mib)
        rows[name] = {"wall_s": wall, "counted_s": counted(name), "extra_s": added,
                      "chain_s": chain + added, "peak_rss_mib": peak,
                      "counted_mib": counted_mib(name), "extra_mib": added_mib}
        print(f"{name}: {wall:.2f} s, counted {counted(name):.2f} s: + {added:.2f} s; "
              f"{peak:.0f} MiB, counted {counted_mib(name):.0f}: + {added_mib:.0f} MiB",
              flush=True)
    return {"machine": machine(), "table": table_path.name, "repeats": repeats,
            "ggx_wall_s": ggx_wall, "rows": rows}


def module_text(res: dict) -> str:
    lines = [
        '"""What each model\'s job costs beyond what ``api.estimate`` counts by its',
        "parameters and steps: its programs' loading and its costlier steps, in seconds.",
        "",
        "Written by ``python -m bench.model_costs`` on " + res["table"] + "; do not edit. A",
        "model not here (a plugin's) counts the largest.",
        "",
        machine_line(res["machine"]),
        '"""',
        "",
        "EXTRA_S: dict[str, float] = {",
    ]
    lines += [f'    "{name}": {row["extra_s"]:.2f},' for name, row in res["rows"].items()]
    lines += ["}", "", "#: The same for a job's peak memory, in MiB: the estimate counts the",
              "#: largest of a job's models'.", "EXTRA_MIB: dict[str, int] = {"]
    lines += [f'    "{name}": {round(row["extra_mib"])},' for name, row in res["rows"].items()]
    lines += ["}", ""]
    return "\n".join(lines)


def markdown(res: dict) -> str:
    lines = ["## Each model's fit beside GGX's: measured against the estimate's count", "",
             machine_line(res["machine"]) + f"; table {res['table']}, default options, each "
             f"run a new process; the median of {res['repeats']} runs (GGX's of "
             f"{2 * res['repeats'] + 1}). `python -m bench.model_costs`.", "",
             "| model | measured job (s) | counted (s) | added (s) | peak RSS (MiB) "
             "| counted (MiB) | added (MiB) |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for name, row in res["rows"].items():
        lines.append(f"| {name} | {row['wall_s']:.2f} | {row['counted_s']:.2f} | "
                     f"{row['extra_s']:.2f} | {row['peak_rss_mib']:.0f} | "
                     f"{row['counted_mib']:.0f} | {row['extra_mib']:.0f} |")
    lines += ["", "Measured: the model's default job, each run a new process finding its "
              "programs in brdffit's cache, as `bench.job_shapes` runs one. Counted: "
              "`api.estimate`'s time for it with nothing added. Added: the seconds its "
              f"estimate gains, for it to exceed the default GGX job's ({res['ggx_wall_s']:.2f} "
              f"s measured) by {HEADROOM}x what its job took beyond that one; none for auto's "
              "default candidates, which the job shapes hold. One job's noise is a few "
              "tenths of a second: a model as costly as GGX may gain that much. Memory: the "
              "MiB its estimate gains for it to be as far above the model's peak as the GGX "
              "job's estimate is above its own."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.model_costs")
    ap.add_argument("--table", type=Path, default=TABLE)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    res = measure(table_on_disk(args.table), args.repeats)
    MODULE.write_text(module_text(res))
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "model_costs.md").write_text(markdown(res))
    print(markdown(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
