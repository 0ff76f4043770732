"""The loss, its normal equations and the full-table error."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from brdffit import models
from brdffit.fitting import loss, sampling
from brdffit.fitting import pipeline as fitting
from data_synth import make_table
from tests.truths import TRUTH

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def noisy_ggx():
    return make_table("ggx", TRUTH["ggx"], noise=0.05, missing=0.1, seed=3)[0]


MORE = {  # models with another parameter layout than TRUTH's
    "ggx2": {"kd": [0.1, 0.1, 0.1], "ks1": [0.5, 0.4, 0.3], "alpha1": 0.05,
             "ks2": [0.2, 0.25, 0.2], "alpha2": 0.3, "f0": 0.5},
    "ggx_dielectric": {"kd": [0.2, 0.1, 0.05], "ks": [0.8, 0.7, 0.6], "alpha": 0.15, "eta": 1.5},
    "ggx_mono": {"kd": [0.2, 0.1, 0.05], "ks": 0.7, "alpha": 0.15, "f0": 0.6},
}


@pytest.mark.parametrize("name", [*TRUTH, *MORE])
def test_structured_normal_equations_equal_plain_jacobian(name, noisy_ggx):
    """The closed-form colour columns of loss.normal_equations (one lobe, two lobes
    in any parameter order, or the generic path) match jacfwd."""
    c = sampling.usable_bins(noisy_ggx)
    s = sampling.stratified_sample(sampling.bin_weights(c.usable), 2048)
    data = fitting.sample_data(noisy_ggx, s.index, s.weight)
    m = models.get(name)
    u = jnp.asarray(m.unconstrain({**TRUTH, **MORE}[name])) + 0.3
    fast = loss.normal_equations(u, (m, data))
    plain = loss._generic_normal_equations(u, (m, data))
    for a, b in zip(fast, plain):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-9, atol=1e-14)


@pytest.mark.parametrize("params", [TRUTH["ggx"], {**TRUTH["ggx"], "alpha": 0.05, "f0": 0.2}])
def test_full_table_error_float32_matches_float64(params, noisy_ggx):
    m = models.get("ggx")
    u = m.unconstrain(params)
    w = sampling.bin_weights(sampling.usable_bins(noisy_ggx).usable)
    e32 = fitting.full_table_metrics(noisy_ggx, m, u, w, dtype=jnp.float32)
    e64 = fitting.full_table_metrics(noisy_ggx, m, u, w, dtype=jnp.float64)
    for k in e64:
        assert e32[k] == pytest.approx(e64[k], rel=1e-4), k


def test_full_table_metrics_equal_the_loss_definition(noisy_ggx):
    """The fused full-table metric is the LossData metric (one definition)."""
    m = models.get("ggx")
    u = jnp.asarray(m.unconstrain(TRUTH["ggx"]))
    w = sampling.bin_weights(sampling.usable_bins(noisy_ggx).usable)
    a = fitting.full_table_metrics(noisy_ggx, m, u, w, dtype=jnp.float64)
    b = loss.error_metrics(u, m, fitting.full_table_data(noisy_ggx, w))
    for k in a:
        assert a[k] == pytest.approx(float(b[k]), rel=1e-10), k


def test_log_rmse_of_the_truth_is_the_noise(noisy_ggx):
    e = fitting.table_error(noisy_ggx, "ggx", TRUTH["ggx"])
    assert 1e-3 < e["log_rmse"] < 0.02
    clean = make_table("ggx", TRUTH["ggx"])[0]
    assert fitting.table_error(clean, "ggx", TRUTH["ggx"])["log_rmse"] < 1e-6


def test_stratified_sample_is_unbiased_and_fixed_size():
    rng = np.random.default_rng(0)
    w = rng.random(90 * 90 * 180) * (rng.random(90 * 90 * 180) > 0.3)
    w /= w.sum()
    f = rng.random(w.size)
    for n in (100, 4096, 16384):
        s = sampling.stratified_sample(w, n, seed=1)
        assert s.index.size == n and s.n_used == n
        assert s.weight.sum() == pytest.approx(1.0)
        assert np.unique(s.index).size == n
        if n >= 4096:  # ~1/sqrt(n) statistical error: only large samples are checked
            assert (s.weight * f[s.index]).sum() == pytest.approx((w * f).sum(), rel=0.03)
    everything = sampling.stratified_sample(w, None)
    assert everything.n_used == np.count_nonzero(w)


@pytest.mark.parametrize("name", ["ggx", "ggx2", "oren_nayar"])
def test_blocked_normal_equations_equal_one_pass(name, noisy_ggx):
    """Every bin (1.46M samples) is summed in blocks; the sums are the same."""
    c = sampling.usable_bins(noisy_ggx)
    s = sampling.stratified_sample(sampling.bin_weights(c.usable), None)
    assert loss._block_size(s.index.size) is not None
    data = fitting.sample_data(noisy_ggx, s.index, s.weight)
    m = models.get(name)
    u = jnp.asarray(m.unconstrain({**TRUTH, **MORE}[name])) + 0.2
    blocked = loss.normal_equations(u, (m, data))
    one_pass = loss._normal_equations(u, m, data)
    for a, b in zip(blocked, one_pass):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-10, atol=1e-16)


# -- the loss as a choice ----------------------------------------------------------------


@pytest.mark.parametrize("choice", loss.LOSSES)
def test_structured_normal_equations_equal_plain_jacobian_for_every_loss(choice, noisy_ggx):
    c = sampling.usable_bins(noisy_ggx)
    s = sampling.stratified_sample(sampling.bin_weights(c.usable), 2048)
    data = fitting.sample_data(noisy_ggx, s.index, s.weight, loss=choice)
    assert data.loss == choice
    m = models.get("ggx")
    u = jnp.asarray(m.unconstrain(TRUTH["ggx"])) + 0.3
    fast = loss.normal_equations(u, (m, data))
    plain = loss._generic_normal_equations(u, (m, data))
    for a, b in zip(fast, plain, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-9, atol=1e-14)


@pytest.mark.parametrize("choice", loss.LOSSES)
def test_every_loss_recovers_the_truth_and_reports_every_metric(choice):
    table, _ = make_table("ggx", TRUTH["ggx"])
    r = fitting.fit(table, "ggx", loss=choice, samples=2048)
    assert r.converged and r.loss == choice
    for name in ("kd", "ks"):
        np.testing.assert_allclose(r.params[name], TRUTH["ggx"][name], rtol=1e-3, atol=1e-5)
    np.testing.assert_allclose(r.params["alpha"], TRUTH["ggx"]["alpha"], rtol=1e-3)
    metric = loss.LOSS_METRIC[choice]
    assert set(r.error) == {"log_rmse", "cube_root_rmse", "rmse_cos", "rel_peak_error",
                            "psnr_db", f"sample_{metric}"}
    assert r.error[metric] < 1e-4 and r.error["psnr_db"] > 40


def test_each_loss_minimises_its_own_metric():
    """A model that cannot fit the table exactly (Blinn-Phong on GGX): each loss
    ends lowest on the metric it optimised, so the choice matters and is reported."""
    table, _ = make_table("ggx", {**TRUTH["ggx"], "alpha": 0.35, "f0": 0.1})
    fits = {c: fitting.fit(table, "blinn_phong", loss=c, samples=4096) for c in loss.LOSSES}
    for c, r in fits.items():
        metric = loss.LOSS_METRIC[c]
        for other in fits.values():
            assert r.error[metric] <= other.error[metric] * 1.01, (c, metric)
    exponents = sorted(r.params["n"] for r in fits.values())
    assert exponents[-1] > 1.02 * exponents[0], exponents  # the choice changes the fit


def test_an_unknown_loss_is_refused_everywhere():
    from brdffit.errors import FitInputError
    from brdffit.fitting.options import FitOptions

    table, _ = make_table("lambert", TRUTH["lambert"])
    with pytest.raises(FitInputError, match="unknown loss 'l1'; choose one of log, cube_root"):
        fitting.fit(table, "lambert", loss="l1")
    with pytest.raises(FitInputError, match="unknown loss 'l1'"):
        FitOptions(loss="l1")


def test_the_resume_key_names_the_loss_only_when_it_is_not_the_default():
    from brdffit.fitting.options import FitOptions

    assert '"loss"' not in FitOptions().key()  # keys of earlier results files still match
    assert FitOptions(loss="cube_root").key() != FitOptions().key()
    assert FitOptions.key_of(FitOptions(loss="linear_cos").fit_keywords()) == \
        FitOptions(loss="linear_cos").key()


def test_the_loss_reaches_the_cli_the_service_job_and_the_batch(tmp_path):
    """``loss`` is a FitOptions field, so every shell takes it without its own code."""
    import json
    import subprocess
    import sys

    from api import tasks
    from api.routes.fits import FitOptions as RequestOptions
    from api.routes.fits import FitResultOut, best_result
    from brdffit.batch.job import run_batch
    from brdffit.batch.store import read_results
    from brdffit.fitting.options import FitOptions
    from brdffit.io import merl

    table, _ = make_table("ggx", {**TRUTH["ggx"], "alpha": 0.35}, noise=0.02, seed=2)
    path = tmp_path / "t.binary"
    merl.write(path, table)
    r = subprocess.run([sys.executable, "-m", "brdffit.cli", "fit", str(path), "--model", "ggx",
                        "--loss", "cube_root", "--samples", "2048", "--json"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    cli = json.loads(r.stdout)
    assert cli["loss"] == "cube_root" and "sample_cube_root_rmse" in cli["error"]

    out = tasks.fit_models(str(path), "t.binary", ["ggx"],
                           RequestOptions(loss="linear_cos", samples=2048).model_dump())
    served = FitResultOut.model_validate(best_result(out["results"]))
    assert served.loss == "linear_cos" and "sample_rmse_cos" in served.error

    run_batch([str(path)], ["ggx"], tmp_path / "r.h5",
              options=FitOptions(loss="cube_root", samples=2048), workers=0, progress=False)
    stored = read_results(tmp_path / "r.h5")["tables"][0]["fits"]["ggx"]["fit"]
    assert stored["loss"] == "cube_root" and stored["uncertainty"]["std_error"]["alpha"] > 0
    for name, v in cli["params"].items():  # the same fit from the CLI and the batch
        np.testing.assert_allclose(stored["params"][name], v, rtol=1e-9)
