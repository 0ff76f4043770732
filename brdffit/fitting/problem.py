"""The problem a fit solves, prepared once per table and shared: ``prepare``, ``solve_batch``.

Everything of a fit but its decisions (``brdffit.fitting.pipeline.fit`` makes those,
and ``brdffit.fitting.physical`` its bounded step):

- the table's usable bins, their weights and the solver's stratified subsample,
  as device arrays in the loss's form (:func:`prepare`, :class:`Prepared`), kept per
  table (:func:`cached`);
- the solvers by name (:data:`SOLVER_REGISTRY`, :func:`solver_for`) and one batched,
  compiled solve (:func:`solve_batch`): the starts one after the other (``lax.map``),
  failures as values (``throw=False``), "successful" only where the optimality test
  holds;
- the error metrics of a solution on every usable bin of the table
  (:func:`full_table_metrics`, :func:`table_error`), and the parameters as plain
  values (:func:`constrained`, :func:`plain_params`).

Compiled functions are keyed on (model, solver, sample bucket, precision, loss kind)
only: the data always travels through ``args``, so the second table with the same
settings reuses the compiled fit, and ``brdffit.executables`` keeps the compiled
executables on disk for the next process.
"""


from __future__ import annotations

import collections
import functools
import hashlib
import os
import threading
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from types import MappingProxyType
from typing import NamedTuple, Protocol

import jax
import jax.numpy as jnp
import numpy as np

from brdffit import executables, models, runtime
from brdffit.errors import FitInputError
from brdffit.fitting import render_loss
from brdffit.fitting.loss import (
    FULL_TABLE_LOSSES,
    LOSS_METRIC,
    LOSS_REGISTRY,
    SELECTABLE,
    SELECTED,
    LossData,
    block_count,
    compress_values,
    get_loss,
    normal_equations,
    normal_equations_with_meat,
    residuals,
    sum_over_blocks,
    sum_squares,
)
from brdffit.fitting.options import DEFAULT_LOSS, DEFAULT_SOLVER, PRECISIONS, SOLVERS
from brdffit.fitting.sampling import (
    bin_weights,
    padded,
    stratified_sample,
    usable_bins,
)
from brdffit.fitting.sphere import SphereReference
from brdffit.fitting.starts import TableHints, table_hints
from brdffit.fitting.uncertainty import linearisation, parameter_uncertainty
from brdffit.io import angles, merl
from brdffit.io.buffers import aligned_copy
from brdffit.io.grid import bin_grid
from brdffit.io.merl import MerlTable
from brdffit.models.frame import Frame, shading_frame

#: The dtype of each precision a fit may be asked for (``FitOptions.precision``).
DTYPES = {name: getattr(jnp, name) for name in PRECISIONS}  # jnp.float64, jnp.float32
#: The largest ``max_steps`` that the "lm" solve takes as data (a traced limit, one
#: compiled solve for every value up to it: ``FitOptions`` allows no more); a larger
#: one is a static argument of its own solve.
STEP_CAP = 10_000
#: |u| within which every parameter transform has a useful slope (softplus(-8) =
#: 3e-4 with slope 3e-4): a nested model's start from its parent is pulled back here.
LIVE_U = 8.0


def _normal_levenberg_marquardt(rtol, atol, gtol):
    from brdffit.fitting.solver import NormalLevenbergMarquardt

    return NormalLevenbergMarquardt(rtol=rtol, atol=atol, gtol=gtol)


def _optimistix(name: str):
    def make(rtol, atol, gtol):  # optimistix's own test their steps, not the gradient
        import optimistix as optx

        return getattr(optx, name)(rtol=rtol, atol=atol)
    return make


@dataclass(frozen=True)
class Solver:
    """One solver a fit can use: how to build it, and what its solve can do beyond
    optimistix's ``least_squares`` contract."""

    name: str
    #: ``make(rtol, atol, gtol)``: the optimistix solver (imported then, not with
    #: brdffit: a process that runs its fits from compiled executables never needs it)
    make: Callable
    #: the step limit is an option of the solve (``step_limit``), so it and the
    #: number of live starts can be data: one compiled solve for every ``max_steps``
    #: up to :data:`STEP_CAP` and every start count up to a bucket
    steps_as_data: bool = False
    #: its final state carries the loss and the optimality test at the point it
    #: returns, and the sandwich covariance's terms (``normal_equations_with_meat``):
    #: no copy of the normal equations, and no uncertainty program, of their own
    carries_terms: bool = False


