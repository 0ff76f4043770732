"""Everything around a fit, on real materials: reading, a new process, auto, every bin.

    python -m bench.startup [--materials red-plastic,gold-metallic-paint]
    # writes bench/results/startup.{json,md}

Rows, each a median measured side by side in this one run, each with the error it
buys (log_rmse on the full table):

- read: ``brdffit.merl.read`` against a plain ``np.fromfile`` of the same file;
- a new process: ``brdffit fit TABLE --model ggx --json`` end to end, with
  brdffit's cache (compiled fits, ``brdffit.executables``) empty, then warm;
- a warm fit: of a table read afresh (read included, and excluded), and again of the
  same table object (its per-table preparation reused, as ``auto`` and a batch do);
- auto: its first call in a new process (compilation cache warm) and warm, as a
  multiple of one warm ggx fit of the same table in the same process;
- every bin (``samples=None``): ggx and ggx2, first call and warm;
- across real materials (all 100 by default, ``--across N``): a warm ggx fit and a warm
  ``auto`` of each, medians and the share meeting 60 ms and 4x.

Real materials come from ``data_synth.nbrdf`` (cached in ``.bench-cache/nbrdf``).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from bench.machine import machine
from bench.real_materials import cache_dir
from brdffit import fit, jsonout
from brdffit.io import merl
from brdffit.selection import select
from data_synth import nbrdf

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def _median_s(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_read(path: str) -> dict:
    plain = _median_s(lambda: np.fromfile(path, dtype="<f8", offset=merl.HEADER_BYTES), 21)
    ours = _median_s(lambda: merl.read(path), 21)
    return {"fromfile_ms": plain * 1e3, "read_ms": ours * 1e3, "ratio": ours / plain}


def _process(argv: list[str], cache: str, code: str | None = None) -> tuple[float, str]:
    """``argv`` in a new process with brdffit's cache at ``cache``, brdffit imported
    from ``code`` (a checkout) when given."""
    env = dict(os.environ, BRDFFIT_CACHE_DIR=cache)
    if code is not None:
        env["PYTHONPATH"] = os.pathsep.join([code, env.get("PYTHONPATH", "")])
    t0 = time.perf_counter()
    # run in ``code``: ``python -c`` puts the working directory first on sys.path
    p = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=900, cwd=code)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"{argv} failed: {p.stderr[-2000:]}")
    return wall, p.stdout


def bench_new_process(path: str) -> dict:
    """``brdffit fit`` in a fresh process: empty cache, then warm (twice)."""
    cache = tempfile.mkdtemp(prefix="brdffit-startup-")
    argv = [sys.executable, "-m", "brdffit.cli", "fit", path, "--model", "ggx", "--json"]
    out = {}
    for label in ("cold_cache", "warm_cache", "warm_cache_again"):
        out[label + "_s"], stdout = _process(argv, cache)
        out["log_rmse"] = json.loads(stdout)["error"]["log_rmse"]
    code = ("import time; t0 = time.perf_counter()\n"
            "from brdffit.io import merl\nfrom brdffit.selection import select\n"
            f"s = select(merl.read({path!r}))\n"
            "print(time.perf_counter() - t0, s.chosen, s.chosen_fit.log_rmse)")
    _process([sys.executable, "-c", code], cache)  # fills the cache with auto's fits
    wall, stdout = _process([sys.executable, "-c", code], cache)
    inner, chosen, err = stdout.split()
    out.update(auto_first_call_process_s=wall, auto_first_call_s=float(inner),
               auto_chosen=chosen, auto_log_rmse=float(err))
    return out


#: Run in a new process: brdffit's command line in process (``brdffit.cli.main``),
#: with JAX's compile events counted; what it compiled goes to the file ``argv[1]``.
COLD_PROBE = r"""
import json, os, sys, time
from jax import monitoring
totals = {}
def on_duration(event, secs, **kwargs):
    t = totals.setdefault(event, [0, 0.0])
    t[0] += 1
    t[1] += secs
