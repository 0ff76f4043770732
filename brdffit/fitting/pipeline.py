"""Fit an analytic model to a MERL table or a sample list: ``fit(table, "ggx") -> FitResult``.

The pipeline is a sequence of stages, each a function here or a module of its own:

1. **prepare**: usable bins (or samples) and their weights, a fixed-size stratified
   subsample for the solver, its device data (``brdffit.fitting.inputs``: a table's
   bins by ``brdffit.fitting.problem.prepare``, a sample list's own directions by
   ``brdffit.fitting.samples``);
2. **starts** (:func:`_start_candidates`): the caller's ``init``; or, for a fit of every
   bin, the **polish** stage: the default fit's optimum, which every bin then only
   polishes; or data-driven candidates (``brdffit.fitting.starts``), scored in one
   batched call and the best ``starts`` kept (:func:`_ranked_starts`);
3. **solve** (``brdffit.fitting.solve.Solve``): an optimistix least-squares solve from
   each start, one after the other in one compiled call; failures stay values
   (``throw=False``) and are reported, never raised;
4. **nested parent** (:func:`_parent_fit`, :func:`_from_the_parent`): a model that
   contains another is refitted from that one's optimum where its own starts did not do;
5. **assemble** (``brdffit.fitting.assemble``): the error metrics on **every** usable bin
   (or sample, with the held-out error), the uncertainty and the verdict;
6. **bound** (:func:`_bound_stage`, ``physical=True``): a bounded step over the free
   fit, solved by the same solve with the bound as an objective term
   (``brdffit.fitting.physical``), assembled by the same ``assemble``.

Stages 1-4 are :func:`solved_fit`, stage 5 :func:`finish`: ``auto`` solves its
candidates, then measures all of them in one pass over the table.

What differs between a table and a sample list is asked of the input
(``brdffit.fitting.inputs``), never tested here.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from brdffit import models, runtime
from brdffit.errors import FitInputError
from brdffit.fitting.assemble import PEAK_NOTE, assemble
from brdffit.fitting.inputs import check_enough, fit_input
from brdffit.fitting.options import (
    DEFAULT_LOSS,
    DEFAULT_MAX_STEPS,
    DEFAULT_MODEL,
    DEFAULT_PRECISION,
    DEFAULT_SEED,
    DEFAULT_SOLVER,
    DEFAULT_STARTS,
    FitOptions,
)
from brdffit.fitting.physical import bound
from brdffit.fitting.problem import (
    DTYPES,
    LIVE_U,
    constrained,
    plain_params,
    report_pool,
    score_starts,
    takes_steps_as_data,
)
from brdffit.fitting.quality import of_the_whole_sphere
from brdffit.fitting.result import FitResult
from brdffit.fitting.sampling import DEFAULT_SAMPLES
from brdffit.fitting.scene import WHOLE_SPHERE_WORDS, Scene, as_scene, full_table_error
from brdffit.fitting.solve import SCOUT_STEPS, Outcome, Solve
from brdffit.fitting.solver import loss_floor
from brdffit.fitting.starts import candidates as start_vectors
from brdffit.fitting.uncertainty import parameter_uncertainty
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
    scene: Scene | dict | str | None = None,
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
            programs compile and its starts are scored meanwhile), or of its
            :class:`Solved` solution (``auto``'s, before it is measured); where it
            raises ``FitInputError``, the parent is fitted here.
        physical: constrain the fit to conserve energy (directional albedo <= 1)
            and to reflectances <= 1; ``FitResult.physical`` reports what that cost
            (``brdffit.fitting.physical``).
        scene: weight the fit towards the directions a scene uses
            (:func:`fit_in_scene`): a ``Scene``, its JSON form (a
            dict), a preset's name (``brdffit.fitting.scene.PRESETS``) or a scene
            file's path. The result's ``error`` is then on the scene's bins, its
            ``full_table_error`` on every bin. Not with ``bin_weight``.
    """
    if scene is not None:
        return _fit_in_scene(table, model, scene, bin_weight, loss=loss, solver=solver,
                             samples=samples, precision=precision, starts=starts,
                             max_steps=max_steps, seed=seed, init=init,
                             parent_fit=parent_fit, physical=physical)
    if isinstance(model, str) and model.strip().lower() == "auto":
        # the shells' "auto" is a selection, not a model: said where to find it
        raise FitInputError("auto chooses among candidates, it is no model: "
                            "brdffit.selection.select(table) returns the ranking and the "
                            "chosen fit (.chosen_fit); brdffit.request.run(table, "
                            "FitRequest.of('auto')) as the shells run it")
    m = models.get(model)
    if not (parent_fit is None or callable(parent_fit)
            or isinstance(parent_fit, FitResult | Solved)):
        raise FitInputError(f"parent_fit must be the FitResult of {m.parent or 'the model'} "
                            f"{m.name} contains, got {type(parent_fit).__name__}")
    if isinstance(parent_fit, FitResult):
        _check_parent_fit(m, parent_fit, table)
    samples, starts, max_steps, seed = _check_options(loss, solver, precision, samples,
                                                      starts, max_steps, physical, seed)
    if physical:
        fit_input(table).refuse_bound()
        return _bound_stage(table, m, parent_fit, loss=loss, solver=solver, samples=samples,
                            precision=precision, starts=starts, max_steps=max_steps,
                            seed=seed, init=init, bin_weight=_checked_bin_weight(bin_weight))
    return finish(solved_fit(table, m, loss=loss, solver=solver, samples=samples,
                             precision=precision, starts=starts, max_steps=max_steps,
                             seed=seed, init=init, bin_weight=bin_weight,
                             parent_fit=parent_fit))


