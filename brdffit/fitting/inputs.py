"""What a fit does differently for a MERL table and for a sample list, in one place.

``brdffit.fitting.pipeline`` runs the same stages on both kinds of measured input:
prepare, choose starts, solve, refit from a parent, assemble. Where they differ it
asks the input (:func:`fit_input`), never ``isinstance``:

- :class:`TableInput`: the table's bins (``brdffit.fitting.problem.prepare``), its
  full-table error, the rendered sphere's PSNR and colour, and programs made ready
  ahead in a new process; a fit of every bin is polished from the default one;
- :class:`SampleInput`: the samples at their own directions
  (``brdffit.fitting.samples``): its weights and subsample, the error over every
  sample, the k-fold held-out error, the coverage and identifiability, and the
  verdict from held-out samples where no sphere can be rendered.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from brdffit.errors import FitInputError
from brdffit.fitting.problem import (
    Prepared,
    cached,
    full_table_metrics,
    prepare,
    ready_report_once,
    sphere_reference,
)
from brdffit.fitting.quality import on_part_of_the_sphere
from brdffit.fitting.sampling import DEFAULT_SAMPLES
from brdffit.io import merl
from brdffit.io.measurements import Measurements
from brdffit.io.merl import MerlTable

#: ``refit(fold_data) -> (u, code)``: the fit's own solve, one start from its optimum,
#: on other data of the same shape (a held-out fold).
Refit = Callable[[object], tuple[np.ndarray, int]]


class Measured(NamedTuple):
    """What an input says of a fit's solution beyond its parameters."""

    metrics: dict[str, float]  # error metrics (docs/results.md), psnr_db among them
    colour: dict  # the sphere's colour block (brdffit.fitting.sphere.sphere_colour)
    basis: str  # what the verdict judged: "sphere" or "held_out"
    input: dict | None  # FitResult.input: a sample list's summary, coverage, folds
    measurable: bool  # every error could be measured (a NaN is no success)


