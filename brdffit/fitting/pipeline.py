"""Fit an analytic model to a MERL table: ``fit(table, "ggx") -> FitResult``.

The pipeline, and where each decision is documented:

1. usable bins and solid-angle weights (``brdffit.fitting.sampling``, ``brdffit.io.grid``);
2. a fixed-size stratified subsample for the solver (``brdffit.fitting.sampling``);
3. data-driven start candidates scored in one batched call
   (``brdffit.fitting.starts``), the best ``starts`` kept;
4. an optimistix least-squares solve from each start, the starts one after the
   other in one compiled call (``lax.map``), on the compressed loss of
   ``brdffit.fitting.loss``; failures stay values (``throw=False``) and are
   reported, never raised; a model that contains another is refitted from that
   one's optimum where its own start did not do;
5. the error metrics of the best solution on **every** usable bin of the table.

Compiled functions are keyed on (model, solver, sample count, precision, loss) only:
the data always travels through ``args``, so the second table with the same
settings reuses the compiled fit, and ``brdffit.executables`` keeps the compiled
executables on disk for the next process.
"""

from __future__ import annotations

import collections
import functools
import hashlib
import os
import threading
import time
import weakref
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from brdffit import executables, models, runtime
from brdffit.errors import FitInputError
from brdffit.fitting import render_loss
from brdffit.fitting.loss import (
    DEFAULT_LOSS,
    LOSS_METRIC,
    LOSSES,
    SELECTABLE,
    SELECTED,
    LossData,
    block_count,
    compress_values,
    normal_equations,
    residuals,
    sum_over_blocks,
    sum_squares,
    tone,
)
from brdffit.fitting.quality import quality
from brdffit.fitting.result import STATUS_NAMES, FitResult
from brdffit.fitting.sampling import (
    DEFAULT_SAMPLES,
    bin_weights,
    padded,
    stratified_sample,
    usable_bins,
)
from brdffit.fitting.sphere import SphereReference
from brdffit.fitting.starts import TableHints, table_hints
from brdffit.fitting.starts import candidates as start_vectors
from brdffit.fitting.uncertainty import parameter_uncertainty
from brdffit.io import merl
from brdffit.io.buffers import aligned_copy
from brdffit.io.grid import bin_grid
from brdffit.io.merl import MerlTable
from brdffit.models.frame import Frame, shading_frame

PRECISIONS = {"float64": jnp.float64, "float32": jnp.float32}
#: One start suffices on every case of the stability suite: the starts are scored
#: on a lobe-shape grid first, so the best one is already in the right basin.
#: More starts (refined side by side with vmap) cost ~linearly more.
DEFAULT_STARTS = 1
#: Steps per start. A default fit of a real material converges in 3-80 steps
#: (bench/results/real_materials.md); the limit only ends a fit that cannot.
DEFAULT_MAX_STEPS = 256
#: The largest ``max_steps`` that the "lm" solve takes as data (a traced limit, one
#: compiled solve for every value up to it: ``FitOptions`` allows no more); a larger
#: one is a static argument of its own solve.
STEP_CAP = 10_000
#: |u| within which every parameter transform has a useful slope (softplus(-8) =
#: 3e-4 with slope 3e-4): a nested model's start from its parent is pulled back here.
LIVE_U = 8.0


@functools.cache
def _solver(name: str, precision: str):
    """The solver ``name`` for ``precision``, built once. optimistix is imported
    here, when a fit is first traced, not with brdffit: a process that runs its
    fits from compiled executables (``brdffit.executables``) never needs it."""
    import optimistix as optx

    from brdffit.fitting import solver as solvers

    # float32 cannot resolve relative changes much below 1e-6: looser tolerances
    # there stop the solver at its attainable accuracy instead of at max_steps.
    rtol, atol = (1e-8, 1e-12) if precision == "float64" else (1e-5, 1e-12)
    gtol = solvers.gtol_for(PRECISIONS[precision])
    return {
        "lm": lambda: solvers.NormalLevenbergMarquardt(rtol=rtol, atol=atol, gtol=gtol),
        "optx-lm": lambda: optx.LevenbergMarquardt(rtol=rtol, atol=atol),
        "dogleg": lambda: optx.Dogleg(rtol=rtol, atol=atol),
        "bfgs": lambda: optx.BFGS(rtol=rtol, atol=atol),
    }[name]()


#: "lm" is brdffit's normal-equations Levenberg-Marquardt (``brdffit.fitting.solver``);
#: "optx-lm" is optimistix's own, kept for comparison.
SOLVERS = ("lm", "optx-lm", "dogleg", "bfgs")


