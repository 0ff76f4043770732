"""Fit an analytic model to a MERL table or a sample list: ``fit(table, "ggx") -> FitResult``.

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

The problem each step works on (the prepared table, the compiled solve, the
full-table metrics) is ``brdffit.fitting.problem``'s; a physically bounded fit is a
bounded step over this free fit (``brdffit.fitting.physical``). A sample list
(``brdffit.io.measurements.Measurements``) runs the same steps at its own directions:
its weights, subsample, held-out folds, coverage and verdict are
``brdffit.fitting.samples``'.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import jax.numpy as jnp
import numpy as np

from brdffit import models, runtime
from brdffit.errors import FitInputError
from brdffit.fitting.loss import LOSS_METRIC
from brdffit.fitting.options import (
    DEFAULT_LOSS,
    DEFAULT_MAX_STEPS,
    DEFAULT_MODEL,
    DEFAULT_PRECISION,
    DEFAULT_SEED,
    DEFAULT_SOLVER,
    DEFAULT_STARTS,
    LOSSES,
    PRECISIONS,
    SOLVERS,
)
from brdffit.fitting.physical import bound
from brdffit.fitting.problem import (
    DTYPES,
    LIVE_U,
    STEP_CAP,
    cached,
    constrained,
    full_table_metrics,
    plain_params,
    prepare,
    ready_report_once,
    report_pool,
    score_starts,
    solve_batch,
    start_bucket,
)
from brdffit.fitting.quality import quality
from brdffit.fitting.result import STATUS_NAMES, FitResult
from brdffit.fitting.sampling import (
    DEFAULT_SAMPLES,
)
from brdffit.fitting.sphere import SphereReference
from brdffit.fitting.starts import candidates as start_vectors
from brdffit.fitting.uncertainty import parameter_uncertainty
from brdffit.io import merl
from brdffit.io.angles import N_BINS
from brdffit.io.measurements import Measurements
from brdffit.io.merl import MerlTable


@runtime.in_float64
def fit(
    table: MerlTable | Measurements,
    model: str | models.AbstractBRDFModel = DEFAULT_MODEL,
    *,
    loss: str = DEFAULT_LOSS,
    solver: str = DEFAULT_SOLVER,
    samples: int | None = DEFAULT_SAMPLES,
    precision: str = DEFAULT_PRECISION,
    starts: int = DEFAULT_STARTS,
    max_steps: int = DEFAULT_MAX_STEPS,
    seed: int = DEFAULT_SEED,
    init: dict | None = None,
    bin_weight: np.ndarray | None = None,
    parent_fit: FitResult | Callable[[], FitResult] | None = None,
    physical: bool = False,
) -> FitResult:
    """Fit ``model`` to ``table``; see the module docstring for the pipeline.

    Args:
        table: the measured table (``brdffit.io.merl.read``), or a sample list
            (``brdffit.io.measurements.Measurements``), fitted at its own
            directions (``brdffit.fitting.samples``: its weights, held-out error,
            coverage and verdict).
        model: a registry name (``brdffit.models.REGISTRY``) or a model instance.
        loss: what the solver minimises (``brdffit.fitting.options.LOSSES``): ``"log"``
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
            the fit's samples than the one it contains. Or a function that returns
            that fit (``auto`` passes its parent's fit still running: this fit's
            programs compile and its starts are scored meanwhile); where it raises
            ``FitInputError``, the parent is fitted here.
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
    on_samples = isinstance(table, Measurements)
    if bin_weight is not None:
        bin_weight = np.asarray(bin_weight, dtype=np.float64).ravel()
        if bin_weight.size != N_BINS or not np.all(np.isfinite(bin_weight)):
            raise FitInputError("bin_weight needs one finite value per MERL bin")
        if np.any(bin_weight < 0):
            raise FitInputError("bin_weight must be >= 0")
    if physical is not False:
        if physical is not True:
            raise FitInputError(f"physical must be true or false, got {physical!r}")
        if on_samples:
            raise FitInputError(
                f"{table.source}: the physical bounds are not available for a sample list "
                "yet (their albedo check reads a table): fit it without them")
        # A bounded step over the free fit (brdffit.fitting.physical); a nested fit
        # seeds from its parent's *unconstrained* optimum.
        parent_fit = _resolved(parent_fit)
        if parent_fit is not None and parent_fit.physical is not None:
            parent_fit = None
        free = fit(table, m, loss=loss, solver=solver, samples=samples, precision=precision,
                   starts=starts, max_steps=max_steps, seed=seed, init=init,
                   bin_weight=bin_weight, parent_fit=parent_fit)
        return bound(table, free, model=m, loss=loss, solver=solver, samples=samples,
                     precision=precision, max_steps=max_steps, seed=seed,
                     bin_weight=bin_weight)

    if on_samples:
        from brdffit.fitting import samples as sample_fit

        prep = sample_fit.prepare_samples(table, bin_weight, samples, seed, precision, loss)
    else:
        prep = prepare(table, bin_weight, samples, seed, precision, loss)
    counts, n_usable, weight, sample_set, data = (
        prep.counts, prep.n_usable, prep.weight, prep.sample_set, prep.data)
    what = "samples" if on_samples else "bins"
    if n_usable < m.n_params * 4:
        raise FitInputError(
            f"{table.source}: only {n_usable} usable {what} (measured, finite, above the "
            f"horizon{', weighted by the scene' if bin_weight is not None else ''}); "
            f"{m.name} needs at least {m.n_params * 4}"
        )
    if prep.brightest < merl.MIN_PEAK:
        raise FitInputError(
            f"{table.source}: every usable {what[:-1]} is below {merl.MIN_PEAK:g} 1/sr"
            f"{' under the scene' if bin_weight is not None else ''}: nothing to fit"
        )
    dtype = DTYPES[precision]

    again = dict(loss=loss, solver=solver, precision=precision, starts=starts,
                 max_steps=max_steps, seed=seed, bin_weight=bin_weight)
    # Every bin (samples=None): the fit on the default subsample, with its starts and
    # its nested parent, lands next to the optimum at ~1/70 of the cost per step;
    # every bin then only polishes it (a few steps instead of dozens, per start).
    polish = (samples is None and init is None and n_usable > 4 * DEFAULT_SAMPLES
              and not on_samples)
    if init is not None:
        u_candidates = m.unconstrain(m.check_params(init))[None]
    elif polish:
        coarse = fit(table, m, samples=DEFAULT_SAMPLES, **again)
        # A coordinate deep in its transform's flat tail (a scale at 1e-14) is pulled
        # back to the tail's edge (|u| <= 14, as every start is): the full table may
        # want it back, and from deep in the tail capped steps would only crawl.
        u_candidates = np.clip(m.unconstrain(m.check_params(coarse.params)), -14.0, 14.0)[None]
    else:
        u_candidates = start_vectors(m, table if prep.start_table is None else prep.start_table,
                                     counts.usable, prep.hints)
    steps_as_data = solver == "lm" and max_steps <= STEP_CAP
    n_starts = min(starts, len(u_candidates))
    ready_here = (None if on_samples else
                  ready_report_once(table, m, u_candidates[0], prep, loss, precision, solver))
    if ready_here is not None and steps_as_data:
        # the solve's program depends on the number of starts, not on which: in a new
        # process it compiles here, beside the scoring below
        report_pool().submit(runtime.in_float64(_ready_solve), m, solver, u_candidates,
                             n_starts, dtype, data, max_steps)
    if len(u_candidates) > 1:  # one candidate (init, a polish) has nothing to rank
        # Score candidates on every 8th sample: ranking starts needs no more.
        scores = np.asarray(score_starts(m, jnp.asarray(u_candidates, dtype), data, 8))
        scores = np.where(np.isfinite(scores), scores, np.inf)
        best_starts = u_candidates[_best_of_each_family(m, scores, n_starts)]
    else:
        best_starts = u_candidates
    if ready_here is not None:
        ready_here()
    parent_start = None
    if init is None and m.parent is not None:
        parent_fit = _resolved(parent_fit)
        on_every_bin = parent_fit is not None and parent_fit.samples["used"] == n_usable
        if (parent_fit is None or parent_fit.model != m.parent or parent_fit.loss != loss
                or (polish and not on_every_bin)):
            parent_fit = fit(table, m.parent, samples=samples, **again)
        parent_start = m.unconstrain(m.check_params(m.embed_parent(parent_fit.params)))

    bucket = start_bucket(len(best_starts))  # the starts the first solve's program holds

    def solve(u_batch: np.ndarray, take_steps: bool = True,
              on=data) -> list[np.ndarray | None]:
        """values, codes, steps, losses, and the uncertainty's (bread, meat) or None,
        of a solve from each start of ``u_batch``; without ``take_steps`` (the lm
        solver only), the losses of the starts themselves. ``on``: the data (a sample
        list's held-out folds reweight it: the same program)."""
        k = len(u_batch)
        if not steps_as_data:
            *out, terms = solve_batch(m, solver, jnp.asarray(u_batch, dtype), on, max_steps)
        else:
            # Every solve of this fit (a nested model's retries from its parent, the
            # parent's own loss) runs in the program of its first: one compile in a
            # new process, where a retry of one start compiled a second solve. The
            # padding takes no step; it costs one evaluation of the loss per slot.
            padded = _padded(u_batch, max(bucket, start_bucket(k)))
            *out, terms = solve_batch(m, solver, jnp.asarray(padded, dtype), on,
                                      jnp.asarray(max_steps),
                                      n_live=jnp.asarray(k if take_steps else 0))
        bread, meat = (None, None) if terms is None else terms
        return [None if a is None else np.asarray(a)[:k] for a in (*out, bread, meat)]

    values, codes, steps, losses, bread, meat = solve(best_starts)
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
        if steps_as_data:  # the solve's own loss, from the same normal equations
            parent_loss = float(solve(parent_start[None], take_steps=False)[3][0])
        else:
            parent_loss = float(score_starts(m, jnp.asarray(parent_start[None], dtype), data)[0])

        def above_parent() -> bool:
            return bool(np.min(np.where(np.isfinite(losses), losses, np.inf)) > parent_loss)

        def solve_also(u) -> None:
            nonlocal values, codes, steps, losses, bread, meat, best_starts
            extra = solve(u[None])
            values, codes, steps, losses, bread, meat = (
                None if a is None else np.concatenate([a, b]) for a, b in
                zip((values, codes, steps, losses, bread, meat), extra))
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
    terms = None if bread is None or result == "nonfinite" else (bread[i], meat[i])
    pending = (report_pool().submit(runtime.in_float64(parameter_uncertainty), m, u_best, data,
                                    terms)
               if result != "nonfinite" else None)
    if on_samples:
        metrics = sample_fit.sample_metrics(m, u_best, sample_fit.every_sample(table, weight))
    else:
        metrics = full_table_metrics(table, m, u_best, weight, peak=prep.peak)
    # the optimised loss on the solver's own subsample: sample_log_rmse for the log loss
    metrics[f"sample_{LOSS_METRIC[loss]}"] = (
        float(np.sqrt(max(losses[i], 0.0) / 3.0)) if finite.any() else float("nan")
    )
    if result == "successful" and not all(np.isfinite(v) for v in metrics.values()):
        result = "nonfinite"  # an error that cannot be measured is no success
    params = plain_params(constrained(m, np.asarray(u_best)))
    basis, measured_input = "sphere", None
    if on_samples:
        held = None
        if result != "nonfinite":
            def refit(fold_data):  # one start from the optimum, in this fit's solve
                values, codes, *_ = solve(np.asarray(u_best, np.float64)[None], on=fold_data)
                return values[0], codes[0]

            held = sample_fit.held_out(m, table, u_best, prep, refit, seed=seed)
        if held is not None:
            metrics.update({f"held_out_{k}": v for k, v in held.metrics.items()})
            if not all(np.isfinite(v) for v in held.metrics.values()):
                result = "nonfinite"  # an error that cannot be measured is no success
        metrics["psnr_db"], colour, basis = sample_fit.look(table, prep, held, m, params)
        measured_input = sample_fit.fitted_input(table, prep, m, params, held)
    else:
        # The image error of the whole sphere (no scene weighting): one figure that
        # compares fits made under different losses.
        metrics["psnr_db"], colour = cached(
            table, "sphere", lambda: SphereReference(table)).psnr_and_colour(m, params)
    uncertainty = None
    if pending is not None and result != "nonfinite":
        uncertainty = pending.result()
    elif pending is not None:  # the metrics say nonfinite: no uncertainty, whatever it was
        pending.exception()
    if measured_input is not None:
        measured_input["identifiability"] = sample_fit.identifiability(uncertainty)
    look = quality(metrics["psnr_db"], colour, model=m, params=params, loss=loss,
                   converged=result == "successful", basis=basis)
    if measured_input is not None:
        look = sample_fit.within_samples(look, measured_input)
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
        input=measured_input,
    )