class TableInput:
    """A MERL table (``brdffit.io.merl.MerlTable``): the grid's fast paths."""

    what = "bins"

    def __init__(self, table: MerlTable):
        self.table = table

    @property
    def source(self) -> str:
        return self.table.source

    def prepare(self, bin_weight, samples, seed: int, precision: str, loss: str) -> Prepared:
        cached(self.table, "blank-but-spikes", lambda: refuse_blank_but_spikes(self.table))
        return prepare(self.table, bin_weight, samples, seed, precision, loss)

    def start_table(self, prep: Prepared) -> MerlTable:
        return self.table

    def distinct_usable(self, prep: Prepared) -> int:
        return prep.n_usable  # each bin is its own direction pair

    def polishes(self, samples, init, prep: Prepared) -> bool:
        """Every bin (``samples=None``): the fit on the default subsample, with its
        starts and its nested parent, lands next to the optimum at ~1/70 of the cost
        per step; every bin then only polishes it (a few steps instead of dozens)."""
        return samples is None and init is None and prep.n_usable > 4 * DEFAULT_SAMPLES

    def ready_report(self, model, u, prep: Prepared, loss: str, precision: str, solver: str,
                     full_table: bool = True):
        return ready_report_once(self.table, model, u, prep, loss, precision, solver,
                                 full_table=full_table)

    def refuse_bound(self) -> None:
        """A table can be fitted under the physical bounds."""

    def measure(self, model, u_best, params: dict, prep: Prepared, refit: Refit | None,
                seed: int, solver_metrics: dict, table_metrics: dict | None = None,
                ) -> Measured:
        """The full-table error (``table_metrics`` where it was measured already;
        ``solver_metrics``, the solver's own, beside it), and the image error of the
        whole sphere (no scene weighting: one figure that compares fits made under
        different losses)."""
        metrics = dict(table_metrics) if table_metrics is not None else full_table_metrics(
            self.table, model, u_best, prep.weight, peak=prep.peak)
        metrics.update(solver_metrics)
        measurable = all(np.isfinite(v) for v in metrics.values())
        metrics["psnr_db"], colour = sphere_reference(self.table).psnr_and_colour(model, params)
        return Measured(metrics, colour, "sphere", None, measurable)

    def judged(self, look: dict, measured: Measured, uncertainty: dict | None) -> tuple[dict,
                                                                                       None]:
        """The verdict with the share of its sphere the table measures."""
        return on_part_of_the_sphere(look, sphere_reference(self.table).measured_share), None

    def refuse_too_few(self, model) -> None:
        """A table is counted once prepared (its bins, the scene's weights)."""

    def findings(self, prep: Prepared) -> tuple[list[str], list[dict]]:
        """What the table holds that the fit's reader should be told of, as notes and
        as next steps (``quality.next_steps``' form): bins the fit used that stand far
        above all their neighbours (``MerlTable.isolated_spikes``), corrupt values that a
        least-squares fit follows."""
        notes, steps = _too_bright(prep)
        # the whole table's brightest (a unit is the table's, whatever a scene weighs),
        # once per table: auto's candidates share it
        brightest = cached(self.table, "brightest-value", lambda: _brightest(self.table.rgb))
        dark_notes, dark_steps = _too_dark(brightest, "table")
        if not dark_notes:
            # a sharp highlight keeps the brightest value up in a table whose every
            # other value is 1500x too dark: its mean says so
            dark_notes, dark_steps = _too_dark_on_average(
                cached(self.table, "mean-level", lambda: mean_level(self.table)))
        notes, steps = notes + dark_notes, steps + dark_steps
        notes += _partly_negative(self.table)
        spikes = cached(self.table, "isolated-spikes", self.table.isolated_spikes)
        used = prep.counts.usable.reshape(merl.SHAPE)
        spikes = [tuple(int(x) for x in b) for b in spikes if used[tuple(b)]]
        if not spikes:
            return notes, steps
        first = spikes[0]
        value = float(self.table.rgb[(slice(None), *first)].max())
        what = (f"{len(spikes):,} bin{'s' if len(spikes) != 1 else ''} over "
                f"{merl.SPIKE_FACTOR:,.0f}x every measured neighbour on the grid (the "
                f"brightest: {value:.3g} 1/sr at theta_h, theta_d, phi_d bin {list(first)})")
        return ([*notes, f"{what}: a corrupt value? A least-squares fit follows such a bin; "
                 "mark it unmeasured (a negative value) to leave it out"],
                [*steps, {"try": "the table without its spikes (mark them unmeasured: a "
                          "negative value)",
                          "why": f"{what}: no reflectance changes so from one bin to the next, "
                                 "and the fit follows them", "gain_db": None}])


#: The diffuse floor's albedo (pi times a low percentile of the mid-angle bins,
#: ``brdffit.fitting.starts.diffuse_estimate``) above which a table's values are
#: not in 1/sr: a surface reflects at most what it receives (albedo 1), and the
#: brightest of the 100 MERL materials is at 0.41 (light-red-paint's red). A MERL
#: table written without its channel scales (1/1500, 1.15/1500, 1.66/1500) is ~1500x
#: too bright; the fit still runs, in the units it was given, and says so.
SUSPECT_ALBEDO = 2.0


#: The share of a table's bins, negative in some channels only, from which a fit says
#: that they were left out and how that biases it.
PARTIAL_SHARE = 0.01


def _partly_negative(table: MerlTable) -> list[str]:
    n, measured = table.n_partial, table.n_measured
    if n < PARTIAL_SHARE * (n + measured):
        return []
    return [f"{n:,} bins ({n / (n + measured):.0%}) are negative in some channels and not "
            "in others: left out whole, as MERL marks an unmeasured bin (negative in every "
            "channel). If they are noise around zero (a dark frame subtracted), leaving them "
            "out biases the dark channels upward: clip such values to 0 instead"]