# -- compiled pieces -----------------------------------------------------------


@executables.jit
def _score(model, u_batch, data, every: int = 1):
    """Loss of each start, on every ``every``-th sample (``every`` is static)."""
    n = data.weight.shape[-1]
    data = jax.tree_util.tree_map(lambda a: a[..., ::every] if a.ndim and a.shape[-1] == n else a,
                                  data)
    return jax.vmap(lambda u: sum_squares(u, model, data))(u_batch)


@executables.jit
def _constrain_jit(model, u):
    return model.constrain(u)


def constrained(model, u) -> dict:
    """``model.constrain(u)`` in one compiled call, not one per eager operation (a
    new process compiles each of those); in the model's parameter order, which a
    pytree (sorted keys) does not keep."""
    values = _constrain_jit(model, u)
    return {s.name: values[s.name] for s in model.param_specs}


def _bound_side(u, args):
    model, _ = args
    return model.bound_side(u)


@executables.jit
def _solve_batch(model, solver_name: str, u_batch, data, max_steps):
    import optimistix as optx

    from brdffit.fitting import solver as solvers

    solver = _solver(solver_name, jnp.dtype(data.target.dtype).name)
    # the loss of an exact fit, on this table's own scale (a dim table is no exact fit)
    floor = solvers.exact_fit_floor(data.target.dtype) * jnp.sum(data.weight * data.target**2)
    options = {"normal_equations": normal_equations, "bound_side": _bound_side,
               "loss_floor": floor}
    if isinstance(solver, solvers.NormalLevenbergMarquardt) and isinstance(max_steps, jax.Array):
        # the step limit is data (fit passes an array): one solve for every max_steps
        options["step_limit"] = max_steps
        max_steps = STEP_CAP

    def one(u0):
        sol = optx.least_squares(
            residuals,
            solver,
            u0,
            args=(model, data),
            options=options,
            max_steps=max_steps,
            throw=False,
        )
        # Whatever the solver and however it stopped, "successful" means the
        # optimality test holds at the point it returns (brdffit.fitting.solver).
        if isinstance(solver, solvers.NormalLevenbergMarquardt):
            # Its final state holds that test, made at that point with the same
            # tolerances and floor: no third copy of the normal equations (after
            # its init's and its step's) to compile into the program.
            loss, optimal = sol.stats["loss"], sol.stats["stop"] == solvers.OPTIMAL
        else:
            loss, jtj, jtr = normal_equations(sol.value, (model, data))
            optimal = solvers.is_optimal(
                loss, jtj, jtr, model.bound_side(sol.value), solvers.gtol_for(loss.dtype), floor
            )
        # Return values, not the Solution: its state holds a jaxpr.
        return sol.value, solvers.status(sol.result, optimal), sol.stats["num_steps"], loss

    return jax.lax.map(one, u_batch)


# -- data preparation --------------------------------------------------------------


@functools.cache
def _device_frames(dtype_name: str) -> Frame:
    """The shading frame of every bin centre, on the device, computed once per
    process: only targets and weights travel per table."""
    g = bin_grid()
    return _shading_frame(np.asarray(g.wi, dtype_name), np.asarray(g.wo, dtype_name))


_shading_frame = executables.jit(shading_frame)


def _make_loss_data(table, index, weight, dtype, frame: Frame, loss: str) -> LossData:
    values = table.rgb.reshape(3, -1)[:, index]
    x = values * np.maximum(bin_grid().cos_i[index], 0.0)
    exposure = energy = None
    if loss == "render":
        w = np.asarray(weight)
        exposure = render_loss.exposures(np.maximum(x, 0.0), w)
        target = tone(np.maximum(x, 0.0) * exposure, np)
        energy = (np.maximum(x, 0.0) @ w / max(float(w.sum()), 1e-300))[:, None]
    else:
        # numpy's log1p for the default: the same targets, to the last bit, as before
        # the loss was a choice (JAX's log1p differs in the last place on some values)
        target = np.log1p(x) if loss == "log" else compress_values(x, loss)
    # the losses of SELECTABLE share one compiled fit: the loss travels as data
    selector = (jnp.asarray(SELECTABLE.index(loss), jnp.int32) if loss in SELECTABLE
                else None)
    return LossData(
        frame=frame, target=jnp.asarray(target, dtype), weight=jnp.asarray(weight, dtype),
        loss=loss if selector is None else SELECTED,
        exposure=None if exposure is None else jnp.asarray(exposure, dtype),
        energy=None if energy is None else jnp.asarray(energy, dtype), selector=selector,
    )


