"""Which model is enough for this material (and this scene), and why: ``select``.

Every candidate is fitted once, cheapest first (the registry's order:
lambert, oren_nayar, blinn_phong, phong, beckmann, ggx, ggx2 by default), and the
ranking reports for each: the parameters, ``log_rmse`` (on the scene's bins when
a scene is given, beside the full-table error), the PSNR of its sphere renders
against the table's (``brdffit.fitting.sphere``), its parameter count, its measured
evaluation cost per sample, a BIC, and whether its specular colour is grey.

The choice (docs/selection.md):

- **tolerance** (default ``brdffit.fitting.options.DEFAULT_TOLERANCE``): the cheapest candidate
  whose error is within ``tolerance`` of the best candidate's, measured *in
  quadrature*: ``excess = sqrt(err^2 - best^2) <= tolerance``. Errors that no
  model can fit (measurement noise, binning) add in quadrature to each model's own
  misfit, so the excess is that misfit and a noisy table does not make every model
  look alike. 0.005 in ``log_rmse`` is ~0.5 % RMS at the highlight, below the
  repeatability of a MERL measurement.
- **budget** (optional): the cheapest candidate with ``err <= budget``; when
  none reaches it, the tolerance rule decides and the reason says so.

BIC (Schwarz 1978), reported, not used for the choice: ``n ln(log_rmse^2) + k ln n``
with ``n`` = 3 x the bins the error is taken over and ``k`` the parameter count; a
Gaussian pseudo-likelihood of the compressed residual. With a million bins it
prefers the richest model as soon as it is measurably better, which is why the
choice uses a tolerance a person can read.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
import re
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from brdffit import models, runtime
from brdffit.errors import FitInputError
from brdffit.fitting.options import (
    DEFAULT_LOSS,
    DEFAULT_MAX_STEPS,
    DEFAULT_STARTS,
    DEFAULT_TOLERANCE,
    FIT_KEYWORDS,
    FitOptions,
)
from brdffit.fitting.quality import (
    ALIKE_DB,
    SPHERE_COMPARED_MIN,
    VERDICTS,
    describe,
    of_the_whole_sphere,
    radiance_verdict,
    with_measured_gains,
)
from brdffit.fitting.result import FitResult
from brdffit.fitting.scene import Scene, as_scene
from brdffit.io.merl import MerlTable

# The modules that compute with JAX (the problem, the sphere renders, the grey-ks
# model) are imported by the functions that fit and render, not here: the service's
# front imports this module for the one "best" rule (``chosen_result``) and
# starts without JAX (tests/test_api.py checks the running server).

#: auto's candidates, cheapest first: the registry's models that declare themselves
#: candidates (``AbstractBRDFModel.auto_candidate``; lambert, oren_nayar, blinn_phong,
#: phong, beckmann, ggx, ggx2 built in).
DEFAULT_CANDIDATES = models.catalogue.auto_candidates()
#: A specular colour is grey when (max - min) / max over R, G, B is at most this.
DEFAULT_GREY_TOLERANCE = 0.05


@dataclass
class Selection:
    """The outcome of :func:`select` as plain data (``to_dict`` is JSON-ready).

    ``ranking`` has one row per candidate, cheapest first; ``fits`` holds the
    :class:`FitResult` behind each row that fitted (the very fits the ranking
    reports: nothing is fitted twice); ``chosen_fit`` is the chosen one.
    """

    chosen: str
    reason: str
    ranking: list[dict]
    #: what the choice ranked by: ``log_rmse`` (the tolerance and budget rules) or,
    #: under the render loss, ``render_psnr_db`` (:func:`choose_by_look`)
    rule: str
    tolerance: float
    budget: float | None
    scene: dict | None
    mono: dict | None
    time_s: float
    table: str | None
    fits: dict[str, FitResult] = field(default_factory=dict, repr=False)

    @property
    def chosen_fit(self) -> FitResult:
        return self.fits[self.chosen]

    @property
    def row(self) -> dict:
        return next(r for r in self.ranking if r["model"] == self.chosen)

    def summary(self) -> dict:
        """Everything but the fits: what the chosen :class:`FitResult` carries as
        its ``selection``. (``asdict`` would copy the fits first, every array of
        them, to drop them: ~10 ms of a warm ``auto``.)"""
        return {f.name: copy.deepcopy(getattr(self, f.name)) for f in dataclasses.fields(self)
                if f.name != "fits"}

    def to_dict(self) -> dict:
        """The chosen fit in the result schema, its ``selection`` set: the same JSON
        shape as any fit's (``brdffit fit --json``, the service, the batch store)."""
        return self.chosen_fit.to_dict()


# -- measured evaluation cost -------------------------------------------------------------


#: Direction pairs that :func:`eval_cost_ns` times a model on.
EVAL_COST_PAIRS = 100_000


@functools.cache
def _eval_cost_inputs(model: models.AbstractBRDFModel, n: int = EVAL_COST_PAIRS):
    """The registry's model (the code a renderer runs), its default parameters
    (float32) and ``n`` random direction pairs. The parameters come from the programs
    of ``model`` as ``auto`` fits it (its family's where it shares them)."""
    import jax.numpy as jnp

    from brdffit.fitting.problem import constrained

    m = models.get(model.name)
    rng = np.random.default_rng(0)
    v = rng.normal(size=(2, n, 3))
    v[..., 2] = np.abs(v[..., 2])
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    wi, wo = (jnp.asarray(a, jnp.float32) for a in v)
    params = {k: np.asarray(x, np.float32) for k, x in
              constrained(model, np.zeros(m.n_params)).items()}
    return m, params, wi, wo


@runtime.in_float64
def ready_eval_cost(model: models.AbstractBRDFModel) -> None:
    """Compile (or load) the evaluation that :func:`eval_cost_ns` times, without
    timing it."""
    from brdffit.fitting.sphere import evaluate

    evaluate.ready(*_eval_cost_inputs(model))


@functools.cache
@runtime.in_float64
def eval_cost_ns(model: models.AbstractBRDFModel, repeats: int = 7) -> float:
    """Median wall time (ns) per direction pair of ``model(params, wi, wo)``.

    Measured once per model per process: the model jitted over
    :data:`EVAL_COST_PAIRS` random pairs in float32 (what a renderer uses), shading
    frame included (a renderer pays for it too), after one warm-up call. Absolute
    values depend on the machine; the ratios between models are what the ranking
    is for.
    """
    from brdffit.fitting.sphere import evaluate

    m, params, wi, wo = _eval_cost_inputs(model)
    # the renders' compiled evaluation: kept on disk, so a new process's first
    # `auto` loads it instead of compiling one per candidate
    evaluate(m, params, wi, wo).block_until_ready()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        evaluate(m, params, wi, wo).block_until_ready()
        times.append(time.perf_counter() - t0)
    return float(np.median(times) / wi.shape[0] * 1e9)


# -- helpers -----------------------------------------------------------------------------


def grey_spread(model: models.AbstractBRDFModel, params: dict) -> float | None:
    """(max - min) / max over R, G, B of the specular scales (worst of ks, ks1, ks2);
    0 for no specular at all; ``None`` for a model without a specular colour. A scale
    under :data:`NEGLIGIBLE_SCALE` of the largest one is left out: a collapsed second
    lobe (ks2 ~ 1e-7 beside a grey ks1 of 886) has no colour anyone sees, and called
    the highlight 60% off grey."""
    from brdffit.models.mono_ks import MonoKs, specular_colour_specs

    specs = specular_colour_specs(model) if not isinstance(model, MonoKs) else ()
    if not specs:
        return None
    scales = [np.asarray(params[s.name], dtype=np.float64) for s in specs]
    largest = max(float(v.max()) for v in scales)
    spread = 0.0
    for v in scales:
        top = float(v.max())
        if top > max(1e-12, NEGLIGIBLE_SCALE * largest):
            spread = max(spread, (top - float(v.min())) / top)
    return spread


#: A specular scale below this fraction of the model's largest is left out of
#: :func:`grey_spread`.
NEGLIGIBLE_SCALE = 1e-3


def bic(log_rmse: float, n_bins: int, n_params: int) -> float:
    n = 3 * max(n_bins, 1)
    return float(n * math.log(max(log_rmse, 1e-150) ** 2) + n_params * math.log(n))


def _order(candidates) -> list[models.AbstractBRDFModel]:
    """Candidates as models, cheapest first in the registry's order (a grey-ks variant
    just before its base model); unknown names raise ``UnknownModelError``.

    The registry's order is the analytic models' size, then each renderer's family,
    whatever its size (gltf_pbr's 5 values after ggx's 8). Ordered by size alone, auto
    with layers on the 100 MERL (bench.auto_layers) took gltf_pbr within the log loss's
    tolerance over ggx on 13 materials: orange-paint 6.5 dB worse in the independent
    render, and two materials more than 0.5 dB worse than auto without layers."""
    from brdffit.models.mono_ks import MonoKs

    ms = [models.get(c) for c in models.catalogue.expand_candidates(candidates)]
    if not ms:
        raise FitInputError("select needs at least one candidate model")
    names = [m.name for m in ms]
    if len(set(names)) != len(names):
        raise FitInputError(f"duplicate candidates in {names}")
    position = {name: i for i, name in enumerate(models.REGISTRY)}

    def rank(m):
        if isinstance(m, MonoKs):
            return position.get(m.base.name, len(position)) - 0.5
        return position.get(m.name, len(position))

    return sorted(ms, key=rank)


