"""Fitting: parameter recovery from two independent writers, failures as values."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from brdffit import FitInputError, fit
from brdffit.fitting.pipeline import FitResult
from brdffit.io import merl
from data_synth import make_table
from tests import reference_merl
from tests.truths import FIT_JSON_KEYS, TRUTH, assert_params_close

pytestmark = pytest.mark.unit

MODELS = list(TRUTH)


@pytest.fixture(scope="module")
def synth_tables():
    return {name: make_table(name, TRUTH[name])[0] for name in MODELS}


@pytest.mark.parametrize("name", MODELS)
def test_recovers_params_from_data_synth_table(name, synth_tables):
    r = fit(synth_tables[name], name)
    assert r.converged, r.result
    assert_params_close(r.params, TRUTH[name], rel=0.02)
    assert r.log_rmse < 1e-6


@pytest.mark.parametrize("name", MODELS)
def test_recovers_params_from_independent_writer(name, tmp_path):
    """The table comes from tests/reference_merl.py (plain numpy from docs/models.md)
    and goes through the file reader: a bug shared by brdffit and data_synth
    cannot hide here."""
    path = tmp_path / f"{name}.binary"
    reference_merl.write(path, name, TRUTH[name])
    r = fit(merl.read(path), name)
    assert r.converged, r.result
    assert_params_close(r.params, TRUTH[name], rel=0.02)


@pytest.mark.parametrize("name", MODELS)
def test_recovers_params_with_noise_and_missing_bins(name):
    table, _ = make_table(name, TRUTH[name], noise=0.05, missing=0.1, seed=7)
    r = fit(table, name)
    assert_params_close(r.params, TRUTH[name], rel=0.05, abs_small=0.005)
    assert 1e-4 < r.log_rmse < 0.05  # the noise is visible in the error, nothing more
    assert r.samples["dropped"]["unmeasured"] > 0.1 * 90 * 90 * 180 * 0.5


def test_result_is_plain_json_with_the_documented_schema(synth_tables):
    r = fit(synth_tables["ggx"], "ggx")
    d = json.loads(r.to_json())
    for key in (*FIT_JSON_KEYS, "solver"):
        assert key in d, key
    assert set(d["params"]) == {"kd", "ks", "alpha", "f0"}
    assert len(d["params"]["kd"]) == 3 and isinstance(d["params"]["alpha"], float)
    assert d["error"]["log_rmse"] >= 0
    assert d["samples"]["used"] <= d["samples"]["usable"] <= d["samples"]["measured"]
    assert FitResult.from_dict(d).params == r.params


def test_non_converged_fit_is_reported_not_raised(synth_tables):
    r = fit(synth_tables["ggx"], "ggx", max_steps=1, starts=1)
    assert not r.converged
    assert r.result == "nonlinear_max_steps_reached"
    assert all(np.all(np.isfinite(v)) for v in r.params.values())
    assert math.isfinite(r.log_rmse)


def test_wrong_family_fit_is_finite_and_honest(synth_tables):
    r = fit(synth_tables["ggx"], "lambert")
    assert all(np.all(np.isfinite(v)) for v in r.params.values())
    assert r.log_rmse > 0.01  # a lambert cannot explain a highlight


@pytest.mark.parametrize("solver", ["dogleg", "bfgs", "optx-lm"])
def test_other_solvers_recover_a_simple_table(solver, synth_tables):
    r = fit(synth_tables["lambert"], "lambert", solver=solver, samples=4096)
    assert_params_close(r.params, TRUTH["lambert"], rel=0.02)
    assert r.solver == solver


def test_float32_agrees_with_float64(synth_tables):
    a = fit(synth_tables["ggx"], "ggx", precision="float64")
    b = fit(synth_tables["ggx"], "ggx", precision="float32")
    assert b.precision == "float32"
    assert_params_close(b.params, a.params, rel=0.01)


@pytest.mark.slow
def test_all_samples_and_subsample_agree(synth_tables):
    a = fit(synth_tables["beckmann"], "beckmann", samples=None, starts=2)
    assert a.samples["used"] == a.samples["usable"]
    assert_params_close(a.params, TRUTH["beckmann"], rel=0.02)
    # the starts asked ran on the subsample fit whose optimum every bin polished
    assert a.starts == 2 and any("polished, from one start" in n for n in a.notes)


def test_starts_say_what_was_refined(synth_tables):
    r = fit(synth_tables["lambert"], "lambert", starts=32, samples=4096)
    assert r.starts == 1
    assert r.notes == ("32 starts asked; lambert has 1 start candidate on these data, and "
                       "every one was refined",)
    assert fit(synth_tables["lambert"], "lambert", samples=4096).notes == ()
    from brdffit.cli.fit import format_result

    assert format_result(r).endswith("\n  note: " + r.notes[0])  # what brdffit fit prints


def test_bin_weight_restricts_the_loss(synth_tables):
    table = synth_tables["ggx"]
    w = np.zeros(table.mask.size)
    w[: w.size // 2] = 1.0  # theta_h rows 0..44 only
    r = fit(table, "ggx", bin_weight=w)
    assert r.samples["usable"] < table.n_measured
    assert_params_close(r.params, TRUTH["ggx"], rel=0.02)


def test_user_init_is_used(synth_tables):
    r = fit(synth_tables["ggx"], "ggx", init=TRUTH["ggx"], max_steps=50)
    assert r.starts == 1 and r.steps <= 3
    with pytest.raises(ValueError, match="alpha"):
        fit(synth_tables["ggx"], "ggx", init={**TRUTH["ggx"], "alpha": -1.0})


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"solver": "newton"}, "unknown solver"),
        ({"precision": "float16"}, "unknown precision"),
        ({"samples": 3}, "samples"),
        ({"starts": 0}, "starts"),
        ({"max_steps": 0}, "max_steps"),
        ({"bin_weight": np.ones(10)}, "bin_weight"),
        ({"bin_weight": -np.ones(90 * 90 * 180)}, "bin_weight"),
        ({"seed": 1.5}, "seed must be an integer"),
        ({"seed": -1}, "seed must be an integer"),
        ({"starts": True}, "starts"),
        ({"samples": 4096.0}, "samples"),
        ({"init": {"kd": "a"}}, "init: lambert: kd must be a number or three, got 'a'"),
        # numpy reads these as 0.5 and 1.0: a hand-edited result's alpha: true was a roughness
        ({"init": {"kd": "0.5"}}, "init: lambert: kd must be a number or three, got '0.5'"),
        ({"init": {"kd": True}}, "init: lambert: kd must be a number or three, got True"),
        ({"init": {"kd": [0.5, "0.5", 0.5]}}, "kd must be a number or three"),
        # three values, nested: "needs 3 value(s), got 3" said nothing
        ({"init": {"kd": [[0.5], [0.5], [0.5]]}},
         r"kd needs 3 value\(s\), got an array of shape \[3, 1\], not a flat list"),
        ({"init": {"kd": [0.5, 0.5]}}, r"kd needs 3 value\(s\), got 2"),
        ({"loss": ["log"]}, "loss must be a name"),
    ],
)
def test_bad_options_raise_input_errors(kwargs, message, synth_tables):
    with pytest.raises(FitInputError, match=message):
        fit(synth_tables["lambert"], "lambert", **kwargs)


def test_a_parent_fit_of_another_model_or_table_is_refused(synth_tables):
    """A given parent fit is the one the model contains, of this table: another table's
    was embedded as the start, another model's dropped without a word."""
    from brdffit.io.merl import MerlTable

    table = synth_tables["ggx"]
    mine = MerlTable(table.rgb, table.mask, "mine.binary")
    other = MerlTable(table.rgb, table.mask, "other.binary")
    lambert = fit(mine, "lambert", samples=4096)
    with pytest.raises(FitInputError, match="parent_fit is a lambert fit; oren_nayar contains "
                                            "lambert|parent_fit is a lambert fit; ggx2 "
                                            "contains ggx"):
        fit(mine, "ggx2", samples=4096, parent_fit=lambert)
    with pytest.raises(FitInputError, match="ggx contains none"):
        fit(mine, "ggx", samples=4096, parent_fit=lambert)
    with pytest.raises(FitInputError, match="parent_fit is a fit of other.binary .*, not of "
                                            "mine.binary"):
        fit(mine, "oren_nayar", samples=4096, parent_fit=fit(other, "lambert", samples=4096))
    assert fit(mine, "oren_nayar", samples=4096, parent_fit=lambert).converged


