"""Right on real materials: every model, default settings, on the 100 MERL materials.

    python -m bench.real_materials [--materials a,b] [--models ggx,ggx2] [--quick]
    make bench-real

Tables are rebuilt from the shipped neural BRDFs (``data_synth.nbrdf``) into a
cache (``$BRDFFIT_BENCH_CACHE``, default ``.bench-cache/``), never committed.

For each material x model this compares the default fit (``brdffit.fit(table,
model)``, nothing else set) with a **best-effort reference**, computed once and
kept in the cache (``reference-v1/NAME.json``, one file per material, so runs over
disjoint materials can go side by side; ``--refresh-reference`` recomputes):

1. candidates: 8 starts on 32768 samples with up to 500 steps; for a nested
   model the optimum of the model it contains, embedded (ggx2 from ggx with its
   second lobe off, oren_nayar from lambert with sigma = 0); the default fit;
2. the best of them on the full table, polished on **every** bin (brdffit's LM,
   up to 100 steps);
3. an independent polish: scipy.optimize.least_squares (TRF, exact Jacobian from
   JAX) on 32768 samples from that point;
4. the reference is the lowest full-table ``log_rmse`` seen in 1-3.

Every error is the full-table ``log_rmse`` (``brdffit.fitting.loss``). Reported per model:
the share of materials within 1.01x of the reference, the worst ratio and its
material, fits that say converged while above 1.05x, nested violations (ggx2 above
1.001x ggx, oren_nayar above 1.001x lambert) and the median time per fit; and the
time of reading a table and of the warm default Lambert + GGX pair. Results go to
``bench/results/real_materials.{json,md,png}``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from datetime import UTC, datetime

import numpy as np

from brdffit import runtime

MODELS = ("lambert", "oren_nayar", "blinn_phong", "phong", "beckmann", "ggx", "ggx2")
#: (child, parent): the child contains the parent, so it must never be worse.
NESTED = (("ggx2", "ggx"), ("oren_nayar", "lambert"))
NESTED_SLACK = 1.001
WITHIN = 1.01
FAR = 1.05
REFERENCE_VERSION = 1
RESULTS = os.path.join(os.path.dirname(__file__), "results")


def cache_dir() -> str:
    return os.environ.get(
        "BRDFFIT_BENCH_CACHE",
        os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), ".bench-cache"),
    )


# -- the reference ---------------------------------------------------------------------


@runtime.in_float64
def _scipy_polish(table, model_name, params, samples=32768, seed=0):
    """scipy's TRF on the fit's own residuals (exact Jacobian from JAX), from
    ``params``; returns polished params. An independent optimiser checks that the
    point is an optimum, not just where brdffit's LM stopped. In float64, as brdffit's
    fits run (without it, JAX truncated the samples to float32 and said so)."""
    import equinox as eqx
    import jax
    from scipy.optimize import least_squares

    from brdffit import models
    from brdffit.fitting import problem as fitting
    from brdffit.fitting.loss import residuals
    from brdffit.fitting.sampling import bin_weights, stratified_sample, usable_bins

    m = models.get(model_name)
    weight = bin_weights(usable_bins(table).usable)
    ss = stratified_sample(weight, samples, seed)
    data = fitting.sample_data(table, ss.index, ss.weight)
    res = eqx.filter_jit(lambda u, d: residuals(u, (m, d)).ravel())
    jac = eqx.filter_jit(jax.jacfwd(lambda u, d: residuals(u, (m, d)).ravel()))
    u0 = m.unconstrain(m.check_params(params))
    sol = least_squares(
        lambda u: np.asarray(res(u, data)), u0, jac=lambda u: np.asarray(jac(u, data)),
        method="trf", x_scale="jac", ftol=1e-14, xtol=1e-14, gtol=1e-14, max_nfev=60,
    )
    return fitting.plain_params(m.constrain(sol.x))


def _embed(child: str, parent_params: dict) -> dict:
    """The parent's optimum as a point of the child model."""
    p = {k: np.asarray(v, float) for k, v in parent_params.items()}
    if child == "ggx2":
        return {"kd": p["kd"], "ks1": p["ks"], "alpha1": p["alpha"], "ks2": np.zeros(3),
                "alpha2": min(1.0, 3 * float(p["alpha"])), "f0": p["f0"]}
    if child == "oren_nayar":
        return {"kd": p["kd"], "sigma": 0.0}
    raise ValueError(child)