def _fit_in_scene(table, model, scene, bin_weight, **fit_options) -> FitResult:
    if bin_weight is not None:
        raise FitInputError("give a scene or a bin_weight, not both: a scene's weights are "
                            "its own (Scene.bin_weight())")
    return fit_in_scene(table, model, as_scene(scene), **fit_options)


@runtime.in_float64
def fit_in_scene(table, model, scene: Scene | None, **fit_options) -> FitResult:
    """``fit`` with the scene's bin weights; the full-table error goes beside the scene's.

    The result's ``error`` is on the scene (the loss and the reported error use the
    same weights); ``scene`` describes the scene and ``full_table_error`` holds the
    same metrics on the whole table (or every sample of a list), so the trade is
    visible. Without a scene this is plain :func:`fit`.
    """
    if scene is None:
        return fit(table, model, **fit_options)
    result = fit(table, model, bin_weight=scene.bin_weight(), **fit_options)
    look = result.quality
    if of_the_whole_sphere(look):
        # the verdict renders every direction (one figure across losses and scenes);
        # "visible" on a scene fit read as if of the scene's directions
        look = {**look, "reason": f"{look['reason']}; {WHOLE_SPHERE_WORDS}"}
    if isinstance(table, MerlTable):
        whole = full_table_error(table, model, result.params)
    else:  # a sample list: every sample, without the scene's weights
        from brdffit.fitting.samples import sample_error

        whole = sample_error(table, model, result.params)
    return dataclasses.replace(result, scene=scene.to_dict(), full_table_error=whole,
                               quality=look)


class Solved(NamedTuple):
    """A fit solved and not yet measured (:func:`solved_fit`): what :func:`finish`
    needs to make it a ``FitResult``. ``auto`` solves its candidates first and
    measures all of them in one pass over the table
    (``brdffit.fitting.problem.full_table_metrics_of``).

    It answers, for its best solution, what a nested model asks of its parent's fit
    (``model``, ``loss``, ``params``, ``samples["used"]``), so that a candidate that
    contains another can start from that one's solution before it is measured."""

    m: models.AbstractBRDFModel
    source: object  # brdffit.fitting.inputs.TableInput | SampleInput
    prep: object  # brdffit.fitting.problem.Prepared
    solve: Solve
    outcome: Outcome
    notes: tuple[str, ...]
    parent: np.ndarray | None  # the parent's optimum, embedded (unconstrained)
    parent_result: object  # the parent's fit (a FitResult, or a Solved in auto)
    n_solved: int
    loss: str
    solver: str
    precision: str
    seed: int
    t0: float  # when the fit began (time.perf_counter)
    solved_at: float  # when its solve ended

    def best(self):
        return self.outcome.best(self.solve.loss_rtol)

    @property
    def model(self) -> str:
        return self.m.name

    @property
    def params(self) -> dict:
        return plain_params(constrained(self.m, np.asarray(self.best().u)))

    @property
    def samples(self) -> dict:
        return {"used": self.prep.sample_set.n_used}

    def final_as_is(self) -> bool:
        """:func:`finish` gives this solution (the measured error decides nothing
        more): it converged, and no parent's fit can be better on the table."""
        return self.parent_result is None and self.best().result == "successful"


