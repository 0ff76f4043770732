"""What a fit returns: :class:`FitResult`, plain Python values and no JAX.

Kept apart from ``brdffit.fitting.pipeline`` so that a process that only reads results
(``brdffit.client``, a batch report) need not import JAX to hold one.

``FitResult.to_dict()`` is *the* result schema (docs/results.md): ``brdffit fit
--json`` prints it, for a fixed model and for ``auto`` alike, the service returns it
for every fit of a job, and the batch store keeps it beside each fit. Its first
key, ``schema``, names the version; a change of a key's meaning is a new version.
"""

from __future__ import annotations

import numbers
from dataclasses import MISSING, asdict, dataclass, fields

from brdffit import jsonout
from brdffit.errors import ResultFormatError

#: The status of a finished fit, as ``FitResult.result`` names it. Only the first
#: means the optimality test holds (``brdffit.fitting.solver``).
STATUS_NAMES = ("successful", "nonlinear_max_steps_reached", "stalled", "nonfinite")

#: The version of the result schema that :meth:`FitResult.to_dict` writes. 2: the
#: ``quality`` block's ``colour_shift`` is a CIEDE2000 figure (it was a per-channel
#: relative error) beside ``brightness_stops``, and the block has ``next``. 3: the
#: key ``input`` (a fit of samples: what binning them did), which a reader of version
#: 2 refuses as unknown. 4: a sample list fitted at its own directions: ``error``'s
#: ``held_out_*``, ``quality.basis``, and ``input``'s ``fitted_at``, ``used``,
#: ``held_out``, ``coverage``, ``identifiability``, ``spectral``. 5: ``notes`` (where the
#: fit did other than asked), and ``starts`` of a fit of every bin counts the starts of
#: the subsample fit whose optimum every bin polished (it said 1). Older results read
#: with no notes. 6: ``quality.displayed_brightness_stops`` (and the grazing light's),
#: which the verdict judges instead of ``brightness_stops`` (the radiance figure, still
#: reported); an older result's verdict stays as it was stored. 7: the grazing light's
#: ``measured_colour_turn`` (how far the table's own colour turns from the key light),
#: which ``next`` reads; an older result's ``next`` stays as it was stored. 8:
#: ``quality.displayed_colour_shift`` (and the grazing light's): the colour of the
#: picture the verdict judges, which it weighs with ``colour_shift`` (the worse of the
#: two), and a table fit's ``quality.sphere_measured`` (below 0.9 a good verdict reads
#: visible); an older result's verdict stays as it was stored. 9: a table fit's
#: ``quality.highlight`` (the fit against the bins where the table resolves its
#: highlight: a spike the table does not hold reads visible); an older result's verdict
#: stays as it was stored.
SCHEMA = "brdffit.fit/9"
#: The versions :meth:`FitResult.from_dict` reads: a result of version 1 reads with
#: its quality block as it was stored (the per-channel ``colour_shift``); one of
#: versions 1 and 2 has no ``input`` (a MERL table's fit: null).
READS = (SCHEMA, "brdffit.fit/8", "brdffit.fit/7", "brdffit.fit/6", "brdffit.fit/5",
         "brdffit.fit/4", "brdffit.fit/3", "brdffit.fit/2", "brdffit.fit/1")