def sample_data(
    table: MerlTable, index: np.ndarray, weight: np.ndarray, dtype=jnp.float64,
    loss: str = DEFAULT_LOSS,
) -> LossData:
    """The bins ``index`` (flat) of ``table`` with their ``weight``s, ready for ``loss``."""
    frame = _gather(_device_frames(jnp.dtype(dtype).name), jnp.asarray(index))
    return _make_loss_data(table, index, weight, dtype, frame, loss)


@executables.jit
def _gather(tree, index):
    return jax.tree_util.tree_map(lambda a: a[..., index], tree)


@executables.jit
def _compress_all(rgb, cos_i, loss):
    # unmeasured bins hold negative values: clamped so that every loss's target is
    # finite there (their weight is 0)
    return compress_values(jnp.maximum(rgb, 0.0) * jnp.maximum(cos_i, 0.0), loss)


def full_table_data(
    table: MerlTable, weight: np.ndarray, dtype=jnp.float64, loss: str = DEFAULT_LOSS
) -> LossData:
    """Every bin of the table (a fixed shape), weighted by ``weight`` (flat; 0 below
    the horizon and on unmeasured bins), as a :class:`LossData` for ``loss``."""
    frame = _device_frames(jnp.dtype(dtype).name)
    if loss == "render":  # the exposures need the table's values in numpy anyway
        return _make_loss_data(table, np.arange(weight.size), weight, dtype, frame, loss)
    rgb = jnp.asarray(table.rgb.reshape(3, -1), dtype)
    return LossData(
        frame=frame, target=_compress_all(rgb, frame.cos_i, loss),
        weight=jnp.asarray(weight, dtype), loss=loss,
    )


#: The full-table error is a report, not an optimisation: float32 evaluates it
#: ~2x faster over the 1.46M bins and agrees with float64 to ~1e-6 relative on
#: log_rmse (tests/test_fitting.py::test_full_table_error_float32_matches_float64).
FULL_TABLE_DTYPE = jnp.float32


#: Per-table arrays, reused by every model fitted to the same table object (a
#: batch or `auto` fits several) and dropped with the table.
_TABLE_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


_TABLE_CACHE_LOCK = threading.RLock()


def _cached(table: MerlTable, key, make):
    # One lock for every table: fits running beside each other (``auto``'s
    # candidates) wait for the first one's preparation instead of repeating it.
    with _TABLE_CACHE_LOCK:
        per_table = _TABLE_CACHE.setdefault(table, {})
        if key not in per_table:
            per_table[key] = make()
        return per_table[key]


def _device_rgb(table: MerlTable):
    """The table's values on the device, as they are (float64, channel-major): no
    copy at all on the CPU, where a 64-byte-aligned array (``merl.read`` allocates
    one) is used in place; each error pass converts them block by block."""
    return _cached(table, "device-rgb", lambda: jax.device_put(table.rgb.reshape(3, -1)))


def _peak_bin(table: MerlTable, weight: np.ndarray) -> int:
    """Bin with the largest measured sum_c f cos_i among those with weight > 0.

    In numpy: XLA's CPU argmax over 1.46M values takes ~30 ms, numpy's ~1 ms. The
    brightest bin of the whole table almost always has weight (unmeasured bins hold
    0); only where it has none (a scene that leaves it out) is the mask applied."""
    brightness = table.rgb.reshape(3, -1).sum(axis=0)
    brightness *= _cos_i_above()
    b = int(np.argmax(brightness))
    if weight[b] > 0:
        return b
    return int(np.argmax(np.where(weight > 0, brightness, -np.inf)))


@functools.cache
def _cos_i_above() -> np.ndarray:
    return np.maximum(bin_grid().cos_i, 0.0)


def _fit_cos(model, u, frame):
    f = jnp.maximum(model.eval_channels(model.constrain(u), frame), 0.0)
    return f * jnp.maximum(frame.cos_i, 0.0)