@runtime.in_float64
def solved_fit(
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
    parent_fit: FitResult | Solved | Callable[[], FitResult | Solved] | None = None,
    full_table_ahead: bool = True,
) -> Solved:
    """:func:`fit`'s stages up to the solve (prepare, starts, solve, nested parent),
    for a fit without the physical bounds; :func:`finish` measures and assembles it.
    ``full_table_ahead=False``: in a new process, the full-table error's program of
    this one model is not made ready ahead (``auto`` measures its candidates in one
    pass of its own)."""
    t0 = time.perf_counter()
    m = models.get(model)
    samples, starts, max_steps, seed = _check_options(loss, solver, precision, samples,
                                                      starts, max_steps, False, seed)
    source = fit_input(table)
    bin_weight = _checked_bin_weight(bin_weight)
    source.refuse_too_few(m)  # a sample list's count, before its costly preparation
    prep = source.prepare(bin_weight, samples, seed, precision, loss)
    check_enough(source, prep, m, scene=bin_weight is not None)
    again = dict(loss=loss, solver=solver, precision=precision, starts=starts,
                 max_steps=max_steps, seed=seed, bin_weight=bin_weight)
    polish = source.polishes(samples, init, prep)
    u_candidates, coarse = _start_candidates(source, m, prep, init, polish, again)
    parent = parent_result = None
    if init is None and not polish and m.parent is not None and m.parent_scan:
        parent, parent_result = _parent_fit(source, table, m, parent_fit, prep, polish,
                                            samples, again)
        u_candidates = np.concatenate([u_candidates, _over_the_parent(m, parent, m.parent_scan)])
    notes = []
    if init is None and not polish and starts < m.least_starts:
        notes.append(f"{m.least_starts} starts refined ({starts} asked): {m.name}'s loss is "
                     "many-moded in what it adds, and fewer starts end in the wrong mode")
        starts = m.least_starts
    n_starts = min(starts, len(u_candidates))
    notes += _start_notes(m, starts, len(u_candidates), init, coarse, prep)
    ready_here = source.ready_report(m, u_candidates[0], prep, loss, precision, solver,
                                     full_table=full_table_ahead)
    # the solve's program holds as many starts as the ranking may refine, so that the
    # program compiled ahead is the one the solve runs
    bucket = _most_refined(m, len(u_candidates), n_starts)
    if ready_here is not None and takes_steps_as_data(solver, max_steps):
        # the solve's program depends on the number of starts, not on which: in a new
        # process it compiles here, beside the scoring below
        ahead = Solve(m, solver, precision, prep.data, max_steps, bucket=bucket)
        report_pool().submit(runtime.in_float64(ahead.ready), u_candidates[:n_starts])
    best_starts = _ranked_starts(m, u_candidates, n_starts, prep, precision,
                                 n_scan=0 if parent is None else len(m.parent_scan))
    if len(best_starts) > n_starts and m.start_family is not None:
        values = ", ".join(f"{v:g}" for v in dict.fromkeys(s[m.start_family]
                                                          for s in m.shape_grid))
        notes.append(f"{len(best_starts)} starts refined ({starts} asked): the best-scored, "
                     f"and the best of each {m.start_family} ({values}): a metal and a "
                     "dielectric explain a highlight differently, each in a basin of its own")
    if ready_here is not None:
        ready_here()
    if parent is None and init is None and m.parent is not None:
        parent, parent_result = _parent_fit(source, table, m, parent_fit, prep, polish,
                                            samples, again)

    solve = Solve(m, solver, precision, prep.data, max_steps,
                  bucket=max(bucket, len(best_starts)))
    parent_loss = None if parent is None else solve.loss_at(parent)
    if parent is not None and parent_loss <= exact_fit_loss(prep):
        # The parent fits these data exactly: nothing is left for what this model adds
        # (a second lobe, a layer), whose own starts would only spend steps (dozens, on
        # ggx2's collapsing lobe) finding the parent again.
        outcome = solve(parent[None])
        notes.append(f"nested: no gain: {m.parent} fits these data exactly (its loss is at "
                     f"the exact-fit floor); this is {m.parent}'s optimum with what "
                     f"{m.name} adds switched off, its own starts not solved")
    elif parent is not None and not polish and _no_descent_off(m, solve, parent, parent_loss):
        # Where no value just off the bound lowers the loss, the parent's optimum is
        # a stationary point of this loss too; the own starts (oren_nayar's sigma 0.05
        # to 1) would only run down to it (a warm oren_nayar fit 59 -> 47 ms without
        # them, median over 15 MERL materials)
        outcome = solve(parent[None])
        probes = "; ".join(", ".join(f"{k} {v:g}" for k, v in p.items())
                           for p in m.first_order_probes)
        notes.append(f"nested: no gain: no value of what {m.name} adds just off "
                     f"{m.parent}'s optimum ({probes}) lowers the loss, so that optimum is "
                     f"a stationary point of {m.name}'s loss too; this is {m.parent}'s "
                     f"optimum with what {m.name} adds switched off, its own starts not "
                     "solved")
    else:
        outcome = solve.best_of(best_starts,
                                np.inf if parent_loss is None else parent_loss)
        if parent is not None:
            outcome = _from_the_parent(m, solve, outcome, parent, parent_loss, polish, notes)
    n_solved = len(outcome.starts) if coarse is None else coarse.starts
    return Solved(m, source, prep, solve, outcome, tuple(notes), parent, parent_result,
                  n_solved, loss, solver, precision, seed, t0, time.perf_counter())