monitoring.register_event_duration_secs_listener(on_duration)
from brdffit import cli, executables
t0 = time.perf_counter()
code = cli.main(sys.argv[2:])
sys.stdout.flush()
events = getattr(executables, "events", [])  # a brdffit from before issue 25 has none
compiled = [e for e in events if e.how == "compiled"]
stats = {
    "command_s": time.perf_counter() - t0,
    "xla_programs": totals.get("/jax/core/compile/backend_compile_duration", [0, 0.0])[0],
    "xla_compile_s": totals.get("/jax/core/compile/backend_compile_duration", [0, 0.0])[1],
    "trace_lower_s": sum(totals.get(k, [0, 0.0])[1] for k in (
        "/jax/core/compile/jaxpr_trace_duration",
        "/jax/core/compile/jaxpr_to_mlir_module_duration")),
    "brdffit_compiled": len(compiled),
    "brdffit_loaded": sum(e.how == "loaded" for e in events),
    "programs": [[e.name.rsplit(".", 1)[-1], round(e.lower_s + e.compile_s, 3)]
                 for e in compiled],
}
with open(sys.argv[1], "w") as f:
    json.dump(stats, f)
sys.stderr.flush()
os._exit(code)
"""

#: The rows of the empty-cache table: (label, command line after ``brdffit``, whether
#: the row starts from an empty cache); each later row reuses the cache its row above
#: left, as a user's next command does.
COLD_ROWS = (
    ("first ggx", ["fit", "{table}", "--model", "ggx", "--json"], True),
    ("ggx again (cached)", ["fit", "{table}", "--model", "ggx", "--json"], False),
    ("then --samples 4096", ["fit", "{table}", "--model", "ggx", "--samples", "4096", "--json"],
     False),
    ("then --loss cube_root", ["fit", "{table}", "--model", "ggx", "--loss", "cube_root",
                               "--json"], False),
    ("first auto", ["fit", "{table}", "--model", "auto", "--json"], True),
    ("auto again (cached)", ["fit", "{table}", "--model", "auto", "--json"], False),
)
#: Models timed one by one, each from an empty cache (``auto``'s candidates).
COLD_MODELS = ("lambert", "oren_nayar", "blinn_phong", "phong", "beckmann", "ggx", "ggx2")


def _probe(args: list[str], cache: str, code: str | None = None) -> dict:
    """One new process running ``brdffit ARGS``: its wall time and what it compiled."""
    fd, stats_path = tempfile.mkstemp(suffix=".json")
    os.close(fd)
    wall, stdout = _process([sys.executable, "-c", COLD_PROBE, stats_path, *args], cache, code)
    with open(stats_path) as f:
        stats = json.load(f)
    os.unlink(stats_path)
    stats["wall_s"] = wall
    try:
        out = json.loads(stdout)
        stats["log_rmse"] = (out.get("error") or out["result"]["error"])["log_rmse"]
    except (ValueError, KeyError, TypeError):
        stats["log_rmse"] = None
    return stats


def _median_rows(runs: list[dict]) -> dict:
    """Per key, the median over repeats of the numbers; the first run's others."""
    out = dict(runs[0])
    for key, value in runs[0].items():
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            out[key] = statistics.median(r[key] for r in runs)
    out["repeats"] = len(runs)
    return out


def bench_cold(path: str, repeats: int = 3, baseline: str | None = None,
               models: tuple[str, ...] = COLD_MODELS) -> dict:
    """The empty-cache rows (:data:`COLD_ROWS`) and one empty-cache fit per model, each
    a new process; medians over ``repeats`` (a fresh cache per repeat). With
    ``baseline`` (another checkout), its rows too, run alternately with this one's so
    that both see the same machine load."""
    codes = {"this": None} if baseline is None else {"this": None, "baseline": baseline}
    rows = {c: {label: [] for label, _, _ in COLD_ROWS} for c in codes}
    per_model = {c: {m: [] for m in models} for c in codes}
    for _ in range(repeats):
        for c, code in codes.items():
            cache = None
            for label, args, empty in COLD_ROWS:
                if empty:
                    cache = tempfile.mkdtemp(prefix="brdffit-cold-")
                rows[c][label].append(_probe([a.format(table=path) for a in args], cache, code))
        for m in models:
            for c, code in codes.items():
                per_model[c][m].append(_probe(["fit", path, "--model", m, "--json"],
                                              tempfile.mkdtemp(prefix="brdffit-cold-"), code))
    return {c: {"code": codes[c] or ".", "rows": {k: _median_rows(v) for k, v in rows[c].items()},
                "models": {k: _median_rows(v) for k, v in per_model[c].items()}}
            for c in codes}


