"""A warm ``auto`` against a warm default GGX fit of the same table, side by side in one
process (issue 41's bar: at most 4x on single-lobe and two-lobe tables).

    python -m bench.auto_speed [--repeats 5] [--synthetic] [--out FILE.json]

Each side's process CPU time is reported beside its wall time: the two sides' CPU
ratio says how much of the wall ratio is work and how much is waiting.

Tables: a noise-free GGX table, the two-lobe preset, and every 10th of the 100 MERL
materials (rebuilt from their networks, ``data_synth.nbrdf``, cached under
``.bench-cache``). Per table: two untimed selections and fits, then ``--repeats``
timed pairs, a selection then a fit, alternating; medians. Tables are read beforehand.

To compare two checkouts, run this module from each, alternately, on a quiet machine
(``PYTHONPATH=<checkout> python -m bench.auto_speed --out <file>``, twice each).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

from bench.machine import machine
from bench.render_loss import cache_dir


def tables(real: bool = True) -> dict:
    from brdffit.io import merl
    from data_synth import make_table, nbrdf
    from data_synth.synth import make_preset

    out = {"ggx (synthetic)": make_table("ggx", None, seed=1)[0],
           "two-lobes (synthetic)": make_preset("two-lobes")[0]}
    directory = os.path.join(cache_dir(), "nbrdf")
    for name in nbrdf.material_names()[::10] if real else ():
        out[name] = merl.read(nbrdf.cached_table(name, directory))
    return out


def _cpu_s() -> float:
    """This process's CPU time, user and system, all threads: what a run costs the
    machine, where its wall time is what it costs the person waiting (a ratio of wall
    times cannot fall below the ratio of CPU times by more than the cores left idle)."""
    t = os.times()
    return t.user + t.system


def run(repeats: int, real: bool = True) -> dict:
    from brdffit import fit
    from brdffit.selection import select

    rows = {}
    for name, table in tables(real).items():
        for _ in range(2):  # compiled or loaded, the table's preparation made
            select(table)
            fit(table, "ggx")
        auto, one, auto_cpu, one_cpu = [], [], [], []
        for _ in range(repeats):
            for run, wall, cpu in ((lambda: select(table), auto, auto_cpu),
                                   (lambda: fit(table, "ggx"), one, one_cpu)):
                c0, t0 = _cpu_s(), time.perf_counter()
                run()
                wall.append(time.perf_counter() - t0)
                cpu.append(_cpu_s() - c0)
        a, g = statistics.median(auto), statistics.median(one)
        ac, gc = statistics.median(auto_cpu), statistics.median(one_cpu)
        rows[name] = {"auto_s": a, "ggx_s": g, "ratio": a / g,
                      "auto_cpu_s": ac, "ggx_cpu_s": gc, "cpu_ratio": ac / gc}
        print(f"{name:28s} auto {1e3 * a:6.0f} ms  ggx {1e3 * g:5.0f} ms  {a / g:.2f}x"
              f"  (CPU {1e3 * ac:6.0f} / {1e3 * gc:4.0f} ms, {ac / gc:.2f}x)", flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.auto_speed")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", help="write the medians here (JSON)")
    ap.add_argument("--synthetic", action="store_true",
                    help="the two synthetic tables alone (issue 41's bar), not the real ones")
    args = ap.parse_args(argv)
    report = {"machine": machine(), "repeats": args.repeats,
              "tables": run(args.repeats, real=not args.synthetic)}
    if args.out:
        with open(args.out, "w") as f:
            json.dump(report, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