#: Why a table's values may not be in 1/sr (:func:`_too_bright`).
MERL_SCALES = ("MERL's .binary holds values to be scaled by 1/1500, 1.15/1500 and "
               "1.66/1500 per channel")
#: Why a sample list's may not be: a reflectance in percent, as many instruments export.
SAMPLE_SCALES = ("Values in percent are 100 times a fraction (a reflectance factor R in % is "
                 "a BRDF of R / (100 pi) 1/sr)")


def refuse_blank_but_spikes(table: MerlTable) -> bool:
    """Refuse a table that is blank (every measured bin below ``merl.MIN_PEAK``, as
    the reader refuses one) but for isolated spikes (``MerlTable.isolated_spikes``):
    one corrupt bin of 1e6 in a table of zeros got past the reader's blank check, which
    reads the brightest bin, and was fitted "good" at 100 dB, black against black, its
    kd and ks at their bounds. Returns False (checked, once per table: ``cached``)."""
    spikes = cached(table, "isolated-spikes", table.isolated_spikes)
    if len(spikes) == 0:
        return False
    rest = table.rgb.max(axis=0)  # a new array: the table's stays as it is
    rest[tuple(spikes.T)] = 0.0
    brightest = float(rest.max())
    if brightest >= merl.MIN_PEAK:
        return False
    first = [int(x) for x in spikes[0]]
    value = float(table.rgb[(slice(None), *first)].max())
    raise FitInputError(
        f"{table.source}: no reflectance to fit but {len(spikes):,} isolated spike"
        f"{'s' if len(spikes) != 1 else ''} (the brightest {value:.3g} 1/sr at theta_h, "
        f"theta_d, phi_d bin {first}, over {merl.SPIKE_FACTOR:,.0f}x every measured "
        f"neighbour): every other measured bin is at most {brightest:.3g} 1/sr, below "
        f"{merl.MIN_PEAK:g}: a blank table (zeros) with corrupt values")


def _too_bright(prep: Prepared, what: str = "table",
                why: str = MERL_SCALES) -> tuple[list[str], list[dict]]:
    """A note and a next step where ``what``'s diffuse floor (the starts' hint, read
    from the table, or from a sample list binned) implies an albedo over
    :data:`SUSPECT_ALBEDO`: values in another unit, which the fit follows silently
    (a list in percent fitted kd [20, 10, 5], judged good). ``why``: the usual cause."""
    hints = prep.hints
    if (hints is None or not hints.kd_from_mid_angles or not np.all(np.isfinite(hints.kd))
            or hints.kd.max() <= SUSPECT_ALBEDO):
        # (a floor read from bins near the highlight, where the table has no others, is
        # the highlight: it told a table measured at its peak alone to divide by 1500)
        return [], []
    return _unit_question(
        f"the {what}'s diffuse floor is an albedo of {hints.kd.max():.3g} (pi times its "
        "mid-angle level; no surface reflects more than it receives, 1): are its values "
        f"in 1/sr? {why}", what)


def _unit_question(said: str, what: str) -> tuple[list[str], list[dict]]:
    """The note and the next step of values that ``said`` doubts are in 1/sr."""
    return ([f"{said}; fitted as given, so the fit's reflectances are in the {what}'s units "
             "(or at their bound, where the model caps them at 1)"],
            [{"try": f"the {what} in 1/sr", "why": said, "gain_db": None}])


#: The brightest value (1/sr) below which a table's or a list's values are read as not in
#: 1/sr: 280x below the lowest brightest value of the 100 MERL materials (white-fabric2,
#: 0.28 1/sr; then black-fabric, 0.35 at a grazing peak), and a Lambertian albedo of 0.3%
#: (black velvets and paints reflect 0.5-2%). A MERL table scaled by its channel factors
#: twice is ~1500x too dark, a fraction read as percent 100x; the fit follows either
#: silently and may even look good (its renders are exposed to the table's own level).
SUSPECT_DARK = 0.001
#: The lowest brightest value of the 100 MERL materials (white-fabric2), 1/sr.
MERL_DARKEST = 0.28
#: Why a table or a list may be too dark (:func:`_too_dark`).
DARK_SCALES = ("a MERL table scaled by its 1/1500 channel factors twice is ~1500x too "
               "dark, a reflectance fraction divided by 100 as if in percent 100x")


