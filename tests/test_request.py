"""brdffit.request: one request, one meaning, whatever door it came in by.

What a request means is decided when it is built (refused there, with the library's
words, before any table is read); :func:`run` returns every fit made and the one
chosen by the library's one rule; a failure crossing a process boundary is an
:class:`~brdffit.outcome.Outcome`.
"""

from __future__ import annotations

import json

import pytest

from brdffit.errors import FitInputError, MerlFormatError
from brdffit.fitting.options import FitOptions, SelectionRule
from brdffit.models import UnknownModelError
from brdffit.outcome import Outcome
from brdffit.request import REPORT_SCHEMA, REQUEST_SCHEMA, FitRequest, legacy_request, run
from brdffit.selection import DEFAULT_CANDIDATES, best, chosen_result
from data_synth import make_table

pytestmark = pytest.mark.unit

FAST = {"samples": 2048, "starts": 1}


@pytest.fixture(scope="module")
def lambert_table():
    return make_table("lambert", {"kd": [0.3, 0.2, 0.1]})[0]


# -- what a request means ------------------------------------------------------------------


def test_a_request_is_checked_when_it_is_built():
    r = FitRequest.of(["ggx", "lambert", "ggx"], samples=4096)
    assert r.models == ("ggx", "lambert") and not r.auto  # a model twice is fitted once
    assert r.options.samples == 4096 and r.fitted_models == ("ggx", "lambert")
    auto = FitRequest.of("auto", candidates=["lambert", "ggx"], tolerance=0.01)
    assert auto.auto and auto.fitted_models == ("lambert", "ggx")
    with pytest.raises(UnknownModelError):
        FitRequest.of("nope")
    with pytest.raises(UnknownModelError):
        FitRequest.of("auto", candidates=["ggx", "nope"])
    with pytest.raises(FitInputError, match="cannot be listed beside other models"):
        FitRequest.of(["auto", "ggx"])
    with pytest.raises(FitInputError, match="give at least one model"):
        FitRequest.of([])
    with pytest.raises(FitInputError, match="samples must be"):
        FitRequest.of("ggx", samples=3)


def test_a_list_of_names_with_an_empty_item_is_refused_and_numpy_numbers_are_numbers():
    """``"ggx,,lambert"`` lost a name silently (read as ggx,lambert): refused, as the
    service's ``models`` string takes it too. A seed from ``rng.integers`` (np.int64)
    is an integer, and the request's JSON form holds it as one."""
    import numpy as np

    from brdffit.request import split_names

    assert split_names(" ggx , lambert ") == ["ggx", "lambert"] and split_names(" ") == []
    for text in ("ggx,,lambert", "ggx,", ",ggx", "ggx, ,lambert"):
        with pytest.raises(FitInputError, match=f"models {text!r} has an empty item "
                                                r"\(two commas in a row, or one at an end\)"):
            FitRequest.of(text)
    for names in (["ggx", ""], ["ggx", "  "]):  # a JSON list, as the service takes it
        with pytest.raises(FitInputError, match="has an empty name"):
            FitRequest.of(names)
    r = FitRequest.of("ggx", seed=np.int64(3), samples=np.int32(4096), starts=np.uint8(2))
    assert r.options.seed == 3 and type(r.options.seed) is int
    assert json.loads(json.dumps(r.to_dict()))["options"]["seed"] == 3
    auto = FitRequest.of("auto", tolerance=np.float32(0.5))
    assert type(auto.rule.tolerance) is float
    with pytest.raises(FitInputError, match="seed must be an integer"):
        FitRequest.of("ggx", seed=np.float64(3.5))


@pytest.mark.parametrize("rule", [{"tolerance": 0.01}, {"budget": 0.02},
                                  {"candidates": ["lambert"]}, {"mono_ks": True}])
def test_a_selection_rule_with_a_fixed_model_is_refused_not_ignored(rule):
    with pytest.raises(FitInputError, match="with model ggx it would be ignored") as e:
        FitRequest.of("ggx", **rule)
    assert next(iter(rule)) in str(e.value) and "model auto" in str(e.value)
    FitRequest.of("auto", **rule)  # where it means something


