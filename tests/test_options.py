"""One fit contract: the library's FitOptions, and every shell reading it.

Each shell's defaults are read from the shell itself (the CLI's parsers, the
service's request schema, the batch job's options), never from brdffit.fitting.options,
so a shell that declares its own value fails here.
"""

from __future__ import annotations

import inspect
import json
import math

import numpy as np
import pytest
from pydantic import ValidationError

from brdffit import FitInputError, FitResult, fit
from brdffit.cli import build_parser
from brdffit.fitting import options
from brdffit.fitting.options import DEFAULT_MODEL, FIT_KEYWORDS, FitOptions, SelectionRule
from brdffit.io import merl
from brdffit.models import UnknownModelError
from brdffit.request import FitRequest
from tests.cli_helpers import run_main

pytestmark = pytest.mark.contract


def _library_defaults() -> dict:
    return FitOptions().to_dict()


# -- defaults: one declaration, every shell -------------------------------------------


def test_fit_signature_and_select_take_the_contract_defaults():
    from brdffit.selection import select

    fit_sig = inspect.signature(fit).parameters
    select_sig = inspect.signature(select).parameters
    want = _library_defaults()
    for name in FIT_KEYWORDS:
        assert fit_sig[name].default == want[name], name
    assert fit_sig["model"].default == DEFAULT_MODEL
    rule = SelectionRule()
    for name in ("tolerance", "budget", "mono_ks"):
        assert select_sig[name].default == getattr(rule, name), name
    assert tuple(select_sig["candidates"].default) == rule.candidates


def test_cli_fit_has_every_option_with_the_contract_default():
    from brdffit.cli.fit import request_from_args

    want = _library_defaults()
    args = build_parser().parse_args(["fit", "t.binary"])
    assert {n: getattr(args, n, "MISSING") for n in want} == want
    assert request_from_args(args) == FitRequest.of(DEFAULT_MODEL)
    # the rule's flags, unset, are no rule: the default one for auto
    args = build_parser().parse_args(["fit", "t.binary", "--model", "auto"])
    assert request_from_args(args).rule == SelectionRule()
    args = build_parser().parse_args(["fit", "t.binary", "--model", "auto", "--tolerance",
                                      "0.02", "--candidates", "lambert,ggx", "--mono-ks"])
    assert request_from_args(args).rule == SelectionRule(tolerance=0.02, mono_ks=True,
                                                         candidates=("lambert", "ggx"))


def test_cli_batch_has_every_fit_option_with_the_contract_default():
    want = FitOptions().fit_keywords()
    args = build_parser().parse_args(["batch", "d", "--models", "ggx", "--out", "o.h5"])
    assert {n: getattr(args, n, "MISSING") for n in want} == want
    from brdffit.cli.fit import request_from_args

    assert request_from_args(args, args.models) == FitRequest.of("ggx")
    # the batch takes what `fit` takes: a scene and auto's rule
    args = build_parser().parse_args(["batch", "d", "--models", "auto", "--out", "o.h5",
                                      "--candidates", "lambert,ggx",
                                      "--scene-preset", "camera-normal"])
    request = request_from_args(args, args.models)
    assert request.rule.candidates == ("lambert", "ggx") and request.scene is not None


@pytest.mark.parametrize("of", [FitOptions, SelectionRule])
def test_api_request_schema_has_every_option_with_the_contract_default_and_range(of):
    from api.routes import fits as route

    body = route.FitJobRequest(table_id="0" * 64)
    assert body.models == DEFAULT_MODEL and body.rule is None and body.scene is None
    model = route.FitOptions if of is FitOptions else route.SelectionRule
    want = of().to_dict()
    got = model().model_dump()
    for name in want:
        _, opt = options.spec(name, of)
        # a list of names is null in the body for the library's default
        assert got[name] == (None if opt.kind is tuple else want[name]), name
    schema = model.model_json_schema()["properties"]
    for name in want:
        _, opt = options.spec(name, of)
        prop = schema[name]
        bounded = next(p for p in prop.get("anyOf", [prop]) if p.get("type") != "null")
        assert bounded.get("minimum") == opt.least, name
        assert bounded.get("exclusiveMinimum") == opt.above, name
        assert bounded.get("maximum") == opt.most, name
        assert set(bounded.get("enum", ())) == set(opt.choices or ()), name
        assert ("anyOf" in prop) == (opt.none is not None or opt.kind is tuple), name


