"""Standard errors, correlations and undetermined parameters (brdffit.fitting.uncertainty),
checked against the spread of fits to noisy copies of a table."""

from __future__ import annotations

import json

import numpy as np
import pytest

from brdffit.fitting.pipeline import fit
from brdffit.fitting.result import FitResult
from brdffit.fitting.uncertainty import entry_names
from brdffit.io.grid import bin_grid
from brdffit.models import get
from data_synth import make_table

pytestmark = pytest.mark.unit

COPIES = 16
SAMPLES = 4096


def _flat(d: dict) -> list:
    out = []
    for v in d.values():
        out += list(v) if isinstance(v, list) else [v]
    return out


def _sharper_first(params: dict, se: dict) -> tuple[dict, dict]:
    # ggx2's lobes are interchangeable: a fit may return the sharper one second
    if "alpha1" in params and params["alpha1"] > params["alpha2"]:
        swap = {"ks1": "ks2", "alpha1": "alpha2", "ks2": "ks1", "alpha2": "alpha1"}
        params = {k: params[swap.get(k, k)] for k in params}
        se = {k: se[swap.get(k, k)] for k in se}
    return params, se


@pytest.mark.slow
@pytest.mark.parametrize("model", ["ggx", "ggx2"])
def test_standard_errors_match_the_spread_of_fits_to_noisy_copies(model):
    """16 copies here (bench/uncertainty_check.py runs 50): every reported error is
    within a factor 1.5 of the standard deviation of the fitted values."""
    values, errors = [], []
    for k in range(COPIES):
        table, _ = make_table(model, noise=0.05, seed=100 + k)
        r = fit(table, model, samples=SAMPLES)
        assert r.converged
        params, se = _sharper_first(r.params, r.uncertainty["std_error"])
        values.append(_flat(params))
        errors.append(_flat(se))
        assert not any(_flat(r.uncertainty["undetermined"]))
    spread = np.std(np.asarray(values), axis=0, ddof=1)
    reported = np.median(np.asarray(errors, dtype=float), axis=0)
    ratio = reported / spread
    names = entry_names(get(model))
    assert np.all((ratio > 1 / 1.5) & (ratio < 1.5)), dict(zip(names, ratio.round(2)))


def test_a_pure_diffuse_table_flags_the_lobe_shape():
    table, _ = make_table("lambert", noise=0.05, seed=7)
    r = fit(table, "ggx", samples=SAMPLES)
    u = r.uncertainty
    assert u["undetermined"]["alpha"] is True
    assert u["why"]["alpha"].startswith("no lobe: ks within 2 standard errors of 0")
    # no figure: the curvature along alpha of a lobe that is not there is the noise's (the
    # JSON read "1.117 +- 0.011" beside the flag; the text printed none)
    assert u["std_error"]["alpha"] is None and u["std_error_transformed"]["alpha"] is None
    assert u["undetermined"]["kd"] == [False, False, False]


def test_an_absent_lobes_shape_is_undetermined_at_a_bound_and_in_every_lobe():
    """A shape held at its bound beside a lobe that is not there is held by the bound,
    not the data (a noisy diffuse table's phong read n = 0.1 "at bound", determined);
    and ggx3's and ggx4's later lobes are lobes too (ggx4's alpha4 beside a ks4 of 1e-12
    read 0.0011111 +- 3.6e-05, determined)."""
    from brdffit.fitting.uncertainty import LOBE_SCALE

    table, _ = make_table("lambert", {"kd": [0.5, 0.35, 0.2]}, noise=0.3, seed=7)
    u = fit(table, "phong", samples=SAMPLES).uncertainty
    assert u["at_bound"]["n"] and u["undetermined"]["n"] is True, u
    assert u["why"]["n"].startswith("no lobe")
    # every lobe's shape names its scale
    for model in ("ggx2", "ggx3", "ggx4"):
        names = {s.name for s in get(model).param_specs}
        for shape in names & {"alpha", "alpha1", "alpha2", "alpha3", "alpha4"}:
            assert set(LOBE_SCALE[shape]) & names, (model, shape)