def _too_dark(brightest: float, what: str) -> tuple[list[str], list[dict]]:
    """A note and a next step where ``what``'s brightest used value (1/sr) is below
    :data:`SUSPECT_DARK`: values in another unit, as :func:`_too_bright`'s."""
    return _darker_than_merl(
        brightest, SUSPECT_DARK, f"the {what}'s brightest value is",
        f"the lowest of the 100 MERL materials' brightest values (white-fabric2: "
        f"{MERL_DARKEST}", MERL_DARKEST, what)


def _darker_than_merl(value: float, suspect: float, measure: str, merl_words: str,
                      darkest: float, what: str) -> tuple[list[str], list[dict]]:
    """The unit question where ``value`` (1/sr, what ``measure`` names) is below
    ``suspect``, saying how far below the MERL materials' ``darkest`` it is."""
    if not (np.isfinite(value) and 0 < value < suspect):
        return [], []
    return _unit_question(
        f"{measure} {value:.3g} 1/sr, {darkest / value:,.0f}x below {merl_words} 1/sr): "
        f"are its values in 1/sr? {DARK_SCALES}", what)


#: The mean value (1/sr, :func:`mean_level`) below which a table's values are read as
#: not in 1/sr: 10x below the darkest of the 100 MERL materials (black-fabric, 0.0067
#: 1/sr; the next, specular-black-phenolic, 0.010; the brightest, 0.17). A MERL table
#: scaled by its channel factors twice: 1.1e-4 at most; a table of black-fabric divided
#: by 100 (percent): 6.7e-5. Only a surface darker than 0.2% albedo on average (a
#: Vantablack) is asked about wrongly; a mirror's peak keeps its mean up (chrome-steel:
#: 0.05 1/sr), where its diffuse floor is 0.
SUSPECT_DARK_MEAN = 6.7e-4
#: The lowest mean value of the 100 MERL materials (black-fabric), 1/sr.
MERL_DARKEST_MEAN = 0.0067


def mean_level(table: merl.MerlTable) -> float:
    """The table's brightest channel averaged over its measured bins, each weighted
    by its solid angle (1/sr): its typical value, whatever its highlight."""
    from brdffit.io.grid import bin_grid

    measured = table.mask.ravel()
    w = bin_grid().weight.ravel()
    w_measured = float(np.sum(w, where=measured))
    if not w_measured > 0:
        return float("nan")
    # over the whole grid, the unmeasured bins zeroed: a boolean selection copied the
    # table and took ~13x as long (75 against 6 ms, a third of a warm ggx fit)
    rgb = table.rgb.reshape(3, -1)
    brightest = np.where(measured, np.maximum(np.maximum(rgb[0], rgb[1]), rgb[2]), 0.0)
    return float(np.dot(brightest, w) / w_measured)


def _too_dark_on_average(mean: float) -> tuple[list[str], list[dict]]:
    """As :func:`_too_dark`, from the table's :func:`mean_level`."""
    return _darker_than_merl(
        mean, SUSPECT_DARK_MEAN, "the table's values (its brightest channel, over its "
        "measured bins by solid angle) average",
        f"the darkest of the 100 MERL materials (black-fabric: {MERL_DARKEST_MEAN}",
        MERL_DARKEST_MEAN, "table")


def _brightest(values: np.ndarray) -> float:
    """The largest finite value of ``values`` (NaN where there is none)."""
    if values.size:
        top = values.max()
        if np.isfinite(top):  # a table's values always are: no selection to copy
            return float(top)
    v = values[np.isfinite(values)]
    return float(v.max()) if v.size else float("nan")