@executables.jit
def _full_errors(model, u, rgb, weight, frame, peak, part, parts: int):
    """The sums behind log_rmse, cube_root_rmse and rmse_cos over the ``part``-th of
    ``parts`` runs of the table's blocks (``brdffit.fitting.loss.sum_over_blocks``),
    and the relative error at the peak bin.

    The measured side of every metric is made here, per block, from the table's own
    values: the model is evaluated once per bin, each block's temporaries stay in
    cache, and no per-table array of targets is built first. Building the three
    targets of 4.4M values beforehand cost 15-25 ms per table; here they cost ~1 ms
    per pass (issue 15)."""

    def sums(block):
        fit_cos = _fit_cos(model, u, block["frame"])
        meas_cos = block["rgb"].astype(u.dtype) * jnp.maximum(block["frame"].cos_i, 0.0)
        w = block["weight"].astype(u.dtype)
        d_log = jnp.log1p(fit_cos) - jnp.log1p(meas_cos)
        d_cube = compress_values(fit_cos, "cube_root") - compress_values(meas_cos, "cube_root")
        lin = fit_cos - meas_cos
        return jnp.stack([jnp.sum(w * d_log * d_log), jnp.sum(w * d_cube * d_cube),
                          jnp.sum(w * lin * lin)])

    arrays = {"frame": frame, "weight": weight, "rgb": rgb}
    total = sum_over_blocks(sums, arrays, weight.shape[-1], part, parts)
    at = _gather(frame, peak[None])
    meas_peak = rgb[:, peak].astype(u.dtype) * jnp.maximum(at.cos_i[0], 0.0)
    at_peak = _fit_cos(model, u, at)[:, 0] - meas_peak
    return total, jnp.max(jnp.abs(at_peak) / jnp.maximum(meas_peak, 1e-12))


#: The full-table pass is a loop over blocks on one core: on a machine with more,
#: its runs of blocks go to separate threads (~1.7x faster on 2 cores). Created on
#: first use, per process (a forked child has none of its parent's threads).
_ERROR_THREADS: dict = {}
_ERROR_THREADS_LOCK = threading.Lock()


def _error_parts(n_bins: int) -> int:
    """Into how many runs of blocks the full-table pass splits: one per usable core
    (at most 4), and a divisor of the block count."""
    blocks = block_count(n_bins)
    parts = min(runtime.usable_cores(), 4, blocks)
    while blocks % parts:
        parts -= 1
    return parts


def _error_pool(parts: int):
    from concurrent.futures import ThreadPoolExecutor

    with _ERROR_THREADS_LOCK:
        pool = _ERROR_THREADS.get(os.getpid())
        if pool is None:
            _ERROR_THREADS.clear()
            pool = _ERROR_THREADS[os.getpid()] = ThreadPoolExecutor(
                parts, thread_name_prefix="brdffit-errors")
        return pool


_REPORT_THREADS: dict = {}
#: The kinds of fit (model, precision, loss, sample shape, scene) whose report's
#: programs this process has made ready (:func:`_ready_report_once`).
_REPORTS_READY: set = set()


def _ready_report_once(table, model, u, prep: _Prepared, loss: str, precision: str) -> None:
    """The first fit of its kind in a process: make the programs of its report (the
    full-table error, the parameters, the sphere, the uncertainty) ready on another
    thread, by running them on a start vector, while this thread compiles (or loads)
    the scoring and the solve. They depend on shapes alone, not on the solution: on
    2 cores a new process compiles both sets at the same time (bench/results/
    startup.md). Later fits of the kind skip this; the results here are dropped."""
    kind = (type(model), model.name, precision, loss, prep.data.weight.shape,
            prep.weight is None or prep.weight.size)
    with _ERROR_THREADS_LOCK:
        if kind in _REPORTS_READY:
            return
        _REPORTS_READY.add(kind)

    def report() -> None:
        try:
            u0 = np.asarray(u, np.float64)
            full_table_metrics(table, model, u0, prep.weight, peak=prep.peak)
            params = _plain(constrained(model, u0))
            _cached(table, "sphere", lambda: SphereReference(table)).psnr(model, params)
            parameter_uncertainty(model, u0, prep.data)
        except Exception as e:  # noqa: BLE001 - a start far off the table: speed only
            runtime.log.debug("brdffit: report of %s not made ready ahead (%s)", model.name, e)

    _report_pool().submit(runtime.in_float64(report))


def _report_pool():
    """One thread per process for the parts of a fit's report that overlap the
    full-table pass (a forked child makes its own, as :func:`_error_pool`)."""
    from concurrent.futures import ThreadPoolExecutor

    with _ERROR_THREADS_LOCK:
        pool = _REPORT_THREADS.get(os.getpid())
        if pool is None:
            _REPORT_THREADS.clear()
            pool = _REPORT_THREADS[os.getpid()] = ThreadPoolExecutor(
                1, thread_name_prefix="brdffit-report")
        return pool