def test_the_api_body_is_the_library_s_request():
    """POST /v1/fits takes ``FitRequest.to_dict()`` and a table id; the form before it
    (``model`` and flat options) is rearranged into it, not refused."""
    from api.routes.fits import FitJobRequest

    request = FitRequest.of("auto", samples=4096, tolerance=0.01,
                            scene={"preset": "camera-normal"})
    body = FitJobRequest(table_id="0" * 64, **request.to_dict())
    assert body.request_dict() == request.to_dict()
    old = FitJobRequest.model_validate({"table_id": "0" * 64, "model": "auto", "options": {
        "samples": 4096, "tolerance": 0.01, "scene": {"preset": "camera-normal"}}})
    assert FitRequest.from_dict(old.request_dict()) == request
    for bad, words in [({"models": "ggx", "rule": {"tolerance": 0.01}}, "would be ignored"),
                       ({"models": ["auto", "ggx"]}, "cannot be listed"),
                       ({"models": "auto", "rule": {"candidates": ["nope"]}}, "unknown model"),
                       ({"model": "ggx", "models": "ggx"}, "not both")]:
        with pytest.raises(ValidationError, match=words):
            FitJobRequest.model_validate({"table_id": "0" * 64, **bad})


def test_every_shell_offers_the_render_loss():
    """A new loss is one FitOptions value: the CLI's fit and batch, the service's
    request schema and the client's options take it without code of their own."""
    from api.routes.fits import FitOptions as RequestOptions

    assert "render" in options.spec("loss")[1].choices
    assert build_parser().parse_args(["fit", "t.binary", "--loss", "render"]).loss == "render"
    batch = build_parser().parse_args(["batch", "d", "--models", "ggx", "--out", "o.h5",
                                       "--loss", "render"])
    assert batch.loss == "render"
    schema = RequestOptions.model_json_schema()["properties"]["loss"]
    assert "render" in schema["enum"]
    assert RequestOptions(loss="render").loss == "render"
    assert FitOptions.from_dict({"loss": "render"}).key() != FitOptions().key()


def test_batch_options_are_the_library_options():
    from brdffit.batch import job as batch
    from brdffit.batch import tasks as batch_tasks

    assert batch_tasks.FitOptions is FitOptions
    # a batch runs one FitRequest, as `brdffit fit` does
    assert list(inspect.signature(batch.run_batch).parameters)[:3] == ["inputs", "request", "out"]
    assert batch.request_of(["ggx", "lambert"]) == FitRequest.of(["ggx", "lambert"])


def _edges(name: str, of=FitOptions):
    """(valid, invalid) values at the ends of an option's range."""
    _, opt = options.spec(name, of)
    if opt.choices is not None:
        return list(opt.choices), ["no-such-" + name]
    if opt.kind is bool:
        return [True, False], ["yes", 1, None]
    step = 1 if opt.kind is int else 1e-9
    valid, invalid = [], []
    if opt.least is not None:
        valid.append(opt.kind(opt.least))
        invalid.append(opt.kind(opt.least - step))
    if opt.above is not None:
        valid.append(opt.above + step)
        invalid.append(opt.kind(opt.above))
    if opt.most is not None:
        valid.append(opt.kind(opt.most))
        invalid.append(opt.kind(opt.most + step))
    # the service is as strict as the library: true is no count, 1e4 (a JSON float) no
    # integer, true no number
    invalid.append(True)
    if opt.kind is int and valid:
        invalid.append(float(valid[0]))
    return valid, invalid


@pytest.mark.parametrize(("of", "name"), [
    *((FitOptions, n) for n in options.names()),
    *((SelectionRule, n) for n in options.names(SelectionRule) if n != "candidates")])
def test_api_and_library_accept_and_refuse_the_same_values(of, name):
    from api.routes import fits as route

    body = route.FitOptions if of is FitOptions else route.SelectionRule
    valid, invalid = _edges(name, of)
    for v in valid:
        of(**{name: v})
        body(**{name: v})
    for v in invalid:
        with pytest.raises(FitInputError):
            of(**{name: v})
        with pytest.raises(ValidationError):
            body(**{name: v})


def test_options_refuse_bad_values_with_a_message():
    for bad, words in [({"starts": 0}, "starts must be an integer in 1 .. 32"),
                       ({"samples": 10}, "samples must be"), ({"seed": True}, "seed"),
                       ({"solver": "newton"}, "newton")]:
        with pytest.raises(FitInputError, match=words):
            FitOptions(**bad)
    for bad, words in [({"tolerance": math.nan}, "tolerance"), ({"budget": 0}, "budget"),
                       ({"candidates": []}, "candidates must be a list"),
                       ({"candidates": "ggx"}, "candidates must be a list")]:
        with pytest.raises(FitInputError, match=words):
            SelectionRule(**bad)
    with pytest.raises(UnknownModelError, match="unknown model 'nope'"):
        SelectionRule(candidates=("nope",))
    with pytest.raises(FitInputError, match="unknown fit options"):
        FitOptions.from_dict({"stars": 2})
    with pytest.raises(FitInputError, match="unknown selection rule keys"):
        SelectionRule.from_dict({"model": "ggx"})
    assert SelectionRule(candidates=("ggx", "lambert", "ggx")).candidates == ("ggx", "lambert")