#: Every solver by name, in the order of ``options.SOLVERS``
#: (tests/test_registries.py checks they agree).
SOLVER_REGISTRY = MappingProxyType({solver.name: solver for solver in (
    # brdffit's normal-equations Levenberg-Marquardt (brdffit.fitting.solver)
    Solver("lm", _normal_levenberg_marquardt, steps_as_data=True, carries_terms=True),
    Solver("optx-lm", _optimistix("LevenbergMarquardt")),
    Solver("dogleg", _optimistix("Dogleg")),
    Solver("bfgs", _optimistix("BFGS")),
)})


def get_solver(name: str) -> Solver:
    """The solver ``name`` of :data:`SOLVER_REGISTRY`; :class:`FitInputError` naming
    the choices for any other name."""
    try:
        return SOLVER_REGISTRY[name]
    except KeyError:
        raise FitInputError(f"unknown solver {name!r}; choose one of {', '.join(SOLVERS)}") \
            from None


def takes_steps_as_data(solver: str, max_steps: int) -> bool:
    """Whether a fit with ``solver`` passes its step limit to :func:`solve_batch` as
    data (an array): the solver supports it, and ``max_steps`` is within the one
    compiled limit (:data:`STEP_CAP`; a larger one is a static argument of its own)."""
    return get_solver(solver).steps_as_data and max_steps <= STEP_CAP


#: The solvers' relative tolerance on the loss, by precision: float32 cannot resolve
#: relative changes much below 1e-6, and looser tolerances there stop the solver at its
#: attainable accuracy instead of at max_steps. Two optima whose losses differ by less
#: are one optimum as far as the solver can tell.
LOSS_RTOL = {"float64": 1e-8, "float32": 1e-5}


@functools.cache
def solver_for(name: str, precision: str):
    """The solver ``name`` for ``precision``, built once. optimistix is imported
    here, when a fit is first traced, not with brdffit: a process that runs its
    fits from compiled executables (``brdffit.executables``) never needs it."""
    from brdffit.fitting import solver as solvers

    return get_solver(name).make(LOSS_RTOL[precision], 1e-12,
                                 solvers.gtol_for(DTYPES[precision]))


# -- compiled pieces -----------------------------------------------------------


@executables.jit
def score_starts(model, u_batch, data, every: int = 1):
    """Loss of each start, on every ``every``-th sample (``every`` is static)."""
    n = data.weight.shape[-1]
    data = jax.tree_util.tree_map(lambda a: a[..., ::every] if a.ndim and a.shape[-1] == n else a,
                                  data)
    return jax.vmap(lambda u: sum_squares(u, model, data))(u_batch)


def constrained(model, u) -> dict:
    """``model.constrain(u)`` in the model's parameter order (which a pytree, with
    sorted keys, does not keep), in one compiled call: the uncertainty's
    linearisation, so that a new process compiles one program for both."""
    theta = np.asarray(linearisation(model, np.asarray(u, np.float64))[0])
    out, i = {}, 0
    for s in model.param_specs:
        out[s.name] = theta[i:i + s.size] if s.rgb else theta[i]
        i += s.size
    return out


def _bound_side(u, args):
    return args[0].solver_bound_side(u)  # (model, data) or (model, data, term)


def _unbounded_above(u, args):
    """The model's softplus coordinates, a constant (the solver's step cap is relative
    there: ``brdffit.fitting.solver.RELATIVE_STEP``)."""
    return jnp.asarray(args[0].unbounded_above())


def start_bucket(n: int) -> int:
    """How many starts a compiled solve holds for ``n`` starts: the next power of two.
    With the step limit as data (the lm solver), the slots past ``n`` take no step
    (a limit of 0), so 3 starts cost 3 solves (and one evaluation), and one compiled
    solve serves 3 and 4."""
    return 1 << max(n - 1, 0).bit_length()