@runtime.in_float64
def finish(solved: Solved, table_metrics: dict | None = None, *, parent_result=None,
           shared_s: float | None = None) -> FitResult:
    """The ``FitResult`` of a :func:`solved_fit`: measured on the full table (or given
    ``table_metrics``, its full-table error measured beside other fits') and
    assembled; a nested fit worse on the table than its parent is the parent's
    optimum, refined (and where that refinement leaves the parent's optimum again, as
    far off on the table, the note says so). ``parent_result``: the parent's fit, where
    the solve started from a :class:`Solved` parent. ``shared_s``: the fit's share of a
    pass measured beside others; its ``time_s`` then counts that share, not the wait for
    the others."""
    s = solved
    t0 = s.t0 if shared_s is None else s.t0 + (time.perf_counter() - s.solved_at) - shared_s
    parent_result = s.parent_result if parent_result is None else parent_result
    result = _assembled(s, s.best(), s.notes, s.n_solved, t0, table_metrics)
    if parent_result is not None and _worse_than_the_parent(result, parent_result):
        # Better than the parent on the solver's samples, worse on the rest of the table:
        # what the model adds fitted the samples' noise (a thin film of 30 nm on
        # color-changing-paint2: log_rmse 0.0415 against 0.0420 on the samples, 0.0444
        # against 0.0421 on every bin). The parent's optimum, embedded, is the answer.
        back = s.solve(s.parent[None])
        worse = (f"{s.m.name}'s optimum on the samples was worse than {s.m.parent}'s on the "
                 f"table (log_rmse {result.error['log_rmse']:.4g} against "
                 f"{parent_result.error['log_rmse']:.4g})")
        best = back.best(s.solve.loss_rtol)
        result = _assembled(s, best, [
            *s.notes, f"{worse}: this is {s.m.parent}'s optimum with what {s.m.name} adds "
            "switched off, refined"], s.n_solved + 1, t0)
        if (_worse_than_the_parent(result, parent_result)
                and best.loss < (1.0 - LEFT_THE_PARENT) * s.solve.loss_at(s.parent)):
            # Refined, it left the parent's optimum for one its loss prefers, as worse on
            # the table as before (color-changing-paint3's ggx2 under the render loss: a
            # near-mirror spike, blown out in every picture, that renders 1.2 dB closer
            # and doubles log_rmse): the note may not call that the parent's optimum.
            went_back = (
                f"{worse}; refined again from {s.m.parent}'s optimum with what {s.m.name} "
                f"adds switched off, it came back to log_rmse {result.error['log_rmse']:.4g}: "
                f"on the solver's samples the {s.loss} loss prefers it (sphere PSNR "
                f"{_psnr(result)} against {s.m.parent}'s {_psnr(parent_result)}), the table "
                "does not")
            result = dataclasses.replace(result, notes=tuple(
                went_back if n.startswith(worse) else n for n in result.notes))
    return result