def _full_error_sums(model, u, rgb, weight, frame, peak):
    n = weight.shape[-1]
    parts = _error_parts(n)
    if parts == 1:
        return _full_errors(model, u, rgb, weight, frame, peak, jnp.asarray(0), 1)
    # float64 is a per-thread setting in JAX: each run sets it as this thread has it
    runs = [_error_pool(parts).submit(runtime.in_float64(_full_errors), model, u, rgb, weight,
                                      frame, peak, jnp.asarray(i), parts)
            for i in range(parts)]
    results = [run.result() for run in runs]
    return sum(total for total, _ in results), results[0][1]


@runtime.in_float64
def full_table_metrics(
    table: MerlTable,
    model: models.AbstractBRDFModel,
    u,
    weight: np.ndarray,
    dtype=FULL_TABLE_DTYPE,
    peak: int | None = None,
) -> dict[str, float]:
    """``brdffit.fitting.loss.error_metrics`` of unconstrained params ``u`` over every bin of
    ``table`` with weight > 0.

    Evaluated in ``dtype`` (float32 by default, for speed). Table values are bounded
    (``brdffit.io.merl.MAX_VALUE``, 1e12 1/sr), so float32 holds every measured term; a
    model far off that scale (a diverged ``ks``) can still overflow it, and then the
    metrics are evaluated again in float64 rather than reported as inf. A metric that
    is not finite even in float64 is returned as it is (NaN or inf): the caller must
    not report such a fit as a success.
    """
    peak = jnp.asarray(_peak_bin(table, weight) if peak is None else peak)
    rgb = _device_rgb(table)
    for dt in (dtype, jnp.float64):
        frame = _device_frames(jnp.dtype(dt).name)
        ut, w = jnp.asarray(u, dt), jnp.asarray(weight)
        total, rel_peak = _full_error_sums(model, ut, rgb, w, frame, peak)
        log_rmse, cube_root_rmse, rmse_cos = np.sqrt(np.asarray(total, np.float64) / 3.0)
        metrics = {"log_rmse": float(log_rmse), "cube_root_rmse": float(cube_root_rmse),
                   "rmse_cos": float(rmse_cos), "rel_peak_error": float(rel_peak)}
        if jnp.dtype(dt) == jnp.float64 or all(map(np.isfinite, metrics.values())):
            break
    return metrics


@runtime.in_float64
def table_error(
    table: MerlTable,
    model: str | models.AbstractBRDFModel,
    params: dict,
    bin_weight: np.ndarray | None = None,
) -> dict[str, float]:
    """Error metrics (``brdffit.fitting.loss.error_metrics``) of ``params`` on every usable
    bin of ``table``, optionally under a scene's ``bin_weight``."""
    m = models.get(model)
    u = m.unconstrain(m.check_params(params))
    weight = bin_weights(usable_bins(table, bin_weight).usable, bin_weight)
    return full_table_metrics(table, m, u, weight)


# -- the result ----------------------------------------------------------------------


def _plain(params: dict) -> dict:
    out = {}
    for k, v in params.items():
        a = np.asarray(v, dtype=np.float64)
        out[k] = a.tolist() if a.ndim else float(a)
    return out


class _Prepared(NamedTuple):
    """What every model's fit of one table with the same options shares."""

    counts: object  # sampling.BinCounts
    n_usable: int
    weight: np.ndarray
    sample_set: object  # sampling.SampleSet
    data: LossData
    peak: int
    brightest: float  # the largest usable value (1/sr)
    hints: TableHints | None  # what the starts read from the table


#: Solid-angle weights and subsamples by usable-bin mask: tables measured on the same
#: gonioreflectometer share their unmeasured bins, so the next table of a batch (or
#: the same file read again) reuses them (~5 ms a table). A few entries: each holds
#: 12 MB of weights.
_SAMPLE_SETS: collections.OrderedDict = collections.OrderedDict()
_SAMPLE_SETS_KEPT = 4
_SAMPLE_SETS_LOCK = threading.Lock()


def _weights_and_samples(usable: np.ndarray, bin_weight, weight_key, samples, seed: int):
    key = (hashlib.sha1(np.packbits(usable)).hexdigest(), weight_key, samples, seed)
    with _SAMPLE_SETS_LOCK:
        hit = _SAMPLE_SETS.get(key)
        if hit is not None:
            _SAMPLE_SETS.move_to_end(key)
            return hit
    weight = aligned_copy(bin_weights(usable, bin_weight))  # used in place by the device
    weight.setflags(write=False)
    hit = (weight, stratified_sample(weight, samples, seed))
    with _SAMPLE_SETS_LOCK:
        _SAMPLE_SETS[key] = hit
        while len(_SAMPLE_SETS) > _SAMPLE_SETS_KEPT:
            _SAMPLE_SETS.popitem(last=False)
    return hit