class ObjectiveTerm(Protocol):
    """A term added to a fit's sum of squares (the physical bound's barrier,
    ``brdffit.fitting.physical.AlbedoBarrier``): its residuals, for the solvers that
    read residuals, and its share of the normal equations, for those that read them.
    An equinox module, so that its arrays are the solve's data."""

    def residuals(self, u, model): ...

    def normal_equations(self, u, model) -> tuple: ...


def _objective_residuals(u, args):
    model, data, term = args
    r = residuals(u, (model, data))
    if term is None:
        return r
    return jnp.concatenate([r.reshape(-1), term.residuals(u, model)])


def _objective_normal_equations(u, args):
    model, data, term = args
    loss, jtj, jtr = normal_equations(u, (model, data))
    if term is None:
        return loss, jtj, jtr
    add_loss, add_jtj, add_jtr = term.normal_equations(u, model)
    return loss + add_loss, jtj + add_jtj, jtr + add_jtr


def _objective_normal_equations_with_meat(u, args):
    model, data, _ = args  # with a term, the solve carries no uncertainty terms
    return normal_equations_with_meat(u, (model, data))


@executables.jit
def solve_batch(model, solver_name: str, u_batch, data, max_steps, n_live=None, term=None):
    """Solve from each start of ``u_batch``: (values, status, steps, loss, terms) per
    start; with ``max_steps`` an array (the lm solver), only the first ``n_live``
    (data) take steps: the rest pad the batch to :func:`start_bucket` and stop where
    they start. ``term``: an :class:`ObjectiveTerm` added to the data's sum of
    squares (the physical bound's barrier; ``loss`` then includes it), or None.

    ``terms`` are the sandwich covariance's (bread, meat) at each solution, in the
    unconstrained parameters (``brdffit.fitting.uncertainty``): the lm solver
    carries them from its own normal equations, so a fit's uncertainty compiles no
    program of its own (~1.3 s of a new process's first GGX fit on 2 cores); None
    for the other solvers, whose fits have it computed afterwards, and with a
    ``term`` (the uncertainty is the data's alone)."""
    import optimistix as optx

    from brdffit.fitting import solver as solvers

    solver = solver_for(solver_name, jnp.dtype(data.target.dtype).name)
    # the loss of an exact fit, on this table's own scale (a dim table is no exact fit)
    floor = solvers.loss_floor(data.target, data.weight)
    spec = get_solver(solver_name)
    carries_terms = spec.carries_terms and term is None
    options = {"normal_equations": (_objective_normal_equations_with_meat if carries_terms
                                    else _objective_normal_equations),
               "bound_side": _bound_side, "unbounded_above": _unbounded_above,
               "loss_floor": floor}
    limits = None
    if spec.steps_as_data and isinstance(max_steps, jax.Array):
        # the step limit is data (fit passes an array): one solve for every max_steps,
        # and every start count up to the batch's length
        live = jnp.arange(u_batch.shape[0]) < (u_batch.shape[0] if n_live is None else n_live)
        limits = jnp.where(live, max_steps, 0)
        max_steps = STEP_CAP
    args = (model, data, term)

    def one(u0, limit):
        sol = optx.least_squares(
            _objective_residuals,
            solver,
            u0,
            args=args,
            options=options if limit is None else {**options, "step_limit": limit},
            max_steps=solvers.loop_steps(solver, max_steps),
            throw=False,
        )
        # Whatever the solver and however it stopped, "successful" means the
        # optimality test holds at the point it returns (brdffit.fitting.solver).
        if carries_terms:
            # Its final state holds that test, made at that point with the same
            # tolerances and floor: no third copy of the normal equations (after
            # its init's and its step's) to compile into the program.
            loss, optimal = sol.stats["loss"], sol.stats["stop"] == solvers.OPTIMAL
            terms = (sol.stats["jtj"], sol.stats["meat"])
        else:
            loss, jtj, jtr = _objective_normal_equations(sol.value, args)
            optimal = solvers.is_optimal(
                loss, jtj, jtr, model.solver_bound_side(sol.value), solvers.gtol_for(loss.dtype),
                floor
            )
            terms = None
        # Return values, not the Solution: its state holds a jaxpr.
        return sol.value, solvers.status(sol.result, optimal), sol.stats["num_steps"], loss, terms

    if limits is None:
        return jax.lax.map(lambda u0: one(u0, None), u_batch)
    return jax.lax.map(lambda a: one(*a), (u_batch, limits))


