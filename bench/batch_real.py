"""A batch of real tables, this checkout against another, side by side: fits per second.

    python -m bench.batch_real [--tables 51] [--baseline /path/to/other/checkout] [--runs 2]
        # writes bench/results/batch_real.{json,md}

``brdffit batch`` (the CLI, local Dask workers, one per core) fits the first
``--tables`` real MERL materials (rebuilt from their networks into ``.bench-cache``)
with the six single-lobe models into a new results file. With ``--baseline``, the
other checkout's CLI runs the same batch, alternately with this one's, so both see the
same machine; a run of each that is not counted goes first (it compiles what its code
needs into brdffit's cache). Recorded per run: wall time, and the user and system CPU
seconds of the batch and its workers; the fits of both sides are compared (log_rmse
and params of every (table, model)).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.machine import machine
from brdffit import jsonout

RESULTS = Path(__file__).with_name("results")
ROOT = Path(__file__).resolve().parents[1]
MODELS = "lambert,oren_nayar,blinn_phong,phong,beckmann,ggx"


def tables(n: int) -> Path:
    """A directory linking the first ``n`` real materials' tables."""
    from data_synth.nbrdf import cached_table, material_names

    cache = ROOT / ".bench-cache" / "nbrdf"
    out = Path(tempfile.mkdtemp(prefix="brdffit-batch-real-"))
    for name in sorted(material_names())[:n]:
        (out / f"{name}.binary").symlink_to(cached_table(name, str(cache)))
    return out


def one_run(checkout: Path, directory: Path, out: Path) -> dict:
    # each checkout's batch in brdffit's default cache, as a user's would run
    env = {k: v for k, v in os.environ.items() if k != "BRDFFIT_CACHE_DIR"}
    env["PYTHONPATH"] = str(checkout)
    out.unlink(missing_ok=True)
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "brdffit.cli", "batch", str(directory),
                             "--models", MODELS, "--out", str(out), "--quiet"],
                            cwd=checkout, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if status != 0:
        raise RuntimeError(f"{checkout}: batch failed: {proc.stderr.read().decode()[-2000:]}")
    return {"wall_s": wall, "user_s": usage.ru_utime, "sys_s": usage.ru_stime}


def fits_of(path: Path) -> dict:
    from brdffit.batch.store import read_results

    return {(t["name"], m): (f["error"]["log_rmse"], f["params"])
            for t in read_results(path)["tables"] for m, f in t["fits"].items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.batch_real")
    ap.add_argument("--tables", type=int, default=51)
    ap.add_argument("--baseline", type=Path, help="another checkout, run alternately")
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    directory = tables(args.tables)
    sides = {"this": ROOT, **({"baseline": args.baseline.resolve()} if args.baseline else {})}
    runs: dict[str, list[dict]] = {s: [] for s in sides}
    with tempfile.TemporaryDirectory() as tmp:
        outs = {s: Path(tmp) / f"{s}.h5" for s in sides}
        for s, checkout in sides.items():  # not counted: fills the cache for its code
            one_run(checkout, directory, outs[s])
        for _ in range(args.runs):
            for s, checkout in sides.items():
                runs[s].append(one_run(checkout, directory, outs[s]))
                print(s, runs[s][-1], flush=True)
        fits = {s: fits_of(outs[s]) for s in sides}
    n_fits = len(fits["this"])
    med = {s: {k: statistics.median(r[k] for r in rs) for k in ("wall_s", "user_s", "sys_s")}
           for s, rs in runs.items()}
    same = None
    if "baseline" in sides:
        same = fits["this"] == fits["baseline"]
    res = {"machine": machine(), "tables": args.tables, "models": MODELS, "fits": n_fits,
           "runs": runs, "median": med, "identical_fits": same}
    lines = ["## A batch of real tables: fits per second", "",
             f"{res['machine']['cpu']}, {res['machine']['cores']} cores; {res['machine']['date']}. "
             f"`brdffit batch` of {args.tables} real MERL tables x {MODELS} ({n_fits} fits), "
             f"local Dask workers (one per core); medians of {args.runs} runs per side, "
             "alternating; a run of each side before them, not counted.", "",
             "| checkout | wall (s) | fits/s | user CPU (s) | system CPU (s) |",
             "|---|---:|---:|---:|---:|"]
    for s, m in med.items():
        lines.append(f"| {s} ({sides[s].name}) | {m['wall_s']:.1f} | {n_fits / m['wall_s']:.1f} "
                     f"| {m['user_s']:.1f} | {m['sys_s']:.1f} |")
    if same is not None:
        lines += ["", f"Speed-up: **{med['baseline']['wall_s'] / med['this']['wall_s']:.2f}x**; "
                  "the fits of both sides are " + ("identical (log_rmse and params of every "
                  "fit)." if same else "**not identical**.")]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "batch_real.json").write_text(jsonout.dumps(
        {**res, "runs": runs}, indent=1))
    (args.out / "batch_real.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