def test_a_scene_weight_far_from_one_is_only_its_shape(synth_tables):
    """bin_weight multiplies the solid angles and is normalised with them: at 5e-324
    everywhere (denormal) it underflowed into a 'nonfinite' fit with a log_rmse of 0."""
    n = 90 * 90 * 180
    ones = fit(synth_tables["lambert"], "lambert", bin_weight=np.ones(n))
    tiny = fit(synth_tables["lambert"], "lambert", bin_weight=np.full(n, 5e-324))
    assert tiny.converged and tiny.params == ones.params and tiny.error == ones.error


def test_numpy_integers_are_counts(synth_tables):
    """A count read from an array (numpy's int64) is an integer like any other."""
    r = fit(synth_tables["lambert"], "lambert", samples=np.int64(4096), starts=np.int64(2),
            seed=np.uint32(3))
    assert r.samples["used"] == 4096 and r.converged


def test_table_with_too_few_bins_is_refused():
    table, _ = make_table("lambert", TRUTH["lambert"])
    mask = np.zeros_like(table.mask)
    mask[40, 40, :5] = True
    tiny = merl.MerlTable.from_values(table.rgb, mask)
    with pytest.raises(FitInputError, match="usable bins"):
        fit(tiny, "ggx")


def test_params_come_in_the_model_order():
    """The result lists parameters as docs/models.md does (kd, ks, alpha, f0), not in
    a pytree's sorted order."""
    table, _ = make_table("ggx", TRUTH["ggx"])
    r = fit(table, "ggx", samples=2048)
    assert list(r.params) == ["kd", "ks", "alpha", "f0"]
    assert list(r.uncertainty["std_error"]) == list(r.params)