def _prepare(table: MerlTable, bin_weight, samples, seed: int, precision: str,
             loss: str) -> _Prepared:
    """The usable bins, their weights, the subsample and its device data: computed
    once per table and options and reused by every model fitted to the same table
    object (``auto``, a batch's models, a nested model's parent), ~10 ms a table."""
    weight_key = None if bin_weight is None else hashlib.sha1(bin_weight.tobytes()).hexdigest()

    def make() -> _Prepared:
        counts = usable_bins(table, bin_weight)
        n_usable = int(np.count_nonzero(counts.usable))
        # the channels' maximum first, then the usable bins' (no boolean selection copy)
        brightest = float(np.max(table.rgb.reshape(3, -1).max(axis=0), where=counts.usable,
                                 initial=0.0))
        if n_usable == 0 or brightest < merl.MIN_PEAK:  # fit() says why
            return _Prepared(counts, n_usable, None, None, None, -1, brightest, None)
        weight, sample_set = _weights_and_samples(counts.usable, bin_weight, weight_key,
                                                  samples, seed)
        if loss == "render" and bin_weight is None:
            # the solver sees the bins of the render loss's views, weighted by how
            # many pixels see them; the error is still judged on every usable bin
            views = render_loss.view_bin_weight()
            _, sample_set = _weights_and_samples(counts.usable & (views > 0), views,
                                                 "render-views", samples, seed)
        sample_set = padded(sample_set)  # one compiled fit for every count up to a bucket
        data = sample_data(table, sample_set.index, sample_set.weight, PRECISIONS[precision],
                           loss)
        return _Prepared(counts, n_usable, weight, sample_set, data, _peak_bin(table, weight),
                         brightest, table_hints(table, counts.usable))

    return _cached(table, ("prepared", samples, seed, precision, loss, weight_key), make)


# -- the front door ------------------------------------------------------------------