def test_a_request_round_trips_through_json():
    r = FitRequest.of("auto", candidates=["lambert", "ggx"], budget=0.01, samples=4096,
                      scene=None)
    d = json.loads(json.dumps(r.to_dict(), allow_nan=False))
    assert FitRequest.from_dict(d) == r and d["schema"] == REQUEST_SCHEMA
    assert set(d) == {"schema", "models", "options", "scene", "rule"}
    assert "model" not in d["options"] and "tolerance" not in d["options"]
    assert d["rule"] == {"tolerance": 0.005, "budget": 0.01, "candidates": ["lambert", "ggx"],
                         "mono_ks": False}
    # the form the service stored and took before: models and one flat dict
    flat = {**d["options"], "candidates": ["lambert", "ggx"], "budget": 0.01, "scene": None,
            "model": "auto"}
    assert FitRequest.from_dict(legacy_request(["auto"], flat)) == r
    # the old form sent the rule's defaults with every model: not a rule of a fixed model
    old = {"samples": 4096, "tolerance": 0.005, "budget": None, "candidates": None,
           "mono_ks": False, "scene": None}
    assert FitRequest.from_dict(legacy_request(["ggx"], old)).rule is None
    with pytest.raises(FitInputError, match="would be ignored"):
        FitRequest.from_dict(legacy_request(["ggx"], {**old, "tolerance": 0.02}))
    with pytest.raises(FitInputError, match="unknown request keys"):
        FitRequest.from_dict({**d, "colour": "red"})
    with pytest.raises(FitInputError, match="unknown fit options"):
        FitRequest.from_dict({**d, "options": {"smaples": 3}})
    assert FitRequest(models=("ggx",)).options == FitOptions()
    with pytest.raises(FitInputError, match="request schema"):
        FitRequest.from_dict({**d, "schema": "brdffit.request/9"})
    with pytest.raises(FitInputError, match="rule must be a JSON object"):
        FitRequest.from_dict({**d, "rule": 0.01})
    assert FitRequest.from_dict({"models": "auto"}).rule == SelectionRule()  # the default rule


# -- one rule for "best" ---------------------------------------------------------------------


def test_best_is_the_lowest_error_and_a_tie_goes_to_fewer_parameters():
    rows = [{"model": "ggx", "n_params": 8, "log_rmse": 0.01},
            {"model": "lambert", "n_params": 3, "log_rmse": 0.01 + 1e-9},
            {"model": "phong", "n_params": 7, "log_rmse": 0.02},
            {"model": "beckmann", "n_params": 8, "status": "failed"}]
    row, reason = best(rows)
    assert row["model"] == "lambert" and "phong 0.02" in reason
    rows[1]["log_rmse"] = 0.011
    assert best(rows)[0]["model"] == "ggx"
    nan = [{"model": "ggx", "n_params": 8, "log_rmse": float("nan")}]
    assert best(nan)[0]["model"] == "ggx" and "No fit has a finite" in best(nan)[1]
    with pytest.raises(FitInputError):
        best([{"model": "ggx", "status": "failed"}])


def test_the_stored_result_of_a_set_of_fits_is_auto_s_choice_or_the_best():
    fits = [{"model": "ggx", "error": {"log_rmse": 0.010}},
            {"model": "lambert", "error": {"log_rmse": None}},
            {"model": "beckmann", "error": {"log_rmse": 0.012}}]
    assert chosen_result(fits)["model"] == "ggx"
    fits[2]["selection"] = {"chosen": "beckmann"}
    assert chosen_result(fits)["model"] == "beckmann"
    assert chosen_result([{"model": "from-the-future", "error": {"log_rmse": 1.0}}])


# -- run --------------------------------------------------------------------------------------


