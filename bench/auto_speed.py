"""A warm ``auto`` against a warm default GGX fit of the same table, side by side in one
process (issue 41's bar: at most 4x on single-lobe and two-lobe tables).

    python -m bench.auto_speed [--repeats 5] [--out FILE.json]

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


def tables() -> dict:
    from brdffit.io import merl
    from data_synth import make_table, nbrdf
    from data_synth.synth import make_preset

    out = {"ggx (synthetic)": make_table("ggx", None, seed=1)[0],
           "two-lobes (synthetic)": make_preset("two-lobes")[0]}
    directory = os.path.join(cache_dir(), "nbrdf")
    for name in nbrdf.material_names()[::10]:
        out[name] = merl.read(nbrdf.cached_table(name, directory))
    return out


def run(repeats: int) -> dict:
    from brdffit import fit
    from brdffit.selection import select

    rows = {}
    for name, table in tables().items():
        for _ in range(2):  # compiled or loaded, the table's preparation made
            select(table)
            fit(table, "ggx")
        auto, one = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            select(table)
            auto.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            fit(table, "ggx")
            one.append(time.perf_counter() - t0)
        a, g = statistics.median(auto), statistics.median(one)
        rows[name] = {"auto_s": a, "ggx_s": g, "ratio": a / g}
        print(f"{name:28s} auto {1e3 * a:6.0f} ms  ggx {1e3 * g:5.0f} ms  {a / g:.2f}x",
              flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.auto_speed")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", help="write the medians here (JSON)")
    args = ap.parse_args(argv)
    report = {"machine": machine(), "repeats": args.repeats, "tables": run(args.repeats)}
    if args.out:
        with open(args.out, "w") as f:
            json.dump(report, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