@runtime.in_float64
def fit(
    table: MerlTable,
    model: str | models.AbstractBRDFModel = "ggx",
    *,
    loss: str = DEFAULT_LOSS,
    solver: str = "lm",
    samples: int | None = DEFAULT_SAMPLES,
    precision: str = "float64",
    starts: int = DEFAULT_STARTS,
    max_steps: int = DEFAULT_MAX_STEPS,
    seed: int = 0,
    init: dict | None = None,
    bin_weight: np.ndarray | None = None,
    parent_fit: FitResult | None = None,
    physical: bool = False,
) -> FitResult:
    """Fit ``model`` to ``table``; see the module docstring for the pipeline.

    Args:
        table: the measured table (``brdffit.io.merl.read``).
        model: a registry name (``brdffit.models.REGISTRY``) or a model instance.
        loss: what the solver minimises (``brdffit.fitting.loss.LOSSES``): ``"log"``
            (default), ``"cube_root"``, ``"linear_cos"`` or ``"render"``
            (``brdffit.fitting.render_loss``). Every metric is reported
            whatever the loss.
        solver: ``"lm"`` (Levenberg-Marquardt, default), ``"dogleg"`` or ``"bfgs"``.
        samples: bins the solver sees (stratified subsample), ``None`` for all.
            The reported error is always on the full table.
        precision: ``"float64"`` (default) or ``"float32"`` for the solve.
        starts: how many of the best-scoring start candidates to refine.
        max_steps: solver step limit per start.
        seed: subsample seed (fits are deterministic for a given seed).
        init: optional starting params (docs/models.md names), used as the only start.
        bin_weight: optional flat weight per bin (90*90*180, >= 0) multiplying the
            solid-angle weight: a scene's use of directions. Bins with weight 0
            are excluded from the loss and from the error.
        parent_fit: for a model that contains another (``model.parent``: ggx2
            contains ggx, oren_nayar contains lambert), that model's fit to the same
            table with the same settings; fitted here when not given. Where the
            model's own start does not converge, or ends above the parent's loss,
            the fit is refitted from the parent's optimum, embedded; the solver only
            accepts steps that lower the loss: the richer model never ends worse on
            the fit's samples than the one it contains.
        physical: constrain the fit to conserve energy (directional albedo <= 1)
            and to reflectances <= 1; ``FitResult.physical`` reports what that cost
            (``brdffit.fitting.physical``).
    """
    t0 = time.perf_counter()
    m = models.get(model)
    if loss not in LOSSES:
        raise FitInputError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")
    if solver not in SOLVERS:
        raise FitInputError(f"unknown solver {solver!r}; choose one of {', '.join(SOLVERS)}")
    if precision not in PRECISIONS:
        raise FitInputError(f"unknown precision {precision!r}; choose float64 or float32")
    if samples is not None and (not isinstance(samples, int) or samples < 64):
        raise FitInputError(f"samples must be an integer >= 64 or None, got {samples!r}")
    if not isinstance(starts, int) or starts < 1:
        raise FitInputError(f"starts must be a positive integer, got {starts!r}")
    if not isinstance(max_steps, int) or max_steps < 1:
        raise FitInputError(f"max_steps must be a positive integer, got {max_steps!r}")
    if bin_weight is not None:
        bin_weight = np.asarray(bin_weight, dtype=np.float64).ravel()
        if bin_weight.size != table.mask.size or not np.all(np.isfinite(bin_weight)):
            raise FitInputError("bin_weight needs one finite value per MERL bin")
        if np.any(bin_weight < 0):
            raise FitInputError("bin_weight must be >= 0")
    if physical is not False:
        if physical is not True:
            raise FitInputError(f"physical must be true or false, got {physical!r}")
        from brdffit.fitting.physical import physical_fit

        return physical_fit(table, m, loss=loss, solver=solver, samples=samples,
                            precision=precision, starts=starts, max_steps=max_steps, seed=seed,
                            init=init, bin_weight=bin_weight, parent_fit=parent_fit)

    prep = _prepare(table, bin_weight, samples, seed, precision, loss)
    counts, n_usable, weight, sample_set, data = (
        prep.counts, prep.n_usable, prep.weight, prep.sample_set, prep.data)
    if n_usable < m.n_params * 4:
        raise FitInputError(
            f"{table.source}: only {n_usable} usable bins (measured, finite, above the "
            f"horizon{', weighted by the scene' if bin_weight is not None else ''}); "
            f"{m.name} needs at least {m.n_params * 4}"
        )
    if prep.brightest < merl.MIN_PEAK:
        raise FitInputError(
            f"{table.source}: every usable bin is below {merl.MIN_PEAK:g} 1/sr"
            f"{' under the scene' if bin_weight is not None else ''}: nothing to fit"
        )
    dtype = PRECISIONS[precision]

    again = dict(loss=loss, solver=solver, precision=precision, starts=starts,
                 max_steps=max_steps, seed=seed, bin_weight=bin_weight)
    # Every bin (samples=None): the fit on the default subsample, with its starts and
    # its nested parent, lands next to the optimum at ~1/70 of the cost per step;
    # every bin then only polishes it (a few steps instead of dozens, per start).
    polish = samples is None and init is None and n_usable > 4 * DEFAULT_SAMPLES
    if init is not None:
        u_candidates = m.unconstrain(m.check_params(init))[None]
    elif polish:
        coarse = fit(table, m, samples=DEFAULT_SAMPLES, **again)
        # A coordinate deep in its transform's flat tail (a scale at 1e-14) is pulled
        # back to the tail's edge (|u| <= 14, as every start is): the full table may
        # want it back, and from deep in the tail capped steps would only crawl.
        u_candidates = np.clip(m.unconstrain(m.check_params(coarse.params)), -14.0, 14.0)[None]
    else:
        u_candidates = start_vectors(m, table, counts.usable, prep.hints)
    _ready_report_once(table, m, u_candidates[0], prep, loss, precision)
    if len(u_candidates) > 1:  # one candidate (init, a polish) has nothing to rank
        # Score candidates on every 8th sample: ranking starts needs no more.
        scores = np.asarray(_score(m, jnp.asarray(u_candidates, dtype), data, 8))
        scores = np.where(np.isfinite(scores), scores, np.inf)
        k = min(starts, len(u_candidates))
        best_starts = u_candidates[np.argsort(scores, kind="stable")[:k]]
    else:
        best_starts = u_candidates
    parent_start = None
    if init is None and m.parent is not None:
        on_every_bin = parent_fit is not None and parent_fit.samples["used"] == n_usable
        if (parent_fit is None or parent_fit.model != m.parent or parent_fit.loss != loss
                or (polish and not on_every_bin)):
            parent_fit = fit(table, m.parent, samples=samples, **again)
        parent_start = m.unconstrain(m.check_params(m.embed_parent(parent_fit.params)))

    solve = functools.partial(_solve_batch, m, solver, data=data,
                              max_steps=jnp.asarray(max_steps) if solver == "lm"
                              and max_steps <= STEP_CAP else max_steps)
    values, codes, steps, losses = (np.asarray(a) for a in solve(
        u_batch=jnp.asarray(best_starts, dtype)))
    if parent_start is not None:
        # A model that contains its parent starts from the parent's optimum too, but
        # only where its own starts did not do: they ended without converging, or
        # above the parent's loss. Where they converged below it (most tables), a
        # second solve from the parent cost 30-100 more steps and found the same
        # optimum (bench/results/real_materials.md; issue 15).
        #
        # The embedding puts what the parent lacks at its bound (ggx2's ks2 = 0,
        # deep in the softplus tail): a saddle, from which LM crawls for dozens of
        # steps. The first retry starts from that point pulled back to where every
        # coordinate moves (|u| <= LIVE_U); the exact embedding comes last, so the
        # fit never ends worse than the parent on its samples.
        parent_loss = float(_score(m, jnp.asarray(parent_start[None], dtype), data)[0])

        def above_parent() -> bool:
            return bool(np.min(np.where(np.isfinite(losses), losses, np.inf)) > parent_loss)

        def solve_also(u) -> None:
            nonlocal values, codes, steps, losses, best_starts
            extra = [np.asarray(a) for a in solve(u_batch=jnp.asarray(u[None], dtype))]
            values, codes, steps, losses = (np.concatenate([a, b]) for a, b in
                                            zip((values, codes, steps, losses), extra))
            best_starts = np.concatenate([best_starts, u[None]])

        converged = np.any(codes == STATUS_NAMES.index("successful"))
        if not polish and (not converged or above_parent()):
            solve_also(np.clip(parent_start, -LIVE_U, LIVE_U))
        if above_parent():
            solve_also(parent_start)
    values = values.astype(np.float64)
    losses = losses.astype(np.float64)
    finite = np.all(np.isfinite(values), axis=1) & np.isfinite(losses)
    if finite.any():
        i = int(np.argmin(np.where(finite, losses, np.inf)))
        u_best, result = values[i], STATUS_NAMES[int(codes[i])]
    else:  # every start diverged: report the best start itself, flagged as such
        i = 0
        u_best, result = np.asarray(best_starts[0], np.float64), "nonfinite"

    # The uncertainty needs the solution alone: it runs on another thread while this
    # one measures the full table and the sphere. Warm, that overlaps a few ms; in a
    # new process each of them compiles its programs first, and side by side they
    # compile at the same time (bench/results/startup.md).
    pending = (_report_pool().submit(runtime.in_float64(parameter_uncertainty), m, u_best, data)
               if result != "nonfinite" else None)
    metrics = full_table_metrics(table, m, u_best, weight, peak=prep.peak)
    # the optimised loss on the solver's own subsample: sample_log_rmse for the log loss
    metrics[f"sample_{LOSS_METRIC[loss]}"] = (
        float(np.sqrt(max(losses[i], 0.0) / 3.0)) if finite.any() else float("nan")
    )
    if result == "successful" and not all(np.isfinite(v) for v in metrics.values()):
        result = "nonfinite"  # an error that cannot be measured is no success
    params = _plain(constrained(m, np.asarray(u_best)))
    # The image error of the whole sphere (no scene weighting): one figure that
    # compares fits made under different losses.
    metrics["psnr_db"] = _cached(table, "sphere", lambda: SphereReference(table)).psnr(m, params)
    uncertainty = None
    if pending is not None and result != "nonfinite":
        uncertainty = pending.result()
    elif pending is not None:  # the metrics say nonfinite: no uncertainty, whatever it was
        pending.exception()
    look = quality(table, m, params, metrics["psnr_db"])
    return FitResult(
        model=m.name,
        params=params,
        error=metrics,
        converged=result == "successful",
        result=result,
        steps=int(steps[i]),
        time_s=time.perf_counter() - t0,
        samples={
            "used": sample_set.n_used,
            "usable": n_usable,
            "measured": counts.measured,
            "dropped": {
                "unmeasured": counts.unmeasured,
                "nonfinite": counts.nonfinite,
                "below_horizon": counts.below_horizon,
            },
        },
        solver=solver,
        precision=precision,
        loss=loss,
        starts=len(best_starts),
        uncertainty=uncertainty,
        table=table.source,
        quality=look,
    )
