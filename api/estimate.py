"""What a requested fit will cost, before it is queued: peak memory and run time.

The figures are fitted to measured jobs (``python -m bench.job_shapes``:
``bench/results/job_shapes.md``), each a new process on a 2-core x86 machine (an AMD
EPYC) running ``brdffit.request.run`` on a real MERL table, as a service worker does:
the default fit, every bin with one and four starts, ggx2, auto, the render loss,
subsamples of 131,072 and 262,144 bins with several starts, the bounded fit. The
estimate is above every one of those measurements and within 2x of it: a job it
accepts fits in what it promised, and it does not refuse jobs the machine can do.

A slower machine runs the same jobs longer (an Intel Xeon took 1.3-2.4x as long:
``bench/results/job_shapes_xeon.md``), and no constants can be within 2x on both. So a
server measures its own: each done job stores the seconds its worker spent on it
(``run_s``), and :func:`machine_factor` raises the estimate by the largest ratio of
measured to estimated time among its recent jobs that measure the machine (not one that
compiled programs, ``api.tasks``, nor one that did work the estimate does not count,
:func:`counts_the_work`), with headroom. It never lowers it: on a faster
machine the constants stay above its jobs. Until a slower machine has run a job, its
first estimates are low; the hard bound on a running job is the server's
``job_time_limit_s``, which stops it.

How a fit spends, and so how the estimate counts:

- **memory** is a worker's process (JAX, the programs, the table and its full-table
  error pass: ~750 MiB whatever the fit) plus the largest solve's arrays, which grow
  with its padded sample count and parameters, not with its starts (the starts are
  solved one after another in one program), and a layered model's measured excess
  (``api.model_costs.EXTRA_MIB``: the thin film's 4 starts peaked at 2.0 GB);
- **time** is a job's fixed part (reading the table, loading the programs, the
  report: about a second per job and a fifth of one per model) plus the solves: samples
  x starts x parameters x steps. A fit stops when the optimality test holds, in 3 to 51
  steps on the measured tables, so the estimate counts ``TYPICAL_STEPS`` (``NESTED_STEPS``
  for a nested model, or ``max_steps`` where fewer), not every start running
  ``max_steps``.
- a model adds the seconds measured beyond what its parameters and steps count
  (``api.model_costs``, ``python -m bench.model_costs``): a layered model's programs
  take seconds to load in a worker, its steps cost far more than GGX's (a coat's
  Fresnel, a thin film's Airy sum, MaterialX's standard_surface), and some refine
  several starts by default; counted by parameters and steps alone, their jobs were
  estimated at a quarter to a third of what they took (gltf_iridescence 2.6 s against
  10 s, auto among MaterialX's candidates 2.5 s against 9.7 s). The added seconds are
  a default fit's: a layered model's larger requests (more samples, more starts) are
  still counted by parameters and steps;
- a fit of every bin (``samples`` null) is the default subsample fit, with the starts
  asked, then one start on every bin that polishes its optimum (``POLISH_STEPS``, or
  ``NESTED_POLISH_STEPS``); a nested model (ggx2, oren_nayar) fits its parent too.

Not counted: the compilation of a worker whose cache is empty. After ``brdffit warmup``
(which ``brdffit serve --warmup`` and the image run) there is none; before it a first
job compiles its programs, ~3 s per model on the Xeon (the default ggx job took 4.3 s
from an empty cache against 1.6 s, auto 14.8 s against 3.6 s:
``bench/results/job_shapes_cold.md``), and a job that compiled stores no worker time
(``api.tasks``), so that one cold job does not teach the server that its machine is
slow. Nor are auto's refits of an unconverged candidate counted (a job that made one
teaches the server nothing either), nor a scene's smaller set of bins (an overestimate).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from api.model_costs import EXTRA_MIB, EXTRA_S
from brdffit.fitting.sampling import DEFAULT_SAMPLES, bucket_size
from brdffit.models import catalogue

MiB = 1024 * 1024

#: A worker's memory besides the solve's arrays: the process with JAX and the
#: programs, the table, the full-table error pass, the sphere renders (measured: 733
#: MiB for the default ggx fit, 745 MiB with compilation).
FIXED_BYTES = 850 * MiB
#: Peak memory per padded sample x (parameter + 1) of the largest solve (measured:
#: every bin of a MERL table, ~1.1M, adds ~210 MiB to a ggx fit, ~200 MiB to ggx2's).
BYTES_PER_SAMPLE_PARAM = 32
#: auto holds every candidate's fit and its programs at once (measured: +110 MiB).
AUTO_BYTES = 150 * MiB
#: The render loss's sphere targets and tone curve (measured: +50 MiB).
RENDER_BYTES = 100 * MiB

#: Seconds per job besides its fits: reading the table, loading the programs, the report.
SECONDS_PER_JOB = 1.5
#: Seconds per model fitted besides its solve: starts, full-table errors, uncertainty,
#: sphere renders and verdict.
SECONDS_PER_MODEL = 0.2
#: The same for each of auto's candidates, which share one full-table pass.
SECONDS_PER_CANDIDATE = 0.05
#: Seconds per sample x start x parameter x solver step.
SECONDS_PER_UNIT_STEP = 2.3e-8
#: Steps a start is counted for (``max_steps`` where fewer): a one-lobe model stopped in
#: 25 to 28 steps on the measured tables, a nested one (a second lobe beside its parent's
#: optimum, which it often leaves unused) in 47 to 51.
TYPICAL_STEPS = 30
NESTED_STEPS = 50
#: A polish of every bin (the subsample fit's optimum, one start) takes few steps: 3 for
#: ggx, 16 for ggx2, each costing more per sample than a subsample's step.
POLISH_STEPS = 4
NESTED_POLISH_STEPS = 18
SECONDS_PER_POLISH_UNIT_STEP = 3.7e-8
#: Besides its steps, a polish readies every bin (its weights and arrays): measured
#: 0.7-1.7 s for ggx's 3 steps on one machine in two hours.
SECONDS_PER_POLISH = 0.45
#: The render loss costs more per step (its tone curve, its energy term) and per model
#: (its sphere targets).
RENDER_STEP_FACTOR = 2.0
RENDER_MODEL_FACTOR = 1.5
#: A physically bounded fit (``physical``) adds this many one-start solves to the
#: unconstrained fit (``len(brdffit.fitting.physical.BARRIERS)``; a test checks it).
PHYSICAL_SOLVES = 2

#: How far above the slowest of a server's recent jobs (measured against this estimate)
#: its estimates stay, and how many recent jobs that looks at (:func:`machine_factor`).
MACHINE_HEADROOM = 1.2
RECENT_JOBS = 50


@dataclass(frozen=True)
class Estimate:
    memory_bytes: int
    seconds: float
    detail: str  # how the numbers came about, for the refusal's message
    #: ``seconds`` before the server's machine factor (:func:`machine_factor`): what a
    #: finished job's measured time is held against
    reference_seconds: float

    @property
    def memory_mib(self) -> float:
        return self.memory_bytes / MiB

    def to_dict(self) -> dict:
        return {"memory_mib": round(self.memory_mib), "seconds": round(self.seconds, 1),
                "detail": self.detail}


def machine_factor(measured: Iterable[tuple[float, float]]) -> float:
    """How much slower than the machine the constants were measured on this server's
    workers are: from its recent jobs' ``(reference_seconds, run_s)`` pairs, the
    largest ratio of measured to estimated time, with :data:`MACHINE_HEADROOM` above
    it; never below 1 (a faster machine keeps the constants, which stay above its
    jobs: an estimate is never lowered by what it measured, only raised)."""
    ratios = [run / ref for ref, run in measured if ref > 0 and run > 0]
    return max([1.0] + [MACHINE_HEADROOM * r for r in ratios])


def _with_parents(names, parents: dict[str, str | None]) -> list[str]:
    """The models a fit of ``names`` makes: a nested model fits its parent too, and
    that one its own (ggx3, ggx2, ggx; from the catalogue: the service's front does
    not import JAX)."""
    out: list[str] = []
    for name in names:
        chain = [name]
        while parents.get(chain[-1]) is not None and parents[chain[-1]] not in chain:
            chain.append(parents[chain[-1]])
        out += [m for m in reversed(chain) if m not in out]
    return out


def _polishes(options, usable_bins: int) -> bool:
    """A fit of every bin runs the default subsample fit, then polishes on every bin."""
    return options.samples is None and usable_bins > 4 * DEFAULT_SAMPLES


def _counted_steps(name: str, options, polish: bool,
                   described: list[dict]) -> tuple[int, int, int]:
    """What the estimate counts of model ``name``'s fit: its solves (starts, and the
    physically bounded ones), the steps of each, and the steps of its polish (0 without
    one)."""
    about = next((d for d in described if d["name"] == name), {})  # a `_mono`: not nested
    nested = about.get("parent") is not None
    solves = max(options.starts, about.get("least_starts", 1)) + (
        PHYSICAL_SOLVES if options.physical else 0)
    steps = min(options.max_steps, NESTED_STEPS if nested else TYPICAL_STEPS)
    polish_steps = min(options.max_steps, NESTED_POLISH_STEPS if nested else POLISH_STEPS)
    return solves, steps, polish_steps if polish else 0


#: How far past the steps the estimate counts a job's fits may go and the job still
#: measure its machine (:func:`counts_the_work`).
COUNTED_STEPS_SLACK = 3


def counts_the_work(request, fits: Iterable, usable_bins: int) -> bool:
    """Whether the estimate counted the work these ``fits`` (``FitResult`` s of
    ``request`` on a table of ``usable_bins``) did: no fit took more than
    :data:`COUNTED_STEPS_SLACK` x the solver steps it counts (its starts x its steps).
    A job that did more (auto's refit of an unconverged candidate, with 4 starts and 4x
    the steps; a table whose fits crawl for hundreds of steps) ran longer for its table,
    not for its machine: :func:`machine_factor` is not taught by it (one such job made
    every later estimate 5x too high, and the server refused fits it runs in a second)."""
    described = catalogue.describe()
    polish = _polishes(request.options, usable_bins)
    for r in fits:
        solves, steps, polish_steps = _counted_steps(r.model, request.options, polish,
                                                     described)
        if r.starts * r.steps > COUNTED_STEPS_SLACK * (solves * steps + polish_steps):
            return False
    return True


def estimate(request, usable_bins: int, machine: float = 1.0,
             extra: dict[str, float] | None = None,
             extra_mib: dict[str, float] | None = None) -> Estimate:
    """The cost of the fits ``request`` (a ``brdffit.request.FitRequest``) asks for on
    a table with ``usable_bins`` measured bins; its time ``machine`` times the
    constants' (:func:`machine_factor`). ``extra``: each model's seconds beyond what
    its parameters and steps count (default: the measured ``api.model_costs.EXTRA_S``;
    a model without them counts the largest); ``extra_mib`` likewise its memory
    (``api.model_costs.EXTRA_MIB``), the largest of the job's models'."""
    extra = EXTRA_S if extra is None else extra
    extra_mib = EXTRA_MIB if extra_mib is None else extra_mib
    costliest = max(extra.values(), default=0.0)
    largest_mib = max(extra_mib.values(), default=0.0)
    added_mib = 0.0
    described = catalogue.describe()
    n_params = {d["name"]: d["n_params"] for d in described}
    # a `_mono` variant (ggx_mono) fits fewer numbers than its base, and no parent
    n_params.update({d["name"] + catalogue.MONO_SUFFIX: d["mono_n_params"]
                     for d in described if d.get("mono_n_params")})
    parents = {d["name"]: d.get("parent") for d in described}
    options = request.options
    polish = _polishes(options, usable_bins)
    samples = (min(DEFAULT_SAMPLES, usable_bins) if polish else
               usable_bins if options.samples is None else min(options.samples, usable_bins))
    starts = options.starts
    render = options.loss == "render"
    step_factor, model_factor = (RENDER_STEP_FACTOR, RENDER_MODEL_FACTOR) if render else (1, 1)
    per_model = SECONDS_PER_CANDIDATE if request.auto else SECONDS_PER_MODEL
    fitted = _with_parents(request.fitted_models, parents)
    largest_solve = bucket_size(usable_bins if polish else samples)
    memory = 0
    seconds = SECONDS_PER_JOB
    for name in fitted:
        k = n_params.get(name, max(n_params.values()))  # a plugin model: assume the largest
        memory = max(memory, BYTES_PER_SAMPLE_PARAM * largest_solve * (k + 1))
        solves, steps, polish_steps = _counted_steps(name, options, polish, described)
        seconds += model_factor * per_model + step_factor * SECONDS_PER_UNIT_STEP * (
            samples * k * solves * steps)
        if polish:
            seconds += SECONDS_PER_POLISH + (
                step_factor * SECONDS_PER_POLISH_UNIT_STEP * usable_bins * k * polish_steps)
        base = name.removesuffix(catalogue.MONO_SUFFIX)
        seconds += extra.get(base, costliest)
        added_mib = max(added_mib, extra_mib.get(base, largest_mib))
    memory += FIXED_BYTES + (AUTO_BYTES if request.auto else 0) + (RENDER_BYTES if render else 0)
    memory += added_mib * MiB
    what = "the auto candidates " + ", ".join(request.fitted_models) if request.auto else (
        ", ".join(request.fitted_models))
    how = (f"{samples:,} samples x {starts} start(s), then one start on every bin "
           f"({usable_bins:,})" if polish else f"{samples:,} samples x {starts} start(s)")
    slower = (f"; time x{machine:.2f}, as this server's recent jobs ran slower than the "
              "machine the constants were measured on" if machine > 1 else "")
    if render:
        how += " under the render loss"
    detail = (f"{what} on {how}, ~{TYPICAL_STEPS} steps a start ({NESTED_STEPS} for a "
              f"nested model){', and the physically bounded solves' if options.physical else ''} "
              f"(from measured jobs: bench/results/job_shapes.md{slower})")
    return Estimate(int(memory), machine * seconds, detail, reference_seconds=seconds)