#: A refinement from the parent's optimum that lowers the loss by more than this
#: (relative) has left it: what the model adds is switched on again.
LEFT_THE_PARENT = 1e-2


def _psnr(result: FitResult) -> str:
    value = result.error.get("psnr_db")
    return "not measured" if value is None else f"{value:.1f} dB"


def _assembled(s: Solved, best, notes, n_solved: int, t0: float,
               table_metrics: dict | None = None) -> FitResult:
    # The uncertainty needs the solution alone: it runs on another thread while this
    # one measures the full table and the sphere. Warm, that overlaps a few ms; in a
    # new process each of them compiles its programs first, and side by side they
    # compile at the same time (bench/results/startup.md).
    m, prep = s.m, s.prep
    pending = None
    if best.result != "nonfinite":
        pending = report_pool().submit(runtime.in_float64(parameter_uncertainty), m,
                                       best.u, prep.data, best.terms)

    def refit(fold_data):  # one start from the optimum, in this fit's solve
        out = s.solve(np.asarray(best.u, np.float64)[None], on=fold_data,
                      max_steps=FOLD_STEPS)
        return out.values[0], out.codes[0]

    return assemble(s.source, m, best.u, plain_params(constrained(m, np.asarray(best.u))),
                    prep, result=best.result, steps=best.steps, starts=n_solved,
                    sample_loss=best.loss, loss=s.loss, solver=s.solver,
                    precision=s.precision, t0=t0, uncertainty=pending, refit=refit,
                    seed=s.seed, notes=notes, table_metrics=table_metrics)


def _check_options(loss, solver, precision, samples, starts, max_steps, physical,
                   seed) -> tuple[int | None, int, int, int]:
    """Refuse, with the reason, options ``fit`` was called with directly, by
    ``FitOptions``: the one declaration of each option's values and range, what the
    command line and the service offer (10**12 samples was a MemoryError of 7.3 TiB
    here, and 64 starts a solve of 64). The counts as Python ints (numpy's integers are
    counts too: one read from an array)."""
    for name, value in (("loss", loss), ("solver", solver), ("precision", precision)):
        if not isinstance(value, str):  # a list of one was a TypeError (unhashable)
            raise FitInputError(f"{name} must be a name, got {value!r}")
    samples, starts, max_steps, seed = (int(x) if _integer(x) else x
                                        for x in (samples, starts, max_steps, seed))
    FitOptions(loss=loss, solver=solver, samples=samples, precision=precision, starts=starts,
               max_steps=max_steps, seed=seed, physical=physical)
    return samples, starts, max_steps, seed


def _integer(x) -> bool:
    """An integer, numpy's too (a count read from an array), but no bool."""
    return isinstance(x, int | np.integer) and not isinstance(x, bool | np.bool_)


def _checked_bin_weight(bin_weight) -> np.ndarray | None:
    if bin_weight is None:
        return None
    bin_weight = np.asarray(bin_weight, dtype=np.float64).ravel()
    if bin_weight.size != N_BINS or not np.all(np.isfinite(bin_weight)):
        raise FitInputError("bin_weight needs one finite value per MERL bin")
    if np.any(bin_weight < 0):
        raise FitInputError("bin_weight must be >= 0")
    # only its shape matters (it is normalised with the solid angles); one far from 1
    # (denormals: 5e-324 everywhere) underflowed there into a 'nonfinite' fit with a
    # log_rmse of 0, so it is scaled to a peak of 1 first
    top = float(bin_weight.max())
    if top > 0 and not 1e-100 <= top <= 1e100:
        bin_weight = bin_weight / top
    return bin_weight


