"""The service's cost estimate against the jobs measured on this machine.

``bench/results/job_shapes.json`` holds peak memory and wall time of each job shape
(``python -m bench.job_shapes``); the estimate for the same request must be above the
measurement and within 2x of it. A change to the estimate's constants, or to how a
request is counted, that breaks either side fails here; a change to the fits' cost
needs the benchmark run again.
"""

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from api.estimate import MACHINE_HEADROOM, _with_parents, counts_the_work, estimate, machine_factor
from brdffit.request import FitRequest

pytestmark = pytest.mark.unit

RESULTS = Path(__file__).resolve().parents[1] / "bench" / "results"
MEASURED = RESULTS / "job_shapes.json"
#: The same shapes on a machine 1.3-2.4x slower than the one the constants fit, and on
#: this machine at an hour 1.3-1.6x slower, with the layered shapes
SLOWER = (RESULTS / "job_shapes_xeon.json", RESULTS / "job_shapes_slow_hour.json")


def _rows(path=MEASURED):
    res = json.loads(path.read_text())
    return res["usable_bins"], res["rows"]


def _request(spec: dict) -> FitRequest:
    spec = dict(spec)
    return FitRequest.of(spec.pop("model"), **spec)


@pytest.mark.parametrize("row", _rows()[1], ids=lambda r: r["shape"])
def test_the_estimate_is_above_the_measured_job_and_within_2x(row):
    usable, _ = _rows()
    cost = estimate(_request(row["request"]), usable)
    assert row["peak_rss_mib"] <= cost.memory_mib <= 2 * row["peak_rss_mib"], cost.detail
    assert row["wall_s"] <= cost.seconds <= 2 * row["wall_s"], cost.detail


def test_the_measured_shapes_cover_what_the_issue_names():
    shapes = {r["shape"] for r in _rows()[1]}
    assert {"default ggx", "every bin, 1 start", "every bin, 4 starts", "ggx2", "auto",
            "render loss"} <= shapes


def test_a_full_table_four_start_ggx_job_is_accepted_under_the_default_limits():
    from api.services.fits import over_limits
    from api.settings import Settings

    cost = estimate(FitRequest.of("ggx", samples=None, starts=4), 1_096_216)
    assert over_limits(cost, Settings()) is None
    assert "then one start on every bin" in cost.detail


def test_starts_and_steps_count_but_max_steps_only_as_a_cap():
    base = estimate(FitRequest.of("ggx"), 1_000_000)
    assert estimate(FitRequest.of("ggx", starts=8), 1_000_000).seconds > base.seconds
    assert estimate(FitRequest.of("ggx", max_steps=10), 1_000_000).seconds < base.seconds
    assert estimate(FitRequest.of("ggx", max_steps=10_000), 1_000_000).seconds == base.seconds
    # a nested model fits its parent too; auto holds every candidate
    assert estimate(FitRequest.of("ggx2"), 1_000_000).seconds > base.seconds
    assert estimate(FitRequest.of("auto"), 1_000_000).memory_mib > base.memory_mib


@pytest.mark.parametrize("path", SLOWER, ids=lambda p: p.stem)
def test_on_a_slower_machine_what_a_server_learns_keeps_every_estimate_above_its_job(path):
    """The constants are under the slower machine's jobs; the factor a server learns
    from its jobs (here every other shape's runs, so no row judges itself) is not.
    Memory is not learned: the estimate is above every peak as it is."""
    usable, rows = _rows(path)
    reference = {r["shape"]: estimate(_request(r["request"]), usable).reference_seconds
                 for r in rows}
    assert any(reference[r["shape"]] < r["wall_s"] for r in rows)  # the constants alone
    for row in rows:
        factor = machine_factor([(reference[r["shape"]], run["wall_s"]) for r in rows
                                 if r is not row for run in r["runs"]])
        cost = estimate(_request(row["request"]), usable, machine=factor)
        assert row["wall_s"] <= cost.seconds <= 2.5 * row["wall_s"], (row["shape"], factor)
        assert row["peak_rss_mib"] <= cost.memory_mib <= 2 * row["peak_rss_mib"], row["shape"]
        assert cost.seconds == pytest.approx(factor * cost.reference_seconds)
        assert f"time x{factor:.2f}" in cost.detail


