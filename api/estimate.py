"""What a requested fit will cost, before it is queued: peak memory and run time.

A fit's solver works on ``samples`` bins x 3 channels for each of ``starts``
starts side by side, with a Jacobian of ``n_params`` columns: its memory and its
time per step grow with ``samples * starts * n_params``. On top of that a worker
holds a fixed amount: the process (JAX, the table) and the full-table error pass.

The constants were measured on a 2-core x86 machine with
``resource.getrusage(RUSAGE_SELF).ru_maxrss`` around ``brdffit.fit`` on a real
MERL table (gold-metallic-paint), for ggx and ggx2 at 16,384 and 131,072 samples
and 1 to 8 starts (ggx2 at 131,072 x 8: 2.2 GB peak, 259 s for 109 steps; this
estimate: 3.9 GB, 808 s at 256 steps), and rounded up: the estimate is meant to be above what a fit
takes, so that a refusal is never wrong by much and an acceptance is safe.
Re-measured after the compiled programs were shared across sample counts (a sample
set is padded up to ``brdffit.fitting.sampling.bucket_size``, so 2,048 samples cost
what 16,384 do), ggx2 in a bare process with its programs compiled:
16,384 x 1 start 728 MiB, x 4 810-945 MiB; 65,536 x 1 1,011 MiB, x 4 1,090 MiB; this
estimate: 952, 1,108, 1,108 and 1,732 MiB. At small sample counts the fixed part
dominates; at the full table the estimate is about 5x the measured peak. The
time is an upper bound: every start running all ``max_steps`` steps (a fit
usually stops well before); refits that ``model="auto"`` may add for an
unconverged candidate are not counted, nor is a scene's smaller set of bins.
"""

from __future__ import annotations

from dataclasses import dataclass

from brdffit.fitting.sampling import bucket_size
from brdffit.models import catalogue

MiB = 1024 * 1024

#: A worker's memory besides the solve: process, table, compilation, full-table error
#: pass and the uncertainty's Jacobian (up to 65,536 bins): a bare ggx2 fit of 16,384
#: samples x 1 start peaks at 730 MiB, of 65,536 x 1 at 1,011 MiB.
FIXED_BYTES = 900 * MiB
#: Peak memory per padded sample x start x (parameter + 1).
BYTES_PER_UNIT = 256
#: Seconds per sample x start x parameter x solver step (measured: 1.4e-7 to 1.9e-7
#: for ggx2, 3e-8 for ggx; the larger, rounded up).
SECONDS_PER_UNIT_STEP = 2.5e-7
#: Seconds of compilation and table reading per model fitted.
SECONDS_PER_MODEL = 3.0
#: A physically bounded fit (``physical``) adds this many one-start solves to the
#: unconstrained fit (``len(brdffit.fitting.physical.BARRIERS)``; a test checks it).
PHYSICAL_SOLVES = 2


@dataclass(frozen=True)
class Estimate:
    memory_bytes: int
    seconds: float
    detail: str  # how the numbers came about, for the refusal's message

    @property
    def memory_mib(self) -> float:
        return self.memory_bytes / MiB

    def to_dict(self) -> dict:
        return {"memory_mib": round(self.memory_mib), "seconds": round(self.seconds, 1),
                "detail": self.detail}


def _n_params() -> dict[str, int]:
    return {d["name"]: d["n_params"] for d in catalogue.describe()}


def estimate(request, usable_bins: int) -> Estimate:
    """The cost of the fits ``request`` (a ``brdffit.request.FitRequest``) asks for on
    a table with ``usable_bins`` measured bins."""
    n_params = _n_params()
    options = request.options
    samples = usable_bins if options.samples is None else min(options.samples, usable_bins)
    starts, steps = options.starts, options.max_steps
    auto = request.auto
    fitted = list(request.fitted_models)
    padded = bucket_size(samples)  # the compiled solve's length, which memory follows
    memory, seconds = FIXED_BYTES, 0.0
    for name in fitted:
        k = n_params.get(name, max(n_params.values()))  # a plugin model: assume the largest
        memory = max(memory, FIXED_BYTES + BYTES_PER_UNIT * padded * starts * (k + 1))
        seconds += SECONDS_PER_MODEL + SECONDS_PER_UNIT_STEP * samples * starts * k * steps
        if options.physical:
            seconds += PHYSICAL_SOLVES * SECONDS_PER_UNIT_STEP * samples * k * steps
    what = "the auto candidates " + ", ".join(fitted) if auto else ", ".join(fitted)
    detail = (f"{what} on {samples:,} samples x {starts} start(s), at most {steps} steps "
              f"each{', and the physically bounded solves' if options.physical else ''} "
              "(an upper bound: fits usually stop sooner)")
    return Estimate(int(memory), seconds, detail)