# -- data preparation --------------------------------------------------------------


@functools.cache
def _device_frames(dtype_name: str) -> Frame:
    """The shading frame of every bin centre, on the device, made once per process
    (only targets and weights travel per table).

    In numpy, from the grid's own axes rather than from its 1.46M direction pairs:
    with phi_h = 0 the half vector is (sin theta_h, 0, cos theta_h) and wi . h =
    cos theta_d, exactly, so half of the frame is a product of one-dimensional
    arrays (~40 ms; a compiled frame cost ~0.3 s of a new process's first fit).
    Equal to :func:`shading_frame` of the directions to rounding
    (tests/test_angles.py)."""
    g = bin_grid()
    theta_h = g.theta_h.reshape(angles.SHAPE)[:, :1, :1]
    theta_d = g.theta_d.reshape(angles.SHAPE)[:1, :, :1]
    wi, wo = g.wi, g.wo

    def flat(a) -> jax.Array:  # one value per bin, or per bin of an axis
        a = a if a.ndim == 1 else np.broadcast_to(a, angles.SHAPE).reshape(-1)
        return jnp.asarray(a.astype(dtype_name))

    return Frame(
        cos_i=flat(np.clip(g.cos_i, 0.0, 1.0)), cos_o=flat(np.clip(g.cos_o, 0.0, 1.0)),
        cos_h=flat(np.cos(theta_h)), cos_d=flat(np.cos(theta_d)),
        sin2_i=flat(np.minimum(wi[:, 0] ** 2 + wi[:, 1] ** 2, 1.0)),
        sin2_o=flat(np.minimum(wo[:, 0] ** 2 + wo[:, 1] ** 2, 1.0)),
        sin2_h=flat(np.sin(theta_h) ** 2),
        dot_xy=flat(wi[:, 0] * wo[:, 0] + wi[:, 1] * wo[:, 1]),
    )


def _make_loss_data(table, index, weight, dtype, frame: Frame, loss: str) -> LossData:
    return loss_data(table.rgb.reshape(3, -1)[:, index], bin_grid().cos_i[index], weight,
                     dtype, frame, loss)


def loss_data(values: np.ndarray, cos_i: np.ndarray, weight, dtype, frame: Frame,
              loss: str) -> LossData:
    """Measured ``values`` (3, s) at directions with incidence cosines ``cos_i`` and
    shading ``frame``, weighted by ``weight`` (s,), as the targets of ``loss``: a
    table's bins and a sample list's own directions alike."""
    x = values * np.maximum(cos_i, 0.0)
    spec = get_loss(loss)
    exposure = energy = None
    if spec.rendered:
        w = np.asarray(weight)
        exposure = render_loss.exposures(np.maximum(x, 0.0), w)
        target = spec.compress(np.maximum(x, 0.0) * exposure, spec.target_xp)
        energy = (np.maximum(x, 0.0) @ w / max(float(w.sum()), 1e-300))[:, None]
    else:
        # in the loss's own array module: the log loss's targets in numpy, as they
        # were to the last bit before the loss was a choice (Loss.target_xp)
        target = spec.compress(x, spec.target_xp)
    # the losses of SELECTABLE share one compiled fit: the loss travels as data
    selector = jnp.asarray(SELECTABLE.index(loss), jnp.int32) if spec.selectable else None
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
    return _make_loss_data(table, index, weight, dtype, _sample_frame(index, dtype), loss)


def _sample_frame(index: np.ndarray, dtype) -> Frame:
    """The shading frame of the bins ``index``, made in numpy from their directions:
    a fit's samples need neither the whole grid's frame nor a compiled program
    (in a new process, ~0.3 s before the first fit could start compiling)."""
    g = bin_grid()
    return frame_of(g.wi[index], g.wo[index], dtype)