class SampleInput:
    """A sample list (``brdffit.io.measurements.Measurements``), fitted at its own
    directions (``brdffit.fitting.samples``)."""

    what = "samples"

    def __init__(self, meas: Measurements):
        from brdffit.fitting import samples

        self.meas, self._samples = meas, samples

    @property
    def source(self) -> str:
        return self.meas.source

    def prepare(self, bin_weight, samples, seed: int, precision: str, loss: str) -> Prepared:
        return self._samples.prepare_samples(self.meas, bin_weight, samples, seed, precision,
                                             loss)

    def start_table(self, prep: Prepared) -> MerlTable:
        return prep.start_table  # the samples binned: the floor and the peak they hold

    def distinct_usable(self, prep: Prepared) -> int:
        return self._samples.distinct_usable(self.meas, prep)

    def polishes(self, samples, init, prep: Prepared) -> bool:
        return False  # a list up to `samples` is fitted whole

    def ready_report(self, model, u, prep: Prepared, loss: str, precision: str, solver: str,
                     full_table: bool = True):
        return None

    def findings(self, prep: Prepared) -> tuple[list[str], list[dict]]:
        """What the list holds that the fit's reader should be told of (its coverage
        and binning are in the input block): values in another unit than 1/sr, as a
        table's (:func:`_too_bright`), rows that repeat another exactly, rows of zeros,
        lone samples far brighter than their nearest (``samples.isolated_spikes``) and
        an azimuth convention other than brdffit's."""
        notes, steps = _too_bright(prep, "sample list", SAMPLE_SCALES)
        usable = self._samples.on_the_surface(self.meas)
        dark_notes, dark_steps = _too_dark(_brightest(self.meas.rgb[usable]), "sample list")
        notes, steps = notes + dark_notes, steps + dark_steps
        within = self.meas.provenance.get("azimuths_within_deg")
        if within is not None:
            radians = ("if they are radians, name their columns phi_i_rad and phi_o_rad "
                       "(HDF5: their units 'radians')")
            notes.append(
                f"every azimuth lies within {within:.3g} degrees (the file says degrees) and "
                "most are not whole numbers: are they radians? Read as degrees, every "
                f"direction lies within {within:.2g} degrees of one plane; {radians}")
            steps = [{"try": "name the azimuth columns phi_i_rad and phi_o_rad if they are "
                             "radians (HDF5: their units 'radians')",
                      "why": f"every azimuth lies within {within:.3g} degrees, and most are "
                             "not whole numbers", "gain_db": None}, *steps]
        spike_notes, spike_steps = self._samples.spike_finding(self.meas, prep)
        return (notes + self._samples.duplicate_note(self.meas, prep)
                + self._samples.zero_note(self.meas, prep) + spike_notes,
                self._samples.azimuth_convention_step(self.meas, prep) + steps + spike_steps)

    def refuse_too_few(self, model) -> None:
        """Refuses, before the preparation (binning, weights, the solver's data: ~5 s
        for a million samples), a list with too few usable samples or distinct direction
        pairs for ``model``: the samples above the horizon, which a scene's weights only
        thin, so that what is refused here would be refused after it too."""
        usable = self._samples.on_the_surface(self.meas)
        on_horizon = self.meas.n - int(usable.sum())
        _refuse_too_few(self, int(usable.sum()),
                        lambda: self._samples.distinct_pairs(self.meas, usable), model,
                        scene=False,
                        # all 500 at theta_o 90 read "only 0 usable samples", no more
                        dropped=(f"{on_horizon:,} of its {self.meas.n:,} lie on the horizon, "
                                 "a light or view at 90 degrees, where f cos is 0"
                                 if on_horizon else ""))

    def refuse_bound(self) -> None:
        raise FitInputError(
            f"{self.source}: the physical bounds are not available for a sample list "
            "yet (their albedo check reads a table): fit it without them")

    def measure(self, model, u_best, params: dict, prep: Prepared, refit: Refit | None,
                seed: int, solver_metrics: dict, table_metrics: dict | None = None,
                ) -> Measured:
        """Every metric over every sample (``solver_metrics`` beside them), the k-fold
        held-out error (each fold refitted by ``refit``; none where the solve diverged
        or the error cannot be measured), and the look from the sphere where the
        samples cover it, else from the held-out predictions. (``table_metrics``: a
        table's only; a sample list's fits are measured one by one.)"""
        s = self._samples
        metrics = s.sample_metrics(model, u_best, s.every_sample(self.meas, prep.weight))
        metrics.update(solver_metrics)
        measurable = all(np.isfinite(v) for v in metrics.values())
        held = None
        if refit is not None and measurable:
            held = s.held_out(model, self.meas, u_best, prep, refit, seed=seed)
        if held is not None:
            metrics.update({f"held_out_{k}": v for k, v in held.metrics.items()})
            measurable &= all(np.isfinite(v) for v in held.metrics.values())
        metrics["psnr_db"], colour, basis = s.look(self.meas, prep, held, model, params)
        return Measured(metrics, colour, basis,
                        s.fitted_input(self.meas, prep, model, params, held), measurable)

    def judged(self, look: dict, measured: Measured, uncertainty: dict | None) -> tuple[dict,
                                                                                       dict]:
        """The verdict as held-out samples can stand behind it, and the input's report
        with each parameter's identifiability."""
        fitted = {**measured.input,
                  "identifiability": self._samples.identifiability(uncertainty)}
        return self._samples.within_samples(look, fitted), fitted