def _fmt(x: float) -> str:
    return f"{x:.3g}"


# -- the front door ------------------------------------------------------------------------


@runtime.in_float64
def select(
    table: MerlTable,
    candidates=DEFAULT_CANDIDATES,
    *,
    tolerance: float = DEFAULT_TOLERANCE,
    budget: float | None = None,
    scene: Scene | dict | str | None = None,
    mono_ks: bool = False,
    grey_tolerance: float = DEFAULT_GREY_TOLERANCE,
    image_size: int | None = None,
    progress: Callable[[int, int, str, dict | None], None] | None = None,
    threads: int | None = None,
    **fit_options,
) -> Selection:
    """Fit every candidate and choose the cheapest that is good enough.

    Args:
        table: the measured table.
        candidates: model names (or instances); fitted cheapest first.
        tolerance: how far (in ``log_rmse``, in quadrature) above the best
            candidate a cheaper one may be and still be chosen.
        budget: optional absolute ``log_rmse`` budget: the cheapest candidate
            under it wins (the tolerance rule decides when none is).
        scene: optional :class:`brdffit.fitting.scene.Scene` (or its JSON form, a
            preset's name or a scene file's path: ``as_scene``): the loss, the errors
            the choice uses, and the ranking are on its bins; the full-table error is
            reported beside.
        mono_ks: also fit the chosen model with a grey ``ks`` (``<model>_mono``)
            when its fitted specular colour is grey within ``grey_tolerance``.
        grey_tolerance: ``(max - min) / max`` of ks over R, G, B that counts as grey.
        image_size: pixels per side of the sphere renders behind ``psnr_db``; None
            (default) takes each fit's own ``psnr_db`` (128 px), rendered once.
        progress: called as ``progress(i, n, model, None)`` before candidate ``i``
            of ``n`` (0-based) is fitted and ``progress(i, n, model, row)`` after,
            with its ranking row (``status`` ``"fitted"`` or ``"failed"``; its
            ``cost_ns`` still None, timed once every fit is done): a shell shows it
            (``brdffit fit --model auto`` on stderr); the library prints nothing. The
            calls come in candidate order, from the calling thread.
        threads: how many candidates are fitted at once, each in its own thread
            (a fit runs on about one core); None: one per core this process may use,
            at most one per candidate. The results do not depend on it.
        **fit_options: passed to :func:`brdffit.fit` (``solver``, ``samples``,
            ``precision``, ``starts``, ``max_steps``, ``seed``).
    """
    # JAX's modules, imported here rather than by the threads below (see the imports)
    from brdffit.fitting import problem
    from brdffit.fitting.inputs import refuse_blank_but_spikes
    from brdffit.fitting.sphere import SphereReference

    if isinstance(table, MerlTable):  # once, not in each candidate's words
        problem.cached(table, "blank-but-spikes", lambda: refuse_blank_but_spikes(table))

    t0 = time.perf_counter()
    # the fit's own options only; select sets parent_fit, init and bin_weight itself
    unknown = set(fit_options) - set(FIT_KEYWORDS)
    if unknown:
        raise FitInputError(
            f"select passes only {', '.join(FIT_KEYWORDS)} to fit, not {sorted(unknown)}"
        )
    FitOptions.from_dict(fit_options)  # refused once, before any candidate (seed=None)
    if scene is not None:
        scene = as_scene(scene)
    if isinstance(candidates, str):  # "ggx" was read letter by letter: unknown model 'g'
        candidates = [c.strip() for c in candidates.split(",") if c.strip()]
    for name, v in (("tolerance", tolerance), ("grey_tolerance", grey_tolerance)):
        if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
            raise FitInputError(f"{name} must be a number >= 0, got {v!r}")
    if budget is not None and not (isinstance(budget, int | float) and budget > 0):
        raise FitInputError(f"budget must be a number > 0, got {budget!r}")
    if threads is not None and not (isinstance(threads, int) and threads >= 1):
        raise FitInputError(f"threads must be a positive integer or None, got {threads!r}")
    from brdffit.models.base import sharing_where_it_pays

    # candidates of one family (ggx and beckmann, ...) compile one program of each kind
    ordered = sharing_where_it_pays(_order(candidates))
    reference = None if image_size is None else SphereReference(table, image_size)
    views = None
    if (fit_options.get("loss") == "render" and budget is None
            and isinstance(table, MerlTable)):
        # the render rule ranks by the render loss's own eight lights (views_psnr_db);
        # made once per table object, as its two-light reference (~25 ms warm)
        from brdffit.fitting.render_loss import LIGHTS as VIEW_LIGHTS

        size = image_size or 128
        views = problem.cached(table, ("render-loss-views", size),
                               lambda: SphereReference(table, size, lights=VIEW_LIGHTS))

    rows, fits = [], {}
    with (_CandidateFits(table, ordered, scene, fit_options, threads) as running,
          ThreadPoolExecutor(1, thread_name_prefix="brdffit-cost") as cost_thread):
        costs_ready = cost_thread.submit(_ready_eval_costs, ordered)
        for i, m in enumerate(ordered):
            if progress is not None:
                progress(i, len(ordered), m.name, None)
            row = {"model": m.name, "n_params": m.n_params}
            try:
                r = running.result(m.name)
            except FitInputError as e:  # e.g. a scene with too few bins for this model
                rows.append({**row, "status": "failed", "message": str(e)})
                if progress is not None:
                    progress(i, len(ordered), m.name, dict(rows[-1]))
                continue
            fits[m.name] = r
            _add_row(rows, row, r, m, scene, reference, views)
            if progress is not None:
                progress(i, len(ordered), m.name, dict(row))  # the choice edits row later
        costs_ready.result()
    # timed once every fit is done: beside running fits, a timing measures their load
    fitted = {m.name: m for m in ordered}
    for row in rows:
        if row["status"] == "fitted":
            row["cost_ns"] = eval_cost_ns(fitted[row["model"]])
    return _decide(table, rows, fits, tolerance, budget, scene, mono_ks, grey_tolerance,
                   fit_options, t0)


def _ready_eval_costs(ordered) -> None:
    """Every candidate's timed evaluation compiled (or loaded), on a thread of its own
    beside the fits: in a new process they held up the first fit by ~2 s on 2 cores
    when they compiled first. The timings (:func:`eval_cost_ns`) run after the fits."""
    for m in ordered:
        ready_eval_cost(m)


def _add_row(rows: list, row: dict, r: FitResult, m, scene, reference, views=None) -> None:
    # A sample list's fits are ranked on their held-out error: on sparse samples the
    # in-sample one flatters the richer model (brdffit.fitting.samples).
    held = r.error.get("held_out_log_rmse")
    err = r.error["log_rmse"] if held is None else held
    full = r.full_table_error["log_rmse"] if scene is not None else r.error["log_rmse"]
    row.update(
        params=r.params,
        log_rmse=err,
        log_rmse_basis="in_sample" if held is None else "held_out",
        log_rmse_se=r.error.get("held_out_log_rmse_se"),
        full_log_rmse=full,
        psnr_db=(r.error["psnr_db"] if reference is None
                 else reference.psnr(m, r.params)),
        # the render rule's measure: the sphere under each of the render loss's lights
        views_psnr_db=None if views is None else _finite_or_none(views.psnr(m, r.params)),
        cost_ns=None,  # timed once every fit is done (select)
        bic=bic(err, r.samples["usable"], m.n_params),
        ks_grey_spread=grey_spread(m, r.params),
        converged=r.converged,
        result=r.result,
        steps=r.steps,
        fit_time_s=r.time_s,
        # how the candidate looks beside the measurement (brdffit.fitting.quality)
        verdict=(r.quality or {}).get("verdict"),
        radiance_verdict=radiance_verdict(r.quality),
        # the share of the verdict's sphere the table measures (absent for samples)
        sphere_measured=(r.quality or {}).get("sphere_measured"),
        status="fitted" if math.isfinite(err) else "failed",
    )
    rows.append(row)


