"""Markdown and plots for bench/speed.py's results (kept apart: no timing code here)."""

from __future__ import annotations

import os

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from brdffit.fitting.sampling import DEFAULT_SAMPLES

TARGETS_MS = 150.0
#: The full-table error is evaluated in float32: two fits whose log_rmse differ by
#: less than this are equally good (noise-free tables reach ~1e-7).
LOG_RMSE_FLOOR = 1e-6


def as_good(a: float, b: float) -> bool:
    """log_rmse a is equal or lower than b: within 1% or below the float32 floor."""
    return a <= b * 1.01 + LOG_RMSE_FLOOR


def _fmt(v, spec=".3g"):
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "NO"
    if isinstance(v, float):
        return format(v, spec)
    return str(v)


def headline(report: dict) -> dict:
    """The figures the README quotes, from one run."""
    fits = report["fits"]
    default = [r for r in fits if r["model"] == "ggx" and r["solver"] == "lm"
               and r["samples"] == DEFAULT_SAMPLES and r["precision"] == "float64"
               and r["table"] in ("ggx-clean", "ggx-noisy")]
    ratios = [s["ratio"] for s in report["scipy"] if s.get("start", "brdffit") == "brdffit"
              and as_good(s["brdffit_log_rmse"], s["scipy_log_rmse"])]
    return {
        "ggx_warm_ms": {r["table"]: r["warm_ms"] for r in default},
        "ggx_excess": {r["table"]: r["excess"] for r in default},
        "ggx_log_rmse": {r["table"]: r["log_rmse"] for r in default},
        "scipy_ratio_min": min(ratios) if ratios else None,
        "scipy_ratio_max": max(ratios) if ratios else None,
        "second_process_s": report["second_process"].get("warm_cache_s"),
        "library": report["library"],
        "nonfinite_fits": sum(
            1 for r in fits if r["log_rmse"] != r["log_rmse"]) + report["library"][
                "nonfinite_params"],
    }