def test_ks_and_f0_trade_off_without_grazing_bins():
    """With only small difference angles the Fresnel term is ~f0 everywhere: the lobe
    scales with ks f0, and the two cannot be told apart."""
    keep = bin_grid().theta_d < np.radians(20)
    table, _ = make_table("ggx", noise=0.02, seed=3, keep=keep)
    r = fit(table, "ggx", samples=SAMPLES)
    u = r.uncertainty
    flagged = {k for k, v in u["undetermined"].items() if any(np.atleast_1d(v))}
    assert "f0" in flagged, u["why"]
    assert any("f0" in others for others in u["strongly_correlated"].values()) \
        or "trades off" in u["why"]["f0"], u


def test_uncertainty_is_strict_json_and_reads_back():
    table, _ = make_table("lambert", noise=0.05, seed=7)
    r = fit(table, "ggx", samples=SAMPLES)
    d = json.loads(r.to_json())  # jsonout refuses NaN: a missing error is null
    u = d["uncertainty"]
    p = len(u["entries"])
    assert len(u["correlation"]) == p and all(len(row) == p for row in u["correlation"])
    assert set(u["std_error"]) == set(r.params) == set(u["std_error_transformed"])
    assert FitResult.from_dict(d).uncertainty == u
    for i in range(p):  # a correlation matrix: 1 on the diagonal where it is defined
        assert u["correlation"][i][i] is None or abs(u["correlation"][i][i] - 1) < 1e-9


def test_fit_text_shows_errors_and_flags():
    from brdffit.cli.fit import format_result

    table, _ = make_table("lambert", noise=0.05, seed=7)
    text = format_result(fit(table, "ggx", samples=SAMPLES))
    assert "±" in text and "UNDETERMINED" in text and "alpha: no lobe" in text
    # an absent lobe's shape is printed without a standard error: it measures nothing
    (alpha,) = [line for line in text.splitlines() if line.strip().startswith("alpha ")]
    assert "±" not in alpha and alpha.endswith("UNDETERMINED"), alpha
    assert "sphere PSNR" in text and "cube_root_rmse" in text


@pytest.mark.parametrize("model,loss", [("ggx", "log"), ("oren_nayar", "cube_root"),
                                        ("ggx", "render")])
def test_the_solvers_terms_give_the_uncertainty_computed_afresh(model, loss):
    """The lm solve carries the sandwich's bread and meat at its solution (its own
    normal equations, the render loss's energy rows included; the generic Jacobian
    of a model that is not colour-linear): the uncertainty from them is the one
    computed afresh at the fitted point."""
    import jax.numpy as jnp

    from brdffit.fitting import problem
    from brdffit.fitting.uncertainty import parameter_uncertainty

    table, _ = make_table(model, noise=0.05, seed=7)
    m = get(model)
    prep = problem.prepare(table, None, SAMPLES, 0, "float64", loss)
    u0 = m.unconstrain(m.check_params(fit(table, model, samples=SAMPLES, loss=loss).params))
    values, _, _, _, terms = problem.solve_batch(
        m, "lm", jnp.asarray(u0[None]), prep.data, jnp.asarray(50), n_live=jnp.asarray(1))
    u = np.asarray(values[0])
    carried = parameter_uncertainty(m, u, prep.data, (terms[0][0], terms[1][0]))
    afresh = parameter_uncertainty(m, u, prep.data)
    assert carried["residuals"] == afresh["residuals"] > 0
    np.testing.assert_allclose(np.asarray(_flat(carried["std_error"]), float),
                               np.asarray(_flat(afresh["std_error"]), float), rtol=1e-8)
    np.testing.assert_allclose(np.asarray(carried["correlation"], float),
                               np.asarray(afresh["correlation"], float), atol=1e-8)