def _best_of_each_family(m, scores: np.ndarray, n_starts: int) -> np.ndarray:
    """Indices of the starts to refine: the ``n_starts`` best-scored, and where the
    model names a ``start_family``, the best-scored start of each of its values too
    (one candidate per ``shape_grid`` entry, in its order)."""
    order = np.argsort(scores, kind="stable")
    chosen = list(order[:n_starts])
    family = m.start_family
    if family is not None and len(m.shape_grid) == len(scores):
        keys = [shape[family] for shape in m.shape_grid]
        for value in dict.fromkeys(keys):
            best = next(int(j) for j in order if keys[j] == value)
            if best not in chosen and np.isfinite(scores[best]):
                chosen.append(best)
    return np.asarray(chosen)


def _resolved(parent_fit) -> FitResult | None:
    """``fit``'s ``parent_fit`` as a fit: called where it is a function; None where
    that raised ``FitInputError`` (the parent is then fitted, and fails, here)."""
    if not callable(parent_fit):
        return parent_fit
    try:
        return parent_fit()
    except FitInputError:
        return None


def _padded(u_batch: np.ndarray, size: int | None = None) -> np.ndarray:
    """``u_batch`` padded to ``size`` starts, by default its :func:`start_bucket` (one
    compiled solve per bucket; the padding takes no step)."""
    k = len(u_batch)
    size = start_bucket(k) if size is None else size
    return np.concatenate([u_batch, np.repeat(u_batch[:1], size - k, 0)])


def _ready_solve(m, solver, u_candidates, n_starts, dtype, data, max_steps) -> None:
    """Compile (or load) the solve that ``fit`` is about to run, without running it."""
    try:
        solve_batch.ready(m, solver, jnp.asarray(_padded(u_candidates[:n_starts]), dtype), data,
                          jnp.asarray(max_steps), n_live=jnp.asarray(n_starts))
    except Exception as e:  # noqa: BLE001 - speed only: the solve itself will say
        runtime.log.debug("brdffit: solve of %s not made ready ahead (%s)", m.name, e)