def _decide(table, rows, fits, tolerance, budget, scene, mono_ks, grey_tolerance,
            fit_options, t0) -> Selection:
    """The choice over the fitted rows, its reason, and the optional grey-ks refit."""
    ok = [row for row in rows if row["status"] == "fitted"]
    if not ok:
        raise FitInputError(f"no candidate could be fitted: {_failures(rows)}")
    loss = fit_options.get("loss", DEFAULT_LOSS)
    rule = _rule_of(loss, budget)
    if rule == "render_psnr_db":
        chosen, reason = choose_by_look(ok)
        best = max(ok, key=_psnr)
        tolerance_used = RENDER_TOLERANCE_DB
    else:
        best = min(ok, key=lambda row: row["log_rmse"])
        se = best.get("log_rmse_se")
        tolerance_used = _within_noise(ok, tolerance)
        # the look (the whole sphere's verdict) breaks ties in the error only without a
        # scene: with one, the scene's bins are all the choice may look at
        chosen, reason = choose(ok, tolerance_used, budget, by_look=scene is None)
        if tolerance_used != tolerance:
            reason += (f" (The tolerance is one standard error, {_fmt(se)}, of "
                       f"{best['model']}'s held-out log_rmse, {_fmt(tolerance_used)} in "
                       f"quadrature, above the {_fmt(tolerance)} asked: these samples tell "
                       "no smaller difference from noise.)")
        if loss == "render":
            reason += (" (The budget is a log_rmse figure: given one, it decides even under "
                       "the render loss.)")
    _layer_gains(ok, rule)
    chosen, reason = _layer_held_to_its_rule(chosen, reason, ok, rule, tolerance, budget,
                                             by_look=scene is None)
    doubtful = [row for row in ok if (row is chosen or row is best) and not row["converged"]]
    if doubtful:
        reason += " " + "; ".join(
            f"{row['model']} did not converge ({row['result']}) even when refitted with more "
            "starts and steps: its error is an upper bound, not an optimum" for row in doubtful
        ) + "."
    # whether the tolerance rule ranked by the look too (choose's by_look; not when a
    # budget was met: the cheapest under it is chosen)
    by_look = rule == "log_rmse" and scene is None and (
        budget is None or not any(row["log_rmse"] <= budget for row in ok))
    for row in ok:
        if row is chosen:
            row["status"] = "chosen"
        elif budget is not None and row["log_rmse"] <= budget:
            row["status"] = "under budget"
        else:
            row["status"] = ("looks worse" if ((rule == "render_psnr_db" or (
                by_look and row["excess"] <= tolerance_used))
                and _verdict_rank(row) > _verdict_rank(chosen))
                or (by_look and row.get("renders_further_off")) else
                "within tolerance" if row["excess"] <= tolerance_used else "too far")
    reason += _all_poor_warning(ok, loss)

    for row in ok:
        spread = row["ks_grey_spread"]
        row["ks_grey"] = None if spread is None else bool(spread <= grey_tolerance)
    mono = None
    spread = chosen["ks_grey_spread"]
    # what the spread is of: ks (ks1, ks2), or MaterialX's specular_color
    what = "ks" if all(p.name != "specular_color"
                       for p in models.get(chosen["model"]).param_specs) else "specular_color"
    if spread is not None:
        if chosen["ks_grey"]:
            reason += (f" Its specular colour is grey ({what} spread {100 * spread:.1f}% <= "
                       f"{100 * grey_tolerance:g}%): a monochrome ks would do")
            if mono_ks:
                mono = _fit_mono(table, models.get(chosen["model"]), fits[chosen["model"]],
                                 scene, tolerance, fit_options)
                fits[mono["model"]] = mono.pop("fit")
                reason += (f"; refitted as {mono['model']} ({mono['n_params']} values): "
                           f"log_rmse {_fmt(mono['log_rmse'])}, "
                           + ("within" if mono["accepted"] else "NOT within")
                           + " tolerance of the RGB fit.")
            else:
                reason += f" ({chosen['n_params'] - 2} values instead of {chosen['n_params']}; "
                reason += "mono_ks=True fits it)."
        else:
            reason += f" Its specular colour is not grey ({what} spread {100 * spread:.1f}%)."
    if scene is not None:
        reason = (f"On scene {scene.describe()}: " + reason[0].lower() + reason[1:]
                  + f" Full-table log_rmse of {chosen['model']}: {_fmt(chosen['full_log_rmse'])}.")
    selection = Selection(
        chosen=chosen["model"],
        reason=reason,
        rule=rule,
        ranking=rows,
        tolerance=float(tolerance),
        budget=None if budget is None else float(budget),
        scene=None if scene is None else scene.to_dict(),
        mono=mono,
        time_s=time.perf_counter() - t0,
        table=table.source,
        fits=fits,
    )
    # the chosen fit carries how it was chosen (the one result schema), and what the
    # candidates that render closer measured for its next steps
    chosen_fit = fits[selection.chosen]
    fits[selection.chosen] = dataclasses.replace(
        chosen_fit, selection=selection.summary(),
        quality=with_measured_gains(chosen_fit.quality,
                                    _render_gains(chosen, ok, scene is not None and (
                                        of_the_whole_sphere(chosen_fit.quality))),
                                    loss=chosen_fit.loss))
    return selection


def rechoose(rows: list[dict], loss: str = DEFAULT_LOSS, tolerance: float = DEFAULT_TOLERANCE,
             budget: float | None = None, by_look: bool = True) -> dict:
    """The row auto chooses among ranking ``rows`` (cheapest first, as
    ``Selection.ranking`` holds them, or a subset), without refitting: the rule that
    ``select`` applies under ``loss`` (the render rule, or the tolerance rule with
    ``tolerance`` and ``budget``; ``by_look`` False as with a scene) and its guard on
    layered choices. It decides on copies: ``rows`` keep their ranks and statuses. For
    replaying a rule on stored rankings (``bench.auto_rows``) and re-deciding on a
    subset of candidates (``bench.auto_layers``)."""
    ok = [dict(copy.deepcopy(row), status="fitted") for row in rows
          if row.get("status") != "failed" and row.get("log_rmse") is not None]
    if not ok:
        raise FitInputError("no fitted candidate to choose among")
    rule = _rule_of(loss, budget)
    chosen, reason = _by_rule(ok, rule, tolerance, budget, by_look)
    _layer_gains(ok, rule)
    chosen, _ = _layer_held_to_its_rule(chosen, reason, ok, rule, tolerance, budget, by_look)
    return chosen


def _rule_of(loss: str, budget: float | None) -> str:
    """What auto ranks by: the render rule under the render loss, unless a budget (a
    log_rmse figure) was given; else the tolerance rule."""
    return "render_psnr_db" if loss == "render" and budget is None else "log_rmse"


def _by_rule(rows: list[dict], rule: str, tolerance: float, budget: float | None,
             by_look: bool) -> tuple[dict, str]:
    """``rule``'s choice among ``rows`` and its reason: :func:`choose_by_look`, or
    :func:`choose` with the tolerance worked out on these rows (:func:`_within_noise`)."""
    if rule == "render_psnr_db":
        return choose_by_look(rows)
    return choose(rows, _within_noise(rows, tolerance), budget, by_look=by_look)


#: Each candidate's last solve in this process (s, wall, its wait for a parent
#: included): the order in which candidates start (:func:`longest_chains_first`).
_SOLVE_SECONDS: dict[str, float] = {}


def _within_noise(ok: list[dict], tolerance: float) -> float:
    """The tolerance rule's tolerance over the rows ``ok``: ``tolerance``, or where their
    best error is a sample list's held-out one, at least one standard error of it (the
    one-standard-error rule), which the rule's excess in quadrature puts at
    sqrt((best + se)^2 - best^2): a smaller difference is noise on these samples."""
    best = min(ok, key=lambda row: row["log_rmse"])
    se = best.get("log_rmse_se")
    if se is None or not math.isfinite(se):
        return tolerance
    return max(tolerance, math.sqrt(max((best["log_rmse"] + se) ** 2
                                        - best["log_rmse"] ** 2, 0.0)))


def _failures(rows: list[dict]) -> str:
    """Why each candidate failed, in one line: a reason that every one of them gives
    (too few samples for any of them) once, with the candidates it stopped."""
    def said(row) -> str:
        return str(row.get("message", row.get("result")))

    def shape(row) -> str:  # the reason without its model's name and its counts
        named = re.sub(rf"(?<![\w-]){re.escape(row['model'])}(?![\w-])", "<model>", said(row))
        return re.sub(r"[\d,]+", "#", named)

    groups: dict[str, list[dict]] = {}
    for row in rows:
        groups.setdefault(shape(row), []).append(row)
    parts = []
    for same in groups.values():
        first = same[0]
        others = [row["model"] for row in same[1:]]
        parts.append(f"{first['model']}: {said(first)}"
                     + (f" (and likewise {', '.join(others)})" if others else ""))
    return "; ".join(parts)


def longest_chains_first(ordered: list) -> list:
    """``ordered``'s candidates in the order their fits start: longest chain of work
    first (a candidate's own cost plus that of the costliest candidate that starts
    from it), a parent always before the candidates that start from it.

    Candidates run side by side on a few threads; in the registry's order the
    costliest chain (ggx, then ggx2, which waits for ggx) started last, and ggx2 ran
    on alone at the end (a warm auto 5% slower, median of 34 MERL materials on 2
    cores). A cost is the candidate's last solve in this process, or its parameter
    count in hundredths of a second before it has one. The order changes which fit
    runs when, never a result."""
    names = {m.name for m in ordered}
    children: dict[str, list] = {}
    for m in ordered:
        if m.parent in names:
            children.setdefault(m.parent, []).append(m)

    @functools.cache
    def chain(name: str, n_params: int) -> float:
        own = _SOLVE_SECONDS.get(name, 0.01 * n_params)
        return own + max((chain(c.name, c.n_params) for c in children.get(name, ())),
                         default=0.0)

    # a parent's chain holds its children's, so it sorts first: ties keep the order given
    return sorted(ordered, key=lambda m: -chain(m.name, m.n_params))