def frame_of(wi: np.ndarray, wo: np.ndarray, dtype) -> Frame:
    """The shading frame of direction pairs (a table's bins, a sample list's samples),
    made in numpy in the solve's own precision (as its frame was when it came from the
    grid's), then put on the device."""
    name = jnp.dtype(dtype).name
    frame = shading_frame(wi.astype(name), wo.astype(name), np)
    return Frame(*(jnp.asarray(a, dtype) for a in frame))


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
    if get_loss(loss).rendered:  # the exposures need the table's values in numpy anyway
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


def cached(table: MerlTable, key, make):
    # One lock for every table: fits running beside each other (``auto``'s
    # candidates) wait for the first one's preparation instead of repeating it.
    with _TABLE_CACHE_LOCK:
        per_table = _TABLE_CACHE.setdefault(table, {})
        if key not in per_table:
            per_table[key] = make()
        return per_table[key]


def sphere_reference(table: MerlTable) -> SphereReference:
    """The table's sphere renders (``brdffit.fitting.sphere.SphereReference``), made once
    per table object: every fit of it scores its sphere against them, and a plot of it
    reads at which exposure the verdict judged each light."""
    return cached(table, "sphere", lambda: SphereReference(table))


def _device_rgb(table: MerlTable):
    """The table's values on the device, as they are (float64, channel-major): no
    copy at all on the CPU, where a 64-byte-aligned array (``merl.read`` allocates
    one) is used in place; each error pass converts them block by block."""
    return cached(table, "device-rgb", lambda: jax.device_put(table.rgb.reshape(3, -1)))


def peak_bin(table: MerlTable, weight: np.ndarray) -> int:
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


#: ``rel_peak_error`` divides a channel's error at the peak by that channel's value,
#: or by this fraction of the peak's brightest channel where the channel is darker.
PEAK_CHANNEL_FLOOR = 0.01


@executables.jit
def _full_errors(models, us, rgb, weight, frame, peak, part, parts: int):
    """The sums behind log_rmse, cube_root_rmse and rmse_cos of each of ``models`` at
    its ``us`` (one row per model) over the ``part``-th of ``parts`` runs of the
    table's blocks (``brdffit.fitting.loss.sum_over_blocks``), and each one's relative
    error at the peak bin.

    The measured side of every metric is made here, per block, from the table's own
    values: the model is evaluated once per bin, each block's temporaries stay in
    cache, and no per-table array of targets is built first. Building the three
    targets of 4.4M values beforehand cost 15-25 ms per table; here they cost ~1 ms
    per pass (issue 15). Several models (``auto``'s candidates) share one pass: the
    table's side (its values, directions, weights and their compressed forms) is read
    and made once for all of them, which was most of a pass's time (issue 41)."""
    dtype = us[0].dtype

    def sums(block):
        cos_i = jnp.maximum(block["frame"].cos_i, 0.0)
        meas_cos = block["rgb"].astype(dtype) * cos_i
        w = block["weight"].astype(dtype)
        measured = [LOSS_REGISTRY[name].compress(meas_cos) for name in FULL_TABLE_LOSSES]
        rows = []
        for model, u in zip(models, us, strict=True):
            fit_cos = _fit_cos(model, u, block["frame"])
            row = []
            for name, g_meas in zip(FULL_TABLE_LOSSES, measured, strict=True):
                d = LOSS_REGISTRY[name].compress(fit_cos) - g_meas
                row.append(jnp.sum(w * d * d))
            rows.append(jnp.stack(row))
        return jnp.stack(rows)

    arrays = {"frame": frame, "weight": weight, "rgb": rgb}
    total = sum_over_blocks(sums, arrays, weight.shape[-1], part, parts)
    at = jax.tree_util.tree_map(lambda a: a[peak][None], frame)
    meas_peak = rgb[:, peak].astype(dtype) * jnp.maximum(at.cos_i[0], 0.0)
    # each channel relative to itself, but to no less than PEAK_CHANNEL_FLOOR of the
    # peak's brightest: a black channel (a pure red table's G and B) made a fit exact
    # to 1e-8 read 250 here, an error divided by 1e-12
    scale = jnp.maximum(meas_peak, jnp.maximum(PEAK_CHANNEL_FLOOR * jnp.max(meas_peak), 1e-12))
    rel_peak = [jnp.max(jnp.abs(_fit_cos(model, u, at)[:, 0] - meas_peak) / scale)
                for model, u in zip(models, us, strict=True)]
    return total, jnp.stack(rel_peak)


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
#: programs this process has made ready (:func:`ready_report_once`).
_REPORTS_READY: set = set()