def reference_fit(table, model: str, default_params: dict, parent: dict | None) -> dict:
    from brdffit import fit
    from brdffit.fitting.problem import table_error

    tried = {"default": (default_params, table_error(table, model, default_params)["log_rmse"])}
    multi = fit(table, model, starts=8, samples=32768, max_steps=500)
    tried["8 starts x 32k samples"] = (multi.params, multi.log_rmse)
    if parent is not None:
        embedded = _embed(model, parent["params"])
        tried["parent embedded"] = (embedded, table_error(table, model, embedded)["log_rmse"])
    best = min(tried.values(), key=lambda t: t[1])
    full = fit(table, model, samples=None, init=best[0], max_steps=100)
    tried["every-bin polish"] = (full.params, full.log_rmse)
    start = min(tried.values(), key=lambda t: t[1])[0]
    polished = _scipy_polish(table, model, start)
    tried["scipy TRF polish"] = (polished, table_error(table, model, polished)["log_rmse"])
    how, (params, log_rmse) = min(tried.items(), key=lambda kv: kv[1][1])
    from brdffit.fitting.problem import plain_params as _plain

    return {"log_rmse": log_rmse, "params": _plain(params), "how": how,
            "tried": {k: v[1] for k, v in tried.items()}}


def load_reference(path: str) -> dict:
    """One material's references, by model (empty if none yet)."""
    if os.path.exists(path):
        with open(path) as f:
            return json.load(f)
    return {}


def save_json(path: str, obj) -> None:
    from brdffit import jsonout

    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        jsonout.dump(obj, f, indent=1)
    os.replace(tmp, path)


# -- the run ---------------------------------------------------------------------------


def run(materials, models, refresh: bool, log=print) -> dict:
    import brdffit
    from brdffit import fit
    from brdffit.io import merl
    from data_synth import nbrdf

    cache = cache_dir()
    ref_dir = os.path.join(cache, f"reference-v{REFERENCE_VERSION}")
    os.makedirs(ref_dir, exist_ok=True)
    rows, read_ms, pair_ms = [], [], []
    t_start = time.perf_counter()
    # the first material compiles every model: fit it once untimed
    warm = merl.read(nbrdf.cached_table(materials[0], os.path.join(cache, "nbrdf")))
    for m in models:
        fit(warm, m)
    for k, name in enumerate(materials):
        path = nbrdf.cached_table(name, os.path.join(cache, "nbrdf"))
        t0 = time.perf_counter()
        table = merl.read(path)
        read_ms.append((time.perf_counter() - t0) * 1e3)
        results = {m: fit(table, m) for m in models}
        if "lambert" in results and "ggx" in results:
            t0 = time.perf_counter()
            fit(table, "lambert")
            fit(table, "ggx")
            pair_ms.append((time.perf_counter() - t0) * 1e3)
        ref_path = os.path.join(ref_dir, f"{name}.json")
        per_model = load_reference(ref_path)
        for m in models:  # parents first (MODELS is ordered so)
            if refresh or m not in per_model:
                t0 = time.perf_counter()
                parent = next((per_model.get(p) for c, p in NESTED if c == m), None)
                per_model[m] = reference_fit(table, m, results[m].params, parent)
                per_model[m]["time_s"] = time.perf_counter() - t0
                save_json(ref_path, per_model)
            r, ref = results[m], per_model[m]
            rows.append({
                "material": name, "model": m, "log_rmse": r.log_rmse,
                "reference": ref["log_rmse"], "reference_how": ref["how"],
                "ratio": r.log_rmse / max(ref["log_rmse"], 1e-300),
                "result": r.result, "converged": r.converged, "steps": r.steps,
                "time_ms": r.time_s * 1e3, "params": r.params,
            })
        worst = max((x for x in rows if x["material"] == name), key=lambda x: x["ratio"])
        log(f"[{k + 1}/{len(materials)}] {name}: worst {worst['model']} "
            f"{worst['ratio']:.4f}x ({time.perf_counter() - t_start:.0f} s)")
    return {
        "when": datetime.now(UTC).isoformat(timespec="seconds"),
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "brdffit": brdffit.__version__,
        "rows": rows,
        "read_ms_median": statistics.median(read_ms),
        "lambert_ggx_ms_median": statistics.median(pair_ms) if pair_ms else None,
        "summary": summarise(rows),
    }