@dataclass(frozen=True)
class FitResult:
    """The outcome of one fit, failed or not, as plain Python values.

    ``params`` uses the docs/models.md names: RGB parameters are lists of 3 floats,
    shape parameters floats. ``error`` holds ``log_rmse`` (see ``brdffit.fitting.loss``)
    and friends, on the bins the fit was judged on (the whole table, or the scene's
    directions). ``result`` says how the solve ended
    (:data:`STATUS_NAMES`): ``"successful"`` only where the optimality
    test holds at the returned point, else ``"nonlinear_max_steps_reached"``,
    ``"stalled"`` or ``"nonfinite"``; ``converged`` is True only for
    ``"successful"``.
    ``loss`` names what the solver minimised (``brdffit.fitting.options.LOSSES``);
    ``error`` holds every metric (``log_rmse``, ``cube_root_rmse``, ``rmse_cos``,
    ``rel_peak_error``, ``psnr_db``) whatever it was, and ``sample_<metric>`` of the
    loss on the solver's subsample.

    Set only on some paths, None elsewhere:

    - ``scene``: the scene the fit was weighted to (``brdffit.fitting.scene``), and
      ``full_table_error``: the same metrics as ``error`` on the whole table;
    - ``uncertainty``: standard errors, correlations and undetermined parameters
      (``brdffit.fitting.uncertainty``); None for a fit whose every start diverged;
    - ``selection``: on the fit ``model="auto"`` chose, how and why it was chosen
      (``brdffit.selection.Selection.summary``: ranking of every candidate, reason);
    - ``quality``: how the fit looks next to the measurement: sphere-render PSNR,
      brightness in stops, colour shift (CIEDE2000), a verdict (good / visible /
      poor), its reason and what to try next (``brdffit.fitting.quality``); None on a
      result stored before it existed;
    - ``physical``: on a physically bounded fit (``physical=True``), what the bounds
      cost against the unconstrained fit and which were active
      (``brdffit.fitting.physical``, docs/results.md);
    - ``input``: on a fit of samples (a gonioreflectometer's list, not a MERL table),
      their format and count and what binning them onto the MERL grid did
      (``brdffit.io.readers.input_summary``).
    """

    model: str
    params: dict[str, float | list[float]]
    error: dict[str, float]
    converged: bool
    result: str
    steps: int
    time_s: float
    samples: dict[str, int | dict[str, int]]
    solver: str = "lm"
    precision: str = "float64"
    loss: str = "log"
    starts: int = 1
    table: str | None = None
    scene: dict | None = None
    full_table_error: dict[str, float] | None = None
    selection: dict | None = None
    uncertainty: dict | None = None
    physical: dict | None = None
    quality: dict | None = None
    input: dict | None = None
    notes: tuple[str, ...] = ()

    @classmethod
    def described(cls) -> dict[str, str]:
        """A one-line meaning per key, for schemas generated from this class (the
        service's ``FitResultOut``)."""
        return dict(FIELD_DOCS)

    @property
    def log_rmse(self) -> float:
        return self.error["log_rmse"]

    def to_dict(self) -> dict:
        """The result schema: ``{"schema": SCHEMA, ...every field}`` (``notes`` a list,
        as JSON and a results file give it back)."""
        return {"schema": SCHEMA, **asdict(self), "notes": list(self.notes)}

    def to_json(self, **kw) -> str:
        """Strict JSON (``brdffit.jsonout``): a metric that is NaN or inf here is null."""
        return jsonout.dumps(self.to_dict(), **kw)

    @classmethod
    def from_dict(cls, d: dict) -> FitResult:
        """A result from :meth:`to_dict`'s output (any version of :data:`READS`), or
        from its strict JSON, where a metric that was not measured (NaN) is null: it
        reads back as NaN, as the fit held it (``r.log_rmse < x`` is then False, not
        a TypeError). Refuses another schema version, unknown or missing keys and values
        of the wrong type (:class:`~brdffit.errors.ResultFormatError`, a ValueError)."""
        d = dict(d)
        schema = d.pop("schema", SCHEMA)
        if schema not in READS:
            raise ResultFormatError(f"result schema {schema!r}; this brdffit reads "
                             f"{', '.join(map(repr, READS[:-1]))} and {READS[-1]!r}")
        if "notes" in d:  # JSON has lists; the result holds a tuple
            d["notes"] = tuple(d["notes"] or ())
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ResultFormatError(f"unknown result keys {unknown} for schema {SCHEMA!r}")
        missing = [f.name for f in fields(cls) if f.name not in d
                   and f.default is MISSING and f.default_factory is MISSING]
        if missing:
            raise ResultFormatError(f"no {', '.join(missing)} (a fit result has "
                             f"{', '.join(f.name for f in fields(cls))})")
        _check_types(d)
        for key in ("error", "full_table_error"):  # strict JSON wrote an unmeasured NaN as null
            if d.get(key) is not None:
                d[key] = {k: float("nan") if v is None else v for k, v in d[key].items()}
        return cls(**d)

    @classmethod
    def keys(cls) -> list[str]:
        """The keys of :meth:`to_dict`, in order."""
        return ["schema", *(f.name for f in fields(cls))]

    def param_arrays(self) -> dict:
        """Params as numpy arrays (``dict[str, np.ndarray]``), ready for
        ``model(params, wi, wo)``."""
        import numpy as np

        return {k: np.asarray(v, dtype=np.float64) for k, v in self.params.items()}