@pytest.mark.parametrize(("model", "kwargs"), [("ggx", {"samples": 3000}),
                                                ("ggx", {"samples": 5000, "loss": "cube_root"}),
                                                ("lambert", {"samples": None})])
def test_padding_a_sample_count_to_its_bucket_changes_no_result(model, kwargs, monkeypatch):
    """A sample count runs the compiled fit of its bucket (``sampling.SAMPLE_BUCKETS``;
    every bin, a multiple of the largest), its arrays padded with zero weights: the
    fit is the unpadded one, to rounding."""
    from brdffit.fitting import problem, sampling

    table, _ = make_table("ggx", TRUTH["ggx"], noise=0.05, missing=0.1, seed=3)
    bucketed = fit(table, model, **kwargs)
    n = bucketed.samples["used"]
    size = sampling.bucket_size(n)
    assert size in sampling.SAMPLE_BUCKETS or size % sampling.SAMPLE_BUCKETS[-1] == 0
    assert size > n  # something was padded
    monkeypatch.setattr(problem, "padded", lambda sample_set: sample_set)
    exact = fit(make_table("ggx", TRUTH["ggx"], noise=0.05, missing=0.1, seed=3)[0], model,
                **kwargs)
    assert exact.samples["used"] == n == (kwargs["samples"] or bucketed.samples["usable"])
    assert exact.result == bucketed.result == "successful"
    assert exact.steps == bucketed.steps
    for name, value in exact.params.items():
        np.testing.assert_allclose(bucketed.params[name], value, rtol=1e-9, atol=0)
    np.testing.assert_allclose(bucketed.log_rmse, exact.log_rmse, rtol=1e-9)
    assert bucketed.uncertainty["residuals"] == exact.uncertainty["residuals"]


@pytest.mark.parametrize("name", ["standard_surface", "standard_surface_coat", "ggx"])
def test_the_solve_compiled_ahead_holds_every_start_the_ranking_refines(name):
    """In a new process the solve compiles while the starts are scored, before the
    ranking says how many it refines: the best-scored and, for standard_surface and
    its layers, the best of each metalness. Its bucket of starts is the one the solve
    then runs in, whatever the scores (some of them not finite)."""
    from brdffit import models
    from brdffit.fitting.pipeline import _best_of_each_family, _most_refined
    from brdffit.fitting.problem import start_bucket

    m = models.get(name)
    n = len(m.shape_grid)
    rng = np.random.default_rng(0)
    reached = 0
    for n_starts in (1, 2, 4):
        most = _most_refined(m, n, n_starts)
        for _ in range(50):
            scores = rng.uniform(size=n)
            scores[rng.uniform(size=n) < 0.2] = np.inf
            refined = len(_best_of_each_family(m, scores, n_starts))
            assert start_bucket(max(most, refined)) == start_bucket(most)
            reached = max(reached, refined - n_starts)
    # the family adds starts for standard_surface's models (so the bound is needed)
    assert (reached > 0) == (m.start_family is not None)