def cold_markdown(cold: dict, material: str) -> list[str]:
    """The empty-cache tables of :func:`bench_cold`'s report."""
    lines = [f"## From an empty cache: {material}", "",
             "Each row a new process (`brdffit ...` run in process by a probe that counts "
             "JAX's compile events); a row marked *empty* starts from an empty "
             "`BRDFFIT_CACHE_DIR`, the others reuse the cache the row above left. XLA "
             "programs: compiled by XLA in that process; compile: XLA's seconds; "
             "trace+lower: JAX's; loaded: brdffit's own compiled programs read from the "
             "store (`brdffit.executables`). Compile seconds add up the programs: "
             "where they compile side by side (this checkout), they exceed the wall "
             "time they cost. On a loaded machine (the load average above) compare the "
             "two checkouts' rows, run alternately, rather than the absolute figures.", ""]
    for c, r in cold.items():
        title = "this checkout" if c == "this" else f"baseline ({r['code']})"
        lines += [f"### {title}", "",
                  "| command | wall | XLA programs | compile | trace+lower | loaded | log_rmse |",
                  "|---|---|---|---|---|---|---|"]
        for label, args, empty in COLD_ROWS:
            row = r["rows"][label]
            cmd = "brdffit " + " ".join(a for a in args if a != "{table}" and a != "--json")
            err = "" if row["log_rmse"] is None else f"{row['log_rmse']:.5f}"
            # a brdffit from before issue 25 records no events: nothing to count
            loaded = (f"{row['brdffit_loaded']:.0f}" if row["brdffit_loaded"]
                      or row["brdffit_compiled"] else "n/a")
            lines.append(f"| {label}{' (*empty*)' if empty else ''}: `{cmd}` | "
                         f"{row['wall_s']:.2f} s | {row['xla_programs']:.0f} | "
                         f"{row['xla_compile_s']:.2f} s | {row['trace_lower_s']:.2f} s | "
                         f"{loaded} | {err} |")
        lines += ["", "One model per new process, each from an empty cache:", "",
                  "| model | wall | XLA programs | compile | trace+lower | slowest programs |",
                  "|---|---|---|---|---|---|"]
        for m, row in r["models"].items():
            slowest = sorted(row["programs"], key=lambda p: -p[1])[:3]
            lines.append(f"| {m} | {row['wall_s']:.2f} s | {row['xla_programs']:.0f} | "
                         f"{row['xla_compile_s']:.2f} s | {row['trace_lower_s']:.2f} s | "
                         + (", ".join(f"{n} {t:.2f} s" for n, t in slowest) or "n/a") + " |")
        lines.append("")
    return lines