# -- the stages ------------------------------------------------------------------------


def _bound_stage(table, m, parent_fit, *, bin_weight, **options) -> FitResult:
    """The physically bounded fit: a bounded step over the free fit
    (``brdffit.fitting.physical``); a nested fit seeds from its parent's
    *unconstrained* optimum."""
    parent_fit = _resolved(parent_fit)
    if parent_fit is not None and parent_fit.physical is not None:
        parent_fit = None
    free = fit(table, m, bin_weight=bin_weight, parent_fit=parent_fit, **options)
    del options["starts"], options["init"]
    return bound(table, free, model=m, bin_weight=bin_weight, **options)


def _start_candidates(source, m, prep, init, polish: bool, again: dict):
    """The starts to rank, and the subsample fit they came from where they did: the
    caller's ``init`` alone; for a polish (every bin), the default fit's optimum
    alone, and that fit; else the data-driven candidates (``brdffit.fitting.starts``)."""
    if init is not None:
        try:
            return m.unconstrain(m.check_params(init))[None], None
        except ValueError as e:  # the caller's start: their input, said as such
            raise FitInputError(f"init: {e}") from None
    if polish:
        coarse = fit(source.table, m, samples=DEFAULT_SAMPLES, **again)
        # A coordinate deep in its transform's flat tail (a scale at 1e-14) is pulled
        # back to the tail's edge (|u| <= 14, as every start is): the full table may
        # want it back, and from deep in the tail capped steps would only crawl. A
        # softplus has no upper tail: a scale of 2000 (a table in other units) is
        # where it is (clipped to 14, the polish ended 80x worse than its start).
        u = np.clip(m.unconstrain(m.check_params(coarse.params)), -14.0,
                    np.where(m.unbounded_above(), np.inf, 14.0))[None]
        return u, coarse
    return start_vectors(m, source.start_table(prep), prep.counts.usable, prep.hints), None


def _start_notes(m, starts: int, n_candidates: int, init, coarse, prep) -> list[str]:
    """What the result's ``starts`` means where it is not simply the starts asked."""
    if coarse is not None:
        # the coarse fit's figures are not this fit's: their notes are said again below
        return [*(n for n in coarse.notes if not n.startswith(PEAK_NOTE)),
                f"every bin ({prep.n_usable:,}) polished, from one start, the optimum of the "
                f"fit on {coarse.samples['used']:,} samples, which refined {coarse.starts} "
                "start(s): starts counts those"]
    if init is not None and starts > 1:
        return [f"init was the only start ({starts} starts asked)"]
    if starts > n_candidates:
        return [f"{starts} starts asked; {m.name} has {n_candidates} start "
                f"candidate{'' if n_candidates == 1 else 's'} on these data, and every one "
                "was refined"]
    return []


def exact_fit_loss(prep) -> float:
    """The loss at or below which a fit of ``prep``'s data is exact (the solver's own
    floor, ``brdffit.fitting.solver.loss_floor``)."""
    return float(loss_floor(prep.data.target, prep.data.weight))


def _ranked_starts(m, u_candidates: np.ndarray, n_starts: int, prep, precision: str,
                   n_scan: int = 0):
    """The ``n_starts`` best-scored candidates (and the best of each start family).
    Where the last ``n_scan`` are the scan over the parent's optimum, half the starts
    are the scan's best and half the model's own: the parent's base is already fitted,
    so its scan scores best, yet a layer can need another base (on a dark dielectric
    under a film, the base's fit is a coloured metal that mimics the film's hue, and
    every start over it ended there)."""
    if len(u_candidates) == 1:  # one candidate (init, a polish) has nothing to rank
        return u_candidates
    # Score candidates on every 8th sample: ranking starts needs no more.
    scores = np.asarray(score_starts(m, jnp.asarray(u_candidates, DTYPES[precision]),
                                     prep.data, 8))
    scores = np.where(np.isfinite(scores), scores, np.inf)
    if n_scan and n_starts > 1:
        own = len(scores) - n_scan
        k_scan = n_starts // 2
        chosen = [*np.argsort(scores[:own], kind="stable")[:n_starts - k_scan],
                  *(own + np.argsort(scores[own:], kind="stable")[:k_scan])]
        return u_candidates[np.asarray(chosen)]
    return u_candidates[_best_of_each_family(m, scores, n_starts)]