def test_run_fits_a_list_and_reports_the_best(lambert_table):
    report = run(lambert_table, FitRequest.of(["ggx", "lambert"], **FAST))
    assert list(report.fits) == ["ggx", "lambert"] and report.failed == {}
    # lambert's own table: ggx fits it as well (ks -> 0), and a tie goes to fewer values
    assert report.chosen == "lambert" and best(report.ranking)[0]["model"] == "lambert"
    assert report.chosen_fit is report.fits[report.chosen] and report.selection is None
    d = json.loads(json.dumps(report.to_dict(), allow_nan=False))
    assert d["schema"] == REPORT_SCHEMA and d["chosen"] == report.chosen
    assert [r["model"] for r in d["results"]] == ["ggx", "lambert"]
    assert [row["model"] for row in d["ranking"]] == ["ggx", "lambert"]


def test_run_auto_is_select(lambert_table):
    calls = []
    report = run(lambert_table, FitRequest.of("auto", candidates=["lambert", "oren_nayar"],
                                              **FAST),
                 progress=lambda i, n, m, row: calls.append((i, m, row is None)))
    assert report.chosen == report.selection.chosen == "lambert"
    assert report.chosen_fit.selection["chosen"] == "lambert"
    assert [r["model"] for r in report.ranking] == ["lambert", "oren_nayar"]
    assert calls == [(0, "lambert", True), (0, "lambert", False), (1, "oren_nayar", True),
                     (1, "oren_nayar", False)]


def test_run_keeps_the_fits_it_could_make_and_says_which_it_could_not():
    """A scene of 20 bins: lambert (3 values) fits, ggx2 (12) cannot."""
    from brdffit.fitting.scene import Scene

    table = make_table("lambert", {"kd": [0.3, 0.2, 0.1]})[0]
    scene = Scene.from_dict({"pairs": [[[0.05 * i, 0.0, 1.0], [-0.05 * i, 0.03 * i, 1.0]]
                                       for i in range(20)], "spread": 0})
    report = run(table, FitRequest.of(["lambert", "ggx2"], scene=scene, **FAST))
    assert list(report.fits) == ["lambert"] and report.chosen == "lambert"
    assert "ggx2 needs at least" in report.failed["ggx2"]
    with pytest.raises(FitInputError, match="ggx2 needs at least"):
        run(table, FitRequest.of(["ggx2"], scene=scene, **FAST))


def test_default_candidates_are_the_registry_s_auto_models():
    from brdffit import models

    assert set(DEFAULT_CANDIDATES) <= set(models.REGISTRY)


# -- what crosses a process boundary ----------------------------------------------------------


def test_an_outcome_is_plain_data_and_tells_input_from_bug():
    ok = Outcome.success([1, 2], notes=["ggx could not be fitted"])
    assert Outcome.from_dict(json.loads(json.dumps(ok.to_dict()))) == ok
    bad = Outcome.failure(MerlFormatError("t.binary", "truncated"))
    assert not bad.ok and not bad.internal and "truncated" in bad.reason
    assert bad.error_type == "MerlFormatError" and bad.traceback is None
    try:
        raise ZeroDivisionError("division by zero")
    except ZeroDivisionError as e:
        bug = Outcome.failure(e)
    assert bug.internal and bug.reason.startswith("internal error: ZeroDivisionError")
    assert "Traceback" in bug.traceback
    import pickle

    assert pickle.loads(pickle.dumps(bug)) == bug


def test_the_rule_belongs_to_auto_and_the_scene_to_the_fit_key():
    """A rule is a request's only with auto; the scene changes what is fitted, so a batch
    resumes a fit only under the same scene."""
    from brdffit.fitting.scene import Scene

    r = FitRequest(models=("beckmann",), options=FitOptions())
    assert r.rule is None and r.to_dict()["models"] == ["beckmann"]
    assert FitRequest(models=("auto",)).rule == SelectionRule()
    with pytest.raises(FitInputError, match="would be ignored"):
        FitRequest(models=("ggx",), rule=SelectionRule())
    scene = Scene.preset("camera-normal")
    assert FitRequest.of("ggx").fit_key() == FitOptions().key()  # earlier files still resume
    assert FitRequest.of("ggx", scene=scene).fit_key() != FitRequest.of("ggx").fit_key()
    assert FitRequest.of("ggx", scene=scene).fit_key() == FitOptions.key_of(
        FitRequest.of("ggx", scene=scene).fit_record())