class _CandidateFits:
    """The candidates' fits, running beside each other on a pool of threads.

    Much of a fit is the solver's loop, one XLA computation on one core, and the
    rest keeps a second core only partly busy: on 2 cores, candidates side by side
    take ~15% less time than one after another (a fit alone keeps ~1.7 cores busy;
    the gain grows with the cores). A candidate that contains another
    (ggx2 contains ggx) compiles its programs and scores its starts meanwhile, then
    waits for that one's solution, which it starts from; the candidates are submitted
    longest chain first (:func:`longest_chains_first`), parents first, so a waiting fit
    never holds up its own parent.

    On a table without a scene, the candidates are solved first and measured after,
    all of them in one pass over the table (``full_table_metrics_of``): a pass is
    mostly reading the table's 1.46M bins, and seven passes cost ~2.3x one pass of
    seven models (issue 41). A nested candidate then starts from its parent's
    solution before that is measured, where the measurement can change nothing (the
    parent converged and has no parent itself); elsewhere it waits for the parent's
    fit and is fitted after the pass, as one fit. A candidate left at its parent's
    optimum, not one step taken, is measured as its parent (:func:`_at_its_parent`).
    (Measuring the candidates solved first beside the last solve, and that one after,
    gained nothing measurable on 2 cores: a solve keeps ~1.5 cores busy, so no core
    was idle.)

    Every fit is the one a sequential run makes: each depends only on the table,
    its options and its parent's fit (the one pass sums each model's errors as its
    own pass does, but in another order: their float32 sums agree to ~1e-7).
    """

    def __init__(self, table, ordered, scene, fit_options: dict, threads: int | None):
        self._futures: dict[str, Future] = {}
        self._table, self._ordered = table, ordered
        self._fit_options = fit_options
        self._results: dict[str, Future] | None = None
        n = threads if threads is not None else runtime.usable_cores()
        self._threads = max(1, min(n, len(ordered)))
        self._pool = ThreadPoolExecutor(self._threads, thread_name_prefix="brdffit-auto")
        self._one_pass = (scene is None and isinstance(table, MerlTable)
                          and not fit_options.get("physical", False))
        work = self._solved if self._one_pass else self._fit
        # one at a time, the order changes nothing: cheapest first, as the ranking reads
        self._submitted = longest_chains_first(ordered) if self._threads > 1 else ordered
        for m in self._submitted:
            parent = self._futures.get(m.parent) if m.parent is not None else None
            self._futures[m.name] = self._pool.submit(self._timed, work, table, m, scene,
                                                      fit_options, parent)

    @staticmethod
    def _timed(work, table, m, scene, fit_options, parent):
        t0 = time.perf_counter()
        out = work(table, m, scene, fit_options, parent)
        _SOLVE_SECONDS[m.name] = time.perf_counter() - t0
        return out

    @staticmethod
    def _fit(table, m, scene, fit_options, parent: Future | None) -> FitResult:
        # the parent's fit as a function: this fit compiles its programs and scores its
        # starts while the parent's runs, and waits for it only to start from it
        fits = {} if parent is None else {m.parent: parent.result}
        return _fit_converged(table, m, scene, fits, fit_options)

    def _solved(self, table, m, scene, fit_options, parent: Future | None):
        """The candidate solved (``pipeline.Solved``), or None: it waits for its
        parent's measured fit (:meth:`_measured_after`)."""
        from brdffit.fitting.pipeline import solved_fit

        def parent_solution():
            solved = parent.result()
            if solved is None or not solved.final_as_is():
                raise _AfterThePass
            return solved

        options = {k: v for k, v in fit_options.items() if k != "physical"}  # False here
        try:
            s = solved_fit(table, m, full_table_ahead=False,
                           **({} if parent is None else {"parent_fit": parent_solution}),
                           **options)
        except _AfterThePass:
            return None
        if parent is None and m is self._submitted[0]:
            # the one pass's program, in a new process, compiles beside the others' solves
            from brdffit.fitting.problem import ready_metrics_of_once

            ready_metrics_of_once(table, [(c, np.zeros(c.n_params)) for c in self._ordered],
                                  s.prep)
        return s

    def _measured(self) -> dict[str, Future]:
        """Every candidate's fit (or its error) once all are solved: measured in one
        pass, then finished (each refitted as ``_fit_converged`` does where it did not
        converge), parents first."""
        from brdffit.fitting.problem import full_table_metrics_of

        solved = {}
        done: dict[str, Future] = {}
        for m in self._ordered:
            try:
                solved[m.name] = self._futures[m.name].result()
            except Exception as e:  # noqa: BLE001 - kept as that candidate's outcome
                done[m.name] = _failed(e)
        ready = [s for s in solved.values() if s is not None]
        # a candidate left at its parent's optimum is measured as its parent
        as_parent = {s.m.name: s.m.parent for s in ready if _at_its_parent(s, solved)}
        measured = [s for s in ready if s.m.name not in as_parent]
        t_pass = time.perf_counter()
        metrics = {} if not measured else dict(zip(
            (s.m.name for s in measured),
            full_table_metrics_of(self._table, [(s.m, s.best().u) for s in measured],
                                  measured[0].prep.weight, peak=measured[0].prep.peak),
            strict=True))
        for name in as_parent:
            parent = as_parent[name]
            while parent in as_parent:  # ggx3 at ggx2's, itself at ggx's
                parent = as_parent[parent]
            metrics[name] = dict(metrics[parent])
        # each measured fit's time counts its share of the pass; one measured as its
        # parent took no part in it
        share = (time.perf_counter() - t_pass) / max(len(measured), 1)
        # finished on the pool, parents first: a fit waits for its parent's only
        finished: dict[str, Future] = {}
        for m in self._ordered:
            if m.name not in done:
                finished[m.name] = self._pool.submit(
                    self._finished, m, solved[m.name], metrics.get(m.name),
                    0.0 if m.name in as_parent else share,
                    finished.get(m.parent) if m.parent is not None else None)
        for name, f in finished.items():
            done[name] = _done_as(f, lambda pair: pair[0])
        return done

    def _finished(self, m, s, metrics: dict | None, share: float,
                  parent: Future | None) -> tuple[FitResult, bool]:
        """The candidate's fit, and whether it is its solution ``s`` finished (a fit
        that contains it may then start from that solution)."""
        from brdffit.fitting.pipeline import finish

        parent_fit, as_solved = None, False
        if parent is not None:
            try:
                parent_fit, as_solved = parent.result()
            except Exception:  # noqa: BLE001 - the parent's own outcome; fitted here
                parent_fit = None
        fits = {} if parent_fit is None else {m.parent: parent_fit}
        if s is None or (parent is not None and not as_solved):
            # the parent's fit is not the solution this one started from
            return _fit_converged(self._table, m, None, fits, self._fit_options), False
        r = finish(s, metrics, parent_result=parent_fit, shared_s=share)
        if r.converged:
            return r, True
        return _converged(r, self._table, m, None, fits, self._fit_options), False

    def result(self, name: str) -> FitResult:
        if not self._one_pass:
            return self._futures[name].result()
        if self._results is None:
            self._results = self._measured()
        return self._results[name].result()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        # on an error, fits not yet started are dropped, running ones finish
        self._pool.shutdown(wait=True, cancel_futures=True)
        return False


def _at_its_parent(s, solved: dict) -> bool:
    """Whether the solved candidate ``s`` is its parent's optimum, solved in this
    ``auto``, with what it adds switched off and not one step taken from there
    ("nested: no gain": oren_nayar on 98 of the 100 MERL, ggx2 on a single-lobe
    table). Its full-table figures are then its parent's: what it adds sits at its
    bound (ggx2's ks2, oren_nayar's sigma, deep in the softplus tail), where it moves
    no bin's value (its loss on the solver's samples is the parent's, to 1e-9, or
    both are at the exact-fit floor). The pass measured it anyway, ~1/7 of the pass
    each, for the parent's figures (to the last bit on 20 MERL materials). A solve
    that moved it, or in another precision, is measured as any other."""
    from brdffit.fitting.pipeline import exact_fit_loss

    parent = solved.get(s.m.parent) if s.m.parent is not None else None
    if parent is None or s.parent is None:
        return False
    best, theirs = s.best(), parent.best()
    if best.steps != 0 or not np.array_equal(np.asarray(best.u, np.float64),
                                             np.asarray(s.parent, np.float64)):
        return False
    return (abs(float(best.loss) - float(theirs.loss))
            <= 1e-9 * abs(float(theirs.loss)) + exact_fit_loss(s.prep))


class _AfterThePass(Exception):
    """A nested candidate's parent solution may still change when it is measured: the
    candidate waits for its parent's fit instead (``_CandidateFits._measured``)."""