#: Step limit of a held-out fold's refit (a sample list's), from the fit's optimum: a
#: fold that converges does so in a few steps from there (ggx's on 2,000 Cornell
#: samples: all five); one still going after this many is in the flat valley its fit
#: crawled along (ggx2's two lobes merged on a single-lobe list: each of the five folds
#: took all 256 steps, its held-out log_rmse 0.3028e-2 against ggx's 0.3024e-2), and says
#: so in its fold's result.
FOLD_STEPS = 64


#: A nested model's log_rmse on the table above this multiple of its parent's is worse
#: than the parent (the promise: never more than 0.1% worse).
NEVER_WORSE = 1.001


def _worse_than_the_parent(result: FitResult, parent: FitResult) -> bool:
    """By log_rmse under every loss, the render loss's too, which does not minimise it:
    the table-wide figure keeps a nested fit from bending to what its loss sees. Judged
    by the loss's own figure instead (the sphere's PSNR under the render loss), auto
    with layers changed 5 of the 100 MERL choices under the render loss, 4 of them
    1.0-2.6 dB worse in bench.render_loss's independent render (alum-bronze's
    gltf_clearcoat kept at its own optimum: -1.9 dB), its poor count unchanged."""
    mine, theirs = result.error.get("log_rmse"), parent.error.get("log_rmse")
    return mine is not None and theirs is not None and mine > NEVER_WORSE * theirs


def _check_parent_fit(m, parent_fit: FitResult, table) -> None:
    """Refuse a given parent fit that is not ``m``'s parent's, or is of another input
    (by its name and measured count): one of another table was embedded as the start
    (ggx2's alpha1 0.156 where its own fit finds 0.029), and one of another model was
    dropped without a word."""
    if m.parent is None:
        raise FitInputError(f"parent_fit is for a model that contains another (ggx2 contains "
                            f"ggx); {m.name} contains none")
    if parent_fit.model != m.parent:
        raise FitInputError(f"parent_fit is a {parent_fit.model} fit; {m.name} contains "
                            f"{m.parent}: give {m.parent}'s fit of this table, or none")
    source = getattr(table, "source", None)
    measured = int(np.count_nonzero(table.mask)) if isinstance(table, MerlTable) else None
    theirs = (parent_fit.samples or {}).get("measured")
    if ((source is not None and parent_fit.table is not None and parent_fit.table != source)
            or (measured is not None and theirs is not None and theirs != measured)):
        raise FitInputError(f"parent_fit is a fit of {parent_fit.table} ({theirs} measured), "
                            f"not of {source} ({measured} measured): give {m.parent}'s fit of "
                            "this table, or none")


def _parent_fit(source, table, m, parent_fit, prep, polish: bool, samples, again: dict):
    """The fit of the model ``m`` contains (``m.parent``), with the same settings: the
    one given where it is that, else fitted here; its optimum embedded in ``m``, and
    the fit itself."""
    parent_fit = _resolved(parent_fit)
    on_every_bin = parent_fit is not None and parent_fit.samples["used"] == prep.n_usable
    if (parent_fit is None or parent_fit.model != m.parent or parent_fit.loss != again["loss"]
            or (polish and not on_every_bin)):
        parent_fit = fit(table, m.parent, samples=samples, **again)
    return m.unconstrain(m.check_params(m.embed_parent(parent_fit.params))), parent_fit


def _over_the_parent(m, parent: np.ndarray, values: tuple[dict, ...]) -> np.ndarray:
    """The parent's optimum (``parent``, embedded) with each of ``values`` of what the
    parent lacks, unconstrained: ``m.parent_scan``'s start candidates (a thin film's
    thickness and index), to be scored with the rest, or ``m.first_order_probes``."""
    embedded = plain_params(constrained(m, parent))
    return np.stack([m.unconstrain(m.check_params({**embedded, **layer}))
                     for layer in values])