def test_tables_of_every_bin_share_the_compiled_fit_of_their_bucket():
    """Every bin of two tables with different usable counts, padded to the same
    multiple of the largest bucket: the second table compiles (or loads) nothing."""
    from brdffit import executables
    from brdffit.fitting import sampling

    first, _ = make_table("lambert", TRUTH["lambert"], missing=0.1, seed=3)
    mask = first.mask.copy()
    mask.reshape(-1)[np.flatnonzero(mask)[::997]] = False  # ~1300 bins fewer
    second = merl.MerlTable.from_values(first.rgb, mask)
    a = fit(first, "lambert", samples=None)
    before = len(executables.events)
    b = fit(second, "lambert", samples=None)
    n_a, n_b = a.samples["used"], b.samples["used"]
    assert n_a > n_b and sampling.bucket_size(n_a) == sampling.bucket_size(n_b)
    assert [e.name for e in executables.events[before:]] == []
    assert b.converged


def test_one_compiled_fit_serves_every_selectable_loss_and_sample_count(synth_tables):
    """Another loss of ``loss.SELECTABLE`` or a sample count up to a bucket is data
    for the default fit's programs: none is compiled (or loaded) again."""
    from brdffit import executables

    table = synth_tables["ggx"]
    fit(table, "ggx")
    before = len(executables.events)
    for kwargs in ({"loss": "cube_root"}, {"loss": "linear_cos"}, {"samples": 4096},
                   {"samples": 2048, "loss": "cube_root"}):
        r = fit(table, "ggx", **kwargs)
        assert r.converged, (kwargs, r.result)
    assert [e.name for e in executables.events[before:]] == []


def test_start_counts_share_the_compiled_solve_of_their_bucket(synth_tables, monkeypatch):
    """3 starts run the solve compiled for 4 (``problem.start_bucket``), the extra slot
    taking no step, and give what an unpadded batch of 3 gives; 4 starts then compile
    nothing."""
    from brdffit import executables
    from brdffit.fitting import problem, solve

    assert [problem.start_bucket(n) for n in (1, 2, 3, 4, 5, 9)] == [1, 2, 4, 4, 8, 16]
    table = synth_tables["ggx"]
    padded = fit(table, "ggx", starts=3, samples=2048)
    assert padded.starts == 3  # the padding is not reported as a start
    before = len(executables.events)
    fit(table, "ggx", starts=4, samples=2048)
    assert [e.name for e in executables.events[before:]] == []
    monkeypatch.setattr(solve, "start_bucket", lambda n: n)  # no padding
    exact = fit(table, "ggx", starts=3, samples=2048)
    assert (exact.result, exact.steps) == (padded.result, padded.steps)
    for name, value in exact.params.items():
        np.testing.assert_allclose(padded.params[name], value, rtol=1e-9, atol=0)


def test_max_steps_is_data_for_the_lm_solve(synth_tables):
    """Every ``max_steps`` runs the same compiled solve; running out of them is
    reported as it was when the limit was static."""
    from brdffit import executables

    table = synth_tables["ggx"]
    fit(table, "ggx")
    before = len(executables.events)
    short = [fit(table, "ggx", max_steps=n, starts=1) for n in (1, 2, 3)]
    assert [e.name for e in executables.events[before:]] == []
    for n, r in zip((1, 2, 3), short, strict=True):
        assert (r.result, r.steps) == ("nonlinear_max_steps_reached", n)
    assert fit(table, "ggx", max_steps=500).result == "successful"


def test_a_black_channel_has_no_relative_peak_error_of_its_own(synth_tables):
    """A pure red table (G and B all 0): each channel's error at the peak is relative
    to no less than 1% of the peak's brightest channel (it read 250 for an exact fit,
    an error divided by 1e-12)."""
    from brdffit.io.merl import MerlTable

    rgb = synth_tables["ggx"].rgb.copy()
    rgb[1:] = 0.0
    red = MerlTable.from_values(rgb, source="red.binary")
    r = fit(red, "ggx")
    assert r.converged and r.error["log_rmse"] < 1e-6
    assert r.error["rel_peak_error"] < 1e-4, r.error
    # a miss still reads as one: the red highlight 1.5x too high, ~50%; light in a black
    # channel counts against 1% of the red peak's value
    from brdffit.fitting.problem import table_error

    ks = np.asarray(r.params["ks"])
    high = table_error(red, "ggx", {**r.params, "ks": [1.5 * ks[0], 0.0, 0.0]})
    assert 0.3 < high["rel_peak_error"] < 0.7, high
    green = table_error(red, "ggx", {**r.params, "ks": [ks[0], 0.001 * ks[0], 0.0]})
    assert 0.05 < green["rel_peak_error"] < 0.2, green
    # the render loss's colour term: a black channel's mean is as black below 0.1% of
    # the brightest's as at 1e-30 (it pulled the shared alpha and f0 to their bounds,
    # ks 232 where 0.8, "successful" and "looks good")
    rendered = fit(red, "ggx", loss="render")
    assert rendered.converged and rendered.error["log_rmse"] < 1e-6, rendered.error
    truth = TRUTH["ggx"]
    assert rendered.params["alpha"] == pytest.approx(truth["alpha"], rel=1e-3)
    assert rendered.params["ks"][0] == pytest.approx(np.ravel(truth["ks"])[0], rel=1e-3)