def _done_as(f: Future, part) -> Future:
    """A future of ``part`` of ``f``'s result (or of its error)."""
    out = Future()
    try:
        out.set_result(part(f.result()))
    except Exception as e:  # noqa: BLE001 - kept as that candidate's outcome
        out.set_exception(e)
    return out


def _failed(e: BaseException) -> Future:
    f = Future()
    f.set_exception(e)
    return f


def fit_in_scene(table, model, scene, **fit_options) -> FitResult:
    """``brdffit.fitting.pipeline.fit_in_scene``, imported at the first fit: the request
    module imports this one, and a client imports the request module, without JAX."""
    from brdffit.fitting.pipeline import fit_in_scene as fit_on_the_scene

    return fit_on_the_scene(table, model, scene, **fit_options)


def _fit_converged(table, m, scene, fits: dict, fit_options: dict) -> FitResult:
    """The candidate's fit, seeded from its parent's when it has one; refitted once
    with more starts and steps when it did not converge, so that the choice rests
    on optima (an unconverged error would make a model look worse than it is)."""
    parent = {"parent_fit": fits[m.parent]} if m.parent in fits else {}
    return _converged(fit_in_scene(table, m, scene, **parent, **fit_options), table, m,
                      scene, fits, fit_options)


def _converged(r: FitResult, table, m, scene, fits: dict, fit_options: dict) -> FitResult:
    """``r``, or where it did not converge, its refit with more starts and steps
    where that converged or ended lower (:func:`_fit_converged`)."""
    if r.converged:
        return r
    parent = {"parent_fit": fits[m.parent]} if m.parent in fits else {}
    retry_options = {
        **fit_options,
        "starts": max(4, fit_options.get("starts", DEFAULT_STARTS)),
        "max_steps": 4 * fit_options.get("max_steps", DEFAULT_MAX_STEPS),
    }
    retry = fit_in_scene(table, m, scene, **parent, **retry_options)
    better = retry.converged or retry.error["log_rmse"] < r.error["log_rmse"]
    if not better:
        return r
    # said where it is read: the result's starts and steps are the retry's (a scene's
    # ggx reported 4 starts and 311 steps against a limit of 256, and no note)
    asked = fit_options.get("starts", DEFAULT_STARTS), fit_options.get("max_steps",
                                                                        DEFAULT_MAX_STEPS)
    note = (f"auto refitted it with {retry_options['starts']} starts and up to "
            f"{retry_options['max_steps']} steps per start: as asked ({asked[0]} start(s), "
            f"{asked[1]} steps) it ended {r.result}, log_rmse {_figure(r)}")
    return dataclasses.replace(retry, notes=(*retry.notes, note))


def _figure(r: FitResult) -> str:
    e = r.error.get("log_rmse")
    return "n/a" if e is None else f"{e:.4g}"


def choose(ok: list[dict], tolerance: float, budget: float | None = None,
           by_look: bool = True) -> tuple[dict, str]:
    """The rule alone: the chosen row of fitted ranking rows ``ok`` (cheapest first,
    each with ``model`` and ``log_rmse``) and the reason, in words. Sets each row's
    ``excess`` and ``rank``. Re-running it with another tolerance or budget re-decides
    without refitting.

    With ``by_look`` (and rows that carry a ``verdict``), the candidates within
    tolerance that read the best verdict any of them reads (:func:`_verdict_rank`) are
    the eligible ones: a cheaper fit within tolerance whose sphere reads worse is passed
    over (its row then ``looks worse``). Within the tolerance the error says the fits
    are alike; the verdict says where they are not: on the 100 MERL, auto took lambert
    (visible) over ggx (good) on two fabrics, and beckmann, 11 dB from the measurement,
    over ggx at 21 on black-soft-plastic; ranked by the look, the four it chooses
    otherwise render 1.3-7.8 dB closer in bench.render_loss's independent render.
    Rows without a verdict all rank alike: the rule is then the error's alone."""
    best = min(ok, key=lambda row: row["log_rmse"])
    for row in ok:
        row["excess"] = math.sqrt(max(row["log_rmse"] ** 2 - best["log_rmse"] ** 2, 0.0))
    for i, row in enumerate(sorted(ok, key=lambda row: row["log_rmse"])):
        row["rank"] = i + 1
    prefix = ""
    if budget is not None:
        under = [row for row in ok if row["log_rmse"] <= budget]
        if under:
            c = _lowest_of_its_size(under[0], under)
            cheaper = ", ".join(f"{r['model']} {_fmt(r['log_rmse'])}" for r in ok[: ok.index(c)]
                                if r not in under)
            return c, (
                f"Chose {c['model']}: the cheapest candidate with log_rmse "
                f"{_fmt(c['log_rmse'])} <= budget {_fmt(budget)}"
                + (f" (cheaper ones miss it: {cheaper})" if cheaper else "")
                + "."
            )
        prefix = (f"No candidate reaches the budget {_fmt(budget)} (best: {best['model']} "
                  f"{_fmt(best['log_rmse'])}), so the tolerance rule decides. ")
    within = [row for row in ok if row["excess"] <= tolerance]
    eligible, further_off, top_row = within, [], None
    if by_look:
        look = min(_verdict_rank(row) for row in within)
        eligible = [row for row in within if _verdict_rank(row) == look]
        # of those, the ones that render within LOOK_WINDOW_DB of the best-looking (not
        # a sample list's: its tolerance is widened for noise, its render is not; nor a
        # row whose render was not measured: not measured is not further off)
        top_row = max(eligible, key=_psnr)
        if math.isfinite(_psnr(top_row)) and not any(
                row.get("log_rmse_basis") == "held_out" for row in eligible):
            further_off = [row for row in eligible if math.isfinite(_psnr(row))
                           and _psnr(row) < _psnr(top_row) - LOOK_WINDOW_DB]
            eligible = [row for row in eligible if row not in further_off]
    for row in ok:  # the ranking's status says it (_decide: "looks worse")
        row["renders_further_off"] = row in further_off
    c = _lowest_of_its_size(eligible[0], eligible)
    cheaper = [row for row in ok[: ok.index(c)] if row not in within]
    # cheaper candidates within tolerance that the look passed over (by the verdict),
    # and those as cheap or cheaper that render further off at the same verdict (a row
    # as large with a lower error among them too: the lower error did not decide)
    looks_worse = [r for r in ok[: ok.index(c)] if r in within and r not in eligible
                   and r not in further_off]
    renders_worse = [r for r in further_off if ok.index(r) < ok.index(c)
                     or r.get("n_params") == c.get("n_params")]
    said = ([f"reads {c.get('verdict')}"] if looks_worse else []) + (
        [f"renders within {LOOK_WINDOW_DB:g} dB of the best-looking of those"]
        if renders_worse else [])
    reads = " that " + " and ".join(said) if said else ""
    if c is best and (looks_worse or renders_worse):
        why = (f"Chose {c['model']}: the best log_rmse ({_fmt(c['log_rmse'])}) and the "
               f"cheapest candidate within tolerance {_fmt(tolerance)} of it{reads}")
    elif c is best:
        why = (f"Chose {c['model']}: the best log_rmse ({_fmt(c['log_rmse'])}) and no cheaper "
               f"candidate within tolerance {_fmt(tolerance)} of it")
    else:
        why = (f"Chose {c['model']}: the cheapest candidate within tolerance {_fmt(tolerance)} "
               f"of the best ({best['model']}, log_rmse {_fmt(best['log_rmse'])}){reads}: its "
               f"log_rmse {_fmt(c['log_rmse'])} is {_fmt(c['excess'])} above it in quadrature")
    if cheaper:
        why += "; cheaper ones are further off (" + ", ".join(
            f"{r['model']} +{_fmt(r['excess'])}" for r in cheaper) + ")"
    if looks_worse:
        why += ("; cheaper ones within tolerance read worse (" + ", ".join(
            f"{r['model']} {_look_words(r)}" for r in looks_worse)
            + ": their PSNR, brightness or colour past the verdict's thresholds, "
            "quality.reason)")
    if renders_worse:
        why += ("; cheaper ones within tolerance that read as well render more than "
                f"{LOOK_WINDOW_DB:g} dB below the best-looking of those ({top_row['model']}, "
                f"{_psnr(top_row):.1f} dB): " + ", ".join(
                    f"{r['model']} {_psnr(r):.1f} dB" for r in renders_worse))
    same_size = [r for r in eligible if r is not c and r.get("n_params") == c.get("n_params")]
    if same_size:
        why += ("; as cheap and within tolerance too, but with a higher error: " + ", ".join(
            f"{r['model']} {_fmt(r['log_rmse'])}" for r in same_size))
    return c, prefix + why + "."


#: auto's rule under the render loss: the cheapest candidate whose sphere render is
#: within this many dB of the best-looking candidate's (the loss measures a picture,
#: so the choice does too; 0.5 dB is below what a viewer tells apart side by side).
RENDER_TOLERANCE_DB = ALIKE_DB


def _look_words(row: dict) -> str:
    """A row's verdict, and its radiance verdict where that one is worse."""
    shown, radiance = row.get("verdict"), row.get("radiance_verdict")
    if radiance in VERDICT_ORDER and shown in VERDICT_ORDER and (
            VERDICT_ORDER.index(radiance) > VERDICT_ORDER.index(shown)):
        return f"{shown}, {radiance} in radiance"
    return str(shown)