def ready_report_once(table, model, u, prep: Prepared, loss: str, precision: str,
                      solver: str = DEFAULT_SOLVER, full_table: bool = True):
    """The first fit of its kind in a process: make the programs of its report (the
    full-table error, the parameters, the sphere, the uncertainty) ready by running
    them on a start vector, while the scoring and the solve compile (or load). They
    depend on shapes alone, not on the solution: a new process compiles them at the
    same time as the solve (``brdffit.executables`` compiles programs side by side;
    bench/results/startup.md). Later fits of the kind skip this; the results here
    are dropped.

    The full-table error (and, but for the float64 lm solve, which carries the
    uncertainty's terms itself, the uncertainty) go to the report pool's threads
    now. The rest (the parameters, the sphere, the quality block) is returned, for
    the caller to run on its own thread once it has scored its starts: it would
    otherwise wait there, idle, for the solve compiling on the pool. None when this
    is not the first fit of its kind. ``full_table=False``: the full-table error is
    measured beside other fits' (:func:`full_table_metrics_of`, made ready by
    :func:`ready_metrics_of_once`), not alone."""
    # the kind of the programs, not of the model: members of a family fitted on its
    # programs (ggx and beckmann in auto; also inside MonoKs) make them ready once
    form = model.compiled_form()
    kind = (type(form), form.name, precision, loss, prep.data.weight.shape,
            prep.weight is None or prep.weight.size, full_table)
    with _ERROR_THREADS_LOCK:
        if kind in _REPORTS_READY:
            return None
        _REPORTS_READY.add(kind)

    def ready(part) -> None:
        try:
            part(np.asarray(u, np.float64))
        except Exception as e:  # noqa: BLE001 - a start far off the table: speed only
            runtime.log.debug("brdffit: report of %s not made ready ahead (%s)", model.name, e)

    def sphere(u0) -> None:
        params = plain_params(constrained(model, u0))
        sphere_reference(table).psnr_and_colour(model, params)

    if full_table:
        report_pool().submit(runtime.in_float64(ready), lambda u0: full_table_metrics(
            table, model, u0, prep.weight, peak=prep.peak))
    # a solve that carries the uncertainty's terms makes them; only float64 ones are used
    if not (get_solver(solver).carries_terms and precision == "float64"):
        report_pool().submit(runtime.in_float64(ready),
                             lambda u0: parameter_uncertainty(model, u0, prep.data))
    return functools.partial(runtime.in_float64(ready), sphere)


def ready_metrics_of_once(table, fits: list, prep: Prepared) -> None:
    """The first time in a process that these models' full-table error is measured in
    one pass (:func:`full_table_metrics_of`, ``auto``'s candidates): make its program
    ready on the report pool now, at start vectors ``fits`` (``(model, u)``), while the
    fits' own programs compile (or load): it depends on the models and shapes alone."""
    kind = (tuple((type(f), f.name) for f in (m.compiled_form() for m, _ in fits)),
            prep.weight.size)
    with _ERROR_THREADS_LOCK:
        if kind in _REPORTS_READY:
            return
        _REPORTS_READY.add(kind)

    def ready() -> None:
        try:
            full_table_metrics_of(table, fits, prep.weight, peak=prep.peak)
        except Exception as e:  # noqa: BLE001 - a start far off the table: speed only
            runtime.log.debug("brdffit: one pass of %d fits not made ready ahead (%s)",
                              len(fits), e)

    report_pool().submit(runtime.in_float64(ready))


