"""One fit's solve (brdffit.fitting.solve): which start's solution a fit takes, and
which starts a many-start solve cuts short, on outcomes made up here (what the solver
returns is tested in test_solvers.py)."""

from __future__ import annotations

import numpy as np
import pytest

from brdffit.fitting.result import STATUS_NAMES
from brdffit.fitting.solve import SCOUT_STEPS, Outcome, Solve

pytestmark = pytest.mark.unit

OPTIMAL = STATUS_NAMES.index("successful")
OUT_OF_STEPS = STATUS_NAMES.index("nonlinear_max_steps_reached")
STALLED = STATUS_NAMES.index("stalled")


def _outcome(losses, codes, steps=None) -> Outcome:
    k = len(losses)
    values = np.arange(2.0 * k).reshape(k, 2)
    return Outcome(values - 1.0, values, np.asarray(codes), np.asarray(steps or [5] * k),
                   np.asarray(losses, np.float64), None, None)


def test_the_lowest_loss_wins_and_an_optimal_start_within_the_tolerance_is_preferred():
    # a stalled start 1e-12 below an optimal one: one optimum to a solver of rtol 1e-8
    tie = _outcome([2.0, 2.0 - 2e-12], [OPTIMAL, STALLED])
    assert tie.best().index == 1 and tie.best().result == "stalled"
    assert tie.best(1e-8).index == 0 and tie.best(1e-8).result == "successful"
    # further below than the tolerance: the lower loss wins, unconverged as it is
    lower = _outcome([2.0, 1.9], [OPTIMAL, OUT_OF_STEPS])
    assert lower.best(1e-8).index == 1 and lower.best(1e-8).result == "nonlinear_max_steps_reached"
    # among several optimal ones within the tolerance, the lowest
    many = _outcome([2.0 + 1e-9, 2.0, 2.0 - 1e-9], [OPTIMAL, OPTIMAL, STALLED])
    assert many.best(1e-8).index == 1
    # nothing finite: the first start, as nonfinite
    lost = _outcome([np.nan, np.inf], [OPTIMAL, OPTIMAL])
    assert lost.best(1e-8).result == "nonfinite" and lost.best(1e-8).index == 0


class _Scripted(Solve):
    """A solve whose calls return scripted outcomes, recording each call's step limit."""

    def __init__(self, *outcomes: Outcome, max_steps: int = 256):
        self.steps_as_data, self.max_steps, self.loss_rtol = True, max_steps, 1e-8
        self.script, self.limits = list(outcomes), []

    def __call__(self, starts, *, take_steps=True, on=None, max_steps=None):
        self.limits.append(max_steps)
        out = self.script.pop(0)
        return out._replace(starts=np.asarray(starts))


def test_one_start_above_a_known_optimum_after_scouting_goes_no_further():
    crawling = _outcome([0.6], [OUT_OF_STEPS], [SCOUT_STEPS])
    solve = _Scripted(crawling)
    out = solve.best_of(np.zeros((1, 2)), known=0.5)
    assert solve.limits == [SCOUT_STEPS] and out.codes.tolist() == [OUT_OF_STEPS]
    # below the known optimum it goes on, from where it stopped, to the step limit
    solve = _Scripted(_outcome([0.4], [OUT_OF_STEPS], [SCOUT_STEPS]),
                      _outcome([0.3], [OPTIMAL], [20]))
    out = solve.best_of(np.zeros((1, 2)), known=0.5)
    assert solve.limits == [SCOUT_STEPS, 256 - SCOUT_STEPS]
    assert out.codes.tolist() == [OPTIMAL] and out.steps.tolist() == [SCOUT_STEPS + 20]
    assert out.losses.tolist() == [0.3]
    # with nothing known, one start is one call to the full limit
    solve = _Scripted(_outcome([0.6], [OPTIMAL], [40]))
    solve.best_of(np.zeros((1, 2)))
    assert solve.limits == [None]


def test_of_many_starts_only_those_still_going_below_every_ended_one_go_on():
    first = _outcome([0.2, 0.5, 0.1, 0.3], [OPTIMAL, OUT_OF_STEPS, OUT_OF_STEPS, OUT_OF_STEPS],
                     [10, SCOUT_STEPS, SCOUT_STEPS, SCOUT_STEPS])
    solve = _Scripted(first, _outcome([0.05], [OPTIMAL], [7]))
    out = solve.best_of(np.zeros((4, 2)), known=0.15)
    # 0.5 and 0.3 are above the ended 0.2; 0.1 is below it and below the known 0.15
    assert solve.limits == [SCOUT_STEPS, 256 - SCOUT_STEPS]
    assert out.losses.tolist() == [0.2, 0.5, 0.05, 0.3]
    assert out.steps.tolist() == [10, SCOUT_STEPS, SCOUT_STEPS + 7, SCOUT_STEPS]
    assert out.best(1e-8).index == 2


def test_starts_cut_short_resume_from_where_they_stopped():
    """resume: the starts best_of stopped (out of steps before the limit) go on for the
    rest of it; those that ended, or ran the whole limit, are left as they are."""
    cut = _outcome([0.6, 0.2, 0.4, 0.5], [OUT_OF_STEPS, OPTIMAL, OUT_OF_STEPS, OUT_OF_STEPS],
                   [SCOUT_STEPS, 10, SCOUT_STEPS, 256])
    solve = _Scripted(_outcome([0.1, 0.35], [OPTIMAL, OUT_OF_STEPS], [40, 224]))
    out = solve.resume(cut)
    assert solve.limits == [256 - SCOUT_STEPS]
    assert out.losses.tolist() == [0.1, 0.2, 0.35, 0.5]
    assert out.steps.tolist() == [SCOUT_STEPS + 40, 10, 256, 256]
    assert out.codes.tolist() == [OPTIMAL, OPTIMAL, OUT_OF_STEPS, OUT_OF_STEPS]
    # nothing cut short: no call, the same outcome
    solve = _Scripted()
    assert solve.resume(out) is out and solve.limits == []
