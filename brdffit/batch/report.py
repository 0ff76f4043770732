"""Read a batch results file back: which model fits each table best, how each model does.

The ranking metric is ``log_rmse`` on the full table (``brdffit.fitting.loss``): the
error a fit is judged by everywhere in brdffit, comparable across models.
Models within ``brdffit.selection.TIE`` of the lowest error are tied, and a tie goes to the model
with fewer parameters: a Lambertian table is fitted exactly by GGX with ks = 0
too, but it is Lambert's table. Fits that failed, and tables that could not be
read, are counted, never ranked.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field

from brdffit import extras, models
from brdffit.batch.store import read_attrs, read_index, read_looks
from brdffit.fitting.quality import VERDICTS, radiance_verdict
from brdffit.selection import DEFAULT_TOLERANCE, best, choose

METRIC = "log_rmse"


@dataclass
class TableRanking:
    name: str
    path: str
    status: str
    message: str
    errors: dict[str, float]  # model -> log_rmse, successful fits only
    failed_models: dict[str, str] = field(default_factory=dict)  # model -> message
    looks: dict[str, dict] = field(default_factory=dict)  # model -> its quality block

    def _rows(self) -> list[dict]:
        """The successful fits as ranking rows, cheapest first (the registry's order)."""
        order = models.names()
        rows = [{"model": m, "log_rmse": e, "n_params": _n_params(m),
                 # the look, which auto's rule reads within its tolerance (none for a fit
                 # stored before results had one: the rule is then the error's alone)
                 "verdict": self.looks.get(m, {}).get("verdict"),
                 "radiance_verdict": radiance_verdict(self.looks.get(m))}
                for m, e in self.errors.items() if math.isfinite(e)]
        rows.sort(key=lambda r: order.index(r["model"]) if r["model"] in order else len(order))
        return rows

    @property
    def best(self) -> str | None:
        """The lowest error, a tie to fewer parameters (``brdffit.selection.best``)."""
        rows = self._rows()
        return best(rows)[0]["model"] if rows else None

    def chosen(self, tolerance: float = DEFAULT_TOLERANCE) -> tuple[str | None, str]:
        """What ``model="auto"`` picks from these fits, and why: the cheapest model
        within ``tolerance`` of the best, in quadrature, of those that look best
        (``brdffit.selection.choose``)."""
        rows = self._rows()
        if not rows:
            return None, "no successful fit"
        row, reason = choose(rows, tolerance)
        return row["model"], reason


@dataclass
class ModelSummary:
    model: str
    fitted: int
    failed: int
    wins: int
    mean: float  # of log_rmse over the tables it fitted
    median: float
    not_converged: int
    #: how many of its fits look good, visible, poor (quality.verdict)
    looks: dict[str, int] = field(default_factory=dict)


@dataclass
class Ranking:
    attrs: dict
    models: list[str]
    tables: list[TableRanking]
    summary: list[ModelSummary]
    #: option -> the values the file's successful fits were made with, where they differ
    #: (runs with other options resumed into one file: a log and a render loss fit side
    #: by side were ranked as one kind of fit, unsaid)
    mixed_options: dict[str, list] = field(default_factory=dict)

    @property
    def failed_tables(self) -> list[TableRanking]:
        return [t for t in self.tables if t.status != "ok" or t.failed_models]


def rank(path: str | os.PathLike) -> Ranking:
    """The ranking of the batch file at ``path``."""
    attrs = read_attrs(path)
    models: dict[str, None] = {}
    for m in _list_attr(attrs.get("models")):
        models.setdefault(m)
    tables, not_converged, keys = [], {}, set()
    for t in sorted(read_index(path).values(), key=lambda t: t.name):
        row = TableRanking(t.name, t.path, t.status, t.message, {})
        for model, f in t.fits.items():
            models.setdefault(model)
            if f.status == "ok":
                keys.add(f.options)
                row.errors[model] = f.log_rmse  # METRIC
                not_converged[model] = not_converged.get(model, 0) + (not f.converged)
            else:
                row.failed_models[model] = f.message
        tables.append(row)
    looks = read_looks(path)
    for t in tables:
        t.looks = {m: looks[t.name, m] for m in t.errors if (t.name, m) in looks}
    summary = []
    for m in models:
        values = sorted(e for t in tables if math.isfinite(e := t.errors.get(m, math.nan)))
        summary.append(ModelSummary(
            model=m,
            fitted=len(values),
            failed=sum(m in t.failed_models for t in tables),
            wins=sum(t.best == m for t in tables),
            mean=sum(values) / len(values) if values else math.nan,
            median=_median(values),
            not_converged=not_converged.get(m, 0),
            looks={v: sum(t.looks.get(m, {}).get("verdict") == v for t in tables)
                   for v in VERDICTS},
        ))
    return Ranking(attrs, list(models), tables, summary, _mixed(keys))


def _mixed(keys: set[str]) -> dict[str, list]:
    """The options whose values differ among the fit keys ``keys`` (JSON objects)."""
    import json

    parsed = []
    for k in keys:
        try:
            parsed.append(json.loads(k))
        except ValueError:
            continue
    names = sorted({n for d in parsed for n in d})
    out = {}
    for n in names:
        values = {json.dumps(d.get(n), sort_keys=True) for d in parsed}
        if len(values) > 1:
            out[n] = sorted(json.loads(v) if v != "null" else None for v in values)
    return out


def _shown(value) -> str:
    """An option's value in a line: its default (absent from the key) said so."""
    return "default" if value is None else str(value)


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def format_ranking(r: Ranking, source: str = "", tolerance: float = DEFAULT_TOLERANCE) -> str:
    """The ranking as a plain-text report: one row per table, then one per model.
    Column ``auto``: the model selection's choice at ``tolerance`` (docs/selection.md)."""
    n_failed = len(r.failed_tables)
    lines = [f"{source or 'batch'}: {_count(len(r.tables), 'table')} ({n_failed} with "
             f"failures), {_count(len(r.models), 'model')}, "
             f"brdffit {r.attrs.get('brdffit_version', '?')}",
             f"{METRIC} on the full table (a sample list's: at its samples), lower is "
             "better; * marks each table's best; "
             f"auto: the cheapest within {tolerance:g} of it (in quadrature)"]
    if r.mixed_options:
        lines.append("Fits made with different options side by side (runs of other options "
                     "resumed into this file): " + "; ".join(
                         f"{k} {', '.join(map(_shown, v))}" for k, v in r.mixed_options.items()))
    lines.append("")
    width = max([len("table")] + [len(t.name) for t in r.tables])
    cols = max([10] + [len(m) + 1 for m in r.models])
    lines.append(f"{'table':<{width}}  {'best':<{cols}}{'auto':<{cols}}"
                 + "".join(f"{m:>{cols + 1}}" for m in r.models))
    for t in r.tables:
        if t.status != "ok":
            lines.append(f"{t.name:<{width}}  FAILED: {t.message.removeprefix(t.path + ': ')}")
            continue
        cells = []
        for m in r.models:
            if m in t.errors:
                cells.append(f"{t.errors[m]:.4g}" + ("*" if m == t.best else " "))
            elif m in t.failed_models:
                cells.append("failed ")
            else:
                cells.append("- ")
        auto = t.chosen(tolerance)[0]
        lines.append(f"{t.name:<{width}}  {t.best or '-':<{cols}}{auto or '-':<{cols}}"
                     + "".join(f"{c:>{cols + 1}}" for c in cells))
    lines += ["", f"{'model':<{cols}} {'fitted':>7} {'failed':>7} {'wins':>6} "
                  f"{'mean ' + METRIC:>14} {'median':>10} {'not conv.':>10}  "
                  "looks good/visible/poor"]
    for s in sorted(r.summary, key=lambda s: (math.isnan(s.mean), s.mean)):
        looks = "/".join(str(s.looks.get(v, 0)) for v in VERDICTS)
        lines.append(f"{s.model:<{cols}} {s.fitted:>7} {s.failed:>7} {s.wins:>6} "
                     f"{_number(s.mean):>14} {_number(s.median):>10} {s.not_converged:>10}  "
                     f"{looks}")
    lines += _next_steps(r)
    if n_failed:
        lines += ["", "failures:"]
        for t in r.failed_tables:
            if t.status != "ok":  # read errors name their file already
                lines.append(f"  {t.message}" if t.message.startswith(t.path)
                             else f"  {t.path}: {t.message}")
            for m, msg in t.failed_models.items():
                lines.append(f"  {t.path} [{m}]: {msg}")
    return "\n".join(lines)


def _number(v: float) -> str:
    """A mean or median in the report: ``-`` where there is none (no successful fit;
    ``nan`` in the text, where --json gives null)."""
    return f"{v:.4g}" if math.isfinite(v) else "-"


def _next_steps(r: Ranking) -> list[str]:
    """For each table whose best fit does not look good: its verdict and the first
    thing to try (the fit's ``quality.next``)."""
    lines = []
    for t in r.tables:
        look = t.looks.get(t.best) if t.best else None
        if not look or look.get("verdict") in (None, "good"):
            continue
        steps = look.get("next") or []
        step = steps[0] if steps else None
        gain = ("" if step is None or step.get("gain_db") is None
                else f" ({step['gain_db']:+.1f} dB)")
        lines.append(f"  {t.name} [{t.best}] looks {look['verdict']}: "
                     + (f"next: {step['try']}{gain}: {step['why']}" if step
                        else look.get("reason", "")))
    if lines:
        lines.insert(0, "")
        lines.insert(1, "what to try next, where the best fit does not look good:")
    return lines


def plot_summary(r: Ranking, png: str | os.PathLike, source: str = "") -> str:
    """A titled two-panel PNG: the spread of each model's error over the tables, and
    how many tables each model fits best; models ordered by median error, best
    first. Sized for ten tables or ten thousand. ``source`` (the results file)
    goes in the title."""
    extras.require("plots", "the batch summary figure", hint="--no-png prints the ranking only")
    png = os.fspath(png)
    summary_figure(r, source).savefig(png, dpi=110, facecolor="white")
    return png


def summary_figure(r: Ranking, source: str = ""):
    """:func:`plot_summary`'s figure (a ``matplotlib.figure.Figure``)."""
    from matplotlib.figure import Figure  # no pyplot: no global state, safe in workers
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    medians = {s.model: s.median for s in r.summary}
    order = sorted(r.models, key=lambda m: (not math.isfinite(medians.get(m, math.nan)),
                                            medians.get(m, math.inf)))
    width = max(11.0, 4.0 + 0.9 * len(order))
    fig = Figure(figsize=(width, 5.2), layout="constrained")
    ax_err, ax_win = fig.subplots(1, 2, width_ratios=[3, 2])
    # each model's fits that a log axis shows (a failed table has none: its "not judged"
    # entry in the legend had no dot)
    fits = [[(e, _look(t, m)) for t in r.tables
             if math.isfinite(e := t.errors.get(m, math.nan)) and e > 0] for m in order]
    positions = list(range(1, len(order) + 1))
    shown = [(p, [e for e, _ in f]) for p, f in zip(positions, fits, strict=True) if f]
    if shown:
        ax_err.boxplot([d for _, d in shown], positions=[p for p, _ in shown], widths=0.5,
                       showfliers=False,  # the median black: orange is a look's colour
                       medianprops={"color": "black", "linewidth": 1.5})
        for p, f in zip(positions, fits, strict=True):
            # every table as a dot, coloured by how its fit looks: a box hides small
            # batches, and an error alone does not say whether the fit looks right
            jitter = [p + 0.18 * ((i * 0.618) % 1 - 0.5) for i in range(len(f))]
            ax_err.scatter(jitter, [e for e, _ in f], s=12, alpha=0.75, zorder=3,
                           color=[LOOK_COLOURS[look] for _, look in f])
        ax_err.set_yscale("log")
        ax_err.legend(handles=[Line2D([], [], ls="", marker="o", color=c,
                                      label=LOOK_LABELS[k])
                               for k, c in LOOK_COLOURS.items()
                               if any(look == k for f in fits for _, look in f)],
                      title="the fit looks", fontsize=9, title_fontsize=9,
                      loc="upper left")  # the best median first: its top is free; "best"
        # is slow over thousands of dots
        ax_err.grid(True, axis="y", which="major", alpha=0.3)
    else:  # an empty axis said "log scale" on a linear one from 0 to 1
        _nothing(ax_err, "no successful fit in this file yet: nothing to plot")
    ax_err.set_xticks(positions, order, rotation=30, ha="right")
    ax_err.set_xlim(0.4, len(order) + 0.6)
    # two lines: in one it ran past the figure's top
    ax_err.set_ylabel(f"{METRIC}, lower is better\n(full table, or a sample list's samples"
                      + ("; log scale)" if shown else ")"))
    ax_err.set_title(f"error per model over {_count(len(r.tables), 'table')}"
                     + (" (best median first)" if shown else ""), fontsize=11)
    wins = [next((s.wins for s in r.summary if s.model == m), 0) for m in order]
    # each model's wins split by how the winning fit looks (quality.verdict)
    bottom = [0] * len(order)
    for look, colour in LOOK_COLOURS.items():
        counts = [sum(t.best == m and _look(t, m) == look for t in r.tables) for m in order]
        if any(counts):
            ax_win.bar(positions, counts, bottom=bottom, color=colour,
                       label=LOOK_LABELS[look])
            bottom = [b + c for b, c in zip(bottom, counts, strict=True)]
    ax_win.set_xticks(positions, order, rotation=30, ha="right")
    ax_win.set_xlim(0.4, len(order) + 0.6)  # as the left panel: no bar at an edge
    if any(wins):
        for p, w in zip(positions, wins, strict=True):
            ax_win.annotate(str(w), (p, w), ha="center", va="bottom", fontsize=9,
                            xytext=(0, 1), textcoords="offset points")
        # beside the axes, not in them: at their upper right it covered a tall bar and
        # its count
        ax_win.legend(title="the best fit looks", fontsize=9, title_fontsize=9,
                      loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
        ax_win.set_ylim(0, max(wins) * 1.15)
        ax_win.yaxis.set_major_locator(MaxNLocator(integer=True))  # no half tables
        ax_win.set_ylabel("tables where it is the best fit")
    else:
        _nothing(ax_win, "no table has a best fit yet")
    n_failed = len(r.failed_tables)
    # the failures on a line of their own: on the title's line they ran off the figure
    ax_win.set_title("best model per table\n(ties go to fewer parameters"
                     + (f"; {_count(n_failed, 'table')} with failures)" if n_failed
                        else ")"), fontsize=11)
    name = os.path.basename(os.fspath(source)) if source else "batch"
    fig.suptitle(f"{name}: {_count(len(r.tables), 'table')} x {_count(len(order), 'model')}",
                 fontsize=13)
    return fig


def _nothing(ax, why: str) -> None:
    """An axis with nothing to show says so, without ticks of a scale it does not have."""
    ax.set_yticks([])
    ax.text(0.5, 0.5, why, transform=ax.transAxes, ha="center", va="center", fontsize=10,
            color="0.35", wrap=True)


#: The summary figure's colour for each look of a fit (None: not judged, e.g. a
#: results file written before verdicts were stored).
LOOK_COLOURS = {"good": "tab:green", "visible": "tab:orange", "poor": "tab:red",
                None: "tab:gray"}
LOOK_LABELS = {"good": "good", "visible": "visible", "poor": "poor", None: "not judged"}


def _look(t, model: str) -> str | None:
    """The verdict of ``t``'s fit of ``model`` (None where there is none)."""
    verdict = (t.looks.get(model) or {}).get("verdict")
    return verdict if verdict in LOOK_COLOURS else None


def _n_params(model: str) -> float:
    info = {m["name"]: m["n_params"] for m in models.describe()}
    return info.get(model, math.inf)  # a model this version lacks


def _median(values: list[float]) -> float:
    if not values:
        return math.nan
    n = len(values)
    return values[n // 2] if n % 2 else 0.5 * (values[n // 2 - 1] + values[n // 2])


def _list_attr(v) -> list[str]:
    if isinstance(v, str):
        try:
            v = json.loads(v)
        except ValueError:
            return []
    return list(v) if isinstance(v, list) else []
