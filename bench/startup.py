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

from bench.real_materials import cache_dir
from bench.speed import machine
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


def _process(argv: list[str], cache: str) -> tuple[float, str]:
    env = dict(os.environ, BRDFFIT_CACHE_DIR=cache)
    t0 = time.perf_counter()
    p = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=900)
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
    args = ap.parse_args(argv)
    directory = os.path.join(cache_dir(), "nbrdf")
    report = {"machine": machine(), "materials": {}}
    for name in args.materials.split(","):
        path = nbrdf.cached_table(name, directory)
        print(f"{name} ...", file=sys.stderr)
        report["materials"][name] = {"read": bench_read(path),
                                     "new_process": bench_new_process(path),
                                     "in_process": bench_in_process(path)}
    if args.across:
        print(f"ggx and auto across {args.across} materials ...", file=sys.stderr)
        report["across"] = bench_across(list(nbrdf.material_names())[:args.across], directory)
    report["machine"]["loadavg_end"] = os.getloadavg()
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "startup.json"), "w") as f:
        jsonout.dump(report, f, indent=1)
    write_markdown(report, os.path.join(args.out, "startup.md"))
    print(f"wrote {args.out}/startup.json, startup.md", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