def write_markdown(report: dict, path: str) -> None:
    h = headline(report)
    m = report["machine"]
    lines = [
        "# Speed vs error (bench/speed.py)",
        "",
        f"Machine: {m['cpu']} ({m['cores']} cores), JAX {m['jax']} on {m['device']}, "
        f"Python {m['python']}, brdffit {m['brdffit']}, {m['date']}. "
        f"Load average at start {m['loadavg']}, at end {m.get('loadavg_end')}."
        + (" **Quick run.**" if report.get("quick") else ""),
        "",
        "Every time is wall clock, median of the stated repeats, measured in one process;",
        "`warm` = read the table from disk + fit + full-table error, compiled fits reused.",
        "`excess` = log_rmse / log_rmse of the full-table optimum - 1 (all bins, 2 starts).",
        "`param err` = max over parameters of |fit - truth| / max(|truth|, 0.05).",
        "",
        "## Targets",
        "",
        "| target | measured | met |",
        "|---|---|---|",
    ]
    for table, ms in h["ggx_warm_ms"].items():
        ex = h["ggx_excess"][table]
        if table.endswith("-noisy"):
            lines.append(f"| warm GGX (Lambert+GGX) fit of `{table}` <= 150 ms, log_rmse within "
                         f"1% of the full-table optimum | {ms:.0f} ms, {100 * ex:+.2f}% | "
                         f"{_fmt(ms <= TARGETS_MS and ex <= 0.01)} |")
        else:  # noise-free: both errors are ~0 and a ratio of them means nothing
            err = h["ggx_log_rmse"][table]
            lines.append(f"| warm GGX fit of noise-free `{table}` <= 150 ms, log_rmse <= "
                         f"{LOG_RMSE_FLOOR:g} | {ms:.0f} ms, {err:.2g} | "
                         f"{_fmt(ms <= TARGETS_MS and err <= LOG_RMSE_FLOOR)} |")
    if h["scipy_ratio_min"] is not None:
        lines.append(f"| >= 100x faster than scipy least_squares at equal or lower log_rmse "
                     f"(within 1% or {LOG_RMSE_FLOOR:g}), per table | "
                     f"{h['scipy_ratio_min']:.0f}x - {h['scipy_ratio_max']:.0f}x | "
                     f"{_fmt(h['scipy_ratio_min'] >= 100)} |")
    sp = h["second_process_s"]
    if sp is not None:
        lines.append(f"| second process, first table <= 3 s end to end | {sp:.2f} s | "
                     f"{_fmt(sp <= 3.0)} |")
    lib = h["library"]
    lines.append(f"| {lib['tables']} tables x {lib['models']} models <= 3 min "
                 f"(one process) | {lib['wall_s']:.0f} s ({lib['fits_per_s']:.1f} fits/s) | "
                 f"{_fmt(lib['wall_s'] <= 180 * lib['tables'] / 100)} |")
    lines.append(f"| zero NaN params | {h['nonfinite_fits']} | {_fmt(h['nonfinite_fits'] == 0)} |")
    lines += ["", "## brdffit vs scipy.optimize.least_squares (same loss, same tables)", "",
              "scipy starts from brdffit's best start after one LM step (`brdffit`: the fairest "
              "race, scipy gets our initialisation for free) or from one fixed generic "
              "guess (`generic`: what a user without our initialisation would write).", "",
              "| table | model | scipy start | scipy | scipy log_rmse | brdffit (default) "
              "| brdffit log_rmse | ratio | scipy param err |",
              "|---|---|---|---|---|---|---|---|---|"]
    for s in report["scipy"]:
        lines.append(f"| {s['table']} | {s['model']} | {s.get('start', 'brdffit')} "
                     f"| {s['scipy_s']:.1f} s ({s['scipy_nfev']} "
                     f"evals) | {s['scipy_log_rmse']:.4g} | {s['brdffit_ms']:.0f} ms | "
                     f"{s['brdffit_log_rmse']:.4g} | {s['ratio']:.0f}x | "
                     f"{_fmt(s['scipy_param_error'])} |")
    sp = report["second_process"]
    lines += ["", "## A new process fitting its first table (GGX, end to end)", "",
              "| persistent compile cache | wall |", "|---|---|"]
    for k in ("cold_cache_s", "warm_cache_s", "warm_cache_again_s"):
        if k in sp:
            lines.append(f"| {k[:-2].replace('_', ' ')} | {sp[k]:.2f} s |")
    lines += ["", "## Every configuration", "",
              "Rows with samples `all` are each table's full-table optimum, the reference "
              "of `excess` (2 starts, up to 1000 steps, every bin): timed once, on its "
              "first call, compilation included, not warm.", "",
              "| table | model | solver | samples | precision | warm ms | compile s | steps "
              "| log_rmse | excess | param err | result |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in report["fits"]:
        lines.append(
            f"| {r['table']} | {r['model']} | {r['solver']} | {r['samples']} | "
            f"{r['precision']} | {r['warm_ms']:.0f} | {_fmt(r['compile_s'], '.2f')} | "
            f"{r['steps']} | {r['log_rmse']:.4g} | {100 * r['excess']:.2f}% | "
            f"{_fmt(r['param_error'])} | {r['result']} |")
    selection = os.path.join(os.path.dirname(path), "selection.md")
    if os.path.exists(selection):  # bench/selection_bench.py's figures, same machine
        with open(selection) as f:
            body = f.read().split("\n", 1)[-1]  # its own title replaced by ours
        lines += ["", "## Model selection (`auto`): time and hit rate "
                  "(from bench/selection_bench.py)", body]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


#: Excess below this (a fit at the full-table optimum) is drawn on this floor.
EXCESS_FLOOR = 1e-4


def write_plots(report: dict, out_dir: str) -> None:
    """speed_pareto.png: per model, warm time against the error's excess over the
    full-table optimum. Colour: samples; marker: solver; hollow: float32. No text
    beside the points (they crowd at the default budgets): the legend says all."""
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    fits = report["fits"]
    models = list(dict.fromkeys(r["model"] for r in fits))
    budgets = sorted({r["samples"] for r in fits if r["samples"] != "all"}, key=int) + ["all"]
    colours = dict(zip(budgets, plt.get_cmap("viridis")(np.linspace(0.0, 0.9, len(budgets)))))
    markers = {"lm": "o", "optx-lm": "s", "dogleg": "^", "bfgs": "v"}
    fig, axes = plt.subplots(2, 3, figsize=(15, 8.8), squeeze=False)
    for ax, model in zip(axes.ravel(), models):
        labels = [r["table"] for r in fits if r["model"] == model]
        table = next((t for t in labels if t.endswith("-noisy")), labels[0])
        rows = [r for r in fits if r["model"] == model and r["table"] == table]
        optimum = rows[0]["optimum_log_rmse"]

        def excess(err, optimum=optimum):
            return max(100.0 * (err / optimum - 1.0), EXCESS_FLOOR)

        for r in rows:
            c = colours[r["samples"]]
            f32 = r["precision"] == "float32"
            ax.scatter(r["warm_ms"], excess(r["log_rmse"]), marker=markers.get(r["solver"], "o"),
                       s=70 if f32 else 55, zorder=3, linewidths=1.6,
                       facecolors="none" if f32 else c, edgecolors=c)
        front, best = [], float("inf")
        for r in sorted(rows, key=lambda r: r["warm_ms"]):
            if r["log_rmse"] < best:
                best = r["log_rmse"]
                front.append((r["warm_ms"], excess(r["log_rmse"])))
        if front:
            xs, ys = zip(*front)
            ax.step(xs, ys, where="post", color="grey", alpha=0.6, lw=1, zorder=2)
        for s in report["scipy"]:
            if s["model"] == model and s["table"] == table:
                ax.scatter(s["scipy_s"] * 1000, excess(s["scipy_log_rmse"]), marker="*",
                           s=200, color="tab:red", zorder=4)
        ax.set_xscale("log")
        ax.set_yscale("log")
        # 1-2-5 ticks: an axis that spans less than a decade still gets labels
        ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.set_title(f"{model} on {table}: optimum {optimum:.4g}", fontsize=10)
        ax.set_xlabel("warm read + fit + full-table error (ms)")
        ax.set_ylabel("log_rmse above the full-table optimum (%)")
        ax.grid(True, which="major", alpha=0.3)
    for ax in axes.ravel()[len(models):]:
        ax.axis("off")
    handles = [Line2D([], [], ls="", marker="o", color=colours[b], label=f"{b} samples")
               for b in budgets]
    handles += [Line2D([], [], ls="", marker=m, color="grey", label=f"solver {name}")
                for name, m in markers.items() if any(r["solver"] == name for r in fits)]
    handles += [Line2D([], [], ls="", marker="o", mfc="none", color="grey", label="float32"),
                Line2D([], [], ls="", marker="*", ms=12, color="tab:red",
                       label="scipy least_squares"),
                Line2D([], [], color="grey", label="brdffit's Pareto front")]
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 7), fontsize=9,
               frameon=False)
    fig.suptitle("brdffit: time against error, one synthetic table per model "
                 f"(lower left is better; an excess below {EXCESS_FLOOR:g}% is drawn at "
                 f"{EXCESS_FLOOR:g}%)", fontsize=12)
    fig.tight_layout(rect=(0, 0.06, 1, 0.96))
    fig.savefig(os.path.join(out_dir, "speed_pareto.png"), dpi=90)
    plt.close(fig)