def test_oren_nayar_stops_at_lamberts_optimum_where_no_roughness_lowers_the_loss(monkeypatch):
    """On this noisy Lambert table no sigma just above 0 lowers oren_nayar's loss at
    lambert's optimum (the first-order test, ``first_order_probes``): the fit is that
    optimum, its own starts not solved, and says so. Without the probes its starts run
    down to the same optimum. On an Oren-Nayar table the probes find the descent and
    the fit finds sigma. (On noise alone the slope in sigma has either sign: with
    seed 5 and 5% noise the probes find a descent, and the fit ends at sigma 0.008.)"""
    from brdffit.models.oren_nayar import OrenNayar

    table, _ = make_table("lambert", TRUTH["lambert"], noise=0.02, seed=2)
    lambert = fit(table, "lambert")
    probed = fit(table, "oren_nayar", parent_fit=lambert)
    assert any(n.startswith("nested: no gain: no value of what oren_nayar adds just off "
                            "lambert's optimum (sigma 0.01; sigma 0.1)") for n in probed.notes)
    assert probed.converged and probed.params["sigma"] < 1e-4
    np.testing.assert_allclose(probed.params["kd"], lambert.params["kd"], rtol=1e-9)
    assert probed.error["log_rmse"] == pytest.approx(lambert.error["log_rmse"], rel=1e-9)
    monkeypatch.setattr(OrenNayar, "first_order_probes", ())
    solved = fit(table, "oren_nayar", parent_fit=lambert)
    assert not any(n.startswith("nested: no gain") for n in solved.notes)
    assert solved.error["log_rmse"] == pytest.approx(probed.error["log_rmse"], rel=1e-5)
    monkeypatch.undo()
    rough, _ = make_table("oren_nayar", {"kd": [0.5, 0.35, 0.2], "sigma": 0.3}, noise=0.05,
                          seed=5)
    r = fit(rough, "oren_nayar")
    assert not any("no gain" in n for n in r.notes)
    assert r.params["sigma"] == pytest.approx(0.3, rel=0.05)


def test_a_lobe_held_at_its_narrowest_bound_is_noted():
    """A GGX table of alpha 3e-4 (below the model's 1e-3) came back alpha 0.001 and ks
    11x too low at +-0.3%, "good", with no word of the bound. A lobe that is there,
    held at the narrow end of the range, is noted; one at its broad end, or an absent
    lobe's shape, is not."""
    from brdffit import models
    from brdffit.fitting.assemble import _lobe_at_its_narrowest

    ggx, phong = models.get("ggx"), models.get("phong")
    held = {"at_bound": {"alpha": True, "f0": True}, "why": {}}
    (said,) = _lobe_at_its_narrowest(ggx, {"alpha": 0.001, "f0": 1.0}, held)
    assert said.startswith("alpha is held at its bound 0.001, the narrowest ggx holds")
    assert _lobe_at_its_narrowest(ggx, {"alpha": 2.0}, held) == []  # its broad end
    absent = {**held, "why": {"alpha": "no lobe: ks within 2 standard errors of 0"}}
    assert _lobe_at_its_narrowest(ggx, {"alpha": 0.001}, absent) == []
    assert _lobe_at_its_narrowest(ggx, {"alpha": 0.001}, None) == []
    top = next(s.upper for s in phong.param_specs if s.name == "n")
    (said,) = _lobe_at_its_narrowest(phong, {"n": top}, {"at_bound": {"n": True}, "why": {}})
    assert said.startswith(f"n is held at its bound {top:g}")
