"""Warm read + default Lambert + GGX fit time on real materials, for comparing commits.

    python -m bench.pair_timing [--materials N] [--repeats R]

Prints one JSON line: median milliseconds of reading a cached table, and of the
default ``lambert`` then ``ggx`` fits (warm: every compile paid before timing),
with the full-table log_rmse of the GGX fits. Run it from two checkouts in
alternation (``git worktree add``) to compare them side by side on the same
machine in one session; the real-material tables come from ``bench.real_materials``'
cache.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.pair_timing")
    ap.add_argument("--materials", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    import brdffit
    from brdffit import fit
    from brdffit.io import merl

    cache = os.environ.get("BRDFFIT_BENCH_CACHE", ".bench-cache")
    directory = os.path.join(cache, "nbrdf")
    names = sorted(f[: -len(".binary")] for f in os.listdir(directory) if f.endswith(".binary"))
    names = names[:: max(1, len(names) // args.materials)][: args.materials]
    warm = merl.read(os.path.join(directory, f"{names[0]}.binary"))
    fit(warm, "lambert")
    fit(warm, "ggx")
    read_ms, pair_ms, errors = [], [], []
    for _ in range(args.repeats):
        for name in names:
            t0 = time.perf_counter()
            table = merl.read(os.path.join(directory, f"{name}.binary"))
            t1 = time.perf_counter()
            fit(table, "lambert")
            r = fit(table, "ggx")
            t2 = time.perf_counter()
            read_ms.append((t1 - t0) * 1e3)
            pair_ms.append((t2 - t1) * 1e3)
            errors.append(r.log_rmse)
    print(json.dumps({
        "brdffit": os.path.dirname(brdffit.__file__),
        "materials": len(names), "repeats": args.repeats,
        "read_ms": statistics.median(read_ms),
        "lambert_ggx_ms": statistics.median(pair_ms),
        "ggx_log_rmse_mean": statistics.fmean(errors[: len(names)]),
    }))
    return 0


if __name__ == "__main__":
    sys.exit(main())