def _look_mark(row: dict) -> str:
    """A row's verdict in the ranking's column, starred where its radiance verdict is
    worse (:func:`_look_words`): alum-bronze's beckmann read "good" there, passed over
    for a "visible" ggx, and nothing in the table said why."""
    words = _look_words(row)
    return f"{row.get('verdict')}*" if words != str(row.get("verdict")) else (
        row.get("verdict") or "-")


def _psnr(row: dict) -> float:
    """What the render rule ranks a row by: its sphere under the render loss's eight
    lights (``views_psnr_db``) where measured, else its own ``psnr_db`` (two lights).
    On two lights, fits of blue-rubber, teflon and dark-red-paint by gltf_pbr and
    gltf_clearcoat rendered 0.1-1.5 dB above ggx's and 5-9 dB below it under
    bench.render_loss's independent lights; on the eight, 3-6 dB below, as there."""
    p = row.get("views_psnr_db")
    if p is None:
        p = row.get("psnr_db")
    return p if isinstance(p, int | float) and math.isfinite(p) else -math.inf


def _measure_words(row: dict) -> str:
    if row.get("views_psnr_db") is not None:
        return "its sphere renders under the render loss's eight lights (views_psnr_db)"
    return "its sphere render (psnr_db)"


def _views_text(row: dict) -> str:
    p = row.get("views_psnr_db")
    return "-" if p is None else f"{p:.1f}"


def _finite_or_none(x: float) -> float | None:
    return x if math.isfinite(x) else None


#: The verdicts (``brdffit.fitting.quality``), best first; a row without one (a fit
#: whose look could not be judged) ranks with "poor".
VERDICT_ORDER = VERDICTS


#: The tolerance rule's look, in dB: of the candidates within the tolerance that read the
#: best verdict, those that render more than this below the best-looking of them are
#: passed over. The verdict is a class: within one, a cheaper fit within the tolerance
#: could render several dB further off (on the 100 MERL under the log loss, ggx over
#: ggx2 on color-changing-paint1, 7.7 dB worse in bench.render_loss's independent
#: render). Replayed on the design half (bench.auto_rows): 6 of auto's choices change,
#: all closer there (+0.6 to +7.7 dB), 13 with layers (11 closer, none further off);
#: on the check half 8 and 14, none further off.
LOOK_WINDOW_DB = 1.0

#: How much worse (dB) than the best-looking candidate one with a better verdict may
#: render and still be preferred: 3 dB, twice the squared error. Beyond it the PSNR
#: gap is itself a visible difference, and the worse verdict (a brightness or colour
#: threshold crossed) no longer outweighs it.
VERDICT_WINDOW_DB = 3.0


def _verdict_rank(row: dict) -> int:
    """The worse of the row's verdict (the picture, its brightness as displayed) and its
    ``radiance_verdict`` (the lit sphere's light, its highlight's included): a fit whose
    highlight holds 0.6 stops too little light can look right at the table's exposure
    and not under another light. Ranked by the displayed verdict alone, auto with layers
    chose 5 of 100 MERL materials' fits 1-6 dB worse in bench.render_loss's independent
    render (red-metallic-paint's beckmann over ggx2: -5.2 dB), 2 better."""
    ranks = [VERDICT_ORDER.index(v) if v in VERDICT_ORDER else len(VERDICT_ORDER) - 1
             for v in (row.get("verdict"), row.get("radiance_verdict", row.get("verdict")))]
    return max(ranks)


def choose_by_look(ok: list[dict], tolerance_db: float = RENDER_TOLERANCE_DB,
                   ) -> tuple[dict, str]:
    """The render rule: among the fitted rows ``ok`` (cheapest first) that render within
    :data:`VERDICT_WINDOW_DB` of the best-looking, those with the best verdict any of
    them has; of those, the cheapest whose PSNR (:func:`_psnr`: ``views_psnr_db``, the
    render loss's eight lights, where measured) is within ``tolerance_db`` of the
    best of them; among candidates as large, the better-looking. The verdict
    comes first because it is what the chosen fit will say of itself: a higher PSNR
    with a brightness or colour shift the verdict calls poor is not the better look
    (five metals chose Mitsuba's dielectric principled, poor, over a visible fit).
    Sets each row's ``excess`` (dB below the best-looking of them all) and ``rank``
    (by PSNR). Returns the row and the reason, in words."""
    best_row = max(ok, key=_psnr)
    top = _psnr(best_row)
    for row in ok:
        row["excess"] = top - _psnr(row) if math.isfinite(top) else 0.0
    for i, row in enumerate(sorted(ok, key=lambda row: -_psnr(row))):
        row["rank"] = i + 1
    # the verdicts of the candidates that render within VERDICT_WINDOW_DB of the best
    window = [row for row in ok if not math.isfinite(top) or _psnr(row) >= top - VERDICT_WINDOW_DB]
    best_verdict = min(_verdict_rank(row) for row in window)
    judged = [row for row in window if _verdict_rank(row) == best_verdict]
    if _verdict_rank(best_row) > best_verdict:  # the best-looking reads worse
        passed_over = best_row
        best_row = max(judged, key=_psnr)
    else:
        passed_over = None
    within = [row for row in judged if _psnr(best_row) - _psnr(row) <= tolerance_db]
    first = within[0]
    same = [row for row in within if row.get("n_params") == first.get("n_params")]
    c = max(same, key=_psnr)
    if c is best_row:
        why = (f"Chose {c['model']} by {_measure_words(c)}: "
               f"the best-looking candidate ({_psnr(c):.1f} dB) and no cheaper one within "
               f"{tolerance_db:g} dB of it")
    else:
        why = (f"Chose {c['model']} by {_measure_words(c)}: "
               f"the cheapest candidate within {tolerance_db:g} dB of the best-looking "
               f"({best_row['model']}, {_psnr(best_row):.1f} dB): it renders at "
               f"{_psnr(c):.1f} dB")
    if passed_over is not None:
        why += (f", among the candidates that look {VERDICT_ORDER[best_verdict]}: "
                f"{passed_over['model']} renders closer ({_psnr(passed_over):.1f} dB) but "
                f"reads {VERDICT_ORDER[_verdict_rank(passed_over)]} (its brightness, as "
                "displayed or in the light its highlight holds, its colour or its "
                "highlight's shape is further off, quality.reason)")
    cheaper = [row for row in ok[: ok.index(c)] if row not in within and row in judged]
    if cheaper:
        why += "; cheaper ones look further off (" + ", ".join(
            f"{r['model']} {_psnr(r):.1f} dB" for r in cheaper) + ")"
    return c, why + "."


def _layer_gains(ok: list[dict], rule: str = "log_rmse") -> None:
    """Each fitted row whose model was fitted from another candidate's fit (a layer
    over its base: gltf_clearcoat over gltf_pbr; ggx2's second lobe over ggx) gets
    ``over_parent``: that candidate, the log_rmse ratio and the PSNR gain (dB), what
    its layer bought; ``no_gain`` by what the ``rule`` ranks (the render's PSNR under
    the render loss, which does not minimise log_rmse: color-changing-paint3's ggx2
    rendered 0.8 dB above ggx at twice its log_rmse, and was said to gain nothing)."""
    by_name = {row["model"]: row for row in ok}
    for row in ok:
        parent = by_name.get(models.get(row["model"]).parent)
        if parent is None:
            continue
        ratio = (row["log_rmse"] / parent["log_rmse"] if parent["log_rmse"] > 0
                 else (1.0 if row["log_rmse"] == 0 else None))
        gain = _psnr(row) - _psnr(parent)
        no_gain = (gain < NO_GAIN_DB if rule == "render_psnr_db" and math.isfinite(gain)
                   else ratio is not None and ratio > 1.0 - NO_GAIN)
        row["over_parent"] = {"model": parent["model"], "log_rmse_ratio": ratio,
                              "psnr_gain_db": gain if math.isfinite(gain) else None,
                              "no_gain": no_gain}


#: A richer candidate whose log_rmse is within this fraction of its base's gained
#: nothing (``over_parent.no_gain``, printed "nested: no gain"): its lobe or layer
#: collapsed, or its parent fitted exactly (the fit's ``notes`` then say so).
NO_GAIN = 1e-3
#: The same under the render rule, in the render's PSNR: an image error within 0.1% of
#: its base's (0.0087 dB).
NO_GAIN_DB = -20.0 * math.log10(1.0 - NO_GAIN)

#: How much worse (dB) than the fit without it a layered candidate may render and still
#: be chosen: a layer is taken where the rule says it gains and its render agrees.
LAYER_RENDER_SLACK_DB = 0.5
#: How much higher (a fraction) than the fit without it a layered candidate's log_rmse
#: may be, under the log_rmse rule: a layer at zero weight is that base, so a layered
#: fit never loses to it by more (as ggx2 to ggx: bench.real_materials' NESTED_SLACK).
LAYER_LOG_RMSE_SLACK = 1e-3