def report_pool():
    """Two threads per process for the parts of a fit's report that overlap the
    full-table pass and, in a new process, the solve's compilation (a forked child
    makes its own, as :func:`_error_pool`)."""
    from concurrent.futures import ThreadPoolExecutor

    with _ERROR_THREADS_LOCK:
        pool = _REPORT_THREADS.get(os.getpid())
        if pool is None:
            _REPORT_THREADS.clear()
            pool = _REPORT_THREADS[os.getpid()] = ThreadPoolExecutor(
                2, thread_name_prefix="brdffit-report")
        return pool


def metrics_from_sums(total, rel_peak) -> dict[str, float]:
    """The metrics of :func:`error_sums`' weighted sums of squares (over R, G, B: the
    root of a third of each; one per loss of ``FULL_TABLE_LOSSES``: log_rmse,
    cube_root_rmse, rmse_cos) and the relative error at the peak."""
    rmse = np.sqrt(np.asarray(total, np.float64) / 3.0)
    return {**{LOSS_METRIC[name]: float(r) for name, r in zip(FULL_TABLE_LOSSES, rmse,
                                                                strict=True)},
            "rel_peak_error": float(rel_peak)}


def error_sums(model, u, rgb, weight, frame, peak):
    """The sums behind every error metric of ``u`` over ``rgb`` (3, n) measured at
    ``frame``, weighted by ``weight``, and the relative error at index ``peak``: one
    implementation for a table's bins and a sample list's directions
    (:func:`metrics_from_sums`)."""
    totals, rel_peaks = _error_sums_of((model,), (u,), rgb, weight, frame, peak)
    return totals[0], rel_peaks[0]


def _error_sums_of(models: tuple, us: tuple, rgb, weight, frame, peak):
    """:func:`error_sums` of several models in one pass: one row each, as numpy arrays
    (rows taken from device arrays would each be a program of its own to compile)."""
    n = weight.shape[-1]
    parts = _error_parts(n)
    if parts == 1:
        total, rel_peak = _full_errors(models, us, rgb, weight, frame, peak, jnp.asarray(0), 1)
        return np.asarray(total), np.asarray(rel_peak)
    # float64 is a per-thread setting in JAX: each run sets it as this thread has it
    runs = [_error_pool(parts).submit(runtime.in_float64(_full_errors), models, us, rgb,
                                      weight, frame, peak, jnp.asarray(i), parts)
            for i in range(parts)]
    results = [run.result() for run in runs]
    return sum(np.asarray(total) for total, _ in results), np.asarray(results[0][1])


def full_table_metrics(
    table: MerlTable,
    model: models.AbstractBRDFModel,
    u,
    weight: np.ndarray,
    dtype=FULL_TABLE_DTYPE,
    peak: int | None = None,
) -> dict[str, float]:
    """The error metrics (docs/results.md: log_rmse, cube_root_rmse, rmse_cos,
    rel_peak_error; :func:`error_sums`, the one implementation) of unconstrained
    params ``u`` over every bin of ``table`` with weight > 0.

    Evaluated in ``dtype`` (float32 by default, for speed). Table values are bounded
    (``brdffit.io.merl.MAX_VALUE``, 1e12 1/sr), so float32 holds every measured term; a
    model far off that scale (a diverged ``ks``) can still overflow it, and then the
    metrics are evaluated again in float64 rather than reported as inf. A metric that
    is not finite even in float64 is returned as it is (NaN or inf): the caller must
    not report such a fit as a success.
    """
    return full_table_metrics_of(table, [(model, u)], weight, dtype, peak)[0]


