"""What a fit request means, decided once: :class:`FitRequest`, :func:`run`, :class:`FitReport`.

Every shell (``brdffit fit``, ``brdffit batch``, the service's route and worker, the
service's cost estimate, the client) turns what it was given (flags, a JSON body,
Python values) into one :class:`FitRequest` and hands it to :func:`run` (the batch:
``run_batch(inputs, request)``); none of them interprets an option again. Its one
serialised form is :meth:`FitRequest.to_dict` (schema ``brdffit.request/1``): the
service's request body is generated from it, and a job and a batch store it. The
request holds:

- ``models``: registry names, fitted each in turn, or ``("auto",)``: the rule's
  candidates are fitted and the cheapest good enough is chosen (``brdffit.selection``);
- ``options``: a :class:`~brdffit.fitting.options.FitOptions`, the one source of fit
  defaults and limits (the keywords of ``brdffit.fit``);
- ``scene``: the directions a scene uses, or None;
- ``rule``: how auto chooses (:class:`~brdffit.fitting.options.SelectionRule`:
  tolerance, budget, candidates, mono_ks), present exactly when ``models`` is auto:
  with a fixed model a rule is refused, not silently ignored.

:func:`run` returns a :class:`FitReport`: every fit made, and the chosen one by the
one rule there is (``brdffit.selection.choose`` for ``auto``, ``brdffit.selection.best``
for a list of models), with the ranking and the reason. The same table and request
give the same report through every door.
"""

from __future__ import annotations

import dataclasses
import numbers
from collections.abc import Callable
from dataclasses import dataclass, field

from brdffit import models as registry
from brdffit.errors import FitInputError
from brdffit.fitting.options import AUTO, DEFAULT_MODEL, FitOptions, SelectionRule, names
from brdffit.fitting.result import FitResult
from brdffit.fitting.scene import Scene
from brdffit.io.measurements import Measurements
from brdffit.io.merl import MerlTable
from brdffit.selection import Selection, best, select

#: The version of :meth:`FitReport.to_dict`'s schema.
REPORT_SCHEMA = "brdffit.report/1"
#: The version of :meth:`FitRequest.to_dict`'s schema: the wire and storage form.
REQUEST_SCHEMA = "brdffit.request/1"
_REQUEST_KEYS = ("schema", "models", "options", "scene", "rule")

#: ``progress(i, n, model, row)``: before model ``i`` of ``n`` is fitted (``row`` None)
#: and after (its ranking row: ``status`` ``"fitted"`` or ``"failed"``).
ModelProgress = Callable[[int, int, str, dict | None], None]


def split_names(text: str, what: str = "models") -> list[str]:
    """The names of a comma-separated list (``"ggx,beckmann"``, as a command line gives
    them), each stripped; blank text is no names. An empty item (``"ggx,,lambert"``, a
    comma at an end) is refused, naming ``what``: a name lost there (a typo, a variable
    that was empty) was dropped silently, and the fit ran without it."""
    if not text.strip():
        return []
    names = [n.strip() for n in text.split(",")]
    if not all(names):
        raise FitInputError(f"{what} {text!r} has an empty item (two commas in a row, or one "
                            "at an end): separate the names by single commas")
    return names


def _plain(value):
    """A numpy scalar as the Python number it holds (``np.int64(3)``, a seed from
    ``rng.integers``, is an integer); anything else as it is, checked by its option.
    The request's JSON form holds only Python numbers."""
    if isinstance(value, bool) or not isinstance(value, numbers.Number):
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return float(value)
    return value


