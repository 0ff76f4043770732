"""``brdffit warmup``: compile the default fits once and keep them, before a user waits.

A new process with an empty cache compiles every program a fit runs (the solve, the
start scoring, the full-table error, the sphere image, the uncertainty), which costs
several times the fit itself, and ``auto`` compiles them for each of its candidates.
This command fits each model to a small synthetic table, so that the compiled
programs land in brdffit's cache (``brdffit.executables`` and JAX's compilation
cache under ``BRDFFIT_CACHE_DIR``): the next process, a server's workers or a
container's first request, loads them in milliseconds. The programs do not depend on
the table, only on the model and the options' shapes: one sample count per bucket
(``brdffit.fitting.sampling.SAMPLE_BUCKETS``) serves every count up to it, so the
default options warm every ``--samples`` up to 16384.
"""

from __future__ import annotations

import sys
import time

from brdffit.cli import name_list
from brdffit.models.catalogue import AUTO  # no JAX for `brdffit --help`


def add_arguments(p) -> None:
    from brdffit.fitting.options import DEFAULT_LOSS, LOSSES
    from brdffit.selection import DEFAULT_CANDIDATES

    # auto first: it fits its candidates side by side, so their programs compile in
    # parallel (~23 s on 2 cores for all of them, against ~35 s one model after
    # another); the models' own fits after it then load nearly everything
    p.add_argument("--models", type=name_list("--models"),
                   default=[AUTO, *DEFAULT_CANDIDATES],
                   help="comma-separated models to compile, 'auto' for the selection "
                        f"itself (default {AUTO},{','.join(DEFAULT_CANDIDATES)})")
    p.add_argument("--loss", action="append", choices=LOSSES, dest="losses",
                   help=f"a loss to compile for (repeatable; default {DEFAULT_LOSS})")


def run(args) -> int:
    from brdffit import executables, models, runtime
    from brdffit.request import FitRequest
    from brdffit.request import run as fit_request
    from data_synth import make_table

    names = [m if m == AUTO else models.get(m).name for m in args.models]  # unknown: error
    losses = args.losses or ["log"]
    where = runtime.cache_dir()
    if where is None:
        print("brdffit warmup: caching is off (BRDFFIT_CACHE_DIR is empty): the compiled "
              "programs last only for this process", file=sys.stderr)
    else:
        print(f"brdffit warmup: cache {where} (what it holds is loaded, the rest compiled)",
              file=sys.stderr)
    # A glossy table with missing bins, as measured ones have: what it holds does not
    # matter (the programs depend on shapes only), but a converging fit runs every
    # program a user's fit runs.
    table, _ = make_table("ggx", {"kd": [0.12, 0.08, 0.05], "ks": [0.9, 0.8, 0.6],
                                  "alpha": 0.12, "f0": 0.7}, noise=0.03, missing=0.05,
                          source="<warmup>")
    t_all = time.perf_counter()
    for loss in losses:
        for name in names:
            before = len(executables.events)
            t0 = time.perf_counter()
            # the request every shell makes: the programs a user's first fit needs
            fit_request(table, FitRequest.of(name, loss=loss))
            done = executables.events[before:]
            compiled = sum(e.how == "compiled" for e in done)
            print(f"  {name:<12} {loss:<10} {time.perf_counter() - t0:6.1f} s  "
                  f"{compiled} compiled, {len(done) - compiled} loaded from the cache",
                  file=sys.stderr, flush=True)
    made = sum(e.how == "compiled" for e in executables.events)
    print(f"brdffit warmup: done in {time.perf_counter() - t_all:.1f} s ("
          + (f"{made} compiled" if made else "all loaded from the cache: nothing to compile")
          + ")", file=sys.stderr)
    return 0
