"""A solution made a result: ``assemble(...) -> FitResult``, for every kind of fit.

The free fit (``brdffit.fitting.pipeline``) and the physically bounded one
(``brdffit.fitting.physical``) end here alike: the errors the input measures
(``brdffit.fitting.inputs``: a table's full-table error and sphere, a sample list's
every-sample and held-out errors), the optimised loss on the solver's own samples,
the uncertainty, and the quality verdict, into one ``FitResult``. "successful" is
kept only where every error could be measured: an error that cannot be measured is
no success.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable

import numpy as np

from brdffit.fitting.inputs import Refit, SampleInput, TableInput
from brdffit.fitting.loss import LOSS_METRIC
from brdffit.fitting.problem import Prepared
from brdffit.fitting.quality import NO_LOBE, quality, spike_off_the_table, without_lobes_on_noise
from brdffit.fitting.result import FitResult


class Later:
    """An uncertainty to compute only if the result stands (``result()``), as a
    ``concurrent.futures.Future`` running it on another thread is awaited."""

    def __init__(self, fn: Callable[[], dict | None]):
        self._fn = fn

    def result(self) -> dict | None:
        return self._fn()

    def exception(self) -> None:
        return None


def assemble(source: TableInput | SampleInput, model, u: np.ndarray, params: dict,
             prep: Prepared, *, result: str, steps: int, starts: int, sample_loss: float,
             loss: str, solver: str, precision: str, t0: float, uncertainty,
             refit: Refit | None = None, seed: int = 0, physical: bool = False,
             notes=(), table_metrics: dict | None = None) -> FitResult:
    """The :class:`FitResult` of ``model`` at ``u`` (unconstrained; ``params`` the same
    point as the model's parameters) fitted to ``source`` prepared as ``prep``.

    ``result``, ``steps`` and ``starts``: the solve's status name, steps and starts
    refined; ``sample_loss``: the optimised loss's sum of squares on the solver's
    samples (NaN where it diverged); ``uncertainty``: a pending computation of it
    (a ``Future`` or :class:`Later`) or None; ``refit``: the fit's own solve from a
    start on other data, for a sample list's held-out folds (None where the solve
    diverged); ``physical``: a bound is active (the verdict says so); ``t0``: the
    fit's start (``time.perf_counter``); ``notes``: where the fit did other than asked;
    ``table_metrics``: a table's full-table error at ``u``, measured already (beside
    other fits', in one pass).
    """
    measured = source.measure(
        model, u, params, prep, None if result == "nonfinite" else refit, seed,
        # the optimised loss on the solver's own subsample: sample_log_rmse for the log loss
        {f"sample_{LOSS_METRIC[loss]}": float(np.sqrt(max(sample_loss, 0.0) / 3.0))
         if np.isfinite(sample_loss) else float("nan")}, table_metrics)
    if result == "successful" and not measured.measurable:
        result = "nonfinite"  # an error that cannot be measured is no success
    found = None
    if uncertainty is not None and result != "nonfinite":
        found = uncertainty.result()
    elif uncertainty is not None:  # the metrics say nonfinite: none, whatever it was
        uncertainty.exception()
    metrics = measured.metrics
    look = quality(metrics["psnr_db"], measured.colour, model=model, params=params, loss=loss,
                   converged=result == "successful", physical=physical, basis=measured.basis,
                   rel_peak_error=metrics.get("rel_peak_error"))
    look, fitted_input = source.judged(look, measured, found)
    look = without_lobes_on_noise(look, model, found)
    found_notes, found_steps = source.findings(prep)
    if found_steps and look.get("verdict") != "good":  # the data's fault comes first
        look = {**look, "next": [*found_steps, *look.get("next", [])]}
    # once each: a polish carries its coarse fit's notes, which found the same table
    notes = tuple(dict.fromkeys((*notes, *_peak_missed(metrics, look, model, source.what),
                                 *_lobe_at_its_narrowest(model, params, found),
                                 *found_notes)))
    counts = prep.counts
    return FitResult(
        model=model.name,
        params=params,
        error=metrics,
        converged=result == "successful",
        result=result,
        steps=int(steps),
        time_s=time.perf_counter() - t0,
        samples={
            "used": prep.sample_set.n_used,
            "usable": prep.n_usable,
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
        starts=starts,
        uncertainty=found,
        table=source.source,
        quality=look,
        input=fitted_input,
        notes=tuple(notes),
    )


#: A fit this far off the table's brightest bin (``rel_peak_error``) has next to none of
#: it: a fitted ggx is 0.53-0.91 off on the sharpest MERL metals, a lambert 1.0 on any.
PEAK_MISSED = 0.99


def _lobe_at_its_narrowest(model, params: dict, found: dict | None) -> list[str]:
    """A note where a lobe that is there is held at the narrow end of the model's range
    (an ``alpha`` at its lower bound, a Phong ``n`` at its upper one): the table's lobe
    is narrower than the model holds, and the other parameters made up for it, their
    standard errors taken with the bound held (a GGX table of alpha 3e-4 came back alpha
    0.001, ks 11x too low at +-0.3%, "good", with no word of the bound)."""
    if not found:
        return []
    at_bound, why = found.get("at_bound") or {}, found.get("why") or {}
    out = []
    for spec in model.param_specs:
        name = spec.name
        # a lobe's width: the narrow end of alpha, alpha1 .. alpha4 is their lower bound,
        # of a Phong exponent its upper one
        narrow = (spec.lower if re.fullmatch(r"alpha\d?", name) else
                  spec.upper if name == "n" else None)
        if narrow is None or at_bound.get(name) is not True or name in why:
            continue
        value = float(np.ravel(params[name])[0])
        if not np.isclose(value, narrow, rtol=1e-3):
            continue  # held at its other, broad end
        out.append(f"{name} is held at its bound {narrow:g}, the narrowest {model.name} "
                   "holds: the fit would go further, so the table's lobe may be narrower, "
                   "and the other parameters then made up for it (their standard errors "
                   "are taken with it held there)")
    return out


def _peak_missed(metrics: dict, look: dict, model=None, what: str = "bins") -> list[str]:
    """Where the verdict is not poor but the fit misses the table's brightest bin
    entirely: a note that the verdict judged the look without that peak (a peak in
    fewer bins than the sphere's pixels see renders as nothing). A model without a lobe
    has no peak to give: said so. It asked "a lone hot bin, an outlier?" of ordinary
    tables (white-paint's and alum-bronze's render-loss fits): a bin far above its
    neighbours is named by the table's own note (``MerlTable.isolated_spikes``, a sample
    list's ``samples.isolated_spikes``), where there is one. ``what``: the input's
    unit (``TableInput.what``, "bins", or "samples": a sample list's notes speak of its
    brightest sample)."""
    rel = metrics.get("rel_peak_error")
    if look.get("verdict") == "poor" or rel is None or not rel >= PEAK_MISSED:
        return []
    if spike_off_the_table(look.get("highlight"), rel):
        return []  # the verdict judged the highlight, and its reason says so
    at, its, few = PEAK_WORDS[what]
    if model is not None and model.name in NO_LOBE:
        return [f"{at} misses {its} by {rel:.0%} of its value "
                f"(rel_peak_error {rel:.3g}): {model.name} has no specular lobe; the "
                f"'{look.get('verdict')}' verdict judges the look, in which the peak is "
                "too small to weigh"]
    if rel > 1.0:  # |fit - measured| beyond the measured value: the fit is above it
        return [f"{at} is {1.0 + rel:.3g}x {its} there (rel_peak_error "
                f"{rel:.3g}): a lobe brighter at the peak than anything measured, in {few}; "
                f"the '{look.get('verdict')}' verdict judges the look without it"]
    return [f"{at} misses {its} by {rel:.0%} of its value "
            f"(rel_peak_error {rel:.3g}): a peak in {few}; the "
            f"'{look.get('verdict')}' verdict judges the look without it"]


#: How :func:`_peak_missed`'s notes begin: a polish over every bin drops its coarse
#: fit's (whose figures they were) and says its own.
PEAK_NOTE = "at the table's brightest bin the fit"
#: :func:`_peak_missed`'s words for each kind of input: where, whose value, how few.
PEAK_WORDS = {
    "bins": (PEAK_NOTE, "the table's", "too few bins for the sphere render to see"),
    "samples": ("at the brightest sample the fit", "its value",
                "too few samples for the verdict's render to weigh"),
}

