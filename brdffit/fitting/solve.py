"""One fit's solve: :class:`Solve`, from any number of starts, in one compiled program.

Every solve a fit makes goes through here: its best starts, a nested model's
retries from its parent's optimum, the parent's own loss at that point, a sample
list's held-out refits (other data of the same shape), and the physically bounded
solve (the same program with the bound's barrier as an objective term,
``brdffit.fitting.physical.AlbedoBarrier``). The compiled solve itself is
``brdffit.fitting.problem.solve_batch``; this module keeps one fit's calls to it on
one program: with the lm solver the starts are padded to the first call's bucket
(:func:`~brdffit.fitting.problem.start_bucket`; the padding takes no step), so a new
process compiles one solve per fit where a retry of one start compiled a second.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from brdffit.fitting.problem import (
    DTYPES,
    LOSS_RTOL,
    score_starts,
    solve_batch,
    start_bucket,
    takes_steps_as_data,
)
from brdffit.fitting.result import STATUS_NAMES

#: Steps every start of a many-start solve takes before the others are compared with
#: it (:meth:`Solve.best_of`). A start that converges takes 5-30 (ggx 18, ggx2 20, the
#: thin film's 7-14: bench/results/selection.md, the film's fits); one still going
#: after this many is crawling.
SCOUT_STEPS = 32
_OUT_OF_STEPS = STATUS_NAMES.index("nonlinear_max_steps_reached")
_SUCCESSFUL = STATUS_NAMES.index("successful")


class Outcome(NamedTuple):
    """What a solve from each of ``starts`` gave: per start its solution ``values``,
    status ``codes`` (``STATUS_NAMES``), ``steps`` and ``losses``, and the sandwich
    covariance's ``bread`` and ``meat`` where the solver carries them (else None)."""

    starts: np.ndarray
    values: np.ndarray
    codes: np.ndarray
    steps: np.ndarray
    losses: np.ndarray
    bread: np.ndarray | None
    meat: np.ndarray | None

    def plus(self, other: Outcome) -> Outcome:
        """Both outcomes' starts, this one's first."""
        return Outcome(*(None if a is None else np.concatenate([a, b])
                         for a, b in zip(self, other, strict=True)))

    @property
    def converged(self) -> bool:
        return bool(np.any(self.codes == _SUCCESSFUL))

    def lowest_loss(self) -> float:
        return float(np.min(np.where(np.isfinite(self.losses), self.losses, np.inf)))

    def best(self, loss_rtol: float = 0.0) -> Best:
        """The start whose solution is finite with the lowest loss; where every start
        diverged, the first start itself, as ``"nonfinite"``.

        Among the starts within ``loss_rtol`` (relative) of the lowest loss, one whose
        optimality test held is preferred: to the solver they are one optimum
        (:data:`~brdffit.fitting.problem.LOSS_RTOL`), and only that one may be reported
        converged. (On black-soft-plastic, ggx2's retry from ggx's optimum converged,
        and ggx's optimum itself, refined last, stalled on its saddle 1e-12 lower: the
        stalled one was taken, and auto refitted ggx2 with 4 starts for 3 s.)"""
        values = self.values.astype(np.float64)
        losses = self.losses.astype(np.float64)
        finite = np.all(np.isfinite(values), axis=1) & np.isfinite(losses)
        if not finite.any():
            return Best(0, np.asarray(self.starts[0], np.float64), "nonfinite",
                        int(self.steps[0]), float("nan"), None)
        ranked = np.where(finite, losses, np.inf)
        i = int(np.argmin(ranked))
        optimal = self.codes == _SUCCESSFUL
        if not optimal[i]:
            near = optimal & (ranked <= ranked[i] + loss_rtol * abs(ranked[i]))
            if near.any():
                i = int(np.argmin(np.where(near, ranked, np.inf)))
        terms = None if self.bread is None else (self.bread[i], self.meat[i])
        return Best(i, values[i], STATUS_NAMES[int(self.codes[i])], int(self.steps[i]),
                    float(losses[i]), terms)


class Best(NamedTuple):
    """The chosen start's solution (unconstrained ``u``), its status name, steps and
    loss, and its uncertainty terms (bread, meat) where the solve carried them."""

    index: int
    u: np.ndarray
    result: str
    steps: int
    loss: float
    terms: tuple | None