def _no_descent_off(m, solve: Solve, parent: np.ndarray, parent_loss: float) -> bool:
    """Whether none of ``m.first_order_probes``, each over the parent's optimum
    (``parent``, embedded), lowers the loss below ``parent_loss``: the first-order
    test at the bound (False where the model declares no probes)."""
    if not m.first_order_probes:
        return False
    return all(solve.loss_at(u) >= parent_loss
               for u in _over_the_parent(m, parent, m.first_order_probes))


def _from_the_parent(m, solve: Solve, outcome: Outcome, parent_start: np.ndarray,
                     parent_loss: float, polish: bool, notes: list[str]) -> Outcome:
    """A model that contains its parent starts from the parent's optimum too, but
    only where its own starts did not do: they ended without converging, or above
    the parent's loss. Where they converged below it (most tables), a second solve
    from the parent cost 30-100 more steps and found the same optimum
    (bench/results/real_materials.md; issue 15).

    The embedding puts what the parent lacks at its bound (ggx2's ks2 = 0, deep in
    the softplus tail): a saddle, from which LM crawls for dozens of steps. The first
    retry starts from that point pulled back to where every coordinate moves (|u| <=
    LIVE_U); the exact embedding comes last, so the fit never ends worse than the
    parent on its samples. Each retry is named in ``notes`` (the result's ``starts``
    counts them). Where the own starts converged above the parent's loss, the first
    retry is scouted as they are (:meth:`Solve.best_of`): still above the parent's
    loss after its first steps, it goes no further (on a diffuse table ggx2's crawled
    256 steps, 0.66 s, to end 1e-8 above ggx's loss). Where they did not converge, it
    takes every step: on pink-fabric2 and polyurethane-foam such a retry, above ggx's
    loss after 32 steps, went on to a second lobe 0.3-0.5% better. Where that retry did
    not converge either, the own starts the scout stopped go on from where they stopped
    (:meth:`Solve.resume`): there ggx2's one start, cut at 32 steps, converged at 113 and
    148 steps to 0.24% and 0.002% below the retry's end at its step limit
    (bench/results/real_materials.md).

    Own starts that converged to the parent's loss within the solver's own tolerance
    found the parent's optimum (oren_nayar's sigma run down to 0 on a table no
    roughness explains, ends 1e-8 above lambert's loss): the first retry would find it
    again (7-30 steps), so only the exact embedding is refined."""
    above = outcome.lowest_loss() > parent_loss * (1.0 + solve.loss_rtol)
    if not polish and (not outcome.converged or above):
        why = "did not converge" if not outcome.converged else f"ended above {m.parent}'s loss"
        retry = np.clip(parent_start, -LIVE_U, LIVE_U)[None]
        outcome = outcome.plus(solve.best_of(retry, parent_loss) if outcome.converged
                               else solve(retry))
        notes.append(f"its own start(s) {why}: refined from {m.parent}'s optimum too")
        if not outcome.converged:
            # the own starts the scout stopped above the parent's loss go on: on
            # polyurethane-foam and pink-fabric2 ggx2's one start converged at 113 and
            # 148 steps, 0.24% and 0.002% below where the retry crawled to its step limit
            before = outcome
            outcome = solve.resume(outcome)
            if outcome is not before:
                notes.append(f"neither converged: its own start(s), stopped after "
                             f"{SCOUT_STEPS} steps above {m.parent}'s loss, went on")
    if outcome.lowest_loss() > parent_loss:
        outcome = outcome.plus(solve(parent_start[None]))
        notes.append(f"{m.parent}'s optimum itself was refined last, so that the fit ends no "
                     f"worse than {m.parent} on its samples")
    return outcome


def _most_refined(m, n_candidates: int, n_starts: int) -> int:
    """The most starts :func:`_ranked_starts` refines of ``n_candidates``: ``n_starts``,
    and where the model names a ``start_family``, the best of each other value of it
    too. (The solve compiled ahead of the ranking once held ``n_starts``: for
    standard_surface and its layers, whose ranking adds each metalness's best, every
    new process compiled a second solve of 5-10 s that nothing ran.)"""
    family = m.start_family
    if family is None or len(m.shape_grid) != n_candidates:
        return n_starts
    values = len(dict.fromkeys(shape[family] for shape in m.shape_grid))
    return min(n_candidates, n_starts + values - 1)


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
