"""What a fit request means, decided once: :class:`FitRequest`, :func:`run`, :class:`FitReport`.

Every shell (``brdffit fit``, the service's worker task, the batch's worker task,
the service's cost estimate) turns what it was given (flags, a JSON body, batch
arguments) into one :class:`FitRequest` and hands it to :func:`run`; none of them
interprets an option again. The request holds:

- ``models``: registry names, fitted each in turn, or ``("auto",)``: the
  selection's candidates are fitted and the cheapest good enough is chosen
  (``brdffit.selection``);
- ``options``: a :class:`~brdffit.fitting.options.FitOptions`, the one source of
  defaults and limits (its ``model`` field is what ``models`` came from);
- ``scene``: the directions a scene uses, or None;
- the selection rule (``options.tolerance``, ``options.budget``, ``candidates``,
  ``mono_ks``), meaningful with ``auto`` only: with a fixed model it is refused,
  not silently ignored.

:func:`run` returns a :class:`FitReport`: every fit made, and the chosen one by the
one rule there is (``brdffit.selection.choose`` for ``auto``, ``brdffit.selection.best``
for a list of models), with the ranking and the reason. The same table and request
give the same report through every door.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field

from brdffit import models as registry
from brdffit.errors import FitInputError
from brdffit.fitting.options import AUTO, DEFAULT_TOLERANCE, FitOptions
from brdffit.fitting.result import FitResult
from brdffit.fitting.scene import Scene
from brdffit.io.measurements import Measurements
from brdffit.io.merl import MerlTable
from brdffit.selection import DEFAULT_CANDIDATES, Selection, best, select

#: The version of :meth:`FitReport.to_dict`'s schema.
REPORT_SCHEMA = "brdffit.report/1"

#: ``progress(i, n, model, row)``: before model ``i`` of ``n`` is fitted (``row`` None)
#: and after (its ranking row: ``status`` ``"fitted"`` or ``"failed"``).
ModelProgress = Callable[[int, int, str, dict | None], None]


def _names(models) -> tuple[str, ...]:
    if isinstance(models, str):
        models = [models]
    names = tuple(dict.fromkeys(m.strip() for m in models if m.strip()))  # twice is once
    if not names:
        raise FitInputError("give at least one model, or auto")
    if AUTO in names:
        if len(names) > 1:
            raise FitInputError(f"auto chooses among its candidates; it cannot be listed "
                                f"beside other models ({', '.join(names)})")
        return names
    for name in names:
        registry.check_name(name)
    return names


@dataclass(frozen=True)
class FitRequest:
    """One fit request, checked on construction: a request that exists is one
    :func:`run` accepts (the table may still have too little to fit)."""

    models: tuple[str, ...]
    options: FitOptions = field(default_factory=FitOptions)
    scene: Scene | None = None
    candidates: tuple[str, ...] = DEFAULT_CANDIDATES
    mono_ks: bool = False

    def __post_init__(self):
        object.__setattr__(self, "models", _names(self.models))
        object.__setattr__(self, "candidates", tuple(self.candidates))
        if not isinstance(self.options, FitOptions):
            raise FitInputError(f"options must be FitOptions, got {type(self.options).__name__}")
        if self.options.model != self.models[0]:
            # ``models`` says what is fitted; ``options.model`` follows it, so that the
            # two never disagree (a batch built requests whose options named another)
            object.__setattr__(self, "options", self.options.replace(model=self.models[0]))
        if self.auto:
            if not self.candidates:
                raise FitInputError("auto needs at least one candidate model")
            for name in self.candidates:
                registry.check_name(name)
            return
        # The selection rule only chooses among auto's candidates: with a fixed model it
        # would be silently ignored, so it is refused, naming what to do instead.
        ignored = [f"{name} {value!r}" for name, value, default in (
            ("tolerance", self.options.tolerance, DEFAULT_TOLERANCE),
            ("budget", self.options.budget, None),
            ("candidates", list(self.candidates), list(DEFAULT_CANDIDATES)),
            ("mono_ks", self.mono_ks, False)) if value != default]
        if ignored:
            raise FitInputError(
                f"{', '.join(ignored)} choose among auto's candidates; with model "
                f"{', '.join(self.models)} they would be ignored: drop them, or fit model auto")

    @classmethod
    def of(cls, model="ggx", *, scene: Scene | None = None, candidates=None,
           mono_ks: bool = False, **options) -> FitRequest:
        """A request from Python values: ``FitRequest.of("auto", samples=4096)``.
        ``model`` is a name, ``"auto"`` or a list of names; ``options`` are
        :class:`FitOptions` fields."""
        names = _names(model)
        first = names[0]
        return cls(models=names, options=FitOptions.from_dict({**options, "model": first}),
                   scene=scene,
                   candidates=DEFAULT_CANDIDATES if candidates is None else tuple(candidates),
                   mono_ks=mono_ks)

    @classmethod
    def from_dict(cls, d: dict) -> FitRequest:
        """A request from its JSON form (:meth:`to_dict`; the service stores it so):
        ``{"models": [...], "options": {...}, "scene": {...} | null, "candidates":
        [...], "mono_ks": bool}``; missing keys take their defaults."""
        unknown = sorted(set(d) - {"models", "options", "scene", "candidates", "mono_ks"})
        if unknown:
            raise FitInputError(f"unknown request keys {unknown}")
        scene = d.get("scene")
        return cls.of(d.get("models", FitOptions().model),
                      scene=None if scene is None else Scene.from_dict(scene),
                      candidates=d.get("candidates"), mono_ks=bool(d.get("mono_ks", False)),
                      **{k: v for k, v in d.get("options", {}).items() if k != "model"})

    @classmethod
    def from_flat(cls, models, options: dict) -> FitRequest:
        """A request from ``models`` and one flat dict of option names with ``scene``,
        ``candidates`` and ``mono_ks`` among them: how the service stores a job."""
        options = dict(options)
        scene, candidates = options.pop("scene", None), options.pop("candidates", None)
        mono_ks = options.pop("mono_ks", False)
        return cls.from_dict({"models": models, "options": options, "scene": scene,
                              "candidates": candidates, "mono_ks": mono_ks})

    def to_dict(self) -> dict:
        options = self.options.to_dict()
        del options["model"]  # `models` says what is fitted
        return {"models": list(self.models), "options": options,
                "scene": None if self.scene is None else self.scene.to_dict(),
                "candidates": list(self.candidates), "mono_ks": self.mono_ks}

    @property
    def auto(self) -> bool:
        return self.models == (AUTO,)

    @property
    def fitted_models(self) -> tuple[str, ...]:
        """The models :func:`run` fits: the candidates for ``auto``."""
        return self.candidates if self.auto else self.models


@dataclass(frozen=True)
class FitReport:
    """What :func:`run` found: every fit made, the chosen one and why.

    ``fits`` holds each model's :class:`FitResult` in the order they were fitted
    (auto: cheapest first); ``failed`` each model that could not be fitted and why
    (e.g. a scene with too few bins for it); ``ranking`` one row per model (the
    selection's, for auto); ``chosen`` the fit the report stands for.
    """

    request: FitRequest
    fits: dict[str, FitResult]
    failed: dict[str, str]
    chosen: str
    reason: str
    ranking: list[dict]
    selection: Selection | None = field(default=None, repr=False)

    @property
    def chosen_fit(self) -> FitResult:
        """The chosen fit (auto's carries its ``selection``)."""
        return self.fits[self.chosen]

    def to_dict(self) -> dict:
        """Strict-JSON-ready: the request, the chosen model and the reason, the
        ranking, every fit in the result schema."""
        return {"schema": REPORT_SCHEMA, "request": self.request.to_dict(),
                "chosen": self.chosen, "reason": self.reason, "ranking": self.ranking,
                "failed": dict(self.failed),
                "results": [r.to_dict() for r in self.fits.values()]}


def run(table: MerlTable | Measurements, request: FitRequest, *,
        progress: ModelProgress | None = None, threads: int | None = None,
        measured_input: dict | None = None) -> FitReport:
    """Make the fits ``request`` asks for on ``table``; see the module docstring.

    Raises :class:`~brdffit.errors.FitInputError` when no model could be fitted;
    a model that could not be fitted beside others that could is in ``failed``.
    ``threads``: auto's candidates fitted at once (``brdffit.selection.select``).
    ``table`` may be a sample list (``brdffit.io.measurements.Measurements``): every
    fit is then made at its own directions (``brdffit.fitting.samples``) and carries
    its ``input``. ``measured_input``: where ``table`` was binned from samples, what
    that did (``brdffit.io.readers.read_table``): every fit carries it
    (``FitResult.input``; a sample fit's own keys win).
    """
    report = _run(table, request, progress, threads)
    if measured_input is None:
        return report
    fits = {name: dataclasses.replace(r, input={**measured_input, **(r.input or {})})
            for name, r in report.fits.items()}
    return dataclasses.replace(report, fits=fits)


def _run(table: MerlTable | Measurements, request: FitRequest, progress: ModelProgress | None,
         threads: int | None) -> FitReport:
    options = request.options
    if request.auto:
        sel = select(table, request.candidates, scene=request.scene, mono_ks=request.mono_ks,
                     progress=progress, threads=threads, **options.selection_keywords(),
                     **options.fit_keywords())
        failed = {row["model"]: row.get("message", row.get("result", ""))
                  for row in sel.ranking if row["status"] == "failed"}
        return FitReport(request=request, fits=dict(sel.fits), failed=failed,
                         chosen=sel.chosen, reason=sel.reason, ranking=sel.ranking,
                         selection=sel)
    from brdffit.fitting.scene import fit_in_scene
    from brdffit.models.base import sharing_where_it_pays

    fits: dict[str, FitResult] = {}
    failed: dict[str, str] = {}
    rows = []
    names = request.models
    # models of one family in the list (ggx and beckmann, ...) share their programs
    to_fit = sharing_where_it_pays([registry.get(name) for name in names])
    for i, (name, model) in enumerate(zip(names, to_fit, strict=True)):
        if progress is not None:
            progress(i, len(names), name, None)
        row = {"model": name, "n_params": model.n_params}
        try:
            r = fit_in_scene(table, model, request.scene, **options.fit_keywords())
        except FitInputError as e:
            failed[name] = str(e)
            row.update(status="failed", message=str(e))
        else:
            fits[name] = r
            # a sample list's fits compare held out, as auto's do (brdffit.selection)
            held = r.error.get("held_out_log_rmse")
            row.update(status="fitted",
                       log_rmse=r.error["log_rmse"] if held is None else held,
                       log_rmse_basis="in_sample" if held is None else "held_out",
                       converged=r.converged,
                       result=r.result, fit_time_s=r.time_s,
                       verdict=(r.quality or {}).get("verdict"))
        rows.append(row)
        if progress is not None:
            progress(i, len(names), name, dict(row))
    if not fits:
        raise FitInputError("; ".join(failed.values()) if len(failed) == 1 else
                            "no model could be fitted: "
                            + "; ".join(f"{m}: {why}" for m, why in failed.items()))
    chosen, reason = best(rows)
    return FitReport(request=request, fits=fits, failed=failed, chosen=chosen["model"],
                     reason=reason, ranking=rows)