def _names(models) -> tuple[str, ...]:
    if isinstance(models, str):
        models = split_names(models)  # "ggx,beckmann", as a command line gives them
    if not isinstance(models, list | tuple) or not all(isinstance(m, str) for m in models):
        raise FitInputError(f"models must be a model name or a list of them, got {models!r}")
    if not all(m.strip() for m in models):  # a list's blank name was lost as a string's
        raise FitInputError(f"models {list(models)!r} has an empty name: give each model's "
                            "name, or leave the item out")
    names = tuple(dict.fromkeys(m.strip() for m in models))  # twice is once
    if not names:
        raise FitInputError("give at least one model, or auto")
    if AUTO in names:
        if len(names) > 1:
            raise FitInputError(f"auto chooses among its candidates; it cannot be listed "
                                f"beside other models ({', '.join(names)}): add them to "
                                "the rule's candidates instead")
        return names
    for name in names:
        registry.check_name(name)
    return names


@dataclass(frozen=True)
class FitRequest:
    """One fit request, checked on construction: a request that exists is one
    :func:`run` accepts (the table may still have too little to fit)."""

    models: tuple[str, ...] = (DEFAULT_MODEL,)
    options: FitOptions = field(default_factory=FitOptions)
    scene: Scene | None = None
    #: how auto chooses; None with fixed models. ``FitRequest(("auto",))`` takes the
    #: default rule.
    rule: SelectionRule | None = None

    def __post_init__(self):
        object.__setattr__(self, "models", _names(self.models))
        if not isinstance(self.options, FitOptions):
            raise FitInputError(f"options must be FitOptions, got {type(self.options).__name__}")
        if self.scene is not None and not isinstance(self.scene, Scene):
            raise FitInputError(f"scene must be a Scene, got {type(self.scene).__name__}")
        if self.rule is not None and not isinstance(self.rule, SelectionRule):
            raise FitInputError(f"rule must be a SelectionRule, got {type(self.rule).__name__}")
        if self.auto:
            if self.rule is None:
                object.__setattr__(self, "rule", SelectionRule())
            return
        if self.rule is not None:
            # The rule only chooses among auto's candidates: with a fixed model it
            # would be silently ignored, so it is refused, naming what to do instead.
            given = [f"{k} {v!r}" for k, v in self.rule.to_dict().items()
                     if v != SelectionRule().to_dict()[k]]
            what = f"the selection rule ({', '.join(given)})" if given else "a selection rule"
            raise FitInputError(
                f"{what} chooses among auto's candidates; with model "
                f"{', '.join(self.models)} it would be ignored: drop it, or fit model auto")

    @classmethod
    def of(cls, model=DEFAULT_MODEL, *, scene: Scene | dict | None = None,
           **keywords) -> FitRequest:
        """A request from Python values: ``FitRequest.of("auto", samples=4096,
        tolerance=0.01)``. ``model`` is a name, ``"auto"`` or a list of names;
        ``keywords`` are :class:`FitOptions` fields and, for auto,
        :class:`SelectionRule` fields (a rule field with another model is refused)."""
        keywords = {k: _plain(v) for k, v in keywords.items()}
        rule_names = set(names(SelectionRule))
        rule = {k: v for k, v in keywords.items() if k in rule_names}
        fit_options = {k: v for k, v in keywords.items() if k not in rule_names}
        return cls(models=_names(model), options=FitOptions.from_dict(fit_options),
                   scene=Scene.from_dict(scene) if isinstance(scene, dict) else scene,
                   rule=SelectionRule.from_dict(rule) if rule else None)

    @classmethod
    def from_dict(cls, d: dict) -> FitRequest:
        """A request from its one serialised form (:meth:`to_dict`): ``{"schema":
        "brdffit.request/1", "models": [...] | "name", "options": {...}, "scene":
        {...} | null, "rule": {...} | null}``; missing keys take their defaults."""
        if not isinstance(d, dict):
            raise FitInputError(f"a fit request is a JSON object, got {type(d).__name__}")
        unknown = sorted(set(d) - set(_REQUEST_KEYS))
        if unknown:
            raise FitInputError(f"unknown request keys {unknown}; a request has "
                                f"{', '.join(_REQUEST_KEYS)}")
        schema = d.get("schema", REQUEST_SCHEMA)
        if schema != REQUEST_SCHEMA:
            raise FitInputError(f"request schema {schema!r}; this brdffit reads "
                                f"{REQUEST_SCHEMA!r}")
        for key in ("options", "scene", "rule"):
            if d.get(key) is not None and not isinstance(d[key], dict):
                raise FitInputError(f"{key} must be a JSON object or null, got {d[key]!r}")
        scene, rule = d.get("scene"), d.get("rule")
        return cls(models=_names(d.get("models", DEFAULT_MODEL)),
                   options=FitOptions.from_dict(d.get("options") or {}),
                   scene=None if scene is None else Scene.from_dict(scene),
                   rule=None if rule is None else SelectionRule.from_dict(rule))

    def to_dict(self) -> dict:
        """The request's one serialised form (strict JSON): what the service's body is,
        what a job and a batch store."""
        return {"schema": REQUEST_SCHEMA, "models": list(self.models),
                "options": self.options.to_dict(),
                "scene": None if self.scene is None else self.scene.to_spec(),
                "rule": None if self.rule is None else self.rule.to_dict()}

    def fit_key(self) -> str:
        """What makes two fits of one model equal: the fit options and the scene
        (``FitOptions.key_of``): a batch resumes a fit whose key, table and model match."""
        return FitOptions.key_of(self.fit_record())

    def fit_record(self) -> dict:
        """The fit keywords and the scene's identity (``Scene.key``), as a batch records
        them beside each fit."""
        scene = {} if self.scene is None else {"scene": self.scene.key()}
        return {**self.options.fit_keywords(), **scene}

    def replace(self, **changes) -> FitRequest:
        return dataclasses.replace(self, **changes)

    @property
    def auto(self) -> bool:
        return self.models == (AUTO,)

    @property
    def fitted_models(self) -> tuple[str, ...]:
        """The models :func:`run` fits: the rule's candidates for ``auto``."""
        return self.rule.candidates if self.auto else self.models