def summarise(rows) -> dict:
    out = {"models": {}, "nested": {}}
    by = {}
    for r in rows:
        by.setdefault(r["model"], []).append(r)
    for m, rs in by.items():
        worst = max(rs, key=lambda r: r["ratio"])
        out["models"][m] = {
            "n": len(rs),
            "within_1.01": sum(r["ratio"] <= WITHIN for r in rs),
            "above_1.05": sum(r["ratio"] > FAR for r in rs),
            "converged_above_1.05": sum(r["ratio"] > FAR and r["converged"] for r in rs),
            "converged": sum(r["converged"] for r in rs),
            "worst_ratio": worst["ratio"],
            "worst_material": worst["material"],
            "median_ratio": statistics.median(r["ratio"] for r in rs),
            "median_ms": statistics.median(r["time_ms"] for r in rs),
            "results": {k: sum(r["result"] == k for r in rs) for k in {r["result"] for r in rs}},
        }
    idx = {(r["material"], r["model"]): r for r in rows}
    for child, parent in NESTED:
        pairs = [(idx[(mat, child)], idx[(mat, parent)]) for (mat, mm) in idx
                 if mm == child and (mat, parent) in idx]
        if not pairs:
            continue
        ratios = [(c["log_rmse"] / max(p["log_rmse"], 1e-300), c["material"]) for c, p in pairs]
        worst = max(ratios)
        out["nested"][f"{child}/{parent}"] = {
            "n": len(ratios),
            "violations": sum(r > NESTED_SLACK for r, _ in ratios),
            "worst_ratio": worst[0],
            "worst_material": worst[1],
        }
    return out


# -- the report ------------------------------------------------------------------------