def _why_not_the_layer(chosen: dict, base: dict, parent: dict | None, rule: str) -> str:
    """Why the layered row ``chosen`` gives way to ``base``, the rule's choice among the
    candidates without a layer (empty where it does not). ``parent`` is the fit its
    layer was added to."""
    gain = (chosen.get("over_parent") or {}).get("psnr_gain_db")
    if parent is not None and gain is not None and gain < -LAYER_RENDER_SLACK_DB:
        return (f"{chosen['model']} passes the rule but renders {-gain:.1f} dB worse than "
                f"its base {parent['model']} ({_psnr(chosen):.1f} against "
                f"{_psnr(parent):.1f} dB): a layer is taken only where its render agrees")
    rendered = math.isfinite(_psnr(chosen)) and math.isfinite(_psnr(base))
    if rule == "render_psnr_db":
        if (_verdict_rank(chosen) < _verdict_rank(base) or not rendered
                or _psnr(chosen) > _psnr(base) + RENDER_TOLERANCE_DB):
            return ""
        closer = (f"renders only {_psnr(chosen) - _psnr(base):.1f} dB closer than"
                  if _psnr(chosen) > _psnr(base) else "renders no closer than")
        return (f"{chosen['model']} {closer} {base['model']} "
                f"({_psnr(chosen):.1f} against {_psnr(base):.1f} dB), the choice among the "
                f"candidates without a layer, within the rule's {RENDER_TOLERANCE_DB:g} dB, "
                f"and reads no better ({_look_words(chosen)}): its layer is not taken")
    if chosen["log_rmse"] > (1.0 + LAYER_LOG_RMSE_SLACK) * base["log_rmse"]:
        return (f"{chosen['model']} passes the rule at log_rmse {_fmt(chosen['log_rmse'])}, "
                f"above {_fmt(base['log_rmse'])} of {base['model']}, the choice among the "
                "candidates without a layer: a layer is taken only where the fit with it "
                "is no further off than the fit without it")
    if rendered and _psnr(chosen) < _psnr(base) - LAYER_RENDER_SLACK_DB:
        return (f"{chosen['model']} passes the rule but renders "
                f"{_psnr(base) - _psnr(chosen):.1f} dB worse than {base['model']}, the "
                f"choice among the candidates without a layer ({_psnr(chosen):.1f} against "
                f"{_psnr(base):.1f} dB): a layer is taken only where its render agrees")
    return ""


def _layer_held_to_its_rule(chosen: dict, reason: str, ok: list[dict], rule: str,
                            tolerance: float, budget: float | None, by_look: bool,
                            ) -> tuple[dict, str]:
    """:func:`_layer_no_worse_than_without`, the choice without a layer made by the rule
    that chose (its tolerance worked out on those rows: :func:`_within_noise`); not where
    a budget was met, which decides alone (the cheapest candidate under it, layered or
    not: a choice without a layer could miss it)."""
    if budget is not None and any(row["log_rmse"] <= budget for row in ok):
        return chosen, reason
    return _layer_no_worse_than_without(
        chosen, reason, ok, rule,
        lambda rows: _by_rule(rows, rule, tolerance, budget, by_look)[0])


def _layer_no_worse_than_without(chosen: dict, reason: str, ok: list[dict], rule: str,
                                 choose_among: Callable[[list[dict]], dict],
                                 ) -> tuple[dict, str]:
    """``chosen``, or what the rule chooses among the candidates without a layer
    (``choose_among`` on copies of those rows: the ranking's rows keep their ranks)
    where ``chosen`` has a layer (a coat, a sheen: ``AbstractBRDFModel.layers``) and
    is worse than that choice; the reason says so. Worse is:

    - under either rule, rendering more than :data:`LAYER_RENDER_SLACK_DB` worse than
      the base its layer was added to: under the log loss a layer can buy log_rmse at
      grazing bins and cost the look;
    - under the render rule, reading no better and rendering no more than the rule's
      :data:`RENDER_TOLERANCE_DB` closer than the choice without a layer: the rule's
      0.5 dB window otherwise lets a layered model with fewer values than ggx2
      (principled_clearcoat's 9 against 12) win on a render no closer, a layer that
      bought nothing the render loss's lights saw; and a layer within that window
      bought a look the rule calls alike, fitted to the very lights it is measured
      under (red-fabric2's gltf_sheen, 0.3 dB closer than generalized_schlick under
      the render loss's lights, rendered 2.7 dB further off under bench.render_loss's
      independent ones: its sheen missed the rim light's forward scatter);
    - under the log_rmse rule, a log_rmse above that choice's by more than
      :data:`LAYER_LOG_RMSE_SLACK`, or a render more than :data:`LAYER_RENDER_SLACK_DB`
      worse: a cheaper layered model within the tolerance otherwise replaces a closer
      fit without a layer.

    The fallback is that choice, not the layer's own base: black-oxidized-steel's
    gltf_clearcoat gave way to gltf_pbr (log_rmse 0.0104) where the choice without a
    layer was generalized_schlick (0.0082). On the 100 MERL under the log loss this
    leaves no material with log_rmse above 1.001x, or more than 0.5 dB worse in
    bench.render_loss's independent render, than auto among the candidates without a
    layer (4 and 3 before; bench.auto_layers)."""
    if not models.get(chosen["model"]).layers:
        return chosen, reason
    without = [copy.deepcopy(row) for row in ok if not models.get(row["model"]).layers]
    if not without:
        return chosen, reason
    by_name = {row["model"]: row for row in ok}
    base = by_name[choose_among(without)["model"]]
    parent = by_name.get((chosen.get("over_parent") or {}).get("model"))
    why = _why_not_the_layer(chosen, base, parent, rule)
    if not why:
        return chosen, reason
    figures = [f"log_rmse {_fmt(base['log_rmse'])}"] if base.get("log_rmse") is not None else []
    figures.append(f"{_psnr(base):.1f} dB" if math.isfinite(_psnr(base))
                   else "its render not measured")
    figures.append(_look_words(base))
    return base, reason + (f" {why}, so {base['model']}, the choice without a layer "
                           f"({', '.join(figures)}), is chosen.")


def _all_poor_warning(ok: list[dict], loss: str = "render") -> str:
    """A sentence for the reason when every candidate looks poor (else empty). Under a
    loss other than the render loss, it does not say that no model here reproduces the
    material: each was fitted to that loss, not to the look (chrome: every candidate
    poor under the log loss, ggx2 good at 30.2 dB under the render loss)."""
    if not ok or any(row.get("verdict") != "poor" for row in ok):
        return ""
    if all(not math.isfinite(_psnr(row)) or _compared_too_little(row) for row in ok):
        # no candidate could be compared: not "the best render lambert, -inf dB", nor
        # the render loss, which fits the same unmeasured pixels (a table of grazing
        # bins alone, fitted exactly; one of 0.1% of its bins)
        return (" Warning: no candidate's look could be compared: the table measures "
                "none or too few of the sphere's pixels, so every verdict reads poor for "
                "want of a comparison, not for a measured difference; the ranking's "
                "log_rmse is what the table measures.")
    top = max(ok, key=_psnr)
    # the eight lights named: the chosen fit's verdict quotes its two-light sphere, and
    # black-obsidian read "the best render ggx2, 14.0 dB" above "sphere render 14.5 dB"
    lights = (" under the render loss's eight lights" if top.get("views_psnr_db") is not None
              else "")
    said = (f" Warning: every candidate looks poor beside the measurement (the best render "
            f"{top['model']}, {_psnr(top):.1f} dB{lights})")
    if loss != "render":
        return (f"{said}, each fitted to the {loss} loss, not to the light a picture "
                "shows: the render loss (--loss render) fits the look; the chosen fit's "
                "quality.next says what to try.")
    return f"{said}: no model here reproduces this material; the chosen fit's quality.next " \
        "says what to try."


def _compared_too_little(row: dict) -> bool:
    """Whether a row's verdict rests on too few of the sphere's pixels to compare
    (``quality.SPHERE_COMPARED_MIN``)."""
    share = row.get("sphere_measured")
    return share is not None and share < SPHERE_COMPARED_MIN


def _render_gains(chosen: dict, ok: list[dict], on_scene: bool = False) -> list[tuple]:
    """Every other candidate's render against the chosen one's, as measured gains
    with the candidate's size (``next`` advises those worth a step:
    :func:`brdffit.fitting.quality.with_measured_gains`)."""
    here = _psnr(chosen)

    def words(row: dict) -> str:
        held = " held-out" if row.get("log_rmse_basis") == "held_out" else ""
        # a candidate that stopped short of its optimum renders where it stopped (a
        # stalled ggx2 was advised for +1.2 dB without a word of it)
        stopped = "" if row.get("converged", True) else (
            f"; its fit did not converge ({row.get('result')}): refit it with more steps")
        # the verdicts as auto ranks them: the worse of the picture's and the light's
        reads = (f"; it reads {VERDICT_ORDER[_verdict_rank(row)]} where this fit reads "
                 f"{VERDICT_ORDER[_verdict_rank(chosen)]}" if better(row) else "")
        return (f"it renders {_psnr(row):.1f} dB against {here:.1f} dB {where}{reads};"
                f"{held} log_rmse {_fmt(row['log_rmse'])}{on}{stopped}")

    def better(row: dict) -> bool:
        return _verdict_rank(row) < _verdict_rank(chosen)

    # the sphere is rendered whole, where auto on a scene chose by the scene's bins
    # alone: a step must not read as auto contradicting its own choice
    where = ("on the whole sphere (auto's ranking; it chose on the scene's directions "
             "alone, which may not need the difference)" if on_scene
             else "on this table (auto's ranking)")
    on = " on the scene" if on_scene else ""

    return [(f"--model {row['model']}", words(row), _psnr(row) - here, row.get("n_params"),
             better(row))
            for row in ok if row is not chosen and math.isfinite(here)
            and math.isfinite(_psnr(row))]