def test_the_machine_factor_only_ever_raises_the_estimate():
    assert machine_factor([]) == 1.0
    assert machine_factor([(2.0, 1.0), (10.0, 3.0)]) == 1.0  # a faster machine
    assert machine_factor([(2.0, 1.0), (2.0, 4.0)]) == pytest.approx(2 * MACHINE_HEADROOM)
    assert machine_factor([(0.0, 4.0), (2.0, 0.0)]) == 1.0  # nothing measured
    plain = estimate(FitRequest.of("ggx"), 1_000_000)
    assert plain.seconds == plain.reference_seconds and "time x" not in plain.detail


def test_every_model_has_its_measured_cost_and_a_plugin_counts_the_costliest():
    """A model added to the catalogue without a measured cost would be counted at the
    costliest one's: run ``python -m bench.model_costs`` after adding one."""
    from api.model_costs import EXTRA_S
    from brdffit.models import catalogue

    builtin = {d["name"] for d in catalogue.describe()}
    assert set(EXTRA_S) == builtin and all(s >= 0.0 for s in EXTRA_S.values())
    # auto's default candidates are held by the measured job shapes, not added to
    assert all(EXTRA_S[name] == 0.0 for name in catalogue.auto_candidates())
    costly = max(EXTRA_S, key=EXTRA_S.get)
    request = FitRequest.of(costly)
    parents = {d["name"]: d.get("parent") for d in catalogue.describe()}
    fitted = _with_parents([costly], parents)  # a nested model's parents add theirs
    assert estimate(request, 10**6).seconds == pytest.approx(
        estimate(request, 10**6, extra={}).seconds + sum(EXTRA_S[m] for m in fitted))
    # a model without measured seconds (a plugin's) counts the largest
    assert estimate(request, 10**6, extra={"ggx": 3.0}).seconds == pytest.approx(
        estimate(request, 10**6, extra={costly: 3.0}).seconds)


@pytest.mark.parametrize("base", ["ggx", "ggx2", "phong"])
def test_a_grey_specular_variant_counts_its_own_parameters(base):
    """``ggx_mono`` fits fewer numbers than ggx and has no parent: it costs no more
    than its base (it was counted as a plugin's model, at the largest count)."""
    from brdffit.models import catalogue

    mono = base + catalogue.MONO_SUFFIX
    plain, grey = (estimate(FitRequest.of(m, samples=None, starts=4), 1_096_216)
                   for m in (base, mono))
    assert grey.seconds <= plain.seconds and grey.memory_mib <= plain.memory_mib
    assert catalogue.n_params(mono) < catalogue.n_params(base)


def test_the_measured_jobs_teach_the_machine_and_an_uncounted_refit_does_not():
    """A job's worker time teaches the server its machine's speed only where the
    estimate counted the job's work: every measured shape's fit did (its starts and
    steps as the benchmark recorded them); auto's refit of an unconverged candidate
    (4 starts, hundreds of steps: a scene's beckmann took 638) did not, and it once made
    every later estimate 5x too high."""
    usable, rows = _rows()
    fixed = [r for r in rows if r["request"]["model"] != "auto"]
    assert len(fixed) >= 5
    for row in fixed:
        request = _request(row["request"])
        for run in row["runs"]:
            fit = SimpleNamespace(model=request.fitted_models[0], starts=run["starts"],
                                  steps=run["steps"])
            assert counts_the_work(request, [fit], usable), (row["shape"], run)
    auto = FitRequest.of("auto")
    ggx = SimpleNamespace(model="ggx", starts=1, steps=25)
    assert counts_the_work(auto, [ggx], usable)
    refit = SimpleNamespace(model="beckmann", starts=4, steps=638)
    assert not counts_the_work(auto, [ggx, refit], usable)