def legacy_request(models, flat: dict) -> dict:
    """A :meth:`FitRequest.to_dict`-shaped dict from the form before it (``models``
    and one flat dict of options holding ``scene``, ``candidates``, ``mono_ks``,
    ``tolerance`` and ``budget`` beside the fit's; a ``model`` key in it ignored,
    ``models`` says what is fitted): how the service stored jobs and took bodies
    before ``brdffit.request/1``. Only rearranged; :meth:`FitRequest.from_dict`
    checks it."""
    if isinstance(models, str):
        models = [models]
    if not isinstance(flat, dict):  # not the earlier form either: left for the checks
        return {"schema": REQUEST_SCHEMA, "models": models, "options": flat}
    flat = dict(flat)
    flat.pop("model", None)
    rule = {k: flat.pop(k) for k in names(SelectionRule) if k in flat}
    scene = flat.pop("scene", None)
    auto = isinstance(models, list | tuple) and list(models) == [AUTO]
    # the old form sent the rule's defaults with any model; only auto has a rule now
    if not auto:
        rule = {k: v for k, v in rule.items() if v not in (None, False)
                and not (k == "tolerance" and v == SelectionRule().tolerance)}
    return {"schema": REQUEST_SCHEMA,
            "models": list(models) if isinstance(models, list | tuple) else models,
            "options": flat, "scene": scene, "rule": rule if auto or rule else None}


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
        sel = select(table, scene=request.scene, progress=progress, threads=threads,
                     **request.rule.selection_keywords(), **options.fit_keywords())
        failed = {row["model"]: row.get("message", row.get("result", ""))
                  for row in sel.ranking if row["status"] == "failed"}
        return FitReport(request=request, fits=dict(sel.fits), failed=failed,
                         chosen=sel.chosen, reason=sel.reason, ranking=sel.ranking,
                         selection=sel)
    from brdffit.fitting.pipeline import fit_in_scene
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