class Solve:
    """The solve of one fit: ``model`` by ``solver`` at ``precision`` on ``data``,
    at most ``max_steps`` per start; ``term``: an objective term (``problem.ObjectiveTerm``)
    added to the data's sum of squares, or None. ``bucket``: the starts its first
    program holds (later calls with fewer starts run in it)."""

    def __init__(self, model, solver: str, precision: str, data, max_steps: int,
                 bucket: int = 1, term=None):
        self.model, self.solver, self.data, self.term = model, solver, data, term
        self.dtype = DTYPES[precision]
        #: losses closer than this (relative) are one optimum to the solver
        self.loss_rtol = LOSS_RTOL[precision]
        self.max_steps = max_steps
        self.steps_as_data = takes_steps_as_data(solver, max_steps)
        self.bucket = start_bucket(bucket)

    def __call__(self, starts: np.ndarray, *, take_steps: bool = True, on=None,
                 max_steps: int | None = None) -> Outcome:
        """Solve from each of ``starts`` (unconstrained, (k, p)); without ``take_steps``
        (the lm solver only), the losses of the starts themselves. ``on``: other data of
        the same shape (a sample list's held-out folds reweight it: the same program).
        ``max_steps``: a lower step limit for this call (where the limit is data)."""
        data = self.data if on is None else on
        limit = self.max_steps if max_steps is None else min(max_steps, self.max_steps)
        k = len(starts)
        term = {} if self.term is None else {"term": self.term}
        if not self.steps_as_data:
            *out, terms = solve_batch(self.model, self.solver, jnp.asarray(starts, self.dtype),
                                      data, self.max_steps, **term)
        else:
            padded = padded_starts(starts, max(self.bucket, start_bucket(k)))
            *out, terms = solve_batch(self.model, self.solver, jnp.asarray(padded, self.dtype),
                                      data, jnp.asarray(limit),
                                      n_live=jnp.asarray(k if take_steps else 0), **term)
        bread, meat = (None, None) if terms is None else terms
        values, codes, steps, losses, bread, meat = (
            None if a is None else np.asarray(a)[:k] for a in (*out, bread, meat))
        return Outcome(np.asarray(starts), values, codes, steps, losses, bread, meat)

    def best_of(self, starts: np.ndarray, known: float = np.inf) -> Outcome:
        """Solve from each of ``starts``, as :meth:`__call__`, but with the crawlers cut
        short: every start takes at most :data:`SCOUT_STEPS` steps first, and only the
        starts still going whose loss is already below the lowest loss of those that
        ended go on to ``max_steps``. The starts run one after another, so a start that
        crawls costs its own steps: one of the thin film's four starts took 97 steps to
        end stalled above the others' optimum, 5 s of a 6.4 s fit (the others took
        7-14). Each step lowers the loss, so a start is dropped only where it would have
        had to pass below where it is through the others' optimum to win. A start that
        goes on resumes from where it stopped (the solver's damping starts afresh).

        ``known``: the loss of an optimum the fit has already (a nested model's parent's,
        embedded), which a start still going must be below as well; with it, one start
        is scouted too. ggx2's one start on black-soft-plastic crawled 256 steps (0.65 s)
        along its two merged lobes, to end above ggx's loss."""
        alone = len(starts) == 1 and not np.isfinite(known)
        if alone or not self.steps_as_data or self.max_steps <= SCOUT_STEPS:
            return self(starts)
        first = self(starts, max_steps=SCOUT_STEPS)
        losses = np.where(np.isfinite(first.losses), first.losses, np.inf)
        going = first.codes == _OUT_OF_STEPS
        ended = ~going & np.isfinite(first.losses)
        bar = min(losses[ended].min() if ended.any() else np.inf, known)
        return self._go_on(first, going & (losses < bar))

    def resume(self, outcome: Outcome) -> Outcome:
        """``outcome`` with the starts :meth:`best_of` cut short (out of steps before
        ``max_steps``) taken on to ``max_steps`` from where they stopped: where nothing
        else converged, the scout's bet that they would only crawl lost."""
        if not self.steps_as_data:
            return outcome
        return self._go_on(outcome, (outcome.codes == _OUT_OF_STEPS)
                           & (outcome.steps < self.max_steps))

    def _go_on(self, outcome: Outcome, on: np.ndarray) -> Outcome:
        """``outcome`` with its starts ``on`` (each stopped after the same number of
        steps) solved on for the rest of ``max_steps``."""
        if not on.any():
            return outcome
        more = self(outcome.values[on], max_steps=self.max_steps - int(outcome.steps[on][0]))
        merged = outcome._asdict()
        for name in ("values", "codes", "losses", "bread", "meat"):
            if merged[name] is not None:
                merged[name] = merged[name].copy()
                merged[name][on] = getattr(more, name)
        merged["steps"] = outcome.steps.copy()
        merged["steps"][on] += more.steps
        return Outcome(**merged)

    def ready(self, starts: np.ndarray) -> None:
        """Compile (or load) the program :meth:`__call__` runs for ``starts``, without
        running it: a new process compiles it beside other work (the lm solver only,
        whose program depends on the number of starts, not on which)."""
        try:
            padded = padded_starts(starts, max(self.bucket, start_bucket(len(starts))))
            solve_batch.ready(self.model, self.solver, jnp.asarray(padded, self.dtype),
                              self.data, jnp.asarray(self.max_steps),
                              n_live=jnp.asarray(len(starts)),
                              **({} if self.term is None else {"term": self.term}))
        except Exception as e:  # noqa: BLE001 - speed only: the solve itself will say
            from brdffit import runtime

            runtime.log.debug("brdffit: solve of %s not made ready ahead (%s)",
                              self.model.name, e)

    def loss_at(self, u: np.ndarray) -> float:
        """The objective at ``u`` itself (no step): from the solve's own normal
        equations where it can take no steps, else the scoring program's."""
        if self.steps_as_data:
            return float(self(u[None], take_steps=False).losses[0])
        return float(score_starts(self.model, jnp.asarray(u[None], self.dtype), self.data)[0])


def padded_starts(starts: np.ndarray, size: int | None = None) -> np.ndarray:
    """``starts`` padded to ``size`` starts, by default their
    :func:`~brdffit.fitting.problem.start_bucket` (one compiled solve per bucket; the
    padding takes no step)."""
    k = len(starts)
    size = start_bucket(k) if size is None else size
    return np.concatenate([starts, np.repeat(starts[:1], size - k, 0)])