def full_table_metrics_of(
    table: MerlTable,
    fits: list[tuple[models.AbstractBRDFModel, object]],
    weight: np.ndarray,
    dtype=FULL_TABLE_DTYPE,
    peak: int | None = None,
) -> list[dict[str, float]]:
    """:func:`full_table_metrics` of each ``(model, u)`` of ``fits``, in one pass over
    the table (``auto``'s candidates: one pass costs about what two of one model do,
    where each alone reads the whole table again). Each fit's metrics are evaluated
    again in float64 alone where they overflow ``dtype``, as one fit's are."""
    peak = jnp.asarray(peak_bin(table, weight) if peak is None else peak)
    rgb = _device_rgb(table)
    w = jnp.asarray(weight)
    out: list[dict[str, float] | None] = [None] * len(fits)
    todo = list(range(len(fits)))
    for dt in (dtype, jnp.float64):
        frame = _device_frames(jnp.dtype(dt).name)
        with np.errstate(over="ignore"):  # what overflows dtype is measured again below
            params = tuple(jnp.asarray(np.asarray(fits[i][1], dt)) for i in todo)
        totals, rel_peaks = _error_sums_of(tuple(fits[i][0] for i in todo), params, rgb, w,
                                           frame, peak)
        last = jnp.dtype(dt) == jnp.float64
        for i, total, rel_peak in zip(todo, totals, rel_peaks, strict=True):
            metrics = metrics_from_sums(total, rel_peak)
            if last or all(map(np.isfinite, metrics.values())):
                out[i] = metrics
        todo = [i for i in todo if out[i] is None]
        if not todo:
            break
    return out


@runtime.in_float64
def table_error(
    table: MerlTable,
    model: str | models.AbstractBRDFModel,
    params: dict,
    bin_weight: np.ndarray | None = None,
) -> dict[str, float]:
    """Error metrics (:func:`full_table_metrics`) of ``params`` on every usable
    bin of ``table``, optionally under a scene's ``bin_weight``."""
    m = models.get(model)
    u = m.unconstrain(m.check_params(params))
    weight = bin_weights(usable_bins(table, bin_weight).usable, bin_weight)
    return full_table_metrics(table, m, u, weight)


# -- the result ----------------------------------------------------------------------


def plain_params(params: dict) -> dict:
    out = {}
    for k, v in params.items():
        a = np.asarray(v, dtype=np.float64)
        out[k] = a.tolist() if a.ndim else float(a)
    return out


class Prepared(NamedTuple):
    """What every model's fit of one table with the same options shares."""

    counts: object  # sampling.BinCounts
    n_usable: int
    weight: np.ndarray
    sample_set: object  # sampling.SampleSet
    data: LossData
    peak: int
    brightest: float  # the largest usable value (1/sr)
    hints: TableHints | None  # what the starts read from the table
    # the table the starts read (a sample list's binned table; None: the table itself)
    start_table: MerlTable | None = None


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


def prepare(table: MerlTable, bin_weight, samples, seed: int, precision: str,
             loss: str) -> Prepared:
    """The usable bins, their weights, the subsample and its device data: computed
    once per table and options and reused by every model fitted to the same table
    object (``auto``, a batch's models, a nested model's parent), ~10 ms a table."""
    weight_key = None if bin_weight is None else hashlib.sha1(bin_weight.tobytes()).hexdigest()

    def make() -> Prepared:
        counts = usable_bins(table, bin_weight)
        n_usable = int(np.count_nonzero(counts.usable))
        # the channels' maximum first, then the usable bins' (no boolean selection copy)
        brightest = float(np.max(table.rgb.reshape(3, -1).max(axis=0), where=counts.usable,
                                 initial=0.0))
        if n_usable == 0 or brightest < merl.MIN_PEAK:  # fit() says why
            return Prepared(counts, n_usable, None, None, None, -1, brightest, None)
        weight, sample_set = _weights_and_samples(counts.usable, bin_weight, weight_key,
                                                  samples, seed)
        if get_loss(loss).rendered and bin_weight is None:
            # the solver sees the bins of the render loss's views, weighted by the
            # area of the pictures that reflect in them; the error is still judged on
            # every usable bin
            views = render_loss.view_bin_weight()
            _, sample_set = _weights_and_samples(counts.usable & (views > 0), views,
                                                 "render-views", samples, seed)
        sample_set = padded(sample_set)  # one compiled fit for every count up to a bucket
        data = sample_data(table, sample_set.index, sample_set.weight, DTYPES[precision],
                           loss)
        return Prepared(counts, n_usable, weight, sample_set, data, peak_bin(table, weight),
                         brightest, table_hints(table, counts.usable))

    return cached(table, ("prepared", samples, seed, precision, loss, weight_key), make)


# -- the front door ------------------------------------------------------------------