def _lowest_of_its_size(first: dict, eligible: list[dict]) -> dict:
    """The cheapest eligible row is ``first``; candidates as large as it (beckmann and
    ggx, 8 values each) cost the same to store, so among those the lower error wins:
    registry order is not a reason to keep a worse fit."""
    size = first.get("n_params")
    same = [row for row in eligible if size is not None and row.get("n_params") == size]
    return min(same, key=lambda row: row["log_rmse"]) if same else first


#: Fits whose log_rmse differ by less than this are tied (far below any difference a
#: reader would act on); a tie goes to the model with fewer parameters.
TIE = 1e-6


def best(rows: list[dict]) -> tuple[dict, str]:
    """The one "best" rule for a list of fitted models (not ``auto``, which is
    :func:`choose`): the lowest ``log_rmse``; a tie goes to fewer parameters.
    ``rows`` are ranking rows (``model``, ``n_params``, ``log_rmse``, ``status``);
    returns the best row and the reason, in words."""
    fitted = [row for row in rows if row.get("status", "fitted") != "failed"]
    if not fitted:
        raise FitInputError("no model could be fitted")
    finite = [row for row in fitted if row.get("log_rmse") is not None
              and math.isfinite(row["log_rmse"])]
    if not finite:
        return fitted[0], (f"No fit has a finite log_rmse; {fitted[0]['model']} is shown "
                           "first as fitted.")
    lowest = min(row["log_rmse"] for row in finite)
    tied = [row for row in finite if row["log_rmse"] <= lowest + TIE]
    b = min(tied, key=lambda row: (row.get("n_params") or 0, row["log_rmse"]))
    if len(finite) == 1:
        return b, f"{b['model']}: the only model fitted (log_rmse {_fmt(b['log_rmse'])})."
    others = ", ".join(f"{row['model']} {_fmt(row['log_rmse'])}" for row in finite
                       if row is not b)
    held = " held-out" if b.get("log_rmse_basis") == "held_out" else ""
    return b, f"Best {b['model']}: the lowest{held} log_rmse ({_fmt(b['log_rmse'])}; {others})."


def chosen_result(results: list[dict]) -> dict:
    """The fit that stands for a set of stored fits of one table (result-schema
    dicts: a service job's, a batch table's): the one ``auto`` chose where one carries
    its ``selection``, else the best by :func:`best` (the lowest log_rmse, a tie to
    fewer parameters; an unknown model counts as the largest)."""
    if not results:
        raise FitInputError("no fits to choose from")
    for r in results:
        if r.get("selection"):
            return r
    rows = []
    for i, r in enumerate(results):
        try:  # from the models' descriptions, without JAX (the service's front asks)
            n_params = models.catalogue.n_params(r["model"])
        except models.UnknownModelError:  # stored by a version with another registry
            n_params = math.inf
        e = r["error"].get("log_rmse")
        rows.append({"model": r["model"], "n_params": n_params, "index": i,
                     "log_rmse": float("nan") if e is None else float(e)})
    return results[best(rows)[0]["index"]]


def _fit_mono(table, model, rgb_fit: FitResult, scene, tolerance, fit_options):
    """The chosen model refitted with a grey ks, started from its RGB fit."""
    from brdffit.models.mono_ks import MonoKs, specular_colour_specs

    mono_model = MonoKs(model)
    init = dict(rgb_fit.params)
    for s in specular_colour_specs(model):
        init[s.name] = float(np.mean(init[s.name]))
    r = fit_in_scene(table, mono_model, scene, init=init, **fit_options)
    err, rgb_err = r.error["log_rmse"], rgb_fit.error["log_rmse"]
    excess = math.sqrt(max(err**2 - rgb_err**2, 0.0))
    return {
        "model": mono_model.name,
        "n_params": mono_model.n_params,
        "params": r.params,
        "log_rmse": err,
        "full_log_rmse": r.full_table_error["log_rmse"] if scene is not None else err,
        "excess_over_rgb": excess,
        "accepted": bool(math.isfinite(err) and excess <= tolerance),
        "converged": r.converged,
        "fit": r,
    }


def _gain_words(gain: dict) -> str:
    ratio, db = gain["log_rmse_ratio"], gain["psnr_gain_db"]
    if gain.get("no_gain"):
        return "nested: no gain"
    return (("log_rmse " + ("-" if ratio is None else f"x{ratio:.3g}"))
            + (", PSNR " + ("-" if db is None else f"{db:+.1f} dB")))


def format_selection(sel: Selection, chosen_params: bool = True) -> str:
    """The ranking as a text table, then the reason; with ``chosen_params``, the chosen
    fit's parameters and how it looks (``brdffit fit --model auto`` prints the chosen fit
    in full after it instead: ``brdffit.cli.fit.format_result``)."""
    scene = sel.scene is not None
    held = any(r.get("log_rmse_basis") == "held_out" for r in sel.ranking)
    views = any(r.get("views_psnr_db") is not None for r in sel.ranking)
    # as wide as the longest name (standard_surface_dielectric: 27), no narrower than 14
    w = max([14, *(len(r["model"]) + 1 for r in sel.ranking)])
    head = (f"{'model':<{w}}{'k':>3} {'held-out' if held else 'log_rmse':>10} "
            + (f"{'full':>10} " if scene else "")
            # in the rule's units: dB below the best-looking under the render rule
            + f"{'excess dB' if sel.rule == 'render_psnr_db' else 'excess':>9} {'PSNR dB':>8} "
            + (f"{'8 lights':>8} " if views else "")
            + f"{'looks':>8} {'ns/eval':>8} {'BIC':>12}  status")
    lines = [f"{sel.table}: model selection ({sel.time_s:.1f} s)", head]
    for r in sel.ranking:
        if r["status"] == "failed":
            lines.append(f"{r['model']:<{w}}{r['n_params']:>3}  failed: "
                         f"{r.get('message', r.get('result'))}")
            continue
        lines.append(
            f"{r['model']:<{w}}{r['n_params']:>3} {r['log_rmse']:>10.3g} "
            + (f"{r['full_log_rmse']:>10.3g} " if scene else "")
            + f"{r['excess']:>9.3g} {r['psnr_db']:>8.1f} "
            + (f"{_views_text(r):>8} " if views else "")
            + f"{_look_mark(r):>8} "
            + f"{r['cost_ns']:>8.1f} {r['bic']:>12.4g}"
            + f"  {r['status']}" + ("" if r["converged"] else " (not converged)")
        )
    layers = [r for r in sel.ranking if r.get("over_parent")]
    if layers:
        lines.append("over their base: " + "; ".join(
            f"{r['model']} over {r['over_parent']['model']} "
            + _gain_words(r["over_parent"]) for r in layers))
    starred = [r for r in sel.ranking if r["status"] != "failed" and _look_mark(r).endswith("*")]
    if starred:
        # said as two verdicts and which one counts where: "* reads ggx good, visible in
        # radiance ... it ranks as the worse" left a newcomer asking whether the chosen
        # fit was good (the fit's summary below says the picture's verdict)
        lines.append("* " + "; ".join(
            f"{r['model']} looks {r.get('verdict')} as displayed, {r.get('radiance_verdict')} "
            "in radiance" for r in starred)
            + ": the light its highlight holds is further off than the picture shows (the "
            "row's radiance_verdict). The ranking counts the worse of the two; the fit's own "
            "verdict is the picture's")
    lines.append("")
    if held:
        from brdffit.fitting.samples import FOLDS

        lines.append(f"Ranked on the {FOLDS}-fold held-out log_rmse of the samples "
                     "(docs/measurements.md).")
    lines.append(sel.reason)
    if chosen_params:
        lines += _param_lines(sel.chosen, sel.row["params"])
        lines += describe(sel.fits[sel.chosen].quality if sel.chosen in sel.fits else None)
    if sel.mono is not None:
        lines += _param_lines(sel.mono["model"], sel.mono["params"])
    return "\n".join(lines)


def _param_lines(model: str, params: dict) -> list[str]:
    """"<model> params:", then a line per parameter (5 significant digits)."""
    lines = [f"{model} params:"]
    for name, v in params.items():
        val = ", ".join(f"{x:.5g}" for x in v) if isinstance(v, list) else f"{v:.5g}"
        lines.append(f"  {name:<6} = {val}")
    return lines
