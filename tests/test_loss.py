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