def fit_input(table) -> TableInput | SampleInput:
    """The input kind of what ``brdffit.fit`` was given; anything else is refused."""
    if isinstance(table, MerlTable):
        return TableInput(table)
    if isinstance(table, Measurements):
        return SampleInput(table)
    raise FitInputError(f"fit takes a MerlTable (brdffit.io.merl.read) or Measurements "
                        f"(brdffit.io.readers.read_measured), got {type(table).__name__}")


def _count(n: int, plural: str) -> str:
    """``n`` and its noun, singular for one: "1 usable sample", "2 usable samples"."""
    return f"{n:,} {plural[:-1] if n == 1 and plural.endswith('s') else plural}"


def _refuse_too_few(source: TableInput | SampleInput, n_usable: int,
                    distinct: Callable[[], int], model, scene: bool,
                    dropped: str = "") -> None:
    """Refuses ``n_usable`` samples (or bins), or their ``distinct()`` direction pairs,
    fewer than ``model`` needs: 4 per parameter. ``dropped``: what was left out, said."""
    what = source.what
    least = model.n_params * 4
    if n_usable < least:
        raise FitInputError(
            f"{source.source}: only {_count(n_usable, 'usable ' + what)} (measured, finite, "
            f"above the horizon{', weighted by the scene' if scene else ''})"
            f"{': ' + dropped if dropped else ''}; {model.name} needs at least {least}")
    pairs = distinct()
    if pairs < least:
        # repeated measurements of one direction pair (or rows pasted twice) are one
        # sample of the BRDF's shape: 100 copies of the normal's were fitted and judged good
        raise FitInputError(
            f"{source.source}: the {_count(n_usable, 'usable ' + what)} hold only "
            f"{_count(pairs, 'distinct direction pairs')} (repeats of a pair count once); "
            f"{model.name} needs at least {least}")


def check_enough(source: TableInput | SampleInput, prep: Prepared, model,
                 scene: bool) -> None:
    """Refuse, with the reason, an input with too little to fit ``model``."""
    what = source.what
    _refuse_too_few(source, prep.n_usable, lambda: source.distinct_usable(prep), model, scene)
    if prep.brightest < merl.MIN_PEAK:
        raise FitInputError(
            f"{source.source}: every usable {what[:-1]} is below {merl.MIN_PEAK:g} 1/sr"
            f"{' under the scene' if scene else ''}: nothing to fit")
