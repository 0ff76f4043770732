"""Speed vs error: every timing beside the error it buys, against scipy.

    python -m bench.speed [--quick]     # writes bench/results/speed.{json,md,png}

For each model x synthetic table (its own family clean and noisy, plus hard
cases for the microfacet models) x sample budget x solver, in ONE process:

- ``warm_ms``: median of >= 5 end-to-end runs of read + fit + full-table error
  (the table is read from disk each time; compiled fits are reused); the
  ``samples=all`` row is the full-table optimum itself, timed once;
- ``compile_s``: first call minus warm time, with the persistent compilation
  cache switched off for this process (so it is the real compile cost);
- ``steps``, ``log_rmse`` on the full table, its excess over the full-table
  optimum (a fit on every bin, 2 starts, up to 1000 steps), and the
  parameter error against the truth: max over parameters of
  |fit - true| / max(|true|, 0.05).

Then scipy.optimize.least_squares (TRF, numpy model, finite differences) on
the same loss over the full table, for the headline models, with the speed ratio
measured in the same run. Then two process-level figures: a second process fitting
its first table (persistent cache warm), and 100 tables x 6 models.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

# Compile times are only measurable without the persistent cache; must precede
# the first brdffit import.
os.environ["BRDFFIT_CACHE_DIR"] = ""

import numpy as np  # noqa: E402

from bench.machine import machine  # noqa: E402
from brdffit import fit, jsonout
from brdffit.io import merl  # noqa: E402
from data_synth import Component, make_table  # noqa: E402
from data_synth.synth import DEFAULT_PARAMS, write_table  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
MODELS = ("lambert", "oren_nayar", "blinn_phong", "phong", "beckmann", "ggx")
BUDGETS = (4096, 8192, 16384, 65536)
DEFAULT_BUDGET = 8192  # brdffit.fitting.sampling.DEFAULT_SAMPLES

HARD = {
    "near-mirror": [Component("ggx", {"kd": [0.02] * 3, "ks": [1.0] * 3, "alpha": 0.01,
                                      "f0": 0.9})],
    "strong-fresnel": [Component("ggx", {"kd": [0.1] * 3, "ks": [1.0] * 3, "alpha": 0.1,
                                         "f0": 0.02})],
    "two-lobes": [Component("ggx", {"kd": [0.1, 0.08, 0.05], "ks": [0.5] * 3, "alpha": 0.03,
                                    "f0": 1.0}),
                  Component("ggx", {"kd": [0.0] * 3, "ks": [0.4] * 3, "alpha": 0.3, "f0": 1.0})],
}


def _median_ms(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return 1000 * statistics.median(times), out


def param_error(got: dict, truth: dict | None) -> float | None:
    if truth is None:
        return None
    worst = 0.0
    for k, want in truth.items():
        g, w = np.atleast_1d(got[k]).astype(float), np.atleast_1d(want).astype(float)
        worst = max(worst, float(np.max(np.abs(g - w) / np.maximum(np.abs(w), 0.05))))
    return worst


def make_tables(directory: str, quick: bool) -> list[dict]:
    """Synthetic tables on disk, each with the model families that fit it."""
    specs = []
    for model in MODELS:
        specs.append((f"{model}-clean", [Component(model, DEFAULT_PARAMS[model])], {}, [model]))
        if not quick:
            specs.append((f"{model}-noisy", [Component(model, DEFAULT_PARAMS[model])],
                          {"noise": 0.05, "missing": 0.1}, [model]))
    for name, comps in HARD.items():
        if quick and name != "near-mirror":
            continue
        specs.append((name, comps, {}, ["ggx", "beckmann"]))
    tables = []
    for label, comps, kw, fit_models in specs:
        table, truth = make_table(comps, seed=1, source=label, **kw)
        path = os.path.join(directory, f"{label}.binary")
        write_table(path, table, truth)
        tables.append({"label": label, "path": path, "truth": truth, "models": fit_models})
    return tables


def bench_fits(tables, quick: bool) -> list[dict]:
    rows = []
    repeats = 3 if quick else 5
    budgets = (4096, DEFAULT_BUDGET) if quick else BUDGETS
    compiled = set()
    for t in tables:
        single = len(t["truth"]["components"]) == 1
        for model in t["models"]:
            truth = t["truth"]["components"][0]["params"] if single and model == t[
                "truth"]["model"] else None
            table = merl.read(t["path"])
            t0 = time.perf_counter()
            optimum = fit(table, model, samples=None, starts=2, max_steps=1000)
            rows.append(_row(t, model, "lm", "all", "float64", optimum,
                             1000 * (time.perf_counter() - t0), None, optimum, truth, 1))
            configs = [("lm", b, "float64") for b in budgets]
            configs.append(("lm", DEFAULT_BUDGET, "float32"))
            if model in ("ggx", "beckmann") and not quick:
                configs += [(s, DEFAULT_BUDGET, "float64") for s in ("optx-lm", "dogleg", "bfgs")]
            for solver, budget, precision in configs:
                def run():
                    return fit(merl.read(t["path"]), model, solver=solver, samples=budget,
                               precision=precision)
                key = (model, solver, budget, precision)
                t0 = time.perf_counter()
                run()
                first_s = time.perf_counter() - t0
                reps = repeats if solver in ("lm",) else max(3, repeats - 2)
                warm_ms, r = _median_ms(run, reps)
                rows.append(_row(t, model, solver, budget, precision, r, warm_ms,
                                 first_s - warm_ms / 1000 if key not in compiled else None,
                                 optimum, truth, reps))
                compiled.add(key)
                print(f"  {t['label']:<18} {model:<11} {solver:<7} {str(budget):>6} {precision}"
                      f"  {warm_ms:8.1f} ms  log_rmse {r.log_rmse:.4g}", file=sys.stderr)
    return rows


def _row(t, model, solver, budget, precision, r, warm_ms, compile_s, optimum, truth, reps):
    return {
        "table": t["label"], "model": model, "solver": solver,
        "samples": budget if budget is not None else "all", "precision": precision,
        "warm_ms": warm_ms, "compile_s": compile_s, "steps": r.steps,
        "converged": r.converged, "result": r.result, "log_rmse": r.log_rmse,
        "optimum_log_rmse": optimum.log_rmse,
        "excess": r.log_rmse / max(optimum.log_rmse, 1e-12) - 1.0,
        "param_error": param_error(r.params, truth), "repeats": reps,
    }


#: A data-agnostic first guess, as a user without brdffit's initialisation might write.
GENERIC_START = {"kd": [0.3, 0.3, 0.3], "ks": [0.5, 0.5, 0.5], "alpha": 0.3, "f0": 0.5}


def bench_scipy(tables, rows, quick: bool) -> list[dict]:
    from bench.scipy_baseline import fit_scipy

    out = []
    cases = [("ggx-clean", "ggx"), ("lambert-clean", "lambert")]
    if not quick:
        cases += [("ggx-noisy", "ggx"), ("near-mirror", "ggx")]
    by_label = {t["label"]: t for t in tables}
    for label, model in cases:
        t = by_label.get(label)
        if t is None:
            continue
        table = merl.read(t["path"])
        ours = next(r for r in rows if r["table"] == label and r["model"] == model
                    and r["solver"] == "lm" and r["samples"] == DEFAULT_BUDGET
                    and r["precision"] == "float64")
        starts = {"brdffit": fit(table, model, init=None, max_steps=1).params}
        if model == "ggx" and not quick:
            starts["generic"] = GENERIC_START
        for start_name, start in starts.items():
            s = fit_scipy(table, model, start)
            out.append({
                "table": label, "model": model, "start": start_name, "scipy_s": s["time_s"],
                "scipy_nfev": s["nfev"], "scipy_log_rmse": s["error"]["log_rmse"],
                "brdffit_ms": ours["warm_ms"], "brdffit_log_rmse": ours["log_rmse"],
                "ratio": s["time_s"] * 1000 / ours["warm_ms"],
                "scipy_param_error": param_error(s["params"], t["truth"]["params"]),
            })
            print(f"  scipy {label} {model} from {start_name}: {s['time_s']:.1f} s vs "
                  f"{ours['warm_ms']:.0f} ms", file=sys.stderr)
    return out


def bench_second_process(path: str) -> dict:
    """Wall time of a fresh `python` that imports brdffit, reads and fits one table."""
    code = ("import time; t=time.perf_counter(); from brdffit import fit, merl; "
            f"r=fit(merl.read({path!r}), 'ggx'); print(time.perf_counter()-t, r.log_rmse)")
    cache = tempfile.mkdtemp(prefix="brdffit-jax-cache-")
    env = dict(os.environ, BRDFFIT_CACHE_DIR=cache)
    out = {}
    for label in ("cold_cache", "warm_cache", "warm_cache_again"):
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                           text=True, timeout=600)
        out[label + "_s"] = time.perf_counter() - t0
        if p.returncode != 0:
            out["error"] = p.stderr[-2000:]
    return out


def bench_library(tables, n_tables: int) -> dict:
    """n_tables reads x 6 models, cycling over the clean/noisy tables on disk."""
    paths = [t["path"] for t in tables if t["label"].endswith(("-clean", "-noisy"))]
    for p in paths[:1]:  # compile every model once, as a long run would
        tab = merl.read(p)
        for m in MODELS:
            fit(tab, m)
    t0 = time.perf_counter()
    n_fits, bad = 0, 0
    for i in range(n_tables):
        tab = merl.read(paths[i % len(paths)])
        for m in MODELS:
            r = fit(tab, m)
            n_fits += 1
            bad += not all(np.all(np.isfinite(v)) for v in r.params.values())
    elapsed = time.perf_counter() - t0
    return {"tables": n_tables, "models": len(MODELS), "fits": n_fits, "wall_s": elapsed,
            "nonfinite_params": bad, "fits_per_s": n_fits / elapsed}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.speed")
    ap.add_argument("--quick", action="store_true", help="fewer tables/budgets (a smoke run)")
    ap.add_argument("--out", default=RESULTS)
    ap.add_argument("--library-tables", type=int, default=100)
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    report = {"machine": machine(), "quick": args.quick}
    with tempfile.TemporaryDirectory(prefix="brdffit-bench-") as tmp:
        print("making tables ...", file=sys.stderr)
        tables = make_tables(tmp, args.quick)
        print("fits ...", file=sys.stderr)
        report["fits"] = bench_fits(tables, args.quick)
        print("scipy ...", file=sys.stderr)
        report["scipy"] = bench_scipy(tables, report["fits"], args.quick)
        print("second process ...", file=sys.stderr)
        report["second_process"] = bench_second_process(tables[0]["path"])
        print("library throughput ...", file=sys.stderr)
        report["library"] = bench_library(tables, 10 if args.quick else args.library_tables)
    report["machine"]["loadavg_end"] = os.getloadavg()
    with open(os.path.join(args.out, "speed.json"), "w") as f:
        jsonout.dump(report, f, indent=1)
    from bench.speed_report import write_markdown, write_plots

    write_markdown(report, os.path.join(args.out, "speed.md"))
    write_plots(report, args.out)
    print(f"wrote {args.out}/speed.json, speed.md, speed_pareto.png", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