@pytest.mark.parametrize(("name", "value"), [("samples", 10**12), ("starts", 64),
                                           ("max_steps", 20_000), ("loss", ["log"]),
                                           ("solver", ("lm",)), ("precision", 64)])
def test_fit_refuses_what_the_shells_refuse_before_any_work(noisy_table, name, value):
    """``fit`` called directly is held to the ranges the command line and the service
    offer (10**12 samples was a MemoryError of 7.3 TiB, a loss in a list a TypeError)."""
    with pytest.raises(FitInputError, match=name):
        fit(merl.read(noisy_table), "lambert", **{name: value})
    with pytest.raises(FitInputError, match=name):
        FitOptions(**{name: value})


def test_cli_refuses_what_the_options_refuse(tmp_path):
    r = run_main("brdffit.cli", "fit", str(tmp_path / "absent.binary"), "--starts", "0")
    assert r.returncode == 2 and "starts must be an integer in 1 .. 32" in r.stderr
    r = run_main("brdffit.cli", "fit", str(tmp_path / "absent.binary"), "--samples", "lots")
    assert r.returncode == 2 and "--samples wants an integer or 'all'" in r.stderr


# -- the batch's resume key ----------------------------------------------------------------


def test_key_format_is_the_one_results_files_hold():
    # The literal string earlier results files hold for these options: a change of
    # format would make every finished fit look unfinished on resume.
    o = FitOptions(solver="lm", samples=4096, precision="float32", starts=2, max_steps=100,
                   seed=7)
    assert o.key() == ('{"max_steps":100,"precision":"float32","samples":4096,"seed":7,'
                       '"solver":"lm","starts":2}')
    assert FitOptions(samples=None).key() == FitOptions.key_of(
        {**FitOptions().fit_keywords(), "samples": None})
    # an option added later is left out of the key at its default: old keys still match
    assert "physical" not in FitOptions().key()
    assert json.loads(FitOptions(physical=True).key())["physical"] is True
    # a stored record from another range is still keyed, not refused
    old = {"solver": "lm", "samples": 4096, "precision": "float64", "starts": 64,
           "max_steps": 20_000, "seed": 0}
    assert json.loads(FitOptions.key_of(old)) == old


# -- one result: library, CLI, service, batch ---------------------------------------------


def _noisy_lambert_file(tmp_path_factory, name: str, kd: list[float]):
    from data_synth import make_table

    # noise, so that the subsample (the seed) changes the fitted values
    table, _ = make_table("lambert", {"kd": kd}, noise=0.05, seed=1)
    path = tmp_path_factory.mktemp("contract") / name
    merl.write(path, table)
    return path


@pytest.fixture(scope="module")
def noisy_table(tmp_path_factory):
    return _noisy_lambert_file(tmp_path_factory, "lambert.binary", [0.5, 0.35, 0.2])


@pytest.fixture(scope="module")
def bright_table(tmp_path_factory):
    # kd above 1: the physically bounded fit has a bound to hold
    return _noisy_lambert_file(tmp_path_factory, "bright.binary", [1.2, 0.8, 0.4])


FAST = {"samples": 2048, "seed": 3}


def _same_fit(a: dict, b: dict) -> None:
    """Two results of one deterministic fit: the same JSON but for the clocks (fit
    times, and the measured evaluation cost that ranks auto's candidates)."""
    clocks = {"time_s", "fit_time_s", "cost_ns"}
    a, b = dict(a), dict(b)
    for d in (a, b):
        d.pop("time_s")
        if d.get("selection"):
            s = d["selection"] = {k: v for k, v in d["selection"].items() if k not in clocks}
            s["ranking"] = [{k: v for k, v in row.items() if k not in clocks}
                            for row in s["ranking"]]
    assert json.loads(json.dumps(a)) == json.loads(json.dumps(b))


# auto and the physical bounds take ~6 s each through every door: the full suite runs
# them, the quick tier the plain fit
@pytest.mark.parametrize("model, physical", [
    ("lambert", False), pytest.param("auto", False, marks=pytest.mark.slow),
    pytest.param("lambert", True, marks=pytest.mark.slow)])
