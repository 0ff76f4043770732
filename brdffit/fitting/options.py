"""The options of a fit, declared once: :class:`FitOptions`.

Every shell takes its options from here rather than declaring its own: the CLI
builds ``brdffit fit`` and ``brdffit batch`` arguments from the fields
(``brdffit.cli.fit``), the service builds its request schema's defaults and
bounds from them (``api/routes/fits.py``), and a batch identifies a finished fit
by :meth:`FitOptions.key`. The defaults and the choices are declared here
(``DEFAULT_STARTS``, ``LOSSES``, ...; ``DEFAULT_SAMPLES`` beside the sampling it
sizes) and ``brdffit.fit``'s signature takes them from here, so a default retuned
here is retuned in every shell and in the docs (``python -m
brdffit.fitting.options --docs`` rewrites their tables; a test checks them).

This module imports no JAX: the service's front checks requests with it and
starts in a second instead of three (``tests/test_api.py`` checks the running server).

Each field carries an :class:`Option` in its metadata: its one-line meaning and
its valid range, which :class:`FitOptions` enforces on construction, so an
options object that exists is one a fit accepts.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from brdffit import jsonout, models
from brdffit.errors import FitInputError
from brdffit.fitting.sampling import DEFAULT_SAMPLES
from brdffit.io.angles import N_PHI_D, N_THETA_D, N_THETA_H
from brdffit.models.catalogue import AUTO as AUTO  # the registry owns the name

#: Selection tolerance in ``log_rmse``, in quadrature: 0.005 is ~0.5 % RMS at the
#: highlight, below the repeatability of a MERL measurement (docs/selection.md).
DEFAULT_TOLERANCE = 0.005
#: The fields of :class:`FitOptions`: the keywords of ``brdffit.fit``, in its order.
#: What to fit (``FitRequest.models``) and how auto chooses (:class:`SelectionRule`)
#: are the request's.
FIT_KEYWORDS = ("loss", "solver", "samples", "precision", "starts", "max_steps", "seed",
                "physical")
#: The fields of :class:`SelectionRule` that are numbers (a command line's flags).
SELECTION_KEYWORDS = ("tolerance", "budget")
N_BINS = N_THETA_H * N_THETA_D * N_PHI_D

DEFAULT_MODEL = "ggx"
#: The losses a fit can minimise (each implemented in ``brdffit.fitting.loss``).
LOSSES = ("log", "cube_root", "linear_cos", "render")
DEFAULT_LOSS = "log"
#: "lm" is brdffit's normal-equations Levenberg-Marquardt (``brdffit.fitting.solver``);
#: "optx-lm" is optimistix's own, kept for comparison.
SOLVERS = ("lm", "optx-lm", "dogleg", "bfgs")
DEFAULT_SOLVER = "lm"
#: The solvers that solve in float32 too: optimistix's LM and dogleg mix the float32
#: residuals with float64 operators (a job accepted, then failed with "Vector and
#: operator structures do not match", or a JAX traceback on the command line).
FLOAT32_SOLVERS = ("lm", "bfgs")


def check_solver_precision(solver: str, precision: str) -> None:
    """Refuses a solver that cannot solve in ``precision``, before anything runs."""
    if precision == "float32" and solver not in FLOAT32_SOLVERS:
        raise FitInputError(f"solver {solver!r} solves in float64 only; float32 is solved by "
                            f"{' and '.join(FLOAT32_SOLVERS)}")


#: Floating point precisions of the solve (``brdffit.fitting.problem.DTYPES``).
PRECISIONS = ("float64", "float32")
DEFAULT_PRECISION = "float64"
#: One start suffices on every case of the stability suite: the starts are scored
#: on a lobe-shape grid first, so the best one is already in the right basin.
#: More starts (refined side by side with vmap) cost ~linearly more.
DEFAULT_STARTS = 1
#: Steps per start. A default fit of a real material converges in 3-80 steps
#: (bench/results/real_materials.md); the limit only ends a fit that cannot.
DEFAULT_MAX_STEPS = 256
DEFAULT_SEED = 0


@dataclass(frozen=True)
class Option:
    """How one option is offered and checked: what every shell needs to know."""

    doc: str  # one line, shown as CLI help and API description
    kind: type  # int, float, str or bool (a flag: --name on a command line)
    choices: tuple[str, ...] | None = None
    least: float | None = None  # smallest valid value, inclusive
    above: float | None = None  # values must be strictly above this
    most: float | None = None  # largest valid value, inclusive
    none: str | None = None  # what None means, where None is allowed
    cli_none: str | None = None  # the word a command line gives for None ("all")
    words: str | None = None  # the valid values, where a range cannot say them

    def check(self, name: str, value) -> None:
        """Raise :class:`FitInputError` unless ``value`` is valid for this option."""
        if value is None:
            if self.none is None:
                raise FitInputError(f"{name} must be given, got None")
            return
        if self.kind is tuple:  # a list of names: each is checked by its owner
            if (isinstance(value, str | bytes) or not hasattr(value, "__iter__")
                    or not all(isinstance(v, str) for v in value) or not len(value)):
                raise FitInputError(f"{name} must be {self.describe_range()}, got {value!r}")
            return
        if self.choices is not None:
            if value not in self.choices:
                raise FitInputError(
                    f"unknown {name} {value!r}; choose one of {', '.join(self.choices)}")
            return
        if self.kind is bool:
            if not isinstance(value, bool):
                raise FitInputError(f"{name} must be {self.describe_range()}, got {value!r}")
            return
        ok_type = (int,) if self.kind is int else (int, float) if self.kind is float else (str,)
        if not isinstance(value, ok_type) or isinstance(value, bool):
            raise FitInputError(f"{name} must be {self.describe_range()}, got {value!r}")
        if self.kind is float and not math.isfinite(value):
            raise FitInputError(f"{name} must be {self.describe_range()}, got {value!r}")
        if ((self.least is not None and value < self.least)
                or (self.above is not None and value <= self.above)
                or (self.most is not None and value > self.most)):
            raise FitInputError(f"{name} must be {self.describe_range()}, got {value!r}")

    def describe_range(self, none_word: str = "None") -> str:
        """The valid values in words: ``"an integer in 1 .. 32"``; ``none_word`` is
        how the reader spells None (``null`` in JSON, ``all`` on a command line)."""
        if self.words is not None:
            text = self.words
        elif self.kind is bool:
            text = "true or false"
        elif self.choices is not None:
            text = "one of " + ", ".join(self.choices)
        else:
            text = {int: "an integer", float: "a number", str: "a string"}[self.kind]
            if self.least is not None and self.most is not None:
                text += f" in {_number(self.least)} .. {_number(self.most)}"
            else:
                bounds = [f"{op} {_number(x)}" for op, x in
                          ((">=", self.least), (">", self.above), ("<=", self.most))
                          if x is not None]
                text += (" " + " and ".join(bounds)) if bounds else ""
        if self.none is not None:
            # one message for every caller: a command line spells None its own way
            spelled = (f"{none_word} or {self.cli_none}" if none_word == "None" and self.cli_none
                       else none_word)
            text += f", or {spelled} ({self.none})"
        return text


def _number(x: float) -> str:
    if float(x).is_integer() and abs(x) >= 10_000:
        return f"{int(x):,}"
    return f"{x:g}"


def _option(default, **spec):
    if isinstance(default, list | dict):
        raise TypeError("a mutable default would be shared")
    return dataclasses.field(default=default, metadata={"option": Option(**spec)})


def _check_fields(obj) -> None:
    for f in dataclasses.fields(obj):
        f.metadata["option"].check(f.name, getattr(obj, f.name))


@dataclass(frozen=True)
class FitOptions:
    """Everything a caller chooses about a fit, with its default and valid range.

    ``FitOptions()`` are the library's defaults; ``fit(table, model,
    **o.fit_keywords())`` runs them (``brdffit.request.FitRequest`` holds them with
    the models and, for auto, the :class:`SelectionRule`). Invalid values raise
    :class:`~brdffit.errors.FitInputError` here, before any table is read.
    """

    loss: str = _option(
        DEFAULT_LOSS, kind=str, choices=LOSSES,
        doc="what the solver minimises: log (log1p(f cos), default), cube_root, linear_cos "
            "(f cos), or render (tone-mapped sphere renders under eight lights, exposed per "
            "channel); every metric is reported whatever the choice (docs/fitting.md)")
    solver: str = _option(
        DEFAULT_SOLVER, kind=str, choices=SOLVERS,
        doc="least-squares solver; lm is brdffit's Levenberg-Marquardt")
    samples: int | None = _option(
        DEFAULT_SAMPLES, kind=int, least=64, most=N_BINS, none="every bin; slow", cli_none="all",
        doc="bins the solver sees (stratified subsample); the error is always on the full "
            "table. Fewer than the default buy no speed: they run the default's compiled "
            "fit, padded with bins of no weight")
    precision: str = _option(
        DEFAULT_PRECISION, kind=str, choices=PRECISIONS,
        doc="floating point precision of the solve")
    starts: int = _option(
        DEFAULT_STARTS, kind=int, least=1, most=32,
        doc="best-scoring start candidates refined, one after another; the best result is "
            "kept (a count runs the solve compiled for the next power of two: 3 and 4 "
            "share one)")
    max_steps: int = _option(
        DEFAULT_MAX_STEPS, kind=int, least=1, most=10_000,
        doc="solver step limit per start; running out is reported, not raised")
    seed: int = _option(
        DEFAULT_SEED, kind=int, least=0, most=2**32 - 1,
        doc="subsample seed: a fit is deterministic for a given seed")
    physical: bool = _option(
        False, kind=bool,
        doc="physically bounded fit: directional albedo <= 1 at every incidence and "
            "reflectances <= 1; the result's `physical` reports the cost (docs/fitting.md)")
    def __post_init__(self):
        _check_fields(self)
        check_solver_precision(self.solver, self.precision)

    # -- what the shells and the library take -------------------------------------

    def fit_keywords(self) -> dict:
        """The keyword arguments of ``brdffit.fit`` (and ``select``'s ``**fit_options``)."""
        return {name: getattr(self, name) for name in FIT_KEYWORDS}

    def key(self) -> str:
        """Canonical JSON of :meth:`fit_keywords`: equal fits, equal key.

        A batch stores it beside each fit's table hash and model, and skips a fit
        on resume when all three match; the model and the selection rule are
        not part of it (a batch records the model separately, and the rule only
        reads finished fits). A scene is (``FitRequest.fit_key``): it changes the fit.
        """
        return self.key_of(self.fit_keywords())

    @staticmethod
    def key_of(fit_keywords: dict) -> str:
        """:meth:`key` of fit keywords as a results file stored them, not checked
        again: a file written under other ranges must still resume. A keyword the
        file lacks (written before the option existed) takes today's default; a
        ``scene`` among them (a scene's dict) is part of the key."""
        defaults = {f.name: f.default for f in dataclasses.fields(FitOptions)}
        d = {name: fit_keywords.get(name, defaults[name]) for name in FIT_KEYWORDS}
        for name in ("loss", "physical"):
            if d[name] == defaults[name]:
                # keys written before the option existed stay the same: resume skips them
                del d[name]
        if fit_keywords.get("scene") is not None:  # absent before batches took scenes
            d["scene"] = fit_keywords["scene"]
        return jsonout.dumps(d, sort_keys=True, separators=(",", ":"))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> FitOptions:
        """Options from a dict of field names (a subset; the rest default)."""
        unknown = sorted(set(d) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise FitInputError(f"unknown fit options {unknown}; known: {', '.join(names())}")
        return cls(**d)

    def replace(self, **changes) -> FitOptions:
        return dataclasses.replace(self, **changes)



@dataclass(frozen=True)
class SelectionRule:
    """How ``auto`` chooses among its candidates (docs/selection.md): part of a
    request that fits ``auto`` (``brdffit.request.FitRequest.rule``), and of no
    other. ``SelectionRule()`` is the library's default rule."""

    tolerance: float = _option(
        DEFAULT_TOLERANCE, kind=float, least=0, most=10,
        doc="the cheapest model within this log_rmse of the best (in quadrature) is chosen, "
            "of those whose sphere reads the best verdict among them")
    budget: float | None = _option(
        None, kind=float, above=0, most=10, none="no budget",
        doc="the cheapest model with log_rmse under this budget is chosen")
    candidates: tuple[str, ...] = _option(
        models.catalogue.auto_candidates(), kind=tuple, words="a list of model names",
        doc="the models to choose among, fitted cheapest first (default: `brdffit models`' "
            "auto candidates); gltf, mitsuba or materialx stands for the materials that "
            "renderer's file carries, layers included, and default for the default list "
            "(default,ggx3,ggx4 adds the third and fourth lobes)")
    mono_ks: bool = _option(
        False, kind=bool,
        doc="also fit the chosen model with a grey ks (<model>_mono) when its fitted "
            "specular colour is grey")

    def __post_init__(self):
        _check_fields(self)
        # a set's name (gltf, mitsuba, materialx, default) stands for its models; twice
        # is once
        names = tuple(dict.fromkeys(models.catalogue.expand_candidates(self.candidates)))
        for name in names:
            models.check_name(name)
        object.__setattr__(self, "candidates", names)

    def selection_keywords(self) -> dict:
        """The keyword arguments of ``brdffit.select`` but the table and the fit's."""
        return {"candidates": self.candidates, "tolerance": self.tolerance,
                "budget": self.budget, "mono_ks": self.mono_ks}

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "candidates": list(self.candidates)}

    @classmethod
    def from_dict(cls, d: dict) -> SelectionRule:
        """A rule from a dict of field names (a subset; the rest default)."""
        unknown = sorted(set(d) - set(names(cls)))
        if unknown:
            raise FitInputError(f"unknown selection rule keys {unknown}; known: "
                                f"{', '.join(names(cls))}")
        d = dict(d)
        if d.get("candidates") is None:
            d.pop("candidates", None)
        return cls(**d)

    def replace(self, **changes) -> SelectionRule:
        return dataclasses.replace(self, **changes)


def names(of: type = None) -> tuple[str, ...]:
    """Every option of ``of`` (:class:`FitOptions` by default, or
    :class:`SelectionRule`), in declaration order."""
    return tuple(f.name for f in dataclasses.fields(FitOptions if of is None else of))


def spec(name: str, of: type = None) -> tuple[object, Option]:
    """``(default, Option)`` of the option ``name`` of ``of`` (:class:`FitOptions` by
    default, or :class:`SelectionRule`)."""
    f = next((f for f in dataclasses.fields(FitOptions if of is None else of)
              if f.name == name), None)
    if f is None:
        raise KeyError(name)
    default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
    return default, f.metadata["option"]


# -- the docs' option table --------------------------------------------------------------

_DOC_BEGIN = "<!-- fit options: generated by `python -m brdffit.fitting.options --docs` -->"
_DOC_END = "<!-- end of fit options -->"


def markdown_table(style: str = "python") -> str:
    """The options as a Markdown table; ``style`` ``"python"`` (keyword, ``None``),
    ``"cli"`` (``--flag``) or ``"json"`` (key, ``null``) names them as each shell does
    (the request's ``options`` object, in JSON); ``rule_python``, ``rule_cli`` and
    ``rule_json`` are the :class:`SelectionRule`'s (the request's ``rule``)."""
    of = SelectionRule if style.startswith("rule_") else FitOptions
    style = style.removeprefix("rule_")
    rows = ["| option | default | valid values | meaning |", "|---|---|---|---|"]
    for name in names(of):
        default, opt = spec(name, of)
        if style == "cli":
            label = f"`--{name.replace('_', '-')}`"
            none_word = f"`{opt.cli_none}`" if opt.cli_none else "absent"
        else:
            label, none_word = f"`{name}`", "`null`" if style == "json" else "`None`"
        if opt.kind is tuple:
            shown = "`brdffit models`' auto candidates"
        elif default is None:
            shown = none_word if style != "cli" or opt.cli_none else "absent"
        elif opt.kind is bool:
            shown = {"cli": "off", "json": f"`{str(default).lower()}`"}.get(style, f"`{default}`")
        else:
            shown = f'`"{default}"`' if isinstance(default, str) else f"`{default}`"
        valid = opt.describe_range(none_word)
        if opt.kind is tuple and style == "cli":
            valid = "comma-separated model names"
        if opt.kind is bool:
            valid = {"cli": "a flag: present is on", "json": "`true` or `false`"}.get(
                style, "`True` or `False`")
        rows.append(f"| {label} | {shown} | {valid} | {opt.doc} |")
    return "\n".join(rows)


def docs_block(style: str) -> str:
    return f"{_DOC_BEGIN.replace('-->', f'style={style} -->')}\n{markdown_table(style)}\n{_DOC_END}"


def rewrite_docs(path: str) -> bool:
    """Replace every generated option table in the Markdown file ``path``; True if
    it changed."""
    import re

    with open(path, encoding="utf-8") as f:
        text = f.read()
    begin = re.escape(_DOC_BEGIN.removesuffix(" -->")) + r" style=(\w+) -->"
    pattern = re.compile(begin + r"\n(?:.*?\n)?" + re.escape(_DOC_END), re.S)
    new = pattern.sub(lambda m: docs_block(m.group(1)), text)
    if new != text:
        with open(path, "w", encoding="utf-8") as f:
            f.write(new)
    return new != text


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(
        prog="python -m brdffit.fitting.options",
        description="Print the fit options as a Markdown table, or rewrite the docs' tables.")
    ap.add_argument("--style", default="python",
                    choices=("python", "cli", "json", "rule_python", "rule_cli", "rule_json"))
    ap.add_argument("--docs", nargs="+", metavar="FILE.md",
                    help="rewrite the generated tables in these files")
    args = ap.parse_args(argv)
    if args.docs:
        for path in args.docs:
            print(f"{path}: {'rewritten' if rewrite_docs(path) else 'up to date'}")
    else:
        print(markdown_table(args.style))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