_NUMBER = (numbers.Real,)  # numpy's scalars too: a result made in-process may hold them
#: The JSON type of each key a result reads (None: may be null). A file edited by hand
#: or written by another tool is refused by its key's name, rather than failing deep in
#: an export with a message about Python's types.
_TYPES: dict[str, tuple] = {
    "model": (str,), "params": (dict,), "error": (dict,), "converged": (bool,),
    "result": (str,), "steps": (numbers.Integral,), "time_s": _NUMBER, "samples": (dict,),
    "solver": (str,), "precision": (str,), "loss": (str,), "starts": (numbers.Integral,),
    "table": (str, None), "scene": (dict, None), "full_table_error": (dict, None),
    "selection": (dict, None), "uncertainty": (dict, None), "physical": (dict, None),
    "quality": (dict, None), "input": (dict, None), "notes": (tuple, list),
}
_WORDS = {str: "text", dict: "an object", bool: "true or false", int: "a whole number",
          float: "a number", numbers.Integral: "a whole number", numbers.Real: "a number",
          tuple: "a list", list: "a list", None: "null"}


def _check_types(d: dict) -> None:
    def a(v) -> str:
        return "null" if v is None else _WORDS.get(type(v), type(v).__name__)

    for key, types in _TYPES.items():
        if key not in d:
            continue
        v = d[key]
        ok = (v is None and None in types) or (
            isinstance(v, tuple(t for t in types if t is not None))
            and not (isinstance(v, bool) and bool not in types))
        if not ok:
            want = " or ".join(dict.fromkeys(_WORDS[t] for t in types))
            raise ResultFormatError(f"{key!r} is {a(v)}, where a fit result has {want}")
    for key in ("error", "full_table_error"):
        for name, v in (d.get(key) or {}).items():
            if v is not None and (not isinstance(v, _NUMBER) or isinstance(v, bool)):
                raise ResultFormatError(f"{key}.{name} is {a(v)}, where a fit result has a "
                                 "number or null")
    quality = d.get("quality") or {}
    if not isinstance(quality.get("verdict", ""), (str, type(None))):
        raise ResultFormatError(f"quality.verdict is {a(quality['verdict'])}, where a fit result "
                         "has text")
    steps = quality.get("next")
    if steps is not None and (not isinstance(steps, list) or not all(
            isinstance(step, dict) and isinstance(step.get("try", ""), str) for step in steps)):
        raise ResultFormatError("quality.next is not a list of steps (objects with 'try' text)")
    if not all(isinstance(n, str) for n in d.get("notes", ())):
        raise ResultFormatError("notes is not a list of text")


#: What each key of the result schema means, in a line (docs/results.md says more).
FIELD_DOCS = {
    "model": "the fitted model's registry name",
    "params": "fitted parameters by their docs/models.md names; RGB ones as 3 floats",
    "error": "log_rmse, cube_root_rmse, rmse_cos, rel_peak_error, psnr_db and the loss on "
             "the solver's samples; null where a fit could not measure one",
    "converged": "true only where the optimality test holds at the returned point",
    "result": "how the solve ended: successful, nonlinear_max_steps_reached, stalled, "
              "nonfinite",
    "steps": "solver steps taken",
    "time_s": "wall time of the fit",
    "samples": "bins used, usable, measured, and dropped by reason",
    "solver": "the least-squares solver",
    "precision": "float64 or float32, of the solve",
    "loss": "the loss the solver minimised (docs/fitting.md)",
    "starts": "start candidates refined",
    "table": "the table's name",
    "scene": "the scene the fit was weighted to, or null",
    "full_table_error": "with a scene: the same metrics on the whole table",
    "selection": "on the fit model auto chose: the ranking and the reason",
    "uncertainty": "standard errors, correlations and undetermined parameters "
                   "(docs/results.md)",
    "physical": "on a physically bounded fit: the unconstrained and bounded log_rmse, the "
                "relative cost, the largest albedo before and after, the active constraints",
    "quality": "how the fit looks next to the measurement: render_psnr_db, "
               "displayed_brightness_stops (judged), brightness_stops (radiance), "
               "displayed_colour_shift and colour_shift (CIEDE2000, as displayed and in "
               "radiance: the worse is judged), estimate_error, grazing, verdict "
               "(good, visible or poor), reason and next (what to try, best first)",
    "input": "on a fit of samples (ASTM, CSV, Excel, HDF5, MATLAB, .npz): their format, count and "
             "what binning them onto the MERL grid moved, or null for a MERL table",
    "notes": "where the fit did other than the request says, and why: the starts a fit of "
             "every bin used, fewer start candidates than starts asked, a nested model "
             "whose parent left it nothing to add",
}


def error_measures_nothing(why: str | None) -> bool:
    """Whether an undetermined reason (``uncertainty["why"]``) says the parameter shapes
    a lobe or layer the data show none of: its standard error then measures nothing (an
    absent film's index read "2.5 ± 1.8e+06"): the uncertainty reports none (null), and
    the text and report print the value without one (also of results stored before it
    reported none)."""
    return bool(why) and why.startswith(("no lobe", "no layer"))