def test_library_cli_api_and_batch_give_the_same_result_json(noisy_table, bright_table,
                                                              tmp_path, model, physical):
    """One fit, four ways: the library, ``brdffit fit --json``, the service's job and
    the batch store all give the result schema with the same keys and values; a
    physically bounded fit (``--physical``) too."""
    from api import tasks
    from api.routes.fits import FitJobRequest, FitResultOut
    from brdffit.batch.job import run_batch
    from brdffit.batch.report import rank
    from brdffit.batch.store import read_fit, read_results
    from brdffit.request import FitRequest
    from brdffit.request import run as run_request
    from brdffit.selection import chosen_result as best_result
    from brdffit.selection import select

    path = str(bright_table if physical else noisy_table)
    fast = {**FAST, "physical": physical}
    candidates = ["lambert", "oren_nayar"]
    if model == "auto":
        library = run_request(merl.read(path), FitRequest.of(
            "auto", candidates=candidates, **fast)).chosen_fit.to_dict()
        assert library["selection"]["chosen"] == library["model"]
        # the front door is select's choice, nothing added
        _same_fit(select(merl.read(path), candidates, **fast).to_dict(), library)
    else:
        library = fit(merl.read(path), model, **fast).to_dict()
    assert list(library) == FitResult.keys() and library["schema"] == "brdffit.fit/9"
    assert (library["physical"] is not None) == physical
    if physical:
        assert library["physical"]["active"][0] == "range: kd[R] <= 1"
    FitResult.from_dict(library)  # reads back

    cli_args = ["--candidates", ",".join(candidates)] if model == "auto" else []
    cli_args += ["--physical"] if physical else []
    r = run_main("brdffit.cli", "fit", path, "--model", model, "--json", "--samples", "2048",
            "--seed", "3", *cli_args)
    assert r.returncode == 0, r.stderr
    _same_fit(json.loads(r.stdout), library)

    request = (FitRequest.of("auto", candidates=candidates, **fast) if model == "auto"
               else FitRequest.of(model, **fast))
    # what the service's worker is handed: the body as the route validated it
    body = FitJobRequest(table_id="0" * 64, **request.to_dict()).request_dict()
    out = tasks.fit_models(path, "noisy.binary", body)
    assert out.ok, out
    served = FitResultOut.model_validate(best_result(out.value)).model_dump(by_alias=True)
    renamed = {**library, "table": "noisy.binary"}  # named as the uploader named it
    if model == "auto":
        renamed["selection"] = {**library["selection"], "table": "noisy.binary"}
    _same_fit(served, renamed)
    assert set(FitResultOut.model_fields) | {"schema"} - {"schema_"} >= set(library)

    run_batch([path], request, tmp_path / "r.h5", workers=0, progress=False)
    stored = read_results(tmp_path / "r.h5")["tables"][0]["fits"]
    # a batch stores every candidate, the chosen one carrying auto's ranking and reason
    _same_fit(stored[library["model"]]["fit"], {**library, "table": path})
    if model == "auto":
        assert set(stored) == set(candidates)
        (ranked,) = rank(tmp_path / "r.h5").tables
        assert ranked.chosen()[0] == library["selection"]["chosen"]
        assert read_fit(tmp_path / "r.h5", ranked.name)["selection"] == stored[
            library["model"]]["fit"]["selection"]
        # "auto" names that choice, as the service's ?model=auto does (it had "no auto fit")
        assert read_fit(tmp_path / "r.h5", ranked.name, "auto") == read_fit(
            tmp_path / "r.h5", ranked.name)


def test_fit_seed_reaches_the_fit(noisy_table):
    path = str(noisy_table)
    seed3 = fit(merl.read(path), "lambert", **FAST).params["kd"]
    seed0 = fit(merl.read(path), "lambert", samples=2048, seed=0).params["kd"]
    assert not np.allclose(seed3, seed0, rtol=1e-9), "the seed must change the subsample"
    r = run_main("brdffit.cli", "fit", path, "--model", "lambert", "--json", "--samples", "2048",
            "--seed", "0")
    assert r.returncode == 0, r.stderr
    np.testing.assert_allclose(json.loads(r.stdout)["params"]["kd"], seed0, rtol=1e-9)


# -- the docs state the defaults from the same source ---------------------------------------


@pytest.mark.parametrize("doc", ["docs/fitting.md", "docs/service.md"])
def test_docs_option_tables_are_generated_from_the_contract(doc):
    import re
    from pathlib import Path

    text = (Path(__file__).parent.parent / doc).read_text()
    blocks = re.findall(r"<!-- fit options: generated .*? style=(\w+) -->\n(.*?)\n<!-- end",
                        text, re.S)
    assert blocks, f"{doc} has no generated option table"
    for style, table in blocks:
        assert table == options.markdown_table(style), (
            f"{doc} is out of date: run `python -m brdffit.fitting.options --docs {doc}`")