def bench_in_process(path: str) -> dict:
    """Warm ggx, auto and every-bin fits of one table, in this process."""
    table = merl.read(path)
    out = {}
    fit(table, "ggx")
    out["ggx_warm_ms"] = 1e3 * _median_s(lambda: fit(merl.read(path), "ggx"), 7)
    tables = [merl.read(path) for _ in range(7)]  # read beforehand: the fit alone
    out["ggx_warm_fresh_table_ms"] = 1e3 * _median_s(lambda: fit(tables.pop(), "ggx"), 7)
    out["ggx_warm_same_table_ms"] = 1e3 * _median_s(lambda: fit(table, "ggx"), 7)
    out["ggx_log_rmse"] = fit(table, "ggx").log_rmse
    t0 = time.perf_counter()
    select(table)
    out["auto_first_in_process_s"] = time.perf_counter() - t0
    out["auto_warm_s"] = _median_s(lambda: select(merl.read(path)), 3)
    out["auto_over_ggx"] = out["auto_warm_s"] / (out["ggx_warm_ms"] / 1e3)
    for model in ("ggx", "ggx2"):
        t0 = time.perf_counter()
        r = fit(table, model, samples=None)
        out[f"{model}_all_first_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        r = fit(merl.read(path), model, samples=None)
        out[f"{model}_all_warm_s"] = time.perf_counter() - t0
        out[f"{model}_all_log_rmse"] = r.log_rmse
        out[f"{model}_all_steps"] = r.steps
        out[f"{model}_all_result"] = r.result
        out[f"{model}_default_log_rmse"] = fit(table, model).log_rmse
    return out


def bench_across(names: list[str], directory: str) -> dict:
    """A warm default ggx fit and a warm ``auto`` of each material, read afresh each
    time (from the page cache): the median over many real materials rather than two."""
    first = merl.read(nbrdf.cached_table(names[0], directory))
    fit(first, "ggx"), select(first)  # compiled (or loaded) before the clock runs
    rows = []
    for name in names:
        path = nbrdf.cached_table(name, directory)
        merl.read(path)  # from the disk into the page cache, as for a table read before
        t0 = time.perf_counter()
        table = merl.read(path)
        read_s = time.perf_counter() - t0
        r = fit(table, "ggx")
        fit_s = time.perf_counter() - t0 - read_s
        t0 = time.perf_counter()
        s = select(merl.read(path))
        auto_s = time.perf_counter() - t0
        rows.append({"material": name, "read_ms": 1e3 * read_s, "ggx_ms": 1e3 * fit_s,
                     "ggx_log_rmse": r.log_rmse, "ggx_steps": r.steps, "auto_ms": 1e3 * auto_s,
                     "auto_chosen": s.chosen, "auto_over_ggx": auto_s / (read_s + fit_s)})

    def median(key):
        return statistics.median(r[key] for r in rows)

    def p90(key):
        return float(np.percentile([r[key] for r in rows], 90))

    return {"n": len(rows), "rows": rows,
            **{f"{k}_median": median(k) for k in ("read_ms", "ggx_ms", "auto_ms", "auto_over_ggx")},
            **{f"{k}_p90": p90(k) for k in ("ggx_ms", "auto_over_ggx")},
            "ggx_read_included_median_ms": statistics.median(r["read_ms"] + r["ggx_ms"]
                                                             for r in rows),
            "ggx_under_60ms": sum(r["ggx_ms"] <= 60 for r in rows),
            "auto_under_4x": sum(r["auto_over_ggx"] <= 4 for r in rows)}


def write_markdown(report: dict, path: str) -> None:
    m = report["machine"]
    lines = ["# Around the fit: reading, a new process, auto, every bin", "",
             f"{m['cpu']}, {m['cores']} cores, JAX {m['jax']} on {m['backend']}, "
             f"{m['date']}, load average {m['loadavg']} at the start. "
             "`python -m bench.startup`; medians, side by side in one run.", ""]
    for name, r in report["materials"].items():
        rd, npr, ip = r["read"], r["new_process"], r["in_process"]
        lines += [f"## {name}", "",
                  "| what | time | error (log_rmse, full table) |", "|---|---|---|",
                  f"| read one table (`np.fromfile` alone: {rd['fromfile_ms']:.1f} ms) | "
                  f"{rd['read_ms']:.1f} ms ({rd['ratio']:.1f}x fromfile) | |",
                  f"| `brdffit fit --model ggx --json`, new process, empty brdffit cache | "
                  f"{npr['cold_cache_s']:.2f} s | {npr['log_rmse']:.5f} |",
                  f"| the same, cache warm (compiled fits loaded) | {npr['warm_cache_s']:.2f} s, "
                  f"{npr['warm_cache_again_s']:.2f} s | {npr['log_rmse']:.5f} |",
                  f"| warm default ggx fit, table read afresh (read included) | "
                  f"{ip['ggx_warm_ms']:.0f} ms | {ip['ggx_log_rmse']:.5f} |",
                  f"| the same fit of a table read beforehand (read excluded) | "
                  f"{ip['ggx_warm_fresh_table_ms']:.0f} ms | {ip['ggx_log_rmse']:.5f} |",
                  f"| the same fit again, same table object (its preparation reused) | "
                  f"{ip['ggx_warm_same_table_ms']:.0f} ms | {ip['ggx_log_rmse']:.5f} |",
                  f"| auto, first call in a new process (cache warm; whole process) | "
                  f"{npr['auto_first_call_s']:.2f} s ({npr['auto_first_call_process_s']:.2f} s) "
                  f"| {npr['auto_log_rmse']:.5f} ({npr['auto_chosen']}) |",
                  f"| auto, warm | {ip['auto_warm_s']:.2f} s = {ip['auto_over_ggx']:.1f} "
                  "warm ggx fits | |"]
        for model in ("ggx", "ggx2"):
            lines.append(
                f"| {model}, every bin (`--samples all`): first call, warm | "
                f"{ip[model + '_all_first_s']:.1f} s, {ip[model + '_all_warm_s']:.1f} s "
                f"({ip[model + '_all_steps']} steps, {ip[model + '_all_result']}) | "
                f"{ip[model + '_all_log_rmse']:.5f} (default samples: "
                f"{ip[model + '_default_log_rmse']:.5f}) |")
        lines.append("")
    cold = report.get("cold")
    if cold:
        cm = cold["machine"]
        lines += [f"`{cold['command']}`: {cm['cpu']}, {cm['cores']} cores, {cm['date']}, load "
                  f"average {cm['loadavg']} at the start, {cm['loadavg_end']} at the end; "
                  f"medians of {cold['runs']['this']['rows']['first ggx']['repeats']} runs.",
                  ""]
        lines += cold_markdown(cold["runs"], cold["material"])
    a = report.get("across")
    if a:
        lines += [f"## Across {a['n']} real materials", "",
                  "Each material read afresh, then a warm default ggx fit of it, then a warm "
                  "`auto` of it read afresh again (both compiled beforehand).", "",
                  "| what | median | 90th percentile | |", "|---|---|---|---|",
                  f"| read one table | {a['read_ms_median']:.1f} ms | | |",
                  f"| warm default ggx fit, table read beforehand | {a['ggx_ms_median']:.0f} ms "
                  f"| {a['ggx_ms_p90']:.0f} ms | {a['ggx_under_60ms']}/{a['n']} at 60 ms or "
                  "less |",
                  f"| the same, read included | {a['ggx_read_included_median_ms']:.0f} ms | | |",
                  f"| auto, read included | {a['auto_ms_median']:.0f} ms | | |",
                  f"| auto over one ggx fit (both read included) | {a['auto_over_ggx_median']:.1f}x"
                  f" | {a['auto_over_ggx_p90']:.1f}x | {a['auto_under_4x']}/{a['n']} at 4x or "
                  "less |", ""]
    with open(path, "w") as f:
        f.write("\n".join(lines))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.startup")
    ap.add_argument("--materials", default="red-plastic,gold-metallic-paint")
    ap.add_argument("--out", default=RESULTS)
    ap.add_argument("--across", type=int, default=100,
                    help="also time ggx and auto on this many real materials (0: none)")
    ap.add_argument("--cold-only", action="store_true",
                    help="only the empty-cache rows (on the first material); the other rows "
                         "of an existing startup.json are kept")
    ap.add_argument("--cold-repeats", type=int, default=3)
    ap.add_argument("--baseline", metavar="CHECKOUT",
                    help="also run the empty-cache rows with brdffit from this checkout, "
                         "alternately with this one's")
    args = ap.parse_args(argv)
    directory = os.path.join(cache_dir(), "nbrdf")
    names = args.materials.split(",")
    json_path = os.path.join(args.out, "startup.json")
    if args.cold_only and os.path.exists(json_path):
        with open(json_path) as f:
            report = json.load(f)
    else:
        report = {"machine": machine(), "materials": {}}
    if not args.cold_only:
        for name in names:
            path = nbrdf.cached_table(name, directory)
            print(f"{name} ...", file=sys.stderr)
            report["materials"][name] = {"read": bench_read(path),
                                         "new_process": bench_new_process(path),
                                         "in_process": bench_in_process(path)}
        if args.across:
            print(f"ggx and auto across {args.across} materials ...", file=sys.stderr)
            report["across"] = bench_across(list(nbrdf.material_names())[:args.across],
                                            directory)
        report["machine"]["loadavg_end"] = os.getloadavg()
    print(f"empty-cache rows on {names[0]} ...", file=sys.stderr)
    cold_machine = machine()
    cold = bench_cold(nbrdf.cached_table(names[0], directory), args.cold_repeats, args.baseline)
    cold_machine["loadavg_end"] = os.getloadavg()
    report["cold"] = {"material": names[0], "machine": cold_machine, "runs": cold,
                      "command": "python -m bench.startup " + " ".join(
                          sys.argv[1:] if argv is None else argv)}
    os.makedirs(args.out, exist_ok=True)
    with open(json_path, "w") as f:
        jsonout.dump(report, f, indent=1)
    write_markdown(report, os.path.join(args.out, "startup.md"))
    print(f"wrote {args.out}/startup.json, startup.md", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