def write_report(report: dict, out_dir: str) -> None:
    os.makedirs(out_dir, exist_ok=True)
    save_json(os.path.join(out_dir, "real_materials.json"), report)
    s = report["summary"]
    n_mat = len({r["material"] for r in report["rows"]})
    lines = [
        "# Real materials: default fits against a best-effort reference",
        "",
        f"`python -m bench.real_materials` on {report['machine']}, {report['when']}; "
        f"{n_mat} materials rebuilt from their published neural BRDFs. Ratio = full-table "
        "log_rmse of the default fit / the reference's (see the module docstring for how "
        "the reference is made).",
        "",
        "| model | within 1.01x | above 1.05x | converged but above 1.05x | worst ratio "
        "(material) | median ratio | converged | median time per fit |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for m in MODELS:
        if m not in s["models"]:
            continue
        x = s["models"][m]
        lines.append(
            f"| {m} | {x['within_1.01']}/{x['n']} | {x['above_1.05']} | "
            f"{x['converged_above_1.05']} | {x['worst_ratio']:.4f} ({x['worst_material']}) | "
            f"{x['median_ratio']:.5f} | {x['converged']}/{x['n']} | {x['median_ms']:.0f} ms |"
        )
    lines += ["", "Nested models (the richer one must not be worse than "
              f"{NESTED_SLACK}x the one it contains):", "",
              "| pair | violations | worst ratio (material) |", "|---|---|---|"]
    for pair, x in s["nested"].items():
        lines.append(f"| {pair} | {x['violations']}/{x['n']} | "
                     f"{x['worst_ratio']:.5f} ({x['worst_material']}) |")
    lines += [
        "",
        (f"Reading one table: median {report['read_ms_median']:.0f} ms. Warm default "
         f"Lambert + GGX fit pair: median {report['lambert_ggx_ms_median']:.0f} ms "
         "(both measured in this run, on every material)."
         if report["lambert_ggx_ms_median"] is not None else
         "Reading and the Lambert + GGX pair: not measured (a run without both models)."),
        "",
        "Worst ten fits:",
        "",
        "| material | model | ratio | log_rmse | reference (how) | result | steps |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in sorted(report["rows"], key=lambda r: -r["ratio"])[:10]:
        lines.append(
            f"| {r['material']} | {r['model']} | {r['ratio']:.4f} | {r['log_rmse']:.5f} | "
            f"{r['reference']:.5f} ({r['reference_how']}) | {r['result']} | {r['steps']} |"
        )
    lines += ["", "![ratio per model](real_materials.png)", ""]
    with open(os.path.join(out_dir, "real_materials.md"), "w") as f:
        f.write("\n".join(lines))
    plot(report, os.path.join(out_dir, "real_materials.png"))


def plot(report: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = report["rows"]
    models = [m for m in MODELS if any(r["model"] == m for r in rows)]
    fig, (ax, ax_t) = plt.subplots(1, 2, figsize=(12, 4.8), width_ratios=(3, 2))
    rng = np.random.default_rng(0)
    for i, m in enumerate(models):
        rs = [r for r in rows if r["model"] == m]
        excess = np.maximum([r["ratio"] - 1.0 for r in rs], 1e-6)
        x = i + rng.uniform(-0.25, 0.25, len(rs))
        colour = ["tab:red" if not r["converged"] else "tab:blue" for r in rs]
        ax.scatter(x, excess, s=12, c=colour, alpha=0.7, linewidths=0)
        ax_t.scatter(np.full(len(rs), i) + rng.uniform(-0.25, 0.25, len(rs)),
                     [r["time_ms"] for r in rs], s=10, alpha=0.6, linewidths=0)
    ax.axhline(WITHIN - 1, color="k", lw=1, ls="--", label="1.01x the reference")
    ax.axhline(FAR - 1, color="tab:red", lw=1, ls=":", label="1.05x")
    ax.set_yscale("log")
    ax.set_ylim(5e-7, max(0.2, ax.get_ylim()[1]))
    ax.set_xticks(range(len(models)), models, rotation=20)
    ax.set_ylabel("log_rmse / reference - 1 (floored at 1e-6)")
    ax.set_title("Default fit vs best-effort reference, per material\n"
                 "(blue: converged, red: not)")
    ax.legend(loc="upper left", fontsize=8)
    ax_t.set_yscale("log")
    ax_t.set_xticks(range(len(models)), models, rotation=20)
    ax_t.set_ylabel("time per fit (ms, warm)")
    ax_t.set_title("Time per default fit")
    n_mat = len({r["material"] for r in rows})
    fig.suptitle(f"brdffit on {n_mat} real materials (MERL, rebuilt from neural BRDFs)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


#: Settings tried by ``--sweep``: (samples, starts), the default first.
SWEEP = ((8192, 1), (4096, 1), (16384, 1), (8192, 2), (32768, 1))
SWEEP_MODELS = ("blinn_phong", "beckmann", "ggx", "ggx2")


def sweep(materials, log=print) -> list[dict]:
    """Share within 1.01x of the (cached) reference and time per fit for each of
    ``SWEEP``'s settings: the evidence behind the defaults."""
    from brdffit import fit
    from brdffit.io import merl
    from data_synth import nbrdf

    cache = cache_dir()
    refs = {name: load_reference(os.path.join(cache, f"reference-v{REFERENCE_VERSION}",
                                              f"{name}.json")) for name in materials}
    materials = [n for n in materials if all(m in refs[n] for m in SWEEP_MODELS)]
    tables = {}
    out = []
    for samples, starts in SWEEP:
        warm = merl.read(nbrdf.cached_table(materials[0], os.path.join(cache, "nbrdf")))
        for m in SWEEP_MODELS:
            fit(warm, m, samples=samples, starts=starts)
        row = {"samples": samples, "starts": starts, "models": {}}
        for m in SWEEP_MODELS:
            ratios, times = [], []
            for name in materials:
                if name not in tables:
                    tables[name] = merl.read(nbrdf.cached_table(name, os.path.join(cache, "nbrdf")))
                r = fit(tables[name], m, samples=samples, starts=starts)
                ratios.append(r.log_rmse / refs[name][m]["log_rmse"])
                times.append(r.time_s * 1e3)
            row["models"][m] = {
                "within_1.01": sum(x <= WITHIN for x in ratios), "n": len(ratios),
                "worst_ratio": max(ratios), "median_ms": statistics.median(times),
            }
        log(f"samples={samples} starts={starts}: " + ", ".join(
            f"{m} {x['within_1.01']}/{x['n']} worst {x['worst_ratio']:.4f} {x['median_ms']:.0f} ms"
            for m, x in row["models"].items()))
        out.append(row)
    return out


def write_sweep(rows: list[dict], out_dir: str) -> None:
    save_json(os.path.join(out_dir, "real_materials_sweep.json"), rows)
    lines = ["# Choosing the defaults: accuracy and cost of each setting", "",
             "`python -m bench.real_materials --sweep`: each setting on every material with a "
             "cached reference; within = full-table log_rmse <= 1.01x the reference.", "",
             "| samples | starts | " + " | ".join(SWEEP_MODELS) + " |",
             "|---|---|" + "---|" * len(SWEEP_MODELS)]
    for r in rows:
        cells = [f"{x['within_1.01']}/{x['n']}, worst {x['worst_ratio']:.4f}, "
                 f"{x['median_ms']:.0f} ms" for x in r["models"].values()]
        lines.append(f"| {r['samples']} | {r['starts']} | " + " | ".join(cells) + " |")
    with open(os.path.join(out_dir, "real_materials_sweep.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.real_materials", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--materials", help="comma-separated subset (default: all 100)")
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--quick", action="store_true", help="10 materials")
    ap.add_argument("--refresh-reference", action="store_true")
    ap.add_argument("--out", default=RESULTS)
    ap.add_argument("--sweep", action="store_true",
                    help="instead: try other samples/starts settings against the cached "
                    "references (the evidence for the defaults)")
    args = ap.parse_args(argv)
    from data_synth import nbrdf

    materials = args.materials.split(",") if args.materials else list(nbrdf.material_names())
    if args.quick:
        materials = materials[:: max(1, len(materials) // 10)][:10]
    if args.sweep:
        write_sweep(sweep(materials, log=lambda s: print(s, file=sys.stderr, flush=True)),
                    args.out)
        return 0
    models = [m for m in MODELS if m in args.models.split(",")]
    report = run(materials, models, args.refresh_reference,
                 log=lambda s: print(s, file=sys.stderr, flush=True))
    write_report(report, args.out)
    s = report["summary"]
    for m, x in s["models"].items():
        print(f"{m:12s} within 1.01x: {x['within_1.01']}/{x['n']}  worst {x['worst_ratio']:.4f} "
              f"({x['worst_material']})  converged>1.05x: {x['converged_above_1.05']}  "
              f"median {x['median_ms']:.0f} ms")
    for pair, x in s["nested"].items():
        print(f"{pair}: {x['violations']} violations, worst {x['worst_ratio']:.5f}")
    pair = report["lambert_ggx_ms_median"]
    print(f"read {report['read_ms_median']:.0f} ms"
          + ("" if pair is None else f"; lambert+ggx {pair:.0f} ms"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
